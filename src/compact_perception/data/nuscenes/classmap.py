"""Class mappings into the 32 nuScenes-lidarseg classes (``classes.NUSCENES_NAMES`` order).

Point / pixel classes (CARLA 0.9.10 tag -> lidarseg index), chosen by meaning:

==================  =====================================  ==================================
CARLA tag            lidarseg class                          note
==================  =====================================  ==================================
unlabeled, sky       0 noise                                 sky is never hit by the LiDAR
building, fence,     28 static.manmade                       nuScenes puts buildings, walls,
wall, pole, bridge,                                          poles, signs, guard rails and
traffic sign,                                                traffic lights in static.manmade
traffic light,
guard rail
other, static        29 static.other
pedestrian           2 human.pedestrian.adult                refined by the actor box (below)
vehicle              17 vehicle.car                          refined by the actor box (below)
road, road line      24 flat.driveable_surface               lane markings are road surface
sidewalk             26 flat.sidewalk
ground, rail track,  25 flat.other
water
terrain              27 flat.terrain
vegetation           30 static.vegetation
dynamic              11 movable_object.pushable_pullable     CARLA "dynamic": movable props
==================  =====================================  ==================================

Actors (annotation boxes, ``boxes`` rows x, y, z, length, width, height, yaw, tag) get a
nuScenes category from their tag and size: pedestrians -> ``human.pedestrian.adult``; vehicles
by length (the world's sizes: bicycle, motorbike, car, truck) -> ``vehicle.bicycle``
(< 2.0 m), ``vehicle.motorcycle`` (< 2.6 m), ``vehicle.car`` (<= 5.5 m), ``vehicle.truck``
(> 5.5 m). LiDAR points tagged vehicle/pedestrian that fall inside an actor box take that box's
class, so a truck's points are labelled ``vehicle.truck`` like in nuScenes-lidarseg.
"""
from __future__ import annotations

import numpy as np

from compact_perception.core.classes import CARLA_NAMES, NUSCENES_NAMES, TAG

NUSCENES_INDEX: dict[str, int] = {n: i for i, n in enumerate(NUSCENES_NAMES)}

_CARLA_TO_NUSCENES_NAMES: dict[str, str] = {
    "unlabeled": "noise",
    "building": "static.manmade",
    "fence": "static.manmade",
    "other": "static.other",
    "pedestrian": "human.pedestrian.adult",
    "pole": "static.manmade",
    "road line": "flat.driveable_surface",
    "road": "flat.driveable_surface",
    "sidewalk": "flat.sidewalk",
    "vegetation": "static.vegetation",
    "vehicle": "vehicle.car",
    "wall": "static.manmade",
    "traffic sign": "static.manmade",
    "sky": "noise",
    "ground": "flat.other",
    "bridge": "static.manmade",
    "rail track": "flat.other",
    "guard rail": "static.manmade",
    "traffic light": "static.manmade",
    "static": "static.other",
    "dynamic": "movable_object.pushable_pullable",
    "water": "flat.other",
    "terrain": "flat.terrain",
}

#: Lookup table: CARLA tag (0..22) -> lidarseg index (0..31).
CARLA_TO_NUSCENES: np.ndarray = np.array(
    [NUSCENES_INDEX[_CARLA_TO_NUSCENES_NAMES[n]] for n in CARLA_NAMES], dtype=np.uint8
)

#: lidarseg indices of the ground ("flat.*") classes splatted into the BEV ground truth.
GROUND_CLASSES: tuple[int, ...] = tuple(
    NUSCENES_INDEX[n] for n in ("flat.driveable_surface", "flat.other", "flat.sidewalk", "flat.terrain")
)
EGO_CLASS: int = NUSCENES_INDEX["vehicle.ego"]


def map_carla_tags(tags: np.ndarray) -> np.ndarray:
    """CARLA tags (any shape, uint8 0..22) -> lidarseg indices (uint8, same shape)."""
    tags = np.asarray(tags)
    if tags.size and int(tags.max()) >= len(CARLA_TO_NUSCENES):
        raise ValueError(f"CARLA tag {int(tags.max())} out of range 0..{len(CARLA_TO_NUSCENES) - 1}")
    return CARLA_TO_NUSCENES[tags.astype(np.int64)]


def actor_category(tag: int, length: float, width: float, height: float) -> str:
    """nuScenes category name of a world actor box (see the module docstring)."""
    tag = int(tag)
    if tag == TAG["pedestrian"]:
        return "human.pedestrian.adult"
    if tag == TAG["vehicle"]:
        if length < 2.0:
            return "vehicle.bicycle"
        if length < 2.6:
            return "vehicle.motorcycle"
        if length <= 5.5:
            return "vehicle.car"
        return "vehicle.truck"
    return _CARLA_TO_NUSCENES_NAMES[CARLA_NAMES[tag]]


def refine_point_labels(
    points: np.ndarray, labels: np.ndarray, tags: np.ndarray, boxes: np.ndarray
) -> np.ndarray:
    """Give vehicle/pedestrian-tagged points inside an actor box's footprint that box's category.

    ``points`` (M, >=3) and ``boxes`` (K, 8) are in the same frame; returns a new label array.
    Only the x-y footprint (+5 cm) is tested: the points are already tagged as actors, and this
    keeps the refinement independent of the box z reference (ground or LiDAR origin).
    """
    labels = labels.copy()
    movable = (tags == TAG["vehicle"]) | (tags == TAG["pedestrian"])
    if not movable.any() or len(boxes) == 0:
        return labels
    idx = np.flatnonzero(movable)
    p = points[idx, :3].astype(np.float64)
    for b in boxes:
        x, y, z, length, width, height, yaw, tag = (float(v) for v in b[:8])
        c, s = np.cos(yaw), np.sin(yaw)
        dx, dy = p[:, 0] - x, p[:, 1] - y
        lx, ly = c * dx + s * dy, -s * dx + c * dy
        inside = (np.abs(lx) <= length / 2 + 0.05) & (np.abs(ly) <= width / 2 + 0.05)
        if inside.any():
            labels[idx[inside]] = NUSCENES_INDEX[actor_category(int(tag), length, width, height)]
    return labels
