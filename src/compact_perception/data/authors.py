"""Ingest the authors' released CARLA dataset, read as released (SPEC 3.2; BASELINES.md).

Layout (read from the authors' public ``train.py``, ``predict.py`` and ``mylib/util.py``)::

    <root>/                              the release's ``dataset/`` folder
        TrSet/ VaSet/ TeSet/             frame folders, one sub-folder per modality
        Tr1/ Tr2/ Tr12345/ Va1/ Va2/ Va12345/ Te1/ Te2/ Te12345/
            data_info.yml                split list: train_idx, val_idx, test_idx (list or
                                         null), n_total, n_seg_class, seg_classes, seg_colors,
                                         n_bird_class, bird_classes, bird_colors

A split folder's first two letters name its frame folder (``Tr1`` -> ``TrSet``).
``datasets.<ds>.source.splits`` names the three split folders (the paper: A Tr1/Va2/Te2,
B Tr2/Va1/Te1, C Tr12345/Va12345/Te12345, as in the authors' scripts). Which list of a
split's ``data_info.yml`` is used follows the authors' code exactly:

- train: ``train_idx``, else ``val_idx``, else ``test_idx`` (``train.py``);
- val: ``val_idx``, else ``test_idx``, else ``train_idx`` (``train.py``);
- test: ``test_idx`` only, sorted (``predict.py`` has no fall-back and sorts the list).

"Else" means the key is null, as in the authors' ``!= None`` tests. The entries are frame
file names (``<id>``, e.g. ``0042.png``: a 4-character extension; ``<stem>`` = the id
without it), which the authors' loader appends to each modality folder. An empty list, a
list that is not a list of such names, a missing ``data_info.yml``, two splits sharing a
frame folder and a frame, or any missing or malformed frame file is a
:class:`~compact_perception.core.errors.RecordError` whose one-line message names the file;
there is no "every frame in the folder" fall-back.

Per frame ``<id>`` of a frame folder (the release is 128 x 128 px)::

    rgb_{f,l,ri,r}/<id>                  colour PNG, BGR as cv2 reads it
    dvs_{f,l,ri,r}/<id>                  CARLA DVS colour PNG: B = positive, R = negative, G unused
    depth_{f,l,ri,r}/<id>                single-channel 8-bit PNG, /255
    lid_depth_top/<id>                   single-channel 8-bit PNG, /255: the 1-layer LiDAR input
    lid_depth_top/<stem>_128.npy         (15, 128, 128): the 15-layer LiDAR input
    segmentation_{f,l,ri,r}/<stem>_128.npy   (n_seg, 128, 128) one-hot
    lid_seg_top/<stem>_128.npy           (n_seg, 128, 128) one-hot
    bird_view/<stem>_128.npy             (n_bird, 128, 128) multi-label

(The authors read the grayscale PNGs with flag ``cv2.COLOR_BGR2GRAY`` = 6, which as an imread
flag is ``IMREAD_ANYDEPTH | IMREAD_ANYCOLOR``: the file as stored, so their code only works
with single-channel PNGs; that is what is required here, and 8-bit, since they divide by 255.)

Conversion to the cache's frame dict (keys and dtypes of :mod:`compact_perception.data.preprocess`):
``rgb`` BGR -> RGB uint8 (the project's convention); ``dvs`` B, R > 0 -> channels 0, 1 of
eq. (1) (CARLA draws events at 255, so this is the authors' /255); ``de`` PNG/255 float16;
``ss``, ``ls`` one-hot -> argmax class index, all-zero pixels -> 255; ``bevp`` > 0.5 -> uint8
masks; ``lidar`` the 15-layer npy as float16, **with channel 14 replaced by
``lid_depth_top/<id>``/255**. The project's 1L model reads channel 14 of the cache
(:class:`compact_perception.data.loader.CacheDataset`), and the authors' 1L model reads that PNG, so
this choice gives the 1L model exactly the authors' 1L input; the 15L models see the PNG in
channel 14 instead of the npy's channel 14. Both come from the same top view in the release;
the ingest logs the largest difference it found between them, so a release where they differ
shows it.

Resolution: the release is 128 px. At another ``world.resolution`` (at ``params.scale``)
every kind is resized: area averaging (cv2 ``INTER_AREA``) for RGB, depth and the LiDAR
layers; nearest pixel centre for the class maps (``ss``, ``ls``) and the BEV masks; DVS
events keep eq. (1)'s "at least one event in the pixel" (area, then > 0) when shrinking and
nearest when enlarging. The cache's ``meta.json`` records ``source_resolution`` and the rule.

Every file of every selected frame is checked (present, PNG size/channels/bit depth, npy
shape/dtype/length from the headers) in the worker pool before anything is written; the
cache is then built atomically, so a decoding error found later leaves nothing behind either.
"""
from __future__ import annotations

import contextlib
import json
import logging
import multiprocessing as mp
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, Mapping, Sequence

import cv2
import numpy as np
import yaml
from PIL import Image, UnidentifiedImageError
from tqdm import tqdm

from ..core.cache import write_cache
from .dvs import dvs_colour_to_image
from ..core.errors import RecordError
from ..core.machine import bounded
from .geometry import VIEWS

log = logging.getLogger(__name__)

SOURCE_SIZE = 128  #: the release's resolution (and the ``_128`` of its npy names)
N_LIDAR = 15
SPLITS: tuple[str, ...] = ("train", "val", "test")
#: which list of a split's data_info.yml is used, first non-null wins (train.py, predict.py)
LIST_KEYS: dict[str, tuple[str, ...]] = {
    "train": ("train_idx", "val_idx", "test_idx"),
    "val": ("val_idx", "test_idx", "train_idx"),
    "test": ("test_idx",),
}
INFO_KEYS: tuple[str, ...] = ("train_idx", "val_idx", "test_idx", "seg_classes", "bird_classes")
RESIZE_RULE = ("area (cv2 INTER_AREA): rgb, de, lidar; nearest pixel centre: ss, ls, bevp; "
               "dvs: any event in the area when shrinking, nearest when enlarging")


# ----------------------------------------------------------------------------- split lists
class _InfoLoader(yaml.SafeLoader):
    """Safe YAML loader that also accepts PyYAML's ``!!python/tuple`` (read as a list)."""


_InfoLoader.add_constructor("tag:yaml.org,2002:python/tuple", lambda loader, node: loader.construct_sequence(node))


def _one_line(err: BaseException) -> str:
    text = str(err).strip().splitlines()
    return text[0] if text else type(err).__name__


@dataclass(frozen=True)
class SplitPlan:
    """One split as the authors' scripts select it."""

    split: str
    folder: str  # e.g. "Tr1"
    info_file: Path  # <root>/<folder>/data_info.yml
    key: str  # the data_info.yml key whose list is used
    frame_dir: Path  # <root>/<folder[:2]>Set
    ids: tuple[str, ...]


@dataclass(frozen=True)
class AuthorsPlan:
    """The three splits plus the class lists of the release."""

    root: Path
    splits: dict[str, SplitPlan]
    seg_classes: list[str]
    bev_classes: list[str]
    seg_colors: Any
    bev_colors: Any

    @property
    def n_seg(self) -> int:
        return len(self.seg_classes)

    @property
    def n_bev(self) -> int:
        return len(self.bev_classes)


def read_data_info(path: str | os.PathLike, what: str = "") -> dict[str, Any]:
    """Read and check one ``<split folder>/data_info.yml``; ``what`` names the param it serves."""
    path = Path(path)
    hint = f" ({what})" if what else ""
    if not path.is_file():
        raise RecordError(f"{path}: file not found; expected the split list data_info.yml{hint}")
    try:
        info = yaml.load(path.read_text(), Loader=_InfoLoader)
    except (yaml.YAMLError, UnicodeDecodeError) as err:
        raise RecordError(f"{path}: not valid YAML ({_one_line(err)})") from None
    if not isinstance(info, dict):
        raise RecordError(f"{path}: expected a mapping with keys {', '.join(INFO_KEYS)}")
    missing = [k for k in INFO_KEYS if k not in info]
    if missing:
        raise RecordError(f"{path}: missing key(s) {', '.join(missing)}")
    for names, count in (("seg_classes", "n_seg_class"), ("bird_classes", "n_bird_class")):
        if not isinstance(info[names], list) or not info[names]:
            raise RecordError(f"{path}: {names} must be a non-empty list of class names")
        if info.get(count) is not None and info[count] != len(info[names]):
            raise RecordError(f"{path}: {count} is {info[count]} but {names} has {len(info[names])} entries")
    return info


def select_frame_ids(info: Mapping[str, Any], split: str, path: Path) -> tuple[str, list[str]]:
    """(key, frame ids) of ``split`` by the authors' rule (see the module docstring)."""
    keys = LIST_KEYS[split]
    key = next((k for k in keys if info.get(k) is not None), None)
    if key is None:
        which = f"{', '.join(keys[:-1])} and {keys[-1]} are all null" if len(keys) > 1 else \
            f"{keys[0]} is null (predict.py reads test_idx only)"
        raise RecordError(f"{path}: {which}; expected the frame list of split {split!r}")
    ids = info[key]
    if not isinstance(ids, list):
        raise RecordError(f"{path}: {key} is a {type(ids).__name__}; expected a list of frame file names")
    if not ids:
        raise RecordError(f"{path}: {key} is an empty list; expected the frame file names of split {split!r}")
    for n, fid in enumerate(ids):
        if not isinstance(fid, str) or len(fid) < 5 or fid[-4] != "." or "/" in fid or "\\" in fid:
            raise RecordError(f"{path}: {key}[{n}] is {fid!r}; expected a frame file name with a "
                              f"4-character extension, such as '0042.png'")
    if len(set(ids)) != len(ids):
        dup = next(f for f in ids if ids.count(f) > 1)
        raise RecordError(f"{path}: {key} lists {dup!r} more than once")
    return key, sorted(ids) if split == "test" else list(ids)


def plan_authors(root: str | os.PathLike | None, splits: Any, dataset_id: str) -> AuthorsPlan:
    """Resolve ``root`` + ``splits`` of ``datasets.<ds>.source`` (model or mapping) into an :class:`AuthorsPlan`."""
    if root is None or not Path(root).is_dir():
        raise RecordError(f"datasets.{dataset_id}.source.root: {root!r} is not a directory; "
                          f"expected the release's dataset/ folder")
    root = Path(root)
    folders = splits.model_dump() if hasattr(splits, "model_dump") else dict(splits or {})
    plans: dict[str, SplitPlan] = {}
    infos: dict[str, dict[str, Any]] = {}
    for split in SPLITS:
        folder = folders.get(split)
        key_name = f"datasets.{dataset_id}.source.splits.{split}"
        if not isinstance(folder, str) or folder[:2] not in ("Tr", "Va", "Te"):
            raise RecordError(f"{key_name}: {folder!r}; expected a split folder such as Tr1, Va2 or Te12345")
        info_file = root / folder / "data_info.yml"
        infos[split] = info = read_data_info(info_file, key_name)
        key, ids = select_frame_ids(info, split, info_file)
        frame_dir = root / f"{folder[:2]}Set"
        if not frame_dir.is_dir():
            raise RecordError(f"{frame_dir}: folder not found; expected the frame folder of {root / folder}")
        plans[split] = SplitPlan(split, folder, info_file, key, frame_dir, tuple(ids))
    ref = plans["train"].info_file
    for split in SPLITS[1:]:
        for names in ("seg_classes", "bird_classes"):
            if list(infos[split][names]) != list(infos["train"][names]):
                raise RecordError(f"{plans[split].info_file}: {names} differ from those of {ref}")
    for a, b in (("train", "val"), ("train", "test"), ("val", "test")):
        pa, pb = plans[a], plans[b]
        if pa.frame_dir == pb.frame_dir:
            common = sorted(set(pa.ids) & set(pb.ids))
            if common:
                raise RecordError(f"{pb.info_file}: {pb.key} shares {len(common)} frame(s) of {pa.frame_dir} "
                                  f"with {pa.info_file} (first {common[0]!r}); expected disjoint {a} and {b} splits")
    info = infos["train"]
    return AuthorsPlan(root, plans, [str(c) for c in info["seg_classes"]], [str(c) for c in info["bird_classes"]],
                       info.get("seg_colors"), info.get("bird_colors"))


# ----------------------------------------------------------------------------- frame files
def frame_files(n_seg: int, n_bev: int) -> list[tuple[str, str, Any]]:
    """(sub-folder, name pattern, expectation) of one frame's files; pattern uses {id} / {stem}.

    expectation: ``"color"`` (colour PNG), ``"gray"`` (8-bit single-channel PNG) or the
    npy shape.
    """
    s = SOURCE_SIZE
    files: list[tuple[str, str, Any]] = []
    for v in VIEWS:
        files += [(f"rgb_{v}", "{id}", "color"), (f"dvs_{v}", "{id}", "color"), (f"depth_{v}", "{id}", "gray"),
                  (f"segmentation_{v}", "{stem}_128.npy", (n_seg, s, s))]
    files += [("lid_depth_top", "{id}", "gray"), ("lid_depth_top", "{stem}_128.npy", (N_LIDAR, s, s)),
              ("lid_seg_top", "{stem}_128.npy", (n_seg, s, s)), ("bird_view", "{stem}_128.npy", (n_bev, s, s))]
    return files


def _name(pattern: str, frame_id: str) -> str:
    return pattern.format(id=frame_id, stem=frame_id[:-4])


def check_files_exist(plan: AuthorsPlan) -> None:
    """Every file of every selected frame exists (one directory listing per modality folder)."""
    listings: dict[Path, set[str]] = {}
    for sp in plan.splits.values():
        for sub, pattern, _ in frame_files(plan.n_seg, plan.n_bev):
            d = sp.frame_dir / sub
            if d not in listings:
                listings[d] = set(os.listdir(d)) if d.is_dir() else set()
            missing = [fid for fid in sp.ids if _name(pattern, fid) not in listings[d]]
            if missing:
                more = f"; {len(missing) - 1} more frame(s) of this split lack it too" if len(missing) > 1 else ""
                raise RecordError(f"{d / _name(pattern, missing[0])}: file not found (frame {missing[0]!r} of "
                                  f"split {sp.split!r}, listed in {sp.info_file}){more}")


def _png_header(path: Path) -> tuple[int, int, str] | None:
    """(width, height, PIL mode) of a PNG from its header (PIL opens lazily: nothing is decoded),
    or None if PIL does not read it as a PNG (then the decoding step reports it)."""
    try:
        with Image.open(path, formats=["PNG"]) as img:
            return img.size[0], img.size[1], img.mode
    except UnidentifiedImageError:
        return None


def _check_npy_header(path: Path, shape: tuple[int, ...]) -> None:
    """Shape, dtype and size of a ``.npy`` from its header: a read-only memory map reads nothing
    else, and fails on a file shorter than its header says."""
    try:
        arr = np.load(path, mmap_mode="r", allow_pickle=False)
        got, dtype = arr.shape, arr.dtype
        del arr
    except (OSError, ValueError, EOFError) as err:
        raise RecordError(f"{path}: corrupt or truncated npy ({_one_line(err)})") from None
    if tuple(got) != tuple(shape):
        raise RecordError(f"{path}: array of shape {tuple(got)}, expected {tuple(shape)} (channels first, 128 px)")
    if dtype.kind not in "biuf":
        raise RecordError(f"{path}: dtype {dtype}, expected a numeric array (float64 in the release)")


def check_frame(frame_dir: str | os.PathLike, frame_id: str, n_seg: int, n_bev: int) -> None:
    """Header-level check of one frame's files (no decoding): sizes, channels, shapes."""
    d = Path(frame_dir)
    for sub, pattern, want in frame_files(n_seg, n_bev):
        path = d / sub / _name(pattern, frame_id)
        if not path.is_file():
            raise RecordError(f"{path}: file not found (frame {frame_id!r})")
        if isinstance(want, tuple):
            _check_npy_header(path, want)
            continue
        head = _png_header(path)
        if head is None:
            continue  # not a PNG: checked when decoded
        w, h, mode = head
        if (w, h) != (SOURCE_SIZE, SOURCE_SIZE):
            raise RecordError(f"{path}: {w}x{h} image, expected {SOURCE_SIZE}x{SOURCE_SIZE} (the release's resolution)")
        if want == "gray" and mode != "L":
            raise RecordError(f"{path}: PNG mode {mode}; expected a single-channel 8-bit grayscale PNG (mode L, "
                              f"read /255 as the authors do)")


# ----------------------------------------------------------------------------- conversion
def _read_color(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)  # the authors' cv2.imread(path): BGR
    if img is None:
        raise RecordError(f"{path}: cannot decode image")
    if img.shape[:2] != (SOURCE_SIZE, SOURCE_SIZE):
        raise RecordError(f"{path}: {img.shape[1]}x{img.shape[0]} image, expected {SOURCE_SIZE}x{SOURCE_SIZE}")
    return img


def _read_gray01(path: Path) -> np.ndarray:
    """The authors' ``cv2.imread(path, 6) / 255`` for a single-channel 8-bit PNG, as float32."""
    img = cv2.imread(str(path), cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR)
    if img is None:
        raise RecordError(f"{path}: cannot decode image")
    if img.ndim != 2 or img.dtype != np.uint8 or img.shape != (SOURCE_SIZE, SOURCE_SIZE):
        raise RecordError(f"{path}: {img.dtype} image of shape {img.shape}, expected a single-channel 8-bit "
                          f"{SOURCE_SIZE}x{SOURCE_SIZE} PNG")
    return img.astype(np.float32) / 255.0


def _read_npy(path: Path, shape: tuple[int, ...]) -> np.ndarray:
    try:
        a = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as err:
        raise RecordError(f"{path}: corrupt or truncated npy ({_one_line(err)})") from None
    if a.shape != tuple(shape):
        raise RecordError(f"{path}: array of shape {a.shape}, expected {tuple(shape)} (channels first, 128 px)")
    return a


def one_hot_to_index(onehot: np.ndarray) -> np.ndarray:
    """(C, H, W) one-hot -> uint8 (H, W) class index (argmax); all-zero pixels -> 255."""
    idx = np.argmax(onehot, axis=0).astype(np.uint8)
    idx[~(onehot > 0).any(axis=0)] = 255
    return idx


def _nearest_index(src: int, dst: int) -> np.ndarray:
    return np.minimum(((np.arange(dst) + 0.5) * src / dst).astype(np.int64), src - 1)


def resize_nearest(a: np.ndarray, size: int) -> np.ndarray:
    """(..., H, W) -> (..., size, size), nearest pixel centre (labels, masks; dtype kept)."""
    if a.shape[-2:] == (size, size):
        return a
    iy, ix = _nearest_index(a.shape[-2], size), _nearest_index(a.shape[-1], size)
    return np.ascontiguousarray(a[..., iy[:, None], ix[None, :]])


def resize_area(a: np.ndarray, size: int) -> np.ndarray:
    """(..., H, W) -> (..., size, size) by cv2 INTER_AREA per channel (images, depth, LiDAR)."""
    if a.shape[-2:] == (size, size):
        return a
    flat = a.reshape((-1,) + a.shape[-2:])
    out = np.stack([cv2.resize(c, (size, size), interpolation=cv2.INTER_AREA) for c in flat])
    return out.reshape(a.shape[:-2] + (size, size))


def resize_events(a: np.ndarray, size: int) -> np.ndarray:
    """Binary (..., H, W) event maps: "any event in the pixel's area" when shrinking, nearest when enlarging."""
    if a.shape[-2:] == (size, size):
        return a
    if size < a.shape[-1]:
        return (resize_area(a.astype(np.float32), size) > 0).astype(np.uint8)
    return resize_nearest(a, size)


def convert_frame(frame_dir: str | os.PathLike, frame_id: str, n_seg: int, n_bev: int,
                  size: int = SOURCE_SIZE) -> dict[str, Any]:
    """One released frame -> the cache's frame dict at ``size`` px (see the module docstring).

    Also returns ``"_lidar14_diff"``: max |npy channel 14 - lid_depth_top/<id> / 255|.
    """
    d = Path(frame_dir)
    stem = frame_id[:-4]
    s0 = SOURCE_SIZE
    rgb, dvs, de, ss = [], [], [], []
    for v in VIEWS:
        bgr = _read_color(d / f"rgb_{v}" / frame_id)
        if size != s0:
            bgr = cv2.resize(bgr, (size, size), interpolation=cv2.INTER_AREA)
        rgb.append(bgr[..., ::-1].transpose(2, 0, 1))
        path = d / f"dvs_{v}" / frame_id
        try:
            events = dvs_colour_to_image(_read_color(path), name=str(path))
        except ValueError as err:
            raise RecordError(_one_line(err)) from None
        dvs.append(resize_events(events, size))
        de.append(resize_area(_read_gray01(d / f"depth_{v}" / frame_id), size)[None])
        onehot = _read_npy(d / f"segmentation_{v}" / f"{stem}_128.npy", (n_seg, s0, s0))
        ss.append(resize_nearest(one_hot_to_index(onehot), size))
    lidar = _read_npy(d / "lid_depth_top" / f"{stem}_128.npy", (N_LIDAR, s0, s0)).astype(np.float32)
    one_layer = _read_gray01(d / "lid_depth_top" / frame_id)
    diff = float(np.abs(lidar[14] - one_layer).max())
    lidar[14] = one_layer  # what the authors' 1L model reads (see the module docstring)
    ls = one_hot_to_index(_read_npy(d / "lid_seg_top" / f"{stem}_128.npy", (n_seg, s0, s0)))
    bev = (_read_npy(d / "bird_view" / f"{stem}_128.npy", (n_bev, s0, s0)) > 0.5).astype(np.uint8)
    return {
        "frame_id": frame_id,
        "rgb": np.ascontiguousarray(np.stack(rgb)).astype(np.uint8),
        "dvs": np.stack(dvs).astype(np.uint8),
        "lidar": resize_area(lidar, size).astype(np.float16),
        "de": np.stack(de).astype(np.float16),
        "ss": np.stack(ss).astype(np.uint8),
        "ls": resize_nearest(ls, size),
        "bevp": resize_nearest(bev, size),
        "_lidar14_diff": diff,
    }


# ----------------------------------------------------------------------------- whole set
AuthorsJob = tuple[str, str, int, int, int]  # one worker job: frame_dir, frame_id, n_seg, n_bev, size


def _check_task(task: AuthorsJob) -> None:
    check_frame(*task[:4])


def _convert_task(task: AuthorsJob) -> dict[str, Any]:
    return convert_frame(*task)


def _tasks(plan: AuthorsPlan, size: int) -> dict[str, list[AuthorsJob]]:
    return {s: [(str(sp.frame_dir), fid, plan.n_seg, plan.n_bev, int(size)) for fid in sp.ids]
            for s, sp in plan.splits.items()}


def _pool(workers: int) -> Any:
    """A fork pool of ``workers`` (at most the usable cores) when that is more than one, else a null
    context (work runs in this process)."""
    workers = bounded(workers)
    return mp.get_context("fork").Pool(workers) if workers > 1 else contextlib.nullcontext(None)


def check_frames(tasks: Mapping[str, Sequence[AuthorsJob]], pool: Any | None, desc: str) -> None:
    """Header-check every frame (in ``pool`` if given) with a progress bar."""
    flat = [t for ts in tasks.values() for t in ts]
    it = pool.imap_unordered(_check_task, flat, chunksize=16) if pool is not None else map(_check_task, flat)
    for _ in tqdm(it, total=len(flat), desc=desc, unit="frame", leave=False):
        pass


def _iter_split(tasks: Sequence[AuthorsJob], pool: Any | None, desc: str,
                stats: dict[str, float]) -> Iterator[dict[str, Any]]:
    it = pool.imap(_convert_task, tasks, chunksize=4) if pool is not None else map(_convert_task, tasks)
    for frame in tqdm(it, total=len(tasks), desc=desc, unit="frame", leave=False):
        diff = frame.pop("_lidar14_diff")
        stats["max"] = max(stats["max"], diff)
        stats["differ"] += diff > 0.5 / 255
        stats["n"] += 1
        yield frame


def _check_size(size: int) -> int:
    size = int(size)
    if size < 1:
        raise RecordError(f"world.resolution: {size}; expected a positive size in px")
    return size


def ingest_authors(root: str | os.PathLike | None, splits: Any, out_dir: str | os.PathLike, dataset_id: str,
                   resolution: int = SOURCE_SIZE, workers: int = 1) -> Path:
    """Convert the release at ``root`` (``splits``: the split folders) into the cache at ``out_dir``.

    Every input is checked before anything is written; the cache is written atomically.
    """
    size = _check_size(resolution)
    plan = plan_authors(root, splits, dataset_id)
    check_files_exist(plan)
    tasks = _tasks(plan, size)
    meta = {
        "dataset": dataset_id, "source": "authors", "authors_root": str(plan.root.resolve()),
        "authors_splits": {s: {"file": str(sp.info_file), "key": sp.key, "frames": str(sp.frame_dir)}
                           for s, sp in plan.splits.items()},
        "seg_classes": plan.seg_classes, "bev_classes": plan.bev_classes,
        "seg_colors": plan.seg_colors, "bev_colors": plan.bev_colors,
        "has_dvs": True, "resolution": size, "source_resolution": SOURCE_SIZE,
        "resize": None if size == SOURCE_SIZE else RESIZE_RULE,
        "lidar_channel_14": "lid_depth_top/<id> / 255 (the authors' 1-layer input)",
        "views": list(VIEWS),
    }
    stats = {"max": 0.0, "differ": 0, "n": 0}
    with _pool(max(1, int(workers))) as pool:
        check_frames(tasks, pool, f"{dataset_id} check")
        write_cache(out_dir, {s: _iter_split(t, pool, f"{dataset_id} {s}", stats) for s, t in tasks.items()}, meta)
    log.info("%s: LiDAR channel 14 = lid_depth_top/<id>/255; it differs from the npy's channel 14 by more than "
             "half a grey level in %d of %d frames (max |difference| %.4f)",
             dataset_id, stats["differ"], stats["n"], stats["max"])
    return Path(out_dir)


def describe_authors_dataset(root: str | os.PathLike | None, splits: Any, dataset_id: str,
                             out_dir: str | os.PathLike, resolution: int = SOURCE_SIZE, workers: int = 1) -> Path:
    """The ``generate`` stage's raw step of an ``authors`` source: nothing is rendered. Checks the
    whole release as :func:`ingest_authors` would, then writes a manifest pointing at ``root``
    (split files, keys and frame ids)."""
    from ..core import io

    size = _check_size(resolution)
    plan = plan_authors(root, splits, dataset_id)
    check_files_exist(plan)
    tasks = _tasks(plan, size)
    with _pool(max(1, int(workers))) as pool:
        check_frames(tasks, pool, f"{dataset_id} check")
    with io.atomic_dir(out_dir) as tmp:
        io.write_json(tmp / "manifest.json", {
            "dataset": dataset_id, "source": "authors", "authors_root": str(plan.root.resolve()),
            "resolution": size, "source_resolution": SOURCE_SIZE,
            "split_files": {s: {"file": str(sp.info_file), "key": sp.key, "frames": str(sp.frame_dir)}
                            for s, sp in plan.splits.items()},
            "splits": {s: list(sp.ids) for s, sp in plan.splits.items()},
            "seg_classes": plan.seg_classes, "bev_classes": plan.bev_classes,
        })
    return Path(out_dir)
