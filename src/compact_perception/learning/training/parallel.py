"""Runs side by side: how many of a stage's runs one machine trains at once.

The jobs themselves (a job is one planned run, :class:`~..plan.PlannedRun`, the stage's params
bound to the worker function) are executed by :mod:`compact_perception.execution`: the local
process pool (the default) or submitit; this module keeps what is about runs, and re-exports the
pool's names for the code that imports them from here.

How many: ``train.parallel_runs`` as written (bounded by the usable cores), or ``auto``
(:func:`runs_side_by_side`): on a CPU the usable cores over ``train.num_threads``; on CUDA, per
visible GPU, as many runs as its memory holds by a measured run's footprint (:mod:`.memory`: one
process trains the stage's costliest run for two steps first), at most :data:`CUDA_RUNS_PER_GPU`,
the best of the counts measured on one GPU (samples/s together); each worker's share of its GPU's
memory is bounded (:func:`~compact_perception.execution.pool.bound_gpu_memory`) so that one run's
peak cannot starve the others, and the workers are spread over the GPUs, one device each.
"""
from __future__ import annotations

import logging
import multiprocessing as mp  # noqa: F401 - the pool's (tests replace its context here)
from typing import Any, Callable, Optional

from ...core.machine import bounded, usable_cores
from ...execution.jobs import Job, JobError
from ...execution.pool import GPU_MEMORY_SHARE, bound_gpu_memory, gpu_count
from ...execution.executor import run_jobs

log = logging.getLogger(__name__)

__all__ = ["CUDA_RUNS_PER_GPU", "GPU_MEMORY_SHARE", "Job", "JobError", "bound_gpu_memory", "run_jobs",
           "runs_side_by_side", "stage_processes"]

#: Runs one CUDA GPU trains side by side under ``train.parallel_runs: auto``. Measured on an NVIDIA
#: H200 (the compact network, batch 6, fp32, k processes each training one run): 12 processes gave
#: about 430 samples/s together at 32 px and 400 at 128 px, 5-6x one process (73-80); 4 gave about
#: 280 and 155 (docs/gpu.md). The processes time-slice the GPU, so more than 12 add little.
#: Under ``auto`` it is the most a GPU gets; its memory may allow fewer (:mod:`.memory`).
CUDA_RUNS_PER_GPU = 12


def runs_side_by_side(parallel_runs: int | str, device_type: str, num_threads: int,
                      per_gpu: int = CUDA_RUNS_PER_GPU) -> int:
    """The worker processes of a stage's runs: ``parallel_runs`` as written (bounded by the usable
    cores), or for ``auto`` ``per_gpu`` per visible GPU on a CUDA device (the runs one GPU's memory
    holds, :func:`~.memory.runs_that_fit`) and the usable cores over ``num_threads`` on a CPU (at
    least 1; never above the usable cores)."""
    if parallel_runs != "auto":
        return max(1, bounded(int(parallel_runs)))
    if device_type == "cuda":
        return max(1, bounded(max(1, per_gpu) * max(1, gpu_count())))
    return max(1, usable_cores() // max(1, int(num_threads)))


def stage_processes(train: Any, probe: Optional[Callable[[], Any]] = None) -> tuple[int, bool]:
    """``(processes, on a CUDA GPU)`` of a stage that runs its runs on ``train.device``, with
    ``train.parallel_runs`` and ``train.num_threads`` (:func:`runs_side_by_side`). ``probe``: what
    measures one run's device memory (:func:`~.memory_probe.measure_in_subprocess` bound to the stage's
    costliest run, returning a :class:`~.memory.RunMemory`), called only for ``auto`` on CUDA; a
    probe that runs out of memory itself leaves one run per GPU."""
    from ...core.determinism import resolve_device

    device = resolve_device(train.device).type
    per_gpu, measured = CUDA_RUNS_PER_GPU, None
    if train.parallel_runs == "auto" and device == "cuda" and probe is not None:
        per_gpu, measured = _measured_per_gpu(probe)
    processes = runs_side_by_side(train.parallel_runs, device, train.num_threads, per_gpu)
    if train.parallel_runs == "auto":
        log.info("train.parallel_runs auto: %d side by side (%s)", processes,
                 _why(device, train.num_threads, per_gpu, measured))
    return processes, device == "cuda"


def _measured_per_gpu(probe: Callable[[], Any]) -> tuple[int, str]:
    """The runs one GPU holds by the probe's measurement, and the measurement in words."""
    from .memory import describe, runs_that_fit

    try:
        memory = probe()
    except Exception as err:  # noqa: BLE001 - torch.OutOfMemoryError or a RuntimeError saying it, from the probe's process
        if "out of memory" not in str(err).lower():
            raise
        return 1, "one run alone ran out of the GPU's memory when measured"
    return runs_that_fit(memory, GPU_MEMORY_SHARE, CUDA_RUNS_PER_GPU), describe(memory)


def _why(device: str, num_threads: int, per_gpu: int = CUDA_RUNS_PER_GPU, measured: Optional[str] = None) -> str:
    """Why ``auto`` chose its count (the one line a stage logs)."""
    cores = usable_cores()
    if device == "cuda":
        gpus = max(1, gpu_count())
        fit = (f"{per_gpu} per CUDA GPU by its memory ({measured}; at most {CUDA_RUNS_PER_GPU}, the best count "
               "measured on one)" if measured else f"{CUDA_RUNS_PER_GPU} per CUDA GPU, the best count measured on one")
        return f"{fit}, x {gpus} GPU{'' if gpus == 1 else 's'}, at most the {cores} usable CPU cores"
    return f"{cores} usable CPU core{'' if cores == 1 else 's'} over train.num_threads {num_threads}"
