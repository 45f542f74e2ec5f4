"""One run's device memory, measured: the probe behind ``train.parallel_runs: auto`` on CUDA
(:mod:`.memory` says what is measured and how the count follows). It builds the run as the
training loop does, so only the train stage and ``pipeline.train_all`` import it.
"""
from __future__ import annotations

import multiprocessing as mp
from typing import Any

from .memory import RunMemory

__all__ = ["PROBE_STEPS", "measure_in_subprocess", "measure_run_memory"]

#: Training steps of the probe: the first builds the cuDNN and cuBLAS handles and their
#: workspaces, the next reuses the allocator's blocks; the peak is reached by the second.
PROBE_STEPS = 2


def measure_run_memory(params: Any, run: Any, steps: int = PROBE_STEPS) -> RunMemory:
    """In this process, on ``train.device`` (CUDA): ``steps`` training steps of the planned run
    ``run`` as the training loop builds it (network, weighting, optimiser, precision, its cache's
    first training batch), writing nothing; the memory they took (:class:`RunMemory`)."""
    import torch

    from ...core import catalog
    from ...core.determinism import resolve_device
    from ...data.loader import make_loader
    from .epoch import train_step
    from .standalone import standalone_run

    device = resolve_device(params.train.device)
    if device.type != "cuda":
        raise RuntimeError(f"train.device {params.train.device!r}: the memory probe measures a CUDA device")
    torch.cuda.init()
    free0, total = torch.cuda.mem_get_info(device)
    state = standalone_run(params, run, device, digest="memory-probe")
    labelled = getattr(state.model, "labelled_maps", ())
    loader = make_loader(run.paths.cache_dir, "train", catalog.MODELS[run.model].lidar_channels,
                         params.train.batch_size, shuffle=False, labelled=labelled, pin_memory=True)
    batch = next(iter(loader))
    for step in range(steps):
        train_step(state, batch, step, steps)
    torch.cuda.synchronize(device)
    free1, _ = torch.cuda.mem_get_info(device)
    reserved = torch.cuda.memory_reserved(device)
    return RunMemory(peak_bytes=int(torch.cuda.max_memory_reserved(device)),
                     outside_bytes=max(0, int(free0 - free1 - reserved)), free_bytes=int(free0), total_bytes=int(total))


def measure_in_subprocess(params: Any, run: Any) -> RunMemory:
    """:func:`measure_run_memory` in a spawned process of its own, which exits with its CUDA context."""
    with mp.get_context("spawn").Pool(1) as pool:
        return pool.apply(measure_run_memory, (params, run))
