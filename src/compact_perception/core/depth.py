"""CARLA's logarithmic depth encoding (SPEC 3.1, docs/ARCHITECTURE.md): the one definition of its
constants, read by the world's depth camera, the nuScenes projection, the depth metrics and the report.

A depth of ``d`` metres is stored as ``x = clip(1 + ln(d / DEPTH_FAR_M) / DEPTH_LOG_K, 0, 1)``:
1.0 is the 1000 m far plane and 0.0 is ``1000 m * exp(-DEPTH_LOG_K)`` = 3.33 m (nearer clips).
"""
from __future__ import annotations

import math

#: The far plane of CARLA's depth camera (m): x = 1.
DEPTH_FAR_M = 1000.0
#: ln(1000 m / ~3.33 m): the log range that x spans.
DEPTH_LOG_K = 5.70378
#: The nearest depth the encoding holds (x = 0): 1000 m * exp(-5.70378) = 3.33 m.
DEPTH_NEAR_M = DEPTH_FAR_M * math.exp(-DEPTH_LOG_K)
