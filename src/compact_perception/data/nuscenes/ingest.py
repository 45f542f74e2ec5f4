"""Any nuScenes-lidarseg dataroot -> preprocessed frame dicts and the cache (paper IV-B).

Read with the real devkit (``nuscenes.nuscenes.NuScenes``); one frame per keyframe sample.

Inputs per sample
    CAM_FRONT, CAM_FRONT_LEFT, CAM_FRONT_RIGHT, CAM_BACK as views f, l, ri, r (stored in
    ``geometry.VIEWS`` order f, l, ri, r); LIDAR_TOP sweep (float32 N x 5) and its lidarseg labels
    (``lidarseg/<version>/<token>_lidarseg.bin``, uint8 per point). No DVS (no ``dvs`` key).

Frames
    nuScenes LIDAR_TOP axes are x right, y forward, z up (its calibrated_sensor rotation is a
    yaw of about -90 deg to the ego frame, whose axes are x forward, y left, z up). Our top-view
    frame (ARCHITECTURE.md) is the ego axes with the origin at the LiDAR, so points are only
    rotated by the LiDAR's calibrated rotation: ``p_ours = R_cs p_sensor`` (= ego minus the LiDAR
    translation; real mounting tilts are removed too). Ground is then at about z = -1.84 m on
    the real car (-lidar.height_m on the simulated set). The 4th LiDAR value that eq. (2)-(5)
    read (cos of the incident angle in CARLA) is ``clip(intensity / 255, 0, 1)``; the simulated
    export stores intensity = 255 cos, so it round-trips.

Inputs / ground truth (S = ``world.resolution`` at the scale, 128 at paper scale)
    - ``rgb`` (V,3,S,S) uint8: the camera images resized to S x S (cv2 INTER_AREA); intrinsics
      scaled by (S/W, S/H) accordingly (:func:`projection.scale_intrinsics`).
    - ``ss`` (V,S,S) uint8 and ``de`` (V,1,S,S) float16: the labelled points of the sweep
      projected into each camera through the devkit's chain (lidar -> ego -> global -> ego at
      camera time -> camera -> intrinsics; depth > 1 m, inside the image) and rasterised by
      :func:`projection.rasterise_points`: a point writes its pixel and, with
      ``preprocess.fill_neighbours``, the 3 x 3 neighbourhood around it (fill radius 1 px at
      S); a direct hit beats a fill and the nearest point wins a pixel. SS = the point's class
      (255 where no point reaches); DE = planar camera depth in CARLA's log encoding
      ``clip(1 + ln(d / 1000 m) / 5.70378, 0, 1)`` (0 where no point reaches: use ``ss != 255``
      as the valid mask).
    - ``lidar`` (15,S,S) float16 and ``ls`` (S,S) uint8: ``compact_perception.data.lidar.topview_15l``
      and ``ls_ground_truth`` (the same functions as sets A-C: highest point wins a cell, LS not
      neighbour-filled, 255 where no point) on the points in our frame with their labels.
    - ``bevp`` (32,S,S) uint8 multi-label masks on the top-view grid (+-R m, ego at the centre):
      (a) every ``sample_annotation`` box of the sample (category -> lidarseg index through the
      category table's ``index``), moved into our frame with the LiDAR keyframe's ego pose and
      rasterised as its oriented footprint (a cell is set when its centre lies inside, and the
      cell of the box centre always, so a 0.6 m pedestrian never falls between cell centres);
      (b) ground classes (flat.driveable_surface, flat.other, flat.sidewalk, flat.terrain): each
      lidarseg point of those classes sets its cell (and, with ``fill_neighbours``, the 3 x 3
      neighbours) in its class channel; (c) ``vehicle.ego``: the ego footprint (4.084 x 1.730 m,
      the nuScenes Renault Zoe) centred on the LiDAR.

Bad input (missing dataroot, table folder, table, lidarseg.json or lidarseg folder, any sweep,
label file or image of the selected samples; a sweep whose size is not a whole number of 5 x
float32 points, a label file whose size is not one uint8 per point of its sweep) raises
:class:`NuScenesInputError` with a one-line message naming the file BEFORE anything is written.
"""
from __future__ import annotations

import contextlib
import io
import logging
import math
import multiprocessing as mp
import time
from pathlib import Path
from typing import Any, Callable, Iterator, Optional, Sequence

import cv2
import numpy as np
from tqdm import tqdm

from compact_perception.core.classes import NUSCENES_NAMES
from compact_perception.core.params import Params, PreprocessParams
from compact_perception.core.cache import write_cache
from compact_perception.core.machine import bounded
from compact_perception.data.geometry import VIEWS, topview_cell_centres, topview_index
from compact_perception.data.lidar import ls_ground_truth, topview_15l
from compact_perception.data.nuscenes import (
    LABEL_RECORD_BYTES, LIDAR_CHANNEL, SWEEP_RECORD_BYTES, VIEW_CHANNELS, dataroot_problem,
)
from compact_perception.data.nuscenes.classmap import EGO_CLASS, GROUND_CLASSES
from compact_perception.data.nuscenes.projection import (
    carla_log_depth, inverse_pose, pose_matrix, project_points, quat_yaw, rasterise_points,
    scale_intrinsics, sensor_to_camera,
)
from compact_perception.data.nuscenes.split import SPLITS, split_scenes

log = logging.getLogger(__name__)

TABLES: tuple[str, ...] = (
    "category", "attribute", "visibility", "instance", "sensor", "calibrated_sensor", "ego_pose",
    "log", "scene", "sample", "sample_data", "sample_annotation", "map",
)
EGO_SIZE_M = (4.084, 1.730)  # length, width of the nuScenes ego vehicle (Renault Zoe)
N_CLASSES = len(NUSCENES_NAMES)


class NuScenesInputError(FileNotFoundError):
    """The dataroot is incomplete or a file is corrupt; the one-line message names it."""


# ----------------------------------------------------------------------------- checks
def preflight(dataroot: str | Path, version: str) -> None:
    """Check the dataroot layout before the devkit loads it (names the first missing items)."""
    root = Path(dataroot)
    problem = dataroot_problem(root, version)
    if problem:
        raise NuScenesInputError(problem)
    tables = root / version
    missing = [f"{tables / (t + '.json')}" for t in TABLES if not (tables / f"{t}.json").is_file()]
    if missing:
        raise NuScenesInputError("nuScenes tables missing: " + ", ".join(missing))
    if not (tables / "lidarseg.json").is_file():
        raise NuScenesInputError(f"nuScenes-lidarseg table missing: {tables / 'lidarseg.json'}")
    seg = root / "lidarseg" / version
    if not seg.is_dir():
        raise NuScenesInputError(f"nuScenes-lidarseg label folder missing: {seg}")


def load_nuscenes(dataroot: str | Path, version: str) -> Any:
    """``NuScenes(version, dataroot)`` after :func:`preflight`; devkit assertions become input errors."""
    preflight(dataroot, version)
    from nuscenes.nuscenes import NuScenes  # the devkit; imported late (heavy)

    t0 = time.perf_counter()
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            nusc = NuScenes(version=version, dataroot=str(dataroot), verbose=False)
    except AssertionError as err:
        raise NuScenesInputError(f"the nuScenes devkit rejected {dataroot}: {err}") from None
    log.info("devkit loaded %s (%s) in %.1f s: %d scenes, %d samples", dataroot, version,
             time.perf_counter() - t0, len(nusc.scene), len(nusc.sample))
    return nusc


def scene_sample_tokens(nusc: Any, scene: dict) -> list[str]:
    """Sample tokens of a scene in time order (first_sample_token -> next ...)."""
    out, tok = [], scene["first_sample_token"]
    while tok:
        out.append(tok)
        tok = nusc.get("sample", tok)["next"]
    return out


def lidar_size_problem(sweep_path: Path, label_path: Path) -> Optional[str]:
    """Why a sweep/label pair is unusable by its sizes alone, or None: a sweep is N points of
    5 float32 (20 bytes), its lidarseg file N uint8 labels (1 byte each)."""
    sweep_bytes, label_bytes = sweep_path.stat().st_size, label_path.stat().st_size
    if sweep_bytes == 0 or sweep_bytes % SWEEP_RECORD_BYTES:
        return (f"LiDAR sweep {sweep_path}: {sweep_bytes} bytes, expected a positive multiple of "
                f"{SWEEP_RECORD_BYTES} (5 float32 per point): truncated or corrupt")
    n_points = sweep_bytes // SWEEP_RECORD_BYTES
    if label_bytes != n_points * LABEL_RECORD_BYTES:
        return (f"lidarseg label file {label_path}: {label_bytes} labels, expected {n_points} "
                f"(1 uint8 per point of {sweep_path.name}): truncated or corrupt")
    return None


def check_sample_files(nusc: Any, sample_tokens: Sequence[str]) -> None:
    """Every sweep, lidarseg label file and camera image of ``sample_tokens`` exists, and every
    sweep and label file has a whole number of records with one label per point, else raise
    one :class:`NuScenesInputError` whose single line names the files."""
    root = Path(nusc.dataroot)
    missing: list[str] = []
    for st in sample_tokens:
        sample = nusc.get("sample", st)
        sweep_path: Optional[Path] = None
        for ch in [LIDAR_CHANNEL] + [VIEW_CHANNELS[v] for v in VIEWS]:
            if ch not in sample["data"]:
                missing.append(f"sample {st}: no {ch} sample_data")
                continue
            sd = nusc.get("sample_data", sample["data"][ch])
            path = root / sd["filename"]
            if not path.is_file():
                kind = "LiDAR sweep" if ch == LIDAR_CHANNEL else "camera image"
                missing.append(f"{kind} {path} not found")
            elif ch == LIDAR_CHANNEL:
                sweep_path = path
        if LIDAR_CHANNEL in sample["data"]:
            sd_tok = sample["data"][LIDAR_CHANNEL]
            try:
                rec = nusc.get("lidarseg", sd_tok)
            except KeyError:
                missing.append(f"sample {st}: no lidarseg record for {sd_tok}")
                continue
            label_path = root / rec["filename"]
            if not label_path.is_file():
                missing.append(f"lidarseg label file {label_path} not found")
            elif sweep_path is not None:
                problem = lidar_size_problem(sweep_path, label_path)
                if problem:
                    missing.append(problem)
    if missing:
        more = f"; ... and {len(missing) - 5} more" if len(missing) > 5 else ""
        raise NuScenesInputError(f"nuScenes input unusable ({len(missing)} problem(s)): "
                                 + "; ".join(missing[:5]) + more)


# ----------------------------------------------------------------------------- lidar helpers
def lidar_topview(points: np.ndarray, labels: np.ndarray, pre: PreprocessParams, size: int) -> tuple[np.ndarray, np.ndarray]:
    """(15,S,S) float16 LiDAR input and (S,S) uint8 LS ground truth, exactly as for sets A-C."""
    top = topview_15l(points, pre.lidar_range_m, size, pre.z_min_m, pre.z_max_m, pre.height_multiplier,
                      pre.fill_neighbours).astype(np.float16)
    return top, ls_ground_truth(points, labels, pre.lidar_range_m, size)


# ----------------------------------------------------------------------------- per sample
def _rasterise_box(mask: np.ndarray, cx: float, cy: float, length: float, width: float, yaw: float, range_m: float) -> None:
    """Set the cells of ``mask`` (S,S) whose centres lie inside an oriented footprint."""
    size = mask.shape[0]
    half = 0.5 * math.hypot(length, width)
    lo_i, hi_i = topview_index(np.array([cx - half, cx + half]), range_m, size)
    lo_j, hi_j = topview_index(np.array([cy - half, cy + half]), range_m, size)
    lo_i, lo_j = max(int(lo_i) - 1, 0), max(int(lo_j) - 1, 0)
    hi_i, hi_j = min(int(hi_i) + 1, size - 1), min(int(hi_j) + 1, size - 1)
    if lo_i > hi_i or lo_j > hi_j:
        return
    c = topview_cell_centres(range_m, size)
    xs, ys = np.meshgrid(c[lo_i:hi_i + 1], c[lo_j:hi_j + 1], indexing="ij")
    dx, dy = xs - cx, ys - cy
    co, si = math.cos(yaw), math.sin(yaw)
    inside = (np.abs(co * dx + si * dy) <= length / 2) & (np.abs(-si * dx + co * dy) <= width / 2)
    mask[lo_i:hi_i + 1, lo_j:hi_j + 1] |= inside.astype(np.uint8)
    ci, cj = int(topview_index(cx, range_m, size)), int(topview_index(cy, range_m, size))
    if abs(cx) <= range_m and abs(cy) <= range_m and 0 <= ci < size and 0 <= cj < size:
        mask[ci, cj] = 1  # small boxes (pedestrians, 0.6 m) never vanish between cell centres


def bev_ground_truth(
    nusc: Any, sample: dict, points: np.ndarray, labels: np.ndarray, lidar_cs: dict, lidar_pose: dict,
    size: int, range_m: float, fill_neighbours: bool = True,
) -> np.ndarray:
    """(32,S,S) uint8 multi-label BEV masks (see the module docstring)."""
    bev = np.zeros((N_CLASSES, size, size), dtype=np.uint8)
    ego_from_global = inverse_pose(pose_matrix(lidar_pose["translation"], lidar_pose["rotation"]))
    lidar_t = np.asarray(lidar_cs["translation"], dtype=np.float64)
    ego_yaw = quat_yaw(lidar_pose["rotation"])
    for ann_tok in sample["anns"]:
        ann = nusc.get("sample_annotation", ann_tok)
        idx = nusc.lidarseg_name2idx_mapping.get(ann["category_name"])
        if idx is None:
            continue
        c = ego_from_global[:3, :3] @ np.asarray(ann["translation"], dtype=np.float64) + ego_from_global[:3, 3] - lidar_t
        yaw = quat_yaw(ann["rotation"]) - ego_yaw
        width, length = float(ann["size"][0]), float(ann["size"][1])
        _rasterise_box(bev[idx], float(c[0]), float(c[1]), length, width, yaw, range_m)
    _rasterise_box(bev[EGO_CLASS], 0.0, 0.0, EGO_SIZE_M[0], EGO_SIZE_M[1], 0.0, range_m)
    ground = np.isin(labels, GROUND_CLASSES) & (np.abs(points[:, 0]) <= range_m) & (np.abs(points[:, 1]) <= range_m)
    if ground.any():
        i, j = topview_index(points[ground, 0], range_m, size), topview_index(points[ground, 1], range_m, size)
        lab = labels[ground].astype(np.int64)
        rad = 1 if fill_neighbours else 0
        for di in range(-rad, rad + 1):
            for dj in range(-rad, rad + 1):
                ii, jj = i + di, j + dj
                ok = (ii >= 0) & (ii < size) & (jj >= 0) & (jj < size)
                bev[lab[ok], ii[ok], jj[ok]] = 1
    return bev


def load_lidar(nusc: Any, lidar_sd: dict) -> tuple[np.ndarray, np.ndarray]:
    """(N,5) float32 sweep and (N,) uint8 lidarseg labels of a LIDAR_TOP sample_data."""
    root = Path(nusc.dataroot)
    sweep_path = root / lidar_sd["filename"]
    label_path = root / nusc.get("lidarseg", lidar_sd["token"])["filename"]
    problem = lidar_size_problem(sweep_path, label_path)  # also checked up front by check_sample_files
    if problem:
        raise NuScenesInputError(problem)
    sweep = np.fromfile(sweep_path, dtype=np.float32).reshape(-1, 5)
    labels = np.fromfile(label_path, dtype=np.uint8)
    return sweep, labels


def ingest_sample(nusc: Any, sample_token: str, resolution: int, pre: PreprocessParams) -> dict[str, np.ndarray]:
    """One preprocessed frame dict (keys rgb, lidar, de, ss, ls, bevp; see ARCHITECTURE.md)."""
    S = int(resolution)
    fill = 1 if pre.fill_neighbours else 0
    sample = nusc.get("sample", sample_token)
    lidar_sd = nusc.get("sample_data", sample["data"][LIDAR_CHANNEL])
    lidar_cs = nusc.get("calibrated_sensor", lidar_sd["calibrated_sensor_token"])
    lidar_pose = nusc.get("ego_pose", lidar_sd["ego_pose_token"])
    sweep, labels = load_lidar(nusc, lidar_sd)

    rgb = np.zeros((len(VIEWS), 3, S, S), dtype=np.uint8)
    ss = np.full((len(VIEWS), S, S), 255, dtype=np.uint8)
    de = np.zeros((len(VIEWS), 1, S, S), dtype=np.float16)
    root = Path(nusc.dataroot)
    for n, v in enumerate(VIEWS):
        cam_sd = nusc.get("sample_data", sample["data"][VIEW_CHANNELS[v]])
        cam_cs = nusc.get("calibrated_sensor", cam_sd["calibrated_sensor_token"])
        cam_pose = nusc.get("ego_pose", cam_sd["ego_pose_token"])
        img = cv2.imread(str(root / cam_sd["filename"]), cv2.IMREAD_COLOR)
        if img is None:
            raise NuScenesInputError(f"camera image unreadable: {root / cam_sd['filename']}")
        h, w = img.shape[:2]
        interp = cv2.INTER_AREA if (w > S or h > S) else cv2.INTER_LINEAR
        small = img if (w, h) == (S, S) else cv2.resize(img, (S, S), interpolation=interp)
        rgb[n] = small[:, :, ::-1].transpose(2, 0, 1)
        k = scale_intrinsics(np.asarray(cam_cs["camera_intrinsic"]), (w, h), (S, S))
        t = sensor_to_camera(lidar_cs, lidar_pose, cam_pose, cam_cs)
        u, vv, depth, keep = project_points(sweep, t, k, S, S, min_depth=1.0)
        ss_v, dm = rasterise_points(u[keep], vv[keep], depth[keep], labels[keep], S, S, fill_radius=fill)
        ss[n] = ss_v
        de[n, 0] = np.where(ss_v != 255, carla_log_depth(np.maximum(dm, 1e-3)), 0.0).astype(np.float16)

    rot = pose_matrix([0, 0, 0], lidar_cs["rotation"])[:3, :3]
    pts = np.empty((len(sweep), 4), dtype=np.float32)
    pts[:, :3] = sweep[:, :3].astype(np.float64) @ rot.T
    pts[:, 3] = np.clip(sweep[:, 3] / 255.0, 0.0, 1.0)
    lidar, ls = lidar_topview(pts, labels, pre, S)
    bevp = bev_ground_truth(nusc, sample, pts, labels, lidar_cs, lidar_pose, S, pre.lidar_range_m, pre.fill_neighbours)
    return {"rgb": rgb, "lidar": lidar, "de": de, "ss": ss, "ls": ls, "bevp": bevp}


# ----------------------------------------------------------------------------- whole set
def plan_ingestion(nusc: Any, split_seed: int) -> dict[str, list[tuple[str, str]]]:
    """Per split, the (frame id, sample token) pairs: scenes split 3:1:1, samples in time order."""
    by_name = {s["name"]: s for s in nusc.scene}
    split = split_scenes(list(by_name), split_seed)
    out: dict[str, list[tuple[str, str]]] = {}
    for name in SPLITS:
        pairs = []
        for scene_name in split[name]:
            for k, tok in enumerate(scene_sample_tokens(nusc, by_name[scene_name])):
                pairs.append((f"{scene_name}_{k:03d}", tok))
        out[name] = pairs
    return out


_WORKER_STATE: dict[str, Any] = {}  # the devkit handle, shared with forked workers


def _ingest_pair(pair: tuple[str, str]) -> dict:
    frame_id, tok = pair
    st = _WORKER_STATE
    frame = ingest_sample(st["nusc"], tok, st["resolution"], st["pre"])
    frame["frame_id"] = frame_id
    return frame


def iter_frames(nusc: Any, pairs: Sequence[tuple[str, str]], resolution: int, pre: PreprocessParams,
                desc: str = "ingest", workers: int = 1) -> Iterator[dict]:
    """Frame dicts (with ``frame_id``) for ``pairs`` in their order, with a progress bar.

    With ``workers > 1`` the samples are read in forked processes that share the loaded
    devkit tables; the order and every byte are the same as with one process.
    """
    _WORKER_STATE.update(nusc=nusc, resolution=resolution, pre=pre)
    bar = tqdm(total=len(pairs), desc=desc, unit="sample", leave=False)
    workers = bounded(workers)  # at most the usable cores (core.machine)
    if workers <= 1 or len(pairs) < 2:
        frames: Iterator[dict] = map(_ingest_pair, pairs)
        for frame in frames:
            bar.update()
            yield frame
    else:
        with mp.get_context("fork").Pool(workers) as pool:
            for frame in pool.imap(_ingest_pair, pairs, chunksize=2):
                bar.update()
                yield frame
    bar.close()


def ingest_nuscenes(
    dataroot: str | Path,
    version: str,
    out_dir: str | Path,
    *,
    resolution: int,
    preprocess: PreprocessParams,
    split_seed: int,
    source: Optional[str] = None,
    writer: Optional[Callable[[Path, dict, dict], Any]] = None,
    workers: int = 1,
) -> dict:
    """Ingest a dataroot into the cache at ``out_dir``; return the meta dict written.

    All inputs are checked before anything is written. ``source`` defaults to
    ``"simulated nuScenes-format"`` when the dataroot carries ``sim_export.json`` and
    ``"nuscenes-lidarseg"`` otherwise. ``writer`` defaults to ``compact_perception.core.cache.write_cache``.
    """
    dataroot, out_dir = Path(dataroot), Path(out_dir)
    nusc = load_nuscenes(dataroot, version)
    plan = plan_ingestion(nusc, split_seed)
    check_sample_files(nusc, [tok for pairs in plan.values() for _, tok in pairs])
    if source is None:
        source = "simulated nuScenes-format" if (dataroot / "sim_export.json").is_file() else "nuscenes-lidarseg"
    meta = {
        "dataset": "nuscenes", "source": source, "seg_classes": list(NUSCENES_NAMES),
        "bev_classes": list(NUSCENES_NAMES), "has_dvs": False, "resolution": int(resolution),
        "views": list(VIEWS), "version": version, "split_seed": int(split_seed),
        "scenes": {name: sorted({fid.rsplit("_", 1)[0] for fid, _ in pairs}) for name, pairs in plan.items()},
    }
    log.info("ingesting %s: %s", dataroot, {k: len(v) for k, v in plan.items()})
    splits = {name: iter_frames(nusc, plan[name], resolution, preprocess, desc=f"nuscenes {name}", workers=workers)
              for name in SPLITS}
    (writer or write_cache)(out_dir, splits, meta)
    return meta


def ingest_from_params(params: Params, out_dir: str | Path, sim_root: str | Path = "data/raw/nuscenes_sim") -> dict:
    """Pipeline entry: the configured dataroot, or the simulated export when it is null."""
    ns = params.datasets.nuscenes
    if ns.dataroot:
        problem = dataroot_problem(ns.dataroot, ns.version)
        if problem:
            raise NuScenesInputError(f"datasets.nuscenes.dataroot: {problem}")
    elif not Path(sim_root).is_dir():
        raise NuScenesInputError(f"{sim_root}: simulated nuScenes set not found (datasets.nuscenes.dataroot is "
                                 "null); run the nuscenes_sim stage first")
    dataroot = Path(ns.dataroot) if ns.dataroot else Path(sim_root)
    source = "nuscenes-lidarseg" if ns.dataroot else "simulated nuScenes-format"
    return ingest_nuscenes(dataroot, ns.version, out_dir, resolution=params.resolution,
                           preprocess=params.preprocess, split_seed=ns.split_seed, source=source,
                           workers=params.preprocess.workers)
