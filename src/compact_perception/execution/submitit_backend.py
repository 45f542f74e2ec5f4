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

A job that dies without a result (killed, out of the node's memory, cancelled from outside):
submitit sees a job end by its result file, else by ``sacct``, which a SLURM without accounting
storage does not answer (submitit then logs "Bypassing sacct error" and keeps waiting). So the
executor also asks the controller itself (:class:`QueueWatch`: ``squeue``, which needs no
accounting): a job it reports in an ended state, or no longer lists, for :data:`DEAD_AFTER_S`
with still no result file has ended without one, and the stage fails with its log.
"""
from __future__ import annotations

import logging
import os
import shlex
import shutil
import subprocess
import time
import traceback
from pathlib import Path
from typing import Any, Callable, Sequence

import submitit
from submitit.helpers import Checkpointable, DelayedSubmission
from tqdm.auto import tqdm

from ..core.determinism import PINNED_ENV, UNPINNED_ENV_VAR
from .jobs import Job, JobError, Outcome, call, in_order, longest_first
from .pool import collect
from .settings import ClusterSettings, SettingsError

log = logging.getLogger(__name__)

__all__ = ["DEAD_AFTER_S", "QueueWatch", "RunTask", "SubmititExecutor", "pin_lines"]

#: How long a job may be ended (or gone from the queue) by the controller's word with no result
#: file before it counts as dead: the file is written just before the job's process ends, and a
#: shared filesystem may show it a little later.
DEAD_AFTER_S = 30.0
#: SLURM's job states that are not waiting or running (``squeue --states=all``); a requeued job
#: is PENDING (or REQUEUED) again.
ENDED_STATES = frozenset({"BOOT_FAIL", "CANCELLED", "COMPLETED", "DEADLINE", "FAILED", "NODE_FAIL",
                          "OUT_OF_MEMORY", "PREEMPTED", "REVOKED", "SPECIAL_EXIT", "TIMEOUT"})


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
        watch = QueueWatch() if self.name == "slurm" else None
        try:
            while pending:
                finished = [j for j in pending if j.done()]
                for sub in finished:
                    collect(self._outcome(sub, jobs[pending.pop(sub)]), results, bar)
                dead = watch.dead(list(pending)) if watch is not None and pending else {}
                for sub, state in dead.items():
                    collect(_no_result(jobs[pending.pop(sub)], f"SLURM state {state}", sub), results, bar)
                if pending and not finished and not dead:
                    time.sleep(self.settings.poll_s)
        except BaseException:
            for sub in pending:
                sub.cancel(check=False)
            raise
        finally:
            bar.close()
        return in_order(results, jobs)

    @staticmethod
    def _outcome(sub: Any, job: Job) -> Outcome:
        """A finished job's outcome; a job that died (killed, out of memory, cancelled) names its log."""
        try:
            return sub.result()
        except Exception as err:  # noqa: BLE001 - submitit's FailedJobError / UncompletedJobError
            lines = [ln.strip() for ln in str(err).splitlines() if ln.strip()]
            return _no_result(job, lines[-1][:200] if lines else type(err).__name__, sub)


def _no_result(job: Job, why: str, sub: Any) -> Outcome:
    """The outcome of a job that ended without a result: why, and the job's log."""
    return job.name, None, f"{job.name}: the job ended without a result ({why}; log: {sub.paths.stderr})"


class QueueWatch:
    """What SLURM's controller says of submitted jobs (``squeue``, no accounting needed): the jobs
    that ended, or left the queue, :data:`DEAD_AFTER_S` ago or more and still have no result file."""

    def __init__(self, dead_after_s: float | None = None, clock: Callable[[], float] = time.monotonic) -> None:
        self.dead_after_s = DEAD_AFTER_S if dead_after_s is None else dead_after_s
        self.clock = clock
        self.ended_since: dict[str, float] = {}

    @staticmethod
    def states(job_ids: Sequence[str]) -> dict[str, str] | None:
        """Each listed job's state (array tasks one per line: ``123_4``); ``None`` where squeue
        cannot be asked (then nothing is judged dead)."""
        try:
            out = subprocess.run(["squeue", "--noheader", "--array", "--states=all", "--format=%i|%T",
                                  "--jobs", ",".join(job_ids)], capture_output=True, text=True, timeout=60)
        except (OSError, subprocess.SubprocessError):
            return None
        if out.returncode != 0 and "Invalid job id" not in out.stderr:
            return None   # an id that left the controller's memory is "Invalid job id": none listed
        listed = (ln.split("|", 1) for ln in out.stdout.splitlines() if "|" in ln)
        return {jid.strip(): state.strip().split()[0] for jid, state in listed if state.strip()}

    def dead(self, subs: Sequence[Any]) -> dict[Any, str]:
        """The jobs of ``subs`` (submitit jobs) dead by the controller's word: ``{job: its state}``
        (``gone`` for a job it no longer lists)."""
        states = self.states([str(sub.job_id) for sub in subs])
        if states is None:
            return {}
        now, dead = self.clock(), {}
        for sub in subs:
            jid = str(sub.job_id)
            state = states.get(jid, "gone")
            if state not in ENDED_STATES and state != "gone":
                self.ended_since.pop(jid, None)
                continue
            since = self.ended_since.setdefault(jid, now)
            if now - since >= self.dead_after_s and not sub.paths.result_pickle.exists():
                dead[sub] = state
        return dead
