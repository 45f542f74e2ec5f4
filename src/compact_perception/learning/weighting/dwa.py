"""Dynamic Weight Average (Liu, Johns, Davison, CVPR 2019, "End-to-end multi-task learning with
attention", section 3.3, eq. 7).

The weight of task k in epoch t (0-based here) is

    w_k(t) = T exp(r_k(t-1) / temp) / sum_i exp(r_i(t-1) / temp),   r_k(t-1) = L_k(t-1) / L_k(t-2),

with ``L_k(t)`` the mean training loss of task k over the steps of epoch t, and ``w_k = 1`` in
the first two epochs (t = 0, 1), where the ratio is not defined yet. ``temp`` is the paper's
temperature T (2 in the paper); the weights sum to T (the number of tasks), as eq. (15) does.
"""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import torch
from pydantic import Field
from torch import Tensor, nn

from ...core.params import Strict
from .base import LossWeighting, register

__all__ = ["DWAParams", "DWAWeighting"]


class DWAParams(Strict):
    """``dwa: {temperature: 2.0}``: the softmax temperature of eq. (7) (the paper's 2)."""

    temperature: float = Field(gt=0.0)


@register("dwa")
class DWAWeighting(LossWeighting):
    """DWA: :meth:`before_backward` adds each task loss of the step (detached, float64) to the
    epoch's sums; :meth:`on_epoch_end` closes the epoch's means ``L_k(t)``, keeps the last two,
    and from the third epoch on sets w by eq. (7) (a softmax with the largest ratio subtracted,
    the same value). ``total`` (eq. 8 with these w as constants) is the default backward.

    A non-finite step loss (a float16 overflow the loss scaler skips) is left out of that task's
    mean; an epoch in which some task has no finite step loss is not recorded (w unchanged, and
    it does not count towards the first two epochs). ``r_k`` divides by ``max(L_k(t-2), 1e-12)``.

    The sums and counts are device tensors, added to without a host read (the sum of a finite
    loss is the Python float sum it was: float64 adds from 0.0, in step order); the epoch's end
    reads them once. Data-parallel (:attr:`ranks`): the epoch's end sums them over the ranks
    before it closes the means, so ``L_k(t)`` is the mean over every rank's steps and every rank
    starts the next epoch with the same w.
    """

    capturable = True  # a step adds to its sums in place; w changes at the epoch's end

    params_model = DWAParams

    def __init__(self, tasks: Sequence[str], *, temperature: float, plateau_patience: int,
                 plateau_factor: float) -> None:
        super().__init__(tasks, plateau_patience=plateau_patience, plateau_factor=plateau_factor)
        if not temperature > 0.0:
            raise ValueError(f"DWA temperature must be > 0, got {temperature}")
        self.temperature = float(temperature)
        self._reset()
        self.history: list[list[float]] = []  # epoch means L(t-2), L(t-1), oldest first
        self.n_epochs = 0  # recorded epochs

    def _reset(self, sums: Sequence[float] | None = None, counts: Sequence[int] | None = None) -> None:
        self.sums = self._device_tensor([0.0] * self.T if sums is None else list(sums))
        self.counts = self._device_tensor([0] * self.T if counts is None else list(counts), torch.int64)

    def to(self, device: torch.device | str) -> "DWAWeighting":
        super().to(device)
        self.sums, self.counts = self.sums.to(self.device), self.counts.to(self.device)
        return self

    def before_backward(self, step: int, n_steps: int, losses: Mapping[str, Tensor], model: nn.Module) -> None:
        """Accumulate this step's finite task losses into the epoch's sums (on the device)."""
        missing = [t for t in self.tasks if t not in losses]
        if missing:
            raise KeyError(f"losses lack task(s) {missing}; got {sorted(losses)}")
        v = torch.stack([losses[t].detach().to(device=self.device, dtype=torch.float64) for t in self.tasks])
        finite = torch.isfinite(v)
        self.sums.copy_(torch.where(finite, self.sums + v, self.sums))  # in place: a captured step's tensors
        self.counts.add_(finite.to(torch.int64))

    def weights_from(self, older: Sequence[float], newer: Sequence[float]) -> Tensor:
        """Eq. (7) from the epoch means ``L(t-2)`` (``older``) and ``L(t-1)`` (``newer``)."""
        r = [n / max(o, 1e-12) for o, n in zip(older, newer)]
        top = max(r)
        e = [math.exp((x - top) / self.temperature) for x in r]
        z = sum(e)
        return torch.tensor([self.T * x / z for x in e], dtype=torch.float64)

    def _epoch_sums(self) -> tuple[list[float], list[int]]:
        """The epoch's sums and counts as the host reads them (one read): in a data-parallel run
        summed over the ranks first (one all-reduce; a count is exact in float64), so every rank
        closes the same means of the global batch's losses and sets the same w before the next
        epoch's first step."""
        if self.ranks is None:
            return self.sums.tolist(), self.counts.tolist()
        both = self.ranks.sum_over_ranks(torch.cat([self.sums, self.counts.to(torch.float64)])).tolist()
        return both[: self.T], [int(n) for n in both[self.T:]]

    def on_epoch_end(self, improved: bool) -> None:
        """Close the epoch's means (one read of the sums; over every rank's steps in a
        data-parallel run); from the third recorded epoch on, w for the next epoch."""
        sums, counts = self._epoch_sums()
        if all(n > 0 for n in counts):
            means = [s / n for s, n in zip(sums, counts)]
            self.history = (self.history + [means])[-2:]
            self.n_epochs += 1
            if len(self.history) == 2:
                self.w = self.weights_from(self.history[0], self.history[1]).to(self.device)
        self._reset()

    def state_dict(self) -> dict[str, Any]:
        st = super().state_dict()
        st.update(temperature=self.temperature, sums=self.sums.tolist(), counts=self.counts.tolist(),
                  history=[list(h) for h in self.history], n_epochs=self.n_epochs)
        return st

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        super().load_state_dict(state)
        self._reset([float(x) for x in state["sums"]], [int(x) for x in state["counts"]])
        self.history = [[float(x) for x in h] for h in state["history"]]
        self.n_epochs = int(state["n_epochs"])
