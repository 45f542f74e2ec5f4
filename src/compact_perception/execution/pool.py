"""The local executor: a stage's jobs in a pool of worker processes on this machine (the default).

``dvc repro`` runs one stage at a time, so parallelism lives inside a stage (DVC-NOTES). A small
network at the default scale does not keep two cores busy from one process (at 32 px, batch 6,
two 1-thread processes train 1.4x faster than one 2-thread process on a 2-core CPU), so a stage
trains its runs in ``train.parallel_runs`` worker processes, each run with ``train.num_threads``
threads. A job's result does not depend on the pool: every run seeds its own RNGs, fixes its own
thread count and starts from its own checkpoint (``tests/test_parallel.py`` checks that a run
trained in a pool after another run is byte-identical to the same run trained alone). Workers are
spawned (fresh interpreters that inherit the kernel pins of :mod:`..core.determinism` through the
environment), live for the whole stage and take the next job when one ends; jobs are submitted
longest first (by :attr:`~.jobs.Job.cost`), so the last ones to finish are short.

On CUDA GPUs each worker's share of its GPU's memory is bounded (:func:`bound_gpu_memory`) so that
one run's peak cannot starve the others; with more than one visible GPU (a multi-GPU workstation)
the workers are spread over them, one device each, round robin (:func:`device_plan`): a worker sees
only its GPU (``CUDA_VISIBLE_DEVICES``), so ``train.device: cuda`` is that GPU.

The first failing job stops the stage: the pool is terminated (a killed run keeps its last
finished epoch in ``last.pt``, from which the next ``dvc repro`` resumes) and its one-line error
is re-raised in the stage process. A run that fails alone (it ran out of its GPU's memory,
:class:`~.jobs.RunAloneError`) stops only itself: its worker takes the next job, the
other runs finish, and then the stage fails with that run's line (:func:`~.jobs.in_order`).
"""
from __future__ import annotations

import logging
import math
import multiprocessing as mp
import os
import queue as queue_module
from typing import Any, Callable, Optional, Sequence

from tqdm.auto import tqdm

from ..core.machine import bounded
from .jobs import Failed, Job, JobError, Outcome, call as _call, in_order, longest_first

log = logging.getLogger(__name__)

__all__ = ["GPU_MEMORY_SHARE", "bound_gpu_memory", "device_plan", "gpu_count", "run_pool", "visible_gpus"]

#: The part of a GPU's memory the workers on it share, each ``GPU_MEMORY_SHARE / k``: the rest is
#: the CUDA contexts' and the allocator's slack.
GPU_MEMORY_SHARE = 0.9
#: How long a spread worker waits for its GPU's id (a worker the pool restarts after a crash may
#: find none left: it then sees every GPU, as a pool on one GPU does).
DEVICE_WAIT_S = 5.0


def bound_gpu_memory(processes: int) -> None:
    """In a worker of a stage that runs ``processes`` side by side on one CUDA GPU: this process
    may allocate at most ``GPU_MEMORY_SHARE / processes`` of the GPU's memory (an allocation past it
    is the allocator's out-of-memory error in this run, not a stall of every run). Nothing elsewhere."""
    import torch

    if processes > 1 and torch.cuda.is_available():
        torch.cuda.set_per_process_memory_fraction(GPU_MEMORY_SHARE / processes)


def gpu_count() -> int:
    """The CUDA devices this process sees (0 without CUDA); a test replaces it with a stand-in."""
    import torch

    return torch.cuda.device_count() if torch.cuda.is_available() else 0


def visible_gpus() -> list[str]:
    """The ids a worker can be given in ``CUDA_VISIBLE_DEVICES``: this process's own list where it
    has one (``"2,3"``), else ``0 .. n-1``; as many as :func:`gpu_count` sees."""
    n = gpu_count()
    listed = [d.strip() for d in os.environ.get("CUDA_VISIBLE_DEVICES", "").split(",") if d.strip()]
    return listed[:n] if listed else [str(i) for i in range(n)]


def device_plan(workers: int, gpus: Sequence[str]) -> list[str]:
    """The GPU of each of ``workers`` workers, round robin over ``gpus`` (worker k on ``gpus[k % n]``)."""
    return [gpus[k % len(gpus)] for k in range(workers)] if gpus else []


def _spread_worker(devices: Any, per_gpu: int) -> None:
    """Pool initializer with several GPUs: take this worker's GPU from the stage's plan before
    CUDA starts here, then bound its memory share among the workers on that GPU."""
    try:
        os.environ["CUDA_VISIBLE_DEVICES"] = devices.get(timeout=DEVICE_WAIT_S)
    except queue_module.Empty:
        pass
    bound_gpu_memory(per_gpu)


def _pool(size: int, gpu: bool, desc: str) -> Any:
    """``size`` spawned workers; on CUDA each one's memory bounded and, with several GPUs, each on one."""
    ctx = mp.get_context("spawn")
    gpus = visible_gpus() if gpu else []
    try:
        if len(gpus) > 1:
            devices = ctx.Queue()
            for device in device_plan(size, gpus):
                devices.put(device)
            log.info("%s: %d workers over %d GPUs (%s)", desc, size, len(gpus), ", ".join(gpus))
            return ctx.Pool(size, _spread_worker, (devices, math.ceil(size / len(gpus))))
        return ctx.Pool(size, bound_gpu_memory if gpu else None, (size,) if gpu else ())
    except OSError as err:  # a worker that cannot start (Broken pipe, no memory to fork): not a job's file
        raise JobError(f"{desc}: could not start {size} worker processes ({err.strerror or err})") from None


def run_pool(fn: Callable[..., Any], jobs: Sequence[Job], processes: int, desc: str,
             gpu: bool = False) -> list[Any]:
    """Run ``fn(job.item)`` for every job in ``processes`` worker processes (in this process
    when ``processes`` is 1 or there is one job) and return the results in the order of
    ``jobs``. ``fn`` must pickle: a module-level function (pickled by name) or a
    :func:`functools.partial` of one with picklable arguments. ``processes`` is
    bounded by the usable cores (:func:`~..core.machine.bounded`); ``gpu``: the jobs run on CUDA,
    each worker's memory bounded (:func:`bound_gpu_memory`) and the workers spread over the
    visible GPUs. Raises :class:`~.jobs.JobError` with the first failing job's message."""
    processes = bounded(processes)
    order = longest_first(jobs)
    results: dict[str, Any] = {}
    bar = tqdm(total=len(jobs), desc=desc, unit="run")
    try:
        if processes <= 1 or len(jobs) <= 1:
            for i in order:
                collect(_call(fn, jobs[i]), results, bar)
        else:
            pool = _pool(min(processes, len(jobs)), gpu, desc)
            try:
                for out in pool.imap_unordered(_Caller(fn), [jobs[i] for i in order]):
                    collect(out, results, bar)
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
    return in_order(results, jobs)


class _Caller:
    """``fn`` bound for ``imap`` (a picklable callable: lambdas and closures are not)."""

    def __init__(self, fn: Callable[..., Any]) -> None:
        self.fn = fn

    def __call__(self, job: Job) -> Outcome:
        return _call(self.fn, job)


def collect(out: Outcome, results: dict[str, Any], bar: Optional[Any]) -> None:
    """One job's outcome into ``results`` (every executor's): its error is the stage's
    :class:`~.jobs.JobError`."""
    name, value, error = out
    if error is not None:  # the message names its file or key; the log names the run
        log.error("%s failed", name)
        raise JobError(error)
    results[name] = value
    if bar is not None:
        bar.update()
    if isinstance(value, Failed):  # this run alone: the others go on, the stage fails at the end
        log.error("%s failed alone; the other runs go on: %s", name, value.line)
    else:
        log.info("finished %s (%d done)", name, len(results))
