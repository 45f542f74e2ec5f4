"""Tests of the embedded procedural world (SPEC 3.1; ARCHITECTURE.md raw layout)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from compact_perception.core.classes import CARLA_NAMES, CARLA_PALETTE, palette_to_index
from compact_perception.core.params import ParamsError, parse_params
from compact_perception.data.geometry import VIEWS, topview_center
from compact_perception.data.world import camera as cam
from compact_perception.data.world import generate as gen
from compact_perception.data.world.events import dvs_events
from compact_perception.data.world.generate import generate_dataset, render_episode


def _params(d: dict, res: int = 32, samples: int = 256, **world):
    d["world"]["resolution"] = {"default": res, "full": res, "paper": 128}
    d["world"]["lidar"]["horizontal_samples"] = samples
    d["world"].update(world)
    return parse_params(d)


def _frames(p, town="town01", seed=3, n=2, res=None):
    return list(render_episode(p.world, town, seed, n, res or p.world.resolution.at(p.scale)))


def test_record_keys_and_dtypes(params_dict):
    p = _params(params_dict)
    rec = _frames(p, n=1)[0]
    S = 32
    for v in VIEWS:
        assert rec[f"rgb_{v}"].dtype == np.uint8 and rec[f"rgb_{v}"].shape == (S, S, 3)
        assert rec[f"sem_{v}"].shape == (S, S, 3)
        assert rec[f"depth_{v}"].dtype == np.uint16 and rec[f"depth_{v}"].shape == (S, S)
        assert rec[f"dvs_{v}"].dtype == np.int64 and rec[f"dvs_{v}"].shape[1] == 4
        palette_to_index(rec[f"sem_{v}"], CARLA_PALETTE)  # every colour in the palette
    assert rec["lidar"].dtype == np.float32 and rec["lidar"].shape[1] == 4
    assert rec["lidar_tag"].shape == (len(rec["lidar"]),)
    assert rec["bev"].shape == (9, S, S) and rec["bev"].dtype == np.uint8
    assert rec["boxes"].shape[1] == 8 and rec["ego_pose"].shape == (3,)
    assert set(rec["meta"]) == {"town", "episode", "step", "time_of_day", "weather"}
    r = np.linalg.norm(rec["lidar"][:, :3], axis=1)
    assert r.max() <= 32.0 + 1e-3
    assert np.all((rec["lidar"][:, 3] >= 0) & (rec["lidar"][:, 3] <= 1.0001))


def test_lidar_matches_depth_and_semantics(params_dict):
    """A LiDAR point's planar depth equals the depth image at its pixel; its tag equals the semantic pixel."""
    p = _params(params_dict, res=64, samples=512)
    ok_depth, ok_tag, n = 0, 0, 0
    for rec in _frames(p, town="town02", seed=11, n=2):
        pts, tags = rec["lidar"][:, :3].astype(np.float64), rec["lidar_tag"]
        S = 64
        K = cam.intrinsic_matrix(S, p.world.camera.fov_deg)
        for v in VIEWS:
            T = np.linalg.inv(cam.ego_from_camera(v, p.world.camera, p.world.lidar.height_m))
            pc = pts @ T[:3, :3].T + T[:3, 3]
            front = pc[:, 2] > 3.4
            uv = pc[front] @ K.T
            u, w = uv[:, 0] / uv[:, 2], uv[:, 1] / uv[:, 2]
            # only points projecting near a pixel centre (the depth image samples pixel centres)
            near = (np.abs(u - np.floor(u) - 0.5) < 0.2) & (np.abs(w - np.floor(w) - 0.5) < 0.2)
            inside = (u >= 0) & (u < S) & (w >= 0) & (w < S) & near
            ui, vi = np.floor(u[inside]).astype(int), np.floor(w[inside]).astype(int)
            z = pc[front][inside, 2]
            d = cam.decode_depth(rec[f"depth_{v}"][vi, ui])
            sem = palette_to_index(rec[f"sem_{v}"], CARLA_PALETTE)[vi, ui]
            ok_depth += int(np.sum(np.abs(d - z) / z < 0.05))
            ok_tag += int(np.sum(sem == tags[front][inside]))
            n += len(z)
    assert n > 200
    assert ok_depth / n >= 0.9, ok_depth / n
    assert ok_tag / n >= 0.95, ok_tag / n


def test_depth_encoding_roundtrip():
    d = np.array([3.5, 10.0, 100.0, 999.0])
    back = cam.decode_depth(cam.encode_depth(d))
    assert np.allclose(back, d, rtol=1e-3)
    assert cam.encode_depth(np.array([1.0]))[0] == 0 and cam.encode_depth(np.array([2000.0]))[0] == 65535


def test_ego_at_bev_centre_and_boxes(params_dict):
    p = _params(params_dict)
    rec = _frames(p, n=1)[0]
    c = topview_center(32)
    assert rec["bev"][4, c, c] == 1
    assert rec["bev"][0].sum() > 0  # road around the ego
    assert rec["bev"][4].sum() < 0.05 * 32 * 32


def test_identical_images_give_no_events():
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (32, 32, 3), dtype=np.uint8)
    assert dvs_events(img, img, 0.3, 0, 100000).shape == (0, 4)
    brighter = np.clip(img.astype(int) * 2 + 5, 0, 255).astype(np.uint8)
    ev = dvs_events(img, brighter, 0.3, 0, 100000)
    assert len(ev) > 0 and np.all(ev[:, 3] == 1) and np.all(np.diff(ev[:, 0]) >= 0)


def test_static_scene_gives_no_events(params_dict, monkeypatch):
    """A step that repeats the previous one (ego and actors frozen, no rain) gives zero events."""
    from compact_perception.data.world import actors

    monkeypatch.setattr(actors, "EGO_STEP_M", 0.0)
    monkeypatch.setattr(actors.Episode, "state", lambda self, step, _o=actors.Episode.state: _o(self, 0))
    d = params_dict
    d["world"]["conditions"] = {"times": ["noon"], "weathers": ["sunny"], "combine_probability": 0.0}
    p = _params(d)
    rec = _frames(p, n=1)[0]
    for v in VIEWS:
        assert len(rec[f"dvs_{v}"]) == 0


def test_moving_ego_gives_events(params_dict):
    p = _params(params_dict, res=64)
    rec = _frames(p, n=2)[1]
    assert sum(len(rec[f"dvs_{v}"]) for v in VIEWS) > 50


def _cond_params(d: dict, time: str, weather: str):
    d["world"]["conditions"] = {"times": [time], "weathers": [weather], "combine_probability": 0.0}
    return _params(d, res=64, samples=512)


def test_night_and_rain_hurt_rgb_not_lidar(params_dict):
    import copy

    base = _frames(_cond_params(copy.deepcopy(params_dict), "noon", "sunny"), seed=5, n=1)[0]
    night = _frames(_cond_params(copy.deepcopy(params_dict), "night", "sunny"), seed=5, n=1)[0]
    rain = _frames(_cond_params(copy.deepcopy(params_dict), "noon", "rainy"), seed=5, n=1)[0]
    fog = _frames(_cond_params(copy.deepcopy(params_dict), "noon", "foggy"), seed=5, n=1)[0]

    def bright(r):
        return np.mean([r[f"rgb_{v}"].astype(float).mean() for v in VIEWS])

    def rough(r):  # high-frequency energy (rain noise/streaks)
        return np.mean([np.abs(np.diff(r[f"rgb_{v}"].astype(float), axis=0)).mean() for v in VIEWS])

    assert bright(night) < 0.5 * bright(base)
    assert bright(rain) < 0.9 * bright(base)
    assert rough(rain) > 1.2 * rough(base)
    # fog washes out contrast
    assert np.std(fog["rgb_f"].astype(float)) < np.std(base["rgb_f"].astype(float))
    n0 = len(base["lidar"])
    for r in (night, rain, fog):
        assert abs(len(r["lidar"]) - n0) / n0 < 0.05
    np.testing.assert_array_equal(base["sem_f"], night["sem_f"])  # geometry unchanged
    # rain makes spurious DVS events even without motion differences
    ev_rain = sum(len(rain[f"dvs_{v}"]) for v in VIEWS)
    ev_base = sum(len(base[f"dvs_{v}"]) for v in VIEWS)
    assert ev_rain > ev_base


def test_towns_differ(params_dict):
    from compact_perception.data.world.town import build_town

    towns = [build_town(f"town0{k}") for k in range(1, 6)]
    sizes = {t.size_m for t in towns}
    widths = {t.road_w for t in towns}
    assert len(sizes) >= 4 and len(widths) >= 2
    hist = [np.bincount(t.tag, minlength=23) / len(t.tag) for t in towns]
    for a in range(5):
        for b in range(a + 1, 5):
            assert np.abs(hist[a] - hist[b]).sum() > 0.05
    p = _params(params_dict)
    r1, r2 = _frames(p, "town01", n=1)[0], _frames(p, "town04", n=1)[0]
    assert not np.array_equal(r1["sem_f"], r2["sem_f"])


@pytest.mark.slow
def test_all_classes_appear_over_towns(params_dict):
    p = _params(params_dict, res=32, samples=256)
    seen = np.zeros(23, bool)
    for k in range(1, 6):
        for ep in range(3):
            for i, rec in enumerate(render_episode(p.world, f"town0{k}", 100 * k + ep, 21, 32)):
                if i % 5:
                    continue
                seen[np.bincount(rec["lidar_tag"], minlength=23) > 0] = True
                for v in VIEWS:
                    seen[np.unique(palette_to_index(rec[f"sem_{v}"], CARLA_PALETTE))] = True
    missing = [CARLA_NAMES[i] for i in range(1, 23) if not seen[i]]
    assert not missing, missing


def _tiny(d: dict, workers: int = 1):
    d["datasets"]["A"]["frames"] = {"default": 10, "full": 10, "paper": 2000}
    d["datasets"]["A"]["split_ratio"]["default"] = {"train": 3, "val": 1, "test": 1}
    d["world"]["frames_per_episode"] = 2
    return _params(d, res=32, samples=128, workers=workers)


def test_generate_dataset_layout_and_determinism(params_dict, tmp_path: Path):
    import copy

    p1 = _tiny(copy.deepcopy(params_dict), workers=1)
    p2 = _tiny(copy.deepcopy(params_dict), workers=2)
    a = generate_dataset(p1, "A", tmp_path / "a" / "A")
    b = generate_dataset(p2, "A", tmp_path / "b" / "A")
    man = json.loads((a / "manifest.json").read_text())
    assert {len(man["splits"][s]) for s in ("train",)} == {6} and len(man["splits"]["val"]) == 2 and len(man["splits"]["test"]) == 2
    towns = {s: {man["frames"][f]["town"] for f in man["splits"][s]} for s in man["splits"]}
    assert towns == {"train": {"town01"}, "val": {"town02"}, "test": {"town02"}}
    eps = {s: {man["frames"][f]["episode"] for f in man["splits"][s]} for s in man["splits"]}
    assert not (eps["train"] & eps["val"]) and not (eps["val"] & eps["test"])
    assert (a / "stats" / "class_frequency_town01.csv").is_file()
    files_a = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    files_b = sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    assert files_a == files_b and len(files_a) == 10 + 2 + 1
    for f in files_a:
        if f.name == "manifest.json":
            ma, mb = json.loads((a / f).read_text()), json.loads((b / f).read_text())
            ma["params"]["world"].pop("workers"), mb["params"]["world"].pop("workers")
            assert ma == mb
        else:
            assert (a / f).read_bytes() == (b / f).read_bytes(), f


def test_interrupted_generation_leaves_nothing(params_dict, tmp_path: Path, monkeypatch):
    p = _tiny(params_dict)
    calls = {"n": 0}
    orig = gen._episode_job

    def boom(job):
        calls["n"] += 1
        if calls["n"] == 3:
            raise KeyboardInterrupt
        return orig(job)

    monkeypatch.setattr(gen, "_episode_job", boom)
    with pytest.raises(KeyboardInterrupt):
        generate_dataset(p, "A", tmp_path / "A")
    assert not (tmp_path / "A").exists()
    assert not list(tmp_path.rglob("manifest.json"))


@pytest.mark.parametrize(
    "edit, key",
    [
        (lambda d: d["datasets"]["A"].__setitem__("frames", {"default": -5, "full": 10, "paper": 2000}), "datasets.A.frames"),
        (lambda d: d["datasets"]["B"].__setitem__("train_towns", ["town09"]), "datasets.B.train_towns"),
        (lambda d: d["world"]["camera"].__setitem__("fov_deg", 200), "world.camera.fov_deg"),
        (lambda d: d["world"]["lidar"].__setitem__("lower_fov_deg", 30), "world.lidar"),
    ],
)
def test_bad_params_name_the_key(params_dict, edit, key):
    edit(params_dict)
    with pytest.raises(ParamsError, match=key.replace(".", r"\.")):
        parse_params(params_dict)


def test_inconsistent_frames_per_episode_fails_before_work(params_dict, tmp_path: Path):
    params_dict["world"]["frames_per_episode"] = 60  # > set A's 50 validation frames (500 at 6:1:3)
    p = parse_params(params_dict)
    with pytest.raises(ParamsError, match=r"world\.frames_per_episode"):
        generate_dataset(p, "A", tmp_path / "A")
    assert not (tmp_path / "A").exists() and not (tmp_path / ".A.partial").exists()


def test_intrinsics_extrinsics():
    K = cam.intrinsic_matrix(128, 90.0)
    assert np.isclose(K[0, 0], 64.0) and K[0, 2] == 64.0
    from repo_params import section

    T = cam.ego_from_camera("l", section("world.camera"), 2.0)
    assert np.allclose(T[:3, 3], [0.0, 1.0, -0.3])
    # optical axis of the left camera points left (+y) and 20 deg up
    assert np.allclose(T[:3, 2], [0.0, np.cos(np.deg2rad(20)), np.sin(np.deg2rad(20))], atol=1e-9)
    assert np.isclose(np.linalg.det(T[:3, :3]), 1.0)


def test_plan_c_splits_by_episode(params_dict):
    params_dict["datasets"]["C"]["frames"]["default"] = 200
    params_dict["world"]["frames_per_episode"] = 20
    p = parse_params(params_dict)
    plan = gen.plan_episodes(p, "C")
    n = {s: sum(e["frames"] for e in plan if e["split"] == s) for s in ("train", "val", "test")}
    assert n == {"train": 60, "val": 40, "test": 100}   # split_ratio 3:2:5 (the default scale's)
    params_dict["datasets"]["C"]["split_ratio"]["default"] = {"train": 3, "val": 1, "test": 1}
    plan = gen.plan_episodes(parse_params(params_dict), "C")
    n = {s: sum(e["frames"] for e in plan if e["split"] == s) for s in ("train", "val", "test")}
    assert n == {"train": 120, "val": 40, "test": 40}   # the paper's 3:1:1
    assert len({e["index"] for e in plan}) == len(plan) and len({e["seed"] for e in plan}) == len(plan)
    assert {e["town"] for e in plan if e["split"] == "train"} == {f"town0{k}" for k in range(1, 6)}


def test_the_world_refuses_a_dataset_of_another_source(tmp_path):
    """generate_dataset writes only 'sim' sets; another source's set is that source's, one line naming the key."""
    from repo_params import carla_source, repo_params_dict

    from compact_perception.core.params import ParamsError, parse_params
    from compact_perception.data.world.generate import generate_dataset

    data = repo_params_dict()
    data["datasets"]["B"]["source"] = carla_source()
    with pytest.raises(ParamsError, match=r"^datasets\.B\.source\.id is 'carla': the embedded world writes only 'sim'"):
        generate_dataset(parse_params(data), "B", tmp_path / "B")
    assert not (tmp_path / "B").exists()
