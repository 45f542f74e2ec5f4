"""Plateau schedule and early stopping of paper section IV-D.

The learning rate is halved when the validation total metric (TM) has not dropped for
``patience`` epochs in a row (down to ``lr_min``); training stops after ``early_stop``
epochs without a drop. The same rule drives MGN's weight learning rate (section III-C).

Two plateau rules (``ModelRecipe.plateau_rule``):

- ``paper``: an epoch improves when the score is strictly below the best so far; the lr is
  halved once ``patience`` epochs in a row bring no improvement (section IV-D's "not dropped
  for 4 epochs").
- ``torch``: PyTorch's ``ReduceLROnPlateau(mode="min", threshold_mode="rel", cooldown=0)``, the
  authors' code: an epoch improves when ``score < best * (1 - threshold)``; the lr is reduced
  once MORE than ``patience`` epochs in a row bring none (patience 4 -> after the 5th), and
  a reduction smaller than 1e-8 (torch's ``eps``) is not applied.

In both, the count restarts after a reduction.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Literal

PlateauRule = Literal["paper", "torch"]
TORCH_EPS = 1e-8  # ReduceLROnPlateau's eps: smaller lr changes are ignored


def plateau_due(bad_epochs: int, patience: int, rule: PlateauRule) -> bool:
    """Whether ``bad_epochs`` epochs in a row without improvement call for a reduction."""
    if rule == "paper":
        return bad_epochs >= patience
    if rule == "torch":
        return bad_epochs > patience
    raise ValueError(f"unknown plateau rule {rule!r}; known: paper, torch")


def plateau_improved(score: float, best: float, rule: PlateauRule, threshold: float) -> bool:
    """Whether ``score`` improves on ``best`` under ``rule`` (lower is better)."""
    if rule == "torch":
        return score < best * (1.0 - threshold) if math.isfinite(best) else score < best
    return score < best


@dataclass
class Plateau:
    """Counts epochs without an improvement of the monitored score (lower is better)."""

    patience: int
    factor: float
    lr_min: float
    rule: PlateauRule
    threshold: float
    best: float = math.inf
    bad_epochs: int = 0

    def step(self, score: float, lr: float) -> tuple[bool, float]:
        """Record one epoch's score; returns (improved under the rule, new_lr).

        The lr is multiplied by ``factor`` once the rule's count of epochs without an
        improvement is reached (:func:`plateau_due`), then the count restarts; it never goes
        below ``lr_min``.
        """
        if plateau_improved(score, self.best, self.rule, self.threshold):
            self.best = score
            self.bad_epochs = 0
            return True, lr
        self.bad_epochs += 1
        if plateau_due(self.bad_epochs, self.patience, self.rule):
            self.bad_epochs = 0
            new = max(lr * self.factor, self.lr_min)
            if self.rule == "paper" or lr - new > TORCH_EPS:
                lr = new
        return False, lr

    def state_dict(self) -> dict:
        return asdict(self)

    def load_state_dict(self, state: dict) -> None:
        for k, v in state.items():
            setattr(self, k, v)


@dataclass
class EarlyStop:
    """Stop after ``patience`` epochs without a new best score."""

    patience: int
    best: float = math.inf
    since_best: int = 0

    def step(self, score: float) -> bool:
        """Record one epoch; True when training should stop."""
        if score < self.best:
            self.best = score
            self.since_best = 0
        else:
            self.since_best += 1
        return self.since_best >= self.patience

    def state_dict(self) -> dict:
        return asdict(self)

    def load_state_dict(self, state: dict) -> None:
        for k, v in state.items():
            setattr(self, k, v)
