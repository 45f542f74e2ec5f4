"""The ``slurm`` executor on a real SLURM: two tiny training runs (the train stage's worker function)
as one ``sbatch --array`` of two jobs on the single-node test service (tests/slurm_service.py,
tests/services/slurm.sh), each run with the bytes of the pool's run of it. Skipped where the service
cannot run (not root, SLURM and munge not installed: CI installs neither by default)."""
from __future__ import annotations

import re
import subprocess
import time
from functools import partial

import pytest

from compact_perception.execution.executor import run_jobs
from compact_perception.execution.jobs import Job

from run_fixture import run_in
from slurm_service import slurm_service  # noqa: F401 (fixture)
from test_executor import _same_run, _submitit, _tiny, jobs_env  # noqa: F401 (fixture)

SEEDS = (0, 1)


def _array_tasks(array_id: str, wait_s: float = 60.0) -> dict[str, tuple[str, str]]:
    """The controller's state and node of each task of array ``array_id``, once none is running
    (a job's result file is written just before its process ends)."""
    deadline = time.monotonic() + wait_s
    while True:
        lines = subprocess.run(["scontrol", "-o", "show", "job", array_id], capture_output=True, text=True,
                               check=True).stdout.splitlines()
        tasks = {re.search(r"\bArrayTaskId=(\d+)", ln).group(1):
                 (re.search(r"\bJobState=(\S+)", ln).group(1), re.search(r"\bNodeList=(\S+)", ln).group(1))
                 for ln in lines}
        if time.monotonic() > deadline or not any(s in ("PENDING", "RUNNING", "COMPLETING") for s, _ in tasks.values()):
            return tasks
        time.sleep(0.5)


@pytest.mark.slow
def test_a_slurm_job_arrays_runs_have_the_pools_bytes(jobs_env, slurm_service, monkeypatch):  # noqa: F811
    """compact_1l seeds 0 and 1 trained by the pool and as the two jobs of one SLURM array: each
    run's best.pt byte for byte, last.pt's network and history, the summary but its wall time; the
    controller ran both array tasks to COMPLETED on its node, so the runs did not come from the pool."""
    from pipeline.train import train_one

    monkeypatch.setenv("SLURM_CONF", slurm_service.conf)
    params, cache = _tiny(jobs_env)
    fn = partial(train_one, params, progress=False)
    pooled = [run_in(params, "compact_1l", cache, jobs_env / "pooled" / f"seed{s}", seed=s) for s in SEEDS]
    queued = [run_in(params, "compact_1l", cache, jobs_env / "slurm" / f"seed{s}", seed=s) for s in SEEDS]
    run_jobs(fn, [Job(f"seed{s}", r) for s, r in zip(SEEDS, pooled)], 1, desc="pool")
    executor = _submitit("slurm", jobs_env, cpus_per_task=1)   # time_min 10, poll_s 0.1
    facts = run_jobs(fn, [Job(f"seed{s}", r) for s, r in zip(SEEDS, queued)], 2, desc="slurm", executor=executor)
    assert [f["stop_reason"] for f in facts] == ["max_epochs"] * 2

    folder = jobs_env / "jobs" / "slurm"
    submissions = list(folder.glob("*_submission.sh"))
    assert len(submissions) == 1 and "#SBATCH --array=0-1" in submissions[0].read_text()
    array_id = submissions[0].name.split("_")[0]
    shown = _array_tasks(array_id)
    assert {task: state for task, (state, _) in shown.items()} == {"0": "COMPLETED", "1": "COMPLETED"}
    assert {node for _, node in shown.values()} == {"localnode"}
    assert sorted(p.name for p in folder.glob("*_log.out")) == [f"{array_id}_{i}_0_log.out" for i in (0, 1)]
    for a, b in zip(pooled, queued):
        _same_run(a.paths.run_dir, b.paths.run_dir)


def _dies(_: object) -> None:
    """A job's process that ends without a result (as one killed for the node's memory does)."""
    import os

    os._exit(3)


@pytest.mark.slow
def test_a_job_that_dies_without_a_result_fails_the_stage_with_its_log(jobs_env, slurm_service, monkeypatch):  # noqa: F811
    """No accounting storage, so no sacct: submitit alone would wait for ever; the controller's
    word (squeue) ends the wait with the job's state and log."""
    from compact_perception.execution import submitit_backend
    from compact_perception.execution.jobs import JobError

    monkeypatch.setenv("SLURM_CONF", slurm_service.conf)
    monkeypatch.setattr(submitit_backend, "DEAD_AFTER_S", 2.0)
    started = time.monotonic()
    with pytest.raises(JobError, match=r"^dies: the job ended without a result \(SLURM state FAILED; log: .*\.err\)$"):
        run_jobs(_dies, [Job("dies", 0)], 1, desc="slurm dies", executor=_submitit("slurm", jobs_env))
    assert time.monotonic() - started < 60
