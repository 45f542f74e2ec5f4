"""Ingest the authors' released dataset (SPEC 3.2; BASELINES.md "authors' released dataset layout").

Accepted layout (``authors_root``)::

    <root>/data_info.yml          train_idx, val_idx, test_idx, seg_classes, seg_colors,
                                  bird_classes, bird_colors (n_* keys optional)
    <root>/[TrSet|VaSet|TeSet]/   optional per-split folders; without them every split
                                  indexes the folders directly under <root>
        rgb_{f,l,ri,r}/<id>       colour image (cv2 reads BGR; converted to RGB)
        dvs_{f,l,ri,r}/<id>       CARLA DVS colour image: blue = positive, red = negative
        depth_{f,l,ri,r}/<id>     grayscale depth, /255
        lid_depth_top/<stem>_128.npy    15-channel LiDAR tensor (C,S,S) or (S,S,C)
        segmentation_{f,l,ri,r}/<stem>_128.npy  one-hot float64 (23 classes)
        lid_seg_top/<stem>_128.npy      one-hot float64 (23)
        bird_view/<stem>_128.npy        multi-label float64 (9)

``<id>`` is a file name with a 4-character extension, ``<stem>`` the id without it. The
frames of a split are the sorted ids of its ``rgb_f`` folder; ``<split>_idx`` entries
are positions in that list (ints) or ids (strings); ``None`` means all of them.

Conversion to the cache's frame dict (same keys and dtypes as
:mod:`compact_perception.preprocess`): one-hot maps -> argmax class index with all-zero
pixels -> 255; BEV -> uint8 masks (> 0.5); LiDAR and depth -> float16.
"""
from __future__ import annotations

import logging
import multiprocessing as mp
import os
from pathlib import Path
from typing import Any, Iterator, Sequence

import cv2
import numpy as np
import yaml
from tqdm import tqdm

from .cache import write_cache
from .dvs import dvs_colour_to_image
from .geometry import VIEWS
from .preprocess import RecordError

log = logging.getLogger(__name__)

SPLIT_DIRS = {"train": "TrSet", "val": "VaSet", "test": "TeSet"}
SPLIT_IDX = {"train": "train_idx", "val": "val_idx", "test": "test_idx"}


def read_data_info(root: str | os.PathLike) -> dict[str, Any]:
    """Read and check ``data_info.yml``."""
    path = Path(root) / "data_info.yml"
    if not path.is_file():
        raise RecordError(f"{root}: authors' dataset incomplete (no data_info.yml)")
    try:
        info = yaml.safe_load(path.read_text())
    except yaml.YAMLError as err:
        raise RecordError(f"{path}: not valid YAML: {err}") from None
    if not isinstance(info, dict):
        raise RecordError(f"{path}: expected a mapping")
    for key in ("seg_classes", "bird_classes", *SPLIT_IDX.values()):
        if key not in info:
            raise RecordError(f"{path}: missing key {key!r}")
    return info


def _one_hot_file(path: Path, n_classes: int, size: int | None, frame_id: str) -> np.ndarray:
    """Load a float one-hot .npy as (C, S, S) float array."""
    if not path.is_file():
        raise RecordError(f"frame {frame_id}: {path}: file not found")
    try:
        a = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as err:
        raise RecordError(f"frame {frame_id}: {path}: corrupt or truncated npy ({err})") from None
    if a.ndim == 3 and a.shape[0] == n_classes:
        pass
    elif a.ndim == 3 and a.shape[-1] == n_classes:
        a = a.transpose(2, 0, 1)
    else:
        raise RecordError(f"frame {frame_id}: {path}: shape {a.shape}, expected {n_classes} channels")
    if size is not None and a.shape[1:] != (size, size):
        raise RecordError(f"frame {frame_id}: {path}: spatial shape {a.shape[1:]}, expected ({size}, {size})")
    return a


def one_hot_to_index(onehot: np.ndarray) -> np.ndarray:
    """(C, H, W) one-hot -> uint8 (H, W) class index (argmax); all-zero pixels -> 255."""
    idx = np.argmax(onehot, axis=0).astype(np.uint8)
    idx[~(onehot > 0).any(axis=0)] = 255
    return idx


def _imread(path: Path, flags: int, frame_id: str) -> np.ndarray:
    if not path.is_file():
        raise RecordError(f"frame {frame_id}: {path}: file not found")
    img = cv2.imread(str(path), flags)
    if img is None:
        raise RecordError(f"frame {frame_id}: {path}: cannot decode image")
    return img


def convert_frame(split_dir: str | os.PathLike, frame_id: str, n_seg: int, n_bev: int, views: Sequence[str] = VIEWS) -> dict[str, Any]:
    """One authors' frame -> the cache's frame dict (``frame_id`` = the image file name)."""
    d = Path(split_dir)
    stem = frame_id[:-4]
    rgb, dvs, de, ss = [], [], [], []
    size: int | None = None
    for v in views:
        bgr = _imread(d / f"rgb_{v}" / frame_id, cv2.IMREAD_COLOR, frame_id)
        if size is None:
            size = bgr.shape[0]
        if bgr.shape[:2] != (size, size):
            raise RecordError(f"frame {frame_id}: {d / f'rgb_{v}' / frame_id}: shape {bgr.shape[:2]}, expected ({size}, {size})")
        rgb.append(bgr[..., ::-1].transpose(2, 0, 1))
        dvs_img = _imread(d / f"dvs_{v}" / frame_id, cv2.IMREAD_COLOR, frame_id)
        dvs.append(dvs_colour_to_image(dvs_img, name=f"frame {frame_id}: dvs_{v}"))
        dep = _imread(d / f"depth_{v}" / frame_id, cv2.IMREAD_GRAYSCALE, frame_id)
        de.append((dep.astype(np.float32) / 255.0)[None])
        ss.append(one_hot_to_index(_one_hot_file(d / f"segmentation_{v}" / f"{stem}_128.npy", n_seg, size, frame_id)))
    lidar = _one_hot_file(d / "lid_depth_top" / f"{stem}_128.npy", 15, size, frame_id)
    ls = one_hot_to_index(_one_hot_file(d / "lid_seg_top" / f"{stem}_128.npy", n_seg, size, frame_id))
    bev = _one_hot_file(d / "bird_view" / f"{stem}_128.npy", n_bev, size, frame_id)
    for name, arr in (("rgb", rgb), ("dvs", dvs), ("de", de)):
        shapes = {a.shape for a in arr}
        if len(shapes) != 1:
            raise RecordError(f"frame {frame_id}: {d}: {name} views differ in shape {sorted(shapes)}")
    return {
        "frame_id": frame_id,
        "rgb": np.ascontiguousarray(np.stack(rgb)).astype(np.uint8),
        "dvs": np.stack(dvs).astype(np.uint8),
        "lidar": lidar.astype(np.float16),
        "de": np.stack(de).astype(np.float16),
        "ss": np.stack(ss),
        "ls": ls,
        "bevp": (bev > 0.5).astype(np.uint8),
    }


def split_frame_ids(root: str | os.PathLike, info: dict[str, Any], split: str) -> tuple[Path, list[str]]:
    """(folder, ids) of one split from ``data_info.yml`` (see the module docstring)."""
    root = Path(root)
    split_dir = root / SPLIT_DIRS[split]
    if not split_dir.is_dir():
        split_dir = root
    rgb_dir = split_dir / "rgb_f"
    if not rgb_dir.is_dir():
        raise RecordError(f"{rgb_dir}: folder not found (authors' layout)")
    all_ids = sorted(p.name for p in rgb_dir.iterdir() if p.is_file())
    sel = info.get(SPLIT_IDX[split])
    if sel is None:
        ids = all_ids
    else:
        ids = []
        for s in sel:
            if isinstance(s, str):
                if s not in all_ids:
                    raise RecordError(f"{root / 'data_info.yml'}: {SPLIT_IDX[split]} names {s!r}, not in {rgb_dir}")
                ids.append(s)
            else:
                if not 0 <= int(s) < len(all_ids):
                    raise RecordError(f"{root / 'data_info.yml'}: {SPLIT_IDX[split]} index {s} outside 0..{len(all_ids) - 1} ({rgb_dir})")
                ids.append(all_ids[int(s)])
    if not ids:
        raise RecordError(f"{root / 'data_info.yml'}: split {split!r} is empty")
    return split_dir, ids


def _convert_task(task: tuple[str, str, int, int]) -> dict[str, Any]:
    return convert_frame(*task)


def _iter_split(tasks: list[tuple[str, str, int, int]], pool: Any | None, desc: str) -> Iterator[dict[str, Any]]:
    it = pool.imap(_convert_task, tasks, chunksize=4) if pool is not None else map(_convert_task, tasks)
    yield from tqdm(it, total=len(tasks), desc=desc, leave=False)


def ingest_authors(root: str | os.PathLike | None, out_dir: str | os.PathLike, dataset_id: str, workers: int = 1) -> Path:
    """Convert the authors' dataset at ``root`` into the cache at ``out_dir`` (atomic)."""
    if root is None or not Path(root).is_dir():
        raise RecordError(f"dataset {dataset_id}: authors_root {root!r} is not a directory")
    info = read_data_info(root)
    n_seg, n_bev = len(info["seg_classes"]), len(info["bird_classes"])
    tasks = {}
    for split in SPLIT_DIRS:
        split_dir, ids = split_frame_ids(root, info, split)
        tasks[split] = [(str(split_dir), fid, n_seg, n_bev) for fid in ids]
    meta = {
        "dataset": dataset_id,
        "source": "authors",
        "seg_classes": list(info["seg_classes"]),
        "bev_classes": list(info["bird_classes"]),
        "seg_colors": info.get("seg_colors"),
        "bev_colors": info.get("bird_colors"),
        "has_dvs": True,
        "resolution": None,
        "views": list(VIEWS),
    }
    first = convert_frame(*tasks["train"][0])
    meta["resolution"] = int(first["rgb"].shape[-1])
    if workers > 1:
        with mp.get_context("fork").Pool(workers) as pool:
            return write_cache(out_dir, {s: _iter_split(t, pool, f"{dataset_id} {s}") for s, t in tasks.items()}, meta)
    return write_cache(out_dir, {s: _iter_split(t, None, f"{dataset_id} {s}") for s, t in tasks.items()}, meta)


def describe_authors_dataset(root: str | os.PathLike | None, dataset_id: str, out_dir: str | os.PathLike,
                             figure_path: str | os.PathLike) -> Path:
    """The ``generate`` stage for ``source: authors``: nothing is rendered, so it writes a
    manifest that points at ``root`` (with the split sizes of ``data_info.yml``) and a
    Fig. 1-like figure of the first test frame, read through :func:`convert_frame`."""
    from . import io
    from .report.figures import plot_qualitative

    if root is None or not Path(root).is_dir():
        raise RecordError(f"datasets.{dataset_id}.authors_root: {root!r} is not a directory")
    info = read_data_info(root)
    n_seg, n_bev = len(info["seg_classes"]), len(info["bird_classes"])
    splits = {split: split_frame_ids(root, info, split)[1] for split in SPLIT_DIRS}
    test_dir, test_ids = split_frame_ids(root, info, "test")
    frame = convert_frame(test_dir, test_ids[0], n_seg, n_bev)
    inputs = {k: np.asarray(frame[k])[None] for k in ("rgb", "dvs", "lidar")}
    inputs.update({f"gt_{k}": np.asarray(frame[k])[None] for k in ("de", "ss", "ls", "bevp")})
    inputs["frame_ids"] = np.array([test_ids[0]])
    plot_qualitative(dataset_id, inputs, {}, Path(figure_path), frame=0, models=[],
                     title=f"dataset {dataset_id}: authors' CARLA data, test frame {test_ids[0]}")
    with io.atomic_dir(out_dir) as tmp:
        io.write_json(tmp / "manifest.json", {
            "dataset": dataset_id, "source": "authors", "authors_root": str(Path(root).resolve()),
            "splits": splits, "seg_classes": list(info["seg_classes"]), "bev_classes": list(info["bird_classes"]),
        })
    return Path(out_dir)
