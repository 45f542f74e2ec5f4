"""The loss-weighting interface (see the package docstring for the step protocol)."""
from __future__ import annotations

from typing import Any, Callable, ClassVar, Mapping, Protocol, Sequence

import torch
from torch import Tensor, nn

from ...core.catalog import WEIGHTING_METHODS
from ...core.params import Strict
from ...core.errors import NonFinite
from ...core.registry import Registry

__all__ = ["LossWeighting", "Ranks", "WEIGHTINGS", "finite_or_raise", "register", "recipe_params", "shared_weights"]


def finite_or_raise(w: Tensor, what: str) -> Tensor:
    """``w`` when every value is finite, else :class:`NonFinite` naming ``what`` and the values.
    A host read of ``w``: a weighting calls it where a step reads anyway (MGN's update at the
    epoch's last step, a float16 run's skipped-step logic), never in an ordinary fp32/bf16 step."""
    if not bool(torch.isfinite(w).all()):
        raise NonFinite(f"non-finite {what} ({[round(float(x), 6) for x in w.tolist()]})")
    return w


class Ranks(Protocol):
    """The data-parallel process group as a loss weighting sees it (training/distributed.py's
    ``Dist``): sums and means over the ranks, each a new tensor on the given tensor's device."""

    def sum_over_ranks(self, t: Tensor) -> Tensor: ...

    def mean_over_ranks(self, t: Tensor) -> Tensor: ...


class LossWeighting:
    """Base class: fixed weights ``w`` (1-D float64 tensor, task order = ``tasks``).

    ``total`` implements eq. (8) with the weights as constants; every hook is a no-op.
    Subclasses override :meth:`before_backward` / :meth:`on_epoch_end` and extend the state.

    ``grad_scale``: the loss scale of the trainer's float16 ``GradScaler`` (the trainer sets it
    before every :meth:`before_backward`; 1.0 = no scaling, the default). Weightings that take
    gradients of the losses themselves (GradNorm, MGN) scale by it and unscale their result,
    so float16 gradients do not underflow (:mod:`compact_perception.learning.training.precision`).

    Device: every tensor of the state (``w``, and a subclass's own: L_i(0), log-variances, their
    optimiser, sums) lives on the network's device (:meth:`to`; :func:`~compact_perception.learning.weighting.build_weighting`
    moves it there), so a step's weighting arithmetic runs on the device and nothing travels
    between host and device. Without loss scaling (fp32, bf16) no hook reads a device value in an
    ordinary step: a non-finite value is left to the trainer's check of the epoch's sums and
    weights (training/epoch.py). Under a float16 GradScaler, whose scale the trainer reads every
    step anyway, the skipped-step logic reads what it needs (``_scaled`` is then true).

    Every concrete class declares ``params_model`` (the pydantic schema of its recipe section,
    named like its registry id; ``None`` when it has no settings). ``label`` (its name in the
    report) and ``adaptive`` (whether its loss weights change during training: the report draws
    those) come from its entry in :data:`compact_perception.core.catalog.WEIGHTING_METHODS`, set
    by :func:`register`.
    """

    key: ClassVar[str]                   # the registry id (set by :func:`register`)
    label: ClassVar[str]
    params_model: ClassVar[type | None]
    adaptive: ClassVar[bool] = True
    grad_scale: float = 1.0

    #: Whether a training step of this method can be captured as a CUDA graph
    #: (:mod:`compact_perception.learning.training.capture`): its ordinary steps (neither the first
    #: nor the last of an epoch) do the same device work whatever the step, read nothing from the
    #: device, change no Python-side state and replace none of its tensors (in-place updates only).
    capturable: bool = False

    #: The process group of a data-parallel run (the trainer sets it: training/train.py), through
    #: which a value closed from every rank's batches is agreed before it sets a weight: DWA's epoch
    #: means, MGN's and GradNorm's L_i(0). ``None`` in one process: nothing is reduced, no op added.
    ranks: Ranks | None = None

    def __init__(
        self,
        tasks: Sequence[str],
        weights: Mapping[str, float] | None = None,
        *,
        plateau_patience: int,
        plateau_factor: float,
    ) -> None:
        if not tasks:
            raise ValueError("a loss weighting needs at least one task")
        if len(set(tasks)) != len(tasks):
            raise ValueError(f"duplicate tasks in {list(tasks)}")
        self.tasks: tuple[str, ...] = tuple(tasks)
        w = [1.0] * len(self.tasks)
        if weights is not None:
            unknown = set(weights) - set(self.tasks)
            if unknown:
                raise KeyError(f"weights for unknown task(s) {sorted(unknown)}; tasks: {list(self.tasks)}")
            w = [float(weights.get(t, 1.0)) for t in self.tasks]
        # w is replaced when it changes, never edited in place (the data-parallel step tells a
        # change by identity: training/epoch.py)
        self.w: Tensor = torch.tensor(w, dtype=torch.float64)
        self.device = torch.device("cpu")
        self.plateau_patience = int(plateau_patience)
        self.plateau_factor = float(plateau_factor)

    @classmethod
    def from_recipe(cls, recipe: Any, tasks: Sequence[str], model: nn.Module | None = None,
                    **kw: Any) -> "LossWeighting":
        """The weighting of a training recipe: the recipe's section named like the registry id
        (``uw: {lr: ...}``), validated by ``params_model``, passed as keyword arguments with
        ``plateau_patience``/``plateau_factor`` (``kw``). Methods that need more (the network's
        shared layers: MGN, GradNorm) override it."""
        settings: dict[str, Any] = {}
        if cls.params_model is not None:
            settings = dict(recipe_params(recipe, cls.key, cls.params_model))
        return cls(tasks, **settings, plateau_patience=kw["plateau_patience"], plateau_factor=kw["plateau_factor"])

    @classmethod
    def network_tasks(cls, recipe: Any, tasks: Sequence[str]) -> tuple[str, ...]:
        """The tasks the network is built for when trained with this weighting: all of them,
        except for a method that trains some tasks only (``single``)."""
        return tuple(tasks)

    # ------------------------------------------------------------------ device
    def to(self, device: torch.device | str) -> "LossWeighting":
        """Keep the weighting's state on ``device`` (the network's); returns ``self``. Call it before
        the first step (a subclass moves its own tensors, optimisers' parameters included)."""
        self.device = torch.device(device)
        self.w = self.w.to(self.device)
        return self

    @property
    def _scaled(self) -> bool:
        """A float16 GradScaler scales this step's losses (its skipped-step logic may read values)."""
        return float(self.grad_scale) != 1.0

    def _device_tensor(self, values: Any, dtype: torch.dtype = torch.float64) -> Tensor:
        """``values`` (numbers, a list, a tensor read from a checkpoint) as a tensor on the device."""
        return torch.as_tensor(values, dtype=dtype).to(self.device)

    # ------------------------------------------------------------------ weights
    @property
    def T(self) -> int:
        """Number of tasks (eq. 15's T)."""
        return len(self.tasks)

    @property
    def weights(self) -> dict[str, float]:
        """Current weights, task -> float."""
        return {t: float(v) for t, v in zip(self.tasks, self.w.tolist())}

    def _weight_tensor(self, like: Tensor) -> Tensor:
        """The weights used in :meth:`total` (constants by default)."""
        return self.w.detach().to(device=like.device, dtype=like.dtype)

    def total(self, losses: Mapping[str, Tensor]) -> Tensor:
        """Eq. (8): ``sum_i w_i L_i`` over the tasks (weights are constants); keys that are not
        tasks (e.g. ``aux_*``) are added with weight 1. Every task must be in ``losses``."""
        missing = [t for t in self.tasks if t not in losses]
        if missing:
            raise KeyError(f"losses lack task(s) {missing}; got {sorted(losses)}")
        first = losses[self.tasks[0]]
        w = self._weight_tensor(first)
        total = sum(w[i] * losses[t] for i, t in enumerate(self.tasks))
        for k, v in losses.items():
            if k not in self.tasks:
                total = total + v
        return total

    # ------------------------------------------------------------------ hooks
    def backward(self, losses: Mapping[str, Tensor], model: nn.Module,
                 scale: Callable[[Tensor], Tensor] = lambda t: t) -> Tensor:
        """Backpropagate this step's losses into the network's ``.grad``; returns the total loss
        (detached, for logging). Default: ``scale(total(losses)).backward()`` (eq. 8).
        ``scale``: the trainer's loss scaling (a float16 ``GradScaler.scale``; identity otherwise).
        Gradient-surgery methods override it and write the combined gradient themselves."""
        total = self.total(losses)
        scale(total).backward()
        return total.detach()

    def before_backward(self, step: int, n_steps: int, losses: Mapping[str, Tensor], model: nn.Module) -> None:
        """Called every training step after the forward pass, before ``total(losses).backward()``."""

    def after_backward(self, taken: bool = True) -> None:
        """Called every training step after :meth:`backward` and the optimiser step. A method that
        computes new weights from this step's graph (:meth:`before_backward`: MGN, GradNorm) takes
        them here, so the step's own backward used the weights it started with, w(t), as Algorithm
        1 and the authors' ``train.py`` (and Chen et al.'s GradNorm) have it. ``taken``: whether the
        optimiser step went through; a float16 GradScaler skips a step whose gradients overflowed,
        and the weights computed from that step are then dropped with it."""

    @classmethod
    def needs_double_backward(cls, settings: Any) -> bool:
        """Whether this method, with these settings (its ``params_model``), differentiates through
        a gradient of the network (``create_graph=True``): torch.compile's AOTAutograd cannot, so
        such a recipe is refused with ``train.compile`` (:func:`~compact_perception.learning.weighting.weighting_settings`)."""
        return False

    def on_epoch_end(self, improved: bool) -> None:
        """Called once per epoch after validation; ``improved`` = the validation TM dropped."""

    # ------------------------------------------------------------------ state
    def state_dict(self) -> dict[str, Any]:
        return {"tasks": list(self.tasks), "w": self.w.tolist()}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        if list(state["tasks"]) != list(self.tasks):
            raise ValueError(f"state is for tasks {state['tasks']}, this weighting has {list(self.tasks)}")
        self.set_weights(torch.tensor(state["w"], dtype=torch.float64))

    def set_weights(self, w: Tensor) -> None:
        """Overwrite the loss weights (resume; agreement across data-parallel ranks), on the device."""
        self.w = w.detach().to(device=self.device, dtype=torch.float64).clone()

    def log_values(self) -> dict[str, float]:
        """Values to log each epoch: ``w_<task>`` (subclasses add ``lr_w``)."""
        return {f"w_{t}": v for t, v in self.weights.items()}


# Every weighting class registers itself under its params.yaml id (``ModelRecipe.weighting``) with
# ``@register("id")``; the package imports every module of this folder, so a new method is one
# new file (plus its params.yaml entry).
WEIGHTINGS: Registry[type[LossWeighting]] = Registry("loss weighting")


def register(key: str) -> Callable[[type[LossWeighting]], type[LossWeighting]]:
    """Class decorator: ``@register("uw")`` makes the class the weighting ``uw`` of params.yaml
    (and sets its ``key``, the name of its recipe section, and its ``label`` and ``adaptive``
    from ``core.catalog.WEIGHTING_METHODS``: an id missing there fails here)."""

    def deco(cls: type[LossWeighting]) -> type[LossWeighting]:
        info = WEIGHTING_METHODS[key]
        cls.key, cls.label, cls.adaptive = key, info.label, info.adaptive
        return WEIGHTINGS.register(key)(cls)

    return deco


def shared_weights(model: nn.Module, names: Sequence[str]) -> list[nn.Parameter]:
    """The weights W of the modules ``names`` (``model.get_submodule``): every parameter called
    ``weight`` inside them (conv kernels / linear matrices; biases excluded), or all of a module's
    parameters if it has none called ``weight`` (the subset W of the paper)."""
    params: list[nn.Parameter] = []
    seen: set[int] = set()
    for name in names:
        mod = model.get_submodule(name)
        named = list(mod.named_parameters())
        chosen = [p for n, p in named if n == "weight" or n.endswith(".weight")] or [p for _, p in named]
        if not chosen:
            raise ValueError(f"shared module {name!r} has no parameters")
        for p in chosen:
            if id(p) not in seen:
                seen.add(id(p))
                params.append(p)
    return params


def recipe_params(recipe: Any, name: str, schema: type[Strict]) -> Any:
    """The weighting section ``name`` of a recipe (``ModelRecipe.section``), validated by
    ``schema``; a clear error when the recipe has none."""
    raw = recipe.section(name)
    if not raw:
        raise ValueError(f"weighting {name!r} needs a {name!r} section in the recipe")
    return schema.model_validate(raw)
