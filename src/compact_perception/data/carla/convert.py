"""CARLA sensor buffers -> the raw record's arrays (docs/ARCHITECTURE.md), from CARLA's documented formats.

Everything here takes plain bytes or numpy arrays (a sensor measurement's ``raw_data``,
``width``, ``height``), so it runs and is tested without the ``carla`` module.

- Camera images (``sensor.camera.rgb``, ``.semantic_segmentation``, ``.depth``): ``raw_data``
  is height x width x 4 bytes, BGRA, row-major.
- RGB: the B, G, R bytes reordered to R, G, B (the project's order).
- Semantic segmentation: the tag of each pixel in the red byte. CARLA 0.9.10 numbers its tags
  0..22 in the order of ``core.classes.CARLA_NAMES``; CARLA 0.9.14 and later renumbered them
  (Cityscapes order, 29 tags). :func:`tag_table` maps either to the 23-class palette.
- Depth: the distance is 24-bit fixed point over the 1000 m far plane,
  ``normalised = (R + G*256 + B*256**2) / (256**3 - 1)``, ``metres = 1000 * normalised``; the
  raw record stores CARLA's logarithmic form ``clip(1 + ln(normalised) / 5.70378, 0, 1)``
  (``core.depth``) x 65535, computed from the 24-bit value (not from an 8-bit converted image).
- DVS (``sensor.camera.dvs``): ``raw_data`` is an array of packed 13-byte events
  ``{uint16 x, uint16 y, int64 t (nanoseconds), bool pol}``; the record holds int64
  (t in microseconds, x, y, polarity +1/-1).
- Semantic LiDAR (``sensor.lidar.ray_cast_semantic``): ``raw_data`` is an array of 24-byte
  points ``{float32 x, y, z, cos_inc_angle; uint32 object_idx, object_tag}`` in the sensor's
  frame, which is left-handed like all of CARLA (x forward, y right, z up). The project's
  ego/LiDAR frame is x forward, y left, z up: y changes sign. ``cos_inc_angle`` is kept
  (CARLA gives it in [-1, 1] depending on the face's side; the record keeps its magnitude,
  as the world does).
"""
from __future__ import annotations

import re

import numpy as np

from ...core.classes import CARLA_NAMES, CARLA_PALETTE, TAG
from ...core.depth import DEPTH_LOG_K

#: packed DVS event of CARLA (13 bytes)
DVS_EVENT_DTYPE = np.dtype([("x", "<u2"), ("y", "<u2"), ("t", "<i8"), ("pol", "?")])
#: semantic LiDAR detection of CARLA (24 bytes)
SEMANTIC_LIDAR_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("cos_inc_angle", "<f4"),
                                 ("object_idx", "<u4"), ("object_tag", "<u4")])
#: 2**24 - 1: the largest 24-bit depth value (the far plane)
DEPTH_24BIT_MAX = 256 ** 3 - 1

#: CARLA 0.9.14+ tag names in tag-id order (as ``carla.CityObjectLabel`` of the 0.9.16 client lists them)
TAGS_0_9_14 = ("unlabeled", "road", "sidewalk", "building", "wall", "fence", "pole", "traffic light",
               "traffic sign", "vegetation", "terrain", "sky", "pedestrian", "rider", "car", "truck", "bus",
               "train", "motorcycle", "bicycle", "static", "dynamic", "other", "water", "road line", "ground",
               "bridge", "rail track", "guard rail")
#: a 0.9.14+ name that is not one of the 23 classes -> the class that holds it
_MERGED = {"rider": "pedestrian", "car": "vehicle", "truck": "vehicle", "bus": "vehicle", "train": "vehicle",
           "motorcycle": "vehicle", "bicycle": "vehicle"}


class FormatError(ValueError):
    """A buffer does not have the size or layout of the documented format."""


def parse_version(text: str) -> tuple[int, ...]:
    """``'0.9.16'``, ``'0.9.10-1'`` or ``'0.9.14-dirty'`` -> (0, 9, 16); FormatError if no x.y.z."""
    m = re.match(r"\s*(\d+)\.(\d+)\.(\d+)", str(text))
    if not m:
        raise FormatError(f"not a CARLA version: {text!r}")
    return tuple(int(g) for g in m.groups())


def tag_table(server_version: str) -> np.ndarray:
    """uint8 (256,) lookup: a server's semantic tag id -> index into ``CARLA_NAMES`` (0 for unknown ids)."""
    table = np.zeros(256, np.uint8)
    if parse_version(server_version) >= (0, 9, 14):
        for tag, name in enumerate(TAGS_0_9_14):
            table[tag] = TAG[_MERGED.get(name, name)]
    else:
        table[: len(CARLA_NAMES)] = np.arange(len(CARLA_NAMES), dtype=np.uint8)
    return table


def _bgra(raw: bytes | memoryview | np.ndarray, width: int, height: int, what: str) -> np.ndarray:
    buf = np.frombuffer(raw, np.uint8) if not isinstance(raw, np.ndarray) else raw.reshape(-1).view(np.uint8)
    if buf.size != width * height * 4:
        raise FormatError(f"{what}: {buf.size} bytes, expected {height} x {width} x 4 (BGRA)")
    return buf.reshape(height, width, 4)


def rgb_from_bgra(raw: bytes | memoryview | np.ndarray, width: int, height: int) -> np.ndarray:
    """uint8 (H, W, 3) RGB of a camera image's BGRA ``raw_data``."""
    return np.ascontiguousarray(_bgra(raw, width, height, "rgb image")[:, :, 2::-1])


def semantic_from_bgra(raw: bytes | memoryview | np.ndarray, width: int, height: int,
                       table: np.ndarray) -> np.ndarray:
    """uint8 (H, W, 3) image in ``CARLA_PALETTE`` of a semantic camera's BGRA ``raw_data`` (tag in red)."""
    tags = _bgra(raw, width, height, "semantic image")[:, :, 2]
    return CARLA_PALETTE[table[tags]]


def depth_metres_from_bgra(raw: bytes | memoryview | np.ndarray, width: int, height: int) -> np.ndarray:
    """float64 (H, W) distance in metres of a depth camera's BGRA ``raw_data`` (24-bit over 1000 m)."""
    px = _bgra(raw, width, height, "depth image").astype(np.int64)
    return 1000.0 * (px[:, :, 2] + px[:, :, 1] * 256 + px[:, :, 0] * 65536) / DEPTH_24BIT_MAX


def log_depth_u16_from_bgra(raw: bytes | memoryview | np.ndarray, width: int, height: int) -> np.ndarray:
    """uint16 (H, W): CARLA's logarithmic depth (normalised 0..1) x 65535, the raw record's ``depth_<v>``."""
    px = _bgra(raw, width, height, "depth image").astype(np.int64)
    normalised = np.maximum(px[:, :, 2] + px[:, :, 1] * 256 + px[:, :, 0] * 65536, 1) / DEPTH_24BIT_MAX
    log = np.clip(1.0 + np.log(normalised) / DEPTH_LOG_K, 0.0, 1.0)
    return np.rint(log * 65535.0).astype(np.uint16)


def dvs_events_from_raw(raw: bytes | memoryview | np.ndarray, width: int, height: int) -> np.ndarray:
    """int64 (N, 4) events (t in microseconds, x, y, polarity +1/-1) of a DVS event array's ``raw_data``."""
    buf = np.frombuffer(raw, np.uint8) if not isinstance(raw, np.ndarray) else raw.reshape(-1).view(np.uint8)
    if buf.size % DVS_EVENT_DTYPE.itemsize:
        raise FormatError(f"dvs events: {buf.size} bytes is not a whole number of "
                          f"{DVS_EVENT_DTYPE.itemsize}-byte events")
    ev = buf.view(DVS_EVENT_DTYPE)
    if ev.size and (int(ev["x"].max()) >= width or int(ev["y"].max()) >= height):
        raise FormatError(f"dvs events: a pixel outside the {width} x {height} image")
    out = np.stack([ev["t"].astype(np.int64) // 1000, ev["x"].astype(np.int64), ev["y"].astype(np.int64),
                    np.where(ev["pol"], 1, -1).astype(np.int64)], axis=1) if ev.size else np.zeros((0, 4), np.int64)
    return out.reshape(-1, 4)


def lidar_from_raw(raw: bytes | memoryview | np.ndarray, table: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(float32 (M, 4) x, y, z, |cos incident angle| in the ego/LiDAR frame, uint8 (M,) tags in
    ``CARLA_NAMES``) of a semantic LiDAR measurement's ``raw_data`` (CARLA's y to the right -> y left)."""
    buf = np.frombuffer(raw, np.uint8) if not isinstance(raw, np.ndarray) else raw.reshape(-1).view(np.uint8)
    if buf.size % SEMANTIC_LIDAR_DTYPE.itemsize:
        raise FormatError(f"semantic lidar: {buf.size} bytes is not a whole number of "
                          f"{SEMANTIC_LIDAR_DTYPE.itemsize}-byte points")
    p = buf.view(SEMANTIC_LIDAR_DTYPE)
    pts = np.stack([p["x"], -p["y"], p["z"], np.abs(p["cos_inc_angle"])], axis=1).astype(np.float32).reshape(-1, 4)
    tags = table[np.minimum(p["object_tag"], 255).astype(np.int64)]
    return pts, tags.astype(np.uint8)


def right_handed_pose(x: float, y: float, yaw_deg: float) -> np.ndarray:
    """float64 (3,) pose (x, y, yaw in radians) in the right-handed world of the project from a
    CARLA location and yaw (left-handed: y and the yaw change sign)."""
    return np.array([float(x), -float(y), -np.deg2rad(float(yaw_deg))], np.float64)
