"""The interval of a contrast (:func:`interval`, :data:`METHOD` = ``seed-cluster-t``) and of a
mean over seeds (:func:`seed_interval`), as an :class:`IntervalResult`.

A comparison's estimate is the contrast of the models' values, each the mean over its training
seeds of the statistic of a run's column means. Seeds and clusters are two crossed random factors
(another training seed and another draw of test episodes would both change the estimate); the
variance parts come from :mod:`.variance`. The methods (:data:`METHODS`):

* ``seed-cluster-t`` gives the seed part and the cluster part each its own t quantile (Banerjee's
  combination): half-width ``sqrt(t_{p,df_seed}^2 V_seed + t_{p,K-1}^2 max(0, V_cluster - V_inter))``,
  p = 1 - alpha/2; ``se`` = ``sqrt(V_seed + max(0, V_cluster - V_inter))`` and ``df`` is the
  effective df at which ``t_{p,df} se`` is that half-width (so :func:`~.power.mde` applies unchanged);
* ``crossed-t`` pools the parts: ``V = V_seed + V_cluster - V_inter`` (the ANOVA estimator of
  ``var(A)/S + var(B)/K + var(E)/(SK)``, floored at ``max(V_seed, V_cluster)``), one
  Satterthwaite df; ``crossed-t-conservative`` keeps ``V_seed + V_cluster``;
* ``seed-t`` ignores the clusters (the seed-paired t: the test frames taken as fixed);
* ``pigeonhole-bootstrap`` is Owen's crossed bootstrap (seeds and clusters resampled
  independently, percentile interval).

The package docstring (:mod:`compact_perception.stats`) gives their measured coverage and why the
report uses ``seed-cluster-t``. Quantiles come from :func:`~.distributions.t_ppf` (scipy).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np

from .comparison import Comparison, Contrast, Statistic
from .power import decidable, mde
from .distributions import t_ppf
from .variance import _cluster_means, _combined, _crossed, _linearise, _Parts, _seed_only, _variance_parts

__all__ = ["BOOTSTRAP_SEED", "N_BOOT", "CONFIDENCE", "METHOD", "METHODS", "IntervalResult", "interval",
           "seed_interval"]

#: Fixed RNG seed of the pigeonhole bootstrap (deterministic reports).
BOOTSTRAP_SEED = 20220
#: Bootstrap replicates.
N_BOOT = 2000
#: Two-sided coverage of every interval.
CONFIDENCE = 0.95
#: The interval method of the report (chosen by coverage, see the package docstring).
METHOD = "seed-cluster-t"


@dataclass(frozen=True)
class IntervalResult:
    """A contrast, its interval and the design it came from. ``df``: the t interval's degrees
    of freedom (inf for a bootstrap, whose ``se`` is the replicates' standard deviation);
    ``n_seeds``/``fixed``: per group; ``paired``: the trained groups share their seeds."""

    estimate: float
    ci_low: float
    ci_high: float
    se: float
    df: float
    method: str
    n_seeds: tuple[int, ...]
    fixed: tuple[bool, ...]
    n_clusters: int
    n_frames: int
    paired: bool
    confidence: float = CONFIDENCE
    parts: Optional[_Parts] = field(default=None, compare=False, repr=False)   # the t methods' variance components

    @property
    def decidable(self) -> bool:
        """Whether the comparison may get a verdict (:func:`decidable`)."""
        return decidable(self.n_seeds, self.fixed)

    @property
    def mde(self) -> float:
        """The minimal detectable effect at 80% power of this design (:func:`mde`)."""
        return mde(self.se, self.df)


def _t_result(comp: Comparison, est: float, se: float, df: float, method: str, confidence: float,
              parts: Optional[_Parts] = None) -> IntervalResult:
    if math.isfinite(se) and not math.isnan(df):
        half = t_ppf(0.5 + confidence / 2.0, df) * se
        lo, hi = est - half, est + half
    else:
        lo = hi = math.nan
    return IntervalResult(est, lo, hi, se, df, method, comp.n_seeds, tuple(g.fixed for g in comp.groups),
                          comp.n_clusters, comp.n_frames, comp.paired, confidence, parts)


def _pigeonhole(comp: Comparison, statistic: Statistic, contrast: Contrast, n_boot: int, seed: int,
                confidence: float) -> IntervalResult:
    """Owen's crossed bootstrap: clusters resampled once per replicate for every run, seeds
    resampled per block of paired groups (the same picks for every group of a block)."""
    rng = np.random.default_rng(seed)
    k = comp.n_clusters
    counts = rng.multinomial(k, np.full(k, 1.0 / k), size=n_boot).astype(np.float64)   # (B, K)
    frames = counts @ comp.cluster_sizes                                                 # (B,)
    picks: dict[tuple[int, ...], np.ndarray] = {}
    values = np.zeros((n_boot, len(comp.groups)))
    for gi, g in enumerate(comp.groups):
        _, mc = _cluster_means(comp, g)
        sums = mc * comp.cluster_sizes[None, :, None]                                    # (S, K, C)
        stat = np.asarray(statistic(np.einsum("bk,skc->bsc", counts, sums) / frames[:, None, None]))  # (B, S)
        if g.fixed:
            values[:, gi] = stat[:, 0]
            continue
        if g.seeds not in picks:
            picks[g.seeds] = rng.integers(0, len(g.seeds), size=(n_boot, len(g.seeds)))
        values[:, gi] = np.take_along_axis(stat, picks[g.seeds], axis=1).mean(axis=1)
    rep = np.asarray(contrast(values), dtype=np.float64)
    full = np.array([np.mean([float(statistic(r.mean(axis=0))) for r in g.runs.values()]) for g in comp.groups])
    est = float(np.asarray(contrast(full[None, :]))[0])
    tail = 100.0 * (1.0 - confidence) / 2.0
    lo, hi = np.percentile(rep, [tail, 100.0 - tail])
    return IntervalResult(est, float(lo), float(hi), float(rep.std(ddof=1)), math.inf, "pigeonhole-bootstrap",
                          comp.n_seeds, tuple(g.fixed for g in comp.groups), comp.n_clusters, comp.n_frames,
                          comp.paired, confidence)


#: The interval methods :func:`interval` knows (the package docstring compares their coverage).
METHODS: tuple[str, ...] = ("seed-cluster-t", "crossed-t", "crossed-t-conservative", "seed-t", "pigeonhole-bootstrap")


def interval(comp: Comparison, statistic: Statistic, contrast: Contrast, *, method: str = METHOD,
             confidence: float = CONFIDENCE, n_boot: int = N_BOOT, seed: int = BOOTSTRAP_SEED) -> IntervalResult:
    """The contrast of the models' values (each the mean over its seeds of ``statistic`` of a
    run's column means) and its ``confidence`` interval by ``method`` (:data:`METHODS`;
    ``n_boot``/``seed``: the pigeonhole bootstrap only). The interval is NaN where the design cannot
    give one (a trained group with one seed; one cluster)."""
    if method not in METHODS:
        raise ValueError(f"interval: method: expected one of {list(METHODS)}, got {method!r}")
    if method == "pigeonhole-bootstrap":
        return _pigeonhole(comp, statistic, contrast, n_boot, seed, confidence)
    lin = _linearise(comp, statistic, contrast)
    parts = _variance_parts(comp, lin)
    if method == "seed-cluster-t":
        se, df = _combined(parts, confidence)
    elif method == "seed-t":
        se, df = _seed_only(parts)
    else:
        se, df = _crossed(parts, method == "crossed-t-conservative")
    return _t_result(comp, lin.estimate, se, df, method, confidence, parts)


def seed_interval(values: Sequence[float], *, confidence: float = CONFIDENCE) -> IntervalResult:
    """Mean of one observation per training seed (e.g. MGN's final-weight margin) with the t
    interval over seeds (df = n - 1); NaN bounds with a single seed."""
    v = np.asarray(values, dtype=np.float64)
    if v.ndim != 1 or v.size == 0 or not np.isfinite(v).all():
        raise ValueError(f"seed_interval: expected a non-empty 1-d array of finite values, got {values!r}")
    se = float(v.std(ddof=1) / math.sqrt(v.size)) if v.size > 1 else math.nan
    df = float(v.size - 1) if v.size > 1 else math.nan
    half = t_ppf(0.5 + confidence / 2.0, df) * se if v.size > 1 else math.nan
    est = float(v.mean())
    return IntervalResult(est, est - half, est + half, se, df, "seed-t", (int(v.size),), (False,), 0, 0, False,
                          confidence)
