"""The record of runs trained to their plateau (``benchmarks/records/full_plateau.json``): its one
definition, below both its writer (``benchmarks/record_plateau.py``: :func:`record_runs`) and its
reader (the report: :func:`compact_perception.report.plateau.load_record`), so neither imports the
other.

The record holds, per run (dataset, model, seed): how it stopped (``epochs_run``, ``best_epoch``,
``max_epochs``, ``stop_reason``, ``train_seconds`` from ``summary.json``), its test-set margin
over the floor per task metric (``floor_margin`` of ``metrics.json``, positive = better than the
better trivial predictor), and the settings it was trained under (:func:`settings_at`); with the
scale, commit, machine and command that made it.

Its schema (:data:`RUN_KEYS`, :func:`run_problem`, :func:`record_problem`) says what each run and
the record itself must hold, by type and range: the writer checks every run before anything is
written, and the reader checks what it reads, so neither can accept what the other refuses. Each
check answers with the first problem as ``<field>: expected <what> (got <value>)``, the value
shown bounded.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Callable, Mapping, Optional, Sequence

from .catalog import DATASETS, MODELS, STOP_CAP, STOP_PLATEAU
from .errors import ReportInputError
from .io import read_json
from .layout import run_paths
from .params_base import SCALES
from .params_errors import shown

__all__ = ["RECORD_VERSION", "RUN_KEYS", "SUMMARY_KEYS", "NEUTRAL_KEYS", "run_problem", "record_problem",
           "settings_at", "record_runs"]

RECORD_VERSION = 1

#: The keys of a run that come from its ``summary.json``.
SUMMARY_KEYS: tuple[str, ...] = ("epochs_run", "best_epoch", "max_epochs", "stop_reason", "train_seconds")


def _int_at_least(lo: int) -> Callable[[Any], bool]:
    return lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= lo


def _finite(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _margins(v: Any) -> bool:
    return isinstance(v, dict) and bool(v) and all(isinstance(k, str) and _finite(x) for k, x in v.items())


def _settings(v: Any) -> bool:
    return isinstance(v, dict) and all(isinstance(k, str) for k in v)


#: Each key of a run: the check its value must pass and what that means, in the error's words.
RUN_KEYS: dict[str, tuple[Callable[[Any], bool], str]] = {
    "dataset": (lambda v: isinstance(v, str) and v in DATASETS, f"one of {sorted(DATASETS)}"),
    "model": (lambda v: isinstance(v, str) and v in MODELS, f"one of {sorted(MODELS)}"),
    "seed": (_int_at_least(0), "an integer of at least 0"),
    "epochs_run": (_int_at_least(1), "an integer of at least 1"),
    "best_epoch": (_int_at_least(0), "an integer of at least 0 (the best epoch, counted from 0)"),
    "max_epochs": (_int_at_least(1), "an integer of at least 1"),
    "stop_reason": (lambda v: v in (STOP_PLATEAU, STOP_CAP), f"{STOP_PLATEAU!r} or {STOP_CAP!r}"),
    "train_seconds": (lambda v: _finite(v) and v >= 0, "a finite number of at least 0"),
    "floor_margin": (_margins, "a non-empty mapping of metric name to a finite number"),
    "settings": (_settings, "a mapping of params key to value"),
}


def run_problem(run: Any, keys: tuple[str, ...] = tuple(RUN_KEYS)) -> Optional[str]:
    """The first problem of ``run`` (a record's run, or the part of one named by ``keys``) as
    ``<field>: expected ... (got ...)``; ``None`` when it holds what the record promises."""
    if not isinstance(run, Mapping):
        return f"expected a mapping of {', '.join(keys)} (got {shown(run)})"
    for key in keys:
        check, what = RUN_KEYS[key]
        if key not in run:
            return f"{key}: missing (expected {what})"
        if not check(run[key]):
            return f"{key}: expected {what} (got {shown(run[key])})"
    if {"best_epoch", "epochs_run"} <= set(keys) and run["best_epoch"] >= run["epochs_run"]:
        return f"best_epoch: expected below epochs_run ({run['epochs_run']}) (got {run['best_epoch']})"
    if {"epochs_run", "max_epochs"} <= set(keys) and run["epochs_run"] > run["max_epochs"]:
        return f"epochs_run: expected at most max_epochs ({run['max_epochs']}) (got {run['epochs_run']})"
    return None


def record_problem(data: Any) -> Optional[str]:
    """The first problem of a whole record (its version, scale, provenance and every run), the
    run named by its index (``runs[2].epochs_run: ...``); ``None`` for a sound record."""
    if not isinstance(data, Mapping):
        return f"expected a JSON object (got {shown(data)})"
    if data.get("version") != RECORD_VERSION:
        return f"version: expected {RECORD_VERSION} (got {shown(data.get('version'))})"
    if data.get("scale") not in SCALES:
        return f"scale: expected one of {list(SCALES)} (got {shown(data.get('scale'))})"
    for key in ("commit", "machine", "command"):
        if not isinstance(data.get(key, ""), str):
            return f"{key}: expected text (got {shown(data[key])})"
    if not isinstance(data.get("runs"), list):
        return f"runs: expected a list (got {shown(data.get('runs'))})"
    for i, run in enumerate(data["runs"]):
        problem = run_problem(run)
        if problem:
            return f"runs[{i}]" + ("." if isinstance(run, Mapping) else ": ") + problem
    return None


# ----------------------------------------------------------------------------- what a run was trained under
#: Settings that change no result (the pipeline's promise: any worker, process or run count gives
#: the same bytes; which test frame a figure shows, how many predictions are saved).
NEUTRAL_KEYS: tuple[str, ...] = ("world.workers", "preprocess.workers", "train.num_workers", "train.parallel_runs",
                                 "train.cuda_graphs",  # a CPU never captures; a GPU only a step bit-equal to eager
                                 "evaluate.figure_frame", "evaluate.save_predictions")


def _resolve(value: Any, scale: str) -> Any:
    """``value`` (plain params data) with every per-scale mapping replaced by its value at ``scale``."""
    if isinstance(value, dict):
        if value and set(value) == set(SCALES):
            return _resolve(value[scale], scale)
        return {k: _resolve(v, scale) for k, v in value.items()}
    if isinstance(value, list):
        return [_resolve(v, scale) for v in value]
    return value


def _flatten(prefix: str, value: Any, out: dict[str, Any]) -> None:
    if isinstance(value, dict) and value:
        for k, v in value.items():
            _flatten(f"{prefix}.{k}", v, out)
    else:
        out[prefix] = value


def settings_at(params: Any, model: str, dataset: str, scale: str) -> dict[str, Any]:
    """Every params value that shapes a run of ``model`` on ``dataset`` at ``scale``, as dotted keys:
    the model's merged recipe (``train.models.<model>``), its epoch cap (``max_epochs``: the
    recipe's own, else the dataset's), the other ``train`` keys, ``seed``, ``world``,
    ``preprocess``, ``evaluate`` and ``datasets.<dataset>`` (its seed list left out: a record keeps
    each run's seed; the sections of a data source it does not use left out too), less
    :data:`NEUTRAL_KEYS`. Read through the params' own sections (so a stage's params audit sees
    every key), each per-scale value taken at ``scale`` whatever the file's own ``scale``."""
    if scale not in SCALES:
        raise ValueError(f"scale {scale!r}: expected one of {list(SCALES)}")
    recipe = _resolve(params.train.models[model].model_dump(mode="json", exclude_none=True), scale)
    section = _resolve(params.dataset(dataset).model_dump(mode="json"), scale)
    section.get("training", {}).pop("seeds", None)
    if section.get("source") != "carla":          # another source's settings shape nothing here
        section.pop("carla", None)
    if section.get("source") != "authors":
        section.pop("authors_root", None)
        section.pop("authors_splits", None)
    out: dict[str, Any] = {"seed": params.seed,
                           "max_epochs": params.max_epochs_of(params.train.models[model], dataset, scale)}
    _flatten(f"train.models.{model}", recipe, out)
    _flatten("train", _resolve(params.train.model_dump(mode="json", exclude={"models", "recipe"}), scale), out)
    for name in ("world", "preprocess", "evaluate"):
        _flatten(name, _resolve(getattr(params, name).model_dump(mode="json"), scale), out)
    _flatten(f"datasets.{dataset}", section, out)
    return {k: v for k, v in sorted(out.items()) if k not in NEUTRAL_KEYS}


# ----------------------------------------------------------------------------- the writer
def record_runs(root: Path, params: Any, dataset: str, seeds: Mapping[str, Sequence[int]],
                provenance: Mapping[str, str]) -> dict[str, Any]:
    """The record of the finished runs under ``root`` (``runs/<ds>/<model>/seed<k>/summary.json``
    and ``results/<ds>/<model>/seed<k>/metrics.json``) of each model of ``seeds`` and its seeds on
    ``dataset``, trained with ``params`` (its own ``scale``); ``provenance``: ``commit``,
    ``machine``, ``command``. Every run is checked against the record's schema
    (the one the report's reader checks with) before the record is returned: a missing file, a
    missing key or a value of the wrong type or range raises :class:`~.errors.ReportInputError`
    naming the file and the field, so nothing is written."""
    runs = []
    for model, model_seeds in seeds.items():
        settings = settings_at(params, model, dataset, params.scale)
        for seed in model_seeds:
            paths = run_paths(dataset, model, seed, root)
            summary_path = paths.run_dir / "summary.json"
            summ, metrics = read_json(summary_path), read_json(paths.metrics_path)
            if not isinstance(metrics, dict) or not isinstance(metrics.get("floor_margin"), dict):
                raise ReportInputError(f"{paths.metrics_path}: no floor_margin (evaluate the run with its floor first)")
            if not isinstance(summ, dict):
                raise ReportInputError(f"{summary_path}: expected a JSON object")
            missing = [k for k in SUMMARY_KEYS if summ.get(k) is None]
            if missing:
                raise ReportInputError(f"{summary_path}: missing {', '.join(missing)}")
            for path, data, keys in ((summary_path, summ, SUMMARY_KEYS),
                                     (paths.metrics_path, metrics, ("floor_margin",))):
                problem = run_problem(data, keys)
                if problem:
                    raise ReportInputError(f"{path}: {problem}")
            runs.append({"dataset": dataset, "model": model, "seed": int(seed), **{k: summ[k] for k in SUMMARY_KEYS},
                         "floor_margin": {k: float(v) for k, v in sorted(metrics["floor_margin"].items())},
                         "settings": settings})
    record = {"version": RECORD_VERSION, "scale": params.scale,
              **{k: str(provenance.get(k, "")) for k in ("commit", "machine", "command")}, "runs": runs}
    problem = record_problem(record)
    if problem:  # the whole record passes the reader's check too (its seeds, settings and provenance)
        raise ReportInputError(f"{root}: {problem}")
    return record
