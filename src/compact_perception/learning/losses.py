"""Task losses (paper section III-B) and the losses the baselines need.

Shapes follow docs/ARCHITECTURE.md: per-view tasks are (B, V, C, H, W), single-view
tasks (B, C, H, W) (treated as V = 1). Every function returns a scalar tensor that
keeps the autograd graph.

- :func:`huber_loss`     eq. (1)-(2), the DE loss (delta = 0.5).
- :func:`de_loss_factor` / :func:`scale_de_loss`: the DE loss form of a recipe (``de_loss``):
  ``huber`` = eq. (2); ``smooth_l1`` = torch's ``smooth_l1_loss(beta=delta)`` = eq. (2) / delta,
  what the authors' code trains with (twice eq. (2) at delta 0.5).
- :func:`bce_dice_loss`  eq. (3), the SS / LS / BEVP loss. The paper writes the BCE term
  without its minus sign; we use the standard, positive BCE
  ``-(y log p + (1-y) log(1-p))`` (the printed form would be maximised by training).
- :func:`cross_entropy_onehot`, :func:`lovasz_softmax`, :func:`squared_loss`,
  :func:`kl_normal`: the baselines' recipes (SegNet/GradNorm, PolarNet, Chen et al.).
"""
from __future__ import annotations

from typing import Sequence

import torch
from torch import Tensor
import torch.nn.functional as F

from .views import as_views, class_dim

__all__ = [
    "huber_loss",
    "de_loss_factor",
    "scale_de_loss",
    "bce_dice_loss",
    "cross_entropy_onehot",
    "lovasz_softmax",
    "squared_loss",
    "kl_normal",
]


def huber_loss(pred: Tensor, target: Tensor, delta: float = 0.5) -> Tensor:
    """Huber loss, eq. (1)-(2): ``z = 0.5 d^2`` if ``|d| < delta`` else ``delta (|d| - 0.5 delta)``.

    Mean over all elements; every view has the same number of elements, so this equals
    eq. (1)'s mean over views of the per-view means.
    """
    d = pred - target
    a = d.abs()
    z = torch.where(a < delta, 0.5 * d * d, delta * (a - 0.5 * delta))
    return z.mean()


#: DE loss forms (``ModelRecipe.de_loss``) -> the factor on eq. (2)'s Huber loss at delta = 0.5
DE_LOSS_FORMS: dict[str, float] = {"huber": 1.0, "smooth_l1": 1.0 / 0.5}


def de_loss_factor(form: str) -> float:
    """Factor turning :func:`huber_loss` (delta 0.5) into the DE loss ``form``: 1 for ``huber``
    (eq. 2), 1 / delta = 2 for ``smooth_l1`` (torch's ``smooth_l1_loss(beta=0.5)``: ``0.5 d^2 / beta``
    below beta, ``|d| - 0.5 beta`` above, i.e. eq. (2) divided by delta)."""
    try:
        return DE_LOSS_FORMS[form]
    except KeyError:
        raise ValueError(f"unknown DE loss form {form!r}; known: {sorted(DE_LOSS_FORMS)}") from None


def scale_de_loss(losses: dict[str, Tensor], factor: float) -> dict[str, Tensor]:
    """``losses`` with the ``de`` entry multiplied by ``factor`` (no copy of the graph at 1.0)."""
    if factor == 1.0 or "de" not in losses:
        return losses
    return {**losses, "de": losses["de"] * factor}


def bce_dice_loss(pred: Tensor, target: Tensor, eps: float = 1e-7) -> Tensor:
    """BCE + Dice, eq. (3): ``mean_v [ BCE_v + (1 - Dice_v) ]``.

    ``pred`` are probabilities (clamped to ``[eps, 1-eps]`` for the logs), ``target`` is
    0/1; shapes (B,C,H,W) (V = 1) or (B,V,C,H,W). For view v, ``BCE_v`` is the standard
    (positive) binary cross entropy averaged over the view's elements (whole batch) and
    ``Dice_v = (2 sum(p y) + eps) / (sum p + sum y + eps)`` over the same elements (the
    eps smoothing makes an empty target with an empty prediction a perfect Dice of 1).
    """
    p = as_views(pred)
    y = as_views(target).to(p.dtype)
    pc = p.clamp(eps, 1.0 - eps)
    bce = -(y * torch.log(pc) + (1.0 - y) * torch.log(1.0 - pc))  # (B,V,C,H,W)
    dims = (0, 2, 3, 4)
    bce_v = bce.mean(dim=dims)  # (V,)
    inter = (p * y).sum(dim=dims)
    denom = p.sum(dim=dims) + y.sum(dim=dims)
    dice_v = (2.0 * inter + eps) / (denom + eps)
    return (bce_v + 1.0 - dice_v).mean()


def cross_entropy_onehot(logits: Tensor, target_onehot: Tensor, labelled: Tensor | None = None) -> Tensor:
    """Pixel-wise cross entropy from logits with one-hot targets.

    The class axis is dim 1 for (B,C,H,W) and dim 2 for (B,V,C,H,W). Pixels whose target
    one-hot vector is all zero (no label, ARCHITECTURE "255") are ignored; the result is
    the mean over labelled pixels (0 with a graph if none is labelled).

    ``labelled``: the flat indices of the labelled pixels (row-major over the per-pixel map), found
    on the host (:class:`compact_perception.data.loader.Labelled`): the same gather, sum and mean as the
    boolean mask, without reading the device (the mask's ``nonzero`` and the count's test do).
    """
    dim = class_dim(logits)
    y = target_onehot.to(logits.dtype)
    logp = F.log_softmax(logits, dim=dim)
    per_pixel = -(y * logp).sum(dim=dim)
    if labelled is not None:
        if labelled.numel() == 0:
            return logits.sum() * 0.0
        return per_pixel.reshape(-1)[labelled].sum() / labelled.numel()
    valid = y.sum(dim=dim) > 0
    n = valid.sum()
    if n == 0:
        return logits.sum() * 0.0
    return per_pixel[valid].sum() / n


def _lovasz_grad(fg_sorted: Tensor) -> Tensor:
    """Gradient of the Lovasz extension of the Jaccard loss at sorted errors (Berman et al. 2018, Alg. 1).

    For prefix sets S_k = {pi_1..pi_k} of pixels sorted by decreasing error,
    ``Delta_J(S_k) = 1 - |gt \\ S_k| / |gt U S_k|`` and the gradient is
    ``g_k = Delta_J(S_k) - Delta_J(S_{k-1})``.
    """
    gts = fg_sorted.sum()
    inter = gts - fg_sorted.cumsum(0)
    union = gts + (1.0 - fg_sorted).cumsum(0)
    jac = 1.0 - inter / union
    if jac.numel() > 1:
        jac = torch.cat([jac[:1], jac[1:] - jac[:-1]])
    return jac


def lovasz_softmax(probs: Tensor, target_onehot: Tensor, labelled: Tensor | None = None,
                   classes: Sequence[int] | None = None) -> Tensor:
    """Lovasz-softmax loss (Berman, Rannen Triki, Blaschko, CVPR 2018), classes = 'present'.

    ``probs``: softmax probabilities, class axis 1 (B,C,H,W) or 2 (B,V,C,H,W). All pixels
    of the batch are pooled; pixels with an all-zero target are ignored. For each class c
    present in the target, errors ``m_c = |y_c - p_c|`` are sorted in decreasing order and
    dotted with the Lovasz-extension gradient of the Jaccard loss; the loss is the mean
    over present classes (0 with a graph if no pixel is labelled).

    ``labelled`` and ``classes``: the labelled pixels' flat indices and the classes present among
    them, found on the host (:class:`compact_perception.data.loader.Labelled`): the same computation
    without a host read of the device (the mask's ``nonzero`` and each class's presence test).
    """
    dim = class_dim(probs)
    c = probs.shape[dim]
    p = probs.movedim(dim, -1).reshape(-1, c)
    y = target_onehot.to(probs.dtype).movedim(dim, -1).reshape(-1, c)
    if labelled is not None and classes is not None:
        p, y, present = p[labelled], y[labelled], set(classes)
    else:
        valid = y.sum(dim=1) > 0
        p, y, present = p[valid], y[valid], None
    losses = []
    for k in range(c):
        fg = y[:, k]
        absent = k not in present if present is not None else bool(fg.sum() <= 0)
        if absent:
            continue
        err = (fg - p[:, k]).abs()
        err_sorted, perm = torch.sort(err, descending=True)
        losses.append(torch.dot(err_sorted, _lovasz_grad(fg[perm])))
    if not losses:
        return probs.sum() * 0.0
    return torch.stack(losses).mean()


def squared_loss(pred: Tensor, target: Tensor) -> Tensor:
    """Mean squared error over all elements."""
    d = pred - target
    return (d * d).mean()


def kl_normal(mu: Tensor, logvar: Tensor) -> Tensor:
    """``KL(N(mu, exp(logvar)) || N(0, I))``: sum over non-batch dims, mean over the batch.

    ``KL = -0.5 * sum(1 + logvar - mu^2 - exp(logvar))``.
    """
    kl = -0.5 * (1.0 + logvar - mu * mu - logvar.exp())
    return kl.reshape(kl.shape[0], -1).sum(dim=1).mean()
