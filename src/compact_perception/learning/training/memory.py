"""How much of a GPU one training run takes, measured, and how many runs one GPU holds side by side.

``train.parallel_runs: auto`` on CUDA used to be a fixed 12 processes per GPU (the count measured
best for speed on an 80-141 GB card). The per-process memory fraction
(:func:`~compact_perception.execution.pool.bound_gpu_memory`) bounds only each process's caching
allocator: every process also holds a CUDA context and the cuDNN and cuBLAS handles outside it, so
on a 16-24 GB card twelve of them do not fit and the first run to run out ended the whole pool.

So before a CUDA train stage starts its workers, one process of its own (spawned, so the stage
holds no CUDA context while the workers run) trains the stage's costliest run for two steps on a
real batch of its cache, exactly as the training loop builds it, and measures (:mod:`.memory_probe`,
apart from this module so that what only counts does not import the training loop):

- the caching allocator's peak reserved memory (``torch.cuda.max_memory_reserved``);
- what the steps took on the device outside the allocator (the drop of the device's free memory,
  ``torch.cuda.mem_get_info``, beyond what the allocator reserved: cuDNN and cuBLAS handles);
- the device's free and total memory once its context exists.

A process's CUDA context cannot be told apart from other processes' use by ``mem_get_info``, so it
is the stated :data:`CUDA_CONTEXT_BYTES`. The runs one GPU takes (:func:`runs_that_fit`) are those
whose footprints (peak + outside + context) fit in :data:`~compact_perception.execution.pool.GPU_MEMORY_SHARE`
of the memory free to the stage, at most :data:`~.parallel.CUDA_RUNS_PER_GPU` (past it they add
no speed) and at least one. The GPUs of one machine are taken to be alike (the probe measures the
first). Nothing here changes a run's bytes: it decides how many run at once.
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["CUDA_CONTEXT_BYTES", "RunMemory", "describe", "runs_that_fit"]

#: Device memory one CUDA process holds for its context (module images, the primary context's own
#: allocations) with PyTorch 2.x and CUDA 12's lazy module loading: 300-600 MiB on recent cards,
#: taken at the top. ``mem_get_info`` cannot tell it apart from other processes' use, so it is stated.
CUDA_CONTEXT_BYTES = 640 * 2**20
#: 1 MiB, for the log line.
MIB = 2**20


@dataclass(frozen=True)
class RunMemory:
    """One run's device memory, as :func:`.memory_probe.measure_run_memory` measured it (bytes)."""

    peak_bytes: int        # the caching allocator's peak reserved memory over the probe's steps
    outside_bytes: int     # taken on the device by the steps outside the allocator (library handles)
    free_bytes: int        # the device's free memory once the probe's context existed
    total_bytes: int       # the device's memory

    @property
    def per_run_bytes(self) -> int:
        """One run's footprint: its allocator's peak, what it holds outside it, its context."""
        return self.peak_bytes + self.outside_bytes + CUDA_CONTEXT_BYTES

    @property
    def available_bytes(self) -> int:
        """The device memory free to the stage's workers (the probe's own context is given back)."""
        return min(self.total_bytes, self.free_bytes + CUDA_CONTEXT_BYTES)


def runs_that_fit(memory: RunMemory, share: float, most: int) -> int:
    """The runs one GPU takes side by side: as many footprints as fit in ``share`` of its free
    memory, at most ``most``, at least 1 (a run that does not fit alone fails with its own line)."""
    fit = int(memory.available_bytes * share // max(1, memory.per_run_bytes))
    return max(1, min(most, fit))


def describe(memory: RunMemory) -> str:
    """The measured figures, for the stage's one log line."""
    return (f"one run measured at {memory.peak_bytes / MIB:.0f} MiB allocator peak + "
            f"{memory.outside_bytes / MIB:.0f} MiB outside it + {CUDA_CONTEXT_BYTES / MIB:.0f} MiB context, "
            f"{memory.available_bytes / MIB:.0f} of {memory.total_bytes / MIB:.0f} MiB free")
