"""The data of one comparison: per model a :class:`Group` of runs keyed by training seed, each a
(frames, columns) array of per-frame scores on the same frames in the same order, and one cluster
label per frame (the episode of sets A/B/C, the scene of nuScenes: consecutive frames are not
independent), validated into a :class:`Comparison` by :func:`make_comparison`; and the statistics
of a run's column means (mean, TM of eq. 6, MV of eq. 7) that a comparison contrasts.

Groups trained at the same set of seeds are *paired* (a seed fixes the initial weights and the
batch order: common random numbers); groups with different seed sets are independent of each
other; a ``fixed`` group (a deterministic predictor, the trivial floor) has one run and no
training randomness.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Mapping, Optional, Sequence, Union

import numpy as np

from ..core import catalog

__all__ = ["Statistic", "Contrast", "stat_mean", "score_stat", "stat_tm", "stat_mv", "STATISTICS", "Group",
           "Comparison", "GroupLike", "make_comparison"]

#: (..., n_cols) column means -> (...) statistic.
Statistic = Callable[[np.ndarray], np.ndarray]
#: (..., n_groups) per-model statistics -> (...) contrast (positive = the claim holds).
Contrast = Callable[[np.ndarray], np.ndarray]


def stat_mean(m: np.ndarray) -> np.ndarray:
    """The mean of a one-column score (``m[..., 0]``)."""
    return np.asarray(m)[..., 0]


def score_stat(key: str) -> Statistic:
    """The statistic of the score ``key`` of :data:`compact_perception.core.catalog.SCORES` (TM,
    eq. 6; MV, eq. 7): its formula (``of_terms``) of the means of columns (mae_de, iou_ss,
    iou_ls, iou_bevp)."""
    of_terms = catalog.SCORES[key].of_terms

    def stat(m: np.ndarray) -> np.ndarray:
        m = np.asarray(m)
        return of_terms(*(m[..., i] for i in range(len(catalog.metric_keys()))))

    stat.__name__ = stat.__qualname__ = f"stat_{key}"
    return stat


STATISTICS: dict[str, Statistic] = {"mean": stat_mean, **{k: score_stat(k) for k in catalog.SCORES.keys()}}
#: TM (eq. 6) and MV (eq. 7) of the means of columns (mae_de, iou_ss, iou_ls, iou_bevp).
stat_tm, stat_mv = STATISTICS["tm"], STATISTICS["mv"]


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
