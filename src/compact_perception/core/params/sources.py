"""The data sources of sets A, B and C: each source is one registration here and one module.

``datasets.<ds>.source`` is a section whose ``id`` names the source and whose other keys are that
source's settings; the section is validated as the union of the registered settings models,
discriminated by ``id`` (:data:`SourceSettings`), so a set carries the settings of its own source
only. A source's registration is its settings model, decorated with :func:`register_source`,
which gives

- its id (``datasets.<ds>.source.id``; the settings model's ``id`` field is that literal),
- its label: how a report names data from it (a cache's ``meta.json`` ``source``),
- its stage deps: the code beyond its module that the generate and preprocess stages run for it
  (``dvc.yaml`` lists them under both stages, ``tests/test_dvc_deps.py`` checks, and that its
  module imports them), and
- its module, ``compact_perception.data.sources.<id>``, named after it, which does the work in
  each data stage (``write_raw``, ``draw_example``, ``cache``; :mod:`compact_perception.data.sources`).

docs/extending.md ("A data source") has the checklist; ``tests/test_extending.py`` adds a toy
source that way and runs the generate and preprocess stages on it.

nuScenes is not a source of this kind: its data are a devkit dataroot with their own scenes, 32
classes and split rule rather than a CARLA-like set split by towns, so it keeps two stages of its
own (``nuscenes_sim``, ``ingest_nuscenes``); :data:`NUSCENES_INPUTS` labels its two inputs.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Callable, Literal, TypeVar, Union

from pydantic import Field, field_validator

from ..registry import Registry
from .base import Strict

__all__ = ["SourceInfo", "SOURCES", "register_source", "SourceSettings", "source_label",
           "NUSCENES_INPUTS", "SimSource", "AuthorsSource", "AuthorsSplits", "CarlaSource"]

S = TypeVar("S", bound=type)


@dataclass(frozen=True)
class SourceInfo:
    """A data source's registration."""

    label: str                               # a report's name for data from it
    settings: type                           # its settings model (the section datasets.<ds>.source)
    deps: tuple[str, ...] = ()               # code beyond its module the data stages run for it (dvc.yaml deps)


SOURCES: Registry[SourceInfo] = Registry("data source", ordered=True)


def register_source(source_id: str, *, label: str, deps: tuple[str, ...] = ()) -> Callable[[S], S]:
    """Decorator: register the settings model it decorates as data source ``source_id`` (whose
    ``id`` field must be ``Literal[source_id]``), with its report label and stage deps."""

    def deco(settings: S) -> S:
        field = getattr(settings, "model_fields", {}).get("id")
        if field is None or getattr(field.annotation, "__args__", None) != (source_id,):
            raise TypeError(f"data source {source_id!r}: {settings.__name__} needs the field id: "
                            f"Literal[{source_id!r}]")
        SOURCES.register(source_id)(SourceInfo(label, settings, tuple(deps)))
        return settings

    return deco


#: What a nuScenes cache records as its ``source`` (the real dataroot or the simulated export) and
#: how a report names it; nuScenes has stages of its own (see the module docstring).
NUSCENES_INPUTS: dict[str, str] = {"nuscenes-lidarseg": "nuScenes-lidarseg",
                                   "simulated nuScenes-format": "simulated nuScenes-format"}


def source_label(source: str) -> str:
    """The report label of a cache's ``source`` (the raw value where none is registered)."""
    if source in SOURCES:
        return SOURCES[source].label
    return NUSCENES_INPUTS.get(source, source)


# ----------------------------------------------------------------------------- the registered sources
@register_source("sim", label="simulated (embedded world)", deps=("src/compact_perception/data/world",))
class SimSource(Strict):
    """The embedded procedural world (``world.*`` sets its sensors; the dataset's towns, frames and
    splits what it renders). No settings of its own."""

    id: Literal["sim"]


class AuthorsSplits(Strict):
    """Split folders of the authors' release (``<root>/<folder>/data_info.yml``, e.g. Tr1,
    Va2, Te2); a folder's first two letters name its frame folder (Tr1 -> TrSet)."""

    train: str
    val: str
    test: str

    @field_validator("train", "val", "test")
    @classmethod
    def _folder(cls, v: str) -> str:
        if v[:2] not in ("Tr", "Va", "Te") or "/" in v or "\\" in v or v in ("TrSet", "VaSet", "TeSet"):
            raise ValueError(f"expected a split folder name starting with Tr, Va or Te (e.g. Tr1, Va2, Te12345), got {v!r}")
        return v


@register_source("authors", label="authors' CARLA dataset", deps=("src/compact_perception/data/authors.py",))
class AuthorsSource(Strict):
    """The authors' released CARLA dataset (docs/data-formats.md): its folder and the three split
    folders used (the paper: A Tr1/Va2/Te2, B Tr2/Va1/Te1, C Tr12345/Va12345/Te12345)."""

    id: Literal["authors"]
    root: str = Field(min_length=1, description="the release's dataset/ folder")
    splits: AuthorsSplits


@register_source("carla", label="CARLA recording", deps=("src/compact_perception/data/carla",))
class CarlaSource(Strict):
    """A dataset recorded from a CARLA server (``source: {id: carla, ...}``; docs/carla.md): what
    ``python -m pipeline.collect_carla --dataset <ds>`` connects to and records, and the folder
    it writes (``root``), which ``generate@<ds>`` validates and brings into ``data/raw/<ds>``.
    The towns are the dataset's ``train_towns``/``eval_towns`` (town01 -> CARLA's Town01), the
    frames and splits its ``frames``/``split_ratio``, the seed ``seed`` + ``seed_offset``, the
    sensor rig ``world.camera``/``world.lidar``/``world.dvs`` at ``world.resolution``."""

    id: Literal["carla"]
    root: str = Field(min_length=1, description="folder the collector writes (never data/raw/<ds>, a DVC output)")
    host: str = Field(min_length=1, description="CARLA server address")
    port: int = Field(ge=1, le=65535, description="CARLA server RPC port (CarlaUE4.sh -carla-rpc-port)")
    timeout_s: float = Field(gt=0.0, le=600.0, description="connection timeout and each sensor's timeout per tick")
    load_world_timeout_s: float = Field(gt=0.0, le=3600.0, description="the client's time-out while the server loads "
                                        "a town (a large map takes longer than a tick)")
    fixed_delta_s: float = Field(gt=0.0, le=0.5, description="synchronous simulation step; "
                                 "world.dvs.step_s / fixed_delta_s ticks make one recorded frame")
    frames_per_episode: int = Field(ge=1, le=10000, description="consecutive frames of one drive (episode length)")
    warmup_ticks: int = Field(ge=0, le=10000, description="ticks driven before an episode's first frame")
    vehicles: int = Field(ge=0, le=1000, description="traffic vehicles on the autopilot")
    pedestrians: int = Field(ge=0, le=1000, description="pedestrians walking to random places")
    times: list[Literal["morning", "noon", "evening", "night"]] = Field(min_length=1, description="drawn per episode")
    weathers: list[Literal["sunny", "cloudy", "rainy", "foggy"]] = Field(min_length=1, description="drawn per episode")

    @field_validator("root")
    @classmethod
    def _root(cls, v: str) -> str:
        parts = Path(v).parts
        if len(parts) >= 2 and parts[-2] == "raw" and "data" in parts[:-2]:
            raise ValueError(f"{v!r} is inside data/raw, which generate writes; record elsewhere (e.g. data/carla/A)")
        return v


#: ``datasets.<ds>.source``: one of the registered settings models, chosen by its ``id``.
SourceSettings = Annotated[Union[tuple(SOURCES[k].settings for k in SOURCES.keys())], Field(discriminator="id")]
