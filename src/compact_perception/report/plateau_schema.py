"""The schema of the plateau record (``benchmarks/records/full_plateau.json``): what each of its
runs and the record itself must hold, by type and range. One schema for both sides: the script
that writes a record (:func:`~.plateau.record_runs`) checks every run before anything is written,
and the report (:func:`~.plateau.load_record`) checks what it reads, so neither can accept what
the other refuses. Each check answers with the first problem as ``<field>: expected <what> (got
<value>)``, the value shown bounded."""
from __future__ import annotations

import math
from typing import Any, Callable, Mapping, Optional

from ..core.catalog import DATASETS, MODELS, STOP_CAP, STOP_PLATEAU
from ..core.params_base import SCALES
from ..core.params_errors import shown

__all__ = ["RECORD_VERSION", "RUN_KEYS", "SUMMARY_KEYS", "run_problem", "record_problem"]

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
