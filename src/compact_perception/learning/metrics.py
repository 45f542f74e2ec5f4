"""Paper metrics, section III-B eq. (4)-(7) and SPEC 6.

- :func:`mae`            eq. (4): mean |pred - gt| over elements and views.
- :func:`iou`            eq. (5): ``|pred>t AND gt>t| / |pred>t OR gt>t|`` over the whole
  one-hot tensor of a view, averaged over views (t = 0.5).
  **Pixels without a label** in the class maps (SS, LS: an all-zero one-hot vector, 255 in the
  cache; an LS cell no LiDAR point reached, a nuScenes camera pixel no LiDAR point projects to)
  count for no model: :func:`labelled_only` sets the prediction there to 0 before eq. (5)
  (:data:`CLASS_MAP_TASKS`). The ground truth says nothing about such a cell, PolarSeg and
  SemanticKITTI score LiDAR segmentation at the points only, and the LiDAR input shows every
  model which cells hold a point; over the whole grid, a softmax head (PolarNet), whose loss
  ignores those cells, would be charged a false positive in every one of them. BEVP is a set of
  binary masks where an all-zero vector is a labelled "none of these", so it is scored whole.
  **Empty union** (nothing predicted and nothing labelled in a view): IoU = 1.0 for that view,
  a perfect agreement on "nothing is there"; it is neither dropped nor counted as 0.
- :func:`total_metric`   eq. (6): ``TM = MAE + (1-IoU_SS) + (1-IoU_LS) + (1-IoU_BEVP)``.
- :func:`metric_variance` eq. (7): population variance of those four terms. In Table II
  each term is a **test-set mean**, so MV is computed once from the four means
  (:func:`scores_from_means`), never averaged over frames (set A 15L+MGN: terms 0.084, 0.373,
  0.530, 0.406 -> 0.0267, printed 0.027). TM is linear, so TM of the means equals the mean of
  the per-frame TM.

TM and MV are implemented once, in :mod:`compact_perception.core.scores` (re-exported here), and
reached through their catalog entries (``catalog.SCORES[k].of_terms``): evaluation, the reports
and the claims' statistics all compute a score that way; :func:`scores_from_means` and
:func:`score_terms` are the catalog's (re-exported here), so the report computes Table II's TM
and MV without torch.

Metrics the field expects, beside the paper's (not in the paper):

- :func:`class_confusion` / :func:`multilabel_confusion`: per-class TP, FP, FN counts, summed
  over the test set by the caller; :func:`class_iou` = TP / (TP + FP + FN) per class and
  :func:`mean_iou` over the classes present (a class with TP + FP + FN = 0, absent from both
  prediction and ground truth, has no IoU and is left out of the mean).
- :func:`decode_log_depth` and :func:`depth_errors_per_sample`: the metric-depth errors of the
  registry :data:`DEPTH_METRICS` (Eigen et al.'s standard set: AbsRel, SqRel, RMSE, RMSE log,
  delta < 1.25, 1.25^2, 1.25^3) on metric depth decoded from the cache's CARLA log encoding, by
  the field's convention (:data:`DEPTH_CONVENTION`: ground truth capped at the evaluated maximum,
  ``evaluate.depth_max_m``, prediction clamped to the evaluated range, valid pixels only). The
  registry and the convention are :mod:`compact_perception.core.depth_metrics`' (re-exported
  here), where the report reads them without torch: a new depth metric is one entry there, and
  evaluation's columns and the report's table derive from the registry.

Batch-level functions (:func:`mae`, :func:`iou`, :func:`compute_metrics`) pool all elements of
the batch (per view for IoU); the ``*_per_sample`` variants return one value per sample, (B,),
for the batch-1 test evaluation of Table II (mean +- variance over test frames).
"""
from __future__ import annotations

from typing import Any, Callable, Collection, Mapping, Optional, Union

import numpy as np
import torch
from torch import Tensor

from ..core import catalog
from ..core.catalog import ARGMAX_TASKS, CLASS_MAP_TASKS, score_terms, scores_from_means
from ..core.scores import metric_variance, total_metric
from ..core.depth import DEPTH_FAR_M, DEPTH_LOG_K, DEPTH_NEAR_M
from ..core.depth_metrics import DEPTH_CONVENTION, DEPTH_METRICS, DepthMetric
from .views import as_views

__all__ = [
    "mae",
    "mae_per_sample",
    "iou",
    "iou_per_sample",
    "total_metric",
    "metric_variance",
    "compute_metrics",
    "metric_tensors",
    "argmax_one_hot",
    "labelled_only",
    "eq5_inputs",
    "CLASS_MAP_TASKS",
    "scored_outputs",
    "compute_metrics_per_sample",
    "iou_argmax_per_sample",
    "ARGMAX_TASKS",
    "scores_from_means",
    "score_terms",
    "total_metric_partial",
    "MV_DEFINITION",
    "class_confusion",
    "multilabel_confusion",
    "class_iou",
    "mean_iou",
    "DEPTH_FAR_M",
    "DEPTH_LOG_K",
    "DEPTH_NEAR_M",
    "DEPTH_CONVENTION",
    "decode_log_depth",
    "depth_valid_mask",
    "depth_errors_per_sample",
    "DepthMetric",
    "DEPTH_METRICS",
]

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


def labelled_only(pred: Tensor, target: Tensor) -> Tensor:
    """``pred`` with 0 at every pixel whose one-hot ``target`` vector is all zero (no label), so
    eq. (5) neither rewards nor charges a prediction there; same shape as ``pred``."""
    g = as_views(target.detach())
    labelled = (g.amax(dim=2, keepdim=True) > 0.5).to(pred.dtype)  # (B,V,1,H,W)
    return (as_views(pred.detach()) * labelled).reshape(pred.shape)


def eq5_inputs(outputs: Mapping[str, Tensor], targets: Mapping[str, Tensor]) -> dict[str, Tensor]:
    """The outputs eq. (5) compares with ``targets``: the class maps' predictions at their
    labelled pixels only (:func:`labelled_only`), every other output as it is."""
    return {k: labelled_only(v, targets[k]) if k in CLASS_MAP_TASKS and k in targets else v
            for k, v in outputs.items()}


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


#: How the project's metrics.json labels MV (paper eq. 7 applied to the test-set means).
MV_DEFINITION = "population variance of the four test-set mean terms (paper eq. 7)"
#: The per-frame scores that enter TM / MV (eq. 6, 7), in this order.
SCORE_TERMS: tuple[str, ...] = catalog.metric_keys()


def total_metric_partial(scores: Mapping[str, float]) -> float:
    """Eq. (6) over the tasks present in ``scores``: ``MAE_DE`` plus ``1 - IoU`` of each IoU
    key present (TM itself for the compact model; a baseline's own share of TM)."""
    out = float(scores.get("mae_de", 0.0))
    for k in SCORE_TERMS[1:]:
        if k in scores:
            out += 1.0 - float(scores[k])
    return out


def argmax_one_hot(probs: Tensor) -> Tensor:
    """A softmax output's predicted class map as a one-hot tensor (class axis -3, as the
    targets): 1 at the arg-max class of every pixel, 0 elsewhere. A scatter into zeros, not
    ``F.one_hot``, which reads the indices' range on the host (a sync on every call)."""
    return torch.zeros_like(probs).scatter_(-3, probs.argmax(dim=-3, keepdim=True), 1.0)


def scored_outputs(outputs: Mapping[str, Tensor], argmax_tasks: Collection[str]) -> dict[str, Tensor]:
    """What eq. (5) scores: every output as it is, except the tasks of ``argmax_tasks`` (a
    model's softmax heads: ``argmax_tasks`` of the model class) replaced by their arg-max
    one-hot map. A softmax spreads one unit of probability over C classes, so its class map
    can be right everywhere with no value above eq. (5)'s 0.5 (docs/gradnorm_segnet.md); the
    sigmoid heads of the compact network are scored by the threshold, as the paper does."""
    return {k: argmax_one_hot(v) if k in argmax_tasks else v for k, v in outputs.items()}


@torch.no_grad()
def metric_tensors(outputs: Mapping[str, Tensor], targets: Mapping[str, Tensor], *,
                   argmax_tasks: Collection[str]) -> dict[str, Tensor]:
    """The batch's task metrics of :func:`compute_metrics` (``mae_de``, ``iou_ss``, ``iou_ls``,
    ``iou_bevp``, those present in both dicts) as 0-d float64 tensors on the outputs' device: no
    value is read by the host (the training loop sums them on the device)."""
    return _task_metrics(outputs, targets, argmax_tasks, mae, iou)


def _task_metrics(outputs: Mapping[str, Tensor], targets: Mapping[str, Tensor], argmax_tasks: Collection[str],
                  depth: Callable[[Tensor, Tensor], Tensor],
                  overlap: Callable[[Tensor, Tensor], Tensor]) -> dict[str, Tensor]:
    """``mae_de`` by ``depth`` and ``iou_<t>`` by ``overlap`` of the tasks in both dicts, on what
    eq. (5) scores (:func:`scored_outputs`, :func:`eq5_inputs`)."""
    outputs = eq5_inputs(scored_outputs(outputs, argmax_tasks), targets)
    out: dict[str, Tensor] = {}
    if "de" in outputs and "de" in targets:
        out["mae_de"] = depth(outputs["de"], targets["de"])
    for t in ("ss", "ls", "bevp"):
        if t in outputs and t in targets:
            out[f"iou_{t}"] = overlap(outputs[t], targets[t])
    return out


def compute_metrics(outputs: Mapping[str, Tensor], targets: Mapping[str, Tensor], *,
                    argmax_tasks: Collection[str]) -> dict[str, float]:
    """Batch metrics for the tasks present in both dicts: ``mae_de``, ``iou_ss``, ``iou_ls``,
    ``iou_bevp``; plus ``tm`` and ``mv`` only when all four are present. ``argmax_tasks``: the
    model's softmax tasks, scored by their arg-max map (:func:`scored_outputs`).

    ``mv`` here is eq. (7) of *this batch's* four scores; a mean of it over batches or frames
    is not the paper's MV (use :func:`scores_from_means` on the split's means)."""
    out = {k: float(v) for k, v in metric_tensors(outputs, targets, argmax_tasks=argmax_tasks).items()}
    terms = score_terms(out)
    if terms is not None:
        out.update({k: float(catalog.SCORES[k].of_terms(*terms)) for k in catalog.SCORES.keys()})
    return out


@torch.no_grad()
def iou_argmax_per_sample(pred: Tensor, target: Tensor) -> Tensor:
    """IoU of the **arg-max class map** per sample (B,): each pixel's highest-scoring class as a
    one-hot map, scored by eq. (5) per view over the pixels that have a ground-truth label (an
    all-zero target vector, 255 in the cache, is left out: no label to be right or wrong about),
    averaged over views. The standard reading of a segmentation map, fair to softmax and sigmoid
    heads alike; Table II keeps eq. (5) on the raw outputs (the paper's rule, SPEC 6), at the
    labelled pixels too."""
    g = as_views(target.detach())
    return iou_per_sample(labelled_only(argmax_one_hot(as_views(pred.detach()).to(g.dtype)), g), g)


def compute_metrics_per_sample(outputs: Mapping[str, Tensor], targets: Mapping[str, Tensor], *,
                               argmax_tasks: Collection[str]) -> dict[str, Tensor]:
    """As :func:`compute_metrics` but every value is a (B,) float64 tensor (one per frame).

    Per-frame scores only (``catalog.SCORES[k].per_frame``: TM; MV is not a per-frame quantity,
    eq. 7 takes the test-set means)."""
    out = _task_metrics(outputs, targets, argmax_tasks, mae_per_sample, iou_per_sample)
    terms = score_terms(out)
    if terms is not None:
        out.update({k: catalog.SCORES[k].of_terms(*terms) for k in catalog.per_frame_scores()})
    return out


def _num(x: Any) -> Union[float, np.ndarray]:
    if isinstance(x, Tensor):
        x = x.detach().cpu().double().numpy()
    arr = np.asarray(x, dtype=np.float64)
    return float(arr) if arr.ndim == 0 else arr


# ----------------------------------------------------------------------------- field metrics
@torch.no_grad()
def class_confusion(pred: Tensor, target: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Per-class ``(TP, FP, FN)`` counts (int64, (C,) each) of a multi-class map (SS, LS).

    ``pred``: scores (B,C,H,W) or (B,V,C,H,W), the predicted class is the arg-max over C;
    ``target``: the one-hot ground truth of the same shape, where an all-zero vector is a
    pixel without a label (255 in the cache, e.g. an LS cell no LiDAR point reaches): such
    pixels are left out. Sum the counts over the test set before :func:`class_iou`.
    """
    p, g = as_views(pred.detach()), as_views(target.detach())
    if p.shape != g.shape:
        raise ValueError(f"class_confusion: prediction {tuple(p.shape)} and target {tuple(g.shape)} differ")
    n_cls = p.shape[2]
    labelled = g.amax(dim=2) > 0.5                       # (B,V,H,W)
    pc = p.argmax(dim=2)[labelled]
    gc = g.argmax(dim=2)[labelled]
    tp = torch.bincount(gc[pc == gc], minlength=n_cls)
    fp = torch.bincount(pc, minlength=n_cls) - tp
    fn = torch.bincount(gc, minlength=n_cls) - tp
    return tp.long().cpu(), fp.long().cpu(), fn.long().cpu()


@torch.no_grad()
def multilabel_confusion(pred: Tensor, target: Tensor, threshold: float = 0.5) -> tuple[Tensor, Tensor, Tensor]:
    """Per-channel ``(TP, FP, FN)`` counts (int64, (C,)) of multi-label masks (BEVP, (B,C,H,W)):
    each class is its own binary problem, ``pred > t`` against ``target > t``."""
    p, g = as_views(pred.detach()) > threshold, as_views(target.detach()) > threshold
    if p.shape != g.shape:
        raise ValueError(f"multilabel_confusion: prediction {tuple(p.shape)} and target {tuple(g.shape)} differ")
    dims = (0, 1, 3, 4)
    tp = (p & g).sum(dim=dims)
    fp = (p & ~g).sum(dim=dims)
    fn = (~p & g).sum(dim=dims)
    return tp.long().cpu(), fp.long().cpu(), fn.long().cpu()


def class_iou(tp: Any, fp: Any, fn: Any) -> np.ndarray:
    """Per-class IoU = TP / (TP + FP + FN) (float64); NaN for a class with TP + FP + FN = 0,
    i.e. absent from both prediction and ground truth."""
    tp, fp, fn = (np.asarray(_num(x), dtype=np.float64) for x in (tp, fp, fn))
    den = tp + fp + fn
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, tp / np.where(den > 0, den, 1.0), np.nan)


def mean_iou(ious: Any) -> float:
    """mIoU: the mean of the per-class IoUs that are defined (absent classes, NaN, are left
    out); NaN if no class is present at all."""
    arr = np.asarray(ious, dtype=np.float64)
    ok = np.isfinite(arr)
    return float(arr[ok].mean()) if ok.any() else float("nan")


#: The cache's depth is CARLA's logarithmic depth in [0, 1] (world/camera.py ``encode_depth``,
#: nuscenes/projection.py ``carla_log_depth``), whose constants :mod:`.core.depth` defines (with
#: ``DEPTH_NEAR_M``, the nearest depth it holds); the depth metrics and their convention are
#: :mod:`.core.depth_metrics`' (the report reads them there, without torch).


def decode_log_depth(x: Tensor) -> Tensor:
    """Metric depth (m) of the cache's normalised log depth: ``1000 m * exp((x - 1) * 5.70378)``
    (x clamped to [0, 1], the encoding's range: 3.33 m .. 1000 m)."""
    return DEPTH_FAR_M * torch.exp((x.double().clamp(0.0, 1.0) - 1.0) * DEPTH_LOG_K)


def depth_valid_mask(target: Tensor, max_m: float = DEPTH_FAR_M) -> Tensor:
    """Ground-truth pixels evaluated: ``0 < x < 1`` and a decoded depth of at most ``max_m``.
    ``x = 0`` is "no depth" (a nuScenes pixel no LiDAR point reaches is stored as 0) or nearer
    than the 3.33 m floor; ``x = 1`` is the 1000 m far clip (sky / no hit in the simulated world);
    beyond ``max_m`` the ground truth is capped away, as the field's depth evaluation does."""
    ok = (target > 0.0) & (target < 1.0)
    if max_m < DEPTH_FAR_M:
        ok = ok & (decode_log_depth(target) <= max_m)
    return ok


@torch.no_grad()
def depth_errors_per_sample(pred: Tensor, target: Tensor, max_m: float = DEPTH_FAR_M) -> dict[str, Tensor]:
    """Per sample (B,): every metric of :data:`DEPTH_METRICS` and ``n_valid``, over the valid
    ground-truth pixels (:func:`depth_valid_mask`: 0 < x* < 1 and d* <= ``max_m``) of all views,
    the field's convention (:data:`DEPTH_CONVENTION`): d is the decoded prediction clamped to
    [3.33 m, ``max_m``] (the encoding's nearest depth, the evaluated maximum), d* the decoded
    ground truth. A sample without valid pixels gives NaN. Sums run in float64 over a fixed
    order (one sample at a time), so the result does not depend on the batch."""
    p, g = pred.detach(), target.detach()
    if p.shape != g.shape:
        raise ValueError(f"depth_errors_per_sample: prediction {tuple(p.shape)} and target {tuple(g.shape)} differ")
    if not DEPTH_NEAR_M < max_m <= DEPTH_FAR_M:
        raise ValueError(f"depth_errors_per_sample: max_m must lie in ({DEPTH_NEAR_M:.2f}, {DEPTH_FAR_M:g}] m, got {max_m}")
    b = p.shape[0]
    valid = depth_valid_mask(g, max_m).reshape(b, -1)
    d = decode_log_depth(p).clamp(DEPTH_NEAR_M, max_m).reshape(b, -1)
    d_gt = decode_log_depth(g).reshape(b, -1)
    n = valid.sum(dim=1).double()
    safe_n = n.clamp(min=1.0)
    v = valid.double()
    nan = torch.full_like(n, float("nan"))
    out: dict[str, Tensor] = {}
    for key in DEPTH_METRICS.keys():
        m = DEPTH_METRICS[key]
        x = m.finish((m.per_pixel(d, d_gt) * v).sum(dim=1) / safe_n)
        out[key] = torch.where(n > 0, x, nan).cpu()
    out["n_valid"] = n.cpu()
    return out
