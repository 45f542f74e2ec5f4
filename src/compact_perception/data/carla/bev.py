"""BEV ground truth of a CARLA frame (paper Table I, SPEC 3.1): the 9 masks of ``BEV_NAMES``
from the map's waypoints and the world's actors, on the top-view grid of
:mod:`compact_perception.data.geometry` (row i ~ ego x forward, column j ~ ego y left, +-R m).

Two steps, so the rasterisation runs and is tested without a server:

1. :func:`map_layers` (once per town) and :func:`actor_layers` (every frame) read duck-typed
   CARLA objects (``carla.Map``, ``carla.Waypoint``, ``carla.Actor``) into oriented rectangles
   ``(cx, cy, yaw, length, width)`` in the project's right-handed world (CARLA's y and yaw
   change sign, :func:`convert.right_handed_pose`):
   - road: one rectangle per driving-lane waypoint (``spacing`` long, ``lane_width`` wide);
   - road lane / road centreline: a thin rectangle along each painted lane marking, at half the
     lane width to the waypoint's left or right; a marking is the centreline when it is yellow
     or the lane beyond it runs the other way (lane ids of opposite sign);
   - other vehicles, pedestrians: each actor's bounding box (the ego's own box is the ego layer);
   - green / yellow / red traffic light: a 2 m stretch of lane at each stop waypoint of a light,
     in the light's current state.
2. :func:`rasterise` fills a cell whose centre lies in a rectangle; every layer but the road is
   grown by half a cell so thin markings and small actors never vanish.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Iterable

import numpy as np

from ...core.classes import BEV_NAMES
from ..geometry import topview_cell_centres, topview_index
from .convert import right_handed_pose

B = {n: i for i, n in enumerate(BEV_NAMES)}
#: painted line width (m) of a lane marking
MARKING_WIDTH_M = 0.3
#: length (m) of lane a traffic light's stop waypoint marks
STOP_ZONE_M = 2.0
_LIGHTS = {"Green": "green traffic light", "Yellow": "yellow traffic light", "Red": "red traffic light"}


def _name(enum_value: Any) -> str:
    """The name of a CARLA enum value (``carla.LaneType.Driving`` -> 'Driving'), or of a fake's string."""
    return str(getattr(enum_value, "name", enum_value)).split(".")[-1]


@dataclass
class Layers:
    """Rectangles (cx, cy, yaw, length, width) per BEV class, right-handed world frame."""

    rects: dict[str, list[tuple[float, float, float, float, float]]] = field(
        default_factory=lambda: {n: [] for n in BEV_NAMES})

    def add(self, name: str, cx: float, cy: float, yaw: float, length: float, width: float) -> None:
        self.rects[name].append((float(cx), float(cy), float(yaw), float(length), float(width)))

    def merged(self, other: "Layers") -> "Layers":
        out = Layers()
        for n in BEV_NAMES:
            out.rects[n] = self.rects[n] + other.rects[n]
        return out


def _pose(transform: Any) -> np.ndarray:
    return right_handed_pose(transform.location.x, transform.location.y, transform.rotation.yaw)


def map_layers(waypoints: Iterable[Any], spacing: float) -> Layers:
    """Road, lane markings and centreline from a map's waypoints (``Map.generate_waypoints(spacing)``)."""
    out = Layers()
    for wp in waypoints:
        if _name(wp.lane_type) != "Driving":
            continue
        x, y, yaw = _pose(wp.transform)
        w = float(wp.lane_width)
        out.add("road", x, y, yaw, spacing * 1.25, w)
        left = np.array([-np.sin(yaw), np.cos(yaw)])
        for side, marking, neighbour in ((1.0, wp.left_lane_marking, "get_left_lane"),
                                         (-1.0, wp.right_lane_marking, "get_right_lane")):
            if marking is None or _name(marking.type) in ("NONE", "Other"):
                continue
            other = getattr(wp, neighbour)()
            opposite = other is not None and int(other.lane_id) * int(wp.lane_id) < 0
            kind = "road centreline" if opposite or _name(marking.color) == "Yellow" else "road lane"
            mx, my = np.array([x, y]) + side * (w / 2.0) * left
            out.add(kind, mx, my, yaw, spacing * 1.25, MARKING_WIDTH_M)
    return out


def _box(actor: Any) -> tuple[float, float, float, float, float, float, float]:
    """(cx, cy, cz, length, width, height, yaw) of an actor's bounding box, right-handed world."""
    tr, bb = actor.get_transform(), actor.bounding_box
    yaw_deg = tr.rotation.yaw
    c, s = np.cos(np.deg2rad(yaw_deg)), np.sin(np.deg2rad(yaw_deg))
    bx, by = bb.location.x, bb.location.y
    cx, cy = tr.location.x + c * bx - s * by, tr.location.y + s * bx + c * by  # CARLA coordinates
    x, y, yaw = right_handed_pose(cx, cy, yaw_deg)
    return x, y, tr.location.z + bb.location.z, 2 * bb.extent.x, 2 * bb.extent.y, 2 * bb.extent.z, yaw


def actor_layers(vehicles: Iterable[Any], walkers: Iterable[Any], lights: Iterable[Any], ego: Any) -> Layers:
    """Other vehicles, the ego, pedestrians and traffic-light states of one frame."""
    out = Layers()
    for a in vehicles:
        x, y, _, L, W, _, yaw = _box(a)
        out.add("ego vehicle" if a.id == ego.id else "other vehicles", x, y, yaw, L, W)
    for a in walkers:
        x, y, _, L, W, _, yaw = _box(a)
        out.add("pedestrian", x, y, yaw, L, W)
    for tl in lights:
        name = _LIGHTS.get(_name(tl.get_state()))
        if name is None:  # Off or Unknown
            continue
        stops = getattr(tl, "get_stop_waypoints", None)  # client 0.9.11+; without it no light is drawn
        for wp in (stops() if stops else []):
            x, y, yaw = _pose(wp.transform)
            out.add(name, x, y, yaw, STOP_ZONE_M, float(wp.lane_width))
    return out


def boxes_in_ego(vehicles: Iterable[Any], walkers: Iterable[Any], ego: Any, ego_pose: np.ndarray,
                 lidar_z: float, range_m: float, tags: tuple[int, int]) -> np.ndarray:
    """float32 (K, 8) x, y, z (centre), length, width, height, yaw, tag of the actors near the
    ego, in the ego/LiDAR frame (``lidar_z``: the LiDAR's world height). ``tags`` = (vehicle, pedestrian)."""
    rows = []
    ex, ey, eyaw = ego_pose
    c, s = np.cos(eyaw), np.sin(eyaw)
    for group, tag in ((vehicles, tags[0]), (walkers, tags[1])):
        for a in group:
            if a.id == ego.id:
                continue
            x, y, z, L, W, H, yaw = _box(a)
            dx, dy = x - ex, y - ey
            u, v = c * dx + s * dy, -s * dx + c * dy
            if abs(u) <= range_m + 5 and abs(v) <= range_m + 5:
                rows.append((u, v, z - lidar_z, L, W, H, (yaw - eyaw + np.pi) % (2 * np.pi) - np.pi, tag))
    return np.array(rows, np.float32).reshape(-1, 8)


def _fill(mask: np.ndarray, rects: np.ndarray, cc: np.ndarray, range_m: float, grow: float) -> None:
    size = mask.shape[0]
    for cx, cy, yaw, L, W in rects:
        hl, hw = L / 2 + grow, W / 2 + grow
        r = float(np.hypot(hl, hw))
        i0, i1 = np.clip(topview_index(np.array([cx - r, cx + r]), range_m, size), 0, size - 1)
        j0, j1 = np.clip(topview_index(np.array([cy - r, cy + r]), range_m, size), 0, size - 1)
        X, Y = cc[i0:i1 + 1, None] - cx, cc[None, j0:j1 + 1] - cy
        c, s = np.cos(yaw), np.sin(yaw)
        mask[i0:i1 + 1, j0:j1 + 1] |= (np.abs(c * X + s * Y) <= hl) & (np.abs(-s * X + c * Y) <= hw)


def rasterise(layers: Layers, ego_pose: np.ndarray, range_m: float, size: int) -> np.ndarray:
    """uint8 (9, S, S) masks in ``BEV_NAMES`` order around ``ego_pose`` (x, y, yaw; right-handed world)."""
    cc = topview_cell_centres(range_m, size)
    half = range_m / (size - 1)  # half a cell
    ex, ey, eyaw = (float(v) for v in ego_pose)
    c, s = np.cos(eyaw), np.sin(eyaw)
    out = np.zeros((len(BEV_NAMES), size, size), bool)
    for name, rects in layers.rects.items():
        if not rects:
            continue
        r = np.asarray(rects, np.float64)
        dx, dy = r[:, 0] - ex, r[:, 1] - ey
        ego = np.stack([c * dx + s * dy, -s * dx + c * dy, r[:, 2] - eyaw, r[:, 3], r[:, 4]], 1)
        reach = range_m + np.hypot(r[:, 3], r[:, 4]) / 2 + half
        ego = ego[(np.abs(ego[:, 0]) <= reach) & (np.abs(ego[:, 1]) <= reach)]
        _fill(out[B[name]], ego, cc, range_m, 0.0 if name == "road" else half)
    return out.astype(np.uint8)
