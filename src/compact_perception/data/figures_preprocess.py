"""The preprocess stage's figure, ``reports/figures/lidar_preprocessing_<ds>.png`` (Fig. 5-like):
the 15-layer LiDAR tensor of one cache frame (section IV-C, eq. (2)-(5))."""
from __future__ import annotations

import logging
import os
from typing import Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..core import io as cio  # noqa: E402

log = logging.getLogger(__name__)


def layer_titles(n_channels: int, z_min: float = -2.0, z_max: float = 11.0) -> list[str]:
    """Panel titles: height band of each eq. (5) channel, then the flattened (1L) layer."""
    mult = n_channels - 2
    step = (z_max - z_min) / mult
    titles = []
    for k in range(n_channels - 1):
        lo, hi = max(z_min, z_min + (k - 0.5) * step), min(z_max, z_min + (k + 0.5) * step)
        titles.append(f"k={k}: z {lo:.1f}..{hi:.1f} m")
    titles.append(f"k={n_channels - 1}: flattened (1L)")
    return titles


def plot_lidar_layers(
    lidar: np.ndarray,
    out_path: str | os.PathLike,
    title: str | None = None,
    titles: Sequence[str] | None = None,
) -> None:
    """Draw the height layers and the flattened layer of a (C, S, S) LiDAR tensor; write a PNG atomically.

    Row i (forward) is drawn upwards, column j (left) to the left, so the image reads as a
    map seen from above with the ego at the centre facing up.
    """
    lidar = np.asarray(lidar, dtype=np.float32)
    if lidar.ndim != 3:
        raise ValueError(f"lidar: expected (C, S, S), got shape {lidar.shape}")
    c = lidar.shape[0]
    titles = list(titles) if titles is not None else layer_titles(c)
    ncols = 5
    nrows = int(np.ceil(c / ncols))
    fig, axes = plt.subplots(nrows, ncols, figsize=(2.4 * ncols, 2.5 * nrows))
    for k, ax in enumerate(np.ravel(axes)):
        ax.axis("off")
        if k >= c:
            continue
        # forward (+i) up and left (+j) left: flip both axes of the (i, j) grid
        ax.imshow(lidar[k][::-1, ::-1], cmap="gray", vmin=0.0, vmax=1.0, interpolation="nearest")
        ax.set_title(titles[k], fontsize=7)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    cio.write_figure(fig, out_path, dpi=110)
    log.info("wrote %s", out_path)
