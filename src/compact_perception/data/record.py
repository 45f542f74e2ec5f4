"""The raw record contract: what a data source writes into ``data/raw/<ds>/`` and the preprocess
stage reads (docs/data-formats.md, "Raw record layout").

``manifest.json`` (written last: it marks the set complete) and one ``frames/<id>.npz`` per
frame. The world (``world.generate``) and a CARLA recording (``carla.recording``) write it;
:mod:`compact_perception.data.preprocess` reads it. It sits below all of them, so no source imports
the stage that consumes its records.

Every input problem (missing, truncated or corrupt npz, missing key, wrong dtype or shape,
empty split, missing manifest) raises :class:`RecordError` whose message names the frame id
and the file.
"""
from __future__ import annotations

import json
import os
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..core.errors import RecordError

SPLITS: tuple[str, ...] = ("train", "val", "test")


@dataclass(frozen=True)
class RecordSpec:
    """What a raw record must contain."""

    views: tuple[str, ...]
    size: int
    has_dvs: bool = True
    n_bev: int = 9


def load_record(path: str | os.PathLike, frame_id: str) -> dict[str, np.ndarray]:
    """Read every array of a raw npz eagerly; corrupt/truncated/missing files raise RecordError."""
    path = Path(path)
    if not path.is_file():
        raise RecordError(f"frame {frame_id}: {path}: file not found")
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError, KeyError) as err:
        raise RecordError(f"frame {frame_id}: {path}: corrupt or truncated npz ({type(err).__name__}: {err})") from None


def _expect(arrays: Mapping[str, np.ndarray], key: str, shape: tuple[int | None, ...], kinds: str, where: str) -> np.ndarray:
    if key not in arrays:
        raise RecordError(f"{where}: missing key {key!r} (has {sorted(arrays)})")
    a = arrays[key]
    ok_shape = a.ndim == len(shape) and all(s is None or s == d for s, d in zip(shape, a.shape))
    if not ok_shape:
        want = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
        raise RecordError(f"{where}: {key} has shape {a.shape}, expected {want}")
    if a.dtype.kind not in kinds:
        raise RecordError(f"{where}: {key} has dtype {a.dtype}, expected kind {kinds!r}")
    return a


def validate_record(arrays: Mapping[str, np.ndarray], spec: RecordSpec, where: str) -> None:
    """Check keys, shapes and dtypes of a raw record (docs/data-formats.md table); ``where`` names frame and file."""
    s = spec.size
    for v in spec.views:
        _expect(arrays, f"rgb_{v}", (s, s, 3), "u", where)
        _expect(arrays, f"sem_{v}", (s, s, 3), "u", where)
        _expect(arrays, f"depth_{v}", (s, s), "u", where)
        if spec.has_dvs:
            _expect(arrays, f"dvs_{v}", (None, 4), "iuf", where)
    lid = _expect(arrays, "lidar", (None, 4), "f", where)
    _expect(arrays, "lidar_tag", (lid.shape[0],), "iu", where)
    _expect(arrays, "bev", (spec.n_bev, s, s), "ub", where)


def load_manifest(raw_dir: str | os.PathLike) -> dict[str, Any]:
    """Read ``manifest.json``; its absence means the world never finished writing the dataset."""
    path = Path(raw_dir) / "manifest.json"
    if not path.is_file():
        raise RecordError(f"{raw_dir}: dataset incomplete (no manifest.json); run the generate stage first")
    try:
        manifest = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise RecordError(f"{path}: not valid JSON: {err}") from None
    for key in ("splits", "resolution", "views"):
        if key not in manifest:
            raise RecordError(f"{path}: missing key {key!r}")
    for split in SPLITS:
        if not manifest["splits"].get(split):
            raise RecordError(f"{path}: split {split!r} is empty")
    return manifest


def manifest_spec(manifest: Mapping[str, Any]) -> RecordSpec:
    """The :class:`RecordSpec` a manifest declares (views, resolution, DVS, number of BEV classes)."""
    return RecordSpec(
        views=tuple(manifest["views"]),
        size=int(manifest["resolution"]),
        has_dvs=bool(manifest.get("has_dvs", True)),
        n_bev=len(manifest.get("bev_classes", [None] * 9)),
    )
