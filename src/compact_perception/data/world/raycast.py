"""Vectorised ray casting against the world's boxes and flat ground (SPEC 3.1: own renderer).

Cameras and LiDAR call the same :func:`trace`, so they see the same geometry. Broad
phase: boxes beyond ``far`` are dropped, rays are grouped into azimuth sectors and each
sector is tested only against the boxes whose angular extent (seen from the origin)
overlaps it. Narrow phase: the slab test on (rays x boxes) arrays.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...core.classes import TAG
from .town import Town

SECTOR_RAD = np.deg2rad(4.0)


@dataclass
class Scene:
    """Geometry at one step: the town's static boxes plus the actors' boxes."""

    town: Town
    bmin: np.ndarray  # (N, 3) float32
    bmax: np.ndarray
    tag: np.ndarray  # (N,) uint8
    color: np.ndarray  # (N, 3) float32


@dataclass
class Hits:
    """Per-ray result; ``t`` = inf and tag sky where nothing was hit."""

    t: np.ndarray  # (R,) metric distance along the unit ray
    tag: np.ndarray  # (R,) uint8
    normal: np.ndarray  # (R, 3) float32
    point: np.ndarray  # (R, 3) float64 world
    color: np.ndarray  # (R, 3) float32 base albedo (boxes; ground filled by the shader)
    box: np.ndarray  # (R,) int64 box index or -1 (ground/sky)


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def trace(scene: Scene, origin: np.ndarray, dirs: np.ndarray, far: float) -> Hits:
    """Cast unit rays ``dirs`` (R, 3) from ``origin`` (3,) in the world frame.

    Boxes are considered up to ``far`` metres (2D); the ground plane z = 0 is unbounded.
    """
    o = np.asarray(origin, np.float64)
    R = dirs.shape[0]
    # ---- broad phase: distance and angular extent of every box from the origin
    cx = np.clip(o[0], scene.bmin[:, 0], scene.bmax[:, 0])
    cy = np.clip(o[1], scene.bmin[:, 1], scene.bmax[:, 1])
    dist = np.hypot(cx - o[0], cy - o[1])
    keep = np.nonzero(dist <= far)[0]
    bmin = scene.bmin[keep].astype(np.float64) - o
    bmax = scene.bmax[keep].astype(np.float64) - o
    inside = dist[keep] < 1e-6
    corners_x = np.stack([bmin[:, 0], bmax[:, 0], bmin[:, 0], bmax[:, 0]], -1)
    corners_y = np.stack([bmin[:, 1], bmin[:, 1], bmax[:, 1], bmax[:, 1]], -1)
    ac = np.arctan2((bmin[:, 1] + bmax[:, 1]) / 2, (bmin[:, 0] + bmax[:, 0]) / 2)
    dd = _wrap(np.arctan2(corners_y, corners_x) - ac[:, None])
    dlo, dhi = dd.min(1), dd.max(1)
    dlo[inside], dhi[inside] = -4.0, 4.0
    # ---- rays into azimuth sectors
    az = np.arctan2(dirs[:, 1], dirs[:, 0])
    sector = np.floor((az + np.pi) / SECTOR_RAD).astype(np.int64)
    order = np.argsort(sector, kind="stable")
    bounds = np.searchsorted(sector[order], np.arange(sector.max() + 2))
    best_t = np.full(R, np.inf)
    best_box = np.full(R, -1, np.int64)
    best_axis = np.zeros(R, np.int64)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / np.where(np.abs(dirs) < 1e-12, 1e-12, dirs)
        for s in range(len(bounds) - 1):
            a, b = bounds[s], bounds[s + 1]
            if a == b:
                continue
            idx = order[a:b]
            centre = -np.pi + (s + 0.5) * SECTOR_RAD
            d = _wrap(ac - centre)
            half = SECTOR_RAD / 2 + 1e-3
            sel = np.nonzero((d + dhi >= -half) & (d + dlo <= half))[0]
            if sel.size == 0:
                continue
            iv = inv[idx]
            t0 = bmin[sel][None, :, :] * iv[:, None, :]
            t1 = bmax[sel][None, :, :] * iv[:, None, :]
            tn = np.minimum(t0, t1)
            tf = np.maximum(t0, t1).min(-1)
            tnear = tn.max(-1)
            hit = (tnear <= tf) & (tnear > 1e-4)
            tt = np.where(hit, tnear, np.inf)
            k = tt.argmin(1)
            r = np.arange(len(idx))
            tk = tt[r, k]
            ok = np.isfinite(tk)
            best_t[idx[ok]] = tk[ok]
            best_box[idx[ok]] = keep[sel[k[ok]]]
            best_axis[idx[ok]] = tn[r[ok], k[ok]].argmax(-1)
    # ---- ground plane z = 0
    with np.errstate(divide="ignore", invalid="ignore"):
        tg = np.where(dirs[:, 2] < -1e-9, -o[2] / dirs[:, 2], np.inf)
    use_ground = tg < best_t
    t = np.where(use_ground, tg, best_t)
    point = o + dirs * np.where(np.isfinite(t), t, 0.0)[:, None]
    tag = np.full(R, TAG["sky"], np.uint8)
    normal = np.zeros((R, 3), np.float32)
    color = np.zeros((R, 3), np.float32)
    hb = (~use_ground) & (best_box >= 0)
    tag[hb] = scene.tag[best_box[hb]]
    color[hb] = scene.color[best_box[hb]]
    ax = best_axis[hb]
    normal[hb, ax] = -np.sign(dirs[hb, ax])
    box = np.where(hb, best_box, -1)
    g = use_ground & np.isfinite(tg)
    tag[g] = scene.town.ground_at(point[g, 0], point[g, 1])
    normal[g, 2] = 1.0
    return Hits(t=t, tag=tag, normal=normal, point=point, color=color, box=box)
