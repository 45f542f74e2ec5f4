"""What an interval lets one decide: the verdict rule (:func:`verdict`, :func:`comparison_verdict`,
:func:`undecidable_reasons`) and the seeds a design needs to decide (:func:`seeds_to_decide`).

Verdict rule (:func:`verdict`, CLAIMS.md): ``reproduced`` when the whole 95% interval lies on
the claimed side of 0 (strictly above 0), ``contradicted`` when it lies wholly on the other
side (strictly below 0), ``inconclusive`` otherwise (an interval touching 0 included). For a
claim of equality, with an equivalence margin m: ``reproduced`` when the interval lies within
[-m, m] (the ends included), ``contradicted`` when it lies wholly outside it (above m or below
-m), ``inconclusive`` otherwise. :func:`comparison_verdict` adds ``not decidable`` (fewer than
:data:`~.power.MIN_SEEDS` seeds in a trained group, :func:`~.power.decidable`).

Seeds to decide (:func:`seeds_to_decide`): the fewest seeds per model at which the design's
:func:`~.power.mde` falls to a given effect (the paper's), from the measured variance components
scaled to that many seeds (the seed part shrinks as 1/S with S - 1 df; the test episodes' part
net of the interaction stays).
"""
from __future__ import annotations

import math
from typing import Optional, Sequence

from .intervals import IntervalResult
from .power import MIN_SEEDS, POWER, mde
from .variance import _combined, _Parts

__all__ = ["REPRODUCED", "CONTRADICTED", "INCONCLUSIVE", "NOT_DECIDABLE", "VERDICTS", "verdict",
           "comparison_verdict", "undecidable_reasons", "MAX_SEEDS_TO_DECIDE", "seeds_to_decide"]

REPRODUCED, CONTRADICTED, INCONCLUSIVE = "reproduced", "contradicted", "inconclusive"
NOT_DECIDABLE = "not decidable"
VERDICTS: tuple[str, ...] = (REPRODUCED, CONTRADICTED, INCONCLUSIVE, NOT_DECIDABLE)


def verdict(ci_low: float, ci_high: float, margin: Optional[float] = None) -> str:
    """CLAIMS.md's rule on a difference oriented so that positive = the claim holds.

    Without ``margin`` (an ordering claim): ``reproduced`` if ``ci_low > 0``, ``contradicted``
    if ``ci_high < 0``, else ``inconclusive`` (an interval touching 0 is inconclusive). With
    ``margin`` (an equality claim): ``reproduced`` if ``-margin <= ci_low`` and
    ``ci_high <= margin``, ``contradicted`` if ``ci_low > margin`` or ``ci_high < -margin``,
    else ``inconclusive``. A NaN bound is ``inconclusive``.
    """
    if not (math.isfinite(ci_low) and math.isfinite(ci_high)):
        return INCONCLUSIVE
    if ci_low > ci_high:
        raise ValueError(f"verdict: ci_low {ci_low} > ci_high {ci_high}")
    if margin is None:
        if ci_low > 0:
            return REPRODUCED
        if ci_high < 0:
            return CONTRADICTED
        return INCONCLUSIVE
    if margin < 0:
        raise ValueError(f"verdict: margin must be >= 0, got {margin}")
    if -margin <= ci_low and ci_high <= margin:
        return REPRODUCED
    if ci_low > margin or ci_high < -margin:
        return CONTRADICTED
    return INCONCLUSIVE


def comparison_verdict(res: IntervalResult, margin: Optional[float] = None) -> str:
    """:data:`NOT_DECIDABLE` below :data:`MIN_SEEDS` seeds, else :func:`verdict` of the interval."""
    return verdict(res.ci_low, res.ci_high, margin) if res.decidable else NOT_DECIDABLE


def undecidable_reasons(res: IntervalResult, labels: Sequence[str]) -> list[str]:
    """Why a comparison is not decidable: ``1 seed: <label>`` for every trained (non-fixed) group
    with fewer than :data:`~.power.MIN_SEEDS` seeds (``labels``: one per group, in order); empty
    if every group has enough (a fixed group is exempt, :func:`~.power.decidable`)."""
    return [f"{n} seed{'' if n == 1 else 's'}: {label}"
            for label, n, fixed in zip(labels, res.n_seeds, res.fixed) if not fixed and n < MIN_SEEDS]


#: The most seeds per model :func:`seeds_to_decide` looks at (beyond: more test episodes are needed).
MAX_SEEDS_TO_DECIDE = 100


def seeds_to_decide(res: IntervalResult, effect: Optional[float], *, max_seeds: int = MAX_SEEDS_TO_DECIDE,
                    power: float = POWER) -> Optional[int]:
    """The fewest training seeds per trained model (at least :data:`MIN_SEEDS`) at which the design
    of ``res`` detects a true difference of ``|effect|`` with probability ``power``: its
    :func:`mde` at S seeds is at most ``|effect|``. The measured variance components are scaled to
    S seeds: each seed block's ``V_seed`` (the variance of its seed means / s) by s / S on S - 1 df,
    the interaction ``V_inter`` (~ 1/S) likewise, so the cluster part net of it,
    ``max(0, V_cluster - V_inter)``, stays (the test episodes do not change with the seeds), and
    the interval's combination (:func:`_combined`) gives the SE and df at S. ``None`` where it
    cannot be said (no effect, an interval from a non-t method, a trained model with one seed: no
    seed variance) or where ``max_seeds`` do not reach it (the test episodes alone then limit the
    design: more test frames, not seeds, are needed)."""
    parts = res.parts
    if effect is None or not math.isfinite(effect) or effect == 0.0 or parts is None:
        return None
    if not parts.seed or not all(math.isfinite(v) for v, _ in parts.seed) or not math.isfinite(parts.cluster[0]):
        return None
    net = parts.cluster[0] - sum(v for v, _ in parts.inter)
    for s in range(MIN_SEEDS, max_seeds + 1):
        seed = tuple((v * (d + 1.0) / s, float(s - 1)) for v, d in parts.seed)
        se, df = _combined(_Parts(seed, (net, parts.cluster[1]), ()), res.confidence)
        if mde(se, df, power=power) <= abs(effect):
            return s
    return None
