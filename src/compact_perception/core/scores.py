"""The scores over the four task metrics (paper section III-B): TM, eq. (6), and MV, eq. (7).

Plain arithmetic on numbers or arrays (element-wise; no torch), so the catalog's score entries
(:data:`.catalog.SCORES`) can carry them: evaluation (:mod:`compact_perception.learning.metrics`), the
report and the statistics (:mod:`compact_perception.stats`) all compute a score through its entry.
"""
from __future__ import annotations

from typing import Any

__all__ = ["total_metric", "metric_variance"]

Number = Any   # a float, a numpy array or a torch tensor: the formulas are element-wise


def total_metric(mae_de: Number, iou_ss: Number, iou_ls: Number, iou_bevp: Number) -> Number:
    """Eq. (6): ``TM = MAE_DE + (1-IoU_SS) + (1-IoU_LS) + (1-IoU_BEVP)`` (element-wise)."""
    return mae_de + (1 - iou_ss) + (1 - iou_ls) + (1 - iou_bevp)


def metric_variance(mae_de: Number, iou_ss: Number, iou_ls: Number, iou_bevp: Number) -> Number:
    """Eq. (7): population variance (1/T, T = 4) of ``M = (MAE, 1-IoU_SS, 1-IoU_LS, 1-IoU_BEVP)``."""
    terms = (mae_de, 1 - iou_ss, 1 - iou_ls, 1 - iou_bevp)
    mean = total_metric(mae_de, iou_ss, iou_ls, iou_bevp) / 4
    return sum((m - mean) ** 2 for m in terms) / 4
