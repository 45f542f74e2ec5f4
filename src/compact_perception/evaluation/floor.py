"""The trivial-predictor floor (SPEC 8): what a network must beat before its numbers mean anything.

In a fixed-camera driving scene the prior of each pixel is strong (sky above, road below, the
ego vehicle at the centre of the top view), so an input-blind predictor already scores well.
Two such predictors are fitted on the **train split** of a cache and scored on its test split
with the same metric code as every model (:mod:`compact_perception.evaluation.evaluate`):

- ``floor_pixel`` (the floor): per pixel, the train split's most frequent SS class of each view
  and LS class, "no label" (255) included as a value of its own (where it wins, the predictor
  predicts nothing there: the all-zero vector, as the cache's one-hot has it); per BEV mask and
  pixel the majority (1 where the mask is set in more than half of the train frames); per pixel
  of each view the mean DE over the train frames.
- ``floor_global``: one value everywhere: the most frequent SS class over every pixel of every
  view, the most frequent LS value over every cell (255 included), per BEV mask its overall
  majority, and the mean DE over every pixel.

Ties go to the lowest class index, and "no label" loses every tie. The predictions are float32
tensors in the targets' layout, so :func:`~compact_perception.learning.metrics.compute_metrics` scores them
by eq. (4)-(7) as it scores a network's sigmoid outputs (threshold 0.5). Where "no label" wins, the
prediction is not all zero but :data:`ABSTAIN_SCORE` (< 0.5) on the most frequent labelled class:
nothing by eq. (5), and that class for the arg-max rule of the extra metrics
(:func:`~compact_perception.learning.metrics.iou_argmax_per_sample`), which scores labelled pixels only.

:func:`floor_of` takes the better of the two per metric: the per-task floor a model's margin
(:func:`margins`) and the report's "above the floor" gate are measured against. The predictors'
ids and labels, :func:`floor_of` and :func:`margins` are :mod:`compact_perception.core.floor_rule`'s
(re-exported here), so the report reads them without torch.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping

import numpy as np
import torch
from torch import Tensor, nn

from ..core import catalog
from ..core.cache import read_meta, read_split
from ..core.floor_rule import FLOOR_PREDICTORS, floor_of, margins
from ..core.registry import Registry

__all__ = ["TrivialInfo", "TRIVIAL", "FixedPredictor", "fit_trivial", "floor_of", "margins", "NO_LABEL",
           "ABSTAIN_SCORE"]

NO_LABEL = 255
#: The score a class map gets where "no label" is the most frequent value: below eq. (5)'s 0.5,
#: on the most frequent labelled class (what an arg-max reads there).
ABSTAIN_SCORE = 0.25
#: Frames per chunk when counting (bounded memory at the paper's scale).
_CHUNK = 256


@dataclass(frozen=True)
class TrivialInfo:
    """One input-blind predictor: its report label and how it is fitted from the train arrays."""

    label: str
    fit: Callable[[Mapping[str, np.ndarray], int], dict[str, np.ndarray]]


def _chunks(a: np.ndarray):
    for i in range(0, a.shape[0], _CHUNK):
        yield np.asarray(a[i:i + _CHUNK])


def _counts(a: np.ndarray, n_cls: int, per_pixel: bool) -> np.ndarray:
    """(n_cls + 1, P) (per pixel) or (n_cls + 1,) counts of every class of uint8 index maps
    ``a`` (frames first), the last row counting ``NO_LABEL``."""
    shape = a.shape[1:]
    n_pix = int(np.prod(shape)) if per_pixel else 1
    out = np.zeros((n_cls + 1) * n_pix, dtype=np.int64)
    for chunk in _chunks(a):
        v = chunk.reshape(chunk.shape[0], -1).astype(np.int64)
        bad = (v != NO_LABEL) & (v >= n_cls)
        if bad.any():
            raise ValueError(f"class index {int(v[bad][0])} outside 0..{n_cls - 1} and not {NO_LABEL}")
        v = np.where(v == NO_LABEL, n_cls, v)
        key = v * n_pix + (np.arange(v.shape[1]) if per_pixel else 0)
        out += np.bincount(key.ravel(), minlength=out.size)
    return out.reshape(n_cls + 1, n_pix)


def _class_scores(a: np.ndarray, n_cls: int, per_pixel: bool, axis: int) -> np.ndarray:
    """The fixed class map of uint8 index maps ``a`` (frames first) as float32 scores with the class
    axis at ``axis``: 1 on the most frequent value ("no label" a value of its own that loses every
    tie), or, where "no label" wins, :data:`ABSTAIN_SCORE` on the most frequent labelled class."""
    counts = _counts(a, n_cls, per_pixel)                            # (n_cls + 1, P)
    mode, labelled = counts.argmax(axis=0), counts[:n_cls].argmax(axis=0)
    score = np.where(mode == n_cls, ABSTAIN_SCORE, 1.0)
    cls = np.where(mode == n_cls, labelled, mode)
    shape = a.shape[1:]
    cls, score = (np.broadcast_to(x.reshape(shape) if per_pixel else x[0], shape) for x in (cls, score))
    return np.stack([np.where(cls == c, score, 0.0) for c in range(n_cls)], axis=axis).astype(np.float32)


def _mean(a: np.ndarray, per_pixel: bool) -> np.ndarray:
    total, n = np.zeros(a.shape[1:], dtype=np.float64), 0
    for chunk in _chunks(a):
        total += chunk.astype(np.float64).sum(axis=0)
        n += chunk.shape[0]
    mean = total / n
    return mean if per_pixel else np.full(a.shape[1:], mean.mean())


def _fit(arrays: Mapping[str, np.ndarray], n_cls: int, per_pixel: bool) -> dict[str, np.ndarray]:
    """The fixed prediction of one trivial predictor, per task, without the batch axis."""
    bev_share = _mean(arrays["bevp"], per_pixel=True)                # (Cb,S,S)
    if not per_pixel:
        bev_share = np.broadcast_to(bev_share.mean(axis=(1, 2), keepdims=True), bev_share.shape)
    return {
        "de": _mean(arrays["de"], per_pixel).astype(np.float32),     # (V,1,S,S)
        "ss": _class_scores(arrays["ss"], n_cls, per_pixel, axis=1),  # (V,C,S,S) from (N,V,S,S)
        "ls": _class_scores(arrays["ls"], n_cls, per_pixel, axis=0),  # (C,S,S) from (N,S,S)
        "bevp": (bev_share > 0.5).astype(np.float32),                # (Cb,S,S)
    }


#: The trivial predictors, in the order of the report's rows: one fit per id of
#: :data:`.core.floor_rule.FLOOR_PREDICTORS`, which gives each its label.
TRIVIAL: Registry[TrivialInfo] = Registry("trivial predictor", ordered=True)


def _register(trivial_id: str, fit: Callable[[Mapping[str, np.ndarray], int], dict[str, np.ndarray]]) -> None:
    """Register ``fit`` for ``trivial_id`` under its label in ``core.floor_rule`` (an id missing there fails)."""
    TRIVIAL.register(trivial_id)(TrivialInfo(FLOOR_PREDICTORS[trivial_id], fit))


_register("floor_pixel", lambda a, c: _fit(a, c, per_pixel=True))
_register("floor_global", lambda a, c: _fit(a, c, per_pixel=False))


class FixedPredictor(nn.Module):
    """An input-blind "model": the same prediction for every frame (one per task), expanded to
    the batch. It has the interface evaluation uses (``tasks``, ``argmax_tasks``, ``forward``)."""

    argmax_tasks: tuple[str, ...] = ()

    def __init__(self, prediction: Mapping[str, np.ndarray]) -> None:
        super().__init__()
        self.tasks = tuple(t for t in catalog.task_ids() if t in prediction)
        for t in self.tasks:
            self.register_buffer(f"pred_{t}", torch.from_numpy(np.ascontiguousarray(prediction[t])))

    def forward(self, batch: Mapping[str, Tensor]) -> dict[str, Tensor]:
        n = next(v for v in batch.values() if isinstance(v, Tensor)).shape[0]
        out = {}
        for t in self.tasks:
            p = getattr(self, f"pred_{t}")
            out[t] = p.unsqueeze(0).expand(n, *p.shape)
        return out


def fit_trivial(trivial_id: str, cache_dir: str | Path) -> FixedPredictor:
    """Fit trivial predictor ``trivial_id`` (:data:`TRIVIAL`) on the train split of ``cache_dir``."""
    meta = read_meta(cache_dir)
    arrays = read_split(cache_dir, "train", meta).arrays
    return FixedPredictor(TRIVIAL[trivial_id].fit(arrays, len(meta["seg_classes"])))
