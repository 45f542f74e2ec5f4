"""Model registry: `build_model(model_id, dataset_id)` (ARCHITECTURE.md, SPEC 5).

Model ids: `compact_1l`, `compact_15l`, `compact_15l_mgn`, `compact_15l_mgn_authors` (the compact
model of section III-A; 15L and both 15L+MGN forms share the network, only the training differs), and the section V-D
baselines `gradnorm_segnet`, `polarnet`, `chen_bev`.  Dataset ids: `A`, `B`, `C` (23 SS/LS
classes, 9 BEV classes, DVS) and `nuscenes` (32 classes for SS, LS and BEVP, no DVS).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from torch import nn

from .. import catalog
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


#: dataset id -> what a model needs to know about it (the ids are catalog.DATASETS')
DATASETS: Registry[DatasetSpec] = Registry("dataset", ordered=True)
for _ds in catalog.dataset_ids():
    if catalog.DATASETS[_ds].simulated:  # the CARLA-like classes of the embedded world / the authors' sets
        DATASETS.register(_ds)(DatasetSpec(len(CARLA_NAMES), len(BEV_NAMES), True))
    else:  # nuScenes-lidarseg: 32 classes for SS, LS and BEVP, no DVS
        DATASETS.register(_ds)(DatasetSpec(len(NUSCENES_NAMES), len(NUSCENES_NAMES), False))

#: network (catalog.ModelInfo.network) -> factory(dataset spec, model info)
NETWORKS: Registry[Callable[[DatasetSpec, catalog.ModelInfo], nn.Module]] = Registry("network")


@NETWORKS.register("compact")
def _compact(ds: DatasetSpec, info: catalog.ModelInfo) -> nn.Module:
    return CompactPerception(ds.n_seg, ds.n_bev, lidar_channels=info.lidar_channels, has_dvs=ds.has_dvs,
                             n_views=ds.n_views)


@NETWORKS.register("gradnorm_segnet")
def _gradnorm_segnet(ds: DatasetSpec, info: catalog.ModelInfo) -> nn.Module:
    return GradNormSegNet(ds.n_seg, n_views=ds.n_views)


@NETWORKS.register("polarnet")
def _polarnet(ds: DatasetSpec, info: catalog.ModelInfo) -> nn.Module:
    return PolarNet(ds.n_seg, in_ch=info.lidar_channels)


@NETWORKS.register("chen_bev")
def _chen_bev(ds: DatasetSpec, info: catalog.ModelInfo) -> nn.Module:
    return ChenBEV(ds.n_seg, ds.n_bev)


#: model id -> its registry entry (catalog.MODELS: label, group, LiDAR channels, tasks, network)
MODELS = catalog.MODELS


def build_model(model_id: str, dataset_id: str) -> nn.Module:
    """A fresh model for `dataset_id`; unknown ids raise KeyError listing the known ones."""
    info = MODELS[model_id]
    return NETWORKS[info.network](DATASETS[dataset_id], info)


def lidar_channels(model_id: str) -> int:
    """LiDAR channels a model reads (1 for compact_1l, else 15)."""
    return MODELS[model_id].lidar_channels


__all__ = [
    "DATASETS", "MODELS", "NETWORKS", "DatasetSpec", "build_model", "count_parameters", "lidar_channels",
    "ChenBEV", "CompactPerception", "GradNormSegNet", "PolarNet",
]
