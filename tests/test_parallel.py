"""Runs side by side (execution/pool.py, training/parallel.py): the pool returns results in job order, starts the
longest jobs first, stops at the first failing job with its one-line error, hands the stage's
params and planned runs to its spawned workers whole, and a run trained in a worker process after
another run has the same bytes as the same run trained alone."""
from __future__ import annotations

import os
import pickle
from functools import partial
from pathlib import Path
from types import SimpleNamespace

import pytest
import yaml

from compact_perception.core.params import parse_params
from compact_perception.learning.plan import dataset_runs
from compact_perception.learning.training import parallel
from compact_perception.learning.training.parallel import Job, JobError, run_jobs

from repo_params import cap_epochs, repo_params_dict
from run_fixture import run_in
from synthetic import make_cache


def _square(x: int) -> int:
    return x * x


def _fail_on(x: int) -> int:
    if x == 3:
        raise ValueError("runs/A/m/seed3/last.pt: unreadable checkpoint")
    return x


def test_results_come_back_in_job_order_whatever_the_pool():
    jobs = [Job(f"j{i}", i, cost=c) for i, c in enumerate((1.0, 5.0, 2.0, 5.0))]
    assert run_jobs(_square, jobs, 1, desc="t") == [0, 1, 4, 9]
    assert run_jobs(_square, jobs, 2, desc="t") == [0, 1, 4, 9]


def test_the_first_failure_is_the_stage_error(caplog):
    jobs = [Job(f"A/m/seed{i}", i) for i in range(5)]
    with pytest.raises(JobError, match=r"^runs/A/m/seed3/last\.pt: unreadable checkpoint$"):
        run_jobs(_fail_on, jobs, 1, desc="t")
    assert "A/m/seed3 failed" in caplog.text


def test_longest_first_keeps_the_order_of_equal_costs(monkeypatch):
    seen: list[str] = []
    from compact_perception.execution import pool

    monkeypatch.setattr(pool, "_call", lambda fn, job: (seen.append(job.name) or (job.name, None, None)))
    run_jobs(_square, [Job("a", 1, 1.0), Job("b", 1, 3.0), Job("c", 1, 1.0), Job("d", 1, 3.0)], 1, "t")
    assert seen == ["b", "d", "a", "c"]


def test_a_stage_starts_its_costliest_runs_first(tmp_path, monkeypatch):
    """The train stage gives each run's job its cost: the epoch cap times its model's epoch cost
    (core.catalog), so at equal caps a GradNorm SegNet run (the slowest network per epoch) is the
    first job run_jobs starts, and no core waits alone for it at the end of the stage."""
    from compact_perception.core import catalog
    import pipeline.train as stage

    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump(cap_epochs(repo_params_dict(), 2), sort_keys=False))
    seen: list[Job] = []

    def capture(fn, jobs, processes, desc, gpu=False, executor=None):
        seen.extend(jobs)
        return [{"epochs_run": 2, "best_epoch": 1, "stop_reason": "max_epochs"}] * len(jobs)

    monkeypatch.setattr(stage, "run_jobs", capture)
    stage.main(["--dataset", "B", "--params", str(params)])
    cost = {j.name: j.cost for j in seen}
    assert cost["B/gradnorm_segnet/seed0"] == 2 * catalog.MODELS["gradnorm_segnet"].epoch_cost
    assert cost["B/compact_15l/seed0"] == 2 * catalog.MODELS["compact_15l"].epoch_cost == 2.0
    assert max(cost, key=cost.get) == "B/gradnorm_segnet/seed0"


def _what_a_worker_gets(params, run) -> tuple:
    """What a worker process reads of the stage's params and of its planned run."""
    return (os.getpid(), pickle.dumps(params), run, params.max_epochs_of(run.recipe, run.dataset),
            run.recipe.key_of("lr"), params.dataset(run.dataset).training.seeds.at(params.scale))


def test_the_stage_params_and_runs_reach_spawned_workers_whole():
    """A stage hands its validated params (``Scaled`` values included: a parametrised pydantic
    class pickles by its type argument) and each planned run to spawned worker processes; there
    they are what the stage has, down to where each recipe value is written (the params audit)."""
    d = repo_params_dict()
    d["study"]["datasets"]["default"] = ["A"]
    params = parse_params(d)
    runs = [r for r in dataset_runs(params, "A") if r.seed == 0 and r.model in ("compact_15l_mgn", "compact_15l")]
    assert {r.arm for r in runs} >= {None, "gradnorm"}
    here = [_what_a_worker_gets(params, r) for r in runs]
    pooled = run_jobs(partial(_what_a_worker_gets, params), [Job(r.name, r) for r in runs], 2, desc="spawn")
    assert os.getpid() not in {p[0] for p in pooled}                # computed in the spawned workers
    assert pickle.loads(pooled[0][1]) == params
    assert [p[2:] for p in pooled] == [h[2:] for h in here]
    assert pooled[0][2].recipe.key == "train.models.compact_15l" and pooled[0][2].paths == runs[0].paths


@pytest.mark.slow
def test_a_run_in_a_pool_has_the_bytes_of_the_run_alone(tmp_path):
    """compact_1l seed 0 trained alone in this process, and in a pool of two worker processes after
    chen_bev seed 0 (the same worker may run both): best.pt and last.pt's network byte for byte."""
    import torch

    from pipeline.train import train_one

    d = cap_epochs(repo_params_dict(), 2)
    d["train"].update(batch_size=2, num_workers=0, device="cpu")
    params = parse_params(d)
    cache = make_cache(tmp_path / "cache", size=16, counts=(4, 2, 2))
    alone = tmp_path / "alone"
    train_one(params, run_in(params, "compact_1l", cache, alone), progress=True)
    pooled = tmp_path / "pooled"
    jobs = [Job("chen", run_in(params, "chen_bev", cache, tmp_path / "chen"), cost=2.0),
            Job("1l", run_in(params, "compact_1l", cache, pooled), cost=1.0),
            Job("15l", run_in(params, "compact_15l", cache, tmp_path / "15l"), cost=1.0)]
    facts = run_jobs(partial(train_one, params, progress=False), jobs, 2, desc="pool")
    assert [f["stop_reason"] for f in facts] == ["max_epochs"] * 3
    assert (pooled / "best.pt").read_bytes() == (alone / "best.pt").read_bytes()
    last = [torch.load(Path(p) / "last.pt", weights_only=True)["model"] for p in (alone, pooled)]
    assert all(torch.equal(last[0][k], last[1][k]) for k in last[0])


# ----------------------------------------------------------------------------- how many side by side
def test_parallel_runs_as_written_is_bounded_by_the_cores(monkeypatch):
    monkeypatch.setattr(parallel, "usable_cores", lambda: 8)
    monkeypatch.setattr("compact_perception.core.machine.usable_cores", lambda: 8)
    assert parallel.runs_side_by_side(3, "cpu", 1) == 3
    assert parallel.runs_side_by_side(3, "cuda", 4) == 3          # a count is a count, on any device
    assert parallel.runs_side_by_side(64, "cuda", 1) == 8


def test_parallel_runs_auto_fills_the_cpu_or_takes_the_measured_gpu_share(monkeypatch):
    monkeypatch.setattr(parallel, "usable_cores", lambda: 16)
    monkeypatch.setattr("compact_perception.core.machine.usable_cores", lambda: 16)
    assert parallel.runs_side_by_side("auto", "cpu", 1) == 16
    assert parallel.runs_side_by_side("auto", "cpu", 3) == 5      # cores over threads
    assert parallel.runs_side_by_side("auto", "cpu", 32) == 1
    assert parallel.runs_side_by_side("auto", "cuda", 1) == parallel.CUDA_RUNS_PER_GPU == 12
    monkeypatch.setattr("compact_perception.core.machine.usable_cores", lambda: 4)
    assert parallel.runs_side_by_side("auto", "cuda", 1) == 4     # one process per core at most


def test_the_stage_resolves_auto_on_the_device_it_runs_on(monkeypatch):
    """On this CPU machine ``auto`` is the usable cores over the threads, and no GPU bound applies."""
    from compact_perception.core.machine import usable_cores

    train = SimpleNamespace(device="auto", parallel_runs="auto", num_threads=1)
    assert parallel.stage_processes(train) == (usable_cores(), False)
    assert parallel.stage_processes(SimpleNamespace(device="cpu", parallel_runs=1, num_threads=1)) == (1, False)


def test_each_gpu_worker_gets_its_share_of_the_memory(monkeypatch):
    import torch

    shares = []
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "set_per_process_memory_fraction", lambda f, device=None: shares.append(f))
    parallel.bound_gpu_memory(12)
    parallel.bound_gpu_memory(1)                                  # alone: the whole GPU
    assert shares == [pytest.approx(0.9 / 12)]
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    parallel.bound_gpu_memory(4)                                  # no GPU: nothing to bound
    assert shares == [pytest.approx(0.9 / 12)]


@pytest.mark.parametrize("value, ok", [("auto", True), (2, True), (0, False), ("many", False), (True, False)])
def test_parallel_runs_is_a_count_or_auto(value, ok):
    from compact_perception.core.params import ParamsError

    data = repo_params_dict()
    data["train"]["parallel_runs"] = value
    if ok:
        assert parse_params(data).train.parallel_runs == value
    else:
        with pytest.raises(ParamsError, match="train.parallel_runs"):
            parse_params(data)
