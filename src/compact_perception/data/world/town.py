"""Procedural towns town01..town05 (SPEC 3.1, paper Table I / section IV-A).

A town is a Manhattan grid of roads. The flat ground (z = 0) is a metric class map
(``Town.ground``, CARLA tags, ``cell_m`` per cell) with painted road lines; everything
above the ground is an axis-aligned box (``Town.bmin``/``bmax``/``tag``/``color``).
Layouts are seeded by the town name only, so a town is the same map in every dataset
(as CARLA's maps are). The five styles differ in block size, road width, lane count,
building density/height, vegetation and which rarer classes (water, bridge, rail
track, guard rail, wall, fence) appear.
"""
from __future__ import annotations

import functools
import zlib
from dataclasses import dataclass, field

import numpy as np

from ...core.classes import CARLA_PALETTE, TAG

#: marking map values (``Town.marking``) used for the BEV lane / centreline masks
MARK_LANE, MARK_CENTRE, MARK_ROAD = 1, 2, 4  # bit 4: drivable road surface (BEV 'road')


@dataclass(frozen=True)
class TownStyle:
    """Layout knobs of one town."""

    n_blocks: int
    block_m: float
    lanes: int  # lanes per direction
    lane_w: float
    sidewalk_m: float
    bld_h: tuple[float, float]
    bld_density: float
    tree_density: float
    river_row: int | None = None  # block row replaced by a river (water + bridges)
    rail_row: int | None = None  # block row holding a rail track
    guard_rails: bool = False
    walls: float = 0.0  # probability a block is walled
    fences: float = 0.0  # probability a block is fenced
    park: float = 0.15  # probability a block is a park (terrain + trees)
    lot: float = 0.1  # probability a block is an unpaved lot (ground + props)


STYLES: dict[str, TownStyle] = {
    "town01": TownStyle(4, 60.0, 1, 3.5, 3.0, (5.0, 12.0), 0.75, 0.5, river_row=2, fences=0.4, park=0.2),
    "town02": TownStyle(5, 45.0, 1, 3.2, 2.5, (4.0, 9.0), 0.9, 0.3, walls=0.3, fences=0.3, lot=0.15),
    "town03": TownStyle(4, 80.0, 2, 3.5, 4.0, (10.0, 40.0), 0.9, 0.2, river_row=1, walls=0.25, park=0.1),
    "town04": TownStyle(3, 100.0, 2, 3.75, 0.0, (4.0, 8.0), 0.3, 0.7, rail_row=1, guard_rails=True, park=0.4, lot=0.2),
    "town05": TownStyle(4, 70.0, 2, 3.5, 3.0, (8.0, 25.0), 0.6, 0.35, rail_row=2, guard_rails=True, fences=0.3, walls=0.15),
}


@dataclass
class Town:
    """Static geometry of one town (world frame: x east, y north, z up, metres)."""

    name: str
    style: TownStyle
    size_m: float
    cell_m: float
    ground: np.ndarray  # (H, W) uint8 CARLA tag, index [ix, iy]
    marking: np.ndarray  # (H, W) uint8 MARK_* (BEV lanes / centrelines)
    road_pos: np.ndarray  # (n+1,) coordinate of road centrelines (same along x and y)
    road_w: float
    bmin: np.ndarray  # (N, 3) float32
    bmax: np.ndarray  # (N, 3) float32
    tag: np.ndarray  # (N,) uint8
    color: np.ndarray  # (N, 3) float32 albedo in [0, 1]
    lamps: np.ndarray  # (L, 2) street-lamp positions (night lighting)
    lights: list[dict] = field(default_factory=list)  # traffic lights: pos, axis, stop box, phase

    def ground_at(self, x: np.ndarray, y: np.ndarray, grid: np.ndarray | None = None, outside: int = TAG["terrain"]) -> np.ndarray:
        """Nearest-cell lookup of ``grid`` (default the class map) at world x, y."""
        g = self.ground if grid is None else grid
        ix = np.floor(x / self.cell_m).astype(np.int64)
        iy = np.floor(y / self.cell_m).astype(np.int64)
        ok = (ix >= 0) & (iy >= 0) & (ix < g.shape[0]) & (iy < g.shape[1])
        out = np.full(ix.shape, outside if grid is None else 0, dtype=g.dtype)
        out[ok] = g[ix[ok], iy[ok]]
        return out


class _Builder:
    """Collects boxes and paints the ground map."""

    def __init__(self, size: float, cell: float, rng: np.random.Generator) -> None:
        self.cell = cell
        n = int(np.ceil(size / cell))
        self.ground = np.full((n, n), TAG["terrain"], np.uint8)
        self.marking = np.zeros((n, n), np.uint8)
        self.boxes: list[tuple[float, float, float, float, float, float, int, tuple[float, float, float]]] = []
        self.rng = rng

    def paint(self, x0: float, x1: float, y0: float, y1: float, tag: int, grid: np.ndarray | None = None) -> None:
        g = self.ground if grid is None else grid
        i0, i1 = int(round(min(x0, x1) / self.cell)), int(round(max(x0, x1) / self.cell))
        j0, j1 = int(round(min(y0, y1) / self.cell)), int(round(max(y0, y1) / self.cell))
        i1, j1 = max(i1, i0 + 1), max(j1, j0 + 1)
        g[max(i0, 0):max(i1, 0), max(j0, 0):max(j1, 0)] = tag

    def box(self, x0: float, y0: float, z0: float, x1: float, y1: float, z1: float, tag: int, jitter: float = 0.12) -> None:
        base = CARLA_PALETTE[tag].astype(np.float64) / 255.0
        if tag in (TAG["building"], TAG["vehicle"], TAG["wall"], TAG["static"], TAG["dynamic"], TAG["other"]):
            base = np.clip(base * (1 + self.rng.uniform(-0.35, 0.35, 3)) + self.rng.uniform(-0.05, 0.1), 0.03, 1)
        else:
            base = np.clip(base * (1 + self.rng.uniform(-jitter, jitter, 3)), 0.02, 1)
        self.boxes.append((min(x0, x1), min(y0, y1), z0, max(x0, x1), max(y0, y1), z1, tag, tuple(base)))


def _hash_seed(name: str) -> int:
    return zlib.crc32(name.encode()) & 0x7FFFFFFF


def _paint_roads(b: "_Builder", st: TownStyle, road_pos: np.ndarray, hw: float, size: float) -> None:
    """The road grid: asphalt, centre and lane lines (dashed between lanes), edge lines and the
    zebra crossings before each intersection, painted into the ground and marking grids."""
    for c in road_pos:
        b.paint(0, size, c - hw, c + hw, TAG["road"])
        b.paint(c - hw, c + hw, 0, size, TAG["road"])
        b.paint(0, size, c - hw, c + hw, MARK_ROAD, grid=b.marking)
        b.paint(c - hw, c + hw, 0, size, MARK_ROAD, grid=b.marking)
    lw = 0.25
    for c in road_pos:
        for axis in (0, 1):
            # segments between intersections (no markings inside intersections)
            edges = np.concatenate([[0.0], np.ravel([[p - hw - 4.0, p + hw + 4.0] for p in road_pos]), [size]])
            for s0, s1 in zip(edges[0::2], edges[1::2]):
                if s1 - s0 < 1:
                    continue
                lines = [(c, MARK_CENTRE, False)]
                for k in range(1, st.lanes):
                    lines += [(c + k * st.lane_w, MARK_LANE, True), (c - k * st.lane_w, MARK_LANE, True)]
                lines += [(c + hw - 0.4, MARK_LANE, False), (c - hw + 0.4, MARK_LANE, False)]
                for off, mk, dashed in lines:
                    segs = [(s, min(s + 3.0, s1)) for s in np.arange(s0, s1, 6.0)] if dashed else [(s0, s1)]
                    for a0, a1 in segs:
                        r = (a0, a1, off - lw / 2, off + lw / 2) if axis == 0 else (off - lw / 2, off + lw / 2, a0, a1)
                        b.paint(*r, TAG["road line"])
                        b.paint(*r, mk | MARK_ROAD, grid=b.marking)
            # zebra crossings before each intersection
            for p in road_pos:
                for side in (-1, 1):
                    z0 = p + side * (hw + 1.0)
                    z1 = p + side * (hw + 3.5)
                    for k in np.arange(c - hw + 0.5, c + hw - 0.5, 1.0):
                        r = (z0, z1, k, k + 0.5) if axis == 0 else (k, k + 0.5, z0, z1)
                        b.paint(*r, TAG["road line"])


def _fill_blocks(b: "_Builder", st: TownStyle, road_pos: np.ndarray, hw: float, size: float,
                 rng: np.random.Generator) -> list[tuple[float, float]]:
    """Every block between the roads: river or rail rows, else sidewalk, then a park, a parking
    lot or buildings, and a wall or fence around it; returns the street lamps' positions."""
    lamps: list[tuple[float, float]] = []
    sw = st.sidewalk_m
    for bi in range(st.n_blocks):
        for bj in range(st.n_blocks):
            x0, x1 = road_pos[bi] + hw, road_pos[bi + 1] - hw
            y0, y1 = road_pos[bj] + hw, road_pos[bj + 1] - hw
            if st.river_row is not None and bj == st.river_row:
                _river_block(b, x0, x1, y0, y1, road_pos, hw, size, bi)
                continue
            if st.rail_row is not None and bj == st.rail_row:
                _rail_block(b, st, x0, x1, y0, y1)
                continue
            _sidewalk_and_edge(b, st, x0, x1, y0, y1, lamps)
            ix0, ix1, iy0, iy1 = x0 + max(sw, 1.5), x1 - max(sw, 1.5), y0 + max(sw, 1.5), y1 - max(sw, 1.5)
            u = rng.uniform()
            if u < st.park:
                _park_block(b, st, ix0, ix1, iy0, iy1)
            elif u < st.park + st.lot:
                _lot_block(b, ix0, ix1, iy0, iy1)
            else:
                _building_block(b, st, ix0, ix1, iy0, iy1)
            if rng.uniform() < st.walls:
                _perimeter(b, ix0, ix1, iy0, iy1, TAG["wall"], 0.3, rng.uniform(2.0, 3.0))
            elif rng.uniform() < st.fences:
                _perimeter(b, ix0, ix1, iy0, iy1, TAG["fence"], 0.1, rng.uniform(1.2, 1.8))
    return lamps


def _place_lights(b: "_Builder", inter: list[tuple[float, float]], hw: float,
                  rng: np.random.Generator) -> list[dict]:
    """At every intersection corner a traffic light (pole, head over the road edge, the stop zone
    of the lanes it controls, one phase per intersection) and, half the time, a sign."""
    lights: list[dict] = []
    for k, (cx, cy) in enumerate(inter):
        phase = int(rng.integers(0, 40))
        for sx, sy in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
            px, py = cx + sx * (hw + 1.0), cy + sy * (hw + 1.0)
            b.box(px - 0.12, py - 0.12, 0, px + 0.12, py + 0.12, 4.2, TAG["pole"])
            # head hangs over the road edge; controls traffic approaching along one axis
            axis = 0 if sx * sy > 0 else 1
            hx, hy = (px, py - sy * 1.2) if axis == 0 else (px - sx * 1.2, py)
            head = len(b.boxes)
            b.box(hx - 0.25, hy - 0.25, 3.4, hx + 0.25, hy + 0.25, 4.4, TAG["traffic light"])
            b.box(min(px, hx) - 0.06, min(py, hy) - 0.06, 4.1, max(px, hx) + 0.06, max(py, hy) + 0.06, 4.2, TAG["pole"])
            # stop zone: the lanes arriving at this corner's side, just before the crossing
            if axis == 0:  # traffic along x arriving from side sx, right-hand lanes at y on side -sx*... use sign of sy
                zx0, zx1 = cx + sx * (hw + 3.5), cx + sx * (hw + 6.0)
                zy0, zy1 = cy, cy + sy * hw
            else:
                zy0, zy1 = cy + sy * (hw + 3.5), cy + sy * (hw + 6.0)
                zx0, zx1 = cx, cx + sx * hw
            lights.append({"pos": (hx, hy), "axis": axis, "phase": phase, "box": head,
                           "zone": (min(zx0, zx1), max(zx0, zx1), min(zy0, zy1), max(zy0, zy1))})
            if rng.uniform() < 0.5:  # traffic sign on its own pole
                qx, qy = cx + sx * (hw + 2.2), cy + sy * (hw + 4.5)
                b.box(qx - 0.06, qy - 0.06, 0, qx + 0.06, qy + 0.06, 2.2, TAG["pole"])
                b.box(qx - 0.4, qy - 0.05, 2.0, qx + 0.4, qy + 0.05, 2.8, TAG["traffic sign"])
    return lights


@functools.lru_cache(maxsize=8)
def build_town(name: str, cell_m: float = 0.25) -> Town:
    """Build (and cache) the static geometry of ``name`` (town01..town05)."""
    if name not in STYLES:
        raise ValueError(f"unknown town {name!r}; known: {sorted(STYLES)}")
    st = STYLES[name]
    rng = np.random.default_rng(_hash_seed(name))
    road_w = 2 * st.lanes * st.lane_w
    margin = 30.0
    pitch = st.block_m + road_w
    road_pos = margin + road_w / 2 + np.arange(st.n_blocks + 1) * pitch
    size = float(road_pos[-1] + road_w / 2 + margin)
    b = _Builder(size, cell_m, rng)
    hw = road_w / 2
    _paint_roads(b, st, road_pos, hw, size)
    lamps = _fill_blocks(b, st, road_pos, hw, size, rng)
    inter = [(float(cx), float(cy)) for cx in road_pos for cy in road_pos]
    lights = _place_lights(b, inter, hw, rng)
    arr = np.array([bx[:6] for bx in b.boxes], dtype=np.float32)
    return Town(
        name=name, style=st, size_m=size, cell_m=cell_m, ground=b.ground, marking=b.marking,
        road_pos=road_pos, road_w=road_w, bmin=arr[:, :3].copy(), bmax=arr[:, 3:].copy(),
        tag=np.array([bx[6] for bx in b.boxes], np.uint8), color=np.array([bx[7] for bx in b.boxes], np.float32),
        lamps=np.array(lamps, np.float64).reshape(-1, 2), lights=lights,
    )


def _sidewalk_and_edge(b: _Builder, st: TownStyle, x0: float, x1: float, y0: float, y1: float, lamps: list) -> None:
    """Sidewalk ring (or a guard-railed terrain shoulder) with lamps, trees and street props."""
    rng, sw = b.rng, st.sidewalk_m
    if sw > 0:
        b.paint(x0, x1, y0, y1, TAG["sidewalk"])
    else:
        b.paint(x0, x1, y0, y1, TAG["terrain"])
        sw = 1.5
    b.paint(x0 + sw, x1 - sw, y0 + sw, y1 - sw, TAG["ground"])
    if st.guard_rails:
        g = 0.3 if st.sidewalk_m == 0 else 0.0
        if g or rng.uniform() < 0.5:
            for (a0, a1, c, ax) in ((x0 + 3, x1 - 3, y0 + g, 0), (x0 + 3, x1 - 3, y1 - g - 0.2, 0),
                                    (y0 + 3, y1 - 3, x0 + g, 1), (y0 + 3, y1 - 3, x1 - g - 0.2, 1)):
                if ax == 0:
                    b.box(a0, c, 0.3, a1, c + 0.2, 0.8, TAG["guard rail"])
                else:
                    b.box(c, a0, 0.3, c + 0.2, a1, 0.8, TAG["guard rail"])
    # lamps / trees / props along the four sides
    for side in range(4):
        length = (x1 - x0) if side < 2 else (y1 - y0)
        for s in np.arange(8.0, length - 6.0, 4.0):
            if side == 0:
                px, py = x0 + s, y0 + sw * 0.5
            elif side == 1:
                px, py = x0 + s, y1 - sw * 0.5
            elif side == 2:
                px, py = x0 + sw * 0.5, y0 + s
            else:
                px, py = x1 - sw * 0.5, y0 + s
            u = rng.uniform()
            if s % 24 < 4:  # street lamp every 24 m
                b.box(px - 0.1, py - 0.1, 0, px + 0.1, py + 0.1, 6.0, TAG["pole"])
                lamps.append((px, py))
            elif u < st.tree_density * 0.35:
                _tree(b, px, py)
            elif u < st.tree_density * 0.35 + 0.08:
                _prop(b, px, py)


def _tree(b: _Builder, x: float, y: float, scale: float = 1.0) -> None:
    r = b.rng.uniform(1.0, 2.0) * scale
    h = b.rng.uniform(2.0, 3.5) * scale
    b.box(x - 0.18, y - 0.18, 0, x + 0.18, y + 0.18, h, TAG["vegetation"])
    b.box(x - r, y - r, h, x + r, y + r, h + b.rng.uniform(2.0, 4.0) * scale, TAG["vegetation"])


def _prop(b: _Builder, x: float, y: float) -> None:
    """Street furniture: static (bench, shelter), dynamic (bin, cart), other (kiosk, box)."""
    k = b.rng.integers(0, 3)
    if k == 0:
        w = b.rng.uniform(0.5, 1.6)
        b.box(x - w, y - 0.3, 0, x + w, y + 0.3, b.rng.uniform(0.5, 2.4), TAG["static"])
    elif k == 1:
        b.box(x - 0.35, y - 0.35, 0, x + 0.35, y + 0.35, 1.0, TAG["dynamic"])
    else:
        b.box(x - 0.5, y - 0.5, 0, x + 0.5, y + 0.5, b.rng.uniform(1.0, 2.0), TAG["other"])


def _building_block(b: _Builder, st: TownStyle, x0: float, x1: float, y0: float, y1: float) -> None:
    rng = b.rng
    depth = min(18.0, (y1 - y0) / 2 - 1, (x1 - x0) / 2 - 1)
    for side in range(4):
        s = 0.0
        length = (x1 - x0) if side < 2 else (y1 - y0) - 2 * depth
        while s < length - 4:
            w = min(rng.uniform(8.0, 22.0), length - s)
            if rng.uniform() < st.bld_density:
                d = rng.uniform(0.6, 1.0) * depth
                h = rng.uniform(*st.bld_h)
                if side == 0:
                    b.box(x0 + s, y0, 0, x0 + s + w, y0 + d, h, TAG["building"])
                elif side == 1:
                    b.box(x0 + s, y1 - d, 0, x0 + s + w, y1, h, TAG["building"])
                elif side == 2:
                    b.box(x0, y0 + depth + s, 0, x0 + d, y0 + depth + s + w, h, TAG["building"])
                else:
                    b.box(x1 - d, y0 + depth + s, 0, x1, y0 + depth + s + w, h, TAG["building"])
            elif rng.uniform() < 0.5:
                cx, cy = ((x0 + s + w / 2, y0 + 3) if side == 0 else (x0 + s + w / 2, y1 - 3) if side == 1
                          else (x0 + 3, y0 + depth + s + w / 2) if side == 2 else (x1 - 3, y0 + depth + s + w / 2))
                _tree(b, cx, cy)
            s += w + rng.uniform(0.0, 3.0)
    b.paint(x0 + depth, x1 - depth, y0 + depth, y1 - depth, TAG["terrain"])


def _park_block(b: _Builder, st: TownStyle, x0: float, x1: float, y0: float, y1: float) -> None:
    rng = b.rng
    b.paint(x0, x1, y0, y1, TAG["terrain"])
    n = int((x1 - x0) * (y1 - y0) / 120 * st.tree_density) + 2
    for _ in range(n):
        _tree(b, rng.uniform(x0 + 2, x1 - 2), rng.uniform(y0 + 2, y1 - 2), rng.uniform(0.8, 1.4))
    for _ in range(3):  # hedges
        hx = rng.uniform(x0 + 2, x1 - 10)
        hy = rng.uniform(y0 + 2, y1 - 2)
        b.box(hx, hy, 0, hx + rng.uniform(4, 9), hy + 1.0, 1.2, TAG["vegetation"])
    for _ in range(2):
        _prop(b, rng.uniform(x0 + 2, x1 - 2), rng.uniform(y0 + 2, y1 - 2))


def _lot_block(b: _Builder, x0: float, x1: float, y0: float, y1: float) -> None:
    rng = b.rng
    b.paint(x0, x1, y0, y1, TAG["ground"])
    for _ in range(int((x1 - x0) * (y1 - y0) / 150) + 3):
        _prop(b, rng.uniform(x0 + 1, x1 - 1), rng.uniform(y0 + 1, y1 - 1))
    kx, ky = rng.uniform(x0 + 3, x1 - 8), rng.uniform(y0 + 3, y1 - 8)
    b.box(kx, ky, 0, kx + rng.uniform(3, 6), ky + rng.uniform(3, 6), rng.uniform(2.5, 3.5), TAG["other"])


def _perimeter(b: _Builder, x0: float, x1: float, y0: float, y1: float, tag: int, t: float, h: float) -> None:
    """Fence/wall around a block interior with gaps (gates)."""
    for a0, a1, c, ax in ((x0, x1, y0, 0), (x0, x1, y1 - t, 0), (y0, y1, x0, 1), (y0, y1, x1 - t, 1)):
        for s in np.arange(a0, a1, 12.0):
            e = min(s + 10.0, a1)
            if ax == 0:
                b.box(s, c, 0, e, c + t, h, tag)
            else:
                b.box(c, s, 0, c + t, e, h, tag)


def _river_block(b: _Builder, x0: float, x1: float, y0: float, y1: float, road_pos: np.ndarray, hw: float, size: float, bi: int) -> None:
    """A river along x filling the block row; roads crossing it are bridges (parapets, trusses)."""
    b.paint(x0 - hw - 0.01, x1 + hw + 0.01, y0 + 3, y1 - 3, TAG["water"])
    b.paint(x0, x1, y0, y0 + 3, TAG["terrain"])
    b.paint(x0, x1, y1 - 3, y1, TAG["terrain"])
    if bi == 0:  # water also beyond the town edges
        b.paint(0, x0, y0 + 3, y1 - 3, TAG["water"])
    b.box(x0, y0 + 2.6, 0, x1, y0 + 2.7, 1.3, TAG["fence"])
    b.box(x0, y1 - 2.7, 0, x1, y1 - 2.6, 1.3, TAG["fence"])
    for c in (road_pos[bi], road_pos[bi + 1]):
        b.paint(c - hw, c + hw, y0 + 3, y1 - 3, TAG["road"])
        for sx in (-1, 1):
            xe = c + sx * (hw + 0.35)
            b.box(xe - 0.35, y0, 0, xe + 0.35, y1, 1.2, TAG["bridge"])  # parapets
        for yy in np.arange(y0 + 6, y1 - 4, 8.0):  # overhead truss beams
            b.box(c - hw - 0.7, yy, 5.5, c + hw + 0.7, yy + 0.6, 6.3, TAG["bridge"])
            for sx in (-1, 1):
                xe = c + sx * (hw + 0.35)
                b.box(xe - 0.3, yy, 1.2, xe + 0.3, yy + 0.6, 6.3, TAG["bridge"])


def _rail_block(b: _Builder, st: TownStyle, x0: float, x1: float, y0: float, y1: float) -> None:
    """Rail corridor: two tracks along x on gravel ground, fenced, with catenary poles."""
    b.paint(x0, x1, y0, y1, TAG["terrain"])
    cy = y0 + 11.0  # close to the road so the LiDAR and cameras see it
    hw = st.lanes * st.lane_w
    b.paint(x0, x1, cy - 6, cy + 6, TAG["ground"])
    for off in (-2.5, 2.5):
        # tracks continue over the crossing roads (level crossings)
        b.paint(x0 - hw, x1 + hw, cy + off - 1.2, cy + off + 1.2, TAG["rail track"])
        b.box(x0, cy + off - 0.8, 0, x1, cy + off - 0.7, 0.18, TAG["rail track"])
        b.box(x0, cy + off + 0.7, 0, x1, cy + off + 0.8, 0.18, TAG["rail track"])
    for xx in np.arange(x0 + 5, x1 - 2, 20.0):
        b.box(xx - 0.15, cy - 0.15, 0, xx + 0.15, cy + 0.15, 6.5, TAG["pole"])
    b.box(x0, cy + 7.0, 0, x1, cy + 7.1, 1.6, TAG["fence"])  # fenced on the far side only
    if st.guard_rails:
        b.box(x0, y0 + 0.3, 0.3, x1, y0 + 0.5, 0.8, TAG["guard rail"])
        b.box(x0, y1 - 0.5, 0.3, x1, y1 - 0.3, 0.8, TAG["guard rail"])
    rng = b.rng
    for _ in range(4):
        _tree(b, rng.uniform(x0 + 2, x1 - 2), rng.choice([y0 + 3, y1 - 3]))
