"""Statistics for the claims scorecard and Table II's bold marks (CLAIMS.md, SPEC 8; issue 24).

A comparison is a *contrast* of per-model statistics of the test scores, oriented so that a
positive value means the claim holds (e.g. ``TM(1L) - TM(15L)`` for "15L has a lower TM").
Every statistic is a function of a run's per-column test-set means (a mean score, TM of the
means (eq. 6, linear), MV of the means (eq. 7, the population variance of the four terms: not
linear)); a model's value is the mean over its training seeds of the statistic of that run's
column means, and the estimate is the contrast of the models' values.

The data of one comparison (:class:`Comparison`, :func:`make_comparison`): per model a
:class:`Group` of runs keyed by training seed, each a (frames, columns) array of per-frame scores
on the same frames in the same order, and one cluster label per frame (the episode of sets
A/B/C, the scene of nuScenes: consecutive frames are not independent). Groups trained at the
same set of seeds are *paired* (a seed fixes the initial weights and the batch order: common
random numbers); groups with different seed sets are independent of each other; a ``fixed``
group (a deterministic predictor, the trivial floor) has one run and no training randomness.

The interval (:func:`interval`, :data:`METHOD` = ``seed-cluster-t``)
--------------------------------------------------------------------
Seeds and clusters are two crossed random factors: another training seed and another draw of
test episodes would both change the estimate. The contrast is linearised (delta method: the
central-difference gradient of the statistic at each run's column means and of the contrast at
the models' values), which turns each block of paired groups into a seeds x clusters table
``d[s, c]`` of contributions (from cluster c's column means; cluster weights ``pi_c = n_c/N``).
For the two-way random-effects model ``d = delta + A_s + B_c + E_sc``:

* ``V_seed``: the variance over seeds of the table's row means / S (df S - 1), per block;
  blocks of unpaired groups are independent, so theirs add (Welch-Satterthwaite df);
* ``V_cluster`` = ``K/(K-1) sum_c pi_c^2 (u_c - u)^2`` of the cluster column ``u_c`` (all groups,
  fixed ones too: the models share the frames; df K - 1);
* ``V_inter``: the weighted residual mean square of each table / (S K) (df (S-1)(K-1)); it
  estimates ``var(E)/(SK)``, which ``V_seed`` and ``V_cluster`` both hold.

``seed-cluster-t`` gives the seed part and the cluster part each its own t quantile (Banerjee's
combination): half-width ``sqrt(t_{p,df_seed}^2 V_seed + t_{p,K-1}^2 max(0, V_cluster - V_inter))``,
p = 1 - alpha/2; ``se`` = ``sqrt(V_seed + max(0, V_cluster - V_inter))`` and ``df`` is the
effective df at which ``t_{p,df} se`` is that half-width (so :func:`mde` applies unchanged).
``crossed-t`` pools the parts: ``V = V_seed + V_cluster - V_inter`` (the ANOVA estimator of
``var(A)/S + var(B)/K + var(E)/(SK)``, floored at ``max(V_seed, V_cluster)``), one Satterthwaite
df; ``crossed-t-conservative`` keeps ``V_seed + V_cluster``; ``seed-t`` ignores the clusters (the
seed-paired t of the issue: the test frames taken as fixed); ``pigeonhole-bootstrap`` is Owen's
crossed bootstrap (seeds and clusters resampled independently, percentile interval);
``hierarchical-bootstrap`` is the former method (:func:`bootstrap_contrast`: seeds resampled
per model, frames one by one). Quantiles come from :func:`t_ppf` (no scipy).

Measured (:func:`coverage`: two models, 3 seeds, nominal 95%, 1800 simulations per composition
of :data:`COMPOSITIONS`, each over mean, TM and MV and a true difference of 0 and 0.03; coverage,
then in brackets the mean width relative to ``seed-cluster-t`` on the same simulated data).
A/B/C design, 10 paired episodes of 10 frames:

=================  ==============  ===========  ============  ===========  ===========  ============
composition        seed-cluster-t  crossed-t    crossed-t-    seed-t       pigeonhole-  hierarchical-
                                                conservative               bootstrap    bootstrap
=================  ==============  ===========  ============  ===========  ===========  ============
balanced           96.8% (1.00)    94.9% (.85)  95.1% (.81)   94.4% (.95)  88.8% (.48)  88.6% (.51)
seed               95.6% (1.00)    95.0% (.99)  94.6% (.99)   95.4% (1.0)  73.3% (.37)  89.9% (.53)
model x episode    96.9% (1.00)    95.4% (.92)  95.6% (.93)   58.8% (.38)  90.6% (.76)  44.1% (.25)
run x episode      96.5% (1.00)    97.6% (.92)  98.7% (.85)   95.0% (.96)  99.1% (.69)  86.4% (.42)
frame noise        97.2% (1.00)    97.9% (.92)  99.0% (.85)   95.2% (.96)  99.0% (.70)  98.4% (.61)
unshared seeds     96.7% (1.00)    94.2% (.88)  93.8% (.84)   94.9% (.97)  84.1% (.43)  80.7% (.39)
=================  ==============  ===========  ============  ===========  ===========  ============

Other designs, lowest composition (``seed-cluster-t`` / ``crossed-t`` / ``seed-t``): 15
nuScenes-like scenes of 5-15 frames 95.6 / 92.6 / 61.1%; 40 episodes of 10 (paper scale)
95.5 / 93.1 / 78.4%; 10 episodes with unpaired seeds 96.6 / 95.3 / 63.5%.

Why ``seed-cluster-t``. The bootstraps undercover (3 seeds give a percentile interval with
normal-like quantiles and no df correction; the former one also ignores the episodes: 44% with a
model x episode effect, the issue's 60.5%); ``seed-t`` fails whenever models differ by episode.
The pooled ``crossed-t`` and its conservative form are 1-19% narrower but fall to 92.1-93.2%
when the seed part carries most of the variance and the clusters are many (15, 40): ``V_seed``
has 2 df, and when it comes out small by chance the pooled Satterthwaite df jumps to the cluster
part's and t shrinks with it (Welch's problem with tiny samples; in the limit of infinitely many
clusters a separate calculation gives 92.1-93.0% at a seed share of 70-95%). Keeping the seed
part on its own 2 df holds >= 95.5% in every composition and design measured, for 1-18% more
width than ``crossed-t`` in the A/B/C design (1% when the seeds dominate). Subtracting
``V_inter`` from the cluster part (it is in ``V_seed`` already) saves 8-12% of the width where
run x episode or frame noise dominate (kept in both parts, those compositions covered
98.7-99.7%). A delete-one jackknife over seeds and clusters gives the same two variances for a
linear statistic, so it is not a separate method. One interval (4 models x 3 seeds x 100 frames
x 4 columns, MV) takes about 7 ms; the report's check, :func:`coverage` with 400 simulations,
3-7 s on a shared 2-core CPU.

Use (the scorecard; ``a[k]``/``b[k]``: (frames, columns) per-frame scores of seed k, ``episode``:
one label per frame)::

    comp = make_comparison([{0: a[0], 1: a[1], 2: a[2]}, {0: b[0], 1: b[1], 2: b[2]}], episode)
    res = interval(comp, stat_tm, lambda v: v[..., 1] - v[..., 0])   # "A has a lower TM than B"
    comparison_verdict(res, margin=None), res.mde, undecidable_note(res)
    coverage_line(coverage(Design.of(comp)))                          # the report's one line

Power (:func:`mde`): the minimal detectable effect at 80% power, two-sided alpha 0.05, is
``(t_{1-alpha/2, df} + t_{power, df}) * SE`` (the usual normal-approximation formula with t
quantiles at the interval's df; it ignores the chance of crossing the opposite bound).

Seeds to decide (:func:`seeds_to_decide`): the fewest seeds per model at which that MDE falls to
a given effect (the paper's), from the measured variance components scaled to that many seeds
(the seed part shrinks as 1/S with S - 1 df; the test episodes' part net of the interaction stays).

No verdict from a single run (:func:`decidable`): with fewer than :data:`MIN_SEEDS` seeds in a
non-fixed group the comparison is :data:`NOT_DECIDABLE`; a fixed group is exempt.

Verdict rule (:func:`verdict`, CLAIMS.md): ``reproduced`` when the whole 95% interval lies on
the claimed side of 0 (strictly above 0), ``contradicted`` when it lies wholly on the other
side (strictly below 0), ``inconclusive`` otherwise (an interval touching 0 included). For a
claim of equality, with an equivalence margin m: ``reproduced`` when the interval lies within
[-m, m] (the ends included), ``contradicted`` when it lies wholly outside it (above m or below
-m), ``inconclusive`` otherwise. :func:`comparison_verdict` adds ``not decidable``.

The former percentile bootstrap (:func:`bootstrap_contrast`, :func:`paired_bootstrap`,
:func:`seed_bootstrap`) stays for its callers in ``report/`` until they move to :func:`interval`.
"""
from __future__ import annotations

import functools
import logging
import math
from dataclasses import dataclass, field
from typing import Callable, Mapping, Optional, Sequence, Union

import numpy as np

from .metrics import metric_variance, total_metric

log = logging.getLogger(__name__)

__all__ = [
    "BOOTSTRAP_SEED", "N_BOOT", "CONFIDENCE", "ALPHA", "POWER", "MIN_SEEDS", "METHOD", "METHODS",
    "REPRODUCED", "CONTRADICTED", "INCONCLUSIVE", "NOT_DECIDABLE", "VERDICTS",
    "COVERAGE_SEED", "COVERAGE_SIMS", "STATISTICS", "LEVELS", "COMPOSITIONS", "SCENARIOS",
    "Group", "Comparison", "make_comparison", "IntervalResult", "interval", "seed_interval",
    "t_cdf", "t_ppf", "normal_ppf", "satterthwaite_df", "mde", "seeds_to_decide", "MAX_SEEDS_TO_DECIDE", "decidable", "comparison_verdict",
    "undecidable_note", "Scenario", "Design", "simulate", "CoverageResult", "coverage", "coverage_line",
    "BootstrapResult", "stat_mean", "stat_tm", "stat_mv", "bootstrap_contrast", "paired_bootstrap",
    "seed_bootstrap", "verdict",
]

#: Fixed RNG seed of every bootstrap (deterministic reports).
BOOTSTRAP_SEED = 20220
#: Bootstrap replicates.
N_BOOT = 2000
#: Two-sided coverage of every interval.
CONFIDENCE = 0.95
#: Two-sided level and power of the minimal detectable effect (:func:`mde`).
ALPHA, POWER = 0.05, 0.8
#: Fewest seeds of a trained model for a verdict (issue 24: no verdict from a single run).
MIN_SEEDS = 3
REPRODUCED, CONTRADICTED, INCONCLUSIVE = "reproduced", "contradicted", "inconclusive"
NOT_DECIDABLE = "not decidable"
VERDICTS: tuple[str, ...] = (REPRODUCED, CONTRADICTED, INCONCLUSIVE, NOT_DECIDABLE)
#: The interval method of the report (chosen by coverage, see the module docstring).
METHOD = "seed-cluster-t"
#: RNG seed and size of the coverage check (:func:`coverage`).
COVERAGE_SEED, COVERAGE_SIMS = 24, 400

#: (..., n_cols) column means -> (...) statistic.
Statistic = Callable[[np.ndarray], np.ndarray]
#: (..., n_groups) per-model statistics -> (...) contrast (positive = the claim holds).
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


#: The statistics by name (the simulation's scenarios name theirs).
STATISTICS: dict[str, Statistic] = {"mean": stat_mean, "tm": stat_tm, "mv": stat_mv}


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


# ----------------------------------------------------------------------------- the data of one comparison
@dataclass(frozen=True, eq=False)
class Group:
    """One model of a comparison: its runs keyed by training seed, each a (frames, columns)
    array of per-frame scores. ``fixed``: a deterministic predictor (the trivial floor), one
    run without training randomness (no seed variance; exempt from :data:`MIN_SEEDS`)."""

    runs: Mapping[int, np.ndarray]
    fixed: bool = False
    name: str = ""

    @property
    def seeds(self) -> tuple[int, ...]:
        return tuple(self.runs)


@dataclass(frozen=True, eq=False)
class Comparison:
    """Validated groups (runs sorted by seed, float arrays of one shape) and the frames'
    clusters as codes ``0..K-1`` (``cluster_sizes[k]`` frames in cluster k)."""

    groups: tuple[Group, ...]
    clusters: np.ndarray
    cluster_sizes: np.ndarray = field(repr=False)

    @property
    def n_frames(self) -> int:
        return int(self.clusters.size)

    @property
    def n_clusters(self) -> int:
        return int(self.cluster_sizes.size)

    @property
    def n_seeds(self) -> tuple[int, ...]:
        return tuple(len(g.runs) for g in self.groups)

    @property
    def paired(self) -> bool:
        """Two or more trained groups, all at the same seeds (common random numbers)."""
        trained = [g.seeds for g in self.groups if not g.fixed]
        return len(trained) >= 2 and len(set(trained)) == 1


GroupLike = Union[Group, Mapping[int, np.ndarray]]


def _as_run(a: object, where: str, shape: Optional[tuple[int, ...]]) -> np.ndarray:
    arr = np.asarray(a, dtype=np.float64)
    arr = arr[:, None] if arr.ndim == 1 else arr
    if arr.ndim != 2 or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ValueError(f"{where}: expected a (frames, columns) array, got shape {arr.shape}")
    if shape is not None and arr.shape != shape:
        raise ValueError(f"{where}: shape {arr.shape} differs from {shape} (every run must score the same frames)")
    if not np.isfinite(arr).all():
        raise ValueError(f"{where}: scores must be finite")
    return arr


def make_comparison(groups: Sequence[GroupLike], clusters: Sequence[object]) -> Comparison:
    """A :class:`Comparison` from per-model runs (a :class:`Group`, or a ``{seed: scores}``
    mapping for a trained model) and one cluster label per frame (episode / scene id, any
    hashable labels); raises ``ValueError`` naming the group and seed of a bad input."""
    if not groups:
        raise ValueError("comparison: no groups")
    shape: Optional[tuple[int, ...]] = None
    out: list[Group] = []
    for gi, g in enumerate(groups):
        grp = g if isinstance(g, Group) else Group(dict(g))
        if not grp.runs:
            raise ValueError(f"comparison: group {gi} has no runs")
        if grp.fixed and len(grp.runs) != 1:
            raise ValueError(f"comparison: group {gi} is fixed (deterministic) but has {len(grp.runs)} runs")
        runs: dict[int, np.ndarray] = {}
        for seed in sorted(grp.runs):
            runs[int(seed)] = _as_run(grp.runs[seed], f"comparison: group {gi} seed {seed}", shape)
            shape = runs[int(seed)].shape
        out.append(Group(runs, grp.fixed, grp.name))
    labels = np.asarray(clusters)
    if labels.ndim != 1 or labels.size != shape[0]:  # type: ignore[index]
        raise ValueError(f"comparison: clusters: expected one label per frame ({shape[0]}), "  # type: ignore[index]
                         f"got shape {labels.shape}")
    _, codes = np.unique(labels, return_inverse=True)
    codes = codes.astype(np.intp).ravel()
    return Comparison(tuple(out), codes, np.bincount(codes).astype(np.float64))


# ----------------------------------------------------------------------------- the linearised contrast
def _gradient(fn: Callable[[np.ndarray], np.ndarray], x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``fn`` at the rows of x (..., n) and its central-difference gradient (..., n)."""
    n = x.shape[-1]
    step = 1e-6 * np.maximum(1.0, np.abs(x))                                   # (..., n)
    eye = np.eye(n)
    pts = np.concatenate([x[..., None, :], x[..., None, :] + eye * step[..., None, :],
                          x[..., None, :] - eye * step[..., None, :]], axis=-2)  # (..., 2n+1, n)
    vals = np.asarray(fn(pts), dtype=np.float64)
    return vals[..., 0], (vals[..., 1:n + 1] - vals[..., n + 1:]) / (2.0 * step)


@dataclass(frozen=True)
class _Linear:
    """The estimate and, per group, its (seeds, clusters) table of linearised contributions
    ``w_g * (h(m_s) + grad h(m_s) . (m_sc - m_s))`` (their frame-weighted mean over clusters,
    averaged over seeds and summed over groups, is the linearised contrast)."""

    estimate: float
    tables: tuple[np.ndarray, ...]
    weights: np.ndarray                       # pi_c = n_c / N


def _cluster_means(comp: Comparison, g: Group) -> tuple[np.ndarray, np.ndarray]:
    """A group's run means (S, C) and cluster means (S, K, C)."""
    runs = np.stack(list(g.runs.values()))                                   # (S, N, C)
    sums = np.zeros((runs.shape[0], comp.n_clusters, runs.shape[2]))
    np.add.at(sums, (slice(None), comp.clusters), runs)
    return runs.mean(axis=1), sums / comp.cluster_sizes[None, :, None]


def _linearise(comp: Comparison, statistic: Statistic, contrast: Contrast) -> _Linear:
    parts = []
    for g in comp.groups:
        m, mc = _cluster_means(comp, g)
        h, grad = _gradient(statistic, m)                                    # (S,), (S, C)
        parts.append((h, h[:, None] + np.einsum("skc,sc->sk", mc - m[:, None, :], grad)))
    values = np.array([h.mean() for h, _ in parts])
    est, w = _gradient(contrast, values)
    tables = tuple(float(w[i]) * t for i, (_, t) in enumerate(parts))
    return _Linear(float(est), tables, comp.cluster_sizes / comp.n_frames)


@dataclass(frozen=True)
class _Parts:
    """Variance estimates ``(v, df)`` of the seed blocks, the clusters, the interactions."""

    seed: tuple[tuple[float, float], ...]
    cluster: tuple[float, float]
    inter: tuple[tuple[float, float], ...]


def _variance_parts(comp: Comparison, lin: _Linear) -> _Parts:
    """The two-way (seeds x clusters) variance components of the linearised contrast; a
    trained block with one seed gives a NaN seed variance, one cluster a NaN cluster variance."""
    pi, k = lin.weights, comp.n_clusters
    blocks: dict[tuple[int, ...], np.ndarray] = {}
    column = np.zeros(k)
    for g, tab in zip(comp.groups, lin.tables):
        if g.fixed:
            column += tab[0]
        else:
            blocks[g.seeds] = blocks.get(g.seeds, 0.0) + tab
    seed, inter = [], []
    for d in blocks.values():
        s = d.shape[0]
        column += d.mean(axis=0)
        if s < 2:
            seed.append((math.nan, 1.0))
            continue
        rows = d @ pi
        seed.append((float(rows.var(ddof=1)) / s, float(s - 1)))
        if k > 1:
            cols = d.mean(axis=0)
            resid = d - rows[:, None] - cols[None, :] + float(cols @ pi)
            inter.append((float((resid ** 2 @ pi ** 2).sum()) * k / ((s - 1) * (k - 1) * s), float((s - 1) * (k - 1))))
    if k < 2:
        return _Parts(tuple(seed), (math.nan, 1.0), tuple(inter))
    v_cl = k / (k - 1) * float((pi ** 2 * (column - column @ pi) ** 2).sum())
    return _Parts(tuple(seed), (v_cl, float(k - 1)), tuple(inter))


def _crossed(parts: _Parts, conservative: bool) -> tuple[float, float]:
    """SE and Satterthwaite df of ``V_seed + V_cluster`` (less ``V_inter`` unless
    ``conservative``, floored at ``max(V_seed, V_cluster)``)."""
    v_seed = sum(v for v, _ in parts.seed)
    v_cl = parts.cluster[0]
    if not (math.isfinite(v_seed) and math.isfinite(v_cl)):
        return math.nan, math.nan
    terms = [*parts.seed, parts.cluster]
    if conservative:
        return math.sqrt(v_seed + v_cl), satterthwaite_df(terms)
    total = v_seed + v_cl - sum(v for v, _ in parts.inter)
    if total >= max(v_seed, v_cl):
        return math.sqrt(total), satterthwaite_df([*terms, *parts.inter], total)
    if v_seed >= v_cl:
        return math.sqrt(v_seed), satterthwaite_df(parts.seed)
    return math.sqrt(v_cl), satterthwaite_df([parts.cluster])


def _effective_df(q: float, p: float) -> float:
    """The df at which ``t_{p, df} = q`` (t quantiles fall as df grows): bisection on log df."""
    if q <= normal_ppf(p):
        return math.inf
    if t_cdf(q, 1.0) >= p:
        return 1.0
    lo, hi = 0.0, math.log(1e7)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if t_cdf(q, math.exp(mid)) < p:
            lo = mid
        else:
            hi = mid
    return math.exp(0.5 * (lo + hi))


def _combined(parts: _Parts, confidence: float) -> tuple[float, float]:
    """The seed part (the blocks' sum, Welch-Satterthwaite df) and the cluster part net of the
    interaction (``max(0, V_cluster - V_inter)``, df K - 1), each with its own t quantile:
    half-width ``sqrt(t_seed^2 V_seed + t_cluster^2 V_net)`` (Banerjee's combination). Returns
    the SE ``sqrt(V_seed + V_net)`` and the effective df at which ``t_{p, df} SE`` is that width."""
    v_seed = sum(v for v, _ in parts.seed)
    v_net = parts.cluster[0] - sum(v for v, _ in parts.inter)
    if not (math.isfinite(v_seed) and math.isfinite(v_net)):
        return math.nan, math.nan
    comps = [(v_seed, satterthwaite_df(parts.seed)), (max(0.0, v_net), parts.cluster[1])]
    total = sum(v for v, _ in comps)
    if total == 0.0:
        return 0.0, math.inf
    p = 0.5 + confidence / 2.0
    half = math.sqrt(sum(t_ppf(p, d) ** 2 * v for v, d in comps if v > 0))
    return math.sqrt(total), _effective_df(half / math.sqrt(total), p)


def _seed_only(parts: _Parts) -> tuple[float, float]:
    """SE and df over seeds only (the test frames taken as fixed)."""
    v = sum(v for v, _ in parts.seed)
    return (math.sqrt(v), satterthwaite_df(parts.seed)) if math.isfinite(v) else (math.nan, math.nan)


# ----------------------------------------------------------------------------- the result
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


#: The interval methods :func:`interval` knows (the module docstring compares their coverage).
METHODS: tuple[str, ...] = ("seed-cluster-t", "crossed-t", "crossed-t-conservative", "seed-t", "pigeonhole-bootstrap",
                            "hierarchical-bootstrap")


def interval(comp: Comparison, statistic: Statistic, contrast: Contrast, *, method: str = METHOD,
             confidence: float = CONFIDENCE, n_boot: int = N_BOOT, seed: int = BOOTSTRAP_SEED) -> IntervalResult:
    """The contrast of the models' values (each the mean over its seeds of ``statistic`` of a
    run's column means) and its ``confidence`` interval by ``method`` (:data:`METHODS`;
    ``n_boot``/``seed``: the bootstraps only). The interval is NaN where the design cannot
    give one (a trained group with one seed; one cluster)."""
    if method not in METHODS:
        raise ValueError(f"interval: method: expected one of {list(METHODS)}, got {method!r}")
    if method == "pigeonhole-bootstrap":
        return _pigeonhole(comp, statistic, contrast, n_boot, seed, confidence)
    if method == "hierarchical-bootstrap":
        b = bootstrap_contrast([list(g.runs.values()) for g in comp.groups], statistic, contrast, n_boot=n_boot,
                               seed=seed, confidence=confidence)
        return IntervalResult(b.estimate, b.ci_low, b.ci_high, math.nan, math.inf, method, comp.n_seeds,
                              tuple(g.fixed for g in comp.groups), comp.n_clusters, comp.n_frames, comp.paired,
                              confidence)
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


# ----------------------------------------------------------------------------- power and decidability
def mde(se: float, df: float, *, alpha: float = ALPHA, power: float = POWER) -> float:
    """The minimal detectable effect of a design: ``(t_{1-alpha/2, df} + t_{power, df}) * se``
    (a true difference this large is found with probability ``power`` by a two-sided level
    ``alpha`` t test; normal quantiles for df = inf); NaN if ``se`` or ``df`` is NaN."""
    if not (math.isfinite(se) and (math.isfinite(df) or df == math.inf)):
        return math.nan
    return (t_ppf(1.0 - alpha / 2.0, df) + t_ppf(power, df)) * se


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


def decidable(n_seeds: Sequence[int], fixed: Optional[Sequence[bool]] = None) -> bool:
    """Whether a comparison may get a verdict: every trained (non-fixed) group has at least
    :data:`MIN_SEEDS` seeds; a fixed (deterministic) group is exempt."""
    flags = list(fixed) if fixed is not None else [False] * len(n_seeds)
    return bool(n_seeds) and all(f or n >= MIN_SEEDS for n, f in zip(n_seeds, flags))


def comparison_verdict(res: IntervalResult, margin: Optional[float] = None) -> str:
    """:data:`NOT_DECIDABLE` below :data:`MIN_SEEDS` seeds, else :func:`verdict` of the interval."""
    return verdict(res.ci_low, res.ci_high, margin) if res.decidable else NOT_DECIDABLE


def undecidable_note(res: IntervalResult) -> str:
    """Why a comparison is not decidable, e.g. ``not decidable (1 vs 3 seeds)``; empty if it is."""
    if res.decidable:
        return ""
    seeds = " vs ".join("fixed" if f else str(n) for n, f in zip(res.n_seeds, res.fixed))
    return f"{NOT_DECIDABLE} ({seeds} seed{'' if seeds == '1' else 's'})"


# ----------------------------------------------------------------------------- coverage by simulation
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
    interval holds the true difference; ``n_boot``: replicates of a bootstrap method."""
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


# ----------------------------------------------------------------------------- the former percentile bootstrap
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
    fewer than ``min_seeds`` runs the interval is NaN (no verdict from so few trainings). The
    former method: :func:`seed_interval` is its t-based successor."""
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
