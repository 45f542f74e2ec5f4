"""LiDAR top-view projections of the paper's section IV-C, eq. (2)-(5), and the LS ground truth.

Grid (eq. (2)-(3), :mod:`compact_perception.data.geometry`): a point (x, y) maps to the cell

    i = rint((x + R) / (2R) * (S - 1)),   j = rint((y + R) / (2R) * (S - 1))

(row i forward, column j left, numpy round-half-to-even). Points with ``|x| > R`` or
``|y| > R`` are **dropped** (never clipped or wrapped onto the border), even where their
rounded index would still fall inside the grid (x = 32.01 m -> rint(127.02) = 127, dropped).
Points with a non-finite x, y or z are dropped too.

Height channel (eq. (5)): ``k = rint((z - z_min) / (z_max - z_min) * multiplier)`` with
z in [-2, 11] m and multiplier 13 gives channels 0..13; points with z outside
[z_min, z_max] are dropped from those channels.

Value (eq. (2)): cos(theta) of the incident angle (column 3 of the point array) of the
**highest** point in the cell (for the 15-layer tensor: in the (cell, channel)); 0 where
no point fell. Ties in z go to the later point in the array (deterministic).

Neighbour filling (paper: "we also give the same value to the nearest pixels"): every
empty cell of the 8-neighbourhood of an occupied cell takes that cell's value. When
several occupied neighbours compete, the one holding the highest point wins (ties: the
later point). A cell that holds a real point is never overwritten by a neighbour.

Implementation: each point gets a 64-bit priority ``(monotone int of float32 z) << 32 |
point index``; the winner of a cell is ``np.maximum.at`` of the priorities (no sort),
and neighbour filling is a max over the 8 shifted priority grids. z is compared at
float32 precision (the sensor's precision).
"""
from __future__ import annotations

import logging

import numpy as np

log = logging.getLogger(__name__)

_EMPTY = np.iinfo(np.int64).min
_IDX_MASK = np.int64(0xFFFFFFFF)


def _check_points(points: np.ndarray, name: str = "points") -> np.ndarray:
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] < 4:
        raise ValueError(f"{name}: expected an (M, 4) array of x, y, z, cos(theta), got shape {pts.shape}")
    if pts.shape[0] >= 2**32:
        raise ValueError(f"{name}: too many points ({pts.shape[0]})")
    return pts


def _z_priority(z: np.ndarray) -> np.ndarray:
    """Per point: int64 that orders by float32 z first, then by point index (eq. (2): highest wins)."""
    bits = np.ascontiguousarray(z, dtype=np.float32).view(np.int32).astype(np.int64)
    # IEEE-754 -> monotone signed integer: negative floats have their magnitude bits reversed.
    mono = np.where(bits < 0, bits ^ np.int64(0x7FFFFFFF), bits)
    return (mono << np.int64(32)) | np.arange(z.shape[0], dtype=np.int64)


def _cells(points: np.ndarray, range_m: float, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (2)-(3) for every point: (keep mask, flat cell index i*S + j of the kept points)."""
    x = points[:, 0].astype(np.float64)
    y = points[:, 1].astype(np.float64)
    keep = (np.abs(x) <= range_m) & (np.abs(y) <= range_m) & np.isfinite(points[:, 2])  # NaN x/y fail the test too
    scale = (size - 1) / (2.0 * range_m)
    i = np.rint((x[keep] + range_m) * scale).astype(np.int64)
    j = np.rint((y[keep] + range_m) * scale).astype(np.int64)
    return keep, i * size + j


def _fill_neighbours(best: np.ndarray) -> np.ndarray:
    """8-neighbourhood filling on (..., S, S) priority grids; occupied cells are kept."""
    h, w = best.shape[-2:]
    pad = np.full(best.shape[:-2] + (h + 2, w + 2), _EMPTY, dtype=np.int64)
    pad[..., 1:-1, 1:-1] = best
    nb = np.full_like(best, _EMPTY)
    for di in (0, 1, 2):
        for dj in (0, 1, 2):
            if di == 1 and dj == 1:
                continue
            np.maximum(nb, pad[..., di:di + h, dj:dj + w], out=nb)
    return np.where(best != _EMPTY, best, nb)


def _render(best: np.ndarray, values: np.ndarray, fill: bool) -> np.ndarray:
    """Priority grid -> float32 value grid (0 where empty)."""
    if fill:
        best = _fill_neighbours(best)
    occupied = best != _EMPTY
    out = np.zeros(best.shape, dtype=np.float32)
    out[occupied] = values[best[occupied] & _IDX_MASK]
    return out


def _winners_1l(points: np.ndarray, range_m: float, size: int) -> np.ndarray:
    keep, cell = _cells(points, range_m, size)
    prio = _z_priority(points[:, 2])[keep]
    best = np.full(size * size, _EMPTY, dtype=np.int64)
    np.maximum.at(best, cell, prio)
    return best.reshape(size, size)


def topview_1l(points: np.ndarray, range_m: float = 32.0, size: int = 128, fill: bool = True) -> np.ndarray:
    """Eq. (2)-(4): one-layer top view, float32 (S, S).

    Cell value = cos(theta) of the highest point in the cell (all heights), 0 where empty;
    with ``fill`` the empty 8-neighbours of occupied cells take the value of the highest
    neighbouring point. Points outside +-``range_m`` in x or y are dropped.
    """
    pts = _check_points(points)
    values = pts[:, 3].astype(np.float32)
    return _render(_winners_1l(pts, range_m, size), values, fill)


def height_channel(z: np.ndarray, z_min: float = -2.0, z_max: float = 11.0, multiplier: int = 13) -> np.ndarray:
    """Eq. (5): k = rint((z - z_min) / (z_max - z_min) * multiplier); -1 for z outside [z_min, z_max]."""
    z = np.asarray(z, dtype=np.float64)
    k = np.rint((z - z_min) / (z_max - z_min) * multiplier).astype(np.int64)
    return np.where((z >= z_min) & (z <= z_max), k, -1)


def topview_15l(
    points: np.ndarray,
    range_m: float = 32.0,
    size: int = 128,
    z_min: float = -2.0,
    z_max: float = 11.0,
    multiplier: int = 13,
    fill: bool = True,
) -> np.ndarray:
    """Eq. (2)-(5): multi-layer top view, float32 (multiplier + 2, S, S) (15 channels in the paper).

    Channels 0..multiplier: the highest point of each (cell, height channel k) by eq. (5),
    points with z outside [z_min, z_max] dropped. Last channel: :func:`topview_1l`
    (all heights, exactly the 1-layer image). Neighbours are filled per channel.
    """
    pts = _check_points(points)
    values = pts[:, 3].astype(np.float32)
    n_layers = multiplier + 1
    keep, cell = _cells(pts, range_m, size)
    prio = _z_priority(pts[:, 2])[keep]
    k = height_channel(pts[keep, 2], z_min, z_max, multiplier)
    in_z = k >= 0
    best = np.full((n_layers + 1) * size * size, _EMPTY, dtype=np.int64)
    np.maximum.at(best, k[in_z] * (size * size) + cell[in_z], prio[in_z])
    np.maximum.at(best, n_layers * size * size + cell, prio)  # flattened layer = 1L image
    return _render(best.reshape(n_layers + 1, size, size), values, fill)


def ls_ground_truth(points: np.ndarray, tags: np.ndarray, range_m: float = 32.0, size: int = 128) -> np.ndarray:
    """LS ground truth on the eq. (2)-(3) grid: uint8 (S, S) class tag of the highest point per cell.

    255 where no point fell. Neighbours are deliberately NOT filled: the label says which
    class a LiDAR return actually hit, and LS is scored only where a point exists
    (section V-C: the target is the zero vector elsewhere). Points outside +-``range_m``
    are dropped. Tags must be in 0..254.
    """
    pts = _check_points(points)
    tags = np.asarray(tags)
    if tags.shape != (pts.shape[0],):
        raise ValueError(f"tags: expected shape ({pts.shape[0]},) to match the points, got {tags.shape}")
    if tags.size and (tags.min() < 0 or tags.max() > 254):
        raise ValueError(f"tags: values must be in 0..254 (255 = no point), got {tags.min()}..{tags.max()}")
    best = _winners_1l(pts, range_m, size)
    out = np.full((size, size), 255, dtype=np.uint8)
    occupied = best != _EMPTY
    out[occupied] = tags.astype(np.uint8)[best[occupied] & _IDX_MASK]
    return out
