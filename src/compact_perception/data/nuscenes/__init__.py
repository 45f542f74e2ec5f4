"""nuScenes-lidarseg support (paper section IV-B, SPEC 3.2).

- :mod:`.export`     the simulated world -> a small dataroot in nuScenes format (tables, sweeps,
  lidarseg labels, images, annotation boxes, map) that the real devkit loads;
- :mod:`.ingest`     any nuScenes-lidarseg dataroot -> preprocessed frame dicts via the devkit;
- :mod:`.split`      scene split 3:1:1 with a fixed seed;
- :mod:`.projection` LiDAR points -> camera pixels (devkit calibrated_sensor / ego_pose chain) and
  the neighbour filling that makes SS/DE ground truth;
- :mod:`.classmap`   CARLA tags / world actors -> the 32 lidarseg classes.

Submodules are imported lazily so that ``import compact_perception.data.nuscenes`` stays cheap and
does not shadow the devkit's top-level ``nuscenes`` package (absolute imports are used throughout).
"""
from __future__ import annotations

from pathlib import Path
from typing import Optional

#: nuScenes camera channel of each of our views (geometry.VIEWS order f, l, ri, r).
VIEW_CHANNELS: dict[str, str] = {
    "f": "CAM_FRONT",
    "l": "CAM_FRONT_LEFT",
    "ri": "CAM_FRONT_RIGHT",
    "r": "CAM_BACK",
}
LIDAR_CHANNEL = "LIDAR_TOP"
#: bytes per point of a LIDAR_TOP sweep .bin (x, y, z, intensity, ring index as float32)
SWEEP_RECORD_BYTES = 5 * 4
#: bytes per point of a lidarseg label .bin (one uint8 class index)
LABEL_RECORD_BYTES = 1


def dataroot_problem(dataroot: str | Path, version: str) -> Optional[str]:
    """What makes ``dataroot`` unusable as a nuScenes dataroot of ``version`` at a glance
    (no folder, no table folder), or None; the full check is ``ingest.preflight``."""
    root = Path(dataroot)
    if not root.is_dir():
        return f"nuScenes dataroot not found: {root} (expected a folder holding the {version} tables)"
    if not (root / version).is_dir():
        return f"nuScenes table folder not found: {root / version} (version {version!r})"
    return None


__all__ = ["VIEW_CHANNELS", "LIDAR_CHANNEL", "SWEEP_RECORD_BYTES", "LABEL_RECORD_BYTES", "dataroot_problem"]
