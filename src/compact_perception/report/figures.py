"""Report figures (SPEC 8): loss weights per epoch (Fig. 8), validation curves, and the
qualitative grids (Fig. 6/7). Matplotlib with the Agg backend; PNGs written atomically.

The qualitative grid (Fig. 6/7) lives in :mod:`.qualitative`.

Every (dataset, model) has one run per training seed: the loss-weight and curve figures draw
the mean over the seeds (thick) with each seed's run (thin); the qualitative grid shows one
run per model (the first seed), as the caption says.

Top-view images (LiDAR, LS, BEVP) are on the grid of eq. (2)-(3): row i grows forward (+x),
column j grows to the left (+y). They are drawn rotated by 180 degrees so that forward is up
and the ego's left is on the left of the picture.
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Mapping, Optional, Sequence, Union

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.ticker import MaxNLocator  # noqa: E402

from .collect import read_summary, read_tsv_metric  # noqa: E402
from ..data.qualitative import plot_qualitative, save_figure  # noqa: E402,F401  (plot_qualitative: re-export)
from .schema import ROW_LABEL, WEIGHT_KEYS, WEIGHT_LABEL, WEIGHT_PREFIX, weight_key, weight_task  # noqa: E402

log = logging.getLogger(__name__)


# ----------------------------------------------------------------------------- training logs
def read_val_curve(run_dir: Path) -> Optional[pd.Series]:
    """A run's validation TM per epoch: dvclive's ``val/tm`` where logged (the compact models),
    else ``val_score`` (the selection score: TM for the compact model, the model's own share of TM
    for a baseline). ``None`` if neither exists."""
    live = Path(run_dir) / "live"
    s = read_tsv_metric(live, "val/tm")
    if s is None:
        s = read_tsv_metric(live, "val_score")
    return s


def read_weight_curves(run_dir: Path) -> dict[str, pd.Series]:
    """Every loss weight a run logged (dvclive ``w_<task>.tsv``), task id -> weight per epoch;
    the paper's four tasks first, in order."""
    mdir = Path(run_dir) / "live" / "plots" / "metrics"
    names = sorted(p.stem for p in mdir.glob(f"{WEIGHT_PREFIX}*.tsv")) if mdir.is_dir() else []
    names = [n for n in WEIGHT_KEYS if n in names] + [n for n in names if n not in WEIGHT_KEYS]
    out = {}
    for n in names:
        s = read_tsv_metric(Path(run_dir) / "live", n)
        if s is not None and len(s):
            out[weight_task(n)] = s
    return out


def mean_curve(series: Sequence[pd.Series]) -> pd.Series:
    """Mean over runs per epoch (over the runs that reached that epoch)."""
    return pd.concat(list(series), axis=1).mean(axis=1).sort_index()


RunDirs = Union[Path, Sequence[Path]]


def _as_runs(runs: RunDirs) -> list[Path]:
    return [Path(runs)] if isinstance(runs, (str, Path)) else [Path(r) for r in runs]


# ----------------------------------------------------------------------------- Fig. 8
def plot_loss_weights(runs: Union[RunDirs, Mapping[str, RunDirs]], out_png: Path, title: str = "") -> Optional[Path]:
    """Loss weights per epoch (Fig. 8): one panel per entry of ``runs`` (panel title -> the run
    folders of its seeds; a folder or a list of folders makes one panel). Per task the mean over
    seeds (thick) and every seed's run (thin); dashed black lines at each seed's best epoch; the
    legend gives the final weights (mean over seeds). ``None`` if no run has weight logs."""
    panels = dict(runs) if isinstance(runs, Mapping) else {"": runs}
    data = {}
    for name, dirs in panels.items():
        curves = [(d, read_weight_curves(d)) for d in _as_runs(dirs)]
        curves = [(d, c) for d, c in curves if c]
        if curves:
            data[name] = curves
    if not data:
        log.warning("no loss-weight logs for %s; skipping %s", list(panels), out_png)
        return None
    fig, axes = plt.subplots(1, len(data), figsize=(6.4 * len(data), 3.8), squeeze=False)
    for ax, (name, curves) in zip(axes[0], data.items()):
        tasks = list(dict.fromkeys(t for _, c in curves for t in c))
        finals = {t: [] for t in tasks}
        for d, c in curves:
            summ = read_summary(d) or {}
            fw = summ.get("final_weights") or {}
            for t, s in c.items():
                finals[t].append(float(fw.get(weight_key(t), s.iloc[-1])))
            best = summ.get("best_epoch")
            if isinstance(best, int) and best >= 0:
                ax.axvline(best, color="black", linestyle="--", linewidth=0.8, alpha=0.6)
        for i, t in enumerate(tasks):
            colour = f"C{i}"
            series = [c[t] for _, c in curves if t in c]
            for s in series if len(series) > 1 else []:
                ax.plot(s.index, s.values, color=colour, linewidth=0.7, alpha=0.35)
            m = mean_curve(series)
            label = f"{WEIGHT_LABEL.get(weight_key(t), t.upper())}: {np.mean(finals[t]):.3f}"
            ax.plot(m.index, m.values, color=colour, marker="o", markersize=3, linewidth=1.8, label=label)
        ax.plot([], [], color="black", linestyle="--", linewidth=0.8, label="best epoch (per seed)")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_xlabel("epoch")
        ax.set_ylabel("loss weight")
        n = len(curves)
        ax.set_title((f"{name}: " if name else "") + (f"mean of {n} seeds (thin: each seed)" if n > 1 else "1 seed"),
                     fontsize=9)
        ax.legend(title="final weights" + (" (mean over seeds)" if n > 1 else ""), fontsize=8, loc="best")
        ax.grid(alpha=0.3)
    fig.suptitle(title or "Loss weights per epoch", fontsize=10)
    return save_figure(fig, out_png)


# ----------------------------------------------------------------------------- curves
def plot_training_curves(runs: Mapping[str, RunDirs], out_png: Path, title: str = "") -> Optional[Path]:
    """Validation score per epoch per model (:func:`read_val_curve`; ``runs``: model -> the run
    folders of its seeds): the mean over seeds (thick), each seed (thin), dots at each seed's
    best epoch."""
    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    drawn = 0
    for i, (model, dirs) in enumerate(runs.items()):
        curves = [(d, read_val_curve(d)) for d in _as_runs(dirs)]
        curves = [(d, s) for d, s in curves if s is not None and len(s)]
        if not curves:
            continue
        colour = f"C{i % 10}"
        m = mean_curve([s for _, s in curves])
        n = len(curves)
        ax.plot(m.index, m.values, color=colour, linewidth=1.6,
                label=ROW_LABEL.get(model, model) + (f" (mean of {n})" if n > 1 else ""))
        for d, s in curves:
            if n > 1:
                ax.plot(s.index, s.values, color=colour, linewidth=0.6, alpha=0.35)
            best = (read_summary(Path(d)) or {}).get("best_epoch")
            if isinstance(best, int) and best in s.index:
                ax.plot([best], [s.loc[best]], "o", color=colour, markersize=3)
        drawn += 1
    if not drawn:
        plt.close(fig)
        log.warning("no validation curves for %s", out_png)
        return None
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("epoch")
    ax.set_ylabel("validation TM (baselines: own tasks' share)")
    ax.set_title(title or "Validation TM per epoch")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    return save_figure(fig, out_png)
