"""The seam between a stage and the engine that runs its jobs.

A stage hands :func:`run_jobs` its jobs (the planned runs still to do, each whole) and the worker
function they are given to; the executor returns their results in the order of the jobs, or
raises :class:`~.jobs.JobError` with the first failure's one line. Two kinds:

- :class:`PoolExecutor` (``pool``, the default): this machine's process pool (:mod:`.pool`);
- :class:`~.submitit_backend.SubmititExecutor` (``slurm``, ``local``, ``debug``): submitit's jobs.

:func:`chosen_executor` reads which (:mod:`.settings`: ``COMPACT_PERCEPTION_EXECUTOR``,
``cluster.yaml``); the choice changes no result, so it is no param and no part of a digest.
"""
from __future__ import annotations

from typing import Any, Callable, Mapping, Optional, Protocol, Sequence

from .jobs import Job
from .pool import run_pool
from .settings import ClusterSettings, read_settings

__all__ = ["Executor", "PoolExecutor", "chosen_executor", "executor_for", "run_jobs"]


class Executor(Protocol):
    """Runs ``fn(job.item)`` for every job and returns the results in the order of ``jobs``."""

    name: str

    def run(self, fn: Callable[..., Any], jobs: Sequence[Job], processes: int, desc: str,
            gpu: bool = False) -> list[Any]: ...


class PoolExecutor:
    """This machine's process pool (:func:`~.pool.run_pool`): ``processes`` workers, ``gpu``: on CUDA."""

    name = "pool"

    def run(self, fn: Callable[..., Any], jobs: Sequence[Job], processes: int, desc: str,
            gpu: bool = False) -> list[Any]:
        return run_pool(fn, jobs, processes, desc, gpu=gpu)


def executor_for(settings: ClusterSettings) -> Executor:
    """The executor ``settings`` name."""
    if not settings.submitted:
        return PoolExecutor()
    from .submitit_backend import SubmititExecutor

    return SubmititExecutor(settings)


def chosen_executor(environ: Optional[Mapping[str, str]] = None) -> Executor:
    """The executor of this stage (:func:`~.settings.read_settings`); a bad setting is a
    :class:`~.settings.SettingsError` of one line, raised before the stage writes anything."""
    return executor_for(read_settings(environ))


def run_jobs(fn: Callable[..., Any], jobs: Sequence[Job], processes: int, desc: str, gpu: bool = False,
             executor: Optional[Executor] = None) -> list[Any]:
    """``fn(job.item)`` for every job through ``executor`` (default: the local pool), the results
    in the order of ``jobs``."""
    return (executor or PoolExecutor()).run(fn, jobs, processes, desc, gpu=gpu)
