"""The simulated world -> a small dataset in nuScenes-lidarseg format (SPEC 3.2).

Where ``params.datasets.nuscenes.dataroot`` is null, the pipeline writes
``data/raw/nuscenes_sim/`` with this module and ingests it through the real devkit, so the
simulated rows of the report run the same code path as real nuScenes-lidarseg.

Layout written (``<dataroot>``)::

    <version>/{category,attribute,visibility,instance,sensor,calibrated_sensor,ego_pose,log,
               scene,sample,sample_data,sample_annotation,map,lidarseg}.json
    samples/CAM_FRONT|CAM_FRONT_LEFT|CAM_FRONT_RIGHT|CAM_BACK/<scene>__<channel>__<ts>.png
    samples/LIDAR_TOP/<scene>__LIDAR_TOP__<ts>.pcd.bin          float32 (N, 5)
    lidarseg/<version>/<lidar sample_data token>_lidarseg.bin    uint8 (N,)
    maps/<map token>.png                                         road prior, 0.1 m / px
    sim_export.json                                              provenance (not read by the devkit)

Scenes are world episodes (``compact_perception.data.world.generate.render_episode``): scene ``i``
drives town ``TOWNS[i % 5]`` with episode seed ``seed * 100003 + 50000 + i`` for
``sim_samples_per_scene`` frames; each frame is one keyframe sample (2 Hz timestamps).

Frames (how our conventions become nuScenes'):

- nuScenes ego frame = our ego/LiDAR frame (x forward, y left, z up) moved down to the ground:
  ``p_ego = p_ours + (0, 0, lidar.height_m)``. The ``ego_pose`` of a frame is the world pose
  (x, y, yaw) plus a per-town offset that makes every global coordinate positive (the devkit's
  map masks index pixels from the global origin).
- LIDAR_TOP follows the nuScenes convention x right, y forward, z up: its calibrated_sensor is
  translation (0, 0, h), rotation yaw -90 deg, so ``p_sensor = (-y, x, z)`` of ours. Sweep
  columns: x, y, z, intensity = 255 * cos(incident angle) (our 4th LiDAR value), ring = the
  laser index from the elevation angle.
- Cameras (CAM_FRONT = f, CAM_FRONT_LEFT = l, CAM_FRONT_RIGHT = ri, CAM_BACK = r; in the world
  the side cameras look at +-90 deg, not nuScenes' +-55 deg): calibrated_sensor from
  ``world.camera.ego_from_camera`` (OpenCV camera axes, as nuScenes) shifted by (0, 0, h);
  ``camera_intrinsic`` from ``world.camera.intrinsic_matrix``. Images are lossless PNG at the
  world resolution.
- lidarseg labels: CARLA tags -> 32 classes (:mod:`.classmap`), vehicle/pedestrian points
  refined by the actor box they lie in.
- Actor boxes -> ``sample_annotation`` (global centre, size as width, length, height, yaw
  quaternion, ``num_lidar_pts`` = actor-tagged points in the footprint), one ``instance`` per
  annotation (the world does not expose actor identities across frames), visibility "4", no
  attributes. Box z follows the raw-record contract (ego/LiDAR frame, so + h in nuScenes ego).
- One log and one calibrated_sensor set per scene; one map per town: a PNG of the road prior
  made from the frames' BEV road masks placed in global coordinates.

The whole dataroot is built in a temporary sibling and swapped in (``io.atomic_dir``); the same
params give identical files (tokens are MD5 hashes of names, JSON is written sorted).
"""
from __future__ import annotations

import hashlib
import io
import json
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Optional

import numpy as np
from PIL import Image
from tqdm import tqdm

from compact_perception.core.classes import NUSCENES_NAMES, TAG
from compact_perception.core.params import TOWNS, CameraParams, LidarParams, Params, WorldParams
from compact_perception.data.geometry import VIEWS, topview_cell_centres
from compact_perception.core.io import atomic_dir, write_bytes
from compact_perception.data.nuscenes import LIDAR_CHANNEL, VIEW_CHANNELS
from compact_perception.data.nuscenes.classmap import actor_category, map_carla_tags, refine_point_labels
from compact_perception.data.nuscenes.projection import matrix_to_quat, yaw_quat
from compact_perception.data.world.camera import ego_from_camera, intrinsic_matrix

log = logging.getLogger(__name__)

#: ``render_episode(world_params, town, episode_seed, n_frames, resolution) -> Iterator[dict]``
EpisodeSource = Callable[[WorldParams, str, int, int, int], Iterable[dict]]

TABLES: tuple[str, ...] = (
    "category", "attribute", "visibility", "instance", "sensor", "calibrated_sensor", "ego_pose",
    "log", "scene", "sample", "sample_data", "sample_annotation", "map",
)
MAP_RESOLUTION_M = 0.1  # the devkit's default map_resolution
_T0_US = 1_600_000_000_000_000
_SCENE_DT_US = 100_000_000
_SAMPLE_DT_US = 500_000
_MAP_MARGIN_M = 40.0


def token(*parts: Any) -> str:
    """Deterministic 32-hex token (nuScenes tokens are 32 hex characters)."""
    return hashlib.md5("/".join(str(p) for p in parts).encode()).hexdigest()


def episode_seed(seed: int, scene_index: int) -> int:
    """World episode seed of simulated nuScenes scene ``scene_index`` (distinct from sets A-C)."""
    return int(seed) * 100003 + 50000 + int(scene_index)


# ----------------------------------------------------------------------------- calibration
def camera_calibration(
    view: str, camera: CameraParams, lidar_height: float, resolution: int
) -> tuple[np.ndarray, np.ndarray]:
    """(3x3 intrinsics, 4x4 ego/LiDAR-frame-from-camera) of one world camera, from the world's
    own camera model (``compact_perception.data.world.camera``), so the export and the renderer agree."""
    return (np.asarray(intrinsic_matrix(resolution, camera.fov_deg), dtype=np.float64),
            np.asarray(ego_from_camera(view, camera, lidar_height), dtype=np.float64))


#: LIDAR_TOP rotation (sensor -> ego): yaw -90 deg, so sensor x = right, y = forward.
LIDAR_ROTATION: list[float] = yaw_quat(-math.pi / 2)


def ours_to_lidar_top(points: np.ndarray) -> np.ndarray:
    """Our ego/LiDAR frame (x fwd, y left) -> nuScenes LIDAR_TOP axes (x right, y fwd)."""
    out = np.empty_like(points[:, :3])
    out[:, 0] = -points[:, 1]
    out[:, 1] = points[:, 0]
    out[:, 2] = points[:, 2]
    return out


def sweep_array(lidar: np.ndarray, lidar_params: LidarParams) -> np.ndarray:
    """World LiDAR (M, 4: x, y, z, cos) -> nuScenes sweep (M, 5: x, y, z, intensity, ring) float32."""
    lidar = np.asarray(lidar, dtype=np.float64)
    out = np.zeros((len(lidar), 5), dtype=np.float32)
    out[:, :3] = ours_to_lidar_top(lidar)
    out[:, 3] = np.clip(lidar[:, 3], 0.0, 1.0) * 255.0
    elev = np.degrees(np.arctan2(lidar[:, 2], np.hypot(lidar[:, 0], lidar[:, 1])))
    span = lidar_params.upper_fov_deg - lidar_params.lower_fov_deg
    ring = np.rint((elev - lidar_params.lower_fov_deg) / span * (lidar_params.channels - 1))
    out[:, 4] = np.clip(ring, 0, lidar_params.channels - 1)
    return out


def _points_in_boxes(points: np.ndarray, tags: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """``num_lidar_pts``: actor-tagged points (vehicle/pedestrian) inside each box's x-y footprint."""
    counts = np.zeros(len(boxes), dtype=np.int64)
    movable = (tags == TAG["vehicle"]) | (tags == TAG["pedestrian"])
    p = points[movable, :3].astype(np.float64)
    for k, b in enumerate(boxes):
        x, y, z, length, width, height, yaw = (float(v) for v in b[:7])
        c, s = math.cos(yaw), math.sin(yaw)
        dx, dy = p[:, 0] - x, p[:, 1] - y
        inside = (np.abs(c * dx + s * dy) <= length / 2 + 0.05) & (np.abs(-s * dx + c * dy) <= width / 2 + 0.05)
        counts[k] = int(inside.sum())
    return counts


# ----------------------------------------------------------------------------- writer
@dataclass
class _FrameInfo:
    scene: int
    step: int
    town: str
    pose: np.ndarray                      # world x, y, yaw
    boxes: np.ndarray                     # (K, 8) ego/LiDAR frame
    box_points: np.ndarray                # (K,) lidar points inside
    lidar_sd: str
    cam_sd: dict[str, str] = field(default_factory=dict)


class _Writer:
    """Accumulates tables while frames stream in; writes files immediately."""

    def __init__(self, root: Path, version: str, resolution: int, world: WorldParams, image_ext: str):
        self.root, self.version, self.S, self.world, self.ext = root, version, resolution, world, image_ext
        self.h = world.lidar.height_m
        self.frames: list[_FrameInfo] = []
        self.scene_names: list[str] = []
        self.scene_towns: list[str] = []
        self.road_cells: dict[str, set[int]] = {}
        self.sensor_tokens = {ch: token("sensor", ch) for ch in list(VIEW_CHANNELS.values()) + [LIDAR_CHANNEL]}
        self.lidarseg: list[dict] = []
        self.sample_data: list[dict] = []
        self.calibrated_sensor: list[dict] = []
        (root / self.version).mkdir(parents=True)
        (root / "lidarseg" / self.version).mkdir(parents=True)
        for ch in self.sensor_tokens:
            (root / "samples" / ch).mkdir(parents=True)
        (root / "maps").mkdir()
        self.cams = {v: camera_calibration(v, world.camera, self.h, resolution) for v in VIEWS}

    # -- per scene -------------------------------------------------------------------------
    def begin_scene(self, index: int, town: str) -> str:
        name = f"scene-{index + 1:04d}"
        self.scene_names.append(name)
        self.scene_towns.append(town)
        for v, (k, ego_from_cam) in self.cams.items():
            ch = VIEW_CHANNELS[v]
            self.calibrated_sensor.append({
                "token": token("cs", name, ch), "sensor_token": self.sensor_tokens[ch],
                "translation": [float(a) for a in ego_from_cam[:3, 3] + np.array([0.0, 0.0, self.h])],
                "rotation": matrix_to_quat(ego_from_cam[:3, :3]),
                "camera_intrinsic": [[float(a) for a in row] for row in k],
            })
        self.calibrated_sensor.append({
            "token": token("cs", name, LIDAR_CHANNEL), "sensor_token": self.sensor_tokens[LIDAR_CHANNEL],
            "translation": [0.0, 0.0, float(self.h)], "rotation": LIDAR_ROTATION, "camera_intrinsic": [],
        })
        return name

    # -- per frame -------------------------------------------------------------------------
    def add_frame(self, scene: int, step: int, rec: dict) -> None:
        name, town = self.scene_names[scene], self.scene_towns[scene]
        ts = _T0_US + scene * _SCENE_DT_US + step * _SAMPLE_DT_US
        sample_tok = token("sample", name, step)
        lidar = np.asarray(rec["lidar"], dtype=np.float32)
        tags = np.asarray(rec["lidar_tag"], dtype=np.uint8)
        boxes = np.asarray(rec.get("boxes", np.zeros((0, 8))), dtype=np.float32).reshape(-1, 8)
        info = _FrameInfo(scene, step, town, np.asarray(rec["ego_pose"], dtype=np.float64), boxes,
                          _points_in_boxes(lidar, tags, boxes), lidar_sd=token("sd", name, step, LIDAR_CHANNEL))
        # LiDAR sweep + lidarseg labels
        fname = f"samples/{LIDAR_CHANNEL}/{name}__{LIDAR_CHANNEL}__{ts}.pcd.bin"
        write_bytes(self.root / fname, sweep_array(lidar, self.world.lidar).tobytes())
        labels = refine_point_labels(lidar, map_carla_tags(tags), tags, boxes).astype(np.uint8)
        seg_name = f"lidarseg/{self.version}/{info.lidar_sd}_lidarseg.bin"
        write_bytes(self.root / seg_name, labels.tobytes())
        self.lidarseg.append({"token": info.lidar_sd, "sample_data_token": info.lidar_sd, "filename": seg_name})
        self._sample_data(info.lidar_sd, sample_tok, name, LIDAR_CHANNEL, step, ts, fname, "pcd", 0, 0)
        # cameras
        for v in VIEWS:
            ch = VIEW_CHANNELS[v]
            sd = token("sd", name, step, ch)
            info.cam_sd[ch] = sd
            rgb = np.asarray(rec[f"rgb_{v}"], dtype=np.uint8)
            fname = f"samples/{ch}/{name}__{ch}__{ts}.{self.ext}"
            img = Image.fromarray(rgb)
            buf = io.BytesIO()
            img.save(buf, format="PNG" if self.ext == "png" else "JPEG", **({"optimize": False} if self.ext == "png" else {"quality": 95}))
            write_bytes(self.root / fname, buf.getvalue())
            self._sample_data(sd, sample_tok, name, ch, step, ts, fname, self.ext, rgb.shape[1], rgb.shape[0])
        # road prior for the town map (BEV channel 0 = road)
        if "bev" in rec:
            self._add_road(town, np.asarray(rec["bev"])[0], info.pose)
        self.frames.append(info)

    def _sample_data(self, sd: str, sample_tok: str, scene: str, ch: str, step: int, ts: int,
                     fname: str, fmt: str, width: int, height: int) -> None:
        self.sample_data.append({
            "token": sd, "sample_token": sample_tok, "ego_pose_token": token("pose", sd),
            "calibrated_sensor_token": token("cs", scene, ch), "timestamp": ts, "fileformat": fmt,
            "is_key_frame": True, "height": int(height), "width": int(width), "filename": fname,
            "prev": token("sd", scene, step - 1, ch) if step > 0 else "", "next": "",  # next fixed at the end
            "_channel": ch, "_scene": scene, "_step": step,
        })

    def _add_road(self, town: str, road: np.ndarray, pose: np.ndarray) -> None:
        ii, jj = np.nonzero(road)
        if len(ii) == 0:
            return
        c = topview_cell_centres(self.world.lidar.range_m, road.shape[0])
        x, y = c[ii], c[jj]
        cy, sy = math.cos(pose[2]), math.sin(pose[2])
        gx, gy = pose[0] + cy * x - sy * y, pose[1] + sy * x + cy * y
        cell = 0.5  # metres per stored road cell (coarser than the map pixels)
        keys = (np.floor(gx / cell).astype(np.int64) << 32) + (np.floor(gy / cell).astype(np.int64) & 0xFFFFFFFF)
        self.road_cells.setdefault(town, set()).update(keys.tolist())

    # -- end -------------------------------------------------------------------------------
    def finish(self) -> dict[str, int]:
        towns = sorted(set(self.scene_towns))
        offsets: dict[str, np.ndarray] = {}
        extents: dict[str, np.ndarray] = {}
        for t in towns:
            poses = np.array([f.pose[:2] for f in self.frames if f.town == t]).reshape(-1, 2)
            lo = poses.min(axis=0) if len(poses) else np.zeros(2)
            hi = poses.max(axis=0) if len(poses) else np.zeros(2)
            pad = _MAP_MARGIN_M + 2 * self.world.lidar.range_m
            offsets[t] = pad - np.floor(lo)
            extents[t] = hi + offsets[t] + pad  # largest global x, y the map must cover
        tables: dict[str, list[dict]] = {n: [] for n in TABLES}
        tables["category"] = [{"token": token("category", n), "name": n, "description": f"nuScenes-lidarseg class {n}",
                               "index": i} for i, n in enumerate(NUSCENES_NAMES)]
        tables["visibility"] = [{"token": str(i + 1), "level": lvl, "description": f"visibility of whole object is {lvl}"}
                                for i, lvl in enumerate(("v0-40", "v40-60", "v60-80", "v80-100"))]
        tables["sensor"] = [{"token": tok, "channel": ch, "modality": "lidar" if ch == LIDAR_CHANNEL else "camera"}
                            for ch, tok in sorted(self.sensor_tokens.items())]
        tables["calibrated_sensor"] = self.calibrated_sensor
        # logs, maps
        for i, (name, town) in enumerate(zip(self.scene_names, self.scene_towns)):
            tables["log"].append({"token": token("log", name), "logfile": f"sim-{town}-{name}", "vehicle": "sim-ego",
                                  "date_captured": "2020-09-13", "location": f"sim-{town}"})
        for t in towns:
            map_tok = token("map", t)
            fname = f"maps/{map_tok}.png"
            self._write_map(fname, t, offsets[t], extents[t])
            tables["map"].append({"token": map_tok, "category": "semantic_prior", "filename": fname,
                                  "log_tokens": [token("log", n) for n, tt in zip(self.scene_names, self.scene_towns) if tt == t]})
        # samples, scenes, poses, annotations
        by_scene: dict[int, list[_FrameInfo]] = {}
        for f in self.frames:
            by_scene.setdefault(f.scene, []).append(f)
        pose_of_sd: dict[str, tuple[list[float], list[float], int]] = {}
        for s, frames in sorted(by_scene.items()):
            name = self.scene_names[s]
            toks = [token("sample", name, f.step) for f in frames]
            for k, f in enumerate(frames):
                ts = _T0_US + s * _SCENE_DT_US + f.step * _SAMPLE_DT_US
                tables["sample"].append({"token": toks[k], "timestamp": ts, "scene_token": token("scene", name),
                                         "prev": toks[k - 1] if k > 0 else "", "next": toks[k + 1] if k + 1 < len(frames) else ""})
                off = offsets[f.town]
                trans = [float(f.pose[0] + off[0]), float(f.pose[1] + off[1]), 0.0]
                rot = yaw_quat(float(f.pose[2]))
                for sd in [f.lidar_sd] + list(f.cam_sd.values()):
                    pose_of_sd[sd] = (trans, rot, ts)
                self._annotations(tables, toks[k], f, trans)
            tables["scene"].append({"token": token("scene", name), "name": name, "log_token": token("log", name),
                                    "description": f"simulated {self.scene_towns[s]} episode", "nbr_samples": len(frames),
                                    "first_sample_token": toks[0], "last_sample_token": toks[-1]})
        # sample_data next links, ego poses
        index = {(d["_scene"], d["_channel"], d["_step"]): d for d in self.sample_data}
        for d in self.sample_data:
            nxt = index.get((d["_scene"], d["_channel"], d["_step"] + 1))
            d["next"] = nxt["token"] if nxt else ""
        for d in self.sample_data:
            trans, rot, ts = pose_of_sd[d["token"]]
            tables["ego_pose"].append({"token": d["ego_pose_token"], "translation": trans, "rotation": rot, "timestamp": ts})
        tables["sample_data"] = [{k: v for k, v in d.items() if not k.startswith("_")} for d in self.sample_data]
        for name in TABLES:
            _write_table(self.root / self.version / f"{name}.json", tables[name])
        _write_table(self.root / self.version / "lidarseg.json", self.lidarseg)
        return {n: len(tables[n]) for n in TABLES}

    def _annotations(self, tables: dict[str, list[dict]], sample_tok: str, f: _FrameInfo, trans: list[float]) -> None:
        cy, sy = math.cos(f.pose[2]), math.sin(f.pose[2])
        for k, b in enumerate(f.boxes):
            x, y, z, length, width, height, yaw, tag = (float(v) for v in b[:8])
            cat = actor_category(int(tag), length, width, height)
            ann = token("ann", sample_tok, k)
            inst = token("instance", sample_tok, k)
            tables["instance"].append({"token": inst, "category_token": token("category", cat), "nbr_annotations": 1,
                                       "first_annotation_token": ann, "last_annotation_token": ann})
            gx, gy = trans[0] + cy * x - sy * y, trans[1] + sy * x + cy * y
            tables["sample_annotation"].append({
                "token": ann, "sample_token": sample_tok, "instance_token": inst, "visibility_token": "4",
                "attribute_tokens": [], "translation": [gx, gy, z + self.h], "size": [width, length, height],
                "rotation": yaw_quat(float(f.pose[2]) + yaw), "prev": "", "next": "",
                "num_lidar_pts": int(f.box_points[k]), "num_radar_pts": 0,
            })

    def _write_map(self, fname: str, town: str, offset: np.ndarray, extent: np.ndarray) -> None:
        w = int(math.ceil(extent[0] / MAP_RESOLUTION_M))
        h = int(math.ceil(extent[1] / MAP_RESOLUTION_M))
        mask = np.zeros((h, w), dtype=np.uint8)
        keys = np.fromiter(self.road_cells.get(town, set()), dtype=np.int64)
        if len(keys):
            keys.sort()
            cx = keys >> 32
            cyy = (keys & 0xFFFFFFFF).astype(np.int64)
            cyy = np.where(cyy >= 2 ** 31, cyy - 2 ** 32, cyy)
            rep = int(round(0.5 / MAP_RESOLUTION_M))
            gx0 = cx * 0.5 + offset[0]
            gy0 = cyy * 0.5 + offset[1]
            c0 = np.floor(gx0 / MAP_RESOLUTION_M).astype(np.int64)
            r0 = h - 1 - np.floor(gy0 / MAP_RESOLUTION_M).astype(np.int64)
            for dr in range(rep):
                for dc in range(rep):
                    rr, cc = r0 - dr, c0 + dc
                    ok = (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)
                    mask[rr[ok], cc[ok]] = 255
        buf = io.BytesIO()
        Image.fromarray(mask).save(buf, format="PNG")
        write_bytes(self.root / fname, buf.getvalue())


def _write_table(path: Path, rows: list[dict]) -> None:
    write_bytes(path, (json.dumps(rows, indent=0, sort_keys=True) + "\n").encode())


# ----------------------------------------------------------------------------- entry point
def _default_episode_source() -> EpisodeSource:
    try:
        from compact_perception.data.world.generate import render_episode  # type: ignore
    except ImportError as err:  # pragma: no cover - depends on the world package being present
        raise RuntimeError("compact_perception.data.world.generate.render_episode is not available; "
                           "pass episode_source= to export_nuscenes_sim") from err
    return render_episode


def scene_plan(params: Params, n_scenes: Optional[int] = None) -> list[tuple[int, str, int]]:
    """(scene index, town, episode seed) of every simulated scene."""
    n = params.nuscenes_sim_scenes if n_scenes is None else int(n_scenes)
    return [(i, TOWNS[i % len(TOWNS)], episode_seed(params.seed, i)) for i in range(n)]


def export_nuscenes_sim(
    params: Params,
    out_dir: str | Path,
    *,
    episode_source: Optional[EpisodeSource] = None,
    n_scenes: Optional[int] = None,
    image_ext: str = "png",
) -> dict[str, int]:
    """Write the simulated nuScenes-format dataroot ``out_dir`` atomically; return table sizes.

    ``episode_source`` defaults to the world's ``render_episode``; ``n_scenes`` defaults to
    ``datasets.nuscenes.sim_scenes`` at ``params.scale``.
    """
    ns = params.datasets.nuscenes
    source = episode_source or _default_episode_source()
    resolution = params.resolution
    plan = scene_plan(params, n_scenes)
    out_dir = Path(out_dir)
    log.info("exporting %d simulated nuScenes scenes x %d samples to %s", len(plan), ns.sim_samples_per_scene, out_dir)
    with atomic_dir(out_dir) as tmp:
        writer = _Writer(tmp, ns.version, resolution, params.world, image_ext)
        bar = tqdm(total=len(plan) * ns.sim_samples_per_scene, desc="nuscenes_sim", unit="sample", leave=False)
        for i, town, seed in plan:
            writer.begin_scene(i, town)
            n = 0
            for step, rec in enumerate(source(params.world, town, seed, ns.sim_samples_per_scene, resolution)):
                writer.add_frame(i, step, rec)
                n += 1
                bar.update(1)
            if n < 1:
                raise RuntimeError(f"episode {seed} ({town}) produced no frames")
        bar.close()
        sizes = writer.finish()
        info = {"source": "simulated nuScenes-format", "version": ns.version, "scenes": len(plan),
                "samples_per_scene": ns.sim_samples_per_scene, "resolution": resolution, "seed": params.seed,
                "views": {v: VIEW_CHANNELS[v] for v in VIEWS}}
        write_bytes(tmp / "sim_export.json", (json.dumps(info, indent=2, sort_keys=True) + "\n").encode())
    log.info("wrote %s: %s", out_dir, sizes)
    return sizes
