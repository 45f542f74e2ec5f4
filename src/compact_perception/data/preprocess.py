"""The preprocess stage: raw record -> preprocessed frame (paper section IV-C; docs/ARCHITECTURE.md).

A raw record (``data/raw/<ds>/frames/<id>.npz``, its contract in :mod:`compact_perception.data.record`)
holds the sensor data as CARLA delivers it; :func:`preprocess_record` turns it into the compact
frame dict of the cache:

| key | dtype, shape | from |
|---|---|---|
| ``rgb`` | uint8 (V,3,S,S) | ``rgb_<v>`` transposed to channels-first (/255 happens on the device) |
| ``dvs`` | uint8 (V,2,S,S) | ``dvs_<v>`` events, eq. (1) (:mod:`compact_perception.data.dvs`) |
| ``lidar`` | float16 (15,S,S) | ``lidar``, eq. (2)-(5) (:func:`compact_perception.data.lidar.topview_15l`) |
| ``de`` | float16 (V,1,S,S) | ``depth_<v>`` / 65535, in [0, 1] |
| ``ss`` | uint8 (V,S,S) | ``sem_<v>`` palette image -> class index (:func:`classes.palette_to_index`) |
| ``ls`` | uint8 (S,S) | tag of the highest LiDAR point per cell, 255 = no point |
| ``bevp`` | uint8 (9,S,S) | ``bev`` masks as 0/1 |

Every input problem (missing, truncated or corrupt npz, missing key, wrong dtype or
shape, empty split, missing manifest) raises :class:`RecordError` whose message names the
frame id and the file. :func:`preprocess_dataset` looks the dataset's source up
(:mod:`compact_perception.data.sources`): a source that writes raw records is read here, any other
brings its own conversion.
"""
from __future__ import annotations

import json
import logging
import multiprocessing as mp
import os
from pathlib import Path
from typing import Any, Iterator, Mapping, Sequence

import numpy as np
from tqdm import tqdm

from ..core.cache import write_cache
from ..core.layout import CACHE_ROOT
from ..core.classes import CARLA_PALETTE, palette_to_index
from ..core.params import Params, PreprocessParams
from ..core.machine import bounded
from .dvs import events_to_image
from ..core.errors import RecordError  # re-exported: ``from .preprocess import RecordError`` keeps working
from .lidar import ls_ground_truth, topview_15l
from .record import SPLITS, RecordSpec, load_manifest, load_record, manifest_spec, validate_record
from .sources import data_source

log = logging.getLogger(__name__)


def preprocess_record(
    arrays: Mapping[str, np.ndarray],
    spec: RecordSpec,
    pp: PreprocessParams,
    *,
    frame_id: str,
    path: str | os.PathLike = "<memory>",
    palette: np.ndarray = CARLA_PALETTE,
) -> dict[str, Any]:
    """One raw record -> the cache's frame dict (section IV-C, eq. (1)-(5)); includes ``frame_id``."""
    where = f"frame {frame_id}: {path}"
    validate_record(arrays, spec, where)
    s, views = spec.size, spec.views
    try:
        frame: dict[str, Any] = {"frame_id": frame_id}
        frame["rgb"] = np.stack([arrays[f"rgb_{v}"].transpose(2, 0, 1) for v in views]).astype(np.uint8)
        if spec.has_dvs:
            frame["dvs"] = np.stack([events_to_image(arrays[f"dvs_{v}"], s, name=f"{where}: dvs_{v}") for v in views])
        pts = arrays["lidar"]
        frame["lidar"] = topview_15l(
            pts, pp.lidar_range_m, s, pp.z_min_m, pp.z_max_m, pp.height_multiplier, pp.fill_neighbours
        ).astype(np.float16)
        frame["de"] = np.stack([(arrays[f"depth_{v}"].astype(np.float32) / 65535.0)[None] for v in views]).astype(np.float16)
        frame["ss"] = np.stack([palette_to_index(arrays[f"sem_{v}"], palette, name=f"{where}: sem_{v}") for v in views])
        frame["ls"] = ls_ground_truth(pts, arrays["lidar_tag"], pp.lidar_range_m, s)
        frame["bevp"] = (arrays["bev"] > 0).astype(np.uint8)
    except RecordError:
        raise
    except ValueError as err:
        msg = str(err)
        raise RecordError(msg if msg.startswith("frame ") else f"{where}: {msg}") from None
    return frame


def _process_one(task: tuple[str, str, RecordSpec, dict[str, Any]]) -> dict[str, Any]:
    path, frame_id, spec, pp_dict = task
    pp = PreprocessParams(**pp_dict)
    return preprocess_record(load_record(path, frame_id), spec, pp, frame_id=frame_id, path=path)


def iter_preprocessed(
    raw_dir: str | os.PathLike,
    frame_ids: Sequence[str],
    spec: RecordSpec,
    pp: PreprocessParams,
    pool: Any | None = None,
    desc: str = "preprocess",
) -> Iterator[dict[str, Any]]:
    """Yield preprocessed frames in ``frame_ids`` order (in ``pool``'s worker processes if given)."""
    tasks = [(str(Path(raw_dir) / "frames" / f"{fid}.npz"), str(fid), spec, pp.model_dump()) for fid in frame_ids]
    it = pool.imap(_process_one, tasks, chunksize=4) if pool is not None else map(_process_one, tasks)
    yield from tqdm(it, total=len(tasks), desc=desc, leave=False)


def preprocess_sim(raw_dir: str | os.PathLike, out_dir: str | os.PathLike, dataset_id: str, pp: PreprocessParams) -> Path:
    """``data/raw/<ds>/`` -> ``data/cache/<ds>/`` (atomic). Returns the cache directory."""
    manifest = load_manifest(raw_dir)
    spec = manifest_spec(manifest)
    meta = {
        "dataset": dataset_id,
        "source": manifest.get("source", "sim"),
        "seg_classes": list(manifest["seg_classes"]),
        "bev_classes": list(manifest["bev_classes"]),
        "has_dvs": spec.has_dvs,
        "resolution": spec.size,
        "views": list(spec.views),
        "preprocess": pp.model_dump(),
    }
    workers = max(1, bounded(pp.workers))  # at most the usable cores (core.machine)
    if workers == 1:
        splits = {s: iter_preprocessed(raw_dir, manifest["splits"][s], spec, pp, None, f"{dataset_id} {s}") for s in SPLITS}
        return write_cache(out_dir, splits, meta)
    with mp.get_context("fork").Pool(workers) as pool:
        splits = {s: iter_preprocessed(raw_dir, manifest["splits"][s], spec, pp, pool, f"{dataset_id} {s}") for s in SPLITS}
        return write_cache(out_dir, splits, meta)


def figure_lidar_of(cache_dir: str | os.PathLike, split: str = "test", index: int = 0) -> np.ndarray:
    """The cached (15, S, S) LiDAR tensor of one frame (for the Fig. 5-like figure)."""
    from ..core.cache import read_split

    return np.asarray(read_split(cache_dir, split).arrays["lidar"][index], dtype=np.float32)


def preprocess_dataset(
    params: Params,
    dataset_id: str,
    raw_root: str | os.PathLike = "data/raw",
    cache_root: str | os.PathLike = CACHE_ROOT,
    figure_path: str | os.PathLike | None = None,
) -> Path:
    """Preprocess dataset A/B/C as its source says (:mod:`compact_perception.data.sources`: the raw
    records of ``data/raw/<ds>`` by :func:`preprocess_sim`, or the source's own conversion) and
    optionally draw the LiDAR figure."""
    ds = getattr(params.datasets, dataset_id, None)
    if ds is None or dataset_id == "nuscenes":
        raise RecordError(f"dataset {dataset_id!r}: not a simulated dataset (A, B or C); nuScenes has its own ingestion")
    raw_dir, out_dir = Path(raw_root) / dataset_id, Path(cache_root) / dataset_id
    source = data_source(ds.source.id)
    if source.cache is None:  # data/raw/<ds> holds raw records (compact_perception.data.record)
        cache = preprocess_sim(raw_dir, out_dir, dataset_id, params.preprocess)
    else:
        cache = source.cache(params, dataset_id, raw_dir, out_dir)
    if figure_path is not None:
        from .figures_preprocess import plot_lidar_layers

        frame = min(params.evaluate.figure_frame, len(json.loads((cache / "test" / "frame_ids.json").read_text())) - 1)
        plot_lidar_layers(figure_lidar_of(cache, "test", frame), figure_path, title=f"Dataset {dataset_id}: LiDAR preprocessing (test frame {frame})")
    return cache
