"""The data sources of sets A, B, C at work: the module of each, by its ``datasets.<ds>.source.id``.

A source is one module of this package, named after its id, that says what it does in each data
stage, and one registration, its settings model in :mod:`compact_perception.core.params.sources`
(its id, the settings of ``datasets.<ds>.source``, its report label and its stage deps):

- ``write_raw(params, dataset_id, out_dir)``: the generate stage's ``data/raw/<ds>``; raw records
  (:mod:`compact_perception.data.record`) or, for a source without them, a manifest;
- ``draw_example(params, dataset_id, raw_dir, figure)``: the generate stage's example frame,
  ``reports/figures/world_<ds>.png`` (drawn by :mod:`compact_perception.data.figures_generate`);
- ``cache``: ``None`` when ``data/raw/<ds>`` holds raw records, which the preprocess stage reads;
  else ``cache(params, dataset_id, raw_dir, out_dir) -> Path``, the source's own conversion into
  the cache (:mod:`compact_perception.core.cache`).

The generate stage (``pipeline/generate.py``) and :func:`compact_perception.data.preprocess.preprocess_dataset`
look the source up here (:func:`data_source`) and call it; neither names a source. This package
imports every module in it; the folder is one dependency of both stages in ``dvc.yaml``, beside
the code the sources run (each registration's ``deps``).
"""
from __future__ import annotations

from pathlib import Path
from types import ModuleType
from typing import Callable, Optional, Protocol

from ...core.params import SOURCES, Params
from ...core.registry import import_submodules


class DataSource(Protocol):
    """What a source module defines (see the module docstring)."""

    cache: Optional[Callable[[Params, str, Path, Path], Path]]

    def write_raw(self, params: Params, dataset_id: str, out_dir: Path) -> None: ...

    def draw_example(self, params: Params, dataset_id: str, raw_dir: Path, figure: Path) -> None: ...


#: source id -> its module (every module of this package, by name)
MODULES: dict[str, ModuleType] = import_submodules(__name__, __path__)


def data_source(source_id: str) -> DataSource:
    """The module of the source registered as ``source_id`` (a ``datasets.<ds>.source.id``)."""
    SOURCES[source_id]  # an unknown id names the registered ones
    if source_id not in MODULES:
        raise KeyError(f"data source {source_id!r} is registered but has no module data/sources/{source_id}.py")
    return MODULES[source_id]
