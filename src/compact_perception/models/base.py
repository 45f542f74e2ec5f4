"""What every network module needs to register itself: the dataset specs and the network registry.

A network module registers its factory with ``@register_network("<id>")`` (the id that
``catalog.ModelInfo.network`` names); :mod:`compact_perception.models` imports every module of
this package, so a new network is found without editing another file.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from torch import nn

from ..core import catalog
from ..core.classes import BEV_NAMES, CARLA_NAMES, NUSCENES_NAMES
from ..core.registry import Registry

__all__ = ["DatasetSpec", "DATASETS", "NETWORKS", "NetworkFactory", "register_network"]


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

#: a network's factory: (dataset spec, the model's registry entry) -> a fresh module
NetworkFactory = Callable[[DatasetSpec, catalog.ModelInfo], nn.Module]

#: network id (catalog.ModelInfo.network) -> its factory
NETWORKS: Registry[NetworkFactory] = Registry("network")


def register_network(key: str) -> Callable[[NetworkFactory], NetworkFactory]:
    """Decorator: ``@register_network("polarnet")`` makes the function the factory of network
    ``polarnet`` (what ``catalog.ModelInfo.network`` names)."""
    return NETWORKS.register(key)
