"""Original GradNorm (Chen, Badrinarayanan, Lee, Rabinovich, ICML 2018), per-step updates."""
from __future__ import annotations

from typing import Any, Literal, Mapping, Sequence

import torch
from pydantic import Field
from torch import Tensor

from ...core.params import Strict
from .base import register
from .mgn import GradNormCore, finite_or_raise

__all__ = ["GradNormParams", "GradNormWeighting"]


class GradNormParams(Strict):
    """``gradnorm: {alpha, lr}``: the original per-step GradNorm (Chen et al., ICML 2018)."""

    alpha: float = Field(ge=0.0)
    lr: float = Field(gt=0.0)


@register("gradnorm")
class GradNormWeighting(GradNormCore):
    """GradNorm: L_i(0) from the very first training step (kept across epochs, saved in the
    state); w updated at EVERY step (including the first, where r_i = 1) with its own optimizer
    (``"adam"`` default, or ``"sgd"``) at ``lr = GradNormParams.lr``; then the positive floor and
    renormalisation to sum T (as in :class:`GradNormCore`). W = ``model.shared_layers()[task]``
    (the last shared layer for the GradNorm-SegNet baseline). The weight lr is constant
    (``on_epoch_end`` only counts bad epochs), as in the original algorithm."""

    params_model = GradNormParams

    def __init__(self, tasks: Sequence[str], shared: Mapping[str, Sequence[str]] | None = None, *,
                 alpha: float, lr: float, optimizer: Literal["adam", "sgd"] = "adam", **kw: Any) -> None:
        super().__init__(tasks, shared, alpha=alpha, lr=lr, lr_min=lr, **kw)
        self.optimizer_name = optimizer
        self._param = torch.nn.Parameter(self.w.clone())
        if optimizer == "adam":
            self.opt: torch.optim.Optimizer = torch.optim.Adam([self._param], lr=self.lr)
        elif optimizer == "sgd":
            self.opt = torch.optim.SGD([self._param], lr=self.lr)
        else:
            raise ValueError(f"unknown GradNorm optimizer {optimizer!r}; known: adam, sgd")

    def to(self, device: torch.device | str) -> "GradNormWeighting":
        """The weights, L_i(0) and the weights' own optimiser (its parameter) on ``device``: the
        per-step update runs there (PyTorch keeps a non-fused Adam's step counter on the host)."""
        super().to(device)
        with torch.no_grad():
            self._param.data = self._param.data.to(self.device)
        if self.L0 is not None:
            self.L0 = self.L0.to(self.device)
        return self

    def on_epoch_end(self, improved: bool) -> None:
        """Constant weight lr (original GradNorm); only the bad-epoch count is kept."""
        self.bad_epochs = 0 if improved else self.bad_epochs + 1

    def before_backward(self, step: int, n_steps: int, losses: Mapping[str, Tensor], model: nn.Module) -> None:
        """One GradNorm update per training step: this step's gradient of L_grad on w, applied by
        :meth:`after_backward` once the step's backward has used w(t) (Chen et al. 2018)."""
        if self.L0 is None:
            self.L0 = self._initial_losses(losses)
        self._pending = self._grad_w(losses, model)

    def after_backward(self, taken: bool = True) -> None:
        """The weights' own optimiser step on this step's gradient, the floor and renormalisation:
        w(t+1). A step the GradScaler skipped (``taken`` false) moves neither w nor that optimiser.
        Under the GradScaler a non-finite gradient or weight is :class:`NonFinite` here (a host
        read); without it nothing is read: non-finite weights are found at the epoch's end
        (training/epoch.py reads the weights with the epoch's sums)."""
        g, self._pending = self._pending, None
        if g is None or not taken:
            return
        self.opt.zero_grad(set_to_none=True)
        self._param.grad = (finite_or_raise(g, "GradNorm weight gradient") if self._scaled else g).clone()
        self.opt.step()
        with torch.no_grad():
            self._param.copy_(self._renormalise(self._param.detach()))
        w = self._param.detach()
        self.set_weights(finite_or_raise(w, "GradNorm loss weights") if self._scaled else w)
        self.n_updates += 1

    def state_dict(self) -> dict[str, Any]:
        s = super().state_dict()
        s["optimizer"] = self.opt.state_dict()
        return s

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        super().load_state_dict(state)
        self.opt.load_state_dict(state["optimizer"])

    def set_weights(self, w: Tensor) -> None:
        super().set_weights(w)
        with torch.no_grad():
            self._param.copy_(self.w)
