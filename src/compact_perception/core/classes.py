"""Class lists and palettes (paper Table I, SPEC 3.1, nuScenes-lidarseg 32 classes)."""
from __future__ import annotations

import numpy as np

#: The 23 CARLA 0.9.10 semantic tags, in tag order, with their palette colours (SPEC 3.1).
CARLA_CLASSES: tuple[tuple[str, tuple[int, int, int]], ...] = (
    ("unlabeled", (0, 0, 0)),
    ("building", (70, 70, 70)),
    ("fence", (100, 40, 40)),
    ("other", (55, 90, 80)),
    ("pedestrian", (220, 20, 60)),
    ("pole", (153, 153, 153)),
    ("road line", (157, 234, 50)),
    ("road", (128, 64, 128)),
    ("sidewalk", (244, 35, 232)),
    ("vegetation", (107, 142, 35)),
    ("vehicle", (0, 0, 142)),
    ("wall", (102, 102, 156)),
    ("traffic sign", (220, 220, 0)),
    ("sky", (70, 130, 180)),
    ("ground", (81, 0, 81)),
    ("bridge", (150, 100, 100)),
    ("rail track", (230, 150, 140)),
    ("guard rail", (180, 165, 180)),
    ("traffic light", (250, 170, 30)),
    ("static", (110, 190, 160)),
    ("dynamic", (170, 120, 50)),
    ("water", (45, 60, 150)),
    ("terrain", (145, 170, 100)),
)
CARLA_NAMES: tuple[str, ...] = tuple(n for n, _ in CARLA_CLASSES)
CARLA_PALETTE: np.ndarray = np.array([c for _, c in CARLA_CLASSES], dtype=np.uint8)
TAG = {name: i for i, name in enumerate(CARLA_NAMES)}

#: The 9 multi-label BEV classes (paper Table I), with display colours.
BEV_CLASSES: tuple[tuple[str, tuple[int, int, int]], ...] = (
    ("road", (128, 64, 128)),
    ("road lane", (157, 234, 50)),
    ("road centreline", (255, 255, 255)),
    ("other vehicles", (0, 0, 142)),
    ("ego vehicle", (0, 200, 255)),
    ("green traffic light", (0, 220, 0)),
    ("yellow traffic light", (250, 220, 0)),
    ("red traffic light", (230, 0, 0)),
    ("pedestrian", (220, 20, 60)),
)
BEV_NAMES: tuple[str, ...] = tuple(n for n, _ in BEV_CLASSES)
BEV_PALETTE: np.ndarray = np.array([c for _, c in BEV_CLASSES], dtype=np.uint8)

#: nuScenes-lidarseg classes, index = position in nuscenes-devkit 1.2.0's colormap.
NUSCENES_NAMES: tuple[str, ...] = (
    "noise",
    "animal",
    "human.pedestrian.adult",
    "human.pedestrian.child",
    "human.pedestrian.construction_worker",
    "human.pedestrian.personal_mobility",
    "human.pedestrian.police_officer",
    "human.pedestrian.stroller",
    "human.pedestrian.wheelchair",
    "movable_object.barrier",
    "movable_object.debris",
    "movable_object.pushable_pullable",
    "movable_object.trafficcone",
    "static_object.bicycle_rack",
    "vehicle.bicycle",
    "vehicle.bus.bendy",
    "vehicle.bus.rigid",
    "vehicle.car",
    "vehicle.construction",
    "vehicle.emergency.ambulance",
    "vehicle.emergency.police",
    "vehicle.motorcycle",
    "vehicle.trailer",
    "vehicle.truck",
    "flat.driveable_surface",
    "flat.other",
    "flat.sidewalk",
    "flat.terrain",
    "static.manmade",
    "static.other",
    "static.vegetation",
    "vehicle.ego",
)


def palette_to_index(image: np.ndarray, palette: np.ndarray, *, name: str = "image") -> np.ndarray:
    """Map an HxWx3 uint8 palette image to an HxW uint8 class-index map.

    Raises ValueError naming ``name`` if a pixel colour is not in the palette.
    """
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"{name}: expected an HxWx3 palette image, got shape {image.shape}")
    codes = (image[..., 0].astype(np.int64) << 16) | (image[..., 1].astype(np.int64) << 8) | image[..., 2]
    pal = (palette[:, 0].astype(np.int64) << 16) | (palette[:, 1].astype(np.int64) << 8) | palette[:, 2]
    order = np.argsort(pal)
    pos = np.searchsorted(pal[order], codes)
    pos = np.clip(pos, 0, len(pal) - 1)
    found = pal[order][pos] == codes
    if not found.all():
        bad = image[~found][0]
        raise ValueError(f"{name}: colour {tuple(int(v) for v in bad)} is not in the class palette")
    return order[pos].astype(np.uint8)
