"""A stage's work as jobs, and the worker-side call every executor makes.

A job is one input of the stage's worker function, whole (a planned run), with a name for
progress and errors and a relative cost (the longest are started first). What every job shares
(the stage's params) is bound to the function (:func:`functools.partial`); both cross to the
worker pickled. A job's expected error (a file or key that is wrong) comes back as its one-line
message, and the first one stops the stage as a :class:`JobError`; a failure of that run alone
(:class:`RunAloneError`: it ran out of its GPU's memory) comes back as a
:class:`Failed` value: the executor lets the other jobs finish, then raises it (:func:`in_order`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Sequence

from ..core.errors import os_error_line

__all__ = ["Failed", "Job", "JobError", "Outcome", "RunAloneError", "call", "in_order", "longest_first"]

#: What a worker sends back for one job: its name, its value, and its one-line error (or ``None``).
Outcome = tuple[str, Any, "str | None"]


@dataclass(frozen=True)
class Job:
    """One unit of a stage's work, as plain data (it crosses process boundaries)."""

    name: str                      # for progress and errors: "A/compact_15l/seed0"
    item: Any                      # the worker function's input (a planned run)
    cost: float = 1.0              # relative expected run time: the longest go first


class JobError(RuntimeError):
    """A job failed; the message is the job's one-line error (it names its file or key)."""


class RunAloneError(RuntimeError):
    """Raised by a worker function: a failure of its run alone, not of the stage's inputs (the run
    ran out of its GPU's memory while other runs shared it). The executor lets the other jobs
    finish, then fails the stage with this line."""


@dataclass(frozen=True)
class Failed:
    """The value of a job that failed alone (:class:`RunAloneError`): its one line."""

    line: str


def in_order(results: dict[str, Any], jobs: Sequence[Job]) -> list[Any]:
    """The jobs' results in their order, once every job has ended; raises :class:`JobError` with
    the first job (in that order) that failed alone, saying how many did and that the others finished."""
    failed = [results[j.name].line for j in jobs if isinstance(results[j.name], Failed)]
    if failed:
        others = len(jobs) - len(failed)
        raise JobError(f"{failed[0]} ({len(failed)} of {len(jobs)} runs failed this way; the other {others} "
                       f"finished)" if len(jobs) > 1 else failed[0])
    return [results[j.name] for j in jobs]


def call(fn: Callable[..., Any], job: Job) -> Outcome:
    """Worker side: run one job; an expected error becomes its one-line message."""
    try:
        return job.name, fn(job.item), None
    except RunAloneError as err:  # this run's alone: the others go on
        return job.name, Failed(" ".join(str(err).split())), None
    except OSError as err:  # a full disk, a read-only folder: the file and the OS's reason
        return job.name, None, " ".join(os_error_line(err, job.name).split())
    except (RuntimeError, ValueError) as err:  # RunError, CacheError, ParamsError
        return job.name, None, " ".join(str(err).split())


def longest_first(jobs: Sequence[Job]) -> list[int]:
    """The jobs' indices, costliest first (a stable sort: equal costs keep their order)."""
    return sorted(range(len(jobs)), key=lambda i: -jobs[i].cost)
