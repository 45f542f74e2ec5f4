"""What every network module needs: the dataset specs and the network contract.

A network is a module of :mod:`compact_perception.learning.models` whose ``build(spec, info)``
function makes it; ``catalog.ModelInfo.network`` names that module, and the model's catalog entry
is its one registration (no second id: the models package finds every module with a ``build``).

The network contract is :class:`PerceptionNet` (what training, evaluation and the loss weightings
use: ``tasks``, ``argmax_tasks``, ``forward``, ``compute_losses``, ``shared_layers``). ``build``
annotates its return with its network class; :func:`network_factory` checks that class against
the contract when the package imports the module, so a network missing a member fails then, not
mid-training.
"""
from __future__ import annotations

from dataclasses import dataclass
from types import ModuleType
from typing import Callable, ClassVar, Protocol

from torch import Tensor, nn

from ...core import catalog
from ...core.classes import BEV_NAMES, CARLA_NAMES, NUSCENES_NAMES
from ...core.registry import Registry

__all__ = ["DatasetSpec", "DATASET_SPECS", "NetworkFactory", "PerceptionNet", "contract_gaps", "network_factory"]


@dataclass(frozen=True)
class DatasetSpec:
    """What a model needs to know about a dataset."""

    n_seg: int
    n_bev: int
    has_dvs: bool
    n_views: int = 4


#: dataset id -> what a model needs to know about it: its class counts and inputs (the ids are
#: catalog.DATASETS', which holds the datasets' labels and kinds)
DATASET_SPECS: Registry[DatasetSpec] = Registry("dataset", ordered=True)
for _ds in catalog.dataset_ids():
    if catalog.DATASETS[_ds].simulated:  # the CARLA-like classes of the embedded world / the authors' sets
        DATASET_SPECS.register(_ds)(DatasetSpec(len(CARLA_NAMES), len(BEV_NAMES), True))
    else:  # nuScenes-lidarseg: 32 classes for SS, LS and BEVP, no DVS
        DATASET_SPECS.register(_ds)(DatasetSpec(len(NUSCENES_NAMES), len(NUSCENES_NAMES), False))

class PerceptionNet(Protocol):
    """The contract of a network (an ``nn.Module``) the pipeline trains and scores.

    - ``tasks``: the task ids it predicts, in the catalog's order (``model.tasks``: a checkpoint's
      tasks, the loss weighting's tasks);
    - ``argmax_tasks``: the tasks whose head is a softmax scored by its arg-max map
      (``metrics.compute_metrics``); the others are sigmoid heads thresholded by eq. (5);
    - ``forward(batch) -> {task: output}``;
    - ``compute_losses(outputs, batch) -> {task: loss}`` (plus optional ``aux_*`` losses);
    - ``shared_layers() -> {task: [module names]}``: the shared weights W the adaptive weightings
      take gradients of (``weighting.base.shared_weights``).
    """

    tasks: ClassVar[tuple[str, ...]]
    argmax_tasks: ClassVar[tuple[str, ...]]

    def forward(self, batch: dict[str, Tensor]) -> dict[str, Tensor]: ...

    def compute_losses(self, outputs: dict[str, Tensor], batch: dict[str, Tensor]) -> dict[str, Tensor]: ...

    def shared_layers(self) -> dict[str, list[str]]: ...


_ATTRIBUTES = ("tasks", "argmax_tasks")
_METHODS = ("forward", "compute_losses", "shared_layers")


def contract_gaps(cls: type) -> list[str]:
    """What ``cls`` lacks of :class:`PerceptionNet` (empty when it meets the contract): not an
    ``nn.Module``, a missing class attribute, a missing method or ``nn.Module``'s unimplemented
    ``forward``."""
    gaps = [] if isinstance(cls, type) and issubclass(cls, nn.Module) else ["not a torch.nn.Module subclass"]
    gaps += [f"class attribute {name!r}" for name in _ATTRIBUTES if not hasattr(cls, name)]
    for name in _METHODS:
        fn = getattr(cls, name, None)
        if not callable(fn) or (name == "forward" and fn is getattr(nn.Module, "forward")):
            gaps.append(f"method {name}()")
    return gaps


#: a network's factory, its module's ``build``: (dataset spec, the model's catalog entry) -> a fresh module
NetworkFactory = Callable[[DatasetSpec, catalog.ModelInfo], nn.Module]


def network_factory(module: ModuleType) -> NetworkFactory:
    """The ``build`` function of network module ``module``. Its return annotation names the network
    class, which must meet :class:`PerceptionNet`; else a :class:`TypeError` names the network (the
    module's last name, what ``catalog.ModelInfo.network`` says) and what it lacks."""
    name = module.__name__.rpartition(".")[2]
    factory = getattr(module, "build", None)
    if not callable(factory):
        raise TypeError(f"network {name!r}: its module defines no build(spec, info) function")
    cls = factory.__annotations__.get("return")
    if isinstance(cls, str):  # postponed annotation: the class named in the factory's module
        cls = factory.__globals__.get(cls)
    if cls is None:
        raise TypeError(f"network {name!r}: its factory {factory.__qualname__} must annotate its return "
                        "with the network class (the PerceptionNet contract is checked on it)")
    gaps = contract_gaps(cls)
    if gaps:
        raise TypeError(f"network {name!r}: {getattr(cls, '__name__', cls)} does not meet the PerceptionNet "
                        f"contract (models/base.py); it lacks: {', '.join(gaps)}")
    return factory
