"""The distribution functions of the intervals, from scipy: Student's t (:func:`t_cdf`,
:func:`t_ppf`; ``df`` need not be an integer: Satterthwaite), the standard normal quantile
(:func:`normal_ppf`), and Satterthwaite's degrees of freedom of a sum of variance estimates.

The t and normal functions call the ufuncs that ``scipy.stats.t.cdf``, ``scipy.stats.t.ppf`` and
``scipy.stats.norm.ppf`` evaluate (``scipy.special.stdtr``, ``stdtrit``, ``ndtri``: the same
numbers, bit for bit) without the ~0.25 ms of argument handling per ``scipy.stats`` call: the
effective df of an interval bisects on :func:`t_cdf` 60 times, and the coverage check computes
hundreds of intervals."""
from __future__ import annotations

import functools
import math
from typing import Optional, Sequence

from scipy import special as _sp

__all__ = ["t_cdf", "t_ppf", "normal_ppf", "satterthwaite_df"]

#: Above this df :func:`t_ppf` is the normal quantile.
_NORMAL_DF = 1e7


def _check_p(p: float, who: str) -> None:
    if not 0.0 < p < 1.0:
        raise ValueError(f"{who}: p must lie in (0, 1), got {p}")


def t_cdf(t: float, df: float) -> float:
    """Student's t distribution function at ``t`` (``scipy.stats.t.cdf``: ``scipy.special.stdtr``);
    ``df`` > 0, not necessarily an integer."""
    if not df > 0:
        raise ValueError(f"t_cdf: df must be > 0, got {df}")
    return float(_sp.stdtr(df, t))


def normal_ppf(p: float) -> float:
    """The standard normal quantile (``normal_ppf(0.975)`` = 1.95996...; ``scipy.stats.norm.ppf``:
    ``scipy.special.ndtri``)."""
    _check_p(p, "normal_ppf")
    return float(_sp.ndtri(p))


@functools.lru_cache(maxsize=4096)
def t_ppf(p: float, df: float) -> float:
    """Student's t quantile ``t_{p, df}`` (e.g. t_{0.975, 2} = 4.303, t_{0.8, 2} = 1.061;
    ``scipy.stats.t.ppf``: ``scipy.special.stdtrit``); the normal quantile for ``df`` = inf or above
    1e7. Cached: the intervals ask for the same few quantiles many times."""
    _check_p(p, "t_ppf")
    if not df > 0:
        raise ValueError(f"t_ppf: df must be > 0, got {df}")
    if df > _NORMAL_DF:
        return normal_ppf(p)
    return float(_sp.stdtrit(df, p))


def satterthwaite_df(parts: Sequence[tuple[float, float]], total: Optional[float] = None) -> float:
    """Satterthwaite's degrees of freedom of a sum of independent variance estimates
    ``(v_i, df_i)``: ``total^2 / sum(v_i^2 / df_i)`` (``total`` = ``sum(v_i)`` unless given, as
    when a term is subtracted), at least 1; inf when every ``v_i`` is 0."""
    den = sum(v * v / d for v, d in parts if v != 0)
    tot = sum(v for v, _ in parts) if total is None else total
    return math.inf if den == 0 else max(1.0, tot * tot / den)
