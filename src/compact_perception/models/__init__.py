"""Model registry: `build_model(model_id, dataset_id)` (ARCHITECTURE.md, SPEC 5).

Model ids: `compact_1l`, `compact_15l`, `compact_15l_mgn` (the compact model of section III-A;
15L and 15L+MGN share the network, only the loss weighting differs), and the section V-D
baselines `gradnorm_segnet`, `polarnet`, `chen_bev`.  Dataset ids: `A`, `B`, `C` (23 SS/LS
classes, 9 BEV classes, DVS) and `nuscenes` (32 classes for SS, LS and BEVP, no DVS).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from torch import nn

from ..classes import BEV_NAMES, CARLA_NAMES, NUSCENES_NAMES
from ..registry import Registry
from .blocks import count_parameters
from .chen import ChenBEV
from .compact import CompactPerception
from .polarnet import PolarNet
from .segnet import GradNormSegNet


@dataclass(frozen=True)
class DatasetSpec:
    """What a model needs to know about a dataset."""

    n_seg: int
    n_bev: int
    has_dvs: bool
    n_views: int = 4


DATASETS: Registry[DatasetSpec] = Registry("dataset")
for _ds in ("A", "B", "C"):
    DATASETS.register(_ds)(DatasetSpec(len(CARLA_NAMES), len(BEV_NAMES), True))
DATASETS.register("nuscenes")(DatasetSpec(len(NUSCENES_NAMES), len(NUSCENES_NAMES), False))

MODELS: Registry[Callable[[DatasetSpec], nn.Module]] = Registry("model")


@MODELS.register("compact_1l")
def _compact_1l(ds: DatasetSpec) -> nn.Module:
    return CompactPerception(ds.n_seg, ds.n_bev, lidar_channels=1, has_dvs=ds.has_dvs, n_views=ds.n_views)


@MODELS.register("compact_15l")
def _compact_15l(ds: DatasetSpec) -> nn.Module:
    return CompactPerception(ds.n_seg, ds.n_bev, lidar_channels=15, has_dvs=ds.has_dvs, n_views=ds.n_views)


MODELS.register("compact_15l_mgn")(_compact_15l)


@MODELS.register("gradnorm_segnet")
def _gradnorm_segnet(ds: DatasetSpec) -> nn.Module:
    return GradNormSegNet(ds.n_seg, n_views=ds.n_views)


@MODELS.register("polarnet")
def _polarnet(ds: DatasetSpec) -> nn.Module:
    return PolarNet(ds.n_seg, in_ch=15)


@MODELS.register("chen_bev")
def _chen_bev(ds: DatasetSpec) -> nn.Module:
    return ChenBEV(ds.n_seg, ds.n_bev)


def build_model(model_id: str, dataset_id: str) -> nn.Module:
    """A fresh model for `dataset_id`; unknown ids raise KeyError listing the known ones."""
    factory = MODELS[model_id]
    return factory(DATASETS[dataset_id])


def lidar_channels(model_id: str) -> int:
    """LiDAR channels a model reads (1 for compact_1l, else 15)."""
    MODELS[model_id]
    return 1 if model_id == "compact_1l" else 15


__all__ = [
    "DATASETS", "MODELS", "DatasetSpec", "build_model", "count_parameters", "lidar_channels",
    "ChenBEV", "CompactPerception", "GradNormSegNet", "PolarNet",
]
