"""DVS events from two consecutive RGB steps (SPEC 3.1; CARLA's DVS camera model).

An event fires each time the per-pixel log intensity ``ln(gray + 1)`` crosses a multiple
of the contrast threshold (0.3) between the previous and the current step; identical
images give no events. Rows: t (microseconds), x (column), y (row), polarity (+1/-1).
"""
from __future__ import annotations

import numpy as np

_GRAY = np.array([0.299, 0.587, 0.114])
MAX_EVENTS_PER_PIXEL = 10


def log_intensity(rgb: np.ndarray) -> np.ndarray:
    """ln(1 + luminance) of a uint8 RGB image."""
    return np.log1p(rgb.astype(np.float64) @ _GRAY)


def dvs_events(prev_rgb: np.ndarray, rgb: np.ndarray, threshold: float, t0_us: int, step_us: int) -> np.ndarray:
    """Events between ``prev_rgb`` (time t0) and ``rgb`` (time t0 + step) as int64 (N, 4), sorted by t, y, x."""
    dl = log_intensity(rgb) - log_intensity(prev_rgb)
    n = np.minimum(np.floor(np.abs(dl) / threshold), MAX_EVENTS_PER_PIXEL).astype(np.int64)
    ys, xs = np.nonzero(n)
    if ys.size == 0:
        return np.zeros((0, 4), np.int64)
    cnt = n[ys, xs]
    rep = np.repeat(np.arange(ys.size), cnt)
    k = np.arange(rep.size) - np.repeat(np.cumsum(cnt) - cnt, cnt) + 1  # 1..n per pixel
    # the k-th crossing happens at fraction k*thr/|dl| of the step (linear log-intensity ramp)
    frac = k * threshold / np.abs(dl[ys[rep], xs[rep]])
    t = t0_us + np.rint(np.minimum(frac, 1.0) * step_us).astype(np.int64)
    pol = np.sign(dl[ys[rep], xs[rep]]).astype(np.int64)
    ev = np.stack([t, xs[rep], ys[rep], pol], axis=1).astype(np.int64)
    order = np.lexsort((ev[:, 1], ev[:, 2], ev[:, 0]))
    return ev[order]
