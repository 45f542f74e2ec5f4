"""The generate stage's figure, ``reports/figures/world_<ds>.png``: one example frame of a source.

A raw record (the world's, a CARLA recording's) is drawn as the Fig. 1-like panel
(:func:`save_frame_figure`: 4 RGB, 4 DVS, 4 semantic, 4 depth, LiDAR top view, BEV); a source
without raw records (the authors' release) as the qualitative grid of its cache frame
(:func:`save_cache_frame_figure`, drawn by :mod:`compact_perception.data.qualitative`, which the
report shares).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..core import io
from ..core.classes import BEV_PALETTE, CARLA_PALETTE
from .geometry import VIEWS, topview_index


def dvs_image(events: np.ndarray, size: int) -> np.ndarray:
    """Events accumulated into an RGB image (positive blue, negative red, white background)."""
    img = np.full((size, size, 3), 255, np.uint8)
    if len(events):
        pos = events[:, 3] > 0
        img[events[pos, 2], events[pos, 1]] = (0, 0, 255)
        img[events[~pos, 2], events[~pos, 1]] = (255, 0, 0)
    return img


def lidar_topview(points: np.ndarray, tags: np.ndarray, range_m: float, size: int) -> np.ndarray:
    """Top view (eq. 2-3 grid; row = x forward, col = y left) coloured by tag, highest point wins."""
    img = np.zeros((size, size, 3), np.uint8)
    i = topview_index(points[:, 0], range_m, size)
    j = topview_index(points[:, 1], range_m, size)
    ok = (i >= 0) & (j >= 0) & (i < size) & (j < size)
    order = np.argsort(points[ok, 2])
    img[i[ok][order], j[ok][order]] = CARLA_PALETTE[tags[ok][order]]
    return img


def bev_image(bev: np.ndarray) -> np.ndarray:
    """Multi-label BEV masks painted in BEV_NAMES order (later classes on top)."""
    img = np.zeros((*bev.shape[1:], 3), np.uint8)
    for k in range(bev.shape[0]):
        img[bev[k] > 0] = BEV_PALETTE[k]
    return img


def save_frame_figure(rec: dict, path: str | Path, range_m: float = 32.0, title: str = "") -> None:
    """Write the panel as a PNG atomically (matplotlib Agg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .world.camera import decode_depth

    S = rec["rgb_f"].shape[0]
    fig, axes = plt.subplots(5, 4, figsize=(8, 10.5))
    rows = [("RGB", lambda v: rec[f"rgb_{v}"]), ("DVS", lambda v: dvs_image(rec[f"dvs_{v}"], S)),
            ("SS", lambda v: rec[f"sem_{v}"]), ("DE", lambda v: np.log(decode_depth(rec[f"depth_{v}"])))]
    for r, (name, fn) in enumerate(rows):
        for c, v in enumerate(VIEWS):
            ax = axes[r, c]
            im = fn(v)
            ax.imshow(im, cmap="magma" if im.ndim == 2 else None, interpolation="nearest")
            ax.set_title(f"{name} {v}", fontsize=8)
    # top views: row i = forward -> flip so forward is up, column j = left -> flip so left is left
    tv = lidar_topview(rec["lidar"], rec["lidar_tag"], range_m, S)[::-1, ::-1]
    axes[4, 0].imshow(tv, interpolation="nearest")
    axes[4, 0].set_title("LiDAR top view (tags)", fontsize=8)
    axes[4, 1].imshow(bev_image(rec["bev"])[::-1, ::-1], interpolation="nearest")
    axes[4, 1].set_title("BEV", fontsize=8)
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
    axes[4, 2].axis("off")
    axes[4, 3].axis("off")
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    io.write_figure(fig, path, dpi=90)


def save_cache_frame_figure(dataset_id: str, frame: Mapping[str, Any], frame_id: str, path: str | Path, title: str = "") -> None:
    """The qualitative grid (inputs and ground truth, no model) of one cache frame dict."""
    from .qualitative import plot_qualitative

    inputs = {k: np.asarray(frame[k])[None] for k in ("rgb", "dvs", "lidar")}
    inputs.update({f"gt_{k}": np.asarray(frame[k])[None] for k in ("de", "ss", "ls", "bevp")})
    inputs["frame_ids"] = np.array([frame_id])
    plot_qualitative(dataset_id, inputs, {}, Path(path), frame=0, models=[], title=title)
