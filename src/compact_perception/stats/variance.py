"""The linearised contrast and its variance parts (the seeds x clusters random-effects model).

The contrast is linearised (delta method: the central-difference gradient of the statistic at
each run's column means and of the contrast at the models' values), which turns each block of
paired groups into a seeds x clusters table ``d[s, c]`` of contributions (from cluster c's column
means; cluster weights ``pi_c = n_c/N``). For the two-way random-effects model
``d = delta + A_s + B_c + E_sc``:

* ``V_seed``: the variance over seeds of the table's row means / S (df S - 1), per block;
  blocks of unpaired groups are independent, so theirs add (Welch-Satterthwaite df);
* ``V_cluster`` = ``K/(K-1) sum_c pi_c^2 (u_c - u)^2`` of the cluster column ``u_c`` (all groups,
  fixed ones too: the models share the frames; df K - 1);
* ``V_inter``: the weighted residual mean square of each table / (S K) (df (S-1)(K-1)); it
  estimates ``var(E)/(SK)``, which ``V_seed`` and ``V_cluster`` both hold.

The SE and df of each t method from those parts: :func:`_combined` (``seed-cluster-t``),
:func:`_crossed` (``crossed-t`` and its conservative form), :func:`_seed_only` (``seed-t``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from .comparison import Comparison, Contrast, Group, Statistic
from .distributions import normal_ppf, satterthwaite_df, t_cdf, t_ppf

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
