"""A record of runs trained to their plateau at a larger scale than the one reported, so the report
can say whether a baseline learns when the runs at hand were stopped by their epoch cap.

The record (``benchmarks/records/full_plateau.json``, written by ``benchmarks/record_plateau.py``
from a finished run tree) holds, per run (dataset, model, seed): how it stopped (``epochs_run``,
``best_epoch``, ``max_epochs``, ``stop_reason``, ``train_seconds`` from ``summary.json``), its
test-set margin over the floor per task metric (``floor_margin`` of ``metrics.json``, positive =
better than the better trivial predictor), and the settings it was trained under
(:func:`settings_at`); with the scale, commit, machine and command that made it.

A record is an input of the report like the runs (``dvc.yaml`` declares it): the report states
what it says and, from :func:`changed_settings`, whether today's params would train that run
differently, in which case the record answers for the old settings only.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence

from ..core.params_base import SCALES
from ..core.catalog import MODELS, STOP_PLATEAU, metric_of
from ..core.layout import run_paths
from .collect import ReportInputError, read_json
from .plateau_schema import RECORD_VERSION, RUN_KEYS, SUMMARY_KEYS, record_problem, run_problem
from .schema import DATASET_LABEL, METRIC_TASK, ROW_LABEL

__all__ = ["RECORD_VERSION", "PlateauRun", "PlateauRecord", "PlateauEvidence", "settings_at", "changed_settings",
           "record_runs", "load_record", "evidence", "recorded_sentence"]

#: Settings that change no result (the pipeline's promise: any worker, process or run count gives
#: the same bytes; which test frame a figure shows, how many predictions are saved).
NEUTRAL_KEYS: tuple[str, ...] = ("world.workers", "preprocess.workers", "train.num_workers", "train.parallel_runs",
                                 "evaluate.figure_frame", "evaluate.save_predictions")

_MISSING = object()

@dataclass(frozen=True)
class PlateauRun:
    """One recorded run (the keys of :data:`~.plateau_schema.RUN_KEYS`)."""

    dataset: str
    model: str
    seed: int
    epochs_run: int
    best_epoch: int
    max_epochs: int
    stop_reason: str
    train_seconds: float
    floor_margin: dict[str, float]
    settings: dict[str, Any]


@dataclass(frozen=True)
class PlateauRecord:
    """A record's provenance and runs; ``path`` is where it was read from (for the report's text)."""

    path: str
    scale: str
    commit: str
    machine: str
    command: str
    runs: tuple[PlateauRun, ...]

    def runs_of(self, model: str) -> list[PlateauRun]:
        return [r for r in self.runs if r.model == model]


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


def changed_settings(run: PlateauRun, params: Any, scale: str) -> list[str]:
    """The settings keys whose value in ``params`` at ``scale`` differs from ``run``'s (added or
    removed keys included), sorted; empty when today's params would train that run the same way."""
    if run.model not in params.train.models:
        return [f"train.models.{run.model}"]
    now = settings_at(params, run.model, run.dataset, scale)
    return sorted(k for k in set(now) | set(run.settings) if now.get(k, _MISSING) != run.settings.get(k, _MISSING))


def record_runs(root: Path, params: Any, dataset: str, seeds: Mapping[str, Sequence[int]],
                provenance: Mapping[str, str]) -> dict[str, Any]:
    """The record of the finished runs under ``root`` (``runs/<ds>/<model>/seed<k>/summary.json``
    and ``results/<ds>/<model>/seed<k>/metrics.json``) of each model of ``seeds`` and its seeds on
    ``dataset``, trained with ``params`` (its own ``scale``); ``provenance``: ``commit``,
    ``machine``, ``command``. Every run is checked against the record's schema
    (:mod:`.plateau_schema`, the one :func:`load_record` reads with) before the record is returned:
    a missing file, a missing key or a value of the wrong type or range raises
    :class:`~.collect.ReportInputError` naming the file and the field, so nothing is written."""
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


def load_record(path: Path) -> Optional[PlateauRecord]:
    """The record at ``path`` (``None`` where there is none); one its schema refuses
    (:func:`~.plateau_schema.record_problem`) raises :class:`~.collect.ReportInputError` naming
    the file, the run and the field."""
    path = Path(path)
    if not path.is_file():
        return None
    data = read_json(path)
    problem = record_problem(data)
    if problem:
        raise ReportInputError(f"{path}: {problem}")
    runs = tuple(PlateauRun(**{k: run[k] for k in RUN_KEYS}) for run in data["runs"])
    return PlateauRecord(str(path), data["scale"], str(data.get("commit", "")), str(data.get("machine", "")),
                         str(data.get("command", "")), runs)


@dataclass(frozen=True)
class PlateauEvidence:
    """A record read for a report, with what today's params change of each recorded run
    (:func:`changed_settings`, keyed by ``(dataset, model, seed)``)."""

    record: PlateauRecord
    changed: dict[tuple[str, str, int], list[str]]


def evidence(record: Optional[PlateauRecord], params: Any) -> Optional[PlateauEvidence]:
    """``record`` beside today's ``params`` (``None`` without a record)."""
    if record is None:
        return None
    return PlateauEvidence(record, {(r.dataset, r.model, r.seed): changed_settings(r, params, record.scale)
                                    for r in record.runs})


def _run_text(run: PlateauRun, changed: Sequence[str]) -> str:
    """What one recorded run says: how it stopped, its margins on its model's tasks, the verdict."""
    metrics = [metric_of(t) for t in MODELS[run.model].tasks]
    margins = {m: run.floor_margin[m] for m in metrics if m in run.floor_margin}
    shown = ", ".join(f"{METRIC_TASK.get(m, m)} {v:+.3f}" for m, v in margins.items()) or "no margin recorded"
    where = f"{DATASET_LABEL.get(run.dataset, run.dataset)}, seed {run.seed}"
    if run.stop_reason != STOP_PLATEAU:
        text = (f"{where}: stopped by its cap after {run.epochs_run} epochs, not at a plateau (margin over the "
                f"floor {shown}): says nothing either way")
    else:
        head = f"{where}: trained to a plateau in {run.epochs_run} epochs (best {run.best_epoch}), margin over the floor {shown}"
        learns = len(margins) == len(metrics) and all(v > 0 for v in margins.values())
        text = head + (": it learns at these settings" if learns else ": it does not learn at these settings")
    if changed:
        keys = ", ".join(f"`{k}`" for k in changed[:4]) + (f" and {len(changed) - 4} more" if len(changed) > 4 else "")
        text += (f" (today's params would train this run differently: {keys}; the record answers for its own "
                 "settings only)")
    return text


def recorded_sentence(ev: Optional[PlateauEvidence], models: Sequence[str], datasets: Sequence[str],
                      link: str) -> Optional[str]:
    """One sentence over the baselines ``models``: what the record says of each one's runs on
    ``datasets`` (``None`` without a record or such a run); ``link`` is the record's path as the
    report links it. One seed's margin has no interval: the sentence says how many seeds it rests on."""
    if ev is None:
        return None
    per_model = []
    for m in models:
        runs = [r for r in ev.record.runs_of(m) if r.dataset in datasets]
        if runs:
            per_model.append(f"{ROW_LABEL.get(m, m)}: " + "; ".join(
                _run_text(r, ev.changed.get((r.dataset, r.model, r.seed), [])) for r in runs))
    if not per_model:
        return None
    rec = ev.record
    n_seeds = len({r.seed for r in rec.runs if r.model in models and r.dataset in datasets})
    return (f"Trained to their plateau at `scale: {rec.scale}` (recorded in [{Path(rec.path).name}]({link}): "
            f"{rec.commit or 'commit not recorded'}, {rec.machine or 'machine not recorded'}; "
            f"{n_seeds} seed{'' if n_seeds == 1 else 's'}, so a margin without an interval): " + ". ".join(per_model) + ".")
