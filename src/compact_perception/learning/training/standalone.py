"""A run built as the training loop's setup step builds it (network, loss weighting, optimiser,
precision, captured step), outside the loop, for code that takes a few of its steps: the GPU memory
probe (:mod:`.memory_probe`), ``benchmarks/gpu_check.py`` and ``bench_census.py``, and the tests.
Its RNGs are seeded with 0; nothing is read from or written to the run's folder.
"""
from __future__ import annotations

from typing import Any, Optional

import torch

from ...core.cache import read_meta
from . import distributed as ddp
from .state import RunSpec, RunState
from .train import _setup

__all__ = ["standalone_run"]


def standalone_run(params: Any, planned: Any, device: torch.device, *, digest: str,
                   dist: Optional[ddp.Dist] = None) -> RunState:
    """The planned run ``planned`` set up on ``device`` at ``train.batch_size`` (``dist``: a
    data-parallel group, default none), its network in training mode; ``digest`` names the caller."""
    spec = RunSpec(params=params, planned=planned, device=device, dist=dist or ddp.Dist(), rng_seed=0, digest=digest,
                   per_rank_batch=params.train.batch_size,
                   num_seg_classes=len(read_meta(planned.paths.cache_dir)["seg_classes"]), progress=False)
    run = _setup(spec)
    run.model.train()
    return run
