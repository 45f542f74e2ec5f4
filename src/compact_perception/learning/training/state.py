"""The state of one training run (paper section IV-D), shared by the steps of :mod:`.train`.

:class:`RunSpec` is the planned run (:class:`~compact_perception.learning.plan.PlannedRun`: its ids, recipe,
epoch cap and paths) with how this process runs it, fixed before anything is built (the device and
processes, the RNG seed and the digest that gates resuming); :class:`RunState` is the spec with
the training machinery the setup step builds and the progress the other steps advance (and a
checkpoint saves: :mod:`.checkpoint`).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

import torch
from torch import nn
from torch.utils.data import DataLoader

from ...core.params import Params
from ..plan import PlannedRun
from ..weighting import LossWeighting
from .distributed import Dist
from ..schedule import EarlyStop, Plateau

__all__ = ["RunSpec", "RunState"]


@dataclass(frozen=True, kw_only=True)
class RunSpec:
    """What one run is (the planned run, the params) and how this process runs it (built by
    keyword only: its fields are read by name everywhere)."""

    params: Params
    planned: PlannedRun
    device: torch.device
    dist: Dist
    rng_seed: int                      # train.run_seed of the planned run's training seed
    digest: str                        # train.run_digest: a checkpoint of another digest is not resumed
    per_rank_batch: int
    num_seg_classes: int
    dtype: torch.dtype = torch.float32
    stop_after_epochs: Optional[int] = None  # end the process after this many epochs of this call (tests)
    progress: bool = True              # a per-step progress bar (off in a stage's worker processes)


@dataclass
class RunState:
    """One run from setup to finish: the machinery (built by the setup step) and the progress
    (restored from ``last.pt`` by the resume step, advanced by every epoch)."""

    spec: RunSpec
    model: nn.Module
    forward: Callable[..., Any]        # the model, or its torch.compile'd forward
    weighting: LossWeighting
    optimizer: torch.optim.Optimizer
    plateau: Plateau
    stopper: EarlyStop
    scaler: torch.amp.GradScaler
    precision: str                     # the resolved train.precision (fp32, bf16, fp16)
    de_factor: float                   # the recipe's DE loss form (losses.de_loss_factor)
    lr: float                          # the lr of the next epoch (plateau schedule)
    next_epoch: int = 0
    history: list[dict] = field(default_factory=list)
    best_score: float = math.inf
    best_epoch: int = -1
    untrained_score: Optional[float] = None
    stopped_early: bool = False
    elapsed_before: float = 0.0        # training seconds of earlier calls (resumed runs)
    started: float = 0.0               # time.perf_counter() at the first epoch of this call
    epochs_this_call: int = 0
    train_loader: Optional[DataLoader] = None
    val_loader: Optional[DataLoader] = None
    live: Any = None                   # dvclive.Live on rank 0, None elsewhere
    synced_w: Any = None               # the weighting's w as last averaged over ranks (data-parallel runs)
    epoch_sums: Any = None             # the running epoch's losses and metrics on the device (epoch.EpochSums)
    captured: Any = None               # the step replayed as a CUDA graph (capture.CapturedStep), or None: eager

    def elapsed(self) -> float:
        """Training seconds so far, earlier calls included."""
        return self.elapsed_before + time.perf_counter() - self.started
