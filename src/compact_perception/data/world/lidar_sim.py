"""Roof LiDAR (paper section IV-A): 64 lasers from -30 to +20 deg, 360 deg, 32 m range.

Rays are cast with :func:`raycast.trace` against the same geometry the cameras see.
Points are (x, y, z, cos incident angle) in the ego/LiDAR frame, with the CARLA tag of
the surface hit. Rain drops a small fraction of returns (LiDAR is barely affected).
"""
from __future__ import annotations

import functools

import numpy as np

from ...core.params import LidarParams
from .raycast import Scene, trace


@functools.lru_cache(maxsize=8)
def lidar_rays(channels: int, lower_deg: float, upper_deg: float, samples: int) -> np.ndarray:
    """(channels*samples, 3) unit directions in the ego frame (laser-major)."""
    el = np.deg2rad(np.linspace(lower_deg, upper_deg, channels))
    az = np.arange(samples) * (2 * np.pi / samples) - np.pi
    e, a = np.meshgrid(el, az, indexing="ij")
    d = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], -1).reshape(-1, 3)
    d.setflags(write=False)
    return d


def scan(scene: Scene, ego: np.ndarray, lp: LidarParams, rain: float = 0.0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """One revolution at pose ``ego`` (x, y, yaw): points float32 (M, 4) and tags uint8 (M,)."""
    d_ego = lidar_rays(lp.channels, lp.lower_fov_deg, lp.upper_fov_deg, lp.horizontal_samples)
    c, s = np.cos(ego[2]), np.sin(ego[2])
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    d_w = d_ego @ rot.T
    origin = np.array([ego[0], ego[1], lp.height_m])
    hits = trace(scene, origin, d_w, lp.range_m)
    ok = hits.t <= lp.range_m
    if rain > 0:
        rng = np.random.default_rng([seed, 104729])
        ok &= rng.uniform(size=ok.shape) >= 0.02 * rain
    xyz = d_ego[ok] * hits.t[ok, None]
    cosi = np.abs(np.sum(hits.normal[ok] * d_w[ok], axis=1))
    pts = np.concatenate([xyz, cosi[:, None]], 1).astype(np.float32)
    return pts, hits.tag[ok].astype(np.uint8)
