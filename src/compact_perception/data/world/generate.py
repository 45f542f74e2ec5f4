"""Frame rendering and dataset generation for sets A, B, C (SPEC 3, 3.1; ARCHITECTURE.md raw layout).

:func:`render_episode` yields one record per step (npz keys of ARCHITECTURE.md plus a
``meta`` dict); :func:`generate_dataset` writes ``data/raw/<ds>/`` with the ``split_ratio`` splits,
per-town class-frequency CSVs and the manifest (last), all inside ``io.atomic_dir``.
Episodes are rendered in worker processes; each episode's seed is derived from
(params.seed, seed_offset, dataset id, episode index), so the output does not depend on
the number of workers and reruns are byte-identical.
"""
from __future__ import annotations

import logging
import multiprocessing as mp
import shutil
import zlib
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import numpy as np
from tqdm import tqdm

from ...core import io
from ...core.catalog import sim_dataset_ids
from ...core.classes import BEV_NAMES, CARLA_NAMES, CARLA_PALETTE, TAG, palette_to_index
from ...core.params import TOWNS, Params, ParamsError, WorldParams
from ...core.errors import RunError
from ...core.machine import bounded
from ..geometry import VIEWS
from ..record import SPLITS
from . import camera as cam
from .actors import Episode, boxes_to_aabb
from .bev_gt import bev_masks
from .conditions import Condition, draw_condition
from .events import dvs_events
from .lidar_sim import scan
from .raycast import Hits, Scene, trace
from .town import Town, build_town

log = logging.getLogger(__name__)

#: boxes farther than this (2D, metres) are not rendered by the cameras
CAMERA_FAR_M = 80.0
#: albedo of a lit traffic-light head: green, yellow, red
LIGHT_RGB = np.array([[0.1, 1.0, 0.2], [1.0, 0.85, 0.05], [1.0, 0.08, 0.05]], np.float32)


@dataclass
class _ViewGeom:
    hits: Hits
    dirs: np.ndarray  # world unit rays (S*S, 3)
    fwd: np.ndarray  # world optical axis
    ego: np.ndarray  # ego pose at that step


def build_scene(town: Town, state: Any) -> Scene:
    """Static town boxes plus the actors' boxes of one step."""
    amin, amax = boxes_to_aabb(state.boxes)
    color = np.concatenate([town.color, state.color])
    heads = np.array([L["box"] for L in town.lights], np.int64)
    if heads.size:  # lit traffic-light heads show their state (emissive in the shader)
        color[heads] = LIGHT_RGB[state.light_state]
    return Scene(town=town, bmin=np.concatenate([town.bmin, amin]), bmax=np.concatenate([town.bmax, amax]),
                 tag=np.concatenate([town.tag, state.tag]), color=color)


def _render_views(wp: WorldParams, scene: Scene, ego: np.ndarray, size: int) -> dict[str, _ViewGeom]:
    rays = cam.pixel_rays(size, wp.camera.fov_deg)
    W = cam.world_from_ego(ego, wp.lidar.height_m)
    out = {}
    for v in VIEWS:
        T = W @ cam.ego_from_camera(v, wp.camera, wp.lidar.height_m)
        dirs = rays @ T[:3, :3].T
        out[v] = _ViewGeom(trace(scene, T[:3, 3], dirs, CAMERA_FAR_M), dirs, T[:3, 2], ego)
    return out


def _shade(g: _ViewGeom, cond: Condition, size: int, view: str, town: Town, noise_seed: int) -> np.ndarray:
    fwd2 = np.array([np.cos(g.ego[2]), np.sin(g.ego[2])])
    return cam.shade(g.hits, g.dirs, cond, size, view, g.ego[:2], fwd2, town.lamps, noise_seed)


def _ego_boxes(state: Any, range_m: float, lidar_height: float) -> np.ndarray:
    """Actors within the top-view extent as (K, 8) x, y, z, l, w, h, yaw, tag in the ego frame."""
    ex, ey, eyaw = state.ego
    c, s = np.cos(eyaw), np.sin(eyaw)
    dx, dy = state.boxes[:, 0] - ex, state.boxes[:, 1] - ey
    x, y = c * dx + s * dy, -s * dx + c * dy
    keep = (np.abs(x) <= range_m + 5) & (np.abs(y) <= range_m + 5)
    z = state.boxes[:, 2] - lidar_height
    yaw = (state.boxes[:, 6] - eyaw + np.pi) % (2 * np.pi) - np.pi
    out = np.stack([x, y, z, state.boxes[:, 3], state.boxes[:, 4], state.boxes[:, 5], yaw, state.tag.astype(np.float64)], 1)
    return out[keep].astype(np.float32)


def render_episode(world_params: WorldParams, town: str, episode_seed: int, n_frames: int, resolution: int,
                   episode: int | None = None) -> Iterator[dict]:
    """Yield ``n_frames`` consecutive frame records of one drive in ``town``.

    Each record holds the npz keys of ARCHITECTURE.md and ``meta`` = {town, episode, step,
    time_of_day, weather}. The DVS of step k compares step k-1 and k re-lit under the
    conditions of step k (rain noise differs per step), so the previous geometry is reused.
    """
    wp = world_params
    T = build_town(town)
    ep = Episode(T, int(episode_seed))
    S = int(resolution)
    step_us = int(round(wp.dvs.step_s * 1e6))
    prev = _render_views(wp, build_scene(T, ep.state(-1)), ep.ego_pose(-1), S)
    for step in range(n_frames):
        st = ep.state(step)
        scene = build_scene(T, st)
        cond = draw_condition(wp.conditions, int(episode_seed), step)
        cur = _render_views(wp, scene, st.ego, S)
        rec: dict[str, Any] = {}
        for v in VIEWS:
            g = cur[v]
            rgb = _shade(g, cond, S, v, T, (int(episode_seed) * 7919 + step) & 0x7FFFFFFF)
            rgb_prev = _shade(prev[v], cond, S, v, T, (int(episode_seed) * 7919 + step - 1) & 0x7FFFFFFF)
            rec[f"rgb_{v}"] = rgb
            rec[f"dvs_{v}"] = dvs_events(rgb_prev, rgb, wp.dvs.contrast_threshold, step * step_us, step_us)
            rec[f"sem_{v}"] = cam.semantic_image(g.hits, S)
            rec[f"depth_{v}"] = cam.depth_image(g.hits, g.dirs, g.fwd, S)
        pts, tags = scan(scene, st.ego, wp.lidar, rain=cond.rain, seed=(int(episode_seed) * 1000003 + step) & 0x7FFFFFFF)
        rec["lidar"], rec["lidar_tag"] = pts, tags
        rec["bev"] = bev_masks(T, st, wp.lidar.range_m, S)
        rec["boxes"] = _ego_boxes(st, wp.lidar.range_m, wp.lidar.height_m)
        rec["ego_pose"] = st.ego.astype(np.float64)
        rec["meta"] = {"town": town, "episode": int(episode if episode is not None else episode_seed), "step": step, **cond.meta()}
        prev = cur
        yield rec


# ----------------------------------------------------------------------------- datasets
def check_dataset_params(params: Params, dataset_id: str) -> None:
    """Fail before any work on impossible dataset settings (message names the key)."""
    if dataset_id not in sim_dataset_ids():
        raise ParamsError(f"datasets.{dataset_id}: not a simulated dataset ({', '.join(sim_dataset_ids())})")
    dp = getattr(params.datasets, dataset_id)
    F = params.frames_of(dataset_id)
    E = params.world.frames_per_episode
    n = params.split_counts_of(dataset_id)
    if min(n.values()) < 1:
        raise ParamsError(f"datasets.{dataset_id}.frames.{params.scale}: {F} frames leave a split empty "
                          f"with split_ratio {n}")
    if E > min(n.values()):
        raise ParamsError(f"world.frames_per_episode: {E} exceeds the smallest split of "
                          f"datasets.{dataset_id}.frames.{params.scale} ({F} frames -> {n})")
    if dp.split_by == "town" and set(dp.train_towns) & set(dp.eval_towns):
        raise ParamsError(f"datasets.{dataset_id}.eval_towns: split_by 'town' needs towns disjoint from train_towns")
    for key in ("train_towns", "eval_towns"):
        bad = [t for t in getattr(dp, key) if t not in TOWNS]
        if bad:
            raise ParamsError(f"datasets.{dataset_id}.{key}: unknown town(s) {bad}")


def episode_seed(params: Params, dataset_id: str, index: int) -> int:
    """Deterministic per-episode seed from params.seed, seed_offset, dataset id and episode index."""
    dp = getattr(params.datasets, dataset_id)
    ss = np.random.SeedSequence([params.seed, dp.seed_offset, zlib.crc32(dataset_id.encode()), index])
    return int(ss.generate_state(1, np.uint32)[0])


def plan_episodes(params: Params, dataset_id: str) -> list[dict]:
    """Episodes of a dataset: split, town, index, seed, frames (``split_ratio``; no episode in two
    splits), as a list (:func:`iter_episodes` plans them one at a time)."""
    return list(iter_episodes(params, dataset_id))


def episode_count(params: Params, dataset_id: str) -> tuple[int, int]:
    """(frames, episodes) of a dataset, counted without planning the episodes."""
    n = params.split_counts_of(dataset_id)
    E = params.world.frames_per_episode
    return sum(n.values()), sum(-(-n[s] // E) for s in SPLITS)


def iter_episodes(params: Params, dataset_id: str) -> Iterator[dict]:
    """The episodes of :func:`plan_episodes`, in its order, planned as they are needed (a dataset's
    plan is never held in memory whole)."""
    dp = getattr(params.datasets, dataset_id)
    E = params.world.frames_per_episode
    n = params.split_counts_of(dataset_id)
    towns = dp.towns_by_split()
    idx = 0
    for split in SPLITS:
        left, k = n[split], 0
        while left > 0:
            m = min(E, left)
            tl = towns[split]
            # val and test alternate towns so both see every eval town (1:1 by episode)
            town = tl[(k + (1 if split == "test" else 0)) % len(tl)]
            yield {"split": split, "town": town, "index": idx, "seed": episode_seed(params, dataset_id, idx), "frames": m}
            idx, left, k = idx + 1, left - m, k + 1


def _frame_id(town: str, index: int, step: int) -> str:
    return f"{town}_ep{index:04d}_{step:03d}"


def _episode_job(job: tuple[dict, dict, int, str]) -> tuple[dict, list[tuple[str, dict]], np.ndarray, np.ndarray]:
    wp_dict, ep, S, frames_dir = job
    wp = WorldParams.model_validate(wp_dict)  # pydantic generics do not pickle; ship a dict
    pix = np.zeros(len(CARLA_NAMES), np.int64)
    pts = np.zeros(len(CARLA_NAMES), np.int64)
    metas = []
    for rec in render_episode(wp, ep["town"], ep["seed"], ep["frames"], S, episode=ep["index"]):
        meta = rec.pop("meta")
        fid = _frame_id(ep["town"], ep["index"], meta["step"])
        io.write_npz(Path(frames_dir) / f"{fid}.npz", rec)
        for v in VIEWS:
            pix += np.bincount(palette_to_index(rec[f"sem_{v}"], CARLA_PALETTE).ravel(), minlength=len(CARLA_NAMES))
        pts += np.bincount(rec["lidar_tag"], minlength=len(CARLA_NAMES))
        metas.append((fid, meta))
    return ep, metas, pix, pts


def _in_order(pool: Any, jobs: Iterator[tuple], window: int) -> Iterator[tuple]:
    """The results of ``_episode_job`` over ``jobs`` in their order, at most ``window`` episodes
    submitted ahead (``Pool.imap`` would plan and queue every episode at once)."""
    pending: deque = deque()
    for job in jobs:
        pending.append(pool.apply_async(_episode_job, (job,)))
        if len(pending) >= window:
            yield pending.popleft().get()
    while pending:
        yield pending.popleft().get()


#: Frames rendered (the first episode's first ones) to estimate a dataset's size on disk, and the
#: manifest's bytes per frame (its id and metadata).
SAMPLE_FRAMES = 3
MANIFEST_BYTES_PER_FRAME = 200


def estimate_disk(params: Params, dataset_id: str) -> tuple[int, int]:
    """(about, at least) the bytes a dataset takes on disk: its frame count times the compressed
    size of its first episode's first frames (their median; 80% of the smallest for "at least",
    as frames differ by their events and points), plus the manifest. Rendering them costs about
    a second at 128 px; it changes nothing (an episode is a function of its seed)."""
    total, _ = episode_count(params, dataset_id)
    ep = next(iter_episodes(params, dataset_id))
    sizes = sorted(len(io.npz_bytes({k: v for k, v in rec.items() if k != "meta"}))
                   for rec in render_episode(params.world, ep["town"], ep["seed"], min(SAMPLE_FRAMES, ep["frames"]),
                                             params.resolution, episode=ep["index"]))
    about = total * (sizes[len(sizes) // 2] + MANIFEST_BYTES_PER_FRAME)
    return about, int(total * 0.8 * sizes[0])


def _mb(n: float) -> str:
    return f"{n / 1e6:,.0f} MB" if n >= 1e6 else f"{n / 1e6:.1f} MB"


def check_disk(params: Params, dataset_id: str, out_dir: Path) -> None:
    """Refuse (:class:`RunError`, one line) a dataset the free disk under ``out_dir`` cannot hold,
    before anything is written (it was found out after 9.5 s of writing, 1e6 frames onto 20 MB)."""
    about, at_least = estimate_disk(params, dataset_id)
    where = out_dir.parent
    while not where.exists() and where != where.parent:
        where = where.parent
    free = shutil.disk_usage(where).free
    log.info("dataset %s: about %s on disk, %s free", dataset_id, _mb(about), _mb(free))
    if free < at_least:
        total, _ = episode_count(params, dataset_id)
        raise RunError(f"{out_dir}: {total} frames need about {_mb(about)} (at least {_mb(at_least)}, measured on "
                       f"the first frames), {_mb(free)} free on {where}; free space or lower "
                       f"datasets.{dataset_id}.frames")


def generate_dataset(params: Params, dataset_id: str, out_dir: str | Path) -> Path:
    """Write the simulated dataset ``dataset_id`` to ``out_dir`` (= data/raw/<ds>) atomically,
    after checking the free disk can hold it (:func:`check_disk`)."""
    check_dataset_params(params, dataset_id)
    dp = getattr(params.datasets, dataset_id)
    if dp.source.id != "sim":
        raise ParamsError(f"datasets.{dataset_id}.source.id is {dp.source.id!r}: the embedded world writes only "
                          f"'sim' datasets (data/sources/{dp.source.id}.py is that source's own)")
    wp = params.world
    S = params.resolution
    total, n_episodes = episode_count(params, dataset_id)
    out_dir = Path(out_dir)
    check_disk(params, dataset_id, out_dir)
    log.info("dataset %s: %d frames in %d episodes at %dx%d -> %s", dataset_id, total, n_episodes, S, S, out_dir)
    with io.atomic_dir(out_dir) as tmp:
        frames_dir = tmp / "frames"
        frames_dir.mkdir()
        wp_dict = wp.model_dump(mode="json")
        jobs = ((wp_dict, e, S, str(frames_dir)) for e in iter_episodes(params, dataset_id))
        splits: dict[str, list[str]] = {s: [] for s in SPLITS}
        frames: dict[str, dict] = {}
        pix: dict[str, np.ndarray] = {}
        pts: dict[str, np.ndarray] = {}
        bar = tqdm(total=total, desc=f"generate {dataset_id}", unit="frame", leave=False)
        workers = min(bounded(wp.workers), n_episodes)  # at most the usable cores (core.machine)
        pool = mp.get_context("fork").Pool(workers) if workers > 1 else None
        try:
            results = _in_order(pool, jobs, 2 * workers) if pool else map(_episode_job, jobs)
            for ep, metas, p, q in results:
                for fid, meta in metas:
                    splits[ep["split"]].append(fid)
                    frames[fid] = meta
                pix[ep["town"]] = pix.get(ep["town"], 0) + p
                pts[ep["town"]] = pts.get(ep["town"], 0) + q
                bar.update(len(metas))
        finally:
            bar.close()
            if pool:
                pool.terminate()
                pool.join()
        for town in sorted(pix):
            lines = ["tag,class,pixels,points"] + [f"{i},{n},{int(pix[town][i])},{int(pts[town][i])}" for i, n in enumerate(CARLA_NAMES)]
            io.write_text(tmp / "stats" / f"class_frequency_{town}.csv", "\n".join(lines) + "\n")
        manifest = {
            "dataset": dataset_id, "source": "sim", "resolution": S, "views": list(VIEWS), "splits": splits,
            "frames": frames, "seg_classes": list(CARLA_NAMES), "bev_classes": list(BEV_NAMES),
            "params": {"seed": params.seed, "scale": params.scale, "world": wp.model_dump(mode="json"),
                       "dataset": dp.model_dump(mode="json", exclude={"training"})},
        }
        io.write_json(tmp / "manifest.json", manifest)
    log.info("dataset %s written: %s", dataset_id, {k: len(v) for k, v in splits.items()})
    return out_dir


__all__ = ["render_episode", "generate_dataset", "estimate_disk", "check_disk", "plan_episodes", "iter_episodes", "episode_count", "episode_seed", "check_dataset_params", "build_scene", "TAG"]
