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


def average_gradients(params: list[torch.nn.Parameter], d: Dist) -> None:
    """All-reduce and average ``.grad`` of ``params`` in one flat buffer."""
    if not d.enabled:
        return
    grads = [p.grad for p in params if p.grad is not None]
    if not grads:
        return
    flat = torch.cat([g.reshape(-1) for g in grads])
    dist.all_reduce(flat, op=dist.ReduceOp.SUM)
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
    # nccl reduces only CUDA tensors: the scalars travel on this rank's device under that backend
    device = torch.device("cuda", torch.cuda.current_device()) if dist.get_backend() == "nccl" else torch.device("cpu")
    t = torch.tensor([values[k] * weight for k in keys] + [weight], dtype=torch.float64, device=device)
    dist.all_reduce(t, op=dist.ReduceOp.SUM)
    return {k: float(t[i] / t[-1]) for i, k in enumerate(keys)}


def average_tensor(t: torch.Tensor, d: Dist) -> torch.Tensor:
    """Mean of ``t`` over ranks (a copy; ``t`` itself is left as it is)."""
    if not d.enabled:
        return t
    out = t.detach().clone()
    dist.all_reduce(out, op=dist.ReduceOp.SUM)
    return out / d.world_size


def barrier(d: Dist) -> None:
    if d.enabled:
        dist.barrier()


def shutdown(d: Dist) -> None:
    if d.enabled and dist.is_initialized():
        dist.destroy_process_group()
