"""Statistics for the claims scorecard and Table II's bold marks (CLAIMS.md, SPEC 8).

A comparison is a *contrast* of per-model statistics of the test scores, oriented so that a
positive value means the claim holds (e.g. ``TM(1L) - TM(15L)`` for "15L has a lower TM").
Its uncertainty comes from a paired, hierarchical percentile bootstrap:

1. seeds: each model's runs (independent trainings) are resampled with replacement;
2. frames: within each resampled seed slot the test frames are resampled with replacement,
   and the **same** resampled frames are used for every model (paired: the models are scored
   on the same test frames, so frame difficulty cancels out).

Every statistic used here is a function of a run's per-column test-set means (a mean score,
TM of the means, MV of the means: eq. 6-7 computed by :mod:`compact_perception.metrics`), so a
resample is a vector of frame counts and the resampled means are ``counts @ scores / n``. A
model's value is the mean over its (resampled) seeds of the run statistic. The RNG seed is
fixed (:data:`BOOTSTRAP_SEED`): the same inputs give the same interval on every machine.

Power (:func:`mde`): the minimal detectable effect at 80% power, two-sided alpha 0.05, is
``(t_{1-alpha/2, df} + t_{power, df}) * SE`` (the usual normal-approximation formula with t
quantiles at the interval's df; it ignores the chance of crossing the opposite bound); the t
quantiles come from :func:`t_ppf` (no scipy).

No verdict from a single run (:func:`decidable`): with fewer than :data:`MIN_SEEDS` seeds in a
non-fixed group the comparison is :data:`NOT_DECIDABLE`; a fixed group is exempt.

Verdict rule (:func:`verdict`, CLAIMS.md): ``reproduced`` when the whole 95% interval lies on
the claimed side of 0 (strictly above 0), ``contradicted`` when it lies wholly on the other
side (strictly below 0), ``inconclusive`` otherwise (an interval touching 0 included). For a
claim of equality, with an equivalence margin m: ``reproduced`` when the interval lies within
[-m, m] (the ends included), ``contradicted`` when it lies wholly outside it (above m or below
-m), ``inconclusive`` otherwise.
"""
from __future__ import annotations

import functools
import logging
import math
from dataclasses import dataclass
from typing import Callable, Optional, Sequence

import numpy as np

from .metrics import metric_variance, total_metric

log = logging.getLogger(__name__)

__all__ = [
    "BOOTSTRAP_SEED",
    "N_BOOT",
    "CONFIDENCE",
    "ALPHA",
    "POWER",
    "MIN_SEEDS",
    "REPRODUCED",
    "CONTRADICTED",
    "INCONCLUSIVE",
    "NOT_DECIDABLE",
    "VERDICTS",
    "t_cdf",
    "t_ppf",
    "normal_ppf",
    "satterthwaite_df",
    "mde",
    "decidable",
    "BootstrapResult",
    "stat_mean",
    "stat_tm",
    "stat_mv",
    "bootstrap_contrast",
    "paired_bootstrap",
    "seed_bootstrap",
    "verdict",
]

#: Fixed RNG seed of every bootstrap (deterministic reports).
BOOTSTRAP_SEED = 20220
#: Bootstrap replicates.
N_BOOT = 2000
#: Two-sided coverage of the percentile interval.
CONFIDENCE = 0.95
#: Two-sided level and power of the minimal detectable effect (:func:`mde`).
ALPHA, POWER = 0.05, 0.8
#: Fewest seeds of a trained model for a verdict (issue 24: no verdict from a single run).
MIN_SEEDS = 3
REPRODUCED, CONTRADICTED, INCONCLUSIVE = "reproduced", "contradicted", "inconclusive"
NOT_DECIDABLE = "not decidable"
VERDICTS: tuple[str, ...] = (REPRODUCED, CONTRADICTED, INCONCLUSIVE, NOT_DECIDABLE)

#: (..., n_cols) column means -> (...) statistic.
Statistic = Callable[[np.ndarray], np.ndarray]
#: (n_boot, n_groups) per-model statistics -> (n_boot,) contrast (positive = the claim holds).
Contrast = Callable[[np.ndarray], np.ndarray]
_CHUNK = 250


def stat_mean(m: np.ndarray) -> np.ndarray:
    """The mean of a one-column score (``m[..., 0]``)."""
    return np.asarray(m)[..., 0]


def stat_tm(m: np.ndarray) -> np.ndarray:
    """TM (eq. 6) of the means of columns (mae_de, iou_ss, iou_ls, iou_bevp)."""
    m = np.asarray(m)
    return total_metric(m[..., 0], m[..., 1], m[..., 2], m[..., 3])


def stat_mv(m: np.ndarray) -> np.ndarray:
    """MV (eq. 7) of the means of columns (mae_de, iou_ss, iou_ls, iou_bevp)."""
    m = np.asarray(m)
    return metric_variance(m[..., 0], m[..., 1], m[..., 2], m[..., 3])


# ----------------------------------------------------------------------------- Student's t
def _beta_cf(a: float, b: float, x: float) -> float:
    """The continued fraction ``1 + d1/(1 + d2/(1 + ...))`` of I_x(a, b) (DLMF 8.17.22),
    evaluated by the modified Lentz method."""
    tiny, f, c, d = 1e-300, 1.0, 1.0, 0.0
    for j in range(1, 2000):
        m = j // 2
        if j % 2:
            num = -(a + m) * (a + b + m) * x / ((a + 2 * m) * (a + 2 * m + 1))
        else:
            num = m * (b - m) * x / ((a + 2 * m - 1) * (a + 2 * m))
        d = 1.0 + num * d
        d = 1.0 / (d if abs(d) > tiny else tiny)
        c = 1.0 + num / c
        c = c if abs(c) > tiny else tiny
        f *= c * d
        if abs(c * d - 1.0) < 1e-15:
            break
    return f


def _betainc(a: float, b: float, x: float) -> float:
    """The regularised incomplete beta function I_x(a, b) (DLMF 8.17.22; the symmetry
    ``I_x(a, b) = 1 - I_{1-x}(b, a)`` where the fraction converges slowly)."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    if x > (a + 1.0) / (a + b + 2.0):
        return 1.0 - _betainc(b, a, 1.0 - x)
    log_front = a * math.log(x) + b * math.log1p(-x) - (math.lgamma(a) + math.lgamma(b) - math.lgamma(a + b))
    return math.exp(log_front) / (a * _beta_cf(a, b, x))


def t_cdf(t: float, df: float) -> float:
    """Student's t distribution function: ``1 - I_x(df/2, 1/2) / 2`` with ``x = df/(df + t^2)``
    for t > 0 (symmetric below 0); ``df`` need not be an integer (Satterthwaite)."""
    if not df > 0:
        raise ValueError(f"t_cdf: df must be > 0, got {df}")
    tail = 0.5 * _betainc(df / 2.0, 0.5, df / (df + t * t))
    return 1.0 - tail if t > 0 else tail


def _normal_cdf(x: float) -> float:
    return 0.5 * math.erfc(-x / math.sqrt(2.0))


def _t_pdf(t: float, df: float) -> float:
    log_c = math.lgamma((df + 1) / 2) - math.lgamma(df / 2) - 0.5 * math.log(df * math.pi)
    return math.exp(log_c - (df + 1) / 2 * math.log1p(t * t / df))


def _invert(cdf: Callable[[float], float], pdf: Callable[[float], float], q: float) -> float:
    """The x > 0 with ``cdf(x) = q`` (q > 1/2) for a symmetric distribution: Newton steps kept
    inside a bisection bracket."""
    lo, hi = 0.0, 1.0
    while cdf(hi) < q:
        lo, hi = hi, hi * 2.0
        if hi > 1e12:
            return math.inf
    x = 0.5 * (lo + hi)
    for _ in range(200):
        f = cdf(x) - q
        if f > 0:
            hi = x
        else:
            lo = x
        dens = pdf(x)
        nxt = x - f / dens if dens > 0 else 0.5 * (lo + hi)
        if not lo < nxt < hi:
            nxt = 0.5 * (lo + hi)
        if abs(nxt - x) <= 1e-13 * max(1.0, x):
            return nxt
        x = nxt
    return x


def _check_p(p: float, who: str) -> None:
    if not 0.0 < p < 1.0:
        raise ValueError(f"{who}: p must lie in (0, 1), got {p}")


def normal_ppf(p: float) -> float:
    """The standard normal quantile (``normal_ppf(0.975)`` = 1.95996...)."""
    _check_p(p, "normal_ppf")
    if p == 0.5:
        return 0.0
    x = _invert(_normal_cdf, lambda v: math.exp(-0.5 * v * v) / math.sqrt(2 * math.pi), max(p, 1 - p))
    return x if p > 0.5 else -x


@functools.lru_cache(maxsize=4096)
def t_ppf(p: float, df: float) -> float:
    """Student's t quantile ``t_{p, df}`` (e.g. t_{0.975, 2} = 4.303, t_{0.8, 2} = 1.061),
    by inverting :func:`t_cdf`; the normal quantile for ``df`` = inf or above 1e7."""
    _check_p(p, "t_ppf")
    if not df > 0:
        raise ValueError(f"t_ppf: df must be > 0, got {df}")
    if df > 1e7:
        return normal_ppf(p)
    if p == 0.5:
        return 0.0
    x = _invert(lambda v: t_cdf(v, df), lambda v: _t_pdf(v, df), max(p, 1 - p))
    return x if p > 0.5 else -x


def satterthwaite_df(parts: Sequence[tuple[float, float]], total: Optional[float] = None) -> float:
    """Satterthwaite's degrees of freedom of a sum of independent variance estimates
    ``(v_i, df_i)``: ``total^2 / sum(v_i^2 / df_i)`` (``total`` = ``sum(v_i)`` unless given, as
    when a term is subtracted), at least 1; inf when every ``v_i`` is 0."""
    den = sum(v * v / d for v, d in parts if v != 0)
    tot = sum(v for v, _ in parts) if total is None else total
    return math.inf if den == 0 else max(1.0, tot * tot / den)




# ----------------------------------------------------------------------------- power and decidability
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


# ----------------------------------------------------------------------------- the percentile bootstrap
@dataclass(frozen=True)
class BootstrapResult:
    """A contrast on the full data and its percentile interval."""

    estimate: float
    ci_low: float
    ci_high: float
    n_boot: int
    n_seeds: tuple[int, ...]
    n_frames: int


def _check_groups(groups: Sequence[Sequence[np.ndarray]]) -> tuple[list[list[np.ndarray]], int]:
    if not groups:
        raise ValueError("bootstrap: no groups")
    out: list[list[np.ndarray]] = []
    n_frames: Optional[int] = None
    n_cols: Optional[int] = None
    for g, runs in enumerate(groups):
        if not runs:
            raise ValueError(f"bootstrap: group {g} has no runs")
        arrs = []
        for r in runs:
            a = np.asarray(r, dtype=np.float64)
            if a.ndim == 1:
                a = a[:, None]
            if a.ndim != 2 or a.shape[0] == 0:
                raise ValueError(f"bootstrap: group {g}: expected a (frames, columns) array, got shape {a.shape}")
            if not np.isfinite(a).all():
                raise ValueError(f"bootstrap: group {g}: scores must be finite")
            if n_frames is None:
                n_frames, n_cols = a.shape
            elif a.shape != (n_frames, n_cols):
                raise ValueError(f"bootstrap: group {g}: shape {a.shape} differs from {(n_frames, n_cols)} "
                                 "(paired runs must score the same frames)")
            arrs.append(a)
        out.append(arrs)
    return out, int(n_frames)  # type: ignore[arg-type]


def _frame_counts(rng: np.random.Generator, n_rep: int, n: int) -> np.ndarray:
    """(n_rep, n) multiplicities of n frames drawn with replacement, per replicate."""
    idx = rng.integers(0, n, size=(n_rep, n))
    flat = (idx + (np.arange(n_rep)[:, None] * n)).ravel()
    return np.bincount(flat, minlength=n_rep * n).reshape(n_rep, n).astype(np.float64)


def bootstrap_contrast(groups: Sequence[Sequence[np.ndarray]], statistic: Statistic, contrast: Contrast, *,
                       n_boot: int = N_BOOT, seed: int = BOOTSTRAP_SEED,
                       confidence: float = CONFIDENCE) -> BootstrapResult:
    """Paired hierarchical bootstrap of ``contrast`` over the per-model statistics.

    ``groups[g]``: the runs (seeds) of model g, each a (frames, columns) array of per-frame
    scores, frames in the same order in every run of every group. Model g's value = mean over
    its runs of ``statistic(column means)``; ``contrast`` maps the (…, G) model values to the
    difference in the claim's direction. Per replicate the seeds of each model are resampled,
    and seed slot k of every model uses the same resampled frames.
    """
    runs, n = _check_groups(groups)
    full = np.array([np.mean([float(statistic(r.mean(axis=0))) for r in g]) for g in runs])
    estimate = float(np.asarray(contrast(full[None, :]))[0])
    rng = np.random.default_rng(seed)
    n_slots = max(len(g) for g in runs)
    reps: list[np.ndarray] = []
    done = 0
    while done < n_boot:
        c = min(_CHUNK, n_boot - done)
        # seed choice per model and slot, then one frame resample per slot shared by all models
        picks = [rng.integers(0, len(g), size=(c, len(g))) for g in runs]
        counts = [_frame_counts(rng, c, n) for _ in range(n_slots)]
        vals = np.zeros((c, len(runs)))
        for gi, g in enumerate(runs):
            for k in range(len(g)):
                # statistic of every run of g on slot k's frames, then the picked run per replicate
                per_run = np.stack([statistic(counts[k] @ r / n) for r in g], axis=1)   # (c, n_runs)
                vals[:, gi] += per_run[np.arange(c), picks[gi][:, k]]
            vals[:, gi] /= len(g)
        reps.append(np.asarray(contrast(vals), dtype=np.float64))
        done += c
    rep = np.concatenate(reps)
    tail = 100.0 * (1.0 - confidence) / 2.0
    lo, hi = np.percentile(rep, [tail, 100.0 - tail])
    return BootstrapResult(estimate, float(lo), float(hi), int(n_boot), tuple(len(g) for g in runs), n)


def paired_bootstrap(better: Sequence[np.ndarray], worse: Sequence[np.ndarray], statistic: Statistic, *,
                     lower_is_better: bool, n_boot: int = N_BOOT, seed: int = BOOTSTRAP_SEED,
                     confidence: float = CONFIDENCE) -> BootstrapResult:
    """The difference "``better`` beats ``worse`` on ``statistic``", positive when it does:
    ``stat(worse) - stat(better)`` if lower is better, else ``stat(better) - stat(worse)``.
    ``better`` / ``worse``: runs (seeds) of per-frame scores on the same frames."""
    sign = 1.0 if lower_is_better else -1.0
    return bootstrap_contrast([better, worse], statistic, lambda v: sign * (v[..., 1] - v[..., 0]),
                              n_boot=n_boot, seed=seed, confidence=confidence)


def seed_bootstrap(values: Sequence[float], *, n_boot: int = N_BOOT, seed: int = BOOTSTRAP_SEED,
                   confidence: float = CONFIDENCE, min_seeds: int = MIN_SEEDS) -> BootstrapResult:
    """Mean over seeds of one observation per run, with a bootstrap-over-seeds interval; with
    fewer than ``min_seeds`` runs the interval is NaN (no verdict from so few trainings)."""
    v = np.asarray(values, dtype=np.float64)
    if v.ndim != 1 or v.size == 0 or not np.isfinite(v).all():
        raise ValueError(f"seed_bootstrap: expected a non-empty 1-d array of finite values, got {values!r}")
    est = float(v.mean())
    if v.size < min_seeds:
        return BootstrapResult(est, math.nan, math.nan, 0, (int(v.size),), 0)
    rng = np.random.default_rng(seed)
    rep = v[rng.integers(0, v.size, size=(n_boot, v.size))].mean(axis=1)
    tail = 100.0 * (1.0 - confidence) / 2.0
    lo, hi = np.percentile(rep, [tail, 100.0 - tail])
    return BootstrapResult(est, float(lo), float(hi), int(n_boot), (int(v.size),), 0)


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
