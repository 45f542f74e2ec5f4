"""What the report says of the record of runs trained to their plateau at a larger scale than the
one reported, so it can say whether a baseline learns when the runs at hand were stopped by their
epoch cap.

The record (``benchmarks/records/full_plateau.json``, written by ``benchmarks/record_plateau.py``
from a finished run tree) is defined in :mod:`compact_perception.core.plateau_record`: what it
holds of a run, its schema (which :func:`load_record` reads with, as the writer checks with it)
and the settings a run was trained under (:func:`~compact_perception.core.plateau_record.settings_at`).

A record is an input of the report like the runs (``dvc.yaml`` declares it): the report states
what it says and, from :func:`changed_settings`, whether today's params would train that run
differently, in which case the record answers for the old settings only.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional, Sequence

from ..core.catalog import MODELS, STOP_PLATEAU, metric_of
from ..core.errors import ReportInputError
from ..core.io import read_json
from ..core.layout import study_run_name
from ..core.plateau_record import RUN_KEYS, STATUS_COMPLETE, changed_keys, record_problem, settings_at
from .schema import DATASET_LABEL, METRIC_TASK, ROW_LABEL

__all__ = ["PlateauRun", "PlateauRecord", "PlateauEvidence", "changed_settings", "load_record", "evidence",
           "recorded_sentence"]

@dataclass(frozen=True)
class PlateauRun:
    """One recorded run (the keys of :data:`~compact_perception.core.plateau_record.RUN_KEYS`; ``arm``:
    the loss-balancing study's arm it trained, ``None`` for a model's own recipe)."""

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
    arm: Optional[str] = None

    @property
    def name(self) -> str:
        """The model id, or ``study:<arm>``."""
        return study_run_name(self.arm) if self.arm is not None else self.model


@dataclass(frozen=True)
class PlateauRecord:
    """A record's provenance and runs; ``path`` is where it was read from (for the report's text)."""

    path: str
    scale: str
    commit: str
    machine: str
    command: str
    runs: tuple[PlateauRun, ...]
    device: str = "cpu"                       # version 1 records were made on CPUs
    data: Optional[dict[str, Any]] = None     # a version-2 record whole (its runs' files: report/full.py)

    def runs_of(self, model: str) -> list[PlateauRun]:
        """The runs of ``model``'s own recipe (a study arm's runs, on its base model, left out)."""
        return [r for r in self.runs if r.model == model and r.arm is None]


def changed_settings(run: PlateauRun, params: Any, scale: str, device: str = "cpu") -> list[str]:
    """The settings keys whose value in ``params`` at ``scale`` differs from ``run``'s (added or
    removed keys included), sorted, less those that cannot change a run on ``device``
    (:func:`~compact_perception.core.plateau_record.changed_keys`); empty when today's params would
    train that run the same way."""
    if run.arm is not None and run.arm not in params.study.arms:
        return [f"study.arms.{run.arm}"]
    if run.model not in params.train.models:
        return [f"train.models.{run.model}"]
    return changed_keys(run.settings, settings_at(params, run.model, run.dataset, scale, run.arm), device)


def load_record(path: Path) -> Optional[PlateauRecord]:
    """The record at ``path`` (``None`` where there is none); one its schema refuses
    (:func:`~compact_perception.core.plateau_record.record_problem`) raises :class:`ReportInputError` naming
    the file, the run and the field."""
    path = Path(path)
    if not path.is_file():
        return None
    data = read_json(path)
    problem = record_problem(data)
    if problem:
        raise ReportInputError(f"{path}: {problem}")
    runs = tuple(PlateauRun(**{k: run[k] for k in RUN_KEYS}, arm=run.get("arm")) for run in data["runs"]
                 if data["version"] == 1 or run["status"] == STATUS_COMPLETE)
    return PlateauRecord(str(path), data["scale"], str(data.get("commit", "")), str(data.get("machine", "")),
                         str(data.get("command", "")), runs, str(data.get("device", "cpu")),
                         data if data["version"] >= 2 else None)


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
    return PlateauEvidence(record, {(r.dataset, r.model, r.seed): changed_settings(r, params, record.scale,
                                                                                   record.device)
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
