"""The authors' released CARLA dataset as a data source (``datasets.<ds>.source: {id: authors,
root, splits}``; its registration: ``core.params.sources.AuthorsSource``). No raw records: the
generate stage checks the release and writes a manifest (:func:`write_raw`), the preprocess stage
converts the release into the cache (:func:`cache`); the conversion is :mod:`..authors`.
"""
from __future__ import annotations

import json
from pathlib import Path

from ...core.params import Params
from ..authors import convert_frame, describe_authors_dataset, ingest_authors


def write_raw(params: Params, dataset_id: str, out_dir: Path) -> None:
    """Check the release and write ``out_dir/manifest.json`` (:func:`describe_authors_dataset`)."""
    settings = params.dataset(dataset_id).source
    describe_authors_dataset(settings.root, settings.splits, dataset_id, out_dir,
                             resolution=params.resolution, workers=params.world.workers)


def draw_example(params: Params, dataset_id: str, raw_dir: Path, figure: Path) -> None:
    """The qualitative grid of the first test frame, converted from the release as the cache holds it."""
    from ..figures_generate import save_cache_frame_figure

    manifest = json.loads((Path(raw_dir) / "manifest.json").read_text())
    fid = manifest["splits"]["test"][0]
    frame = convert_frame(manifest["split_files"]["test"]["frames"], fid, len(manifest["seg_classes"]),
                          len(manifest["bev_classes"]), int(manifest["resolution"]))
    save_cache_frame_figure(dataset_id, frame, fid, figure,
                            title=f"dataset {dataset_id}: authors' CARLA data, test frame {fid}")


def cache(params: Params, dataset_id: str, raw_dir: Path, out_dir: Path) -> Path:
    """Convert the release into the cache at ``out_dir`` (:func:`ingest_authors`)."""
    settings = params.dataset(dataset_id).source
    return ingest_authors(settings.root, settings.splits, out_dir, dataset_id,
                          resolution=params.resolution, workers=params.preprocess.workers)
