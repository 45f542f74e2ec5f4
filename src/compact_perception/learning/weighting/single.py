"""Single-task networks: the reference of the loss-balancing study's Δm.

"Single-task networks" in the multi-task learning literature (e.g. LibMTL's Δm baseline) are the
same architecture trained on one task alone. Here that is the compact network built for that
task (:meth:`SingleTaskWeighting.network_tasks`): the encoders, bottleneck 1 and the task's own
decoder for DE, SS or LS; for BEVP the whole network, whose second stage reads the DE, SS and
LS outputs (their decoders are then hidden layers with no loss of their own). Eq. (8) reduces
to the task's loss, ``w_task = 1``; the weight never changes.
"""
from __future__ import annotations

from typing import Any, Sequence

from ...core.params import Strict
from .base import LossWeighting, recipe_params, register

__all__ = ["SingleTaskParams", "SingleTaskWeighting"]


class SingleTaskParams(Strict):
    """``single: {task: de}``: the one task whose loss trains the network."""

    task: str


@register("single")
class SingleTaskWeighting(LossWeighting):
    """One-hot weights: eq. (8) reduces to the loss of ``task``."""

    params_model = SingleTaskParams
    capturable = True

    @classmethod
    def network_tasks(cls, recipe: Any, tasks: Sequence[str]) -> tuple[str, ...]:
        """Only the recipe's ``single.task``: the network is built for that task alone."""
        task = recipe_params(recipe, cls.key, cls.params_model).task
        if task not in tasks:
            raise KeyError(f"single-task weighting: task {task!r} is not one of the model's tasks {list(tasks)}")
        return (task,)

    def __init__(self, tasks: Sequence[str], *, task: str, plateau_patience: int, plateau_factor: float) -> None:
        if task not in tasks:
            raise KeyError(f"single-task weighting: task {task!r} is not one of the model's tasks {list(tasks)}")
        super().__init__(tasks, {t: float(t == task) for t in tasks}, plateau_patience=plateau_patience,
                         plateau_factor=plateau_factor)
        self.task = task

