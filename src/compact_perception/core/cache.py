"""The model-ready cache (SPEC 4, docs/ARCHITECTURE.md "Cache layout").

```
<out_dir>/meta.json                 meta given by the caller + counts, keys, dtypes, shapes, and
                                    the SHA-256 of every file of every split (``sha256``)
<out_dir>/<split>/<key>.npy         one memory-mappable array per key, first axis = frame
<out_dir>/<split>/frame_ids.json
```

:func:`write_cache` is generic over the keys present: whatever arrays the first frame
of a split carries (e.g. no ``dvs`` for nuScenes, 32-class maps) define the arrays of
that split, and every later frame must carry the same keys with the same dtype and
shape (else a ValueError naming the frame). Frames stream to disk one at a time (memory
stays O(one frame)) into .npy files whose fixed-size header is rewritten with the final
count at the end; everything is built inside :func:`compact_perception.core.io.atomic_dir`,
so an error or an interruption leaves no cache directory behind. The hashes recorded when the
cache is written let a reader check it was not changed since (:func:`verify_cache`: a copy
damaged in a DVC remote or on a disk), before it trusts it.

A frame dict holds numpy arrays plus an optional ``"frame_id"`` (str); frames without
one are named ``<split>_<index:06d>``. Frames come in clusters of consecutive, correlated frames
(an episode of the world, a nuScenes scene): :func:`frame_cluster` reads the cluster from the id.
"""
from __future__ import annotations

import json
import logging
import os
import re
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
from tqdm import tqdm

from . import io as cio

log = logging.getLogger(__name__)

CACHE_FORMAT_VERSION = 1
#: meta.json's ``{split: {file name: SHA-256}}`` of every file of every split, recorded when written.
HASHES_KEY = "sha256"
_HEADER_LEN = 256  # fixed .npy header size (magic + version + len + dict), multiple of 64
ID_KEY = "frame_id"


#: ``<cluster>_<step>``: the world's ``town01_ep0003_007`` and nuScenes' ``scene-0061_012``.
_CLUSTERED_ID = re.compile(r"^(?P<cluster>.+)_(?P<step>\d{3})$")
#: Consecutive frames grouped into one cluster where the id records none (the authors' release).
AUTHORS_BLOCK = 10


def frame_cluster(frame_id: str) -> str:
    """The cluster (a drive of consecutive, correlated frames) of a frame id: the episode of a
    simulated frame (``town02_ep0035_004`` -> ``town02_ep0035``), the scene of a nuScenes sample
    (``scene-0061_012`` -> ``scene-0061``). The authors' release names frames by a number only
    (``0042.png``) and records no episode: there, blocks of :data:`AUTHORS_BLOCK` consecutive
    numbers stand in for episodes (``0042.png`` -> ``block0004``), an approximation of the drives
    it was recorded in. Any other id is a cluster of its own."""
    m = _CLUSTERED_ID.match(frame_id)
    if m:
        return m.group("cluster")
    stem = frame_id.rsplit(".", 1)[0]
    if stem.isdigit():
        return f"block{int(stem) // AUTHORS_BLOCK:04d}"
    return frame_id


class CacheError(ValueError):
    """A cache cannot be written or read; the message names the split, frame or file."""


def _npy_header(dtype: np.dtype, shape: tuple[int, ...]) -> bytes:
    """A version-1.0 .npy header padded to exactly ``_HEADER_LEN`` bytes."""
    d = {"descr": np.lib.format.dtype_to_descr(np.dtype(dtype)), "fortran_order": False, "shape": tuple(shape)}
    text = repr(d).encode("latin1")
    body_len = _HEADER_LEN - 10  # 6 magic + 2 version + 2 length bytes
    if len(text) + 1 > body_len:
        raise CacheError(f"npy header too long for shape {shape}")
    text = text + b" " * (body_len - len(text) - 1) + b"\n"
    return b"\x93NUMPY" + bytes([1, 0]) + struct.pack("<H", body_len) + text


class _ArrayStream:
    """Appends frames to ``<key>.npy``; the header gets the final count on close."""

    def __init__(self, path: Path, dtype: np.dtype, shape: tuple[int, ...]) -> None:
        self.path, self.dtype, self.shape, self.count = path, np.dtype(dtype), tuple(shape), 0
        self.fh = open(path, "wb")
        self.fh.write(_npy_header(self.dtype, (0,) + self.shape))

    def append(self, arr: np.ndarray) -> None:
        self.fh.write(np.ascontiguousarray(arr).tobytes())
        self.count += 1

    def close(self) -> None:
        self.fh.seek(0)
        self.fh.write(_npy_header(self.dtype, (self.count,) + self.shape))
        self.fh.close()


def _write_split(split_dir: Path, split: str, frames: Iterable[Mapping[str, Any]], progress: bool = False) -> dict[str, Any]:
    split_dir.mkdir(parents=True)
    streams: dict[str, _ArrayStream] = {}
    ids: list[str] = []
    try:
        total = len(frames) if hasattr(frames, "__len__") else None  # type: ignore[arg-type]
        for n, frame in enumerate(tqdm(frames, desc=f"cache {split}", total=total, leave=False, disable=not progress)):
            fid = str(frame.get(ID_KEY, f"{split}_{n:06d}"))
            arrays = {k: np.asarray(v) for k, v in frame.items() if k != ID_KEY}
            if not streams:
                if not arrays:
                    raise CacheError(f"split {split!r}, frame {fid}: frame has no arrays")
                for key in sorted(arrays):
                    a = arrays[key]
                    streams[key] = _ArrayStream(split_dir / f"{key}.npy", a.dtype, a.shape)
            if set(arrays) != set(streams):
                raise CacheError(
                    f"split {split!r}, frame {fid}: keys {sorted(arrays)} differ from the split's keys {sorted(streams)}"
                )
            for key, s in streams.items():
                a = arrays[key]
                if a.dtype != s.dtype or a.shape != s.shape:
                    raise CacheError(
                        f"split {split!r}, frame {fid}: {key} is {a.dtype}{a.shape}, expected {s.dtype}{s.shape}"
                    )
                s.append(a)
            ids.append(fid)
    finally:
        for s in streams.values():
            s.close()
    if not ids:
        raise CacheError(f"split {split!r} is empty: no frames to cache")
    if len(set(ids)) != len(ids):
        raise CacheError(f"split {split!r}: duplicate frame ids")
    cio.write_json(split_dir / "frame_ids.json", ids)
    return {"count": len(ids), "keys": {k: {"dtype": s.dtype.str, "shape": list(s.shape)} for k, s in streams.items()}}


def write_cache(
    out_dir: str | os.PathLike,
    splits: Mapping[str, Iterable[Mapping[str, Any]]],
    meta: Mapping[str, Any],
    progress: bool = False,
) -> Path:
    """Write the cache atomically (nothing partial remains on error); returns ``out_dir``.

    ``splits`` maps split names to iterables of frame dicts (consumed once, in order);
    ``meta`` must be JSON-serialisable (e.g. ``dataset, source, seg_classes, bev_classes,
    has_dvs, resolution, views``); ``counts``, ``keys`` and ``format_version`` are added.
    Raises :class:`CacheError` for an empty split, inconsistent frames, or ``has_dvs``
    disagreeing with the frames. ``progress`` shows a tqdm bar per split (off by default:
    callers usually wrap their frame iterator in their own bar).
    """
    out_dir = Path(out_dir)
    if not splits:
        raise CacheError(f"{out_dir}: no splits given")
    full_meta = dict(meta)
    try:
        json.dumps(full_meta)
    except TypeError as err:
        raise CacheError(f"{out_dir}: meta is not JSON-serialisable: {err}") from None
    with cio.atomic_dir(out_dir) as tmp:
        info = {name: _write_split(tmp / name, name, frames, progress) for name, frames in splits.items()}
        if "has_dvs" in full_meta:
            for name, inf in info.items():
                if bool(full_meta["has_dvs"]) != ("dvs" in inf["keys"]):
                    raise CacheError(f"split {name!r}: meta has_dvs={full_meta['has_dvs']} but keys are {sorted(inf['keys'])}")
        full_meta["counts"] = {name: inf["count"] for name, inf in info.items()}
        full_meta["keys"] = {name: inf["keys"] for name, inf in info.items()}
        full_meta["format_version"] = CACHE_FORMAT_VERSION
        full_meta[HASHES_KEY] = {name: {f.name: cio.sha256_file(f) for f in sorted((tmp / name).iterdir())}
                                 for name in info}
        cio.write_json(tmp / "meta.json", full_meta)
    log.info("wrote cache %s: %s", out_dir, full_meta["counts"])
    return out_dir


@dataclass(frozen=True)
class CacheSplit:
    """One split of a cache: frame ids and read-only memory-mapped arrays (first axis = frame)."""

    name: str
    frame_ids: list[str]
    arrays: dict[str, np.ndarray] = field(repr=False)

    def __len__(self) -> int:
        return len(self.frame_ids)


@dataclass(frozen=True)
class CacheInfo:
    """An opened cache (:func:`read_cache`)."""

    path: Path
    meta: dict[str, Any]
    splits: dict[str, CacheSplit]

    @property
    def has_dvs(self) -> bool:
        return bool(self.meta.get("has_dvs", any("dvs" in s.arrays for s in self.splits.values())))

    @property
    def num_seg_classes(self) -> int:
        return len(self.meta["seg_classes"])

    @property
    def num_bev_classes(self) -> int:
        return len(self.meta["bev_classes"])

    def __getitem__(self, split: str) -> CacheSplit:
        try:
            return self.splits[split]
        except KeyError:
            raise CacheError(f"{self.path}: no split {split!r}; has {sorted(self.splits)}") from None


_RERUN = "rerun the stage that writes the cache (preprocess or ingest_nuscenes)"


def _read_json(path: Path, what: str) -> Any:
    try:
        return json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as err:
        raise CacheError(f"{path}: unreadable {what} ({type(err).__name__}: {err}); {_RERUN}") from None


def check_array_file(path: Path, n_rows: int, dtype: Any, shape: Sequence[int]) -> None:
    """Raise :class:`CacheError` unless ``path`` is a complete .npy of ``n_rows`` frames of ``dtype``
    ``shape``: its header is readable, says exactly that, and the file size is the header plus
    the data (a truncated or over-long file is caught here, before it is memory-mapped)."""
    want_dtype, want_shape = np.dtype(dtype), (int(n_rows),) + tuple(int(n) for n in shape)
    expected = f"{want_shape} {want_dtype} (one row per frame id)"
    try:
        size = path.stat().st_size
        with open(path, "rb") as fh:
            version = np.lib.format.read_magic(fh)
            if version == (1, 0):
                got_shape, fortran, got_dtype = np.lib.format.read_array_header_1_0(fh)
            elif version == (2, 0):
                got_shape, fortran, got_dtype = np.lib.format.read_array_header_2_0(fh)
            else:
                raise ValueError(f"unsupported .npy format version {version}")
            offset = fh.tell()
    except FileNotFoundError:
        raise CacheError(f"{path}: file not found; expected a cache array of {expected}; {_RERUN}") from None
    except (OSError, ValueError, SyntaxError) as err:
        raise CacheError(f"{path}: not a readable .npy file ({err}); expected a cache array of {expected}; "
                         f"{_RERUN}") from None
    if tuple(got_shape) != want_shape or np.dtype(got_dtype) != want_dtype or fortran:
        raise CacheError(f"{path}: header says {tuple(got_shape)} {np.dtype(got_dtype)}"
                         f"{' (Fortran order)' if fortran else ''}, expected {expected}; {_RERUN}")
    need = offset + int(np.prod(want_shape, dtype=np.int64)) * want_dtype.itemsize
    if size != need:
        state = "truncated" if size < need else "longer than its header says"
        raise CacheError(f"{path}: {state}: {size} bytes, expected {need} ({offset}-byte header + "
                         f"{expected}); {_RERUN}")


def read_split(cache_dir: str | os.PathLike, split: str, meta: Mapping[str, Any] | None = None) -> CacheSplit:
    """Open one split's arrays with ``mmap_mode="r"``.

    Before mapping, every array file is checked against meta.json and frame_ids.json
    (:func:`check_array_file`: header, dtype, shape, one row per frame id, file size), so a
    truncated or corrupt file raises :class:`CacheError` naming it instead of failing later.
    """
    cache_dir = Path(cache_dir)
    if meta is None:
        meta = read_meta(cache_dir)
    sdir = cache_dir / split
    ids_path = sdir / "frame_ids.json"
    if split not in meta.get("counts", {}) or not ids_path.is_file():
        raise CacheError(f"{cache_dir}: no split {split!r} (has {sorted(meta.get('counts', {}))})")
    ids = _read_json(ids_path, "frame id list")
    if not isinstance(ids, list) or not all(isinstance(i, str) for i in ids):
        raise CacheError(f"{ids_path}: expected a JSON list of frame id strings; {_RERUN}")
    keys = meta.get("keys", {}).get(split) if isinstance(meta.get("keys"), dict) else None
    if not isinstance(keys, dict) or not keys:
        raise CacheError(f"{cache_dir / 'meta.json'}: no array list (keys.{split}); {_RERUN}")
    arrays: dict[str, np.ndarray] = {}
    for key, spec in keys.items():
        path = sdir / f"{key}.npy"
        try:
            check_array_file(path, len(ids), spec["dtype"], spec["shape"])
        except (KeyError, TypeError):
            raise CacheError(f"{cache_dir / 'meta.json'}: keys.{split}.{key} needs dtype and shape; {_RERUN}") from None
        try:
            arr = np.load(path, mmap_mode="r")
        except (OSError, ValueError) as err:
            raise CacheError(f"{path}: cannot open cache array: {err}") from None
        arrays[key] = arr
    return CacheSplit(split, ids, arrays)


def read_meta(cache_dir: str | os.PathLike) -> dict[str, Any]:
    """Read a cache's meta.json (CacheError if the directory is not a cache)."""
    cache_dir = Path(cache_dir)
    path = cache_dir / "meta.json"
    if not path.is_file():
        raise CacheError(f"{cache_dir}: not a cache (no meta.json); run the preprocess stage")
    meta = _read_json(path, "cache meta")
    if not isinstance(meta, dict):
        raise CacheError(f"{path}: expected a JSON object; {_RERUN}")
    return meta


def verify_cache(cache_dir: str | os.PathLike) -> bool:
    """Check every file of every split of the cache against the SHA-256 its meta.json recorded when
    the cache was written (:func:`write_cache`); :class:`CacheError` naming the first file that
    differs (a copy damaged in a DVC remote, on a disk, or edited). ``False`` where meta.json
    records no hashes (a cache written before they were recorded: nothing to check against)."""
    cache_dir = Path(cache_dir)
    meta_path = cache_dir / "meta.json"
    recorded = read_meta(cache_dir).get(HASHES_KEY)
    if recorded is None:
        return False
    if not isinstance(recorded, dict) or not all(
            isinstance(files, dict) and all(isinstance(n, str) and Path(n).name == n and n not in ("", ".", "..")
                                            and isinstance(h, str) for n, h in files.items())
            for files in recorded.values()):
        raise CacheError(f"{meta_path}: {HASHES_KEY}: expected {{split: {{file name: SHA-256}}}}; {_RERUN}")
    for split in sorted(recorded):
        for name, want in sorted(recorded[split].items()):
            path = cache_dir / str(split) / name
            try:
                got = cio.sha256_file(path)
            except FileNotFoundError:
                raise CacheError(f"{path}: file not found; {meta_path} records it; {_RERUN}") from None
            except OSError as err:
                raise CacheError(f"{path}: unreadable ({err.strerror or err}); {_RERUN}") from None
            if got != want:
                raise CacheError(f"{path}: does not match the hash recorded when it was written (SHA-256 "
                                 f"{got[:16]}..., {meta_path} records {want[:16]}...); {_RERUN}")
    return True


def read_cache(cache_dir: str | os.PathLike) -> CacheInfo:
    """Open a cache written by :func:`write_cache` (arrays memory-mapped read-only)."""
    cache_dir = Path(cache_dir)
    meta = read_meta(cache_dir)
    splits = {name: read_split(cache_dir, name, meta) for name in meta["counts"]}
    return CacheInfo(cache_dir, meta, splits)
