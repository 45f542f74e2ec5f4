"""Plateau schedule and early stopping of paper section IV-D.

The learning rate is halved when the validation total metric (TM) has not dropped for
``patience`` epochs in a row (down to ``lr_min``); training stops after ``early_stop``
epochs without a drop. The same rule drives MGN's weight learning rate (section III-C).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass


@dataclass
class Plateau:
    """Counts epochs without a drop of the monitored score (lower is better)."""

    patience: int
    factor: float
    lr_min: float
    best: float = math.inf
    bad_epochs: int = 0

    def step(self, score: float, lr: float) -> tuple[bool, float]:
        """Record one epoch's score; returns (improved, new_lr).

        The lr is multiplied by ``factor`` once ``patience`` epochs in a row bring no
        drop, then the count restarts; it never goes below ``lr_min``.
        """
        if score < self.best:
            self.best = score
            self.bad_epochs = 0
            return True, lr
        self.bad_epochs += 1
        if self.bad_epochs >= self.patience:
            self.bad_epochs = 0
            lr = max(lr * self.factor, self.lr_min)
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
