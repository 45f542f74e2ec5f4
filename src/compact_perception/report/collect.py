"""Read the pipeline's outputs for the reports, with clear errors naming the bad file.

Inputs (ARCHITECTURE.md / SPEC 2):

- ``results/<ds>/<model>/metrics.json``: ``{"mae_de": {"mean", "var"}, ..., "tm", "mv",
  "n_frames", "source", "device"}`` with the keys of the tasks the model performs; ``tm`` /
  ``mv`` may be ``{"mean", "var"}`` or a plain float;
- ``results/benchmark/efficiency.json`` (written by ``pipeline/benchmark.py``);
- ``runs/<ds>/<model>/summary.json`` and the dvclive TSVs under ``runs/<ds>/<model>/live``;
- ``data/cache/<ds>/meta.json`` (frame counts, resolution, source).
"""
from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import numpy as np
import pandas as pd

log = logging.getLogger(__name__)

TASK_METRICS: tuple[str, ...] = ("mae_de", "iou_ss", "iou_ls", "iou_bevp")
SCORE_KEYS: tuple[str, ...] = TASK_METRICS + ("tm", "mv")
#: Human-readable data sources (as ``compact_perception.evaluate`` writes them).
SOURCE_LABEL: dict[str, str] = {
    "sim": "simulated (embedded world)",
    "authors": "authors' CARLA dataset",
    "nuscenes-lidarseg": "nuScenes-lidarseg",
}


class ReportInputError(ValueError):
    """A report input is malformed; the message names the file and key."""


@dataclass(frozen=True)
class Cell:
    """A mean (and, for task metrics, the variance over test frames)."""

    mean: float
    var: Optional[float] = None


@dataclass
class ModelResult:
    """One ``metrics.json``."""

    dataset: str
    model: str
    scores: dict[str, Cell]
    n_frames: Optional[int] = None
    source: Optional[str] = None
    device: Optional[str] = None


def _num(v: Any, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
        raise ReportInputError(f"{where}: expected a finite number, got {v!r}")
    return float(v)


def read_json(path: Path) -> dict[str, Any]:
    """Parse a JSON object; errors name the file."""
    try:
        data = json.loads(Path(path).read_text())
    except json.JSONDecodeError as err:
        raise ReportInputError(f"{path}: not valid JSON ({err})") from None
    if not isinstance(data, dict):
        raise ReportInputError(f"{path}: expected a JSON object")
    return data


def read_metrics(path: Path, dataset: str = "", model: str = "") -> ModelResult:
    """Parse and validate one ``metrics.json``."""
    data = read_json(path)
    scores: dict[str, Cell] = {}
    for key in SCORE_KEYS:
        if key not in data:
            continue
        v = data[key]
        where = f"{path}: {key}"
        if isinstance(v, dict):
            if "mean" not in v:
                raise ReportInputError(f"{where}: missing 'mean'")
            var = v.get("var")
            scores[key] = Cell(_num(v["mean"], f"{where}.mean"), None if var is None else _num(var, f"{where}.var"))
        else:
            scores[key] = Cell(_num(v, where))
    if not any(k in scores for k in TASK_METRICS):
        raise ReportInputError(f"{path}: none of the task metrics {list(TASK_METRICS)} present")
    n = data.get("n_frames")
    return ModelResult(dataset, model, scores, None if n is None else int(n), data.get("source"), data.get("device"))


def load_results(results_dir: Path, datasets: tuple[str, ...] | list[str],
                 models: tuple[str, ...] | list[str]) -> dict[str, dict[str, ModelResult]]:
    """All present ``results/<ds>/<model>/metrics.json``; missing ones are logged and skipped."""
    out: dict[str, dict[str, ModelResult]] = {}
    for ds in datasets:
        out[ds] = {}
        for m in models:
            p = Path(results_dir) / ds / m / "metrics.json"
            if p.is_file():
                out[ds][m] = read_metrics(p, ds, m)
            else:
                log.warning("no metrics for %s/%s (%s missing)", ds, m, p)
    return out


def read_tsv_metric(live_dir: Path, name: str) -> Optional[pd.Series]:
    """A dvclive metric as a Series indexed by step (``live/plots/metrics/<name>.tsv``;
    nested names are sub-folders). ``None`` if the file does not exist."""
    path = Path(live_dir) / "plots" / "metrics" / f"{name}.tsv"
    if not path.is_file():
        return None
    try:
        df = pd.read_csv(path, sep="\t")
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as err:
        raise ReportInputError(f"{path}: unreadable TSV ({err})") from None
    col = name.rsplit("/", 1)[-1]
    if "step" not in df.columns or col not in df.columns:
        raise ReportInputError(f"{path}: expected columns 'step' and {col!r}, got {list(df.columns)}")
    s = pd.Series(df[col].to_numpy(dtype=float), index=df["step"].to_numpy(dtype=int), name=col)
    return s[~s.index.duplicated(keep="last")].sort_index()


def read_summary(run_dir: Path) -> Optional[dict[str, Any]]:
    p = Path(run_dir) / "summary.json"
    return read_json(p) if p.is_file() else None


def read_meta(cache_dir: Path) -> Optional[dict[str, Any]]:
    p = Path(cache_dir) / "meta.json"
    return read_json(p) if p.is_file() else None


def load_npz(path: Path) -> Optional[dict[str, np.ndarray]]:
    """All arrays of an npz (``None`` if the file is absent)."""
    if not Path(path).is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (OSError, ValueError) as err:
        raise ReportInputError(f"{path}: unreadable npz ({err})") from None


@dataclass
class DatasetScale:
    """What this run did on one dataset (for the paper-vs-reproduced table and the index)."""

    dataset: str
    source: Optional[str] = None
    counts: dict[str, int] = field(default_factory=dict)
    resolution: Optional[int] = None
    has_dvs: Optional[bool] = None
    epochs: dict[str, dict[str, Any]] = field(default_factory=dict)   # model -> summary facts


def collect_scale(root: Path, datasets: list[str] | tuple[str, ...], models: list[str] | tuple[str, ...],
                  results: Optional[dict[str, dict[str, ModelResult]]] = None) -> dict[str, DatasetScale]:
    """Frame counts, resolution, data source and epochs run, per dataset."""
    out: dict[str, DatasetScale] = {}
    for ds in datasets:
        sc = DatasetScale(ds)
        meta = read_meta(Path(root) / "data" / "cache" / ds)
        if meta:
            sc.counts = {k: int(v) for k, v in (meta.get("counts") or {}).items()}
            sc.resolution = meta.get("resolution")
            sc.has_dvs = meta.get("has_dvs")
            src = meta.get("source")
            sc.source = SOURCE_LABEL.get(src, src) if src else None
        for m in models:
            summ = read_summary(Path(root) / "runs" / ds / m)
            if summ:
                sc.epochs[m] = {k: summ.get(k) for k in ("epochs_run", "best_epoch", "max_epochs", "train_seconds", "stopped_early")}
        if results and ds in results:
            srcs = {r.source for r in results[ds].values() if r.source}
            if srcs:
                sc.source = "; ".join(sorted(srcs))
        out[ds] = sc
    return out
