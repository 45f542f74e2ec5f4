"""Data-parallel training under ``torchrun`` (SPEC 9: gloo on CPU, nccl on GPU, rank 0 writes).

Gradients are averaged across ranks explicitly after each backward pass: the same maths
as ``DistributedDataParallel`` (every rank applies the mean gradient of the global batch),
but it leaves the model unwrapped so that MGN/GradNorm can call ``torch.autograd.grad``
on named shared layers, which DDP's reducer hooks do not support.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import torch
import torch.distributed as dist


@dataclass(frozen=True)
class Dist:
    rank: int = 0
    world_size: int = 1
    local_rank: int = 0

    @property
    def enabled(self) -> bool:
        return self.world_size > 1

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    def sum_over_ranks(self, t: torch.Tensor) -> torch.Tensor:
        """The sum of ``t`` over the ranks, a new tensor on ``t``'s device (``t`` itself in one
        process). A loss weighting closes a value from every rank's batches with it
        (:attr:`~compact_perception.learning.weighting.base.LossWeighting.ranks`)."""
        return _sum_over_ranks(t, self) if self.enabled else t

    def mean_over_ranks(self, t: torch.Tensor) -> torch.Tensor:
        """The mean of ``t`` over the ranks (:func:`average_tensor`)."""
        return average_tensor(t, self)


def init_from_env(device_type: str) -> Dist:
    """Join the process group that ``torchrun`` describes in the environment (if any)."""
    world_size = int(os.environ.get("WORLD_SIZE", "1"))
    if world_size <= 1:
        return Dist()
    rank = int(os.environ["RANK"])
    local_rank = int(os.environ.get("LOCAL_RANK", "0"))
    if not dist.is_initialized():
        backend = "nccl" if device_type == "cuda" else "gloo"
        if device_type == "cuda":
            torch.cuda.set_device(local_rank)
        dist.init_process_group(backend=backend)
    return Dist(rank=rank, world_size=world_size, local_rank=local_rank)


def group_device(d: Dist) -> torch.device:
    """The device the process group reduces on: this rank's GPU under nccl (which refuses CPU
    tensors), the CPU under gloo. Every collective here stages its tensor there and back, so a
    caller may hand it a tensor on any device (a loss weighting's CPU float64 weights, say)."""
    if dist.get_backend() == "nccl":
        return torch.device("cuda", torch.cuda.current_device())
    return torch.device("cpu")


def _from_group(staged: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """A reduced tensor back on ``like``'s device and in its dtype."""
    return staged.to(device=like.device, dtype=like.dtype)


def _sum_over_ranks(t: torch.Tensor, d: Dist) -> torch.Tensor:
    """The sum of ``t`` over ranks, reduced on the group's device (:func:`group_device`) and
    returned as a new tensor on ``t``'s device."""
    staged = t.detach().to(group_device(d), copy=True)
    dist.all_reduce(staged, op=dist.ReduceOp.SUM)
    return _from_group(staged, t)


def average_gradients(params: list[torch.nn.Parameter], d: Dist) -> None:
    """All-reduce and average ``.grad`` of ``params`` in one flat buffer.

    Called before the GradScaler unscales (training/epoch.py): a rank's inf or nan then reaches
    every rank's mean gradient, so every rank's scaler skips the same step and their loss scales
    stay equal."""
    if not d.enabled:
        return
    grads = [p.grad for p in params if p.grad is not None]
    if not grads:
        return
    flat = _sum_over_ranks(torch.cat([g.reshape(-1) for g in grads]), d)
    flat /= d.world_size
    offset = 0
    for g in grads:
        n = g.numel()
        g.copy_(flat[offset : offset + n].view_as(g))
        offset += n


def average_scalars(values: dict[str, float], d: Dist, weight: float = 1.0) -> dict[str, float]:
    """Weighted mean of per-rank scalar dicts (all ranks must pass the same keys)."""
    if not d.enabled:
        return dict(values)
    keys = sorted(values)
    t = _sum_over_ranks(torch.tensor([values[k] * weight for k in keys] + [weight], dtype=torch.float64), d)
    return {k: float(t[i] / t[-1]) for i, k in enumerate(keys)}


def average_tensor(t: torch.Tensor, d: Dist) -> torch.Tensor:
    """Mean of ``t`` over ranks: a new tensor on ``t``'s device and of its dtype (``t`` itself is
    left as it is)."""
    if not d.enabled:
        return t
    return _sum_over_ranks(t, d) / d.world_size


def barrier(d: Dist) -> None:
    if d.enabled:
        dist.barrier()


def shutdown(d: Dist) -> None:
    if d.enabled and dist.is_initialized():
        dist.destroy_process_group()
