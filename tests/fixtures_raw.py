"""Fabricated raw records and datasets in the exact layout of docs/data-formats.md (no world needed)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from compact_perception.core.classes import BEV_NAMES, CARLA_NAMES, CARLA_PALETTE
from compact_perception.data.geometry import VIEWS
from compact_perception.core.io import write_json, write_npz


def make_record(size: int = 16, seed: int = 0, n_points: int = 300, n_events: int = 50) -> dict[str, np.ndarray]:
    """One raw record (all keys of the ARCHITECTURE table) with random but valid content."""
    rng = np.random.default_rng(seed)
    rec: dict[str, np.ndarray] = {}
    for v in VIEWS:
        rec[f"rgb_{v}"] = rng.integers(0, 256, (size, size, 3), dtype=np.uint8)
        rec[f"sem_{v}"] = CARLA_PALETTE[rng.integers(0, len(CARLA_PALETTE), (size, size))]
        rec[f"depth_{v}"] = rng.integers(0, 65536, (size, size), dtype=np.uint16)
        ev = np.stack(
            [
                np.sort(rng.integers(0, 100_000, n_events)),
                rng.integers(0, size, n_events),
                rng.integers(0, size, n_events),
                rng.choice([-1, 1], n_events),
            ],
            axis=1,
        ).astype(np.int64)
        rec[f"dvs_{v}"] = ev
    pts = np.stack(
        [
            rng.uniform(-35, 35, n_points),
            rng.uniform(-35, 35, n_points),
            rng.uniform(-2.5, 8, n_points),
            rng.uniform(0, 1, n_points),
        ],
        axis=1,
    ).astype(np.float32)
    rec["lidar"] = pts
    rec["lidar_tag"] = rng.integers(0, len(CARLA_NAMES), n_points).astype(np.uint8)
    rec["bev"] = rng.integers(0, 2, (len(BEV_NAMES), size, size), dtype=np.uint8)
    rec["boxes"] = np.zeros((0, 8), dtype=np.float32)
    rec["ego_pose"] = np.zeros(3, dtype=np.float64)
    return rec


def make_raw_dataset(
    root: Path, size: int = 16, n_frames: int = 5, dataset: str = "A", manifest: bool = True
) -> tuple[Path, dict[str, list[str]]]:
    """Write ``root/frames/*.npz`` (+ manifest.json) with a 3:1:1 split; returns (root, splits)."""
    root = Path(root)
    ids = [f"{dataset}_{i:05d}" for i in range(n_frames)]
    n_train = max(1, n_frames * 3 // 5)
    n_val = max(1, (n_frames - n_train) // 2)
    splits = {"train": ids[:n_train], "val": ids[n_train:n_train + n_val], "test": ids[n_train + n_val:]}
    for i, fid in enumerate(ids):
        write_npz(root / "frames" / f"{fid}.npz", make_record(size, seed=i))
    if manifest:
        write_json(
            root / "manifest.json",
            {
                "dataset": dataset,
                "source": "sim",
                "resolution": size,
                "views": list(VIEWS),
                "splits": splits,
                "frames": {fid: {"town": "town01", "episode": 0, "step": i, "time_of_day": "noon", "weather": {}} for i, fid in enumerate(ids)},
                "seg_classes": list(CARLA_NAMES),
                "bev_classes": list(BEV_NAMES),
                "params": {},
            },
        )
    return root, splits


def read_manifest(root: Path) -> dict:
    return json.loads((Path(root) / "manifest.json").read_text())
