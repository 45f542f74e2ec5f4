"""Cameras F, L, Ri, R (paper section IV-A, Fig. 4; ARCHITECTURE.md conventions).

Pinhole, OpenCV camera frame (x right, y down, z forward), ``fx = fy = (S/2)/tan(fov/2)``,
``cx = cy = S/2``, pixel (v, u) is the ray through (u + 0.5, v + 0.5). Each camera sits
``mount_offset_m`` from the ego centre along its view direction, ``height_m`` above the
ground, pitched up by ``pitch_deg``. Depth is planar z (CARLA depth camera), encoded with
CARLA's logarithmic depth x 65535.
"""
from __future__ import annotations

import numpy as np

from ...core.classes import CARLA_PALETTE, TAG
from ...core.depth import DEPTH_FAR_M, DEPTH_LOG_K
from ...core.params import CameraParams
from ..geometry import VIEW_YAW_DEG
from .conditions import TIMES, Condition, sun_vector
from .raycast import Hits


def intrinsic_matrix(size: int, fov_deg: float) -> np.ndarray:
    """3x3 pinhole intrinsics for a ``size`` x ``size`` image with ``fov_deg`` FOV."""
    f = (size / 2.0) / np.tan(np.deg2rad(fov_deg) / 2.0)
    return np.array([[f, 0.0, size / 2.0], [0.0, f, size / 2.0], [0.0, 0.0, 1.0]])


def camera_rotation(view: str, pitch_deg: float) -> np.ndarray:
    """3x3 rotation whose columns are the camera x (right), y (down), z (forward) axes in the ego frame."""
    yaw, p = np.deg2rad(VIEW_YAW_DEG[view]), np.deg2rad(pitch_deg)
    fwd = np.array([np.cos(p) * np.cos(yaw), np.cos(p) * np.sin(yaw), np.sin(p)])
    right = np.array([np.sin(yaw), -np.cos(yaw), 0.0])
    down = np.cross(fwd, right)
    return np.stack([right, down, fwd], axis=1)


def ego_from_camera(view: str, camera: CameraParams, lidar_height: float) -> np.ndarray:
    """4x4 transform from the OpenCV camera frame of ``view`` to the ego/LiDAR frame."""
    yaw = np.deg2rad(VIEW_YAW_DEG[view])
    T = np.eye(4)
    T[:3, :3] = camera_rotation(view, camera.pitch_deg)
    T[:3, 3] = [camera.mount_offset_m * np.cos(yaw), camera.mount_offset_m * np.sin(yaw), camera.height_m - lidar_height]
    return T


def pixel_rays(size: int, fov_deg: float) -> np.ndarray:
    """(S*S, 3) unit ray directions in the camera frame, row-major over (v, u)."""
    K = intrinsic_matrix(size, fov_deg)
    v, u = np.meshgrid(np.arange(size) + 0.5, np.arange(size) + 0.5, indexing="ij")
    d = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1).reshape(-1, 3)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def world_from_ego(ego: np.ndarray, lidar_height: float) -> np.ndarray:
    """4x4 transform from the ego/LiDAR frame to the world for pose (x, y, yaw)."""
    c, s = np.cos(ego[2]), np.sin(ego[2])
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:3, 3] = [ego[0], ego[1], lidar_height]
    return T


def encode_depth(depth_m: np.ndarray) -> np.ndarray:
    """CARLA logarithmic depth, normalised 0..1, x 65535 as uint16."""
    with np.errstate(divide="ignore"):
        d = np.clip(1.0 + np.log(np.maximum(depth_m, 1e-6) / DEPTH_FAR_M) / DEPTH_LOG_K, 0.0, 1.0)
    return np.rint(d * 65535.0).astype(np.uint16)


def decode_depth(depth_u16: np.ndarray) -> np.ndarray:
    """Inverse of :func:`encode_depth` (metres; 0 maps to ~3.33 m)."""
    return DEPTH_FAR_M * np.exp((depth_u16.astype(np.float64) / 65535.0 - 1.0) * DEPTH_LOG_K)


def _hash(p: np.ndarray, scale: float) -> np.ndarray:
    """Deterministic value noise in [0, 1) tied to world position (texture that moves with the world)."""
    q = np.floor(p * scale).astype(np.int64)
    h = (q[..., 0] * 73856093) ^ (q[..., 1] * 19349663) ^ (q[..., 2] * 83492791)
    return ((h & 0xFFFF) / 65536.0).astype(np.float32)


_GROUND_ALBEDO = {
    TAG["road"]: (0.28, 0.27, 0.28), TAG["road line"]: (0.85, 0.85, 0.8), TAG["sidewalk"]: (0.55, 0.52, 0.5),
    TAG["ground"]: (0.42, 0.35, 0.28), TAG["terrain"]: (0.3, 0.45, 0.2), TAG["water"]: (0.12, 0.2, 0.3),
    TAG["rail track"]: (0.35, 0.3, 0.28),
}
_GROUND_LUT = np.full((256, 3), 0.4, np.float32)
for _k, _v in _GROUND_ALBEDO.items():
    _GROUND_LUT[_k] = _v


def shade(hits: Hits, dirs: np.ndarray, cond: Condition, size: int, view: str, ego_xy: np.ndarray,
          ego_fwd: np.ndarray, lamps: np.ndarray, noise_seed: int) -> np.ndarray:
    """RGB uint8 (S, S, 3) from a camera's hits under ``cond`` (illumination, fog, rain, night lights).

    ``noise_seed`` drives the rain streaks/noise, which differ between time steps.
    """
    tod = TIMES[cond.time_of_day]
    sky = hits.box < 0
    sky &= ~np.isfinite(hits.t)
    albedo = np.where((hits.box < 0)[:, None], _GROUND_LUT[hits.tag], hits.color)
    tex = _hash(hits.point, 2.0) * 0.25 + _hash(hits.point, 7.0) * 0.15 + 0.8
    albedo = albedo * tex[:, None]
    lit_sun = tod[2] * (1.0 - 0.75 * cond.cloud)
    amb = tod[3] * (1.0 - 0.3 * cond.cloud) + 0.1 * cond.cloud * (tod[2] > 0)
    ndotl = np.clip(hits.normal @ sun_vector(cond).astype(np.float32), 0.0, None)
    light = amb + lit_sun * ndotl * (1.0 - 0.25 * cond.cloud)
    if cond.time_of_day in ("night", "evening"):
        k = 1.0 if cond.time_of_day == "night" else 0.35
        p2 = hits.point[:, :2]
        if len(lamps):
            near = lamps[np.hypot(lamps[:, 0] - ego_xy[0], lamps[:, 1] - ego_xy[1]) < 70.0]
            for lx, ly in near:
                d2 = (p2[:, 0] - lx) ** 2 + (p2[:, 1] - ly) ** 2
                light = light + k * 0.9 * np.exp(-d2 / 40.0)
        rel = p2 - ego_xy
        dist = np.linalg.norm(rel, axis=1) + 1e-6
        cosang = (rel @ ego_fwd) / dist
        light = light + k * 1.6 * np.clip((cosang - 0.8) / 0.2, 0, 1) / (1.0 + (dist / 12.0) ** 2)
    light = np.where(hits.tag == TAG["traffic light"], np.maximum(light, 1.0), light)  # emissive heads
    rgb = albedo * light[:, None].astype(np.float32)
    sky_rgb = np.array(tod[4], np.float32)
    grey = np.float32(sky_rgb.mean())
    sky_rgb = sky_rgb * (1 - 0.7 * cond.cloud) + grey * 0.7 * cond.cloud
    elev = np.clip(dirs[:, 2], 0, 1)[:, None]
    rgb[sky] = (sky_rgb * (1.1 - 0.4 * elev[sky])).astype(np.float32)
    # fog: attenuation with distance towards the fog colour
    if cond.fog > 0:
        fog_col = np.float32(0.7 * max(tod[3] / 0.45, 0.08))
        att = np.exp(-np.where(np.isfinite(hits.t), hits.t, 1e4) * 0.07 * cond.fog).astype(np.float32)
        rgb = rgb * att[:, None] + fog_col * (1 - att[:, None])
    rgb = rgb.reshape(size, size, 3)
    if cond.rain > 0:
        rng = np.random.default_rng([noise_seed, size, ord(view[0]) + len(view)])
        rgb = rgb * (1.0 - 0.3 * cond.rain)
        rgb = rgb + rng.normal(0, 0.04 * cond.rain, rgb.shape).astype(np.float32)
        n = int(cond.rain * size * size / 60)
        ln = max(2, size // 12)
        xs = rng.integers(0, size, n)
        ys = rng.integers(-ln, size, n)
        for k in range(ln):
            yy = ys + k
            ok = (yy >= 0) & (yy < size)
            rgb[yy[ok], xs[ok]] += 0.18
    out = np.clip(rgb, 0, 1) ** (1 / 2.2)
    return np.rint(out * 255).astype(np.uint8)


def semantic_image(hits: Hits, size: int) -> np.ndarray:
    """Semantic image in CARLA_PALETTE (S, S, 3)."""
    return CARLA_PALETTE[hits.tag.reshape(size, size)]


def depth_image(hits: Hits, dirs: np.ndarray, fwd: np.ndarray, size: int) -> np.ndarray:
    """Planar z-depth (metres, sky = 1000) as CARLA log-encoded uint16 (S, S)."""
    z = np.where(np.isfinite(hits.t), hits.t * (dirs @ fwd), DEPTH_FAR_M)
    return encode_depth(z.reshape(size, size))
