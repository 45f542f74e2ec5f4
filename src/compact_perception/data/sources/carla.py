"""A CARLA recording as a data source (``datasets.<ds>.source: {id: carla, root, ...}``; its
registration: ``core.params.sources.CarlaSource``). The smallest source: copy this file for a new one.

- raw records: :func:`write_raw` checks the recording at ``datasets.<ds>.source.root``
  (``pipeline.collect_carla`` wrote it) and copies it into ``data/raw/<ds>``;
- the cache: none of its own (``cache = None``): the preprocess stage reads the raw records;
- an example frame: :func:`draw_example` draws the first test frame's raw record.
"""
from __future__ import annotations

import logging
from pathlib import Path

from ...core.params import Params
from ..carla.recording import import_recording
from ..record import load_manifest, load_record

log = logging.getLogger(__name__)

#: The preprocess stage reads this source's raw records (compact_perception.data.record).
cache = None


def write_raw(params: Params, dataset_id: str, out_dir: Path) -> None:
    """Check the recording at ``datasets.<ds>.source.root`` and copy it into ``out_dir`` (= data/raw/<ds>)."""
    root = params.dataset(dataset_id).source.root
    import_recording(params, dataset_id, root, out_dir)
    log.info("copied the CARLA recording %s into %s", root, out_dir)


def draw_example(params: Params, dataset_id: str, raw_dir: Path, figure: Path) -> None:
    """The panel of the first test frame of the copied recording."""
    from ..figures_generate import save_frame_figure

    fid = load_manifest(raw_dir)["splits"]["test"][0]
    rec = load_record(Path(raw_dir) / "frames" / f"{fid}.npz", fid)
    save_frame_figure(rec, figure, params.world.lidar.range_m, title=f"dataset {dataset_id}: CARLA, test frame {fid}")
