"""The sections of params.yaml and the whole file (:class:`Params`), validated by
:func:`parse_params` (see :mod:`compact_perception.core.params` for the rules)."""
from __future__ import annotations

from typing import Any, Callable, Literal, Optional, Union

from pydantic import Field, PrivateAttr, ValidationError, ValidatorFunctionWrapHandler, field_validator, model_validator
from pydantic_core import PydanticCustomError

from .. import catalog
from .base import (MAX_BATCH, MAX_FRAMES, MAX_SAVED_PREDICTIONS, MAX_SCENES, MAX_WORKERS, SCALES,
                          ScaleName, Scaled, Strict, _scaled_at_least, _scaled_at_most, _scaled_distinct_seeds,
                          resolve_scale)
from .errors import ParamsError, _format, _in_params
from .sources import SOURCES, SourceSettings
from .recipe import ModelRecipe, _from_base, _inherited, _plain, merge_recipe

TOWNS = ("town01", "town02", "town03", "town04", "town05")
# Model and dataset ids live in the registries (compact_perception.core.catalog, no torch): the recipes
# of train.models must be of registered models.


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
    """A CARLA-like dataset (A, B, C): town splits of paper Table I, from the data source its
    ``source`` section names (:mod:`.sources`)."""

    source: SourceSettings = Field(description="where its data come from: {id: <source>, <that source's settings>}")
    frames: Scaled[int]
    split_ratio: Scaled[SplitRatio] = Field(description="train:val:test shares (paper 3:1:1); the default scale "
                                            "gives the test split more frames, so frame sampling is not the main noise")
    train_towns: list[str]
    eval_towns: list[str]
    split_by: Literal["town", "episode"]
    seed_offset: int = Field(ge=0, description="added to the top-level seed for this dataset's episodes")
    training: TrainingBudget

    @field_validator("source", mode="before")
    @classmethod
    def _source_section(cls, v: Any) -> Any:
        """A section ``{id: <source>, <its settings>}``; a bare id (``source: sim``, the former
        layout) is one line saying so."""
        if not isinstance(v, dict):
            raise PydanticCustomError("source_section", "expected a section: id (one of {ids}) and that source's "
                                      "settings (docs/data-formats.md)", {"ids": ", ".join(SOURCES.keys())})
        return v

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

    def towns_by_split(self) -> dict[str, list[str]]:
        """The towns each split's episodes cycle through: ``split_by: town`` keeps the train towns
        for training and the eval towns for validation and test; ``episode`` lets every split visit
        every town (train towns first, each once)."""
        if self.split_by == "town":
            return {"train": list(self.train_towns), "val": list(self.eval_towns), "test": list(self.eval_towns)}
        every = list(dict.fromkeys([*self.train_towns, *self.eval_towns]))
        return {split: every for split in ("train", "val", "test")}


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
    parallel_runs: Union[int, Literal["auto"]] = Field(
        description="runs a stage trains side by side, each in its own process with num_threads threads "
                    "(learning/training/parallel.py): any count gives the same result; 'auto': on a CUDA GPU "
                    "the measured best share of one GPU, on a CPU the usable cores over num_threads")
    num_threads: int = Field(ge=1, le=MAX_WORKERS, description="torch intra-op threads: a threaded reduction's "
                             "result depends on the count, so it is a tracked param (determinism.set_threads)")
    device: Literal["auto", "cpu", "cuda"]
    precision: Literal["fp32", "bf16", "fp16", "auto"] = Field(
        description="fp32 (bit-reproducible), bf16/fp16 autocast, or auto: the fastest the hardware runs "
                    "natively (precision.resolve_precision); anything but fp32 lifts the CPU kernel pins")
    channels_last: Union[bool, Literal["inputs"]] = Field(
        description="NHWC memory format for the convolutions: true, the network with its inputs and targets; "
                    "'inputs', the network and its inputs only (the targets stay as the loader expands them, one "
                    "copy less per target and step; the losses' sums then run in another order, so their last "
                    "bits differ from true's); false, none")
    compile: bool = Field(description="torch.compile the forward (falls back to eager with one warning)")
    cuda_graphs: Literal["auto", "off"] = Field(
        description="auto: on a CUDA GPU, replay the ordinary training steps as a CUDA graph where the run's "
                    "step can be captured (learning/training/capture.py; one logged line where it cannot, and "
                    "a first replay that differs from the eager step by a bit falls back too); a CPU never "
                    "captures. off: every step eager")
    deterministic: bool = Field(description="deterministic kernels where they exist, cuDNN without benchmarking, "
                                "cuBLAS's deterministic workspace (determinism.set_determinism; docs/gpu.md)")
    tf32: bool = Field(description="let a GPU run fp32 matrix products and convolutions in TF32 (faster, fewer "
                       "mantissa bits); false keeps fp32 fp32")
    recipe: dict[str, Any] = Field(description="the base recipe: every key of a model's recipe that "
                                   "train.models.<id> does not set")
    models: dict[str, ModelRecipe] = Field(description="model id -> what its recipe changes in `recipe` (null "
                                           "removes a key); read here as the merged recipe (merge_recipe)")


    @field_validator("parallel_runs", mode="before")
    @classmethod
    def _runs(cls, v: Any) -> Any:
        """A count of processes, 1 to MAX_WORKERS, or ``auto``; one message either way."""
        if v == "auto" or (type(v) is int and 1 <= v <= MAX_WORKERS):
            return v
        raise PydanticCustomError("count_or_auto", "expected a count from 1 to {hi} or 'auto'", {"hi": MAX_WORKERS})

    @field_validator("channels_last", mode="before")
    @classmethod
    def _layout(cls, v: Any) -> Any:
        """true, false or ``inputs``; one message otherwise."""
        if type(v) is bool or v == "inputs":
            return v
        raise PydanticCustomError("bool_or_inputs", "expected a boolean (true or false) or 'inputs'")

    @field_validator("cuda_graphs", mode="before")
    @classmethod
    def _graphs(cls, v: Any) -> Any:
        """``auto`` or ``off``, where a YAML false is ``off``: ``dvc exp run -S train.cuda_graphs=off``
        writes the word unquoted (DVC writes YAML 1.2, where it is text) and this loader (YAML 1.1)
        reads it as false. Only this key's values include such a word (tests/test_set_param.py)."""
        return "off" if v is False else v

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
    batch_size: int = Field(ge=1, le=256, description="test frames the network runs on together, each scored on its "
                            "own outputs; 1 gives the committed scores (a frame's outputs move in their last bits "
                            "with the batch it runs in)")


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
    world: WorldParams
    datasets: DatasetsParams
    preprocess: PreprocessParams
    train: TrainParams
    study: StudyParams
    evaluate: EvalParams
    benchmark: BenchmarkParams

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

    # The values of this file's ``scale``. ``scale`` is resolved once, here, when params load
    # (:meth:`model_post_init`: every per-scale value of the file at its scale, by the one
    # resolver ``resolve_scale``), and nowhere below: a module reads a per-scale value through
    # these, never with ``.at(params.scale)`` (tests/test_layers.py holds it).

    _at_scale: dict = PrivateAttr(default_factory=dict)

    def model_post_init(self, context: Any) -> None:
        """Resolve ``scale`` once: the whole file's values at its scale, which the accessors read."""
        self._at_scale = resolve_scale(self.model_dump(mode="python"), self.scale)

    def model_copy(self, *, update: Optional[dict[str, Any]] = None, deep: bool = False) -> "Params":
        """A copy (pydantic's), its values at its scale resolved again: ``update`` may change the
        scale or a section (benchmarks do)."""
        copy = super().model_copy(update=update, deep=deep)
        copy.model_post_init(None)
        return copy

    @property
    def resolution(self) -> int:
        """``world.resolution`` at this scale: the side S of every image and top view (px)."""
        return self._at_scale["world"]["resolution"]

    def frames_of(self, dataset: str) -> int:
        """``datasets.<ds>.frames`` at this scale (a simulated set's frames in all splits)."""
        self.dataset(dataset)  # an unknown id is one line
        return self._at_scale["datasets"][dataset]["frames"]

    def split_counts_of(self, dataset: str) -> dict[str, int]:
        """Frames per split of a simulated set at this scale (``split_ratio`` applied to ``frames``)."""
        self.dataset(dataset)
        return SplitRatio(**self._at_scale["datasets"][dataset]["split_ratio"]).counts(self.frames_of(dataset))

    @property
    def study_datasets(self) -> list[str]:
        """``study.datasets`` at this scale: the datasets the loss-balancing study runs on."""
        return list(self._at_scale["study"]["datasets"])

    @property
    def nuscenes_sim_scenes(self) -> int:
        """``datasets.nuscenes.sim_scenes`` at this scale (scenes of the simulated nuScenes set)."""
        return self._at_scale["datasets"]["nuscenes"]["sim_scenes"]

    def patience_of(self, recipe: ModelRecipe) -> int:
        """A run's early-stopping patience at this scale (the recipe's ``early_stop_patience``)."""
        return recipe.early_stop_patience.at(self.scale)

    def seeds_of(self, group: str, dataset: str, scale: Optional[ScaleName] = None) -> list[int]:
        """The training seeds of a model group (``catalog.ModelInfo.group``) on ``dataset`` at
        ``scale`` (default: this file's), by the group's rule (``catalog.GROUPS``):
        ``datasets.<ds>.training.seeds`` for ``compact``, ``baseline_seeds`` for ``baseline``."""
        by_dataset = catalog.GROUPS[group].seeds == "dataset"
        if scale is not None:  # another scale's (the report at full asks): read there, not this file's scale
            return list((self.dataset(dataset).training.seeds if by_dataset else self.baseline_seeds).at(scale))
        if by_dataset:
            self.dataset(dataset)  # an unknown id is one line
            return list(self._at_scale["datasets"][dataset]["training"]["seeds"])
        return list(self._at_scale["baseline_seeds"])

    def max_epochs_of(self, recipe: ModelRecipe, dataset: str, scale: Optional[ScaleName] = None) -> int:
        """The epoch cap of a run of ``recipe`` on ``dataset``: the recipe's own ``max_epochs`` where
        it has one (a costly baseline), else ``datasets.<ds>.training.max_epochs``, at ``scale``
        (default: this file's ``scale``)."""
        cap = recipe.max_epochs if recipe.max_epochs is not None else self.dataset(dataset).training.max_epochs
        return cap.at(scale or self.scale)

    def dataset(self, dataset: str) -> "SimDatasetParams | NuScenesParams":
        """The ``datasets.<ds>`` section."""
        if dataset not in DATASET_IDS:
            raise ParamsError(f"datasets: no dataset {dataset!r}; known: {DATASET_IDS}")
        return getattr(self.datasets, dataset)


def _recipe_place(data: Any) -> Callable[[tuple], tuple]:
    """Where an error lies in the raw params ``data``: inside ``train.models.<id>``, at
    ``train.recipe.<key>`` for a key that model does not set (:class:`TrainParams`'s merge); inside
    ``datasets.<ds>.source``, at the key itself (the union's tag, the source id, is no key)."""
    def place(loc: tuple) -> tuple:
        if len(loc) >= 4 and loc[0] == "datasets" and loc[2] == "source" and loc[3] in SOURCES:
            return loc[:3] + loc[4:]
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
