"""The floor's facts (SPEC 8) that evaluation and the report share, without torch: the trivial
predictors (their ids, in the order of the report's rows, and their labels), how the per-task
floor is taken from their test-set means (:func:`floor_of`) and a model's margin over it
(:func:`margins`).

The predictors are fitted and scored in :mod:`compact_perception.evaluation.floor`, which registers a fit for
each id of :data:`FLOOR_PREDICTORS` (an id missing here fails there).
"""
from __future__ import annotations

from typing import Mapping

from . import catalog
from .registry import Registry

__all__ = ["FLOOR_PREDICTORS", "floor_of", "margins"]

#: Trivial predictor id -> its report label, in the order of the report's rows (first in every
#: dataset's block): ``floor_pixel`` the floor's per-pixel prior, ``floor_global`` one value everywhere.
FLOOR_PREDICTORS: Registry[str] = Registry("trivial predictor", ordered=True)
FLOOR_PREDICTORS.register("floor_pixel")("Floor (per-pixel prior)")
FLOOR_PREDICTORS.register("floor_global")("Floor (global prior)")


def floor_of(floors: Mapping[str, Mapping[str, float]]) -> dict[str, float]:
    """Per task metric, the best test-set mean of the trivial predictors ``floors`` (id -> metric
    -> mean): the floor a model must beat on that task; and ``tm`` the best TM among them."""
    out: dict[str, float] = {}
    for metric in (*catalog.metric_keys(), "tm"):
        vals = [float(f[metric]) for f in floors.values() if metric in f]
        if vals:
            higher = metric != "tm" and catalog.higher_is_better(metric)
            out[metric] = max(vals) if higher else min(vals)
    return out


def margins(means: Mapping[str, float], floor: Mapping[str, float]) -> dict[str, float]:
    """A model's test-set margin over the floor per metric it has, positive = better than the
    floor: ``floor - model`` for MAE_DE and TM, ``model - floor`` for the IoUs."""
    out: dict[str, float] = {}
    for metric, f in floor.items():
        if metric in means:
            higher = metric != "tm" and catalog.higher_is_better(metric)
            out[metric] = float(means[metric]) - f if higher else f - float(means[metric])
    return out
