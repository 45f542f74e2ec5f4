"""Read the pipeline's outputs for the reports, with clear errors naming the bad file.

Inputs (ARCHITECTURE.md / SPEC 2), per run (one training seed ``k`` of a (dataset, model)):

- ``results/<ds>/<model>/seed<k>/metrics.json``: ``{"mae_de": {"mean", "var"}, ..., "tm", "mv",
  "n_frames", "source", "device"}`` with the keys of the tasks the model performs; ``tm`` is
  ``{"mean", "var"}``, ``mv`` is ``{"value", "definition"}`` (one number: eq. 7 of the four
  test-set means); older files with ``{"mean", "var"}`` or a plain float are read too; the
  optional ``class_iou``, ``depth`` and ``argmax`` blocks (metrics beyond the paper's; ``argmax``:
  the class maps scored by the arg-max rule) go to :attr:`ModelResult.extra`;
- ``results/<ds>/<trivial id>/metrics.json`` and ``data/eval/<ds>/<trivial id>/per_frame.csv``:
  the trivial predictors of the floor (:data:`compact_perception.core.floor_rule.FLOOR_PREDICTORS`,
  no seed; :func:`load_floor_results`, :func:`load_floor_frames`);
- ``data/eval/<ds>/<model>/seed<k>/per_frame.csv``: one row per test frame (``frame_id`` and
  the scores), read by :func:`load_frames` for the intervals (:mod:`compact_perception.stats`); ``inputs.npz`` and
  ``predictions.npz`` beside it (the qualitative figures);
- ``runs/<ds>/<model>/seed<k>/summary.json`` (``epochs_run``, ``best_epoch``, ``stop_reason``:
  ``plateau`` when early stopping ended it, ``max_epochs`` when the cap did; ``final_weights``)
  and the dvclive TSVs under ``…/seed<k>/live``;
- ``results/benchmark/efficiency.json`` (written by ``pipeline/benchmark.py``);
- ``data/cache/<ds>/meta.json`` (frame counts, resolution, source).

Runs: :func:`list_runs` is the one place of the report that knows which runs (seeds) of a
(dataset, model) exist; each is a :class:`compact_perception.core.layout.RunPaths`
(:func:`~compact_perception.core.layout.run_paths`, where every stage writes them). Given the seed
list of params.yaml (``seeds`` for the compact models, ``baseline_seeds`` for the baselines) it
lists exactly those seeds' runs that exist: a stale ``seed<k>`` folder of a seed no longer in the
list is ignored. Without a seed list (``None``) it lists every ``seed<k>`` folder. Every loader
below takes the seeds through it, and the seed list of a (dataset, model) through
:func:`seeds_for` (per model, or per dataset and model).

Comparisons (:func:`frame_comparison`): the per-frame scores of several rows on the frames all of
them scored, each row's runs keyed by training seed, and each frame's cluster (its episode or
scene, :func:`compact_perception.core.cache.frame_cluster`): the input of
:func:`compact_perception.stats.interval`.

Over seeds (:func:`aggregate_runs`): each metric's run-level value (a run's test-set mean; TM and
MV of the run's four test-set means, eq. 6-7 via :func:`compact_perception.core.catalog.scores_from_means`)
is averaged over the runs, with the sample standard deviation (n - 1) over them; the per-frame
variance the paper prints is averaged over the runs.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
import re
from typing import Any, Mapping, Optional, Sequence

import numpy as np
import pandas as pd

from ..core import catalog
from ..core.cache import frame_cluster
from ..core.errors import ReportInputError
from ..core.params import source_label
from ..core.io import read_json
from ..core.layout import RunPaths, cache_dir, floor_paths, run_paths
from ..stats import Comparison, Group, make_comparison
from .schema import COMBINATION, COMBINATION_SOURCE, FLOOR_IDS, PER_FRAME_COLUMNS, TABLE2_COLUMNS, TASK_COLUMNS

log = logging.getLogger(__name__)

#: Seed lists: per model id (params ``seeds`` / ``baseline_seeds`` by model group), per dataset
#: and model id (``{ds: {model: seeds}}``), one list for every model, or ``None`` (every
#: ``seed<k>`` folder found); :func:`seeds_for` reads it.
SeedSpec = Optional[Mapping[str, Any] | Sequence[int]]

#: Blocks of metrics.json beyond the paper's (written by ``compact_perception.evaluation.evaluate``).
EXTRA_KEYS: tuple[str, ...] = ("class_iou", "depth", "argmax")


@dataclass(frozen=True)
class Cell:
    """One metric of a model: ``mean`` (of one run, or the mean over seeds of the run-level
    values), ``var`` the variance over test frames (the paper's ``±``; the mean over seeds of
    each run's), ``std`` the sample standard deviation (n - 1) of the run-level values over
    the ``n_seeds`` runs (``None`` with one run)."""

    mean: float
    var: Optional[float] = None
    std: Optional[float] = None
    n_seeds: int = 1


@dataclass
class ModelResult:
    """One ``metrics.json`` (``seed`` set, ``runs`` empty), or a model's runs aggregated over
    seeds by :func:`aggregate_runs` (``runs`` the per-seed results, ``seeds`` their seeds)."""

    dataset: str
    model: str
    scores: dict[str, Cell]
    n_frames: Optional[int] = None
    source: Optional[str] = None
    device: Optional[str] = None
    extra: dict[str, Any] = field(default_factory=dict)
    seed: Optional[int] = None
    runs: list["ModelResult"] = field(default_factory=list)

    @property
    def n_seeds(self) -> int:
        return len(self.runs) if self.runs else 1

    @property
    def seeds(self) -> tuple[Optional[int], ...]:
        return tuple(r.seed for r in self.runs) if self.runs else (self.seed,)

    def per_run(self) -> list["ModelResult"]:
        """The per-seed results (itself for a single metrics file)."""
        return list(self.runs) if self.runs else [self]


def _num(v: Any, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
        raise ReportInputError(f"{where}: expected a finite number, got {v!r}")
    return float(v)


def read_metrics(path: Path, dataset: str = "", model: str = "") -> ModelResult:
    """Parse and validate one ``metrics.json``."""
    data = read_json(path)
    scores: dict[str, Cell] = {}
    for key in TABLE2_COLUMNS:
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
    if not any(k in scores for k in TASK_COLUMNS):
        raise ReportInputError(f"{path}: none of the task metrics {list(TASK_COLUMNS)} present")
    extra: dict[str, Any] = {}
    for key in EXTRA_KEYS:
        if key in data:
            if not isinstance(data[key], dict):
                raise ReportInputError(f"{path}: {key}: expected an object, got {type(data[key]).__name__}")
            extra[key] = data[key]
    n = data.get("n_frames")
    return ModelResult(dataset, model, scores, None if n is None else int(n), data.get("source"), data.get("device"),
                       extra)


def seeds_for(seeds: SeedSpec, model: str, dataset: str) -> Optional[tuple[int, ...]]:
    """The seed list of ``model`` (on ``dataset``) in ``seeds``: the one lookup of the report
    (``None``: every seed folder found)."""
    if seeds is None:
        return None
    if isinstance(seeds, Mapping):
        if isinstance(seeds.get(dataset), Mapping):
            seeds = seeds[dataset]
        if model not in seeds:
            return None
        return tuple(int(k) for k in seeds[model])
    return tuple(int(k) for k in seeds)


def _sample_std(values: Sequence[float]) -> Optional[float]:
    return float(np.std(np.asarray(values, dtype=float), ddof=1)) if len(values) > 1 else None


def aggregate_cells(cells: Sequence[Cell]) -> Cell:
    """Mean over runs of the run-level values, their sample std (n - 1; ``None`` for one run),
    and the mean of the per-frame variances (``None`` unless every run has one)."""
    if not cells:
        raise ValueError("aggregate_cells: no cells")
    means = [c.mean for c in cells]
    var = None if any(c.var is None for c in cells) else float(np.mean([c.var for c in cells]))
    return Cell(float(np.mean(means)), var, _sample_std(means), len(cells))


def with_derived(result: ModelResult, where: str = "") -> ModelResult:
    """``result`` with TM and MV recomputed from its four task means (eq. 6-7, the project's
    one implementation); a stored value that differs (an older file holding the mean of a
    per-frame MV) is logged and replaced. Models without the four tasks keep what they have."""
    means = {c: cell.mean for c, cell in result.scores.items() if c in TASK_COLUMNS}
    derived = catalog.scores_from_means(means)
    if not derived:
        return result
    scores = dict(result.scores)
    for c in catalog.SCORES.keys():
        info, old = catalog.SCORES[c], scores.get(c)
        if old is not None and abs(old.mean - derived[c]) > 1e-9:
            log.warning("%s: %s %.6g is not eq. %s of the four means (%.6g); the report uses the latter "
                        "(re-run evaluate)", where or f"{result.dataset}/{result.model}", c, old.mean,
                        info.equation, derived[c])
        # a per-frame score keeps its variance over test frames; MV is one number per run
        scores[c] = Cell(derived[c], old.var if (info.per_frame and old is not None) else None)
    return ModelResult(result.dataset, result.model, scores, result.n_frames, result.source, result.device,
                       result.extra, result.seed, list(result.runs))


def aggregate_runs(runs: Sequence[ModelResult]) -> ModelResult:
    """One model's runs (seeds) as one result: every score a :class:`Cell` over the runs
    (:func:`aggregate_cells`; a score only some runs have is left out and logged), ``runs`` the
    per-seed results (TM, MV recomputed per run, :func:`with_derived`)."""
    if not runs:
        raise ValueError("aggregate_runs: no runs")
    runs = [with_derived(r, str(r.seed)) for r in runs]
    first = runs[0]
    keys = [k for k in TABLE2_COLUMNS if any(k in r.scores for r in runs)]
    scores: dict[str, Cell] = {}
    for k in keys:
        have = [r.scores[k] for r in runs if k in r.scores]
        if len(have) != len(runs):
            log.warning("%s/%s: %s present in %d of %d runs; left out", first.dataset, first.model, k, len(have),
                        len(runs))
            continue
        scores[k] = aggregate_cells(have)
    frames = sorted({r.n_frames for r in runs if r.n_frames is not None})
    if len(frames) > 1:
        log.warning("%s/%s: the runs scored different numbers of test frames %s", first.dataset, first.model, frames)
    srcs = sorted({r.source for r in runs if r.source})
    devs = sorted({r.device for r in runs if r.device})
    return ModelResult(first.dataset, first.model, scores, frames[0] if frames else None,
                       "; ".join(srcs) or None, "; ".join(devs) or None, first.extra, None, list(runs))


def load_model_runs(root: Path, dataset: str, model: str, seeds: Optional[Sequence[int]] = None
                    ) -> list[ModelResult]:
    """The ``metrics.json`` of every run of (``dataset``, ``model``) that :func:`list_runs`
    lists and that has one (``seed`` set on each); runs without one are logged and skipped."""
    out = []
    for run in list_runs(root, dataset, model, seeds):
        if run.metrics_path.is_file():
            r = read_metrics(run.metrics_path, dataset, model)
            r.seed = run.seed
            out.append(r)
        else:
            log.warning("no metrics for %s/%s seed %s (%s missing)", dataset, model, run.seed, run.metrics_path)
    return out


def load_results(root: Path, datasets: Sequence[str], models: Sequence[str], seeds: SeedSpec = None
                 ) -> dict[str, dict[str, ModelResult]]:
    """Every (dataset, model) with at least one run's ``metrics.json`` (runs from
    :func:`list_runs` with the model's seeds), aggregated over its runs (:func:`aggregate_runs`);
    a (dataset, model) without any is logged and left out."""
    out: dict[str, dict[str, ModelResult]] = {}
    for ds in datasets:
        out[ds] = {}
        for m in models:
            runs = load_model_runs(root, ds, m, seeds_for(seeds, m, ds))
            if runs:
                out[ds][m] = aggregate_runs(runs)
            else:
                log.warning("no metrics for %s/%s", ds, m)
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


#: The facts of a run's ``summary.json`` the report shows (how deep it trained).
SUMMARY_FACTS: tuple[str, ...] = ("epochs_run", "best_epoch", "max_epochs", "stop_reason", "train_seconds",
                                  "stopped_early")
#: ``stop_reason`` of a run that converged (:data:`~compact_perception.core.catalog.STOP_PLATEAU`);
#: ``max_epochs`` (``STOP_CAP``) means the safety cap did.
CONVERGED = catalog.STOP_PLATEAU


@dataclass
class DatasetScale:
    """What this run did on one dataset (for the paper-vs-reproduced table and the index)."""

    dataset: str
    source: Optional[str] = None
    counts: dict[str, int] = field(default_factory=dict)
    resolution: Optional[int] = None
    has_dvs: Optional[bool] = None
    #: model -> one dict of summary facts per run (``seed`` included), in seed order
    epochs: dict[str, list[dict[str, Any]]] = field(default_factory=dict)
    #: test frames scored per run (``n_frames`` of the metrics files; several values if they differ)
    n_test_frames: tuple[int, ...] = ()
    #: model -> seeds of its runs with results
    seeds: dict[str, tuple[Optional[int], ...]] = field(default_factory=dict)


def collect_scale(root: Path, datasets: Sequence[str], models: Sequence[str],
                  results: Optional[dict[str, dict[str, ModelResult]]] = None,
                  seeds: SeedSpec = None) -> dict[str, DatasetScale]:
    """Frame counts, resolution, data source, test frames, seeds and epochs run, per dataset."""
    out: dict[str, DatasetScale] = {}
    for ds in datasets:
        sc = DatasetScale(ds)
        meta = read_meta(cache_dir(ds, root))
        if meta:
            sc.counts = {k: int(v) for k, v in (meta.get("counts") or {}).items()}
            sc.resolution = meta.get("resolution")
            sc.has_dvs = meta.get("has_dvs")
            src = meta.get("source")
            sc.source = source_label(src) if src else None
        for m in models:
            facts = []
            for run in list_runs(root, ds, m, seeds_for(seeds, m, ds)):
                summ = read_summary(run.run_dir)
                if summ:
                    facts.append({"seed": run.seed, **{k: summ.get(k) for k in SUMMARY_FACTS}})
            if facts:
                sc.epochs[m] = facts
        if results and ds in results:
            srcs = {s for r in results[ds].values() for s in (r.source or "").split("; ") if s}
            if srcs:
                sc.source = "; ".join(sorted(srcs))
            sc.n_test_frames = tuple(sorted({r.n_frames for res in results[ds].values() for r in res.per_run()
                                             if r.n_frames is not None}))
            sc.seeds = {m: res.seeds for m, res in results[ds].items()}
        out[ds] = sc
    return out


# ----------------------------------------------------------------------------- runs and per-frame scores
_SEED_DIR = re.compile(r"^seed(\d+)$")
_STALE_LOGGED: set[tuple] = set()   # stale seed folders already logged (once per run of the report)


def list_runs(root: Path, dataset: str, model: str, seeds: Optional[Sequence[int]] = None) -> list[RunPaths]:
    """The runs of (``dataset``, ``model``) under ``root``, sorted by seed.

    ``seeds`` given (params ``seeds`` / ``baseline_seeds``): the run of each listed seed ``k``
    whose ``runs/…/seed<k>``, ``results/…/seed<k>/metrics.json`` or ``data/eval/…/seed<k>``
    exists; ``seed<k>`` folders of other seeds are ignored (stale, logged). ``seeds`` ``None``:
    one run per ``seed<k>`` folder found (under runs/, results/ or data/eval/)."""
    root = Path(root)
    probe = run_paths(dataset, model, 0, root)           # its parents hold every seed<k> folder
    bases = (probe.run_dir.parent, probe.metrics_path.parent.parent, probe.eval_dir.parent)
    found = sorted({int(m.group(1)) for base in bases for p in (base.iterdir() if base.is_dir() else [])
                    if p.is_dir() and (m := _SEED_DIR.match(p.name))})
    if seeds is None:
        return [run_paths(dataset, model, k, root) for k in found]
    wanted = sorted({int(k) for k in seeds})
    stale = [k for k in found if k not in wanted]
    if stale and (str(root), dataset, model, tuple(stale)) not in _STALE_LOGGED:
        _STALE_LOGGED.add((str(root), dataset, model, tuple(stale)))
        log.info("%s/%s: ignoring seed folder(s) %s (not in the seed list %s)", dataset, model,
                 [f"seed{k}" for k in stale], wanted)
    runs = [run_paths(dataset, model, k, root) for k in wanted]
    return [p for p in runs if p.run_dir.is_dir() or p.metrics_path.is_file() or p.eval_dir.is_dir()]


def run_name(run: RunPaths) -> str:
    """``<ds>/<model>/seed<k>``: the ``run`` field of the plots' CSV files."""
    return f"{run.dataset}/{run.model}/seed{run.seed}"


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
    for c in list(columns) + [c for c in PER_FRAME_COLUMNS if c in df.columns and c not in columns]:
        vals = pd.to_numeric(df[c], errors="coerce")
        if not np.isfinite(vals.to_numpy(dtype=float)).all():
            raise ReportInputError(f"{path}: column {c!r} has a missing or non-numeric value")
        df[c] = vals.astype(float)
    return df.set_index("frame_id").sort_index()


def load_frames(root: Path, dataset: str, model: str, columns: Sequence[str] = (),
                seeds: Optional[Sequence[int]] = None) -> list[pd.DataFrame]:
    """Per-frame scores of every run of (``dataset``, ``model``) that :func:`list_runs` lists
    (with ``seeds``) and that has a ``per_frame.csv`` (``df.attrs["seed"]`` its seed); runs
    without one are logged and skipped."""
    return run_frames(list_runs(root, dataset, model, seeds), columns, f"{dataset}/{model}")


def run_frames(runs: Sequence[Any], columns: Sequence[str] = (), what: str = "") -> list[pd.DataFrame]:
    """Per-frame scores of every run of ``runs`` (each with ``eval_dir`` and ``seed``) whose
    ``eval_dir`` has a ``per_frame.csv`` (``df.attrs["seed"]`` its seed); with ``what`` (the
    runs' name in the log), a run without one is logged; runs without an ``eval_dir`` are skipped."""
    out = []
    for run in runs:
        if run.eval_dir is None:
            continue
        p = run.eval_dir / "per_frame.csv"
        if p.is_file():
            df = read_per_frame(p, columns)
            df.attrs["seed"] = run.seed
            out.append(df)
        elif what:
            log.warning("no per-frame scores for %s (%s missing)", what, p)
    return out


def pair_by_seed(runs: Sequence[Sequence[Any]], seed_of: Any) -> list[tuple[Any, ...]]:
    """Runs of several models matched into tuples: by seed value (the seeds all of them have, in
    order) when every run has a seed, else by position (as many as the model with the fewest)."""
    if not runs or not all(runs):
        return []
    seeds = [[seed_of(r) for r in g] for g in runs]
    if all(k is not None for g in seeds for k in g):
        common = sorted(set.intersection(*(set(g) for g in seeds)))
        return [tuple(g[seeds[i].index(k)] for i, g in enumerate(runs)) for k in common]
    n = min(len(g) for g in runs)
    return [tuple(g[k] for g in runs) for k in range(n)]


def combination_frames(frames: dict[str, list[pd.DataFrame]]) -> list[pd.DataFrame]:
    """Per-frame scores of the combination of baselines (SPEC 6): each task metric of the model
    that gives it (:data:`~.schema.COMBINATION_SOURCE`: ``mae_de``, ``iou_ss`` of GradNorm,
    ``iou_ls`` of PolarNet, ``iou_bevp`` of Chen et al.), joined on ``frame_id`` (frames all of
    them scored). One combination run per training seed the source models all have
    (:func:`pair_by_seed`); empty if one has no per-frame scores."""
    sources = sorted(set(COMBINATION_SOURCE.values()))
    if not all(frames.get(m) for m in sources):
        return []
    for c, m in COMBINATION_SOURCE.items():
        if any(c not in df.columns for df in frames[m]):
            log.warning("combination: the per-frame scores of %s lack %r; no per-frame combination", m, c)
            return []
    out = []
    for group in pair_by_seed([frames[m] for m in sources], lambda df: df.attrs.get("seed")):
        run = dict(zip(sources, group))
        parts = [run[m][[c]] for c, m in COMBINATION_SOURCE.items()]
        joined = pd.concat(parts, axis=1, join="inner").sort_index()[list(COMBINATION_SOURCE)]
        joined.attrs["seed"] = group[0].attrs.get("seed")
        out.append(joined)
    return out


def common_frames(groups: Sequence[Sequence[pd.DataFrame]]) -> pd.Index:
    """The frame ids every run of every group scored, sorted (errors if there is none)."""
    common: Optional[pd.Index] = None
    for g in groups:
        for df in g:
            common = df.index if common is None else common.intersection(df.index)
    if common is None or len(common) == 0:
        raise ReportInputError("per-frame scores: the runs compared share no test frame")
    return common.sort_values()


def frame_comparison(groups: Sequence[Sequence[pd.DataFrame]], columns: Sequence[str],
                     fixed: Sequence[bool] = ()) -> Comparison:
    """The :class:`~compact_perception.stats.Comparison` of ``groups`` (one per row compared, its
    runs) on ``columns``: the frames all runs scored (:func:`common_frames`), each group's runs
    keyed by training seed (``df.attrs["seed"]``), the frames' clusters from their ids (episode or
    scene, :func:`~compact_perception.core.cache.frame_cluster`). ``fixed[g]``: group g is a
    deterministic predictor (the floor), one run without training randomness."""
    common = common_frames(groups)
    out = []
    for gi, g in enumerate(groups):
        keys = [df.attrs.get("seed") for df in g]
        keys = keys if all(isinstance(k, int) for k in keys) and len(set(keys)) == len(keys) else list(range(len(g)))
        runs = {int(k): df.loc[common, list(columns)].to_numpy(dtype=float) for k, df in zip(keys, g)}
        out.append(Group(runs, bool(fixed[gi]) if gi < len(fixed) else False))
    return make_comparison(out, [frame_cluster(str(f)) for f in common])


def load_row_frames(root: Path, dataset: str, models: Sequence[str], seeds: SeedSpec = None
                    ) -> dict[str, list[pd.DataFrame]]:
    """Per-frame scores of every model of ``dataset`` with any (all its runs of ``seeds``), plus
    the ``combination`` of baselines (:func:`combination_frames`) when its three sources have them."""
    frames = {m: load_frames(root, dataset, m, seeds=seeds_for(seeds, m, dataset)) for m in models}
    frames = {m: f for m, f in frames.items() if f}
    comb = combination_frames(frames)
    if comb:
        frames[COMBINATION] = comb
    return frames


# ----------------------------------------------------------------------------- the floor
def load_floor_results(root: Path, dataset: str) -> dict[str, ModelResult]:
    """The ``metrics.json`` of every trivial predictor of ``dataset`` that has one (:data:`~.schema.FLOOR_IDS`
    order; TM and MV of its four means, :func:`with_derived`)."""
    out = {}
    for tid in FLOOR_IDS:
        path = floor_paths(dataset, tid, root).metrics_path
        if path.is_file():
            out[tid] = with_derived(read_metrics(path, dataset, tid))
    if not out:
        log.warning("%s: no trivial-predictor results (results/%s/<%s>/metrics.json): no floor", dataset, dataset,
                    "|".join(FLOOR_IDS))
    return out


def load_floor_frames(root: Path, dataset: str) -> dict[str, pd.DataFrame]:
    """The per-frame scores of every trivial predictor of ``dataset`` that has them (one run each)."""
    out = {}
    for tid in FLOOR_IDS:
        path = floor_paths(dataset, tid, root).eval_dir / "per_frame.csv"
        if path.is_file():
            out[tid] = read_per_frame(path)
    return out
