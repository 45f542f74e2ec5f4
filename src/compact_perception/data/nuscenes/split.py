"""Scene split 3:1:1 (paper section IV-B: 850 trainval scenes -> 510 / 170 / 170).

The split is by scene, so no scene (and no sample) is in two splits. It is a deterministic
function of the scene names and ``params.datasets.nuscenes.split_seed``: the names are sorted,
permuted with ``numpy.random.default_rng(seed)``, and cut into shares
``round(n * 3/5)``, ``round(n / 5)`` and the rest. Within a split, scenes keep sorted order.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

SPLITS: tuple[str, ...] = ("train", "val", "test")


def split_sizes(n: int, ratio: Sequence[int] = (3, 1, 1)) -> tuple[int, int, int]:
    """Sizes of train/val/test for ``n`` scenes at ``ratio`` (850 -> 510, 170, 170)."""
    if n < len(SPLITS):
        raise ValueError(f"need at least 3 scenes for a train/val/test split, got {n}")
    total = float(sum(ratio))
    n_train = int(round(n * ratio[0] / total))
    n_val = int(round(n * ratio[1] / total))
    n_train = min(max(n_train, 1), n - 2)
    n_val = min(max(n_val, 1), n - n_train - 1)
    return n_train, n_val, n - n_train - n_val


def split_scenes(names: Sequence[str], seed: int, ratio: Sequence[int] = (3, 1, 1)) -> dict[str, list[str]]:
    """Split scene names into ``{"train", "val", "test"}`` lists, deterministically from ``seed``."""
    uniq = sorted(set(names))
    if len(uniq) != len(names):
        raise ValueError("scene names must be unique")
    n_train, n_val, _ = split_sizes(len(uniq), ratio)
    perm = np.random.default_rng(seed).permutation(len(uniq))
    shuffled = [uniq[i] for i in perm]
    parts = (shuffled[:n_train], shuffled[n_train:n_train + n_val], shuffled[n_train + n_val:])
    return {name: sorted(part) for name, part in zip(SPLITS, parts)}
