"""The data sources of sets A, B, C, by their ``datasets.<ds>.source`` id in params.yaml.

A source is a module that says what it does in each data stage:

- ``write_raw(params, dataset_id, out_dir)``: the generate stage's ``data/raw/<ds>``; raw records
  (:mod:`compact_perception.data.record`) or, for a source without them, a manifest;
- ``draw_example(params, dataset_id, raw_dir, figure)``: the generate stage's example frame,
  ``reports/figures/world_<ds>.png`` (drawn by :mod:`compact_perception.data.figures_generate`);
- ``cache``: ``None`` when ``data/raw/<ds>`` holds raw records, which the preprocess stage reads;
  else ``cache(params, dataset_id, raw_dir, out_dir) -> Path``, the source's own conversion into
  the cache (:mod:`compact_perception.core.cache`).

The generate stage (``pipeline/generate.py``) and :func:`compact_perception.data.preprocess.preprocess_dataset`
look the source up here and call it. A new source is one module plus its line below; the params
schema's ``source`` ids (``core.params.schema.SimDatasetParams``) must equal :data:`SOURCES`'
(``tests/test_registries.py``). nuScenes is not one of them: it has stages of its own
(``nuscenes_sim``, ``ingest_nuscenes``) and no ``source`` key.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable, Optional, Protocol

from . import authors
from .carla import source as carla_source
from ..core.params import Params
from ..core.registry import Registry
from .world import source as world_source


class DataSource(Protocol):
    """What a source module defines (see the module docstring)."""

    cache: Optional[Callable[[Params, str, Path, Path], Path]]

    def write_raw(self, params: Params, dataset_id: str, out_dir: Path) -> None: ...

    def draw_example(self, params: Params, dataset_id: str, raw_dir: Path, figure: Path) -> None: ...


SOURCES: Registry[DataSource] = Registry("data source", ordered=True)
SOURCES.register("sim")(world_source)       # the embedded world (world/source.py)
SOURCES.register("authors")(authors)        # the authors' released CARLA dataset (authors.py)
SOURCES.register("carla")(carla_source)     # a recording from a CARLA server (carla/source.py)


def data_source(source_id: str) -> DataSource:
    """The source registered as ``source_id`` (a ``datasets.<ds>.source`` value)."""
    return SOURCES[source_id]
