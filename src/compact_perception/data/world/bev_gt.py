"""BEV ground truth (paper Table I, SPEC 3.1): 9 multi-label masks on the top-view grid.

Grid of geometry.py (eq. 2-3): row i ~ ego x (forward), column j ~ ego y (left), +-R m,
ego at ``topview_center(S)``. Ground classes are supersampled 3x3 per cell ("any" for lane
and centre markings, centre sample for road); actors and the ego are footprints tested at
cell centres with extents grown by half a cell so small actors never vanish.
"""
from __future__ import annotations

import numpy as np

from ...core.classes import BEV_NAMES, TAG
from ..geometry import topview_cell_centres
from .actors import EGO_SIZE, ActorState
from .town import MARK_CENTRE, MARK_LANE, MARK_ROAD, Town

B = {n: i for i, n in enumerate(BEV_NAMES)}


def _to_world(ego: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c, s = np.cos(ego[2]), np.sin(ego[2])
    return ego[0] + c * x - s * y, ego[1] + s * x + c * y


def _footprint(mask: np.ndarray, X: np.ndarray, Y: np.ndarray, cx: float, cy: float, yaw: float, L: float, W: float, grow: float) -> None:
    c, s = np.cos(yaw), np.sin(yaw)
    dx, dy = X - cx, Y - cy
    u, v = c * dx + s * dy, -s * dx + c * dy
    mask |= (np.abs(u) <= L / 2 + grow) & (np.abs(v) <= W / 2 + grow)


def bev_masks(town: Town, st: ActorState, range_m: float, size: int) -> np.ndarray:
    """uint8 (9, S, S) masks in BEV_NAMES order."""
    cc = topview_cell_centres(range_m, size)
    cell = 2 * range_m / (size - 1)
    out = np.zeros((len(BEV_NAMES), size, size), bool)
    X, Y = np.meshgrid(cc, cc, indexing="ij")  # ego-frame x (rows), y (cols)
    offs = (np.arange(3) - 1) * cell / 3
    for ox in offs:
        for oy in offs:
            wx, wy = _to_world(st.ego, X + ox, Y + oy)
            mk = town.ground_at(wx, wy, grid=town.marking)
            out[B["road lane"]] |= (mk & 3) == MARK_LANE
            out[B["road centreline"]] |= (mk & 3) == MARK_CENTRE
            if ox == 0 and oy == 0:
                out[B["road"]] = (mk & MARK_ROAD) > 0
    half = cell / 2
    ex, ey = st.ego[0], st.ego[1]
    WX, WY = _to_world(st.ego, X, Y)
    for (cx, cy, _, L, W, _, yaw), tag in zip(st.boxes, st.tag):
        if abs(cx - ex) > range_m * 1.5 + L or abs(cy - ey) > range_m * 1.5 + L:
            continue
        k = B["pedestrian"] if tag == TAG["pedestrian"] else B["other vehicles"]
        _footprint(out[k], WX, WY, cx, cy, yaw, L, W, half)
    _footprint(out[B["ego vehicle"]], X, Y, 0.0, 0.0, 0.0, EGO_SIZE[0], EGO_SIZE[1], half)
    names = ("green traffic light", "yellow traffic light", "red traffic light")
    for L_, s in zip(town.lights, st.light_state):
        x0, x1, y0, y1 = L_["zone"]
        if abs((x0 + x1) / 2 - ex) > range_m * 1.5 or abs((y0 + y1) / 2 - ey) > range_m * 1.5:
            continue
        out[B[names[s]]] |= (WX >= x0 - half) & (WX <= x1 + half) & (WY >= y0 - half) & (WY <= y1 + half)
    return out.astype(np.uint8)
