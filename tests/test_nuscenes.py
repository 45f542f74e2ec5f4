"""nuScenes-lidarseg export / ingestion (paper IV-B, SPEC 3.2).

The simulated export is built from a fabricated world episode (:func:`fake_episode`, records in
the ARCHITECTURE.md raw layout) so these tests do not depend on the renderer's speed; the real
devkit then loads it, and its own projection is compared with the ingestion's ground truth.
"""
from __future__ import annotations

import contextlib
import hashlib
import io
import json
import math
import shutil
from pathlib import Path
from typing import Iterator

import numpy as np
import pytest

from compact_perception.core.classes import CARLA_NAMES, NUSCENES_NAMES, TAG
from compact_perception.core.params import WorldParams, parse_params
from compact_perception.data.geometry import VIEWS, topview_index
from compact_perception.data.nuscenes import LIDAR_CHANNEL, VIEW_CHANNELS
from compact_perception.data.nuscenes.classmap import CARLA_TO_NUSCENES, NUSCENES_INDEX, actor_category
from compact_perception.data.nuscenes.export import export_nuscenes_sim
from compact_perception.data.nuscenes.ingest import (
    NuScenesInputError, ingest_nuscenes, ingest_sample, load_nuscenes,
)
from compact_perception.data.nuscenes.projection import (
    carla_log_depth, matrix_to_quat, project_points, quat_to_matrix, rasterise_points, sensor_to_camera, yaw_quat,
)
from compact_perception.data.nuscenes.split import split_scenes, split_sizes

S_EXPORT = 32
N_SCENES, N_SAMPLES = 5, 2


# ----------------------------------------------------------------------------- fabricated world
def fake_episode(world: WorldParams, town: str, seed: int, n_frames: int, resolution: int) -> Iterator[dict]:
    """A tiny, deterministic episode in the raw record layout (stand-in for render_episode)."""
    rng = np.random.default_rng(seed)
    h = world.lidar.height_m
    S = resolution
    for step in range(n_frames):
        pts, tags = [], []
        # ground: rings of points, road near the ego line, sidewalk / terrain beyond
        r = np.repeat(np.arange(3.0, 31.0, 1.5), 90)
        a = np.tile(np.radians(np.arange(0, 360, 4.0)), len(np.arange(3.0, 31.0, 1.5)))
        x, y = r * np.cos(a), r * np.sin(a)
        pts.append(np.stack([x, y, np.full_like(x, -h)], 1))
        tags.append(np.where(np.abs(y) < 5, TAG["road"], np.where(np.abs(y) < 8, TAG["sidewalk"], TAG["terrain"])))
        # a car at (10, 3) and a pedestrian at (6, -5): points filling the boxes
        for (cx, cy, L, W, H, tag) in ((10.0, 3.0, 4.5, 1.8, 1.5, TAG["vehicle"]), (6.0, -5.0, 0.6, 0.6, 1.8, TAG["pedestrian"])):
            p = rng.uniform(-0.45, 0.45, size=(150, 3)) * [L, W, H] + [cx, cy, -h + H / 2]
            pts.append(p)
            tags.append(np.full(len(p), tag))
        # a building wall ahead-left and vegetation behind
        wy = np.linspace(-10, 10, 120)
        wz = rng.uniform(-h, 4.0, 120)
        pts.append(np.stack([np.full(120, 25.0), wy, wz], 1)); tags.append(np.full(120, TAG["building"]))
        pts.append(np.stack([np.full(60, -15.0), rng.uniform(-6, 6, 60), rng.uniform(-1.5, 1.0, 60)], 1))
        tags.append(np.full(60, TAG["vegetation"]))
        xyz = np.concatenate(pts).astype(np.float32)
        lidar = np.concatenate([xyz, rng.uniform(0.2, 1.0, (len(xyz), 1)).astype(np.float32)], 1)
        rec: dict = {
            "lidar": lidar,
            "lidar_tag": np.concatenate(tags).astype(np.uint8),
            "boxes": np.array([[10.0, 3.0, -h + 0.75, 4.5, 1.8, 1.5, 0.3, TAG["vehicle"]],
                               [6.0, -5.0, -h + 0.9, 0.6, 0.6, 1.8, 0.0, TAG["pedestrian"]]], dtype=np.float32),
            "ego_pose": np.array([5.0 * step + (seed % 7), -3.0 * (seed % 5), 0.1 * step], dtype=np.float64),
            "bev": np.zeros((9, S, S), dtype=np.uint8),
            "meta": {"town": town, "episode": seed, "step": step},
        }
        rec["bev"][0, S // 2 - 3:S // 2 + 3, :] = 1
        for v in VIEWS:
            rec[f"rgb_{v}"] = rng.integers(0, 256, (S, S, 3), dtype=np.uint8)
            rec[f"sem_{v}"] = np.zeros((S, S, 3), dtype=np.uint8)
            rec[f"depth_{v}"] = np.zeros((S, S), dtype=np.uint16)
        yield rec


def _params(params_dict: dict):
    d = json.loads(json.dumps(params_dict))
    d["world"]["resolution"]["default"] = S_EXPORT
    d["datasets"]["nuscenes"]["sim_scenes"]["default"] = N_SCENES
    d["datasets"]["nuscenes"]["sim_samples_per_scene"] = N_SAMPLES
    d["datasets"]["nuscenes"]["version"] = "v1.0-sim"
    return parse_params(d)


def _tree_hash(root: Path) -> str:
    h = hashlib.sha256()
    for p in sorted(root.rglob("*")):
        if p.is_file():
            h.update(str(p.relative_to(root)).encode())
            h.update(p.read_bytes())
    return h.hexdigest()


@pytest.fixture(scope="module")
def params(root):
    import yaml

    with (root / "params.yaml").open() as fh:
        return _params(yaml.safe_load(fh))


@pytest.fixture(scope="module")
def sim_root(tmp_path_factory, params) -> Path:
    out = tmp_path_factory.mktemp("nus") / "nuscenes_sim"
    export_nuscenes_sim(params, out, episode_source=fake_episode)
    return out


@pytest.fixture(scope="module")
def nusc(sim_root, params):
    from nuscenes.nuscenes import NuScenes

    with contextlib.redirect_stdout(io.StringIO()):
        return NuScenes(version=params.datasets.nuscenes.version, dataroot=str(sim_root), verbose=False)


# ----------------------------------------------------------------------------- export + devkit
def test_devkit_loads_simulated_set(nusc, sim_root):
    from nuscenes.utils.data_classes import LidarPointCloud

    assert len(nusc.scene) == N_SCENES and len(nusc.sample) == N_SCENES * N_SAMPLES
    assert nusc.lidarseg_idx2name_mapping == dict(enumerate(NUSCENES_NAMES))
    assert list(nusc.colormap) == list(NUSCENES_NAMES)
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        nusc.list_lidarseg_categories(sort_by="index")
    assert "vehicle.car" in buf.getvalue() and "flat.driveable_surface" in buf.getvalue()
    sample = nusc.sample[0]
    assert set(sample["data"]) == set(VIEW_CHANNELS.values()) | {LIDAR_CHANNEL}
    path, boxes, k = nusc.get_sample_data(sample["data"]["CAM_FRONT"])
    assert Path(path).is_file() and k.shape == (3, 3) and len(boxes) >= 1
    _, lboxes, _ = nusc.get_sample_data(sample["data"][LIDAR_CHANNEL])
    assert {b.name for b in lboxes} == {"vehicle.car", "human.pedestrian.adult"}
    # the car box, seen from LIDAR_TOP (x right, y forward): centre (-3, 10) relative to the LiDAR
    car = next(b for b in lboxes if b.name == "vehicle.car")
    np.testing.assert_allclose(car.center[:2], [-3.0, 10.0], atol=1e-4)
    sd = nusc.get("sample_data", sample["data"][LIDAR_CHANNEL])
    pc = LidarPointCloud.from_file(str(sim_root / sd["filename"]))
    labels = np.fromfile(sim_root / nusc.get("lidarseg", sd["token"])["filename"], dtype=np.uint8)
    assert labels.shape == (pc.points.shape[1],) and labels.max() < 32
    assert (labels == NUSCENES_INDEX["vehicle.car"]).sum() == 150
    assert nusc.get("map", nusc.map[0]["token"])["mask"].mask().max() == 255  # a real road prior


def test_export_deterministic(tmp_path, params, sim_root):
    out = tmp_path / "again"
    export_nuscenes_sim(params, out, episode_source=fake_episode)
    assert _tree_hash(out) == _tree_hash(sim_root)


def _devkit_labels(nusc, lidar_tok: str, cam_tok: str):
    """Devkit projection: (u, v, depth, label) of the points it keeps."""
    ex = nusc.explorer
    pts, depth, im = ex.map_pointcloud_to_image(lidar_tok, cam_tok)
    pts2, colors, _ = ex.map_pointcloud_to_image(lidar_tok, cam_tok, show_lidarseg=True)
    np.testing.assert_allclose(pts, pts2)
    pal = np.array([nusc.colormap[n] for n in NUSCENES_NAMES], dtype=np.float64) / 255.0
    lab = np.argmin(((colors[:, None, :3] - pal[None]) ** 2).sum(-1), axis=1)
    return pts[0], pts[1], depth, lab, im.size


@pytest.mark.parametrize("size", [S_EXPORT, S_EXPORT // 2])
def test_devkit_projection_agrees_with_ingestion(nusc, params, size):
    sample = nusc.sample[1]
    frame = ingest_sample(nusc, sample["token"], size, params.preprocess)
    assert frame["ss"].shape == (4, size, size) and frame["de"].shape == (4, 1, size, size)
    checked = 0
    for n, v in enumerate(VIEWS):
        u, vv, depth, lab, (w, h) = _devkit_labels(nusc, sample["data"][LIDAR_CHANNEL], sample["data"][VIEW_CHANNELS[v]])
        uc, vc = u * size / w, vv * size / h
        col, row = np.floor(uc).astype(int), np.floor(vc).astype(int)
        interior = (col >= 1) & (col < size - 1) & (row >= 1) & (row < size - 1)
        # the devkit projects in float32: skip both pixels at an edge a point lies within 1e-3 px of
        edge = (np.abs(uc - np.rint(uc)) < 1e-3) | (np.abs(vc - np.rint(vc)) < 1e-3)
        near = {(r + dr) * size + c + dc for r, c in zip(row[edge], col[edge]) for dr in (-1, 0, 1) for dc in (-1, 0, 1)}
        interior &= ~np.isin(row * size + col, list(near))
        for pix in np.unique(row[interior] * size + col[interior]):
            sel = np.flatnonzero(interior & (row * size + col == pix))
            best = sel[np.argmin(depth[sel])]
            r, c = divmod(int(pix), size)
            assert frame["ss"][n, r, c] == lab[best], (v, r, c)
            assert abs(float(frame["de"][n, 0, r, c]) - float(carla_log_depth(depth[best]))) < 2e-3
            checked += 1
    assert checked > 20


def test_ingest_writes_cache_and_bev(tmp_path, sim_root, params, nusc):
    out = tmp_path / "cache"
    meta = ingest_nuscenes(sim_root, params.datasets.nuscenes.version, out, resolution=S_EXPORT,
                           preprocess=params.preprocess, split_seed=0)
    saved = json.loads((out / "meta.json").read_text())
    assert saved["source"] == meta["source"] == "simulated nuScenes-format"
    assert saved["has_dvs"] is False and saved["seg_classes"] == list(NUSCENES_NAMES) == saved["bev_classes"]
    assert saved["counts"] == {"train": 3 * N_SAMPLES, "val": N_SAMPLES, "test": N_SAMPLES}
    assert not (out / "train" / "dvs.npy").exists()
    ss = np.load(out / "train" / "ss.npy")
    lidar, ls, bev = (np.load(out / "train" / f"{k}.npy") for k in ("lidar", "ls", "bevp"))
    assert ss.shape == (6, 4, S_EXPORT, S_EXPORT) and lidar.shape == (6, 15, S_EXPORT, S_EXPORT) and bev.shape[1] == 32
    assert lidar.dtype == np.float16 and set(np.unique(ls)) <= set(range(32)) | {255}
    # the car (10, 3) and the pedestrian (6, -5) in their BEV channels; road points splatted
    car_i, car_j = topview_index(10.0, 32.0, S_EXPORT), topview_index(3.0, 32.0, S_EXPORT)
    ped_i, ped_j = topview_index(6.0, 32.0, S_EXPORT), topview_index(-5.0, 32.0, S_EXPORT)
    assert bev[:, NUSCENES_INDEX["vehicle.car"], car_i, car_j].all()
    assert bev[:, NUSCENES_INDEX["human.pedestrian.adult"], ped_i, ped_j].all()
    assert bev[:, NUSCENES_INDEX["flat.driveable_surface"]].sum() > 0 and bev[:, NUSCENES_INDEX["vehicle.ego"], 16, 16].all()
    assert ls[:, car_i, car_j].tolist() == [NUSCENES_INDEX["vehicle.car"]] * 6


def test_ingest_workers_give_the_same_bytes(tmp_path, sim_root, params):
    """Parallel ingestion (forked workers) writes exactly what one process writes."""
    for workers in (1, 2):
        ingest_nuscenes(sim_root, params.datasets.nuscenes.version, tmp_path / f"w{workers}", resolution=S_EXPORT,
                        preprocess=params.preprocess, split_seed=0, workers=workers)
    assert _tree_hash(tmp_path / "w1") == _tree_hash(tmp_path / "w2")


# ----------------------------------------------------------------------------- split
def test_scene_split():
    names = [f"scene-{i:04d}" for i in range(1, 851)]
    a, b = split_scenes(names, 0), split_scenes(list(reversed(names)), 0)
    assert a == b
    assert [len(a[k]) for k in ("train", "val", "test")] == [510, 170, 170]
    assert set(a["train"]).isdisjoint(a["val"]) and set(a["train"]).isdisjoint(a["test"]) and set(a["val"]).isdisjoint(a["test"])
    assert set(a["train"]) | set(a["val"]) | set(a["test"]) == set(names)
    assert split_scenes(names, 1) != a
    assert split_sizes(5) == (3, 1, 1) and split_sizes(10) == (6, 2, 2)


# ----------------------------------------------------------------------------- projection
def test_projection_hand_placed_point():
    # ego at (100, 50) yaw 30 deg for both sensors; LiDAR at the ego origin, LIDAR_TOP axes
    pose = {"translation": [100.0, 50.0, 0.0], "rotation": yaw_quat(math.radians(30))}
    lidar_cs = {"translation": [0.0, 0.0, 0.0], "rotation": yaw_quat(-math.pi / 2)}
    cam_rot = np.stack([[0, -1, 0], [0, 0, -1], [1, 0, 0]], axis=1).astype(float)  # columns: right, down, fwd
    cam_cs = {"translation": [1.0, 0.0, 1.5], "rotation": matrix_to_quat(cam_rot)}
    np.testing.assert_allclose(quat_to_matrix(cam_cs["rotation"]), cam_rot, atol=1e-12)
    t = sensor_to_camera(lidar_cs, pose, pose, cam_cs)
    # ego point (11, -1, 2.0) = camera (x 1, y -0.5, z 10); in LIDAR_TOP axes (x right, y fwd): (1, 11, 2.0)
    k = np.array([[16.0, 0, 16.0], [0, 16.0, 16.0], [0, 0, 1]])
    pts = np.array([[1.0, 11.0, 2.0], [1.0, 21.0, 2.0], [0.0, 0.5, 0.0]])
    u, v, d, keep = project_points(pts, t, k, 32, 32)
    np.testing.assert_allclose([u[0], v[0], d[0]], [17.6, 15.2, 10.0], atol=1e-9)
    assert keep.tolist() == [True, True, False]  # the last point is behind the camera
    # a farther point on the same pixel loses; its neighbour fill does not override a direct hit
    ss, dm = rasterise_points(np.array([17.6, 17.3]), np.array([15.2, 15.9]), np.array([10.0, 20.0]),
                              np.array([17, 24]), 32, 32, fill_radius=1)
    assert ss[15, 17] == 17 and dm[15, 17] == pytest.approx(10.0)
    assert ss[14, 16] == 17 and ss[16, 18] == 17 and (ss != 255).sum() == 9


# ----------------------------------------------------------------------------- classes
def test_class_maps():
    assert CARLA_TO_NUSCENES.shape == (len(CARLA_NAMES),) and CARLA_TO_NUSCENES.max() < 32
    assert NUSCENES_NAMES[CARLA_TO_NUSCENES[TAG["road"]]] == "flat.driveable_surface"
    assert NUSCENES_NAMES[CARLA_TO_NUSCENES[TAG["vegetation"]]] == "static.vegetation"
    assert actor_category(TAG["vehicle"], 8.0, 2.5, 3.0) == "vehicle.truck"
    assert actor_category(TAG["vehicle"], 1.7, 0.6, 1.6) == "vehicle.bicycle"
    assert actor_category(TAG["pedestrian"], 0.6, 0.6, 1.8) == "human.pedestrian.adult"


# ----------------------------------------------------------------------------- bad input
def test_missing_dataroot(tmp_path, params):
    out = tmp_path / "cache"
    with pytest.raises(NuScenesInputError, match="dataroot not found: .*nowhere"):
        ingest_nuscenes(tmp_path / "nowhere", "v1.0-sim", out, resolution=16, preprocess=params.preprocess, split_seed=0)
    assert not out.exists()


def test_missing_lidarseg_folder(tmp_path, sim_root, params):
    root = tmp_path / "copy"
    shutil.copytree(sim_root, root)
    shutil.rmtree(root / "lidarseg" / "v1.0-sim")
    out = tmp_path / "cache"
    with pytest.raises(NuScenesInputError, match=r"lidarseg label folder missing: .*lidarseg/v1\.0-sim"):
        ingest_nuscenes(root, "v1.0-sim", out, resolution=16, preprocess=params.preprocess, split_seed=0)
    assert not out.exists() and not any(tmp_path.glob(".cache*"))


def test_missing_sweep(tmp_path, sim_root, params):
    root = tmp_path / "copy"
    shutil.copytree(sim_root, root)
    victim = sorted((root / "samples" / LIDAR_CHANNEL).iterdir())[-1]
    victim.unlink()
    out = tmp_path / "cache"
    with pytest.raises(NuScenesInputError, match=f"LiDAR sweep .*{victim.name}"):
        ingest_nuscenes(root, "v1.0-sim", out, resolution=16, preprocess=params.preprocess, split_seed=0)
    assert not out.exists() and not any(tmp_path.glob(".cache*"))


def test_load_nuscenes_names_missing_table(tmp_path, sim_root):
    root = tmp_path / "copy"
    shutil.copytree(sim_root, root)
    (root / "v1.0-sim" / "sample_data.json").unlink()
    with pytest.raises(NuScenesInputError, match="sample_data.json"):
        load_nuscenes(root, "v1.0-sim")


def test_sim_stage_with_real_dataroot_records_it(tmp_path, params_dict, root):
    """With a real dataroot the nuscenes_sim stage still writes its DVC output (a pointer)."""
    import subprocess
    import sys

    import yaml

    params_dict["datasets"]["nuscenes"]["dataroot"] = str(tmp_path / "nuscenes")
    (tmp_path / "nuscenes" / "v1.0-trainval").mkdir(parents=True)  # checked: a missing dataroot is an error
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(params_dict))
    out = tmp_path / "raw" / "nuscenes_sim"
    r = subprocess.run([sys.executable, "-m", "pipeline.nuscenes_sim", "--params", str(tmp_path / "params.yaml"),
                        "--out", str(out)], capture_output=True, text=True, timeout=120, cwd=root)
    assert r.returncode == 0, r.stderr
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest == {"source": "nuScenes-lidarseg", "dataroot": str(tmp_path / "nuscenes"),
                        "version": "v1.0-trainval"}
    assert [p.name for p in out.iterdir()] == ["manifest.json"]
