"""Read the pipeline's outputs for the reports, with clear errors naming the bad file.

Inputs (ARCHITECTURE.md / SPEC 2):

- ``results/<ds>/<model>/metrics.json``: ``{"mae_de": {"mean", "var"}, ..., "tm", "mv",
  "n_frames", "source", "device"}`` with the keys of the tasks the model performs; ``tm`` is
  ``{"mean", "var"}``, ``mv`` is ``{"value", "definition"}`` (one number: eq. 7 of the four
  test-set means); older files with ``{"mean", "var"}`` or a plain float are read too; the
  optional ``class_iou`` and ``depth`` blocks (metrics beyond the paper's) go to
  :attr:`ModelResult.extra`;
- ``data/eval/<ds>/<model>/per_frame.csv``: one row per test frame (``frame_id`` and the
  scores), read by :func:`load_frames` for the bootstrap statistics;
- ``results/benchmark/efficiency.json`` (written by ``pipeline/benchmark.py``);
- ``runs/<ds>/<model>/summary.json`` and the dvclive TSVs under ``runs/<ds>/<model>/live``;
- ``data/cache/<ds>/meta.json`` (frame counts, resolution, source).

Runs: :func:`list_runs` is the one place that knows where the runs (seeds) of a (dataset,
model) live: today one run, ``runs/<ds>/<model>`` with ``results/<ds>/<model>`` and
``data/eval/<ds>/<model>``; when ``runs/<ds>/<model>/seed<k>/`` folders exist, one run per
such folder (``results/…/seed<k>``, ``data/eval/…/seed<k>``).
"""
from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
import re
from typing import Any, Optional, Sequence

import numpy as np
import pandas as pd

log = logging.getLogger(__name__)

TASK_METRICS: tuple[str, ...] = ("mae_de", "iou_ss", "iou_ls", "iou_bevp")
SCORE_KEYS: tuple[str, ...] = TASK_METRICS + ("tm", "mv")
#: Blocks of metrics.json beyond the paper's (written by ``compact_perception.evaluate``).
EXTRA_KEYS: tuple[str, ...] = ("class_iou", "depth")
#: The model each task of the combination of baselines comes from (paper section V-D, SPEC 6).
COMBINATION_SOURCE: dict[str, str] = {
    "mae_de": "gradnorm_segnet", "iou_ss": "gradnorm_segnet", "iou_ls": "polarnet", "iou_bevp": "chen_bev",
}
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
    extra: dict[str, Any] = field(default_factory=dict)


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
        if isinstance(v, dict) and key == "mv" and "value" in v:
            scores[key] = Cell(_num(v["value"], f"{where}.value"))
        elif isinstance(v, dict):
            if "mean" not in v:
                raise ReportInputError(f"{where}: missing 'mean'")
            var = v.get("var")
            scores[key] = Cell(_num(v["mean"], f"{where}.mean"), None if var is None else _num(var, f"{where}.var"))
        else:
            scores[key] = Cell(_num(v, where))
    if not any(k in scores for k in TASK_METRICS):
        raise ReportInputError(f"{path}: none of the task metrics {list(TASK_METRICS)} present")
    extra: dict[str, Any] = {}
    for key in EXTRA_KEYS:
        if key in data:
            if not isinstance(data[key], dict):
                raise ReportInputError(f"{path}: {key}: expected an object, got {type(data[key]).__name__}")
            extra[key] = data[key]
    n = data.get("n_frames")
    return ModelResult(dataset, model, scores, None if n is None else int(n), data.get("source"), data.get("device"),
                       extra)


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
            runs = list_runs(root, ds, m)
            summ = read_summary(runs[0].run_dir) if runs else None
            if summ:
                sc.epochs[m] = {k: summ.get(k) for k in ("epochs_run", "best_epoch", "max_epochs", "train_seconds", "stopped_early")}
        if results and ds in results:
            srcs = {r.source for r in results[ds].values() if r.source}
            if srcs:
                sc.source = "; ".join(sorted(srcs))
        out[ds] = sc
    return out


# ----------------------------------------------------------------------------- runs and per-frame scores
_SEED_DIR = re.compile(r"^seed(\d+)$")


@dataclass(frozen=True)
class RunRef:
    """Where one run (one training seed) of a (dataset, model) keeps its outputs."""

    dataset: str
    model: str
    seed: Optional[int]            # None: the single run of today's layout
    run_dir: Path                  # runs/<ds>/<model>[/seed<k>]: summary.json, live/
    metrics_path: Path             # results/<ds>/<model>[/seed<k>]/metrics.json
    eval_dir: Path                 # data/eval/<ds>/<model>[/seed<k>]: per_frame.csv, npz files


def list_runs(root: Path, dataset: str, model: str) -> list[RunRef]:
    """The runs of (``dataset``, ``model``) under ``root``, sorted by seed: one per
    ``runs/<ds>/<model>/seed<k>/`` folder if there are any, else the single run
    ``runs/<ds>/<model>`` (listed whenever its run, metrics or per-frame folder exists)."""
    root = Path(root)
    base_run, base_res, base_eval = (root / "runs" / dataset / model, root / "results" / dataset / model,
                                     root / "data" / "eval" / dataset / model)
    seeds = sorted(int(m.group(1)) for p in (base_run.iterdir() if base_run.is_dir() else [])
                   if p.is_dir() and (m := _SEED_DIR.match(p.name)))
    if seeds:
        return [RunRef(dataset, model, k, base_run / f"seed{k}", base_res / f"seed{k}" / "metrics.json",
                       base_eval / f"seed{k}") for k in seeds]
    if base_run.is_dir() or (base_res / "metrics.json").is_file() or base_eval.is_dir():
        return [RunRef(dataset, model, None, base_run, base_res / "metrics.json", base_eval)]
    return []


def read_per_frame(path: Path, columns: Sequence[str] = ()) -> pd.DataFrame:
    """One ``per_frame.csv`` indexed by ``frame_id`` (errors name the file): ``columns`` must be
    present, finite, and frame ids unique."""
    try:
        df = pd.read_csv(path, dtype={"frame_id": str})
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as err:
        raise ReportInputError(f"{path}: unreadable CSV ({err})") from None
    if "frame_id" not in df.columns:
        raise ReportInputError(f"{path}: no 'frame_id' column")
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise ReportInputError(f"{path}: missing column(s) {missing}")
    if df["frame_id"].duplicated().any():
        raise ReportInputError(f"{path}: duplicate frame_id {df.loc[df['frame_id'].duplicated(), 'frame_id'].iloc[0]!r}")
    for c in list(columns) + [c for c in TASK_METRICS + ("tm",) if c in df.columns and c not in columns]:
        vals = pd.to_numeric(df[c], errors="coerce")
        if not np.isfinite(vals.to_numpy(dtype=float)).all():
            raise ReportInputError(f"{path}: column {c!r} has a missing or non-numeric value")
        df[c] = vals.astype(float)
    return df.set_index("frame_id").sort_index()


def load_frames(root: Path, dataset: str, model: str, columns: Sequence[str] = ()) -> list[pd.DataFrame]:
    """Per-frame scores of every run of (``dataset``, ``model``) that has a ``per_frame.csv``
    (see :func:`list_runs`); runs without one are logged and skipped."""
    out = []
    for run in list_runs(root, dataset, model):
        p = run.eval_dir / "per_frame.csv"
        if p.is_file():
            out.append(read_per_frame(p, columns))
        else:
            log.warning("no per-frame scores for %s/%s (%s missing)", dataset, model, p)
    return out


def combination_frames(frames: dict[str, list[pd.DataFrame]]) -> list[pd.DataFrame]:
    """Per-frame scores of the combination of baselines (SPEC 6): ``mae_de``, ``iou_ss`` of
    GradNorm, ``iou_ls`` of PolarNet, ``iou_bevp`` of Chen et al., joined on ``frame_id``
    (frames all three scored). Run k of the combination joins run k of each baseline (as
    many runs as the baseline with the fewest); empty if a baseline has no per-frame scores."""
    sources = sorted(set(COMBINATION_SOURCE.values()))
    if not all(frames.get(m) for m in sources):
        return []
    for c, m in COMBINATION_SOURCE.items():
        if any(c not in df.columns for df in frames[m]):
            log.warning("combination: the per-frame scores of %s lack %r; no per-frame combination", m, c)
            return []
    n = min(len(frames[m]) for m in sources)
    out = []
    for k in range(n):
        parts = [frames[m][k][[c]] for c, m in COMBINATION_SOURCE.items()]
        joined = pd.concat(parts, axis=1, join="inner").sort_index()
        out.append(joined[list(COMBINATION_SOURCE)])
    return out


def align(groups: Sequence[Sequence[pd.DataFrame]], columns: Sequence[str]) -> list[list[np.ndarray]]:
    """The (frames, columns) arrays of every run of every group on the frames all of them
    scored (sorted by frame id), for a paired bootstrap."""
    common: Optional[pd.Index] = None
    for g in groups:
        for df in g:
            common = df.index if common is None else common.intersection(df.index)
    if common is None or len(common) == 0:
        raise ReportInputError("per-frame scores: the runs compared share no test frame")
    common = common.sort_values()
    return [[df.loc[common, list(columns)].to_numpy(dtype=float) for df in g] for g in groups]


def load_row_frames(root: Path, dataset: str, models: Sequence[str]) -> dict[str, list[pd.DataFrame]]:
    """Per-frame scores of every model of ``dataset`` with any (all its runs), plus the
    ``combination`` of baselines (:func:`combination_frames`) when its three sources have them."""
    frames = {m: load_frames(root, dataset, m) for m in models}
    frames = {m: f for m, f in frames.items() if f}
    comb = combination_frames(frames)
    if comb:
        frames["combination"] = comb
    return frames
