"""What the machine lends a stage: the CPU cores this process may run on, the worker counts of
params bounded by them, and whether the device params ask for is there.

A worker count (``world.workers``, ``preprocess.workers``, ``train.num_workers``,
``train.parallel_runs``) changes no result, only how many processes share the work, so a count
above the usable cores buys nothing but memory and switching: ``train.parallel_runs: 64`` on two
cores started up to 64 training processes (each with its loader workers). Every place that starts
processes asks :func:`bounded` for its count; the params keep the value written (it is part of
what the data stages record), and the stage logs one line naming each count it lowers
(:func:`bounded_counts_line`). ``train.num_threads`` is not such a count: a threaded reduction's
result depends on it, so it is used as written.
"""
from __future__ import annotations

import os
from typing import Any, Iterable, Optional

__all__ = ["WORKER_COUNTS", "cpu_name", "usable_cores", "bounded", "bounded_counts_line", "device_problem"]

#: The params keys that count worker processes (any value gives the same result).
WORKER_COUNTS: tuple[str, ...] = ("world.workers", "preprocess.workers", "train.num_workers", "train.parallel_runs")


def cpu_name() -> str:
    """The CPU's model name as /proc/cpuinfo gives it; ``platform.processor()`` (often empty) or
    the architecture where there is no such file."""
    import platform

    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.partition(":")[2].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown"


def usable_cores() -> int:
    """The CPU cores this process may run on (its affinity mask, e.g. under ``taskset`` or a
    container's cpuset; the machine's count where the OS has no masks)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def bounded(count: int) -> int:
    """A worker count at most :func:`usable_cores` (0, "no worker processes", stays 0)."""
    return min(int(count), usable_cores())


def _value(params: Any, key: str) -> Optional[int]:
    """The count at ``key``; ``None`` for ``auto`` (chosen from the machine, never above it)."""
    node = params
    for part in key.split("."):
        node = getattr(node, part)
    return None if node == "auto" else int(node)


def bounded_counts_line(params: Any, keys: Iterable[str] = WORKER_COUNTS) -> Optional[str]:
    """The one line a stage logs when :func:`bounded` lowers any of its worker counts ``keys``
    (``None`` when none is above the usable cores)."""
    cores = usable_cores()
    over = [(key, value) for key in keys if (value := _value(params, key)) is not None and value > cores]
    if not over:
        return None
    return (f"this machine lends {cores} CPU core{'' if cores == 1 else 's'}: "
            + ", ".join(f"{key} {value} -> {cores}" for key, value in over)
            + " (a worker count changes no result)")


def device_problem(preference: str) -> Optional[str]:
    """Why ``train.device: <preference>`` cannot run here (``None`` when it can): asked once, by
    the stage, before it starts any worker process."""
    if preference != "cuda":
        return None
    import torch

    if not torch.cuda.is_available():
        return "train.device: 'cuda' but this machine has no CUDA device (use 'auto' or 'cpu')"
    return None
