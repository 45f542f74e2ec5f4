"""Loss weighting: static weights, MGN (paper section III-C, Algorithm 1), original GradNorm, and
the loss-balancing study's methods: uncertainty weighting, DWA, PCGrad, CAGrad.

Registry ``WEIGHTINGS`` (classes, each registered by ``@register("id")`` in its own module; this
package imports every module, so a new method is one new file plus its params.yaml entry) keyed by
``ModelRecipe.weighting``: ``static``, ``none``, ``mgn``,
``gradnorm``, ``uw`` (Kendall et al. 2018), ``dwa`` (Liu et al. 2019), ``pcgrad`` (Yu et al.
2020), ``cagrad`` (Liu et al. 2021), ``single`` (one-hot weights: the study's single-task
reference); build one with :func:`build_weighting`. Each class has a
``label`` and a ``params_model`` (the schema of its recipe section, named like its id, e.g.
``uw: {lr: ...}``, defined in the method's own module; ``None`` for static / none);
:func:`weighting_settings` checks a recipe's section against it when a stage starts.

Interface (:class:`~.base.LossWeighting`)
----------------------------------------
- ``tasks``: tuple of task keys; ``w``: 1-D float64 tensor in task order, on the network's device
  (``to(device)``); ``weights``: dict task -> float.
- ``total(losses) -> Tensor``: eq. (8), ``sum_i w_i L_i`` with the weights as constants (detached);
  keys of ``losses`` that are not tasks (e.g. ``aux_*``) are added with weight 1.
- ``backward(losses, model, scale) -> Tensor``: backpropagates the step into the network's
  ``.grad`` and returns the (detached) total loss for logging. Default:
  ``scale(total(losses)).backward()``. ``scale`` is the trainer's ``GradScaler.scale`` (identity
  when loss scaling is off). Gradient-surgery methods (pcgrad, cagrad) override it: T per-task
  ``torch.autograd.grad`` passes, then the combined gradient is *added* to ``.grad`` (set when
  it is ``None``); uw overrides it to also step its log-variances.
- ``before_backward(step, n_steps, losses, model) -> None``; ``after_backward(taken=True) -> None``
  (``taken``: whether the optimiser step went through; a float16 GradScaler skips overflowing ones)
- ``on_epoch_end(improved: bool) -> None``: ``improved`` = this epoch's validation TM dropped;
  plateau halving of the weight lr (MGN) after ``plateau_patience`` epochs without a drop,
  ``lr <- max(lr * plateau_factor, lr_min)``.
- ``state_dict() / load_state_dict(state)``: everything needed to resume bit-identically (weights,
  lr, plateau count, L_i(0), optimizer states, uw's s, dwa's epoch sums and means, pcgrad's
  generator state); plain Python/tensors, ``torch.save``-able.
- ``log_values() -> dict[str, float]``: ``w_<task>`` for every task, ``lr_w`` (MGN, GradNorm),
  ``conflicts`` (PCGrad).

Step protocol (trainer, every training step; ``step`` counts 0..n_steps-1 within the epoch)::

    optimizer.zero_grad(set_to_none=True)  # before the forward: MGN's authors_mode writes .grad
                                           # in before_backward
    outputs = model(batch)
    losses = model.compute_losses(outputs, batch)          # task -> scalar (+ aux_* keys)
    weighting.grad_scale = scaler.get_scale()              # 1.0 without loss scaling
    weighting.before_backward(step, n_steps, losses, model)  # MGN / GradNorm compute w(t+1) here
    total = weighting.backward(losses, model, scaler.scale)  # with the step's weights w(t)
    average_gradients(...)                                   # data-parallel: before unscaling
    scaler.unscale_(optimizer); scaler.step(optimizer); scaler.update()
    weighting.after_backward(taken)                          # w(t+1) committed with a step taken
    # data-parallel: w averaged over ranks when it changed (w is replaced, never edited in place)
    ... after validation: weighting.on_epoch_end(improved)

Data-parallel runs: the trainer sets ``weighting.ranks`` (the process group), through which a value
taken from each rank's own batches is agreed over the ranks before it sets a weight (DWA's epoch
sums, MGN's and GradNorm's L_i(0)); in one process it is ``None`` and nothing is reduced.

- static / none: every hook is a no-op (w = 1).
- mgn: step 0 records L_i(0) (detached); step ``n_steps - 1`` (the same step when n_steps == 1)
  does one update of w (G_i, r_i, detached targets, L_MGN, SGD step, positive floor, sum w = T).
  No network parameter or ``.grad`` is touched (``torch.autograd.grad`` with ``retain_graph``).
  ``authors_mode`` (:class:`~.mgn.MgnParams`): second-order terms of L_MGN are accumulated into the network
  ``.grad`` and w also gets ``dL_total/dw`` (see :class:`~.mgn.MGNWeighting`).
- gradnorm: L_i(0) from the very first step; one update of w at every step (Adam).
- uw: ``sum_i exp(-s_i) L_i + s_i``; ``backward`` also takes one Adam step on s; w = exp(-s).
- dwa: ``before_backward`` sums the task losses, ``on_epoch_end`` sets w from the last two
  epochs' means (w = 1 in the first two epochs).
- pcgrad / cagrad: everything happens in ``backward`` (T backward passes per step); pcgrad's w
  stays 1, cagrad's w are the effective weights of its direction d on the shared parameters.

Non-positive weights (MGN, GradNorm): after a step, ``w <- max(w, 1e-3 T)`` before eq. (15) renormalisation,
so every weight stays strictly positive and sum w = T (see :class:`~.mgn.GradNormCore`).
"""
from __future__ import annotations

from typing import Any, Sequence

from pydantic import ValidationError
from torch import nn

from ...core.params import ModelRecipe, ParamsError, Strict, format_error
from ...core.registry import import_submodules
from .base import WEIGHTINGS, LossWeighting, register, shared_weights

# Every module of this package registers its classes (``@register("id")``) on import; importing
# them all here means a new method is one new file, found without editing this one.
import_submodules(__name__, __path__)

from .cagrad import CAGradParams, CAGradWeighting  # noqa: E402
from .dwa import DWAParams, DWAWeighting  # noqa: E402
from .gradnorm import GradNormParams, GradNormWeighting  # noqa: E402
from .mgn import GradNormCore, MGNWeighting, MgnParams  # noqa: E402
from .pcgrad import PCGradParams, PCGradWeighting  # noqa: E402
from .single import SingleTaskParams, SingleTaskWeighting  # noqa: E402
from .static import NoWeighting, StaticWeighting  # noqa: E402
from .uw import UncertaintyWeighting, UWParams  # noqa: E402

__all__ = [
    "WEIGHTINGS",
    "register",
    "build_weighting",
    "network_tasks",
    "weighting_class",
    "weighting_settings",
    "LossWeighting",
    "StaticWeighting",
    "NoWeighting",
    "MGNWeighting",
    "MgnParams",
    "GradNormWeighting",
    "GradNormParams",
    "GradNormCore",
    "UncertaintyWeighting",
    "UWParams",
    "DWAWeighting",
    "DWAParams",
    "PCGradWeighting",
    "PCGradParams",
    "CAGradWeighting",
    "CAGradParams",
    "SingleTaskWeighting",
    "SingleTaskParams",
    "shared_weights",
]


def weighting_class(key: str) -> type[LossWeighting]:
    """The class registered as ``key`` (its ``label``, ``params_model`` and ``from_recipe``)."""
    return WEIGHTINGS[key]


def weighting_settings(recipe: ModelRecipe, source: str = "params.yaml", *, compiled: bool = False) -> Strict | None:
    """The settings of the recipe's weighting, its section validated by the method's ``params_model``
    (``None`` for a method without settings), checked before a stage writes anything. Bad input is a
    :class:`~compact_perception.core.params.ParamsError` naming the key in ``source``, e.g.
    ``params.yaml: study.arms.uw.uw.lr: Input should be a valid number (got 'fast')``. ``compiled``
    (``train.compile``): a method that differentiates through the network's gradients
    (:meth:`~.base.LossWeighting.needs_double_backward`: MGN's authors update) is refused, since
    torch.compile's AOTAutograd has no double backward."""
    if recipe.weighting not in WEIGHTINGS:
        raise ParamsError(f"{source}: {recipe.key_of('weighting')}: unknown loss weighting {recipe.weighting!r}; "
                          f"known: {', '.join(WEIGHTINGS.keys())}")
    cls = WEIGHTINGS[recipe.weighting]
    schema, key = cls.params_model, recipe.key_of(recipe.weighting)
    if schema is None:
        if recipe.section(recipe.weighting):
            raise ParamsError(f"{source}: {key}: weighting {recipe.weighting!r} takes no settings; remove the key")
        return None
    try:
        settings = schema.model_validate(recipe.section(recipe.weighting))
    except ValidationError as err:
        raise ParamsError(format_error(err, source, key)) from None
    if compiled and cls.needs_double_backward(settings):
        raise ParamsError(f"{source}: train.compile: true cannot train {key} (its update differentiates through the "
                          "network's gradients, a double backward torch.compile does not support); set "
                          "train.compile: false")
    return settings


def network_tasks(recipe: ModelRecipe, tasks: Sequence[str]) -> tuple[str, ...]:
    """The tasks a network trained with ``recipe`` is built for (all ``tasks`` but for ``single``)."""
    return WEIGHTINGS[recipe.weighting].network_tasks(recipe, tuple(tasks))


def build_weighting(
    recipe: ModelRecipe,
    tasks: Sequence[str],
    model: nn.Module | None = None,
    *,
    plateau_patience: int,
    plateau_factor: float,
) -> LossWeighting:
    """The weighting named by ``recipe.weighting`` for ``tasks``; adaptive ones read W's module
    names from ``model.shared_layers()`` (now if ``model`` is given, else at the first update).
    ``plateau_patience``/``plateau_factor``: TrainParams' values and ``recipe.plateau_rule``, for
    MGN's weight-lr halving. The weighting's state lives on the device of ``model``'s parameters."""
    kw: dict[str, Any] = {"plateau_patience": plateau_patience, "plateau_factor": plateau_factor,
                          "plateau_rule": recipe.plateau_rule}
    weighting = WEIGHTINGS[recipe.weighting].from_recipe(recipe, tuple(tasks), model, **kw)
    first = next(model.parameters(), None) if model is not None else None
    return weighting.to(first.device) if first is not None else weighting
