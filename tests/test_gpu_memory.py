"""``train.parallel_runs: auto`` on a CUDA GPU takes as many runs as the GPU's memory holds by a
measured run (learning/training/memory.py), not 12 whatever the card; one run that runs out of its
GPU's memory fails alone: the stage's other runs finish, then the stage fails with that run's
one line naming it and what to set (issue 55 item 6). No GPU here: the device, its memory and the
allocator's error are stand-ins."""
from __future__ import annotations

import logging
from functools import partial
from pathlib import Path

import pytest
import torch

from compact_perception.core.params import parse_params
from compact_perception.execution.executor import run_jobs
from compact_perception.execution.jobs import Failed, Job, JobError, RunAloneError, call
from compact_perception.learning.training import memory, memory_probe, parallel

from repo_params import repo_params_dict
from run_fixture import run_in

MIB = 2**20


def _card(total_mib: int, free_mib: int, peak_mib: int = 1200, outside_mib: int = 150) -> memory.RunMemory:
    return memory.RunMemory(peak_bytes=peak_mib * MIB, outside_bytes=outside_mib * MIB, free_bytes=free_mib * MIB,
                            total_bytes=total_mib * MIB)


def test_the_runs_one_gpu_takes_follow_from_its_memory_and_the_measured_run():
    """By hand: one run is 1200 + 150 + 640 (context) = 1990 MiB; a 16 GiB card with 15,800 MiB free
    after the probe's context has min(16,384, 15,800 + 640) = 16,384 MiB for the workers, 0.9 of it
    14,745.6 MiB: 7 runs (7.41). A 24 GiB card: 0.9 x 24,576 / 1990 = 11.1, 11 runs; an 80 GB card:
    36, capped at 12; a run larger than the card: 1."""
    assert memory.CUDA_CONTEXT_BYTES == 640 * MIB
    m = _card(16384, 15800)
    assert m.per_run_bytes == 1990 * MIB and m.available_bytes == 16384 * MIB
    assert memory.runs_that_fit(m, 0.9, 12) == 7
    assert memory.runs_that_fit(_card(24576, 24000), 0.9, 12) == 11
    assert memory.runs_that_fit(_card(81559, 80000), 0.9, 12) == 12
    assert memory.runs_that_fit(_card(8192, 8000, peak_mib=9000), 0.9, 12) == 1
    # another process holds 10 GiB of a 24 GiB card: its free memory, not its total, counts
    assert memory.runs_that_fit(_card(24576, 14336), 0.9, 12) == 6      # 0.9 x 14,976 / 1990 = 6.77


@pytest.fixture()
def on_stand_in_gpus(monkeypatch):
    """``train.device: cuda`` resolves to a CUDA device, ``gpus`` of them, on a 64-core machine."""
    def use(gpus: int):
        monkeypatch.setattr("compact_perception.core.determinism.resolve_device", lambda pref: torch.device("cuda"))
        monkeypatch.setattr("compact_perception.core.machine.usable_cores", lambda: 64)
        monkeypatch.setattr(parallel, "usable_cores", lambda: 64)
        monkeypatch.setattr(parallel, "gpu_count", lambda: gpus)
    return use


def _train(parallel_runs="auto"):
    from types import SimpleNamespace

    return SimpleNamespace(device="cuda", parallel_runs=parallel_runs, num_threads=1)


def test_auto_on_a_16_gb_card_takes_what_its_memory_holds_and_says_why(on_stand_in_gpus, caplog):
    """Two 16 GiB GPUs and the measured run above: 7 per GPU, 14 workers (before: 12 per GPU, 24),
    and one log line with the measured figures."""
    on_stand_in_gpus(2)
    with caplog.at_level(logging.INFO):
        assert parallel.stage_processes(_train(), lambda: _card(16384, 15800)) == (14, True)
    line, = [r.getMessage() for r in caplog.records if "parallel_runs" in r.getMessage()]
    assert line.startswith("train.parallel_runs auto: 14 side by side (7 per CUDA GPU by its memory (one run "
                           "measured at 1200 MiB allocator peak + 150 MiB outside it + 640 MiB context, 16384 of "
                           "16384 MiB free; at most 12")
    assert "x 2 GPUs" in line


def test_auto_on_a_large_card_keeps_the_speed_measured_count(on_stand_in_gpus):
    on_stand_in_gpus(1)
    assert parallel.stage_processes(_train(), lambda: _card(143771, 140000)) == (12, True)


def test_a_probe_that_runs_out_of_memory_leaves_one_run_per_gpu(on_stand_in_gpus, caplog):
    def probe():
        raise torch.OutOfMemoryError("CUDA out of memory. Tried to allocate 20.00 GiB")

    on_stand_in_gpus(2)
    with caplog.at_level(logging.INFO):
        assert parallel.stage_processes(_train(), probe) == (2, True)
    assert "one run alone ran out of the GPU's memory when measured" in caplog.text


def test_the_probe_is_measured_only_for_auto_on_cuda(on_stand_in_gpus, monkeypatch):
    on_stand_in_gpus(1)
    never = lambda: pytest.fail("measured a run for a count written out or on a CPU")  # noqa: E731
    assert parallel.stage_processes(_train(parallel_runs=3), never) == (3, True)
    monkeypatch.setattr("compact_perception.core.determinism.resolve_device", lambda pref: torch.device("cpu"))
    assert parallel.stage_processes(_train(), never) == (64, False)


def test_the_probe_measures_a_cuda_device_only():
    params = parse_params(repo_params_dict())
    with pytest.raises(RuntimeError, match="the memory probe measures a CUDA device"):
        memory_probe.measure_run_memory(params, None)


# ----------------------------------------------------------------------------- a run that runs out fails alone
def test_a_runs_out_of_memory_fails_it_alone_in_one_line(monkeypatch, tmp_path):
    """A worker's CUDA out-of-memory error: the run fails alone (a Failed value, not the stage's
    error), its line naming the run and what to set, and the device's cache is given back."""
    import pipeline.train as stage

    def oom(params, run, progress):
        raise torch.OutOfMemoryError("CUDA out of memory. Tried to allocate 2.00 GiB (GPU 0; 15.7 GiB total)\nmore")

    released = []
    params = parse_params(repo_params_dict())
    run = run_in(params, "compact_1l", tmp_path / "cache", tmp_path / "run")
    monkeypatch.setattr(stage, "train_run", oom)
    monkeypatch.setattr(stage, "release_device_memory", lambda: released.append(True))
    name, value, error = call(partial(stage.train_one, params, progress=False), Job(run.name, run))
    assert error is None and isinstance(value, Failed) and released == [True]
    assert value.line.startswith(f"{run.name}: out of memory (CUDA out of memory. Tried to allocate")
    assert "set train.parallel_runs to a lower count" in value.line and "\n" not in value.line


def _out_of_memory_on_first(out: Path, x: int) -> int:
    """A stand-in run: job 0 runs out of memory at once; the others take a while, then write a file."""
    import time

    if x == 0:
        raise RunAloneError(f"A/m/seed{x}: out of memory (CUDA out of memory); set train.parallel_runs lower")
    time.sleep(0.3)
    (out / f"run{x}").write_text("done")
    return x


@pytest.mark.parametrize("processes", [1, 2])
def test_the_other_runs_finish_before_the_stage_fails_with_the_one_that_ran_out(tmp_path, processes):
    """Job 0 (the costliest, so the first given out) runs out of memory; before: the pool stopped at
    it and the others never ran or were killed. Now every other run finishes, then the stage fails
    with that run's line."""
    jobs = [Job(f"A/m/seed{x}", x, cost=10.0 if x == 0 else 1.0) for x in range(4)]
    with pytest.raises(JobError) as err:
        run_jobs(partial(_out_of_memory_on_first, tmp_path), jobs, processes, desc="train A")
    assert str(err.value) == ("A/m/seed0: out of memory (CUDA out of memory); set train.parallel_runs lower "
                              "(1 of 4 runs failed this way; the other 3 finished)")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run1", "run2", "run3"]


def test_a_run_alone_that_runs_out_fails_with_its_line_only(tmp_path):
    with pytest.raises(JobError) as err:
        run_jobs(partial(_out_of_memory_on_first, tmp_path), [Job("A/m/seed0", 0)], 1, desc="train A")
    assert str(err.value) == "A/m/seed0: out of memory (CUDA out of memory); set train.parallel_runs lower"
