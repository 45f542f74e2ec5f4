"""Runs side by side: the jobs of one DVC stage in a pool of worker processes.

``dvc repro`` runs one stage at a time, so parallelism lives inside a stage (DVC-NOTES). A small
network at the default scale does not keep two cores busy from one process (at 32 px, batch 6,
two 1-thread processes train 1.4x faster than one 2-thread process on a 2-core CPU), so a stage
trains its runs (every model and seed of a dataset, every study arm and seed) in
``train.parallel_runs`` worker processes, each run with ``train.num_threads`` threads. A job is
one input to the stage's worker function, whole (a planned run, :class:`~..plan.PlannedRun`); what
every job shares (the stage's params) is bound to the function (:func:`functools.partial`), and
both cross to the workers pickled.

A run's result does not depend on the pool: every run seeds its own RNGs, fixes its own thread
count and starts from its own checkpoint (``tests/test_parallel.py`` checks that a run trained in
a pool after another run is byte-identical to the same run trained alone). Workers are spawned
(fresh interpreters that inherit the kernel pins of :mod:`..core.determinism` through the
environment), live for the whole stage and take the next job when one ends; jobs are submitted
longest first (by :attr:`Job.cost`), so the last ones to finish are short.

How many: ``train.parallel_runs`` as written (bounded by the usable cores), or ``auto``
(:func:`runs_side_by_side`): on a CPU the usable cores over ``train.num_threads``; on a CUDA GPU
:data:`CUDA_RUNS_PER_GPU`, the best of the counts measured on one GPU (samples/s together),
each worker's share of the GPU's memory bounded (:func:`bound_gpu_memory`) so that one run's peak
cannot starve the others.

The first failing job stops the stage: the pool is terminated (a killed run keeps its last
finished epoch in ``last.pt``, from which the next ``dvc repro`` resumes) and its one-line error
is re-raised in the stage process.
"""
from __future__ import annotations

import logging
import multiprocessing as mp
from dataclasses import dataclass
from typing import Any, Callable, Sequence

from tqdm.auto import tqdm

from ...core.errors import os_error_line
from ...core.machine import bounded, usable_cores

log = logging.getLogger(__name__)

__all__ = ["CUDA_RUNS_PER_GPU", "GPU_MEMORY_SHARE", "Job", "JobError", "bound_gpu_memory", "run_jobs",
           "runs_side_by_side", "stage_processes"]

#: Runs one CUDA GPU trains side by side under ``train.parallel_runs: auto``. Measured on an NVIDIA
#: H200 (the compact network, batch 6, fp32, k processes each training one run): 12 processes gave
#: about 430 samples/s together at 32 px and 400 at 128 px, 5-6x one process (73-80); 4 gave about
#: 280 and 155 (docs/gpu.md). The processes time-slice the GPU, so more than 12 add little.
CUDA_RUNS_PER_GPU = 12
#: The part of a GPU's memory the workers of one stage share, each ``GPU_MEMORY_SHARE / k``:
#: the rest is the CUDA contexts' and the allocator's slack.
GPU_MEMORY_SHARE = 0.9


def runs_side_by_side(parallel_runs: int | str, device_type: str, num_threads: int) -> int:
    """The worker processes of a stage's runs: ``parallel_runs`` as written (bounded by the usable
    cores), or for ``auto`` :data:`CUDA_RUNS_PER_GPU` on a CUDA device and the usable cores over
    ``num_threads`` on a CPU (at least 1; never above the usable cores)."""
    if parallel_runs != "auto":
        return max(1, bounded(int(parallel_runs)))
    if device_type == "cuda":
        return max(1, bounded(CUDA_RUNS_PER_GPU))
    return max(1, usable_cores() // max(1, int(num_threads)))


def stage_processes(train: Any) -> tuple[int, bool]:
    """``(processes, on a CUDA GPU)`` of a stage that runs its runs on ``train.device``, with
    ``train.parallel_runs`` and ``train.num_threads`` (:func:`runs_side_by_side`)."""
    from ...core.determinism import resolve_device

    device = resolve_device(train.device).type
    return runs_side_by_side(train.parallel_runs, device, train.num_threads), device == "cuda"


def bound_gpu_memory(processes: int) -> None:
    """In a worker of a stage that runs ``processes`` side by side on a CUDA GPU: this process may
    allocate at most ``GPU_MEMORY_SHARE / processes`` of the GPU's memory (an allocation past it is
    the allocator's out-of-memory error in this run, not a stall of every run). Nothing elsewhere."""
    import torch

    if processes > 1 and torch.cuda.is_available():
        torch.cuda.set_per_process_memory_fraction(GPU_MEMORY_SHARE / processes)


@dataclass(frozen=True)
class Job:
    """One unit of a stage's work, as plain data (it crosses process boundaries)."""

    name: str                      # for progress and errors: "A/compact_15l/seed0"
    item: Any                      # the worker function's input (a planned run)
    cost: float = 1.0              # relative expected run time: the longest go first


class JobError(RuntimeError):
    """A job failed; the message is the job's one-line error (it names its file or key)."""


def _call(fn: Callable[..., Any], job: Job) -> tuple[str, Any, str | None]:
    """Worker side: run one job; an expected error becomes its one-line message."""
    try:
        return job.name, fn(job.item), None
    except OSError as err:  # a full disk, a read-only folder: the file and the OS's reason
        return job.name, None, " ".join(os_error_line(err, job.name).split())
    except (RuntimeError, ValueError) as err:  # RunError, CacheError, ParamsError
        return job.name, None, " ".join(str(err).split())


def run_jobs(fn: Callable[..., Any], jobs: Sequence[Job], processes: int, desc: str,
             gpu: bool = False) -> list[Any]:
    """Run ``fn(job.item)`` for every job in ``processes`` worker processes (in this process
    when ``processes`` is 1 or there is one job) and return the results in the order of
    ``jobs``. ``fn`` must pickle: a module-level function (pickled by name) or a
    :func:`functools.partial` of one with picklable arguments. ``processes`` is
    bounded by the usable cores (:func:`~..core.machine.bounded`); ``gpu``: the jobs run on a CUDA
    GPU, each worker's memory bounded (:func:`bound_gpu_memory`). Raises :class:`JobError` with
    the first failing job's message."""
    processes = bounded(processes)
    order = sorted(range(len(jobs)), key=lambda i: -jobs[i].cost)   # stable: equal costs keep their order
    results: dict[str, Any] = {}
    bar = tqdm(total=len(jobs), desc=desc, unit="run")
    try:
        if processes <= 1 or len(jobs) <= 1:
            for i in order:
                _collect(_call(fn, jobs[i]), results, bar)
        else:
            size = min(processes, len(jobs))
            try:
                pool = mp.get_context("spawn").Pool(size, bound_gpu_memory if gpu else None, (size,) if gpu else ())
            except OSError as err:  # a worker that cannot start (Broken pipe, no memory to fork): not a job's file
                raise JobError(f"{desc}: could not start {size} worker processes ({err.strerror or err})") from None
            try:
                for out in pool.imap_unordered(_Caller(fn), [jobs[i] for i in order]):
                    _collect(out, results, bar)
            except OSError as err:  # the pool's pipes (a job's own errors come back as its message)
                pool.terminate()
                raise JobError(f"{desc}: lost the worker processes ({err.strerror or err})") from None
            except BaseException:
                pool.terminate()
                raise
            pool.close()  # the workers exit normally (their exit handlers run: the params audit)
            pool.join()
    finally:
        bar.close()
    return [results[j.name] for j in jobs]


class _Caller:
    """``fn`` bound for ``imap`` (a picklable callable: lambdas and closures are not)."""

    def __init__(self, fn: Callable[..., Any]) -> None:
        self.fn = fn

    def __call__(self, job: Job) -> tuple[str, Any, str | None]:
        return _call(self.fn, job)


def _collect(out: tuple[str, Any, str | None], results: dict[str, Any], bar: Any) -> None:
    name, value, error = out
    if error is not None:  # the message names its file or key; the log names the run
        log.error("%s failed", name)
        raise JobError(error)
    results[name] = value
    bar.update()
    log.info("finished %s (%d done)", name, len(results))
