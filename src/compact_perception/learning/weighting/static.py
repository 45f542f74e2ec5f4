"""Static weights (the 1L / 15L variants, w_i = 1) and 'none' (plain unweighted sum)."""
from __future__ import annotations

from .base import LossWeighting, register

__all__ = ["StaticWeighting", "NoWeighting"]


@register("static")
class StaticWeighting(LossWeighting):
    """Fixed weights (default all 1, eq. 8 with w_i = 1); nothing adapts."""

    params_model = None
    capturable = True


@register("none")
class NoWeighting(StaticWeighting):
    """No weighting: ``total`` is the plain sum of all losses (identical to static w = 1).

    Used by baselines whose own recipe combines its losses itself."""

    params_model = None
