"""The embedded world as a data source (``datasets.<ds>.source: {id: sim}``; its registration:
``core.params.sources.SimSource``).

- raw records: :func:`write_raw` renders the set into ``data/raw/<ds>`` (:func:`..world.generate.generate_dataset`);
- the cache: none of its own (``cache = None``): the preprocess stage reads the raw records;
- an example frame: :func:`draw_example` renders the first two frames of the first test episode
  again and draws the last as the generate stage's panel.
"""
from __future__ import annotations

from pathlib import Path

from ...core.params import Params
from ..world import generate
from ..world.generate import iter_episodes, render_episode

#: The preprocess stage reads this source's raw records (compact_perception.data.record).
cache = None


def write_raw(params: Params, dataset_id: str, out_dir: Path) -> None:
    """Render dataset ``dataset_id`` into ``out_dir`` (= data/raw/<ds>)."""
    generate.generate_dataset(params, dataset_id, out_dir)  # looked up when called (tests replace it there)


def draw_example(params: Params, dataset_id: str, raw_dir: Path, figure: Path) -> None:
    """The panel of one test frame, rendered again with its metadata (the title names its conditions)."""
    from ..figures_generate import save_frame_figure

    ep = next(e for e in iter_episodes(params, dataset_id) if e["split"] == "test")
    rec = None
    for rec in render_episode(params.world, ep["town"], ep["seed"], min(2, ep["frames"]),
                              params.resolution, episode=ep["index"]):
        pass
    assert rec is not None
    save_frame_figure(rec, figure, params.world.lidar.range_m, title=f"dataset {dataset_id}: {rec['meta']}")
