"""Frame conventions shared by the world, preprocessing and nuScenes ingestion.

Ego / LiDAR frame: right-handed, x forward, y left, z up, origin at the LiDAR
(roof, ``lidar.height_m`` above the ground, so flat ground is at z = -height).

Top-view grid (paper eq. (2)-(3)): a point (x, y) in [-R, R] m maps to the cell

    i = round((x + R) / (2R) * (S - 1)),  j = round((y + R) / (2R) * (S - 1))

with R = 32 m and S = 128 in the paper (S = grid size). Row i grows with x (forward),
column j grows with y (left). The ego sits at cell (round((S-1)/2), round((S-1)/2)),
i.e. (64, 64) for S = 128 (numpy rounds half to even). LiDAR top views, LS ground
truth and BEV masks all use this grid, so they overlay exactly.
"""
from __future__ import annotations

import numpy as np

#: Camera views in the paper's order: front, left, right, rear.
VIEWS: tuple[str, ...] = ("f", "l", "ri", "r")
#: Yaw of each camera in the ego frame (degrees, counter-clockwise from +x).
VIEW_YAW_DEG: dict[str, float] = {"f": 0.0, "l": 90.0, "ri": -90.0, "r": 180.0}


def topview_index(coord: np.ndarray, range_m: float, size: int) -> np.ndarray:
    """Eq. (2)/(3): metric coordinate(s) in [-range_m, range_m] -> integer cell index.

    Rounds half to even (numpy ``rint``). Values outside the range give indices
    outside [0, size-1]; callers drop those (never wrap).
    """
    return np.rint((np.asarray(coord, dtype=np.float64) + range_m) / (2.0 * range_m) * (size - 1)).astype(np.int64)


def topview_center(size: int) -> int:
    """Cell index of the ego (x = y = 0) on a ``size`` grid."""
    return int(np.rint((size - 1) / 2.0))


def topview_cell_centres(range_m: float, size: int) -> np.ndarray:
    """Metric coordinate of each cell index 0..size-1 (inverse of :func:`topview_index`)."""
    return np.arange(size, dtype=np.float64) / (size - 1) * (2.0 * range_m) - range_m
