"""The coverage check of the intervals by simulation: two simulated models (:class:`Scenario`,
the variance :data:`COMPOSITIONS` x statistic x true difference of :data:`SCENARIOS`) at a
comparison's :class:`Design`, :func:`simulate` one comparison, :func:`coverage` the share of
simulated intervals that hold the true difference (deterministic: RNG ``(seed, i)`` per
simulation), :func:`coverage_line` the report's one line on it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .comparison import STATISTICS, Comparison, make_comparison
from .intervals import CONFIDENCE, METHOD, interval
from .power import MIN_SEEDS

__all__ = ["COVERAGE_SEED", "COVERAGE_SIMS", "LEVELS", "Scenario", "COMPOSITIONS", "SCENARIOS", "Design",
           "simulate", "CoverageResult", "coverage", "coverage_line"]

#: RNG seed and size of the coverage check (:func:`coverage`).
COVERAGE_SEED, COVERAGE_SIMS = 24, 400

#: Column means of the simulated model 0 (this run's default-scale Table II: MAE_DE, IoU_SS,
#: IoU_LS, IoU_BEVP); the ``mean`` statistic uses the first column only.
LEVELS: tuple[float, ...] = (0.28, 0.10, 0.06, 0.25)


@dataclass(frozen=True)
class Scenario:
    """Two simulated models whose per-frame scores are, per column (sds below),
    ``y[g,s,f] = mu_g + a[g,s] + b[c] + ab[g,c] + r[g,s,c] + e[f] + noise[g,s,f]`` (f in cluster
    c): a seed effect ``a`` (a share ``seed_shared`` of its variance common to the two models'
    runs of one seed when the design pairs them), a cluster effect ``b`` shared by the models,
    a model x cluster interaction ``ab``, a run x cluster interaction ``r``, a frame effect ``e``
    shared by all runs, run x frame noise. ``mu_0`` = :data:`LEVELS`, ``mu_1`` the same plus
    ``delta`` on column 0; the claim "model 0 has the lower statistic" has the contrast
    ``v_1 - v_0`` and the true value ``stat(mu_1) - stat(mu_0)`` (exact for statistics of degree
    <= 2, as mean, TM and MV: both models' effects are distributed alike)."""

    name: str
    statistic: str
    delta: float = 0.0
    seed_sd: float = 0.015
    seed_shared: float = 0.5
    cluster_sd: float = 0.04
    model_cluster_sd: float = 0.01
    run_cluster_sd: float = 0.01
    frame_sd: float = 0.05
    noise_sd: float = 0.03


#: Variance compositions of the coverage check (sds per column; unnamed ones as in :class:`Scenario`).
COMPOSITIONS: dict[str, dict[str, float]] = {
    "balanced": {},
    "seed": {"seed_sd": 0.04, "model_cluster_sd": 0.003, "run_cluster_sd": 0.003, "noise_sd": 0.01},
    "model x episode": {"seed_sd": 0.005, "model_cluster_sd": 0.03, "run_cluster_sd": 0.005, "noise_sd": 0.01},
    "run x episode": {"seed_sd": 0.005, "model_cluster_sd": 0.003, "run_cluster_sd": 0.03, "noise_sd": 0.01},
    "frame noise": {"seed_sd": 0.003, "model_cluster_sd": 0.0, "run_cluster_sd": 0.0, "noise_sd": 0.1},
    "unshared seeds": {"seed_shared": 0.0},
}
#: Every composition x statistic (mean, TM, MV) x true difference (0, 0.03 on column 0).
SCENARIOS: tuple[Scenario, ...] = tuple(
    Scenario(f"{comp}/{stat}/{delta:g}", stat, delta, **kw)
    for comp, kw in COMPOSITIONS.items() for stat in STATISTICS for delta in (0.0, 0.03))


@dataclass(frozen=True)
class Design:
    """The sizes of a comparison: seeds per model, frames per cluster, seed pairing."""

    n_seeds: int = MIN_SEEDS
    cluster_sizes: tuple[int, ...] = (10,) * 10
    paired: bool = True

    @classmethod
    def of(cls, comp: Comparison) -> "Design":
        """This comparison's design (the fewest seeds of a trained group)."""
        trained = [n for n, g in zip(comp.n_seeds, comp.groups) if not g.fixed] or [MIN_SEEDS]
        return cls(min(trained), tuple(int(n) for n in comp.cluster_sizes), comp.paired)


def _claim(v: np.ndarray) -> np.ndarray:
    """The simulated claim "model 0 has the lower statistic"."""
    return v[..., 1] - v[..., 0]


def simulate(sc: Scenario, design: Design, rng: np.random.Generator) -> tuple[Comparison, float]:
    """One simulated comparison of :class:`Scenario` ``sc`` at ``design`` and its true contrast."""
    stat = STATISTICS[sc.statistic]
    n_cols = 1 if sc.statistic == "mean" else len(LEVELS)
    mu = np.tile(np.asarray(LEVELS[:n_cols]), (2, 1))
    mu[1, 0] += sc.delta
    sizes = np.asarray(design.cluster_sizes)
    cl = np.repeat(np.arange(sizes.size), sizes)
    s, k, n = design.n_seeds, sizes.size, int(sizes.sum())
    z = rng.standard_normal
    rho = sc.seed_shared if design.paired else 0.0
    a = sc.seed_sd * (math.sqrt(rho) * z((1, s, n_cols)) + math.sqrt(1.0 - rho) * z((2, s, n_cols)))
    y = (mu[:, None, None, :] + a[:, :, None, :] + sc.cluster_sd * z((k, n_cols))[cl]
         + sc.model_cluster_sd * z((2, k, n_cols))[:, None, cl] + sc.run_cluster_sd * z((2, s, k, n_cols))[:, :, cl]
         + sc.frame_sd * z((n, n_cols)) + sc.noise_sd * z((2, s, n, n_cols)))
    offset = 0 if design.paired else 1000
    groups = [{i: y[0, i] for i in range(s)}, {offset + i: y[1, i] for i in range(s)}]
    return make_comparison(groups, cl), float(stat(mu[1]) - stat(mu[0]))


@dataclass(frozen=True)
class CoverageResult:
    """Coverage of ``method``'s intervals over ``n_sim`` simulations (cycling through the
    scenarios); ``per_scenario``: (name, coverage, mean width, simulations) each."""

    method: str
    confidence: float
    n_sim: int
    n_seeds: int
    n_clusters: int
    coverage: float
    mean_width: float
    per_scenario: tuple[tuple[str, float, float, int], ...]


def coverage(design: Design = Design(), *, scenarios: Sequence[Scenario] = SCENARIOS, n_sim: int = COVERAGE_SIMS,
             method: str = METHOD, seed: int = COVERAGE_SEED, confidence: float = CONFIDENCE,
             n_boot: int = 500) -> CoverageResult:
    """The share of ``n_sim`` simulated comparisons (:func:`simulate`; simulation i draws
    scenario ``i mod len(scenarios)`` from RNG ``(seed, i)``: deterministic) whose ``method``
    interval holds the true difference; ``n_boot``: replicates of the pigeonhole bootstrap."""
    if n_sim < 1 or not scenarios or design.n_seeds < 2:
        raise ValueError(f"coverage: need n_sim >= 1, a scenario and >= 2 seeds, got n_sim={n_sim}, "
                         f"{len(scenarios)} scenarios, {design.n_seeds} seeds")
    hits: dict[str, list[float]] = {sc.name: [] for sc in scenarios}
    widths: dict[str, list[float]] = {sc.name: [] for sc in scenarios}
    for i in range(n_sim):
        sc = scenarios[i % len(scenarios)]
        comp, truth = simulate(sc, design, np.random.default_rng([seed, i]))
        r = interval(comp, STATISTICS[sc.statistic], _claim, method=method, confidence=confidence,
                     n_boot=n_boot, seed=seed + i)
        hits[sc.name].append(float(r.ci_low <= truth <= r.ci_high))
        widths[sc.name].append(r.ci_high - r.ci_low)
    per = tuple((name, float(np.mean(h)), float(np.mean(widths[name])), len(h)) for name, h in hits.items() if h)
    all_hits = [x for h in hits.values() for x in h]
    all_widths = [x for w in widths.values() for x in w]
    return CoverageResult(method, confidence, n_sim, design.n_seeds, len(design.cluster_sizes),
                          float(np.mean(all_hits)), float(np.mean(all_widths)), per)


def coverage_line(res: CoverageResult) -> str:
    """The report's one line on the intervals, e.g. ``intervals: crossed-t; coverage 95.3% at
    nominal 95% in 400 simulations at 3 seeds, 10 clusters``."""
    return (f"intervals: {res.method}; coverage {100 * res.coverage:.1f}% at nominal {100 * res.confidence:g}% in "
            f"{res.n_sim} simulations at {res.n_seeds} seeds, {res.n_clusters} clusters")
