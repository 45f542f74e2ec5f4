"""Synthetic model-ready caches for training/evaluation tests (layout: docs/data-formats.md)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from compact_perception.core.cache import write_cache
from compact_perception.core.classes import BEV_NAMES, CARLA_NAMES, NUSCENES_NAMES
from compact_perception.data.geometry import VIEWS


def synthetic_frame(rng: np.random.Generator, size: int, n_cls: int, n_bev: int, dvs: bool) -> dict:
    """One learnable frame: class maps follow simple image structure so a model can fit them."""
    ss = rng.integers(0, n_cls, (len(VIEWS), size, size), dtype=np.uint8)
    rgb = np.stack([(ss.astype(np.int32) * 11 % 256).astype(np.uint8)] * 3, axis=1)
    frame = {
        "rgb": rgb,
        "lidar": rng.random((15, size, size)).astype(np.float16),
        "de": rng.random((len(VIEWS), 1, size, size)).astype(np.float16),
        "ss": ss,
        "ls": np.where(rng.random((size, size)) < 0.2, 255, rng.integers(0, n_cls, (size, size))).astype(np.uint8),
        "bevp": (rng.random((n_bev, size, size)) < 0.3).astype(np.uint8),
    }
    if dvs:
        frame["dvs"] = (rng.random((len(VIEWS), 2, size, size)) < 0.1).astype(np.uint8)
    return frame


def make_cache(out: Path, dataset: str = "A", size: int = 32, counts=(6, 3, 3), seed: int = 0) -> Path:
    nus = dataset == "nuscenes"
    seg = NUSCENES_NAMES if nus else CARLA_NAMES
    bev = NUSCENES_NAMES if nus else BEV_NAMES
    rng = np.random.default_rng(seed)
    splits = {
        name: [synthetic_frame(rng, size, len(seg), len(bev), not nus) for _ in range(n)]
        for name, n in zip(("train", "val", "test"), counts)
    }
    meta = {"dataset": dataset, "source": "synthetic test cache", "seg_classes": list(seg),
            "bev_classes": list(bev), "has_dvs": not nus, "resolution": size, "views": list(VIEWS)}
    write_cache(out, splits, meta)
    return out
