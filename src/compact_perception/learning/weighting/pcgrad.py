"""PCGrad: projecting conflicting gradients (Yu, Kumar, Gupta, Levine, Hausman, Finn, NeurIPS 2020,
"Gradient surgery for multi-task learning", Algorithm 1).

Per training step every task loss is differentiated on its own (T backward passes through the
retained graph). On the *shared* parameters each task gradient ``g_i`` is projected, in random
order of the other tasks ``j``, onto the normal plane of every ``g_j`` it conflicts with::

    g_i^PC <- g_i^PC - (g_i^PC . g_j) / ||g_j||^2  g_j      if g_i^PC . g_j < 0

(``g_j`` is always the *original* gradient, as in Algorithm 1), and the update is
``sum_i g_i^PC``. Task-specific parameters get the plain sum of their task gradients.

"Shared" here: a parameter that at least two task losses reach (``torch.autograd.grad`` returns
a tensor, not ``None``, for two or more tasks), so the definition follows the graph, not a list
of module names. In the compact network that is the three input encoders and bottleneck 1 (all
four tasks) and the DE / SS / LS decoders (their own task and BEVP, whose second encoders read
their outputs); the second encoders, bottleneck 2 and the BEVP decoder are BEVP's own. The
surgery is done on the concatenation of all shared parameters, as in the paper.

The per-task gradient machinery lives in :mod:`.gradients` (shared with :mod:`.cagrad`). Because each
``g_i^PC`` stays a linear combination of the original gradients, the projections are computed on
the Gram matrix and the result is written as ``sum_k c_k g_k``: the same vector, with every dot
product taken in float64.
"""
from __future__ import annotations

from typing import Any, Callable, Mapping, Sequence

import torch
from pydantic import Field
from torch import Tensor, nn

from ...core.params import Strict
from .base import LossWeighting, register
from .gradients import shared_gram, task_gradients, unweighted_total, write_combination

__all__ = ["PCGradParams", "PCGradWeighting"]


# ----------------------------------------------------------------------------- PCGrad
class PCGradParams(Strict):
    """``pcgrad: {seed: 0}``: seed of the weighting's own ``torch.Generator`` that draws the
    random projection orders (Algorithm 1's "random order")."""

    seed: int = Field(ge=0)


@register("pcgrad")
class PCGradWeighting(LossWeighting):
    """PCGrad (Yu et al. 2020, Algorithm 1) on the shared parameters; see the module docstring.

    Random order: for each task ``i`` in task order, one ``torch.randperm(T, generator=g)`` (the
    weighting's own generator, seeded with ``seed``; ``i`` itself is skipped) gives the order of
    the ``j``. The generator state is part of :meth:`state_dict`, so a resumed run draws the same
    orders. A projection onto a zero ``g_j`` never happens (its dot product is 0, not < 0).

    There is no weight vector: ``w`` stays 1 (``total`` is the plain sum) and ``log_values``
    reports ``w_<task> = 1`` plus ``conflicts``: the mean number of projections per step over the
    last epoch (0 .. T(T-1)). :meth:`backward` returns the unweighted sum of the losses.
    The coefficients of the last update (``g_shared = sum_k c_k g_k``) are in ``last["coeffs"]``.

    Float16 ``GradScaler``: every task loss is scaled before differentiation (the projection is
    invariant to a common scale); a non-finite Gram matrix (overflow) makes the update the plain
    sum, whose non-finite values make the scaler skip the step.
    """

    params_model = PCGradParams

    def __init__(self, tasks: Sequence[str], *, seed: int, plateau_patience: int, plateau_factor: float) -> None:
        super().__init__(tasks, plateau_patience=plateau_patience, plateau_factor=plateau_factor)
        if seed < 0:
            raise ValueError(f"PCGrad seed must be >= 0, got {seed}")
        self.seed = int(seed)
        self.generator = torch.Generator(device="cpu")
        self.generator.manual_seed(self.seed)
        self.epoch_steps = 0
        self.epoch_conflicts: Tensor | int = 0  # a device count during an epoch
        self.conflicts_per_step = 0.0  # mean over the last finished epoch
        self.last: dict[str, Any] = {}

    def to(self, device: torch.device | str) -> "PCGradWeighting":
        """The generator of the orders on ``device`` too (a fresh one, seeded with ``seed``, when the
        device changes: call it before the first step)."""
        super().to(device)
        if self.generator.device.type != self.device.type:
            self.generator = torch.Generator(device=self.device)
            self.generator.manual_seed(self.seed)
        return self

    def project(self, gram: Tensor) -> tuple[Tensor, Tensor]:
        """Algorithm 1 on the Gram matrix, on its device without a host read: returns ``c`` (float64,
        (T,)) with ``sum_i g_i^PC = sum_k c_k g_k`` and the number of projections made (an int64
        0-d tensor). Draws T permutations from the generator.

        The same float64 arithmetic, in the same order, as the loop over Python floats it replaces:
        each dot product ``sum_k A[i][k] Q[k][j]`` and each coefficient ``sum_i A[i][k]`` is a
        sequential sum from 0 (``cumsum``'s last element), a skipped projection (``j == i``, no
        conflict, a zero ``g_j``) a ``where`` that keeps the old value."""
        T, dev = self.T, gram.device
        A = torch.eye(T, dtype=torch.float64, device=dev)  # g_i^PC = sum_k A[i][k] g_k
        n = torch.zeros((), dtype=torch.int64, device=dev)
        diag = torch.diagonal(gram)
        for i in range(T):
            order = torch.randperm(T, generator=self.generator, device=dev)
            row = A[i]
            for pos in range(T):
                j = order[pos:pos + 1]
                dot = torch.cumsum(row * gram.index_select(1, j).reshape(T), 0)[-1]
                qjj = diag.index_select(0, j).reshape(())
                hit = (j.reshape(()) != i) & (dot < 0.0) & (qjj > 0.0)
                aij = row.index_select(0, j)
                row.index_copy_(0, j, torch.where(hit, aij - dot / qjj, aij))
                n = n + hit.to(torch.int64)
        return torch.cumsum(A, 0)[-1], n

    def backward(self, losses: Mapping[str, Tensor], model: nn.Module,
                 scale: Callable[[Tensor], Tensor] = lambda t: t) -> Tensor:
        """T per-task backward passes, surgery on the shared parameters, ``.grad`` written."""
        tg = task_gradients(losses, self.tasks, model, scale)
        gram = shared_gram(tg)
        coeffs, n = self.project(gram)  # always draws, so the stream does not depend on overflow
        finite = torch.isfinite(gram).all()
        coeffs = torch.where(finite, coeffs, torch.ones_like(coeffs))
        n = torch.where(finite, n, torch.zeros_like(n))
        write_combination(tg, coeffs)
        self.epoch_steps += 1
        self.epoch_conflicts = self.epoch_conflicts + n
        self.last = {"gram": gram, "coeffs": coeffs, "conflicts": n}
        return unweighted_total(losses, self.tasks)

    def on_epoch_end(self, improved: bool) -> None:
        """Closes the epoch's conflict count (nothing else adapts)."""
        if self.epoch_steps:
            self.conflicts_per_step = int(self.epoch_conflicts) / self.epoch_steps
        self.epoch_steps = self.epoch_conflicts = 0

    def state_dict(self) -> dict[str, Any]:
        s = super().state_dict()
        s.update(seed=self.seed, generator=self.generator.get_state().clone(), epoch_steps=self.epoch_steps,
                 epoch_conflicts=int(self.epoch_conflicts), conflicts_per_step=self.conflicts_per_step)
        return s

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        super().load_state_dict(state)
        if int(state["seed"]) != self.seed:
            raise ValueError(f"state is for PCGrad seed {state['seed']}, this weighting has seed {self.seed}")
        self.generator.set_state(state["generator"].detach().to("cpu", torch.uint8).clone())
        self.epoch_steps = int(state["epoch_steps"])
        self.epoch_conflicts = int(state["epoch_conflicts"])
        self.conflicts_per_step = float(state["conflicts_per_step"])

    def log_values(self) -> dict[str, float]:
        out = super().log_values()
        out["conflicts"] = float(self.conflicts_per_step)
        return out

