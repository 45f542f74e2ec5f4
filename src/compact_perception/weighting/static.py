"""Static weights (the 1L / 15L variants, w_i = 1) and 'none' (plain unweighted sum)."""
from __future__ import annotations

from typing import Sequence

from torch import nn

from ..config import ModelRecipe
from .base import LossWeighting

__all__ = ["StaticWeighting", "NoWeighting"]


class StaticWeighting(LossWeighting):
    """Fixed weights (default all 1, eq. 8 with w_i = 1); nothing adapts."""

    @classmethod
    def from_recipe(cls, recipe: ModelRecipe, tasks: Sequence[str], model: nn.Module | None = None, **kw) -> "StaticWeighting":
        return cls(tasks, plateau_patience=kw.get("plateau_patience", 4), plateau_factor=kw.get("plateau_factor", 0.5))


class NoWeighting(StaticWeighting):
    """No weighting: ``total`` is the plain sum of all losses (identical to static w = 1).

    Used by baselines whose own recipe combines its losses itself."""
