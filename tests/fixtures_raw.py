"""Fabricated raw records and datasets in the exact layout of docs/ARCHITECTURE.md (no world needed)."""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import yaml

from compact_perception.classes import BEV_NAMES, CARLA_NAMES, CARLA_PALETTE
from compact_perception.geometry import VIEWS
from compact_perception.io import write_json, write_npz


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


def make_authors_layout(root: Path, n: int = 5, s: int = 16) -> list[dict]:
    """Write ``n`` frames in the authors' released layout (float64 one-hot, BGR images,
    data_info.yml with a 3/1/1 split) under ``root``; returns the expected cache content."""
    rng = np.random.default_rng(0)
    truth = []
    for i in range(n):
        fid, stem = f"{i:04d}.png", f"{i:04d}"
        t: dict = {"ss": [], "rgb": []}
        for v in VIEWS:
            for sub in ("rgb", "dvs", "depth", "segmentation"):
                (root / f"{sub}_{v}").mkdir(parents=True, exist_ok=True)
            rgb = rng.integers(0, 256, (s, s, 3), dtype=np.uint8)
            cv2.imwrite(str(root / f"rgb_{v}" / fid), rgb[..., ::-1])  # stored BGR
            dvs = np.zeros((s, s, 3), np.uint8)
            dvs[1, 2] = (255, 0, 0)  # BGR blue: positive
            dvs[3, 4] = (0, 0, 255)  # BGR red: negative
            cv2.imwrite(str(root / f"dvs_{v}" / fid), dvs)
            cv2.imwrite(str(root / f"depth_{v}" / fid), np.full((s, s), 51, np.uint8))
            ss = rng.integers(0, 23, (s, s))
            oh = np.eye(23)[ss].transpose(2, 0, 1)  # float64 one-hot
            oh[:, 0, 0] = 0.0  # unlabeled pixel
            np.save(root / f"segmentation_{v}" / f"{stem}_128.npy", oh)
            ss = ss.astype(np.uint8)
            ss[0, 0] = 255
            t["ss"].append(ss)
            t["rgb"].append(rgb.transpose(2, 0, 1))
        for sub in ("lid_depth_top", "lid_seg_top", "bird_view"):
            (root / sub).mkdir(exist_ok=True)
        t["lidar"] = rng.random((15, s, s))
        np.save(root / "lid_depth_top" / f"{stem}_128.npy", t["lidar"])
        ls = rng.integers(0, 23, (s, s))
        ls_oh = np.eye(23)[ls]  # channels-last variant
        ls_oh[5:, :, :] = 0.0
        np.save(root / "lid_seg_top" / f"{stem}_128.npy", ls_oh)
        t["ls"] = np.where(np.arange(s)[:, None] < 5, ls, 255).astype(np.uint8)
        t["bev"] = rng.integers(0, 2, (9, s, s)).astype(np.float64)
        np.save(root / "bird_view" / f"{stem}_128.npy", t["bev"])
        truth.append(t)
    info = {"train_idx": [0, 1, 2], "val_idx": [3], "test_idx": [4], "n_total": 5, "n_seg_class": 23,
            "seg_classes": list(CARLA_NAMES), "seg_colors": CARLA_PALETTE.tolist(), "n_bird_class": 9,
            "bird_classes": list(BEV_NAMES), "bird_colors": [[0, 0, 0]] * 9}
    (root / "data_info.yml").write_text(yaml.safe_dump(info))
    return truth
