"""Paper metrics, section III-B eq. (4)-(7) and SPEC 6.

- :func:`mae`            eq. (4): mean |pred - gt| over elements and views.
- :func:`iou`            eq. (5): ``|pred>t AND gt>t| / |pred>t OR gt>t|`` over the whole
  one-hot tensor of a view, averaged over views (t = 0.5).
  **Empty union** (nothing predicted and nothing labelled in a view): IoU = 1.0 for that view,
  a perfect agreement on "nothing is there"; it is neither dropped nor counted as 0.
- :func:`total_metric`   eq. (6): ``TM = MAE + (1-IoU_SS) + (1-IoU_LS) + (1-IoU_BEVP)``.
- :func:`metric_variance` eq. (7): population variance of those four terms.

Batch-level functions (:func:`mae`, :func:`iou`, :func:`compute_metrics`) pool all elements of
the batch (per view for IoU); the ``*_per_sample`` variants return one value per sample, (B,),
for the batch-1 test evaluation of Table II (mean +- variance over test frames).
"""
from __future__ import annotations

from typing import Any, Mapping, Union

import numpy as np
import torch
from torch import Tensor

from .losses import as_views

__all__ = [
    "TASKS",
    "mae",
    "mae_per_sample",
    "iou",
    "iou_per_sample",
    "total_metric",
    "metric_variance",
    "compute_metrics",
    "compute_metrics_per_sample",
    "combine_tasks",
]

TASKS = ("de", "ss", "ls", "bevp")
Number = Union[float, Tensor, np.ndarray]


@torch.no_grad()
def mae_per_sample(pred: Tensor, target: Tensor) -> Tensor:
    """Eq. (4) per sample: (B,) mean |pred - target| over each sample's elements and views."""
    d = (pred.detach().double() - target.detach().double()).abs()
    return d.reshape(d.shape[0], -1).mean(dim=1)


@torch.no_grad()
def mae(pred: Tensor, target: Tensor) -> Tensor:
    """Eq. (4): mean |pred - target| over all elements and views (scalar, float64)."""
    return (pred.detach().double() - target.detach().double()).abs().mean()


def _iou_from_counts(inter: Tensor, union: Tensor) -> Tensor:
    """inter/union with the documented empty-union convention (IoU = 1)."""
    safe = torch.where(union > 0, union, torch.ones_like(union))
    return torch.where(union > 0, inter / safe, torch.ones_like(inter))


@torch.no_grad()
def iou_per_sample(pred: Tensor, target: Tensor, threshold: float = 0.5) -> Tensor:
    """Eq. (5) per sample: (B,) IoU per view over the view's whole one-hot tensor, averaged over views."""
    p = as_views(pred.detach()) > threshold
    g = as_views(target.detach()) > threshold
    inter = (p & g).sum(dim=(2, 3, 4)).double()  # (B,V)
    union = (p | g).sum(dim=(2, 3, 4)).double()
    return _iou_from_counts(inter, union).mean(dim=1)


@torch.no_grad()
def iou(pred: Tensor, target: Tensor, threshold: float = 0.5) -> Tensor:
    """Eq. (5): per view, ``|p>t AND g>t| / |p>t OR g>t|`` over the view's tensor pooled over
    the batch, then the mean over views (scalar, float64). Empty union -> 1.0."""
    p = as_views(pred.detach()) > threshold
    g = as_views(target.detach()) > threshold
    inter = (p & g).sum(dim=(0, 2, 3, 4)).double()  # (V,)
    union = (p | g).sum(dim=(0, 2, 3, 4)).double()
    return _iou_from_counts(inter, union).mean()


def total_metric(mae_de: Number, iou_ss: Number, iou_ls: Number, iou_bevp: Number) -> Number:
    """Eq. (6): ``TM = MAE_DE + (1-IoU_SS) + (1-IoU_LS) + (1-IoU_BEVP)`` (element-wise)."""
    return mae_de + (1 - iou_ss) + (1 - iou_ls) + (1 - iou_bevp)


def metric_variance(mae_de: Number, iou_ss: Number, iou_ls: Number, iou_bevp: Number) -> Number:
    """Eq. (7): population variance (1/T, T = 4) of ``M = (MAE, 1-IoU_SS, 1-IoU_LS, 1-IoU_BEVP)``."""
    terms = (mae_de, 1 - iou_ss, 1 - iou_ls, 1 - iou_bevp)
    mean = total_metric(mae_de, iou_ss, iou_ls, iou_bevp) / 4
    return sum((m - mean) ** 2 for m in terms) / 4


def compute_metrics(outputs: Mapping[str, Tensor], targets: Mapping[str, Tensor]) -> dict[str, float]:
    """Batch metrics for the tasks present in both dicts: ``mae_de``, ``iou_ss``, ``iou_ls``,
    ``iou_bevp``; plus ``tm`` and ``mv`` only when all four are present."""
    out: dict[str, float] = {}
    if "de" in outputs and "de" in targets:
        out["mae_de"] = float(mae(outputs["de"], targets["de"]))
    for t in ("ss", "ls", "bevp"):
        if t in outputs and t in targets:
            out[f"iou_{t}"] = float(iou(outputs[t], targets[t]))
    if all(k in out for k in ("mae_de", "iou_ss", "iou_ls", "iou_bevp")):
        out["tm"] = float(total_metric(out["mae_de"], out["iou_ss"], out["iou_ls"], out["iou_bevp"]))
        out["mv"] = float(metric_variance(out["mae_de"], out["iou_ss"], out["iou_ls"], out["iou_bevp"]))
    return out


def compute_metrics_per_sample(outputs: Mapping[str, Tensor], targets: Mapping[str, Tensor]) -> dict[str, Tensor]:
    """As :func:`compute_metrics` but every value is a (B,) float64 tensor (one per frame)."""
    out: dict[str, Tensor] = {}
    if "de" in outputs and "de" in targets:
        out["mae_de"] = mae_per_sample(outputs["de"], targets["de"])
    for t in ("ss", "ls", "bevp"):
        if t in outputs and t in targets:
            out[f"iou_{t}"] = iou_per_sample(outputs[t], targets[t])
    if all(k in out for k in ("mae_de", "iou_ss", "iou_ls", "iou_bevp")):
        out["tm"] = total_metric(out["mae_de"], out["iou_ss"], out["iou_ls"], out["iou_bevp"])
        out["mv"] = metric_variance(out["mae_de"], out["iou_ss"], out["iou_ls"], out["iou_bevp"])
    return out


def _num(x: Any) -> Union[float, np.ndarray]:
    if isinstance(x, Tensor):
        x = x.detach().cpu().double().numpy()
    arr = np.asarray(x, dtype=np.float64)
    return float(arr) if arr.ndim == 0 else arr


def _out(x: Union[float, np.ndarray]) -> Union[float, list[float]]:
    return float(x) if np.ndim(x) == 0 else [float(v) for v in np.asarray(x)]


def combine_tasks(
    gradnorm: Mapping[str, Any], polarnet: Mapping[str, Any], chen: Mapping[str, Any]
) -> dict[str, Union[float, list[float]]]:
    """The "combination of baselines" row (SPEC 6): DE and SS from GradNorm-SegNet
    (``mae_de``, ``iou_ss``), LS from PolarNet (``iou_ls``), BEVP from Chen et al.
    (``iou_bevp``); returns those four plus ``tm`` (eq. 6) and ``mv`` (eq. 7).

    Values may be scalars or per-test-frame sequences/tensors (same frame order in all
    three); per-frame inputs give per-frame ``tm``/``mv`` lists, to be aggregated like any
    model's per-frame scores.
    """
    m = {
        "mae_de": _num(gradnorm["mae_de"]),
        "iou_ss": _num(gradnorm["iou_ss"]),
        "iou_ls": _num(polarnet["iou_ls"]),
        "iou_bevp": _num(chen["iou_bevp"]),
    }
    shapes = {np.shape(v) for v in m.values()}
    if len(shapes) != 1:
        raise ValueError(f"combine_tasks: inputs must all be scalars or all have the same length, got shapes {shapes}")
    m["tm"] = total_metric(m["mae_de"], m["iou_ss"], m["iou_ls"], m["iou_bevp"])
    m["mv"] = metric_variance(m["mae_de"], m["iou_ss"], m["iou_ls"], m["iou_bevp"])
    return {k: _out(v) for k, v in m.items()}
