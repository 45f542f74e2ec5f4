"""The qualitative grid of one test frame (Fig. 6/7) and the colouring helpers it needs.

Kept apart from the training-log figures so that the data stages (the ``authors`` source's
``generate`` draws this grid) depend only on this module, the class palettes and io, not on the
model catalog or the metrics. Matplotlib with the Agg backend; PNGs written atomically.

Top-view images (LiDAR, LS, BEVP) are on the grid of eq. (2)-(3): row i grows forward (+x),
column j grows to the left (+y). They are drawn rotated by 180 degrees so that forward is up
and the ego's left is on the left of the picture.
"""
from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..core import io  # noqa: E402
from ..core.classes import BEV_PALETTE, CARLA_PALETTE  # noqa: E402
from ..core.depth import DEPTH_FAR_M, DEPTH_LOG_K  # noqa: E402

log = logging.getLogger(__name__)

NO_LABEL = 255
VIEW_NAMES: tuple[str, ...] = ("F", "L", "Ri", "R")


def nuscenes_palette(n: int = 32) -> np.ndarray:
    """A fixed, distinct ``n``-colour palette (uint8 RGB) for the nuScenes-lidarseg classes:
    tab20 followed by tab20b (class 0, noise/unlabelled, is black)."""
    cols = [plt.get_cmap("tab20")(i)[:3] for i in range(20)] + [plt.get_cmap("tab20b")(i)[:3] for i in range(20)]
    pal = (np.array(cols[:n]) * 255).round().astype(np.uint8)
    pal[0] = 0
    return pal


def palettes(dataset: str) -> tuple[np.ndarray, np.ndarray]:
    """(segmentation palette, BEV palette) of a dataset."""
    if dataset == "nuscenes":
        p = nuscenes_palette(32)
        return p, p
    return CARLA_PALETTE, BEV_PALETTE


def colour_index(index: np.ndarray, palette: np.ndarray) -> np.ndarray:
    """Class-index map -> RGB; out-of-palette values (255 = no label) are black."""
    idx = np.asarray(index).astype(np.int64)
    out = np.zeros(idx.shape + (3,), np.uint8)
    ok = (idx >= 0) & (idx < len(palette))
    out[ok] = palette[idx[ok]]
    return out


def colour_masks(masks: np.ndarray, palette: np.ndarray) -> np.ndarray:
    """Multi-label masks (C,S,S) -> RGB, later classes painted over earlier ones."""
    masks = np.asarray(masks)
    out = np.zeros(masks.shape[1:] + (3,), np.uint8)
    for c in range(min(len(masks), len(palette))):
        out[masks[c] > 0] = palette[c]
    return out


def colour_dvs(dvs: np.ndarray) -> np.ndarray:
    """DVS event image (2,S,S), channel 0 positive, 1 negative -> red/blue on black."""
    d = np.asarray(dvs, dtype=np.float32)
    out = np.zeros(d.shape[1:] + (3,), np.float32)
    for ch, col in ((0, 0), (1, 2)):
        m = d[ch].max()
        if m > 0:
            out[..., col] = d[ch] / m
    return (out * 255).astype(np.uint8)


def topview(img: np.ndarray) -> np.ndarray:
    """Rotate a top-view grid image (i forward, j left) so forward is up, left is left."""
    return np.asarray(img)[::-1, ::-1]


def save_figure(fig: "plt.Figure", path: Path, dpi: int = 100) -> Path:
    """Write a report figure (tight bounding box) atomically; closes the figure."""
    return io.write_figure(fig, path, dpi=dpi, tight=True)


# ----------------------------------------------------------------------------- Fig. 6/7
def _frame_index(arrays: Mapping[str, np.ndarray], frame_id: Any) -> Optional[int]:
    ids = arrays.get("frame_ids")
    if ids is None:
        return None
    hits = np.nonzero(np.asarray(ids).astype(str) == str(frame_id))[0]
    return int(hits[0]) if len(hits) else None


def _task_images(arrays: Mapping[str, np.ndarray], i: int, prefix: str, seg_pal: np.ndarray,
                 bev_pal: np.ndarray) -> dict[str, Any]:
    """Per column key -> image for one frame: ss0..3, de0..3, ls, bevp."""
    out: dict[str, Any] = {}
    if f"{prefix}ss" in arrays:
        for v, img in enumerate(arrays[f"{prefix}ss"][i]):
            out[f"ss{v}"] = colour_index(img, seg_pal)
    if f"{prefix}de" in arrays:
        for v, img in enumerate(arrays[f"{prefix}de"][i]):
            out[f"de{v}"] = ("gray", np.asarray(img, np.float32).reshape(img.shape[-2:]))
    if f"{prefix}ls" in arrays:
        out["ls"] = topview(colour_index(arrays[f"{prefix}ls"][i], seg_pal))
    if f"{prefix}bevp" in arrays:
        out["bevp"] = topview(colour_masks(arrays[f"{prefix}bevp"][i], bev_pal))
    return out


def plot_qualitative(dataset: str, inputs: Mapping[str, np.ndarray],
                     predictions: Mapping[str, Mapping[str, np.ndarray]], out_png: Path,
                     frame: int = 0, models: Optional[Sequence[str]] = None, title: str = "",
                     labels: Optional[Mapping[str, str]] = None) -> Optional[Path]:
    """Fig. 6/7-like grid for one test frame.

    Row 1 (inputs): 4 RGB views, 4 DVS views (if present), LiDAR top view (1-layer channel).
    Row 2 (ground truth) and one row per model: SS (4 views, palette colours), DE (4 views),
    LS, BEVP; blank where the model does not perform a task. ``inputs``: ``inputs.npz``
    arrays; ``predictions``: model id -> ``predictions.npz`` arrays. ``frame`` indexes the
    saved frames of ``inputs``; each model's prediction is matched by frame id. ``labels``:
    model id -> row name (the id itself where missing).
    """
    if "rgb" not in inputs or len(inputs["rgb"]) == 0:
        log.warning("%s: no saved inputs; skipping %s", dataset, out_png)
        return None
    n_saved = len(inputs["rgb"])
    frame = min(max(frame, 0), n_saved - 1)
    fid = inputs["frame_ids"][frame] if "frame_ids" in inputs else frame
    seg_pal, bev_pal = palettes(dataset)
    n_views = inputs["rgb"].shape[1]
    models = list(models if models is not None else predictions.keys())
    cols = 2 * n_views + 2
    nrows = 2 + len(models)
    fig, axes = plt.subplots(nrows, cols, figsize=(1.3 * cols, 1.4 * nrows), squeeze=False)
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
        for sp in ax.spines.values():
            sp.set_visible(False)

    def show(ax: Any, img: Any, label: str = "") -> None:
        if isinstance(img, tuple):
            ax.imshow(img[1], cmap=img[0], vmin=0.0, vmax=1.0, interpolation="nearest")
        else:
            ax.imshow(img, interpolation="nearest")
        if label:
            ax.set_title(label, fontsize=7)

    # inputs
    for v in range(n_views):
        show(axes[0, v], np.transpose(inputs["rgb"][frame, v], (1, 2, 0)), f"RGB {VIEW_NAMES[v] if v < 4 else v}")
        if "dvs" in inputs:
            show(axes[0, n_views + v], colour_dvs(inputs["dvs"][frame, v]), f"DVS {VIEW_NAMES[v] if v < 4 else v}")
    if "lidar" in inputs:
        lid = np.asarray(inputs["lidar"][frame], np.float32)
        show(axes[0, 2 * n_views], ("gray", topview(lid[-1])), "LiDAR (top)")
    axes[0, 0].set_ylabel("input", fontsize=8)

    col_of = {**{f"ss{v}": v for v in range(n_views)}, **{f"de{v}": n_views + v for v in range(n_views)},
              "ls": 2 * n_views, "bevp": 2 * n_views + 1}
    titles = {**{f"ss{v}": f"SS {VIEW_NAMES[v] if v < 4 else v}" for v in range(n_views)},
              **{f"de{v}": f"DE {VIEW_NAMES[v] if v < 4 else v}" for v in range(n_views)}, "ls": "LS", "bevp": "BEVP"}
    rows: list[tuple[str, dict[str, Any]]] = [("ground truth", _task_images(inputs, frame, "gt_", seg_pal, bev_pal))]
    for m in models:
        arr = predictions.get(m)
        idx = _frame_index(arr, fid) if arr is not None else None
        if arr is not None and idx is None and "frame_ids" not in arr and frame < len(next(iter(arr.values()))):
            idx = frame
        imgs = _task_images(arr, idx, "", seg_pal, bev_pal) if arr is not None and idx is not None else {}
        if arr is not None and idx is None:
            log.warning("%s: frame %s not in %s's predictions", dataset, fid, m)
        rows.append(((labels or {}).get(m, m), imgs))
    for r, (name, imgs) in enumerate(rows, start=1):
        for key, img in imgs.items():
            show(axes[r, col_of[key]], img, titles[key] if r == 1 else "")
        axes[r, 0].set_ylabel(name, fontsize=8)
    fig.suptitle(title or f"{dataset}: test frame {fid}", fontsize=9)
    fig.tight_layout(rect=(0.0, 0.05, 1.0, 1.0))
    _depth_scale(fig)
    return save_figure(fig, out_png, dpi=110)


#: Depths (m) marked on the DE colour scale.
DEPTH_TICKS_M: tuple[float, ...] = (DEPTH_FAR_M * math.exp(-DEPTH_LOG_K), 10.0, 30.0, 80.0, 300.0, DEPTH_FAR_M)


def _depth_scale(fig: Any) -> None:
    """The DE columns' grey scale under the grid: the cache's CARLA log depth x in [0, 1] shown
    linearly (a prediction above 1 as white), ticked in metres (x = 1 + ln(d / 1000 m) / 5.70378)."""
    import matplotlib as mpl

    cax = fig.add_axes((0.30, 0.022, 0.40, 0.012))
    sm = mpl.cm.ScalarMappable(norm=mpl.colors.Normalize(0.0, 1.0), cmap="gray")
    bar = fig.colorbar(sm, cax=cax, orientation="horizontal")
    bar.set_ticks([1.0 + math.log(d / DEPTH_FAR_M) / DEPTH_LOG_K for d in DEPTH_TICKS_M])
    bar.set_ticklabels([f"{d:.3g}" if d < 10 else f"{d:.0f}" for d in DEPTH_TICKS_M], fontsize=6)
    bar.set_label("DE: depth (m), log scale (CARLA log depth x; white: 1000 m far clip, sky, or x > 1)", fontsize=6)
