"""DVS event preprocessing, paper section IV-C, eq. (1).

``I_DVS[c, i, j] = 1`` if at least one event of polarity c fell on pixel (row i = y,
column j = x) during the step, else 0; channel 0 = positive, channel 1 = negative
polarity. Timestamps are only used for synchronisation and are ignored here.

Events outside the image are **rejected with a ValueError** (not dropped): CARLA's DVS
camera only emits in-image pixel coordinates, so an out-of-range event means a corrupt
record or a resolution mismatch, and silently dropping it would hide that.
"""
from __future__ import annotations

import numpy as np


def events_to_image(events: np.ndarray, size: int, *, name: str = "events") -> np.ndarray:
    """Eq. (1): events (N, 4) = t, x (column), y (row), polarity -> uint8 (2, S, S) in {0, 1}.

    Polarity > 0 is positive (channel 0); polarity <= 0 is negative (channel 1), so both
    the +1/-1 convention and CARLA's boolean (1/0) convention work.
    Raises ValueError naming ``name`` for a wrong shape or an event outside the image.
    """
    ev = np.asarray(events)
    out = np.zeros((2, size, size), dtype=np.uint8)
    if ev.size == 0:
        if ev.ndim != 2 and ev.shape != (0,):
            raise ValueError(f"{name}: expected an (N, 4) event array, got shape {ev.shape}")
        return out
    if ev.ndim != 2 or ev.shape[1] != 4:
        raise ValueError(f"{name}: expected an (N, 4) event array (t, x, y, polarity), got shape {ev.shape}")
    x = ev[:, 1].astype(np.int64)
    y = ev[:, 2].astype(np.int64)
    bad = (x < 0) | (x >= size) | (y < 0) | (y >= size)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise ValueError(
            f"{name}: {int(bad.sum())} event(s) outside the {size}x{size} image, first at x={x[k]}, y={y[k]}"
        )
    channel = (ev[:, 3] <= 0).astype(np.int64)
    out[channel, y, x] = 1
    return out


def dvs_colour_to_image(image_bgr: np.ndarray, *, name: str = "dvs image") -> np.ndarray:
    """CARLA's DVS colour image (as read by cv2, BGR) -> uint8 (2, H, W) of eq. (1).

    CARLA draws positive events blue and negative events red (green unused): channel 0 =
    blue > 0, channel 1 = red > 0.
    """
    img = np.asarray(image_bgr)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"{name}: expected an HxWx3 BGR image, got shape {img.shape}")
    return np.stack([img[..., 0] > 0, img[..., 2] > 0]).astype(np.uint8)
