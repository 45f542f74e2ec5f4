"""The learnedness gate (SPEC 8 "the floor"; issues 23 and 24): is a row above the trivial-predictor
floor on a metric?

The floor of a dataset on a task metric is the better of its trivial predictors' test-set means
(:func:`compact_perception.core.floor_rule.floor_of`: ``floor_pixel`` and ``floor_global``, fitted
on the train split, scored on the test split with the same metric code as every model); on TM the
better of their TMs. A row's **margin** on a metric is its value's distance from that floor,
positive when it is better (:func:`compact_perception.core.floor_rule.margins`): the mean over its
training seeds of the run-level value against the predictor that gives the floor, with the interval of
:func:`compact_perception.stats.interval` (the row's runs keyed by seed, the predictor a ``fixed``
group: one deterministic run; the frames' episodes or scenes as clusters).

A row is

- ``above`` the floor on a metric when the 95% interval of its margin lies above 0 and the row
  has at least :data:`~compact_perception.stats.MIN_SEEDS` seeds (a decidable comparison);
- ``below`` when its margin (mean over seeds) is not above 0: no better than an input-blind predictor;
- ``not shown above`` otherwise: a better mean whose interval reaches 0, or too few seeds to tell;
- ``no floor`` / ``no data`` where the floor's or the row's per-frame scores are missing.

Only ``above`` passes: Table II bolds nothing else, a claim is decided only when every row it
compares passes on the metrics it uses (:func:`~.schema.stat_columns`: TM and MV use all four task
metrics), and the study reports Δm only for arms that pass on every task.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Sequence

import numpy as np
import pandas as pd

from ..core.floor_rule import floor_of
from ..stats import MIN_SEEDS, IntervalResult, interval, stat_mean
from .collect import ModelResult, ReportInputError, frame_comparison, load_floor_frames, load_floor_results
from .schema import FLOOR_IDS, METRIC_TASK, ROW_LABEL, TASK_COLUMNS, beats, column_stat, stat_columns

__all__ = ["ABOVE", "BELOW", "UNSHOWN", "NO_FLOOR", "NO_DATA", "Margin", "DatasetFloor", "Gate", "status_of",
           "failing_text", "margin_on_column", "dataset_floor", "dataset_gate"]

ABOVE, BELOW, UNSHOWN = "above", "below", "not shown above"
NO_FLOOR, NO_DATA = "no floor", "no data"


def status_of(res: IntervalResult) -> str:
    """The gate's status of a margin's interval (positive = better than the floor): ``above`` when
    the comparison is decidable (enough seeds) and the interval's low end is above 0, ``below``
    when the estimate is not above 0, ``not shown above`` otherwise (an interval touching 0 included)."""
    if not res.estimate > 0:
        return BELOW
    if res.decidable and math.isfinite(res.ci_low) and res.ci_low > 0:
        return ABOVE
    return UNSHOWN


def _opt(v: float) -> Optional[float]:
    return float(v) if math.isfinite(v) else None


@dataclass(frozen=True)
class Margin:
    """A row's margin over the floor on one metric (positive = better than the floor) and its
    gate status; ``floor_id``: the trivial predictor that gives the floor on that metric."""

    metric: str
    status: str
    floor_id: Optional[str] = None
    estimate: Optional[float] = None
    ci_low: Optional[float] = None
    ci_high: Optional[float] = None
    n_seeds: int = 0
    result: Optional[IntervalResult] = None

    @property
    def above(self) -> bool:
        return self.status == ABOVE

    @classmethod
    def of(cls, metric: str, floor_id: str, res: IntervalResult) -> "Margin":
        n = min((k for k, f in zip(res.n_seeds, res.fixed) if not f), default=0)
        return cls(metric, status_of(res), floor_id, _opt(res.estimate), _opt(res.ci_low), _opt(res.ci_high), n, res)

    def reason(self) -> str:
        """The status, with the seeds where too few kept it from ``above``: ``not shown above: 1 seed``."""
        if self.status == UNSHOWN and 0 < self.n_seeds < MIN_SEEDS:
            return f"{UNSHOWN}: {self.n_seeds} seed{'' if self.n_seeds == 1 else 's'}"
        return self.status

    def text(self, decimals: int = 3) -> str:
        """``+0.123 [+0.050, +0.196]`` (the interval left out where there is none)."""
        if self.estimate is None:
            return self.status
        ci = (f" [{self.ci_low:+.{decimals}f}, {self.ci_high:+.{decimals}f}]"
              if self.ci_low is not None and self.ci_high is not None else "")
        return f"{self.estimate:+.{decimals}f}{ci}"


@dataclass
class DatasetFloor:
    """One dataset's trivial predictors: their metrics (id -> :class:`~.collect.ModelResult`) and
    per-frame scores (id -> frame-indexed table)."""

    dataset: str
    results: dict[str, ModelResult]
    frames: dict[str, pd.DataFrame] = field(default_factory=dict)

    def means(self) -> dict[str, dict[str, float]]:
        """id -> metric -> test-set mean (the task metrics and TM)."""
        return {t: {k: c.mean for k, c in r.scores.items() if k != "mv"} for t, r in self.results.items()}

    def value(self) -> dict[str, float]:
        """Per task metric and TM, the floor (:func:`compact_perception.core.floor_rule.floor_of`)."""
        return floor_of(self.means())

    def source(self, metric: str) -> Optional[str]:
        """The trivial predictor that gives the floor on ``metric`` (the first in order on a tie)."""
        value = self.value().get(metric)
        means = self.means()
        return next((t for t in FLOOR_IDS if t in means and means[t].get(metric) == value), None)


def dataset_floor(root: Path, ds: str) -> DatasetFloor:
    """The trivial predictors of ``ds`` from their outputs under ``root`` (:mod:`.collect`)."""
    return DatasetFloor(ds, load_floor_results(Path(root), ds), load_floor_frames(Path(root), ds))


def dataset_gate(root: Path, ds: str, frames: Optional[dict[str, list[pd.DataFrame]]]) -> "Gate":
    """The gate of ``ds``: its floor read under ``root`` and the rows' per-frame scores ``frames``."""
    return Gate(dataset_floor(root, ds), frames)


class Gate:
    """One dataset's floor and the margins over it of the rows of ``frames`` (row id -> per-frame
    scores per run), each computed once (:meth:`margin`)."""

    def __init__(self, floor: Optional[DatasetFloor], frames: Optional[dict[str, list[pd.DataFrame]]] = None):
        self.floor = floor
        self.frames = frames or {}
        self._cache: dict[tuple[str, str], Margin] = {}

    @property
    def has_floor(self) -> bool:
        return bool(self.floor and self.floor.results)

    def margin_of(self, runs: Sequence[pd.DataFrame], metric: str) -> Margin:
        """The margin over the floor on ``metric`` (a task metric or ``tm``) of ``runs`` (one per seed)."""
        src = self.floor.source(metric) if self.floor else None
        if src is None or src not in self.floor.frames:  # type: ignore[union-attr]
            return Margin(metric, NO_FLOOR)
        cols = stat_columns(metric)
        ref = self.floor.frames[src]  # type: ignore[union-attr]
        if not runs or any(c not in df.columns for df in (*runs, ref) for c in cols):
            return Margin(metric, NO_DATA, src)
        try:
            comp = frame_comparison([list(runs), [ref]], cols, fixed=(False, True))
        except ReportInputError:
            return Margin(metric, NO_DATA, src)
        return Margin.of(metric, src, interval(comp, column_stat(metric), beats(metric)))

    def margin(self, row_id: str, metric: str) -> Margin:
        """The margin of row ``row_id`` (its per-frame scores in ``frames``) on ``metric``."""
        key = (row_id, metric)
        if key not in self._cache:
            self._cache[key] = self.margin_of(self.frames.get(row_id) or [], metric)
        return self._cache[key]

    def failing(self, row_id: str, metrics: Sequence[str]) -> list[Margin]:
        """The margins of ``row_id`` on ``metrics`` that do not pass the gate."""
        return [m for m in (self.margin(row_id, c) for c in metrics) if not m.above]

    def passes(self, row_id: str, metrics: Sequence[str] = TASK_COLUMNS) -> bool:
        return not self.failing(row_id, metrics)


def margin_on_column(runs: Sequence[pd.DataFrame], floor_id: str, ref: pd.DataFrame, column: str,
                     higher_is_better: bool) -> Margin:
    """The margin over a trivial predictor's per-frame scores ``ref`` (a fixed group) of ``runs``
    (one per seed) on one per-frame ``column`` of a metric beyond the paper's (an arg-max IoU, a
    depth error), positive when better; frames where a run or the predictor has no value (a frame
    without valid depth pixels) left out. The same interval and status rule as Table II's margins."""
    if not runs or any(column not in df.columns for df in (*runs, ref)):
        return Margin(column, NO_DATA, floor_id)
    keep = [df[np.isfinite(df[column].to_numpy(dtype=float))] for df in (*runs, ref)]
    try:
        comp = frame_comparison([keep[:-1], [keep[-1]]], [column], fixed=(False, True))
    except ReportInputError:
        return Margin(column, NO_DATA, floor_id)
    contrast = (lambda v: v[..., 0] - v[..., 1]) if higher_is_better else (lambda v: v[..., 1] - v[..., 0])
    return Margin.of(column, floor_id, interval(comp, stat_mean, contrast))


def failing_text(failing: Sequence[tuple[str, Sequence[Margin]]], labels: Optional[dict[str, str]] = None) -> str:
    """``15L LS/BEVP, 1L LS``: each row (label) with the tasks on which it does not pass the gate."""
    labels = labels or ROW_LABEL
    parts = []
    for row_id, margins in failing:
        if margins:
            tasks = "/".join(METRIC_TASK.get(m.metric, m.metric.upper()) for m in margins)
            parts.append(f"{labels.get(row_id, row_id)} {tasks}")
    return ", ".join(parts)
