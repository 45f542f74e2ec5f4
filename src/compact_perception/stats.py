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

Verdict rule (:func:`verdict`, CLAIMS.md): ``reproduced`` when the whole 95% interval lies on
the claimed side of 0 (strictly above 0), ``contradicted`` when it lies wholly on the other
side (strictly below 0), ``inconclusive`` otherwise (an interval touching 0 included). For a
claim of equality, with an equivalence margin m: ``reproduced`` when the interval lies within
[-m, m] (the ends included), ``contradicted`` when it lies wholly outside it (above m or below
-m), ``inconclusive`` otherwise.
"""
from __future__ import annotations

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
    "MIN_SEEDS",
    "REPRODUCED",
    "CONTRADICTED",
    "INCONCLUSIVE",
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
#: Fewest seeds for a verdict on a one-number-per-run observation (e.g. MGN's final weights).
MIN_SEEDS = 3
REPRODUCED, CONTRADICTED, INCONCLUSIVE = "reproduced", "contradicted", "inconclusive"

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
