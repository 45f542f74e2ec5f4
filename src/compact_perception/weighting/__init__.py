"""Loss weighting: static weights, MGN (paper section III-C, Algorithm 1), original GradNorm.

Registry ``WEIGHTINGS`` keyed by ``ModelRecipe.weighting``: ``static``, ``none``, ``mgn``,
``gradnorm``; build one with :func:`build_weighting`.

Interface (:class:`~.base.LossWeighting`)
----------------------------------------
- ``tasks``: tuple of task keys; ``w``: 1-D float64 tensor in task order; ``weights``: dict
  task -> float.
- ``total(losses) -> Tensor``: eq. (8), ``sum_i w_i L_i`` with the weights as constants (detached);
  keys of ``losses`` that are not tasks (e.g. ``aux_*``) are added with weight 1.
- ``before_backward(step, n_steps, losses, model) -> None``
- ``on_epoch_end(improved: bool) -> None``: ``improved`` = this epoch's validation TM dropped;
  plateau halving of the weight lr (MGN) after ``plateau_patience`` epochs without a drop,
  ``lr <- max(lr * plateau_factor, lr_min)``.
- ``state_dict() / load_state_dict(state)``: everything needed to resume (weights, lr, plateau
  count, L_i(0), optimizer state); plain Python/tensors, ``torch.save``-able.
- ``log_values() -> dict[str, float]``: ``w_<task>`` for every task and ``lr_w`` (adaptive ones).

Step protocol (trainer, every training step; ``step`` counts 0..n_steps-1 within the epoch)::

    outputs = model(batch)
    losses = model.compute_losses(outputs, batch)          # task -> scalar (+ aux_* keys)
    weighting.before_backward(step, n_steps, losses, model)
    optimizer.zero_grad()   # may also come before before_backward: in the default mode
                            # before_backward writes no .grad (authors_mode does, so zero first)
    weighting.total(losses).backward()                     # uses the (possibly updated) w
    optimizer.step()
    ... after validation: weighting.on_epoch_end(improved)

- static / none: every hook is a no-op (w = 1).
- mgn: step 0 records L_i(0) (detached); step ``n_steps - 1`` (the same step when n_steps == 1)
  does one update of w (G_i, r_i, detached targets, L_MGN, SGD step, positive floor, sum w = T).
  No network parameter or ``.grad`` is touched (``torch.autograd.grad`` with ``retain_graph``).
  ``authors_mode`` (MgnParams): second-order terms of L_MGN are accumulated into the network
  ``.grad`` and w also gets ``dL_total/dw`` (see :class:`~.mgn.MGNWeighting`).
- gradnorm: L_i(0) from the very first step; one update of w at every step (Adam).

Non-positive weights: after a step, ``w <- max(w, 1e-3 T)`` before eq. (15) renormalisation,
so every weight stays strictly positive and sum w = T (see :class:`~.mgn.GradNormCore`).
"""
from __future__ import annotations

from typing import Any, Callable, Sequence

from torch import nn

from ..config import ModelRecipe
from ..registry import Registry
from .base import LossWeighting, shared_weights
from .gradnorm import GradNormWeighting
from .mgn import GradNormCore, MGNWeighting
from .static import NoWeighting, StaticWeighting

__all__ = [
    "WEIGHTINGS",
    "build_weighting",
    "LossWeighting",
    "StaticWeighting",
    "NoWeighting",
    "MGNWeighting",
    "GradNormWeighting",
    "GradNormCore",
    "shared_weights",
]

WeightingFactory = Callable[..., LossWeighting]
WEIGHTINGS: Registry[WeightingFactory] = Registry("loss weighting")
WEIGHTINGS.register("static")(StaticWeighting.from_recipe)
WEIGHTINGS.register("none")(NoWeighting.from_recipe)
WEIGHTINGS.register("mgn")(MGNWeighting.from_recipe)
WEIGHTINGS.register("gradnorm")(GradNormWeighting.from_recipe)


def build_weighting(
    recipe: ModelRecipe,
    tasks: Sequence[str],
    model: nn.Module | None = None,
    *,
    plateau_patience: int = 4,
    plateau_factor: float = 0.5,
) -> LossWeighting:
    """The weighting named by ``recipe.weighting`` for ``tasks``; adaptive ones read W's module
    names from ``model.shared_layers()`` (now if ``model`` is given, else at the first update).
    ``plateau_patience``/``plateau_factor``: TrainParams' values, for MGN's weight-lr halving."""
    kw: dict[str, Any] = {"plateau_patience": plateau_patience, "plateau_factor": plateau_factor}
    return WEIGHTINGS[recipe.weighting](recipe, tuple(tasks), model, **kw)
