"""Typed schema of params.yaml (SPEC 9): unknown keys and wrong types are errors
whose message names the offending key.

Types are strict: a bool or a string never passes as a number (``batch_size: true`` is an
error, not 1), a YAML int passes where a float is expected. Every setting that can change a
result is required, so params.yaml spells out every value a result depends on and no default
hides in code; only settings that cannot change a result (worker counts, the device
preference) have defaults. An optional override (a model's ``max_epochs``, an optimiser's own
settings) is absent when not used.

A model's training recipe is ``train.recipe`` (the base every model shares) merged with
``train.models.<id>`` (what that model changes): :func:`merge_recipe`, applied by the schema, so
``Params.train.models[id]`` is the whole recipe. A recipe's loss-weighting settings sit in a
section named after its weighting (``mgn: {...}``), validated by that method's own schema
(``compact_perception.weighting``), which this module does not import (no torch here).

``scale`` is the one switch (README "Scale"): ``default`` (a 2-core CPU, under an hour for the
whole pipeline: set A's main ablation trained deep, the rest shallow), ``full`` (the same data,
every dataset, model, seed and the study trained to the plateau: hours on a CPU) and ``paper``
(the paper's frames, resolution and schedule: a GPU). Every value that differs between them is
written as ``{default: ..., full: ..., paper: ...}`` (a :class:`Scaled`) and resolved with
:meth:`Scaled.at`.

How deep a run trains is its dataset's ``training`` (:class:`TrainingBudget`: the compact
models' seeds and the epoch cap; a recipe's own ``max_epochs`` overrides the cap): early stopping
(``train.early_stop_patience``) ends a run when validation stops improving, the cap only bounds it.
"""
from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, Callable, Generic, Literal, Optional, TypeVar

import yaml
from pydantic import (BaseModel, ConfigDict, Field, PrivateAttr, ValidationError, ValidatorFunctionWrapHandler,
                      field_validator, model_validator)
from pydantic_core import InitErrorDetails, PydanticCustomError

from . import catalog

T = TypeVar("T")

TOWNS = ("town01", "town02", "town03", "town04", "town05")
# Model and dataset ids live in the registries (compact_perception.core.catalog, no torch): the recipes
# of train.models must be of registered models.
ScaleName = Literal["default", "full", "paper"]
#: The values of ``scale``, each a field of every :class:`Scaled`.
SCALES: tuple[str, ...] = ("default", "full", "paper")


class Strict(BaseModel):
    """Base for every section: unknown keys are rejected, types are strict (no bool/str -> int),
    and a float must be finite (YAML's ``.inf``/``.nan`` are errors: an infinite lr diverges)."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)


class Scaled(Strict, Generic[T]):
    """A value that differs between the scales (``default``, ``full``, ``paper``)."""

    default: T
    full: T
    paper: T

    def at(self, scale: ScaleName) -> T:
        return getattr(self, scale)


def _scaled_at_least(v: Optional[Scaled[int]], lo: int) -> Optional[Scaled[int]]:
    """Every scale of an integer :class:`Scaled` count is ``>= lo``."""
    if v is not None:
        for name in SCALES:
            if getattr(v, name) < lo:
                raise ValueError(f"{name} must be at least {lo}, got {getattr(v, name)}")
    return v


def _scaled_at_most(v: Optional[Scaled[int]], hi: int, why: str) -> Optional[Scaled[int]]:
    """Every scale of an integer :class:`Scaled` count that sizes memory, processes or disk is
    ``<= hi``: ``default: 1000000000 exceeds 1000000 (<why>)``, before any work starts."""
    if v is not None:
        for name in SCALES:
            if getattr(v, name) > hi:
                raise PydanticCustomError("too_large", "{scale}: {value} exceeds {hi} ({why})",
                                          {"scale": name, "value": getattr(v, name), "hi": hi, "why": why})
    return v


#: Upper bounds of the counts that size memory, processes or disk (issue 26): far above every
#: scale's value (the paper's 10000 frames, 850 scenes, batch 6), far below what exhausts a machine.
MAX_FRAMES = 1_000_000
MAX_SCENES = 10_000
MAX_WORKERS = 256
MAX_BATCH = 1024
MAX_SAVED_PREDICTIONS = 10_000


# ----------------------------------------------------------------------------- world
class CameraParams(Strict):
    """RGB/DVS/semantic/depth cameras (paper section IV-A, Fig. 4)."""

    fov_deg: float = Field(gt=10.0, lt=170.0, description="horizontal and vertical FOV (paper 90)")
    pitch_deg: float = Field(ge=-45.0, le=45.0, description="upward rotation (paper 20)")
    height_m: float = Field(gt=0.2, le=4.0)
    mount_offset_m: float = Field(ge=0.0, le=3.0, description="distance from the ego centre")


class LidarParams(Strict):
    """Roof LiDAR (paper section IV-A)."""

    channels: int = Field(ge=4, le=256)
    upper_fov_deg: float = Field(gt=-90.0, lt=90.0)
    lower_fov_deg: float = Field(gt=-90.0, lt=90.0)
    range_m: float = Field(gt=1.0, le=200.0)
    height_m: float = Field(gt=0.5, le=5.0)
    horizontal_samples: int = Field(ge=64, le=8192, description="rays per laser per revolution")

    @model_validator(mode="after")
    def _fov_order(self) -> "LidarParams":
        if self.lower_fov_deg >= self.upper_fov_deg:
            raise ValueError("lower_fov_deg must be below upper_fov_deg")
        return self


class DvsParams(Strict):
    contrast_threshold: float = Field(gt=0.0, le=5.0, description="log-intensity change per event (CARLA 0.3)")
    step_s: float = Field(gt=0.0, le=2.0, description="simulated time between the two compared steps")


class ConditionParams(Strict):
    """Per-frame time of day and weather draws (SPEC 3.1)."""

    times: list[Literal["morning", "noon", "evening", "night"]] = Field(min_length=1)
    weathers: list[Literal["sunny", "cloudy", "rainy", "foggy"]] = Field(min_length=1)
    combine_probability: float = Field(ge=0.0, le=1.0, description="chance a second weather is mixed in")


class WorldParams(Strict):
    resolution: Scaled[int]
    camera: CameraParams
    lidar: LidarParams
    dvs: DvsParams
    conditions: ConditionParams
    frames_per_episode: int = Field(ge=1, le=10000, description="consecutive frames of one drive (a 'scene')")
    workers: int = Field(ge=1, le=MAX_WORKERS, description="generator processes: any count gives the same files")

    @field_validator("resolution")
    @classmethod
    def _res(cls, v: Scaled[int]) -> Scaled[int]:
        """What every registered network takes: GradNorm SegNet's five 2x2 poolings need a
        multiple of 32 (16 px leaves its fifth pooling nothing to pool; models/segnet.py)."""
        for name in SCALES:
            r = getattr(v, name)
            if not 32 <= r <= 1024 or r % 32:
                raise ValueError(f"resolution.{name} must be a multiple of 32 in [32, 1024] (GradNorm SegNet's "
                                 f"five 2x2 poolings), got {r}")
        return v


# ----------------------------------------------------------------------------- datasets
class AuthorsSplits(Strict):
    """Split folders of the authors' release (``<authors_root>/<folder>/data_info.yml``, e.g. Tr1,
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


class CarlaSource(Strict):
    """A dataset recorded from a CARLA server (``source: carla``; docs/carla.md): what
    ``python -m pipeline.collect_carla --dataset <ds>`` connects to and records, and the folder
    it writes (``root``), which ``generate@<ds>`` validates and brings into ``data/raw/<ds>``.
    The towns are the dataset's ``train_towns``/``eval_towns`` (town01 -> CARLA's Town01), the
    frames and splits its ``frames``/``split_ratio``, the seed ``seed`` + ``seed_offset``, the
    sensor rig ``world.camera``/``world.lidar``/``world.dvs`` at ``world.resolution``."""

    root: str = Field(min_length=1, description="folder the collector writes (never data/raw/<ds>, a DVC output)")
    host: str = Field(min_length=1, description="CARLA server address")
    port: int = Field(ge=1, le=65535, description="CARLA server RPC port (CarlaUE4.sh -carla-rpc-port)")
    timeout_s: float = Field(gt=0.0, le=600.0, description="connection timeout and each sensor's timeout per tick")
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


class SplitRatio(Strict):
    """Integer shares of the train / val / test splits (the paper's Table I: 3:1:1)."""

    train: int = Field(ge=1)
    val: int = Field(ge=1)
    test: int = Field(ge=1)

    def counts(self, frames: int) -> dict[str, int]:
        """Frames per split: floor shares for train and val, the rest to test."""
        total = self.train + self.val + self.test
        n = {"train": frames * self.train // total, "val": frames * self.val // total}
        n["test"] = frames - n["train"] - n["val"]
        return n


def _scaled_distinct_seeds(v: Scaled[list[int]]) -> Scaled[list[int]]:
    """Training seeds at every scale: a non-empty list of distinct non-negative integers."""
    for name in SCALES:
        seeds = getattr(v, name)
        if not seeds or any(k < 0 for k in seeds) or len(set(seeds)) != len(seeds):
            raise ValueError(f"{name}: expected a non-empty list of distinct non-negative integers, got {seeds}")
    return v


class TrainingBudget(Strict):
    """How deep a dataset's runs train (section IV-D; README "Scale"): the training seeds of the
    compact models (each (model, seed) one run, ``runs/<ds>/<model>/seed<k>``) and the epoch cap.
    Early stopping (``train.early_stop_patience`` epochs without a new best) ends a run; the cap
    bounds it where the budget allows no more (a run's ``summary.json`` says which ended it)."""

    seeds: Scaled[list[int]]
    max_epochs: Scaled[int]

    @field_validator("seeds")
    @classmethod
    def _seeds(cls, v: Scaled[list[int]]) -> Scaled[list[int]]:
        return _scaled_distinct_seeds(v)

    @field_validator("max_epochs")
    @classmethod
    def _epochs(cls, v: Scaled[int]) -> Scaled[int]:
        return _scaled_at_least(v, 1)


class SimDatasetParams(Strict):
    """A simulated dataset (A, B, C): town splits of paper Table I."""

    source: Literal["sim", "authors", "carla"]
    authors_root: Optional[str] = Field(description="root of the authors' released dataset (source: authors); null otherwise")
    authors_splits: AuthorsSplits = Field(description="split folders used with source: authors (paper: "
                                          "A Tr1/Va2/Te2, B Tr2/Va1/Te1, C Tr12345/Va12345/Te12345)")
    frames: Scaled[int]
    split_ratio: Scaled[SplitRatio] = Field(description="train:val:test shares (paper 3:1:1); the default scale "
                                            "gives the test split more frames, so frame sampling is not the main noise")
    train_towns: list[str]
    eval_towns: list[str]
    split_by: Literal["town", "episode"]
    seed_offset: int = Field(ge=0, description="added to the top-level seed for this dataset's episodes")
    carla: CarlaSource = Field(description="the CARLA server and recording folder of source: carla")
    training: TrainingBudget

    @field_validator("train_towns", "eval_towns")
    @classmethod
    def _towns(cls, v: list[str]) -> list[str]:
        if not v:
            raise ValueError("needs at least one town")
        bad = [t for t in v if t not in TOWNS]
        if bad:
            raise ValueError(f"unknown town(s) {bad}; known: {list(TOWNS)}")
        return v

    @field_validator("frames")
    @classmethod
    def _frames(cls, v: Scaled[int]) -> Scaled[int]:
        _scaled_at_most(v, MAX_FRAMES, "frames a dataset may have")
        return _scaled_at_least(v, 5)  # one frame per split at least

    @model_validator(mode="after")
    def _authors(self) -> "SimDatasetParams":
        if self.source == "authors" and not self.authors_root:
            raise ValueError("source 'authors' needs authors_root")
        return self


class NuScenesParams(Strict):
    """nuScenes-lidarseg (section IV-B). With no dataroot a simulated nuScenes-format set is written."""

    dataroot: Optional[str] = Field(description="a nuScenes-lidarseg dataroot; null = the simulated export")
    version: str = Field(min_length=1)
    sim_scenes: Scaled[int]
    sim_samples_per_scene: int = Field(ge=2, le=100)
    split_seed: int = Field(ge=0)
    training: TrainingBudget

    @field_validator("sim_scenes")
    @classmethod
    def _scenes(cls, v: Scaled[int]) -> Scaled[int]:
        _scaled_at_most(v, MAX_SCENES, "simulated scenes a dataset may have")
        return _scaled_at_least(v, 3)  # one scene per split at least


class DatasetsParams(Strict):
    A: SimDatasetParams
    B: SimDatasetParams
    C: SimDatasetParams
    nuscenes: NuScenesParams


# ----------------------------------------------------------------------------- preprocessing
class PreprocessParams(Strict):
    """Section IV-C, eq. (1)-(5)."""

    lidar_range_m: float = Field(gt=1.0)
    z_min_m: float
    z_max_m: float
    height_multiplier: int = Field(ge=1, le=64, description="eq. (5): channels 0..multiplier")
    fill_neighbours: bool
    workers: int = Field(ge=1, le=MAX_WORKERS, description="preprocessing processes: any count gives the same cache")

    @model_validator(mode="after")
    def _z(self) -> "PreprocessParams":
        if self.z_min_m >= self.z_max_m:
            raise ValueError("z_min_m must be below z_max_m")
        return self


# ----------------------------------------------------------------------------- training
def check_lr_floor(lr: float, lr_min: float) -> None:
    """The plateau halving's floor (section IV-D; MGN's weight lr too) must not exceed the lr it
    starts from."""
    if lr_min > lr:
        raise ValueError(f"lr_min ({lr_min}) must not exceed lr ({lr})")


def _plain(value: Any) -> Any:
    """``value`` as plain YAML data (dicts and lists), whatever mapping type held it."""
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_plain(v) for v in value]
    return value


def merge_recipe(base: Mapping[str, Any], changes: Mapping[str, Any]) -> dict[str, Any]:
    """The recipe ``base`` with ``changes`` applied: a key of ``changes`` replaces the base's, a
    null removes it (``momentum: null`` for an Adam recipe), and a new ``weighting`` drops the
    base's section of the weighting it replaces. Used for ``train.recipe`` + ``train.models.<id>``
    and for a study arm on its base model's recipe."""
    merged = _plain(base)
    old = merged.get("weighting")
    if "weighting" in changes and isinstance(old, str) and changes["weighting"] != old:
        merged.pop(old, None)
    merged.update(_plain(changes))
    return {k: v for k, v in merged.items() if v is not None}


def _error(key: str, value: Any, message: str) -> InitErrorDetails:
    """A validation error at ``key`` (a model validator's errors sit at the model otherwise)."""
    return InitErrorDetails(type=PydanticCustomError("recipe_key", message), loc=(key,), input=value)


def _from_base(key: str) -> str:
    """The params key of the base recipe's ``key``."""
    return f"train.recipe.{key}"


def _inherited(merged: Mapping[str, Any], changes: Mapping[str, Any], source: Callable[[str], str]) -> dict[str, str]:
    """The keys of a merged recipe that its base supplies, each with the params key holding its value."""
    return {k: source(k) for k in merged if k not in changes}


def _in_params(loc: tuple, key: str, inherited: Mapping[str, str]) -> tuple:
    """Location ``loc`` inside the recipe read at params key ``key`` (``""``: not read from params),
    as the params key that holds the value there."""
    if loc and loc[0] in inherited:
        return (*inherited[loc[0]].split("."), *loc[1:])
    return (*(key.split(".") if key else ()), *loc)


class ModelRecipe(Strict):
    """One model's training recipe (``train.recipe`` merged with ``train.models.<id>``).
    ``weighting`` names a loss weighting of the registry (``compact_perception.weighting.WEIGHTINGS``);
    its settings sit in a section of the same name (``mgn: {...}``), checked against that method's
    own schema when the training or study stage starts (``weighting.weighting_settings``). Only
    the named method's section is allowed.

    A recipe read from params knows where each of its values is written (:meth:`key_of`): its
    own key, or ``train.recipe`` for what it inherits (error messages and the params audit use it)."""

    model_config = ConfigDict(extra="allow", frozen=True, strict=True)

    optimizer: Literal["sgd", "adam"]
    de_loss: Optional[Literal["huber", "smooth_l1"]] = Field(
        None, description="compact models' DE loss: 'huber' = eq. (2) with delta 0.5 (the paper), 'smooth_l1' = "
                          "torch's smooth_l1_loss(beta=0.5) = eq. (2) / delta (the authors' code); required for "
                          "the compact models, not allowed for the baselines (their own losses)")
    plateau_rule: Literal["paper", "torch"] = Field(
        description="lr halving on a validation-TM plateau (main lr and MGN's weight lr): 'paper' = after "
                    "train.plateau_patience epochs without a drop (section IV-D); 'torch' = PyTorch's "
                    "ReduceLROnPlateau as in the authors' code: after more than plateau_patience epochs without a "
                    "relative drop of train.plateau_threshold")
    lr: float = Field(gt=0.0)
    lr_min: float = Field(gt=0.0)
    momentum: Optional[float] = Field(None, ge=0.0, lt=1.0, description="SGD momentum: required with sgd, "
                                      "not allowed with adam (which has none)")
    betas: Optional[list[float]] = Field(None, description="Adam's (beta1, beta2): required with adam, "
                                         "not allowed with sgd")
    eps: Optional[float] = Field(None, gt=0.0, description="Adam's epsilon: required with adam, not allowed with sgd")
    weight_decay: float = Field(ge=0.0)
    weighting: str = Field(min_length=1, description="a loss weighting id (weighting.WEIGHTINGS)")
    max_epochs: Optional[Scaled[int]] = Field(None, description="overrides the dataset's epoch cap "
                                              "(datasets.<ds>.training.max_epochs) for this model")

    _key: str = PrivateAttr("")                                  # the params key of this recipe
    _inherited: dict[str, str] = PrivateAttr(default_factory=dict)  # key -> where its value is written

    @field_validator("max_epochs")
    @classmethod
    def _epochs(cls, v: Optional[Scaled[int]]) -> Optional[Scaled[int]]:
        return _scaled_at_least(v, 1)

    @model_validator(mode="after")
    def _optimizer_settings(self) -> "ModelRecipe":
        if self.optimizer == "sgd" and self.momentum is None:
            raise ValueError("momentum: required with optimizer 'sgd' (the paper's 0.9)")
        if self.optimizer == "adam" and self.momentum is not None:
            raise ValueError("momentum: not used by optimizer 'adam'; remove the key")
        if self.optimizer == "adam" and (self.betas is None or self.eps is None):
            raise ValueError("betas and eps: required with optimizer 'adam' (PyTorch's [0.9, 0.999] and 1.0e-8)")
        if self.optimizer == "sgd" and (self.betas is not None or self.eps is not None):
            raise ValueError("betas/eps: not used by optimizer 'sgd'; remove the keys")
        if self.betas is not None and (len(self.betas) != 2 or not all(0.0 <= b < 1.0 for b in self.betas)):
            raise ValueError(f"betas: expected two numbers in [0, 1), got {self.betas}")
        check_lr_floor(self.lr, self.lr_min)
        return self

    @model_validator(mode="after")
    def _weighting_section(self) -> "ModelRecipe":
        """Besides the schema's keys, only the section named by ``weighting``, a mapping; each error
        is placed at its key."""
        errors = []
        for key, value in (self.model_extra or {}).items():
            if key != self.weighting:
                errors.append(_error(key, value, "unknown key (not in the schema, and not the settings section "
                                                 "of the recipe's weighting)"))
            elif not isinstance(value, dict):
                errors.append(_error(key, value, "expected a mapping of the weighting's settings"))
        if errors:
            raise ValidationError.from_exception_data(type(self).__name__, errors)
        return self

    def section(self, name: str) -> dict:
        """The settings section ``name`` (the weighting's own params), ``{}`` when absent."""
        return dict((self.model_extra or {}).get(name) or {})

    def key_of(self, name: str) -> str:
        """The params key that holds this recipe's value of ``name`` (``train.recipe.lr`` for an
        inherited lr); just ``name`` for a recipe not read from params."""
        return ".".join(_in_params((name,), self._key, self._inherited))

    def placed(self, key: str, inherited: Mapping[str, str]) -> "ModelRecipe":
        """This recipe, recorded as read from params key ``key``, its ``inherited`` keys from elsewhere."""
        self._key, self._inherited = key, dict(inherited)
        return self


class TrainParams(Strict):
    """Section IV-D: batch 6, SGD, plateau halving, early stop, best checkpoint."""

    batch_size: int = Field(ge=1, le=MAX_BATCH)
    plateau_patience: int = Field(ge=1)
    plateau_factor: float = Field(gt=0.0, lt=1.0)
    plateau_threshold: float = Field(ge=0.0, lt=1.0, description="relative improvement the 'torch' plateau "
                                     "rule requires (ReduceLROnPlateau's threshold, mode 'rel')")
    early_stop_patience: Scaled[int] = Field(description="epochs without a new best validation score "
                                             "that end a run (section IV-D: 25)")
    num_workers: int = Field(ge=0, le=MAX_WORKERS, description="loader processes: any count gives the same result")
    parallel_runs: int = Field(ge=1, le=MAX_WORKERS, description="runs a stage trains side by side, each in its own "
                               "process with num_threads threads (training/parallel.py): any count gives the "
                               "same result")
    num_threads: int = Field(ge=1, le=MAX_WORKERS, description="torch intra-op threads: a threaded reduction's "
                             "result depends on the count, so it is a tracked param (determinism.set_threads)")
    device: Literal["auto", "cpu", "cuda"]
    precision: Literal["fp32", "bf16", "fp16", "auto"] = Field(
        description="fp32 (bit-reproducible), bf16/fp16 autocast, or auto: the fastest the hardware runs "
                    "natively (precision.resolve_precision); anything but fp32 lifts the CPU kernel pins")
    channels_last: bool = Field(description="NHWC memory format for the convolutions")
    compile: bool = Field(description="torch.compile the forward (falls back to eager with one warning)")
    recipe: dict[str, Any] = Field(description="the base recipe: every key of a model's recipe that "
                                   "train.models.<id> does not set")
    models: dict[str, ModelRecipe] = Field(description="model id -> what its recipe changes in `recipe` (null "
                                           "removes a key); read here as the merged recipe (merge_recipe)")

    @model_validator(mode="wrap")
    @classmethod
    def _merge_recipes(cls, data: Any, handler: ValidatorFunctionWrapHandler) -> "TrainParams":
        """Each ``models.<id>`` validated as ``recipe`` merged with it, knowing which keys it inherits."""
        base, changes = (data.get("recipe"), data.get("models")) if isinstance(data, dict) else (None, None)
        if not isinstance(base, dict) or not isinstance(changes, dict):
            return handler(data)  # the field errors name what is missing or wrong
        merged = {m: merge_recipe(base, c) if isinstance(c, dict) else c for m, c in changes.items()}
        train = handler({**data, "models": merged})
        for m, recipe in train.models.items():
            recipe.placed(f"train.models.{m}", _inherited(merged[m], changes[m], _from_base))
        return train

    @field_validator("early_stop_patience")
    @classmethod
    def _patience(cls, v: Scaled[int]) -> Scaled[int]:
        return _scaled_at_least(v, 1)

    @field_validator("models", mode="before")
    @classmethod
    def _registered(cls, v: Any) -> Any:
        unknown = [m for m in v if m not in catalog.MODELS] if isinstance(v, dict) else []
        if unknown:
            raise ValueError(f"unknown model id(s) {unknown}; registered (core/catalog.py): "
                             f"{list(catalog.model_ids())}")
        return v



#: The dataset ids params.yaml knows (the sections of ``datasets``).
DATASET_IDS: list[str] = list(DatasetsParams.model_fields)


def _unknown_datasets(ids: list[str]) -> list[str]:
    """The ids in ``ids`` that are not a section of ``datasets``."""
    return [d for d in ids if d not in DATASET_IDS]


class StudyParams(Strict):
    """The loss-balancing study (beyond the paper): the compact 15L network trained with each
    weighting method ("arm") on ``datasets`` at every seed of ``seeds``. An arm is the base model's
    recipe with its ``weighting`` (and that method's section) replaced by the arm's. The arms
    "static", "mgn" and "mgn_authors" are not retrained here: they are the runs of
    compact_15l, compact_15l_mgn and compact_15l_mgn_authors."""

    datasets: Scaled[list[str]]
    base_model: Literal["compact_15l"] = Field(description="the network and recipe every arm shares")
    arm_ids: list[str] = Field(min_length=1, description="the arms trained by the study stage (its DVC matrix)")
    arms: dict[str, dict] = Field(description="arm id -> {weighting: <id>, <id>: {settings}}")

    @field_validator("datasets")
    @classmethod
    def _datasets(cls, v: Scaled[list[str]]) -> Scaled[list[str]]:
        for name in SCALES:  # an empty list: the study does not run at that scale
            ds = getattr(v, name)
            if _unknown_datasets(ds) or len(set(ds)) != len(ds):
                raise ValueError(f"{name}: expected distinct ids of {DATASET_IDS}, got {ds}")
        return v

    @model_validator(mode="after")
    def _arms(self) -> "StudyParams":
        if sorted(self.arm_ids) != sorted(self.arms) or len(set(self.arm_ids)) != len(self.arm_ids):
            raise ValueError(f"arm_ids {self.arm_ids} must list each key of arms {sorted(self.arms)} once")
        for arm, spec in self.arms.items():
            if not isinstance(spec.get("weighting"), str) or set(spec) - {"weighting", spec["weighting"]}:
                raise ValueError(f"arms.{arm}: expected {{weighting: <id>, <id>: {{settings}}}}, got {spec}")
        return self


class EvalParams(Strict):
    figure_frame: int = Field(ge=0, description="test frame shown in the qualitative figures")
    save_predictions: int = Field(ge=0, le=MAX_SAVED_PREDICTIONS, description="test frames whose predictions are saved")
    depth_max_m: float = Field(gt=3.34, le=1000.0, description="metric-depth evaluation: ground truth capped at this "
                               "depth (m) and predictions clamped to it (the field's convention: 80 m)")


class BenchmarkParams(Strict):
    warmup: int = Field(ge=0)
    runs: int = Field(ge=3)


class Params(Strict):
    scale: ScaleName
    seed: int = Field(ge=0)
    baseline_seeds: Scaled[list[int]] = Field(description="training seeds of the baselines on every dataset "
                                              "(the compact models': datasets.<ds>.training.seeds)")

    sim_ids: list[str] = Field(min_length=1, description="simulated datasets (generate/preprocess matrix)")
    dataset_ids: list[str] = Field(min_length=1, description="datasets trained and evaluated (train/evaluate matrix)")
    model_ids: list[str] = Field(min_length=1, description="the models each dataset's train stage trains and its "
                                 "evaluate stage scores")

    @field_validator("baseline_seeds")
    @classmethod
    def _seeds(cls, v: Scaled[list[int]]) -> Scaled[list[int]]:
        return _scaled_distinct_seeds(v)

    @field_validator("sim_ids", "dataset_ids", "model_ids")
    @classmethod
    def _ids(cls, v: list[str]) -> list[str]:
        if len(set(v)) != len(v):
            raise ValueError(f"expected distinct ids, got {v}")
        return v

    @model_validator(mode="after")
    def _id_lists(self) -> "Params":
        for key in ("sim_ids", "dataset_ids"):
            bad = _unknown_datasets(getattr(self, key))
            if bad:
                raise ValueError(f"{key}: unknown dataset(s) {bad}; known: {DATASET_IDS}")
        unknown = [m for m in self.model_ids if m not in catalog.MODELS]
        if unknown:
            raise ValueError(f"model_ids: unknown model(s) {unknown}; registered (core/catalog.py): "
                             f"{list(catalog.model_ids())}")
        missing = [m for m in self.model_ids if m not in self.train.models]
        if missing:
            raise ValueError(f"model_ids: no recipe train.models.<id> for {missing}")
        return self

    def study_recipe(self, arm: str, source: str = "params.yaml") -> ModelRecipe:
        """The recipe of study arm ``arm``: ``study.base_model``'s recipe with the arm's weighting and
        its section (:func:`merge_recipe`); ``source`` names the params file in errors."""
        if arm not in self.study.arms:
            raise ParamsError(f"{source}: study.arms: no arm {arm!r}; known: {sorted(self.study.arms)}")
        key, base, spec = f"study.arms.{arm}", self.train.models[self.study.base_model], _plain(self.study.arms[arm])
        merged = merge_recipe(base.model_dump(exclude_none=True), spec)
        inherited = _inherited(merged, spec, base.key_of)
        try:
            recipe = ModelRecipe.model_validate(merged)
        except ValidationError as err:
            raise ParamsError(_format(err, source, lambda loc: _in_params(loc, key, inherited))) from None
        return recipe.placed(key, inherited)

    def seeds_of(self, group: str, dataset: str) -> list[int]:
        """The training seeds of a model group (``catalog.ModelInfo.group``) on ``dataset`` at this
        scale: ``datasets.<ds>.training.seeds`` for ``compact``, ``baseline_seeds`` for ``baseline``."""
        if group not in ("compact", "baseline"):
            raise ValueError(f"unknown model group {group!r}; known: compact, baseline")
        seeds = self.dataset(dataset).training.seeds if group == "compact" else self.baseline_seeds
        return list(seeds.at(self.scale))

    def max_epochs_of(self, recipe: ModelRecipe, dataset: str) -> int:
        """The epoch cap of a run of ``recipe`` on ``dataset``: the recipe's own ``max_epochs`` where
        it has one (a costly baseline), else ``datasets.<ds>.training.max_epochs``, at this scale."""
        cap = recipe.max_epochs if recipe.max_epochs is not None else self.dataset(dataset).training.max_epochs
        return cap.at(self.scale)

    def dataset(self, dataset: str) -> "SimDatasetParams | NuScenesParams":
        """The ``datasets.<ds>`` section."""
        if dataset not in DATASET_IDS:
            raise ParamsError(f"datasets: no dataset {dataset!r}; known: {DATASET_IDS}")
        return getattr(self.datasets, dataset)
    world: WorldParams
    datasets: DatasetsParams
    preprocess: PreprocessParams
    train: TrainParams
    study: StudyParams
    evaluate: EvalParams
    benchmark: BenchmarkParams


class ParamsError(ValueError):
    """params.yaml is invalid; the message names every offending key."""


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _format(err: ValidationError, source: str, place: Callable[[tuple], tuple] = lambda loc: loc) -> str:
    """One line: ``<file>: <key>: <problem> (got <value>)``, problems joined by ``; ``. ``place``
    maps an error's location to the params key that holds the value (a merged recipe's inherited
    keys sit in ``train.recipe``); a problem found at several places is named once."""
    problems: list[str] = []
    for e in err.errors():
        key = ".".join(str(p) for p in place(tuple(e["loc"]))) or "<root>"
        msg = e["msg"]
        if e["type"] == "extra_forbidden":
            msg = "unknown key (not in the schema)"
        got = e.get("input")
        got_s = "" if e["type"] in ("extra_forbidden", "missing") or isinstance(got, dict) else f" (got {got!r})"
        if e["type"] == "float_type" and isinstance(got, str) and _is_number(got):
            got_s += " (YAML reads an exponent without a dot as text: write e.g. 1.0e-4)"
        problem = _one_line(f"{key}: {msg}{got_s}")
        if problem not in problems:
            problems.append(problem)
    head = f"{source}: " if len(problems) == 1 else f"{source}: {len(problems)} invalid parameters: "
    return head + "; ".join(problems)


def format_error(err: ValidationError, source: str, key: str = "") -> str:
    """:func:`_format` for a section validated on its own (a weighting's settings) at params key ``key``."""
    return _format(err, source, lambda loc: _in_params(loc, key, {}))


def _recipe_place(data: Any) -> Callable[[tuple], tuple]:
    """Where an error inside ``train.models.<id>`` lies in the raw params ``data``: at
    ``train.recipe.<key>`` for a key that model does not set (:class:`TrainParams`'s merge)."""
    def place(loc: tuple) -> tuple:
        train = data.get("train") if isinstance(data, dict) else None
        if len(loc) < 4 or loc[:2] != ("train", "models") or not isinstance(train, dict):
            return loc
        changes = (train.get("models") or {}).get(loc[2])
        if isinstance(changes, dict) and loc[3] not in changes:
            return ("train", "recipe", *loc[3:])
        return loc
    return place


def parse_params(data: dict, source: str = "params.yaml") -> Params:
    """Validate a params mapping; raises :class:`ParamsError` whose one-line message names each bad key."""
    if not isinstance(data, dict):
        raise ParamsError(f"{source}: expected a mapping at the top level")
    try:
        return Params.model_validate(data)
    except ValidationError as err:
        raise ParamsError(_format(err, source, _recipe_place(data))) from None


class DuplicateKeyError(yaml.YAMLError):
    """A mapping of a YAML file names one key twice."""


class UniqueKeyLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that rejects a key written twice in one mapping: PyYAML would keep the
    last value silently, while DVC (ruamel) rejects the file, so ``dvc status`` and the stages
    would disagree. A merge key (``<<: *anchor``) is not a duplicate of the keys it supplies."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        seen: set = set()
        for key_node, _ in node.value:
            if not isinstance(key_node, yaml.ScalarNode) or key_node.tag == "tag:yaml.org,2002:merge":
                continue
            key = self.construct_object(key_node)
            if key in seen:
                raise DuplicateKeyError(f"duplicate key {key!r} at line {key_node.start_mark.line + 1}")
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


#: A params file larger than this is not a params file (params.yaml is ~20 kB): refused at once,
#: before YAML reads it (a 50 MB file took minutes to reach its error).
MAX_PARAMS_BYTES = 1 << 20


def _params_text(path: Path) -> str:
    """The text of params file ``path``: :class:`ParamsError` for a file that is missing, too
    large (:data:`MAX_PARAMS_BYTES`), unreadable or not UTF-8, naming the file."""
    try:
        if not path.is_file():
            raise ParamsError(f"{path}: file not found")
        size = path.stat().st_size
        if size > MAX_PARAMS_BYTES:
            raise ParamsError(f"{path}: {size} bytes, too large for a params file (at most {MAX_PARAMS_BYTES})")
        raw = path.read_bytes()[:MAX_PARAMS_BYTES + 1]
    except OSError as err:
        raise ParamsError(f"{path}: could not read ({err.strerror or err})") from None
    if len(raw) > MAX_PARAMS_BYTES:  # grew since stat
        raise ParamsError(f"{path}: too large for a params file (at most {MAX_PARAMS_BYTES} bytes)")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as err:
        line = raw[:err.start].count(b"\n") + 1
        raise ParamsError(f"{path}: not UTF-8 text (byte 0x{raw[err.start]:02x} at line {line})") from None


def load_params(path: str | Path = "params.yaml") -> Params:
    """Read and validate params.yaml (a key written twice in one mapping is an error; a file
    that is not UTF-8 or larger than :data:`MAX_PARAMS_BYTES` is refused before YAML reads it)."""
    path = Path(path)
    text = _params_text(path)
    try:
        data = yaml.load(text, Loader=UniqueKeyLoader)
    except DuplicateKeyError as err:
        raise ParamsError(f"{path}: {err}") from None
    except yaml.YAMLError as err:
        raise ParamsError(f"{path}: not valid YAML: {_one_line(err)}") from None
    except RecursionError:
        raise ParamsError(f"{path}: not valid YAML: nested too deeply") from None
    return parse_params(data, str(path))
