"""Typed schema of params.yaml (SPEC 9): unknown keys and wrong types are errors
whose message names the offending key.

``scale`` is the one switch between the default scale (a 2-core CPU, about 30 min for
the whole pipeline) and the paper's scale: every value that differs between the two is
written as ``{default: ..., paper: ...}`` (a :class:`Scaled`) and resolved with
:meth:`Scaled.at`.
"""
from __future__ import annotations

from pathlib import Path
from typing import Generic, Literal, Optional, TypeVar

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

T = TypeVar("T")

TOWNS = ("town01", "town02", "town03", "town04", "town05")
DATASET_IDS = ("A", "B", "C", "nuscenes")
MODEL_IDS = ("compact_1l", "compact_15l", "compact_15l_mgn", "gradnorm_segnet", "polarnet", "chen_bev")
ScaleName = Literal["default", "paper"]


class Strict(BaseModel):
    """Base for every section: unknown keys are rejected."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class Scaled(Strict, Generic[T]):
    """A value that differs between the default and the paper scale."""

    default: T
    paper: T

    def at(self, scale: ScaleName) -> T:
        return getattr(self, scale)


# ----------------------------------------------------------------------------- world
class CameraParams(Strict):
    """RGB/DVS/semantic/depth cameras (paper section IV-A, Fig. 4)."""

    fov_deg: float = Field(90.0, gt=10.0, lt=170.0, description="horizontal and vertical FOV")
    pitch_deg: float = Field(20.0, ge=-45.0, le=45.0, description="upward rotation")
    height_m: float = Field(1.7, gt=0.2, le=4.0)
    mount_offset_m: float = Field(1.0, ge=0.0, le=3.0, description="distance from the ego centre")


class LidarParams(Strict):
    """Roof LiDAR (paper section IV-A)."""

    channels: int = Field(64, ge=4, le=256)
    upper_fov_deg: float = Field(20.0, gt=-90.0, lt=90.0)
    lower_fov_deg: float = Field(-30.0, gt=-90.0, lt=90.0)
    range_m: float = Field(32.0, gt=1.0, le=200.0)
    height_m: float = Field(2.0, gt=0.5, le=5.0)
    horizontal_samples: int = Field(1024, ge=64, le=8192, description="rays per laser per revolution")

    @model_validator(mode="after")
    def _fov_order(self) -> "LidarParams":
        if self.lower_fov_deg >= self.upper_fov_deg:
            raise ValueError("lower_fov_deg must be below upper_fov_deg")
        return self


class DvsParams(Strict):
    contrast_threshold: float = Field(0.3, gt=0.0, le=5.0, description="log-intensity change per event (CARLA 0.3)")
    step_s: float = Field(0.1, gt=0.0, le=2.0, description="simulated time between the two compared steps")


class ConditionParams(Strict):
    """Per-frame time of day and weather draws (SPEC 3.1)."""

    times: list[Literal["morning", "noon", "evening", "night"]] = ["morning", "noon", "evening", "night"]
    weathers: list[Literal["sunny", "cloudy", "rainy", "foggy"]] = ["sunny", "cloudy", "rainy", "foggy"]
    combine_probability: float = Field(0.3, ge=0.0, le=1.0, description="chance a second weather is mixed in")


class WorldParams(Strict):
    resolution: Scaled[int]
    camera: CameraParams = CameraParams()
    lidar: LidarParams = LidarParams()
    dvs: DvsParams = DvsParams()
    conditions: ConditionParams = ConditionParams()
    frames_per_episode: int = Field(20, ge=1, le=10000, description="consecutive frames of one drive (a 'scene')")
    workers: int = Field(2, ge=1, le=256)

    @field_validator("resolution")
    @classmethod
    def _res(cls, v: Scaled[int]) -> Scaled[int]:
        for name in ("default", "paper"):
            r = getattr(v, name)
            if not 16 <= r <= 1024 or r % 16:
                raise ValueError(f"resolution.{name} must be a multiple of 16 in [16, 1024], got {r}")
        return v


# ----------------------------------------------------------------------------- datasets
class SimDatasetParams(Strict):
    """A simulated dataset (A, B, C): town splits of paper Table I, ratio 3:1:1."""

    source: Literal["sim", "authors"] = "sim"
    authors_root: Optional[str] = Field(None, description="root of the authors' released dataset (source: authors)")
    frames: Scaled[int]
    train_towns: list[str]
    eval_towns: list[str]
    split_by: Literal["town", "episode"]
    seed_offset: int = Field(0, ge=0)

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
        for name in ("default", "paper"):
            if getattr(v, name) < 5:
                raise ValueError(f"frames.{name} must be at least 5 (one per split share of 3:1:1), got {getattr(v, name)}")
        return v

    @model_validator(mode="after")
    def _authors(self) -> "SimDatasetParams":
        if self.source == "authors" and not self.authors_root:
            raise ValueError("source 'authors' needs authors_root")
        return self


class NuScenesParams(Strict):
    """nuScenes-lidarseg (section IV-B). With no dataroot a simulated nuScenes-format set is written."""

    dataroot: Optional[str] = None
    version: str = "v1.0-trainval"
    sim_scenes: Scaled[int]
    sim_samples_per_scene: int = Field(8, ge=2, le=100)
    split_seed: int = 0


class DatasetsParams(Strict):
    A: SimDatasetParams
    B: SimDatasetParams
    C: SimDatasetParams
    nuscenes: NuScenesParams


# ----------------------------------------------------------------------------- preprocessing
class PreprocessParams(Strict):
    """Section IV-C, eq. (1)-(5)."""

    lidar_range_m: float = Field(32.0, gt=1.0)
    z_min_m: float = -2.0
    z_max_m: float = 11.0
    height_multiplier: int = Field(13, ge=1, le=64, description="eq. (5): channels 0..multiplier")
    fill_neighbours: bool = True
    workers: int = Field(2, ge=1, le=256)

    @model_validator(mode="after")
    def _z(self) -> "PreprocessParams":
        if self.z_min_m >= self.z_max_m:
            raise ValueError("z_min_m must be below z_max_m")
        return self


# ----------------------------------------------------------------------------- training
class MgnParams(Strict):
    """Section III-C, Algorithm 1."""

    alpha: float = Field(1.5, ge=0.0)
    lr: float = Field(0.1, gt=0.0)
    lr_min: float = Field(1e-4, gt=0.0)
    authors_mode: bool = Field(False, description="reproduce the authors' public code (SPEC 7)")


class GradNormParams(Strict):
    """Original per-step GradNorm (Chen et al., ICML 2018)."""

    alpha: float = Field(1.5, ge=0.0)
    lr: float = Field(0.025, gt=0.0)


class ModelRecipe(Strict):
    optimizer: Literal["sgd", "adam"]
    lr: float = Field(gt=0.0)
    lr_min: float = Field(1e-5, gt=0.0)
    momentum: float = Field(0.9, ge=0.0, lt=1.0)
    weight_decay: float = Field(1e-4, ge=0.0)
    weighting: Literal["static", "mgn", "gradnorm", "none"] = "static"
    max_epochs: Optional[Scaled[int]] = Field(None, description="overrides train.max_epochs for this model")
    mgn: Optional[MgnParams] = None
    gradnorm: Optional[GradNormParams] = None

    @model_validator(mode="after")
    def _weighting(self) -> "ModelRecipe":
        if self.weighting == "mgn" and self.mgn is None:
            raise ValueError("weighting 'mgn' needs an 'mgn' section")
        if self.weighting == "gradnorm" and self.gradnorm is None:
            raise ValueError("weighting 'gradnorm' needs a 'gradnorm' section")
        return self


class TrainParams(Strict):
    """Section IV-D: batch 6, SGD, plateau halving, early stop, best checkpoint."""

    batch_size: int = Field(6, ge=1)
    max_epochs: Scaled[int]
    plateau_patience: int = Field(4, ge=1)
    plateau_factor: float = Field(0.5, gt=0.0, lt=1.0)
    early_stop_patience: int = Field(25, ge=1)
    num_workers: int = Field(2, ge=0)
    device: Literal["auto", "cpu", "cuda"] = "auto"
    amp: bool = False
    models: dict[str, ModelRecipe]

    @field_validator("models")
    @classmethod
    def _models(cls, v: dict[str, ModelRecipe]) -> dict[str, ModelRecipe]:
        bad = [m for m in v if m not in MODEL_IDS]
        if bad:
            raise ValueError(f"unknown model id(s) {bad}; known: {list(MODEL_IDS)}")
        return v


class EvalParams(Strict):
    figure_frame: int = Field(0, ge=0, description="test frame shown in the qualitative figures")
    save_predictions: int = Field(2, ge=0, description="test frames whose predictions are saved")


class BenchmarkParams(Strict):
    warmup: int = Field(10, ge=0)
    runs: int = Field(50, ge=3)


class Params(Strict):
    scale: ScaleName
    seed: int = Field(ge=0)
    world: WorldParams
    datasets: DatasetsParams
    preprocess: PreprocessParams = PreprocessParams()
    train: TrainParams
    evaluate: EvalParams = EvalParams()
    benchmark: BenchmarkParams = BenchmarkParams()


class ParamsError(ValueError):
    """params.yaml is invalid; the message names every offending key."""


def _format(err: ValidationError, source: str) -> str:
    lines = [f"{source}: invalid parameters"]
    for e in err.errors():
        key = ".".join(str(p) for p in e["loc"]) or "<root>"
        msg = e["msg"]
        if e["type"] == "extra_forbidden":
            msg = "unknown key (not in the schema)"
        got = e.get("input")
        got_s = "" if e["type"] in ("extra_forbidden", "missing") or isinstance(got, dict) else f" (got {got!r})"
        lines.append(f"  {key}: {msg}{got_s}")
    return "\n".join(lines)


def parse_params(data: dict, source: str = "params.yaml") -> Params:
    """Validate a params mapping; raises :class:`ParamsError` naming each bad key."""
    if not isinstance(data, dict):
        raise ParamsError(f"{source}: expected a mapping at the top level")
    try:
        return Params.model_validate(data)
    except ValidationError as err:
        raise ParamsError(_format(err, source)) from None


def load_params(path: str | Path = "params.yaml") -> Params:
    """Read and validate params.yaml."""
    path = Path(path)
    if not path.is_file():
        raise ParamsError(f"{path}: file not found")
    with path.open() as fh:
        try:
            data = yaml.safe_load(fh)
        except yaml.YAMLError as err:
            raise ParamsError(f"{path}: not valid YAML: {err}") from None
    return parse_params(data, str(path))
