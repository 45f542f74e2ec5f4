"""The metric-depth errors beyond the paper (Eigen et al. 2014's standard set: AbsRel, SqRel, RMSE,
RMSE log, delta < 1.25, 1.25^2, 1.25^3) and the convention they are evaluated by: the one definition
of each (its label, definition, direction, decimals and formula), which evaluation computes
(:func:`compact_perception.learning.metrics.depth_errors_per_sample`, on torch tensors) and the report
labels and prints (``report/tables/extra.py``), without importing torch.

A new depth metric is one entry of :data:`DEPTH_METRICS`: evaluation's columns and the report's
table derive from the registry. The formulas are written with tensor methods (``d.log()``,
``x.sqrt()``, ``a.maximum(b)``), so this module names no tensor library of its own.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Literal

from .registry import Registry

__all__ = ["DEPTH_CONVENTION", "DepthMetric", "DEPTH_METRICS"]

#: Where the depth-evaluation convention comes from (metrics.json and the report's notes cite it).
DEPTH_CONVENTION = (
    "Eigen et al. (NIPS 2014) as KITTI depth benchmarks since apply it: ground truth capped at the evaluated "
    "maximum (pixels beyond it left out), prediction clamped to the evaluated range, valid pixels only, each "
    "error per frame then averaged over frames")

Tensor = Any   # a torch tensor (float64): the formulas call its methods only


@dataclass(frozen=True)
class DepthMetric:
    """A metric-depth error beyond the paper: per frame, ``finish(mean over the valid pixels of
    per_pixel(d, d*))``, with d the decoded, range-clamped prediction and d* the decoded ground
    truth (m)."""

    label: str                                   # report label: "RMSE (m)"
    definition: str                              # how it is computed, in words (metrics.json)
    direction: Literal["lower", "higher"]
    decimals: int                                # digits in the report's table
    per_pixel: Callable[[Tensor, Tensor], Tensor]
    finish: Callable[[Tensor], Tensor] = lambda x: x


def _delta(power: int) -> Callable[[Tensor, Tensor], Tensor]:
    return lambda d, g: ((d / g).maximum(g / d) < 1.25 ** power).double()


#: depth metric id (the metrics.json key) -> its definition; evaluation and the report iterate it
#: (the standard set of Eigen et al. 2014: AbsRel, SqRel, RMSE, RMSE log and the three delta accuracies)
DEPTH_METRICS: Registry[DepthMetric] = Registry("depth metric", ordered=True)
DEPTH_METRICS.register("abs_rel")(DepthMetric(
    "AbsRel", "AbsRel = mean |d - d*| / d*", "lower", 3, lambda d, g: (d - g).abs() / g))
DEPTH_METRICS.register("sq_rel")(DepthMetric(
    "SqRel (m)", "SqRel = mean (d - d*)^2 / d* (m)", "lower", 3, lambda d, g: (d - g) ** 2 / g))
DEPTH_METRICS.register("rmse_m")(DepthMetric(
    "RMSE (m)", "RMSE = sqrt(mean (d - d*)^2) (m)", "lower", 2, lambda d, g: (d - g) ** 2, lambda x: x.sqrt()))
DEPTH_METRICS.register("rmse_log")(DepthMetric(
    "RMSE log", "RMSE log = sqrt(mean (ln d - ln d*)^2)", "lower", 3,
    lambda d, g: (d.log() - g.log()) ** 2, lambda x: x.sqrt()))
DEPTH_METRICS.register("delta_1.25")(DepthMetric(
    "δ<1.25", "delta_1.25 = share with max(d/d*, d*/d) < 1.25", "higher", 3, _delta(1)))
DEPTH_METRICS.register("delta_1.25^2")(DepthMetric(
    "δ<1.25²", "delta_1.25^2 = share with max(d/d*, d*/d) < 1.25^2", "higher", 3, _delta(2)))
DEPTH_METRICS.register("delta_1.25^3")(DepthMetric(
    "δ<1.25³", "delta_1.25^3 = share with max(d/d*, d*/d) < 1.25^3", "higher", 3, _delta(3)))
