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

from ...core.params import Strict
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
        self._updates = torch.zeros((), dtype=torch.int64)  # steps whose losses were finite
        self.last: dict[str, Any] = {}

    def to(self, device: torch.device | str) -> "UncertaintyWeighting":
        """s, its Adam (through its parameter) and w on ``device``."""
        super().to(device)
        with torch.no_grad():
            self.s.data = self.s.data.to(self.device)
        self._updates = self._updates.to(self.device)
        return self

    @property
    def n_updates(self) -> int:
        """Adam steps taken on s (steps whose task losses were all finite); a host read."""
        return int(self._updates)

    def backward(self, losses: Mapping[str, Tensor], model: nn.Module,
                 scale: Callable[[Tensor], Tensor] = lambda t: t) -> Tensor:
        """Network backward of ``L_UW`` (w constant), then one Adam step on s.

        Nothing is read on the host without loss scaling: the step's ``L_UW`` adds ``sum_i s_i``
        on the device (cast to the total's dtype, as adding the Python float did), and a step with
        a non-finite task loss takes Adam's step on a zero gradient and then puts s, w and Adam's
        moments back (so they stay unchanged; Adam's step count, on the host, still counts it: in
        fp32 and bf16 such a step ends the run at the epoch's last step anyway). Under a float16
        GradScaler, which skips such steps, the finiteness is read on the host and the step is left
        out entirely, as before."""
        total = self.total(losses)  # checks every task is present
        scale(total).backward()
        L = torch.stack([losses[t].detach().to(torch.float64) for t in self.tasks])
        s = self.s.detach().clone()
        objective = total.detach() + s.sum().to(total.dtype)
        grad_s = 1.0 - torch.exp(-s) * L
        self.last = {"L": L, "s": s, "grad_s": grad_s}
        if self._scaled:
            if bool(torch.isfinite(L).all()):
                self._adam_step(grad_s)
                self._updates = self._updates + 1
                self.w = torch.exp(-self.s.detach())
            return objective
        finite = torch.isfinite(L).all()
        st = self.opt.state.get(self.s)
        before = [t.clone() for t in (st["exp_avg"], st["exp_avg_sq"])] if st else None
        self._adam_step(torch.where(finite, grad_s, torch.zeros_like(grad_s)))
        with torch.no_grad():
            self.s.copy_(torch.where(finite, self.s, s))
            st = self.opt.state[self.s]
            for key, old in zip(("exp_avg", "exp_avg_sq"), before or [torch.zeros_like(s)] * 2):
                st[key].copy_(torch.where(finite, st[key], old))
        self._updates = self._updates + finite.to(torch.int64)
        self.w = torch.where(finite, torch.exp(-self.s.detach()), self.w)
        return objective

    def _adam_step(self, grad: Tensor) -> None:
        self.opt.zero_grad(set_to_none=True)
        self.s.grad = grad.clone()
        self.opt.step()
        self.s.grad = None

    def state_dict(self) -> dict[str, Any]:
        st = super().state_dict()
        st.update(lr=self.lr, s=self.s.detach().tolist(), optimizer=self.opt.state_dict(), n_updates=self.n_updates)
        return st

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        super().load_state_dict(state)  # w (through set_weights), then s exactly as saved
        with torch.no_grad():
            self.s.copy_(self._device_tensor(state["s"]))
        self.w = torch.exp(-self.s.detach())
        self.opt.load_state_dict(state["optimizer"])
        self._updates = self._device_tensor(int(state["n_updates"]), torch.int64)

    def set_weights(self, w: Tensor) -> None:
        """Overwrite w (data-parallel agreement, resume): ``s = -log w`` follows. Weights given on the
        host (a checkpoint's, a caller's) must be > 0; on a GPU they are not read back (the
        data-parallel mean of the ranks' positive weights is positive)."""
        if w.device.type == "cpu" and not bool((w > 0).all()):
            raise ValueError(f"uncertainty weights must be > 0, got {w.tolist()}")
        super().set_weights(w)
        with torch.no_grad():
            self.s.copy_(-torch.log(self.w))

