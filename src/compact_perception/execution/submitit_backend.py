"""SLURM through submitit: a stage's jobs as one job array, each job one run.

submitit (the engine of DINOv2, DeiT, ConvNeXt, DETR, fairseq) pickles the worker function and
each job into ``folder``, submits them with ``sbatch --array`` (``slurm``), as subprocesses of
this machine (``local``) or in this process (``debug``), and pickles each result back; the stage
waits for them all and reads them in its own order. ``folder`` must be on a filesystem every node
shares, as must the checkout, its ``data/cache/`` and ``runs/``.

The same bytes as the pool: a job computes as a pool worker does, so its environment must hold
the numeric pins of :mod:`..core.determinism` before any numeric library loads; submitit imports
numpy before it unpickles the function (the stage package's import, which sets the pins in a pool
worker, comes too late), so the pins are exported in the job's own setup lines (:func:`pin_lines`).

Preemption and time limits: the job's callable is checkpointable (:class:`RunTask`); on SLURM's
signal before the limit (or a preemption) submitit calls :meth:`RunTask.checkpoint`, which
requeues the same job; the run then resumes from its ``last.pt`` (the last finished epoch, under
the same digest) and ends with the uninterrupted run's bytes. ``max_requeues`` bounds the timeouts.

The first failing job stops the stage: the others are cancelled (a run keeps its last finished
epoch) and its one-line error is the stage's.
"""
from __future__ import annotations

import logging
import os
import shlex
import shutil
import time
import traceback
from pathlib import Path
from typing import Any, Callable, Sequence

import submitit
from submitit.helpers import Checkpointable, DelayedSubmission
from tqdm.auto import tqdm

from ..core.determinism import PINNED_ENV, UNPINNED_ENV_VAR
from .jobs import Job, JobError, Outcome, call, longest_first
from .pool import collect
from .settings import ClusterSettings, SettingsError

log = logging.getLogger(__name__)

__all__ = ["RunTask", "SubmititExecutor", "pin_lines"]


def pin_lines(environ: Any = None) -> list[str]:
    """Shell lines that put the numeric pins in a job's environment before its Python starts
    (:data:`~..core.determinism.PINNED_ENV`; none but the opt-out when this process runs unpinned)."""
    env = os.environ if environ is None else environ
    if env.get(UNPINNED_ENV_VAR) == "1":
        return [f"export {UNPINNED_ENV_VAR}=1"]
    return [f"export {k}={shlex.quote(v)}" for k, v in PINNED_ENV.items()]


class RunTask(Checkpointable):
    """A job's callable: the stage's worker function on one job, requeued whole when the job is
    preempted or reaches its time limit (the run resumes from its ``last.pt``)."""

    def __init__(self, fn: Callable[..., Any]) -> None:
        self.fn = fn

    def __call__(self, job: Job) -> Outcome:
        try:
            return call(self.fn, job)
        except Exception as err:  # noqa: BLE001 - a job's log holds the traceback; the stage gets one line
            log.error("%s failed:\n%s", job.name, traceback.format_exc())
            where = _job_log()
            return job.name, None, f"{job.name}: {type(err).__name__}: {' '.join(str(err).split())[:300]}" + (
                f" (traceback in {where})" if where else "")

    def checkpoint(self, job: Job) -> DelayedSubmission:
        """Requeue the same job: the run's ``last.pt`` holds every finished epoch."""
        log.warning("%s: preempted or at its time limit; requeued, it resumes from its last finished epoch", job.name)
        return DelayedSubmission(self, job)


def _job_log() -> str | None:
    """The stderr file of the running submitit job (``None`` outside one)."""
    try:
        return str(submitit.JobEnvironment().paths.stderr)
    except Exception:  # noqa: BLE001 - not in a job (debug executor)
        return None


class SubmititExecutor:
    """The stage's jobs as submitit jobs (``slurm``, ``local`` or ``debug``), :class:`~.settings.ClusterSettings`."""

    def __init__(self, settings: ClusterSettings) -> None:
        self.settings = settings
        self.name = settings.executor
        if settings.executor == "slurm" and shutil.which("sbatch") is None:
            raise SettingsError("executor: slurm needs SLURM's sbatch and srun on PATH (none found on this machine)")

    def executor(self, folder: Path) -> submitit.Executor:
        """The submitit executor with the cluster settings."""
        s = self.settings
        setup = [*pin_lines(), *s.setup]
        if s.executor == "debug":
            return submitit.DebugExecutor(folder)
        if s.executor == "local":
            ex = submitit.LocalExecutor(folder, max_num_timeout=s.max_requeues)
            ex.update_parameters(timeout_min=s.time_min, gpus_per_node=s.gpus_per_task, setup=setup)
            return ex
        ex = submitit.SlurmExecutor(folder, max_num_timeout=s.max_requeues)
        given = {"partition": s.partition, "account": s.account, "qos": s.qos, "cpus_per_task": s.cpus_per_task,
                 "mem": f"{s.mem_gb:g}GB" if s.mem_gb else None, "gpus_per_node": s.gpus_per_task or None}
        ex.update_parameters(time=s.time_min, array_parallelism=s.array_parallelism, setup=setup,
                             **{k: v for k, v in given.items() if v is not None}, **dict(s.extra))
        return ex

    def run(self, fn: Callable[..., Any], jobs: Sequence[Job], processes: int, desc: str,
            gpu: bool = False) -> list[Any]:
        """Submit every job (longest first, one array), wait for them, and return their results in
        the order of ``jobs``; ``processes`` and ``gpu`` are the pool's (the cluster file says what
        each job gets). Raises :class:`~.jobs.JobError` with the first failing job's message."""
        if not jobs:
            return []
        folder = Path(self.settings.folder) / desc.replace(" ", "_")
        ex = self.executor(folder)
        task = RunTask(fn)
        order = longest_first(jobs)
        try:
            with ex.batch():
                submitted = [ex.submit(task, jobs[i]) for i in order]
        except Exception as err:  # noqa: BLE001 - sbatch refused (a partition, an account): its one line
            raise JobError(f"{desc}: {self.name} did not take the jobs ({' '.join(str(err).split())[:300]})") from None
        log.info("%s: %d jobs submitted to submitit's %s executor (%s)", desc, len(jobs), self.name, folder)
        return self._wait(dict(zip(submitted, order)), jobs, desc)

    def _wait(self, pending: dict[Any, int], jobs: Sequence[Job], desc: str) -> list[Any]:
        results: dict[str, Any] = {}
        bar = tqdm(total=len(jobs), desc=desc, unit="run")
        try:
            while pending:
                finished = [j for j in pending if j.done()]
                for sub in finished:
                    collect(self._outcome(sub, jobs[pending.pop(sub)]), results, bar)
                if pending and not finished:
                    time.sleep(self.settings.poll_s)
        except BaseException:
            for sub in pending:
                sub.cancel(check=False)
            raise
        finally:
            bar.close()
        return [results[j.name] for j in jobs]

    @staticmethod
    def _outcome(sub: Any, job: Job) -> Outcome:
        """A finished job's outcome; a job that died (killed, out of memory, cancelled) names its log."""
        try:
            return sub.result()
        except Exception as err:  # noqa: BLE001 - submitit's FailedJobError / UncompletedJobError
            lines = [ln.strip() for ln in str(err).splitlines() if ln.strip()]
            last = lines[-1][:200] if lines else type(err).__name__
            return job.name, None, f"{job.name}: the job ended without a result ({last}; log: {sub.paths.stderr})"
