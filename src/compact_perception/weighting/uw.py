"""Uncertainty weighting (Kendall, Gal, Cipolla, CVPR 2018, "Multi-task learning using uncertainty to
weigh losses for scene geometry and semantics", eq. 7 and 10).

Learnable log-variances ``s_i = log sigma_i^2``, one per task, trained jointly with the network on

    L_UW = sum_i exp(-s_i) L_i + s_i.

The paper derives ``1/(2 sigma^2) L + log sigma`` for a regression (Gaussian) likelihood and
``1/sigma^2 L + log sigma`` for a classification (softmax) one. Here the uniform form above is
used for all four tasks (DE is a Huber loss, not a Gaussian likelihood, and SS/LS/BEVP are
BCE + Dice, not softmax cross-entropy, so neither derivation applies exactly): it is the form of
the common multi-task libraries, with ``s = log sigma^2``. The regression form is the same up to
a constant factor 1/2 on the whole objective (``exp(-s) L / 2 + s / 2``), which a learning rate
absorbs.
"""
from __future__ import annotations

from typing import Any, Callable, Mapping, Sequence

import torch
from pydantic import Field
from torch import Tensor, nn

from ..core.config import Strict
from .base import LossWeighting, register

__all__ = ["UWParams", "UncertaintyWeighting"]


class UWParams(Strict):
    """``uw: {lr: 0.025}``: learning rate of the log-variances' own Adam."""

    lr: float = Field(gt=0.0)


@register("uw")
class UncertaintyWeighting(LossWeighting):
    """Uncertainty weighting: ``w_i = exp(-s_i)``, ``s_i(0) = 0`` (so the first step is eq. 8 with
    w = 1).

    :meth:`backward` backpropagates ``sum_i w_i L_i`` (+ the non-task losses, weight 1) into the
    network with w constant -- the network gradient of ``L_UW`` -- then takes one step of the
    weighting's own Adam (PyTorch's defaults: betas 0.9 / 0.999, eps 1e-8; the trainer's optimizer
    holds only the network's parameters) on s with ``dL_UW/ds_i = 1 - exp(-s_i) L_i`` (float64,
    from the detached losses), and sets ``w = exp(-s)``. The network and s are thus updated from
    the same step's losses at the same s, as in joint training. The returned (detached) loss is
    ``L_UW`` at the s of the step (it includes ``sum_i s_i`` and can be negative). A step with a
    non-finite task loss leaves s unchanged. The lr of s is constant (no plateau halving).
    """

    params_model = UWParams

    def __init__(self, tasks: Sequence[str], *, lr: float, plateau_patience: int, plateau_factor: float) -> None:
        super().__init__(tasks, plateau_patience=plateau_patience, plateau_factor=plateau_factor)
        if not lr > 0.0:
            raise ValueError(f"uncertainty weighting lr must be > 0, got {lr}")
        self.lr = float(lr)
        self.s = torch.nn.Parameter(torch.zeros(self.T, dtype=torch.float64))
        self.opt = torch.optim.Adam([self.s], lr=self.lr)
        self.n_updates = 0
        self.last: dict[str, Any] = {}

    def backward(self, losses: Mapping[str, Tensor], model: nn.Module,
                 scale: Callable[[Tensor], Tensor] = lambda t: t) -> Tensor:
        """Network backward of ``L_UW`` (w constant), then one Adam step on s."""
        total = self.total(losses)  # checks every task is present
        scale(total).backward()
        L = torch.tensor([float(losses[t].detach()) for t in self.tasks], dtype=torch.float64)
        s = self.s.detach().clone()
        objective = total.detach() + float(s.sum())
        grad_s = 1.0 - torch.exp(-s) * L
        self.last = {"L": L, "s": s, "grad_s": grad_s}
        if bool(torch.isfinite(L).all()):
            self.opt.zero_grad(set_to_none=True)
            self.s.grad = grad_s.clone()
            self.opt.step()
            self.s.grad = None
            self.n_updates += 1
            self.w = torch.exp(-self.s.detach())
        return objective

    def state_dict(self) -> dict[str, Any]:
        st = super().state_dict()
        st.update(lr=self.lr, s=self.s.detach().tolist(), optimizer=self.opt.state_dict(), n_updates=self.n_updates)
        return st

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        super().load_state_dict(state)  # w (through set_weights), then s exactly as saved
        with torch.no_grad():
            self.s.copy_(torch.tensor(state["s"], dtype=torch.float64))
        self.w = torch.exp(-self.s.detach())
        self.opt.load_state_dict(state["optimizer"])
        self.n_updates = int(state["n_updates"])

    def set_weights(self, w: Tensor) -> None:
        """Overwrite w (data-parallel agreement, resume): ``s = -log w`` follows."""
        super().set_weights(w)
        if not bool((self.w > 0).all()):
            raise ValueError(f"uncertainty weights must be > 0, got {self.w.tolist()}")
        with torch.no_grad():
            self.s.copy_(-torch.log(self.w))

