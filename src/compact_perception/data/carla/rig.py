"""The paper's sensor rig (section IV-A, Table I) as CARLA sensor blueprints, from the same
``world.camera``, ``world.lidar`` and ``world.dvs`` settings the embedded world renders with.

Per view v of ``geometry.VIEWS`` four cameras share one mount: ``rgb_<v>``
(``sensor.camera.rgb``), ``dvs_<v>`` (``sensor.camera.dvs``), ``sem_<v>``
(``sensor.camera.semantic_segmentation``), ``depth_<v>`` (``sensor.camera.depth``), S x S
pixels, ``fov_deg`` wide, ``mount_offset_m`` from the vehicle's origin along the view direction,
``height_m`` above it, pitched up ``pitch_deg``. One semantic LiDAR
(``sensor.lidar.ray_cast_semantic``) sits ``lidar.height_m`` above the origin: ``channels``
lasers from ``lower_fov_deg`` to ``upper_fov_deg``, ``range_m``, one full revolution per
simulation step (``rotation_frequency`` = 1 / step) with ``horizontal_samples`` points per laser.

CARLA's frame is left-handed (x forward, y right, z up; yaw clockwise seen from above), so a
view at yaw +90 deg in the project's frame (left) sits at CARLA yaw -90 deg and y < 0.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ...core.params import WorldParams
from ..geometry import VIEWS, VIEW_YAW_DEG

CAMERA_KINDS: dict[str, str] = {"rgb": "sensor.camera.rgb", "dvs": "sensor.camera.dvs",
                                "sem": "sensor.camera.semantic_segmentation", "depth": "sensor.camera.depth"}
LIDAR_BLUEPRINT = "sensor.lidar.ray_cast_semantic"


@dataclass(frozen=True)
class SensorSpec:
    """One sensor: the raw-record key it fills, its blueprint and attributes, its mount on the
    ego vehicle in CARLA's frame (x, y, z metres; pitch, yaw, roll degrees)."""

    key: str
    blueprint: str
    attributes: tuple[tuple[str, str], ...]
    location: tuple[float, float, float]
    rotation: tuple[float, float, float]


def sensor_specs(wp: WorldParams, size: int, step_s: float) -> list[SensorSpec]:
    """Every sensor of the rig at ``size`` pixels for a simulation step of ``step_s`` seconds."""
    cam, lid = wp.camera, wp.lidar
    specs: list[SensorSpec] = []
    for v in VIEWS:
        yaw = float(VIEW_YAW_DEG[v])
        loc = (cam.mount_offset_m * float(np.cos(np.deg2rad(yaw))), -cam.mount_offset_m * float(np.sin(np.deg2rad(yaw))),
               cam.height_m)
        rot = (float(cam.pitch_deg), -yaw, 0.0)
        for kind, bp in CAMERA_KINDS.items():
            attrs = {"image_size_x": str(size), "image_size_y": str(size), "fov": f"{cam.fov_deg:g}"}
            if kind == "dvs":
                attrs.update(positive_threshold=f"{wp.dvs.contrast_threshold:g}",
                             negative_threshold=f"{wp.dvs.contrast_threshold:g}")
            specs.append(SensorSpec(f"{kind}_{v}", bp, tuple(sorted(attrs.items())), loc, rot))
    freq = 1.0 / step_s
    attrs = {"channels": str(lid.channels), "range": f"{lid.range_m:g}", "upper_fov": f"{lid.upper_fov_deg:g}",
             "lower_fov": f"{lid.lower_fov_deg:g}", "rotation_frequency": f"{freq:g}",
             "points_per_second": str(int(round(lid.channels * lid.horizontal_samples * freq)))}
    specs.append(SensorSpec("lidar", LIDAR_BLUEPRINT, tuple(sorted(attrs.items())), (0.0, 0.0, lid.height_m),
                            (0.0, 0.0, 0.0)))
    return specs


def blueprint(library: Any, spec: SensorSpec) -> Any:
    """The blueprint of ``spec`` from a ``carla.BlueprintLibrary`` with its attributes set."""
    bp = library.find(spec.blueprint)
    for name, value in spec.attributes:
        bp.set_attribute(name, value)
    return bp


def transform(carla: Any, spec: SensorSpec) -> Any:
    """The ``carla.Transform`` of ``spec``'s mount (``carla`` = the client module)."""
    x, y, z = spec.location
    pitch, yaw, roll = spec.rotation
    return carla.Transform(carla.Location(x=x, y=y, z=z), carla.Rotation(pitch=pitch, yaw=yaw, roll=roll))
