"""Model registry: `build_model(model_id, dataset_id)` (ARCHITECTURE.md, SPEC 5).

Model ids (``catalog.MODELS``): `compact_1l`, `compact_15l`, `compact_15l_mgn`,
`compact_15l_mgn_authors` (the compact model of section III-A; 15L and both 15L+MGN forms share
the network, only the training differs), and the section V-D baselines `gradnorm_segnet`,
`polarnet`, `chen_bev`. Dataset ids: `A`, `B`, `C` (23 SS/LS classes, 9 BEV classes, DVS) and
`nuscenes` (32 classes for SS, LS and BEVP, no DVS).

A model's one registration is its ``catalog.MODELS`` entry (its id); the entry's ``network``
names the module of this package whose ``build(spec, info)`` makes the network
(:func:`.base.network_factory` checks it against the contract). This package imports every module
in it, so a new network is one new file, plus its model's entry in ``core/catalog.py`` and its
recipe and id in params.yaml (docs/extending.md).
"""
from __future__ import annotations

import inspect
from typing import Sequence

from torch import nn

from ...core import catalog
from ...core.registry import import_submodules
from .base import DATASET_SPECS, DatasetSpec, NetworkFactory, network_factory
from .blocks import count_parameters

#: network (``catalog.ModelInfo.network``: a module of this package) -> its ``build``, every module
#: of the package that defines one (imported here, in name order, each checked against the contract)
NETWORKS: dict[str, NetworkFactory] = {name: network_factory(module)
                                       for name, module in import_submodules(__name__, __path__).items()
                                       if hasattr(module, "build")}

#: model id -> its registry entry (catalog.MODELS: label, group, LiDAR channels, tasks, network)
MODELS = catalog.MODELS


def build_model(model_id: str, dataset_id: str, tasks: Sequence[str] | None = None) -> nn.Module:
    """A fresh model for `dataset_id`; unknown ids raise KeyError listing the known ones.

    ``tasks`` (default: the model's own, ``catalog``) builds the network for a subset of its
    tasks, where its factory takes a ``tasks`` argument (the compact network: the study's
    single-task references); any other network raises ValueError."""
    info = MODELS[model_id]
    if info.network not in NETWORKS:
        raise KeyError(f"model {model_id}: no network module {info.network!r} in learning/models with a "
                       f"build(spec, info) function; known: {sorted(NETWORKS)}")
    factory = NETWORKS[info.network]
    if tasks is None or tuple(tasks) == tuple(info.tasks):
        return factory(DATASET_SPECS[dataset_id], info)
    if "tasks" not in inspect.signature(factory).parameters:
        raise ValueError(f"model {model_id} is built for all of its tasks {list(info.tasks)}, not {list(tasks)}")
    return factory(DATASET_SPECS[dataset_id], info, tasks=tuple(tasks))


def lidar_channels(model_id: str) -> int:
    """LiDAR channels a model reads (1 for compact_1l, else 15)."""
    return MODELS[model_id].lidar_channels


__all__ = [
    "DATASET_SPECS", "MODELS", "NETWORKS", "DatasetSpec", "build_model", "count_parameters", "lidar_channels",
]
