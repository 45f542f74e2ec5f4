"""A small copy of the authors' released CARLA dataset, in exactly the release's layout.

Written from the layout as the authors' public scripts read it (train.py, predict.py,
mylib/util.py of github.com/oskarnatan/compact-perception), not from the project's reader::

    dataset/TrSet|VaSet|TeSet/<modality>/<id>             frames (128 x 128)
    dataset/{Tr,Va,Te}{1,2,12345}/data_info.yml           split lists

Modalities per frame ``<id>`` (``<stem>`` = id without its 4-character extension):
``rgb_{f,l,ri,r}/<id>`` BGR PNG; ``dvs_{f,l,ri,r}/<id>`` PNG with positive events blue and
negative events red (255), green 0; ``depth_{f,l,ri,r}/<id>`` 8-bit grayscale PNG;
``lid_depth_top/<id>`` 8-bit grayscale PNG (1-layer LiDAR); ``lid_depth_top/<stem>_128.npy``
(15, 128, 128) float64 whose channel 14 is that PNG / 255; ``segmentation_{f,l,ri,r}`` and
``lid_seg_top`` ``<stem>_128.npy`` (23, 128, 128) float64 one-hot (a few all-zero pixels);
``bird_view/<stem>_128.npy`` (9, 128, 128) float64 0/1.

Each frame folder holds frames of several towns; ``Tr1`` lists the town-1 frames of TrSet,
``Tr2`` the town-2 ones, ``Tr12345`` all of them (likewise Va, Te). Train folders fill
``train_idx``, validation folders ``val_idx``, test folders ``test_idx`` (listed in reverse
order, since predict.py sorts); the other two keys are null.

:func:`frame_content` regenerates a frame's arrays from its folder and id, so tests can
compare without keeping them in memory. :func:`link_copy` makes a cheap hard-linked copy to
damage; :func:`replace` rewrites one file of such a copy without touching the original.
"""
from __future__ import annotations

import os
import shutil
import zlib
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
import yaml

S = 128
VIEWS = ("f", "l", "ri", "r")
SEG_CLASSES = ["unlabeled", "building", "fence", "other", "pedestrian", "pole", "road line", "road", "sidewalk",
               "vegetation", "vehicle", "wall", "traffic sign", "sky", "ground", "bridge", "rail track",
               "guard rail", "traffic light", "static", "dynamic", "water", "terrain"]
SEG_COLORS = [[0, 0, 0], [70, 70, 70], [100, 40, 40], [55, 90, 80], [220, 20, 60], [153, 153, 153],
              [157, 234, 50], [128, 64, 128], [244, 35, 232], [107, 142, 35], [0, 0, 142], [102, 102, 156],
              [220, 220, 0], [70, 130, 180], [81, 0, 81], [150, 100, 100], [230, 150, 140], [180, 165, 180],
              [250, 170, 30], [110, 190, 160], [170, 120, 50], [45, 60, 150], [145, 170, 100]]
BIRD_CLASSES = ["road", "road lane", "road centreline", "other vehicles", "ego vehicle", "green traffic light",
                "yellow traffic light", "red traffic light", "pedestrian"]
BIRD_COLORS = [[128, 64, 128], [157, 234, 50], [255, 255, 255], [0, 0, 142], [255, 0, 0], [0, 255, 0],
               [255, 255, 0], [255, 0, 0], [220, 20, 60]]
#: frames per town in each frame folder
TOWN_FRAMES: dict[str, dict[int, int]] = {
    "TrSet": {1: 2, 2: 1, 3: 1},
    "VaSet": {1: 1, 2: 1},
    "TeSet": {1: 1, 2: 1, 5: 1},
}
SPLIT_FOLDERS = ("Tr1", "Tr2", "Tr12345", "Va1", "Va2", "Va12345", "Te1", "Te2", "Te12345")
LIST_KEY = {"Tr": "train_idx", "Va": "val_idx", "Te": "test_idx"}


def frame_ids(frame_folder: str) -> dict[str, int]:
    """id -> town of a frame folder's frames (ids numbered within the folder)."""
    out, n = {}, 0
    for town, count in TOWN_FRAMES[frame_folder].items():
        for _ in range(count):
            out[f"{n:04d}.png"] = town
            n += 1
    return out


def split_list(folder: str) -> list[str]:
    """The frame ids a split folder lists (in the order written)."""
    towns = {int(c) for c in folder[2:]}
    ids = [fid for fid, town in frame_ids(f"{folder[:2]}Set").items() if town in towns]
    return ids[::-1] if folder.startswith("Te") else ids


def frame_content(frame_folder: str, frame_id: str) -> dict[str, np.ndarray]:
    """The arrays of one frame, as written (images in file order: BGR, H x W)."""
    rng = np.random.default_rng(zlib.crc32(f"{frame_folder}/{frame_id}".encode()))
    c: dict[str, np.ndarray] = {}
    c["bgr"] = rng.integers(0, 256, (4, S, S, 3), dtype=np.uint8)
    dvs = np.zeros((4, S, S, 3), np.uint8)
    dvs[..., 0] = np.where(rng.random((4, S, S)) < 0.03, 255, 0)  # blue: positive events
    dvs[..., 2] = np.where(rng.random((4, S, S)) < 0.03, 255, 0)  # red: negative events
    c["dvs_bgr"] = dvs
    c["depth"] = rng.integers(0, 256, (4, S, S), dtype=np.uint8)
    c["ss"] = rng.integers(0, 23, (4, S, S)).astype(np.uint8)
    c["ss"][:, :3, :3] = 255  # no class (all-zero one-hot)
    c["lid1"] = rng.integers(0, 256, (S, S), dtype=np.uint8)
    lid = rng.random((15, S, S))
    lid[14] = c["lid1"] / 255.0
    c["lid15"] = lid
    c["ls"] = rng.integers(0, 23, (S, S)).astype(np.uint8)
    c["ls"][rng.random((S, S)) < 0.5] = 255  # cells without a LiDAR point
    c["bev"] = (rng.random((9, S, S)) < 0.3).astype(np.float64)
    return c


def one_hot(index: np.ndarray, n: int = 23) -> np.ndarray:
    """uint8 (H, W) class index (255 = none) -> float64 (n, H, W) one-hot."""
    out = np.zeros((n,) + index.shape, np.float64)
    hit = index != 255
    out[index[hit].astype(np.int64), np.nonzero(hit)[0], np.nonzero(hit)[1]] = 1.0
    return out


def write_frame(frame_dir: Path, frame_id: str, c: dict[str, np.ndarray]) -> None:
    stem = frame_id[:-4]
    for n, v in enumerate(VIEWS):
        cv2.imwrite(str(frame_dir / f"rgb_{v}" / frame_id), c["bgr"][n])
        cv2.imwrite(str(frame_dir / f"dvs_{v}" / frame_id), c["dvs_bgr"][n])
        cv2.imwrite(str(frame_dir / f"depth_{v}" / frame_id), c["depth"][n])
        np.save(frame_dir / f"segmentation_{v}" / f"{stem}_128.npy", one_hot(c["ss"][n]))
    cv2.imwrite(str(frame_dir / "lid_depth_top" / frame_id), c["lid1"])
    np.save(frame_dir / "lid_depth_top" / f"{stem}_128.npy", c["lid15"])
    np.save(frame_dir / "lid_seg_top" / f"{stem}_128.npy", one_hot(c["ls"]))
    np.save(frame_dir / "bird_view" / f"{stem}_128.npy", c["bev"])


def data_info(folder: str) -> dict:
    """The data_info.yml content of a split folder."""
    ids = split_list(folder)
    info = {"train_idx": None, "val_idx": None, "test_idx": None}
    info[LIST_KEY[folder[:2]]] = ids
    info.update({"n_total": len(ids), "n_seg_class": 23, "seg_classes": SEG_CLASSES, "seg_colors": SEG_COLORS,
                 "n_bird_class": 9, "bird_classes": BIRD_CLASSES, "bird_colors": BIRD_COLORS})
    return info


def build_release(base: Path) -> Path:
    """Write the release under ``base/dataset``; returns that folder (the ``authors_root``)."""
    root = Path(base) / "dataset"
    subs = [f"{m}_{v}" for m in ("rgb", "dvs", "depth", "segmentation") for v in VIEWS]
    subs += ["lid_depth_top", "lid_seg_top", "bird_view"]
    for frame_folder in TOWN_FRAMES:
        for sub in subs:
            (root / frame_folder / sub).mkdir(parents=True)
        for fid in frame_ids(frame_folder):
            write_frame(root / frame_folder, fid, frame_content(frame_folder, fid))
    for folder in SPLIT_FOLDERS:
        (root / folder).mkdir()
        (root / folder / "data_info.yml").write_text(yaml.dump(data_info(folder), default_flow_style=None))
    return root


def link_copy(src: Path, dst: Path) -> Path:
    """A copy of the tree ``src`` at ``dst`` made of hard links (falls back to copying)."""
    def link(a: str, b: str) -> None:
        try:
            os.link(a, b)
        except OSError:
            shutil.copy2(a, b)

    shutil.copytree(src, dst, copy_function=link)
    return dst


def replace(path: Path, write: Callable[[Path], object]) -> None:
    """Rewrite ``path`` of a :func:`link_copy` (unlinks first, so the original is untouched)."""
    path.unlink()
    write(path)


def set_info(root: Path, folder: str, **changes: object) -> Path:
    """Rewrite ``<root>/<folder>/data_info.yml`` with ``changes`` applied; returns its path."""
    info = data_info(folder)
    info.update(changes)
    path = root / folder / "data_info.yml"
    replace(path, lambda p: p.write_text(yaml.dump(info, default_flow_style=None)))
    return path
