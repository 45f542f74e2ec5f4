"""Power and decidability of a design: the minimal detectable effect (:func:`mde`) and the rule
"no verdict from a single run" (:func:`decidable`, :data:`MIN_SEEDS`).

Power (:func:`mde`): the minimal detectable effect at 80% power, two-sided alpha 0.05, is
``(t_{1-alpha/2, df} + t_{power, df}) * SE`` (the usual normal-approximation formula with t
quantiles at the interval's df; it ignores the chance of crossing the opposite bound).

No verdict from a single run (:func:`decidable`): with fewer than :data:`MIN_SEEDS` seeds in a
non-fixed group a comparison gets no verdict; a fixed (deterministic) group is exempt.
"""
from __future__ import annotations

import math
from typing import Optional, Sequence

from .distributions import t_ppf

__all__ = ["ALPHA", "POWER", "MIN_SEEDS", "mde", "decidable"]

#: Two-sided level and power of the minimal detectable effect (:func:`mde`).
ALPHA, POWER = 0.05, 0.8
#: Fewest seeds of a trained model for a verdict (issue 24: no verdict from a single run).
MIN_SEEDS = 3


def mde(se: float, df: float, *, alpha: float = ALPHA, power: float = POWER) -> float:
    """The minimal detectable effect of a design: ``(t_{1-alpha/2, df} + t_{power, df}) * se``
    (a true difference this large is found with probability ``power`` by a two-sided level
    ``alpha`` t test; normal quantiles for df = inf); NaN if ``se`` or ``df`` is NaN."""
    if not (math.isfinite(se) and (math.isfinite(df) or df == math.inf)):
        return math.nan
    return (t_ppf(1.0 - alpha / 2.0, df) + t_ppf(power, df)) * se


def decidable(n_seeds: Sequence[int], fixed: Optional[Sequence[bool]] = None) -> bool:
    """Whether a comparison may get a verdict: every trained (non-fixed) group has at least
    :data:`MIN_SEEDS` seeds; a fixed (deterministic) group is exempt."""
    flags = list(fixed) if fixed is not None else [False] * len(n_seeds)
    return bool(n_seeds) and all(f or n >= MIN_SEEDS for n, f in zip(n_seeds, flags))
