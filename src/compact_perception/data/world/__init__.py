"""The embedded procedural driving world: the default data source of sets A, B, C (SPEC 3.1).

Design
------
- ``town``: five seeded Manhattan-grid towns (town01..town05) that differ in block size,
  road width, lanes, building density/heights, vegetation and rarer classes (river with
  bridges, rail corridor, guard rails, walls, fences). Ground = flat metric class map
  (z = 0) with painted road lines; everything else = axis-aligned boxes.
- ``actors``: ego route (random walk on the road graph, ~1 m per step), vehicles (car,
  truck, bicycle, motorbike), pedestrians on sidewalks and zebra crossings, traffic lights
  cycling green/yellow/red. Pure functions of (town, episode seed, step).
- ``conditions``: per-frame time of day x weather intensities (0-100 %, combinable).
- ``raycast``: vectorised numpy ray casting (azimuth-sector broad phase + slab test,
  analytic ground plane); cameras and LiDAR share it, so all sensors see the same geometry.
- ``camera`` (intrinsics/extrinsics helpers, shading, semantic, CARLA log depth),
  ``events`` (DVS from log-intensity change, threshold 0.3), ``lidar_sim`` (64 lasers,
  -30..+20 deg, 32 m, (x, y, z, cos incidence) + tag), ``bev_gt`` (9 BEV masks).
- ``generate``: :func:`render_episode` and :func:`generate_dataset`; ``source``: the world as the
  ``sim`` data source (:mod:`compact_perception.data.sources`); its panel is drawn by
  :mod:`compact_perception.data.figures_generate`.

Raw record layout: exactly :mod:`compact_perception.data.record` (docs/data-formats.md): ``data/raw/<ds>/``
with ``frames/<town>_ep<episode>_<step>.npz`` (keys ``rgb_<v>``, ``dvs_<v>``, ``sem_<v>``,
``depth_<v>``, ``lidar``, ``lidar_tag``, ``bev``, ``boxes``, ``ego_pose``; v in f, l, ri, r),
``stats/class_frequency_<town>.csv`` (tag, class, pixels, points) and ``manifest.json``
written last (splits by ``split_ratio``, per-frame town/episode/step/time_of_day/weather).
"""
from __future__ import annotations

from .generate import generate_dataset, render_episode

__all__ = ["generate_dataset", "render_episode"]
