"""Single-task training of the multi-task network: the reference of the loss-balancing study's Δm.

"Single-task networks" in the multi-task learning literature (e.g. LibMTL's Δm baseline) are the
same architecture trained on one task alone. Here that is the compact network with the loss
weights one-hot: ``w_task = 1`` and every other ``w_i = 0`` in eq. (8), so only the chosen
task's loss trains the network (the other heads stay in the graph and receive no gradient).
The weights never change.
"""
from __future__ import annotations

from typing import Sequence

from ..core.config import Strict
from .base import LossWeighting, register

__all__ = ["SingleTaskParams", "SingleTaskWeighting"]


class SingleTaskParams(Strict):
    """``single: {task: de}``: the one task whose loss trains the network."""

    task: str


@register("single")
class SingleTaskWeighting(LossWeighting):
    """One-hot weights: eq. (8) reduces to the loss of ``task``."""

    label = "Single-task network"
    params_model = SingleTaskParams

    def __init__(self, tasks: Sequence[str], *, task: str, plateau_patience: int, plateau_factor: float) -> None:
        if task not in tasks:
            raise KeyError(f"single-task weighting: task {task!r} is not one of the model's tasks {list(tasks)}")
        super().__init__(tasks, {t: float(t == task) for t in tasks}, plateau_patience=plateau_patience,
                         plateau_factor=plateau_factor)
        self.task = task

