"""LiDAR points -> camera pixels, and SS/DE ground truth from projected labelled points.

Transform chain (the devkit's ``NuScenesExplorer.map_pointcloud_to_image``):
point sensor -> ego at the sweep's time (LiDAR ``calibrated_sensor``) -> global (LiDAR
``ego_pose``) -> ego at the camera's time (camera ``ego_pose``) -> camera (camera
``calibrated_sensor``), then the camera intrinsic matrix. Rotations are quaternions
``(w, x, y, z)``; cameras follow the OpenCV convention (x right, y down, z forward), in both
nuScenes and our world. Points with depth (camera z) <= ``min_depth`` (1 m, as the devkit) or
outside the image are dropped.

Pixel convention (ARCHITECTURE.md): the continuous image coordinate (u, v) spans [0, W] x [0, H]
and pixel (row, col) = (floor(v), floor(u)); resizing an image from W x H to S x S therefore
scales the intrinsics by (S/W, S/H) (:func:`scale_intrinsics`).

Ground truth (:func:`rasterise_points`): each kept point writes its class (SS) and its planar
depth (DE) into the pixel it hits; with ``fill_radius`` r > 0 it also fills the
(2r+1) x (2r+1) neighbourhood, so the sparse LiDAR pattern becomes a dense-ish image (paper
IV-B: "give neighbouring pixels the same class or value"). Priority per pixel: a point that
hits the pixel itself beats any neighbour fill; among equals the nearest point (smallest depth)
wins, so foreground objects occlude what is behind them. Pixels no point reaches keep
SS = 255 (no label) and depth 0. DE is encoded like CARLA's depth camera (the simulated sets):
``clip(1 + ln(d / 1000 m) / 5.70378, 0, 1)`` (:func:`carla_log_depth`).
"""
from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from ...core.depth import DEPTH_FAR_M, DEPTH_LOG_K

NO_LABEL = 255

# The quaternion maths below is written out rather than taken from pyquaternion /
# nuscenes.utils.geometry_utils (installed with the devkit): their formulas agree to ~1e-16
# (rotation matrices; 3e-13 for an inverted pose) but not bit for bit, and that moved a few
# points across pixel and BEV-cell boundaries of the ingested cache (checked: the exported
# calibrated_sensor.json and every ingested array differed), so the data would not be the same bytes.


def quat_to_matrix(q: Sequence[float]) -> np.ndarray:
    """Rotation matrix of a unit quaternion given as (w, x, y, z)."""
    w, x, y, z = (float(v) for v in q)
    n = np.sqrt(w * w + x * x + y * y + z * z)
    if n == 0:
        raise ValueError("zero quaternion")
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_quat(r: np.ndarray) -> list[float]:
    """Unit quaternion (w, x, y, z) of a rotation matrix, with w >= 0."""
    r = np.asarray(r, dtype=np.float64)
    t = np.trace(r)
    if t > 0:
        s = np.sqrt(t + 1.0) * 2
        q = [0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2]) * 2
        q = [(r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s]
    elif r[1, 1] > r[2, 2]:
        s = np.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2]) * 2
        q = [(r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s]
    else:
        s = np.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1]) * 2
        q = [(r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s]
    q = np.asarray(q)
    q = q / np.linalg.norm(q)
    if q[0] < 0:
        q = -q
    return [float(v) for v in q]


def yaw_quat(yaw: float) -> list[float]:
    """Quaternion (w, x, y, z) of a rotation by ``yaw`` radians about +z."""
    return [float(np.cos(yaw / 2)), 0.0, 0.0, float(np.sin(yaw / 2))]


def quat_yaw(q: Sequence[float]) -> float:
    """Yaw (rotation about +z, radians) of a quaternion (w, x, y, z)."""
    r = quat_to_matrix(q)
    return float(np.arctan2(r[1, 0], r[0, 0]))


def pose_matrix(translation: Sequence[float], rotation: Sequence[float]) -> np.ndarray:
    """4x4 homogeneous transform ``child -> parent`` from a nuScenes record's fields."""
    t = np.eye(4)
    t[:3, :3] = quat_to_matrix(rotation)
    t[:3, 3] = np.asarray(translation, dtype=np.float64)
    return t


def inverse_pose(t: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 transform."""
    inv = np.eye(4)
    inv[:3, :3] = t[:3, :3].T
    inv[:3, 3] = -t[:3, :3].T @ t[:3, 3]
    return inv


def sensor_to_camera(
    point_cs: Mapping, point_pose: Mapping, cam_pose: Mapping, cam_cs: Mapping
) -> np.ndarray:
    """4x4 transform point sensor -> camera from the four devkit records (see module docstring)."""
    ego_from_sensor = pose_matrix(point_cs["translation"], point_cs["rotation"])
    global_from_ego = pose_matrix(point_pose["translation"], point_pose["rotation"])
    ego_cam_from_global = inverse_pose(pose_matrix(cam_pose["translation"], cam_pose["rotation"]))
    cam_from_ego = inverse_pose(pose_matrix(cam_cs["translation"], cam_cs["rotation"]))
    return cam_from_ego @ ego_cam_from_global @ global_from_ego @ ego_from_sensor


def scale_intrinsics(k: np.ndarray, src_wh: tuple[int, int], dst_wh: tuple[int, int]) -> np.ndarray:
    """Intrinsics of an image resized from ``src_wh`` to ``dst_wh`` (width, height)."""
    k = np.asarray(k, dtype=np.float64).copy()
    sx, sy = dst_wh[0] / float(src_wh[0]), dst_wh[1] / float(src_wh[1])
    k[0, :] *= sx
    k[1, :] *= sy
    return k


def project_points(
    points: np.ndarray, cam_from_sensor: np.ndarray, k: np.ndarray, width: int, height: int,
    min_depth: float = 1.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Project (N, >=3) sensor-frame points into an image.

    Returns ``(u, v, depth, keep)``: continuous pixel coordinates and camera-z depth of every
    point, and the mask of points with depth > ``min_depth`` that land inside [0, W) x [0, H).
    """
    p = np.asarray(points, dtype=np.float64)[:, :3]
    pc = p @ cam_from_sensor[:3, :3].T + cam_from_sensor[:3, 3]
    depth = pc[:, 2]
    safe = np.where(np.abs(depth) < 1e-9, 1e-9, depth)
    uvw = pc @ np.asarray(k, dtype=np.float64).T
    u, v = uvw[:, 0] / safe, uvw[:, 1] / safe
    keep = (depth > min_depth) & (u >= 0) & (u < width) & (v >= 0) & (v < height)
    return u, v, depth, keep


def carla_log_depth(depth_m: np.ndarray) -> np.ndarray:
    """CARLA's logarithmic depth encoding in [0, 1] (float32)."""
    d = np.maximum(np.asarray(depth_m, dtype=np.float64), 1e-6)
    return np.clip(1.0 + np.log(d / DEPTH_FAR_M) / DEPTH_LOG_K, 0.0, 1.0).astype(np.float32)


def rasterise_points(
    u: np.ndarray, v: np.ndarray, depth: np.ndarray, labels: np.ndarray, height: int, width: int,
    fill_radius: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """Splat projected points into (SS class map uint8, depth map float32 metres).

    Inputs are the already-kept points (see :func:`project_points`). Priority per pixel: direct
    hit before neighbour fill, then nearest depth. Unreached pixels: class 255, depth 0.
    """
    ss = np.full((height, width), NO_LABEL, dtype=np.uint8)
    dm = np.zeros((height, width), dtype=np.float32)
    if len(u) == 0:
        return ss, dm
    col = np.floor(u).astype(np.int64)
    row = np.floor(v).astype(np.int64)
    r = max(int(fill_radius), 0)
    offs = [(dr, dc) for dr in range(-r, r + 1) for dc in range(-r, r + 1)]
    rows, cols, dep, lab, fill = [], [], [], [], []
    for dr, dc in offs:
        rr, cc = row + dr, col + dc
        ok = (rr >= 0) & (rr < height) & (cc >= 0) & (cc < width)
        rows.append(rr[ok]); cols.append(cc[ok]); dep.append(depth[ok]); lab.append(labels[ok])
        fill.append(np.full(int(ok.sum()), 0 if (dr, dc) == (0, 0) else 1, dtype=np.int8))
    rows_a, cols_a = np.concatenate(rows), np.concatenate(cols)
    dep_a, lab_a, fill_a = np.concatenate(dep), np.concatenate(lab), np.concatenate(fill)
    pix = rows_a * width + cols_a
    order = np.lexsort((dep_a, fill_a, pix))  # by pixel, then direct hits first, then nearest
    pix_sorted = pix[order]
    first = np.ones(len(order), dtype=bool)
    first[1:] = pix_sorted[1:] != pix_sorted[:-1]
    win = order[first]
    ss.reshape(-1)[pix[win]] = lab_a[win].astype(np.uint8)
    dm.reshape(-1)[pix[win]] = dep_a[win].astype(np.float32)
    return ss, dm
