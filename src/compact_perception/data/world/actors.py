"""Actors of an episode (SPEC 3.1): the ego route, other vehicles, pedestrians, traffic lights.

Everything is a pure function of (town, episode seed, step), so any step of an episode
can be rendered on its own (the previous step for DVS included). One step is
``DvsParams.step_s`` (0.1 s); the ego drives ~1 m per step (36 km/h).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...core.classes import TAG
from .town import Town

EGO_SIZE = (4.6, 1.9, 1.5)  # length, width, height
EGO_STEP_M = 1.0
#: name -> (length, width, height, metres per step)
VEHICLE_TYPES: dict[str, tuple[float, float, float, float]] = {
    "car": (4.5, 1.9, 1.5, 1.0),
    "truck": (8.0, 2.5, 3.3, 0.8),
    "bicycle": (1.8, 0.6, 1.7, 0.45),
    "motorbike": (2.2, 0.8, 1.5, 1.1),
}
PED_SIZE = (0.5, 0.5, 1.75)
#: traffic light cycle in steps: green, yellow, red (red = green + yellow of the cross axis)
LIGHT_CYCLE = (16, 4)


@dataclass
class ActorState:
    """Dynamic geometry at one step (world frame)."""

    ego: np.ndarray  # (3,) x, y, yaw of the ego (LiDAR origin)
    boxes: np.ndarray  # (K, 7) cx, cy, cz, length, width, height, yaw
    tag: np.ndarray  # (K,) uint8 CARLA tag
    color: np.ndarray  # (K, 3) float32 albedo
    light_state: np.ndarray  # (n_lights,) 0 green, 1 yellow, 2 red


class Episode:
    """Route and actor population of one episode (seeded)."""

    def __init__(self, town: Town, seed: int) -> None:
        self.town = town
        rng = np.random.default_rng(seed)
        self.seed = seed
        self._route(rng)
        self._population(rng)

    # ------------------------------------------------------------------ ego route
    def _route(self, rng: np.random.Generator) -> None:
        t = self.town
        n = len(t.road_pos)
        lane_off = t.style.lane_w * (0.5 if t.style.lanes == 1 else 1.5) if t.style.lanes > 1 else t.style.lane_w * 0.5
        dirs = [(1, 0), (0, 1), (-1, 0), (0, -1)]
        i, j = int(rng.integers(1, n - 1)), int(rng.integers(1, n - 1))
        d = int(rng.integers(0, 4))
        nodes, headings = [(i, j)], []
        for _ in range(60):
            opts = []
            for turn, w in ((0, 0.6), (1, 0.2), (-1, 0.2)):
                nd = (d + turn) % 4
                ni, nj = i + dirs[nd][0], j + dirs[nd][1]
                if 0 <= ni < n and 0 <= nj < n:
                    opts.append((nd, w))
            ws = np.array([w for _, w in opts])
            d = opts[int(rng.choice(len(opts), p=ws / ws.sum()))][0]
            i, j = i + dirs[d][0], j + dirs[d][1]
            nodes.append((i, j))
            headings.append(d)
        pts = []
        for k, (ni, nj) in enumerate(nodes):
            c = np.array([t.road_pos[ni], t.road_pos[nj]])
            off = np.zeros(2)
            for h in {headings[max(k - 1, 0)], headings[min(k, len(headings) - 1)]}:
                dx, dy = dirs[h]
                off += np.array([dy, -dx]) * lane_off  # right-hand traffic: lane right of the heading
            pts.append(c + off)
        pts = np.array(pts)
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        self.route_pts = pts
        self.route_s = np.concatenate([[0.0], np.cumsum(seg)])
        self.s0 = float(seg[0] * rng.uniform(0.3, 0.6))

    def _route_xy(self, s: np.ndarray) -> np.ndarray:
        s = np.clip(s, 0, self.route_s[-1])
        return np.stack([np.interp(s, self.route_s, self.route_pts[:, 0]), np.interp(s, self.route_s, self.route_pts[:, 1])], -1)

    def ego_pose(self, step: int) -> np.ndarray:
        """World (x, y, yaw) of the ego at ``step``; yaw smoothed over +-4 m around corners."""
        s = self.s0 + step * EGO_STEP_M
        p = self._route_xy(np.array([s, s - 4.0, s + 4.0]))
        d = p[2] - p[1]
        return np.array([p[0, 0], p[0, 1], np.arctan2(d[1], d[0])])

    # ------------------------------------------------------------------ population
    def _population(self, rng: np.random.Generator) -> None:
        t = self.town
        st = t.style
        names = list(VEHICLE_TYPES)
        veh = []  # axis, road coord, lane offset, direction, s0, type
        for axis in (0, 1):
            for c in t.road_pos:
                for lane in range(st.lanes):
                    for direction in (1, -1):
                        off = -direction * (lane + 0.5) * st.lane_w
                        if axis == 1:
                            off = -off
                        for _ in range(int(rng.poisson(t.size_m / 90.0))):
                            kind = names[int(rng.choice(4, p=[0.65, 0.15, 0.1, 0.1]))]
                            veh.append((axis, c + off, direction, rng.uniform(0, t.size_m), kind))
        self.vehicles = veh
        self.veh_color = rng.uniform(0.05, 0.9, (len(veh), 3)).astype(np.float32)
        peds = []  # axis, coord, direction, s0, speed, crossing?
        hw = t.road_w / 2
        sw = max(st.sidewalk_m, 1.5)
        for axis in (0, 1):
            for c in t.road_pos:
                for side in (-1, 1):
                    for _ in range(int(rng.poisson(t.size_m / 40.0))):
                        peds.append((axis, c + side * (hw + sw * 0.5), int(rng.choice([-1, 1])), rng.uniform(0, t.size_m), rng.uniform(0.1, 0.18), None))
        # pedestrians walking back and forth over zebra crossings
        for cx in t.road_pos:
            for cy in t.road_pos:
                if rng.uniform() < 0.35:
                    axis = int(rng.integers(0, 2))
                    side = int(rng.choice([-1, 1]))
                    at = (cx if axis == 0 else cy) + side * (hw + 2.2)
                    peds.append((axis, at, 1, rng.uniform(0, 4 * hw), 0.14, (cy if axis == 0 else cx)))
        self.peds = peds
        self.ped_color = rng.uniform(0.1, 0.9, (len(peds), 3)).astype(np.float32)

    def light_states(self, step: int) -> np.ndarray:
        """0 green / 1 yellow / 2 red for every traffic light; cross axes alternate."""
        g, y = LIGHT_CYCLE
        cyc = 2 * (g + y)
        out = np.empty(len(self.town.lights), np.uint8)
        for k, L in enumerate(self.town.lights):
            ph = (step + L["phase"] + self.seed % cyc + L["axis"] * (g + y)) % cyc
            out[k] = 0 if ph < g else 1 if ph < g + y else 2
        return out

    def state(self, step: int) -> ActorState:
        """All dynamic boxes at ``step`` (vehicles within ~5 m of the ego are dropped)."""
        t = self.town
        ego = self.ego_pose(step)
        rows, tags, cols = [], [], []
        for k, (axis, coord, direction, s0, kind) in enumerate(self.vehicles):
            L, W, H, v = VEHICLE_TYPES[kind]
            s = (s0 + direction * v * step) % t.size_m
            x, y = (s, coord) if axis == 0 else (coord, s)
            yaw = (0.0 if direction > 0 else np.pi) if axis == 0 else (np.pi / 2 if direction > 0 else -np.pi / 2)
            if abs(x - ego[0]) < L / 2 + 4.0 and abs(y - ego[1]) < L / 2 + 4.0:
                continue
            rows.append((x, y, H / 2, L, W, H, yaw))
            tags.append(TAG["vehicle"])
            cols.append(self.veh_color[k])
        hw = t.road_w / 2
        for k, (axis, coord, direction, s0, v, cross) in enumerate(self.peds):
            if cross is None:
                s = (s0 + direction * v * step) % t.size_m
                x, y = (s, coord) if axis == 0 else (coord, s)
            else:  # ping-pong over the crossing
                span = 2 * hw + 4.0
                u = (s0 + v * step) % (2 * span)
                off = (u if u < span else 2 * span - u) - span / 2
                x, y = (coord, cross + off) if axis == 0 else (cross + off, coord)
            if abs(x - ego[0]) < 3.0 and abs(y - ego[1]) < 3.0:
                continue
            rows.append((x, y, PED_SIZE[2] / 2, *PED_SIZE, 0.0))
            tags.append(TAG["pedestrian"])
            cols.append(self.ped_color[k])
        boxes = np.array(rows, np.float64).reshape(-1, 7)
        return ActorState(ego=ego, boxes=boxes, tag=np.array(tags, np.uint8),
                          color=np.array(cols, np.float32).reshape(-1, 3), light_state=self.light_states(step))


def boxes_to_aabb(boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(K, 7) oriented boxes -> axis-aligned min/max corners (exact for yaw multiple of 90 deg)."""
    c, s = np.abs(np.cos(boxes[:, 6])), np.abs(np.sin(boxes[:, 6]))
    hx = (boxes[:, 3] * c + boxes[:, 4] * s) / 2
    hy = (boxes[:, 3] * s + boxes[:, 4] * c) / 2
    half = np.stack([hx, hy, boxes[:, 5] / 2], -1)
    return (boxes[:, :3] - half).astype(np.float32), (boxes[:, :3] + half).astype(np.float32)
