"""The executor seam (src/compact_perception/execution): a stage hands its planned runs and worker
function to the local pool (the default) or to submitit (``slurm``; its ``local`` and ``debug``
executors here) and gets their results in order, the first failure as one line; the choice is a
setting no result depends on; a finished run costs no job; a run trained as a submitit job has the
pool's bytes, computed under the same numeric pins; a requeued job resumes its run to the
uninterrupted bytes; on a multi-GPU workstation the pool gives each worker one GPU."""
from __future__ import annotations

import json
import os
import signal
import time
from functools import partial
from pathlib import Path

import pytest
import yaml

from compact_perception.core.params import parse_params
from compact_perception.core.determinism import NUMPY_AVX512, PINNED_ENV
from compact_perception.execution import pool
from compact_perception.execution.executor import PoolExecutor, chosen_executor, executor_for, run_jobs
from compact_perception.execution.jobs import Job, JobError, call
from compact_perception.execution.settings import (CLUSTER_FILE_ENV, EXECUTOR_ENV, ClusterSettings, SettingsError,
                                                   read_settings)

from repo_params import cap_epochs, repo_params_dict
from run_fixture import run_in
from synthetic import make_cache

ROOT = Path(__file__).resolve().parents[1]
TESTS = Path(__file__).resolve().parent


def _square(x: int) -> int:
    return x * x


def _fail_on(x: int) -> int:
    if x == 3:
        raise ValueError("runs/A/m/seed3/last.pt: unreadable checkpoint")
    if x == 4:
        raise KeyError("a bug")
    return x


def _pins(_: object) -> dict:
    """Inside a job: the pins in its environment, and what numpy (imported before this function
    was unpickled) took of them."""
    import sys

    import numpy

    features = numpy.core._multiarray_umath.__cpu_features__
    return {"env": {k: os.environ.get(k) for k in PINNED_ENV}, "numpy_first": "numpy" in sys.modules,
            "avx512": [f for f in NUMPY_AVX512 if features.get(f)], "pid": os.getpid()}


@pytest.fixture()
def jobs_env(tmp_path, monkeypatch):
    """A submitit job started from here imports this test module (PYTHONPATH) and the stage
    package (the repository root as its working directory); no cluster file is read."""
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(TESTS), str(ROOT)]))
    monkeypatch.chdir(ROOT)
    monkeypatch.delenv(EXECUTOR_ENV, raising=False)
    monkeypatch.setenv(CLUSTER_FILE_ENV, str(_cluster_file(tmp_path, {})))
    return tmp_path


def _cluster_file(tmp_path: Path, values: dict) -> Path:
    path = tmp_path / "cluster.yaml"
    path.write_text(yaml.safe_dump(values))
    return path


def _submitit(kind: str, tmp_path: Path, **kw) -> object:
    return executor_for(ClusterSettings(executor=kind, folder=str(tmp_path / "jobs"), poll_s=0.1, time_min=10, **kw))


# ----------------------------------------------------------------------------- the setting
def test_the_default_is_the_pool_and_the_environment_chooses(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)                                          # no cluster.yaml here
    monkeypatch.delenv(EXECUTOR_ENV, raising=False)
    monkeypatch.delenv(CLUSTER_FILE_ENV, raising=False)
    assert read_settings() == ClusterSettings() and isinstance(chosen_executor(), PoolExecutor)
    assert chosen_executor({EXECUTOR_ENV: "debug"}).name == "debug"
    (tmp_path / "cluster.yaml").write_text("executor: local\npartition: gpu\ntime_min: 60\nsetup: [module load cuda]\n")
    s = read_settings({})
    assert (s.executor, s.partition, s.time_min, s.setup) == ("local", "gpu", 60, ("module load cuda",))
    assert read_settings({EXECUTOR_ENV: "pool"}).executor == "pool"     # the environment over the file


@pytest.mark.parametrize("text, message", [
    ("executor: cloud\n", "cluster.yaml: executor: expected one of pool, slurm, local, debug, got 'cloud'"),
    ("partion: gpu\n", "cluster.yaml: partion: not a cluster setting (expected one of executor, folder, "),
    ("time_min: 0\n", "cluster.yaml: time_min: expected an integer >= 1, got '0'"),
    ("mem_gb: lots\n", "cluster.yaml: mem_gb: expected a number > 0, got 'lots'"),
    ("setup: module load cuda\n", "cluster.yaml: setup: expected a list of shell lines (strings)"),
    ("time_min: 1\ntime_min: 2\n", "cluster.yaml: duplicate key 'time_min' at line 2"),
    ("- slurm\n", "cluster.yaml: expected a mapping of cluster settings, got a list"),
    ("executor: [\n", "cluster.yaml: not valid YAML: "),
])
def test_a_bad_cluster_file_is_one_line(tmp_path, monkeypatch, text, message):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "cluster.yaml").write_text(text)
    with pytest.raises(SettingsError) as err:
        read_settings({})
    assert str(err.value).startswith(message) and "\n" not in str(err.value)


def test_a_bad_executor_stops_the_stage_in_one_line_before_anything_is_written(tmp_path, monkeypatch):
    import pipeline.train as stage

    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump(cap_epochs(repo_params_dict(), 1), sort_keys=False))
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv(EXECUTOR_ENV, "kubernetes")
    monkeypatch.setattr(stage, "run_jobs", lambda *a, **k: pytest.fail("jobs were handed out"))
    with pytest.raises(SystemExit) as exc:
        stage.main(["--dataset", "A", "--params", str(params)])
    assert exc.value.code == f"error: {EXECUTOR_ENV}: expected one of pool, slurm, local, debug, got 'kubernetes'"
    assert not (tmp_path / "runs").exists()


def test_slurm_without_sbatch_is_one_line(monkeypatch):
    monkeypatch.setenv("PATH", "/nonexistent")
    with pytest.raises(SettingsError, match=r"^executor: slurm needs SLURM's sbatch and srun on PATH"):
        executor_for(ClusterSettings(executor="slurm"))


def test_the_executor_is_no_param_and_no_dvc_param():
    """Switching the executor reruns no stage: no stage of dvc.yaml lists it among its params, and
    params.yaml has no such key."""
    stages = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]
    listed = [p for s in stages.values() for p in s.get("do", s).get("params", []) if isinstance(p, str)]
    assert not [p for p in listed if "executor" in p or "cluster" in p]
    assert "executor" not in yaml.safe_load((ROOT / "params.yaml").read_text())
    assert not [d for s in stages.values() for d in s.get("do", s).get("deps", []) if "cluster" in str(d)]


# ----------------------------------------------------------------------------- the seam
@pytest.mark.parametrize("kind", ["pool", "debug"])
def test_every_executor_returns_results_in_job_order(kind, tmp_path):
    jobs = [Job(f"j{i}", i, cost=c) for i, c in enumerate((1.0, 5.0, 2.0, 5.0))]
    executor = PoolExecutor() if kind == "pool" else _submitit(kind, tmp_path)
    assert run_jobs(_square, jobs, 2, desc="t", executor=executor) == [0, 1, 4, 9]


def test_a_submitit_jobs_failure_is_one_line(tmp_path):
    """An expected error is the job's own line; an unexpected one names the job, the error and
    the job's log, never a traceback."""
    debug = _submitit("debug", tmp_path)
    with pytest.raises(JobError, match=r"^runs/A/m/seed3/last\.pt: unreadable checkpoint$"):
        run_jobs(_fail_on, [Job(f"A/m/seed{i}", i) for i in (0, 3)], 1, desc="t", executor=debug)
    with pytest.raises(JobError) as err:
        run_jobs(_fail_on, [Job("A/m/seed4", 4)], 1, desc="t", executor=debug)
    assert str(err.value).startswith("A/m/seed4: KeyError: 'a bug'") and "\n" not in str(err.value)


def test_a_local_job_computes_under_the_pins_already_in_its_environment(jobs_env, monkeypatch):
    """submitit's job imports numpy before it unpickles the stage's function, so the pins must be
    in the job's environment when its Python starts: with none in this process's environment, a
    job still has every pin, and numpy took them (no AVX-512 loop)."""
    for key in PINNED_ENV:
        monkeypatch.delenv(key, raising=False)
    out = run_jobs(_pins, [Job("pins", None)], 1, desc="pins", executor=_submitit("local", jobs_env))[0]
    assert out["pid"] != os.getpid() and out["numpy_first"]
    assert out["env"] == PINNED_ENV
    assert out["avx512"] == []


# ----------------------------------------------------------------------------- a finished run costs no job
def _finished(params, run, data: str | None = None) -> None:
    """``run`` as a finished run of this code, params and data (its summary's digest, a last.pt);
    ``data``: of other data instead."""
    import torch

    from compact_perception.learning.training.train import cache_fingerprint, run_digest, run_seed

    data = data or cache_fingerprint(run.paths.cache_dir)
    digest = run_digest(params, run, run_seed(params, run.dataset, run.seed), data, 1)
    run.paths.run_dir.mkdir(parents=True, exist_ok=True)
    torch.save({"digest": digest, "finished": True}, run.paths.last)
    run.paths.summary.write_text(json.dumps({"digest": digest, "epochs_run": 2, "best_epoch": 1,
                                             "stop_reason": "max_epochs"}))


def test_a_finished_run_is_found_where_the_plan_is_made_and_costs_no_job(tmp_path, monkeypatch):
    """The train stage decides which runs are complete (their digest) before it hands any job to
    the executor: only the others are submitted; a run finished on other data, or whose last.pt is
    truncated, is not complete."""
    import pipeline.train as stage
    from compact_perception.learning.plan import dataset_runs

    d = cap_epochs(repo_params_dict(), 2)
    params_path = tmp_path / "params.yaml"
    params_path.write_text(yaml.safe_dump(d, sort_keys=False))
    params = parse_params(d)
    monkeypatch.chdir(tmp_path)
    make_cache(tmp_path / "data" / "cache" / "A", size=16, counts=(2, 1, 1))
    runs = dataset_runs(params, "A")
    _finished(params, runs[0])
    _finished(params, runs[1], data="other data")                         # finished on other data
    _finished(params, runs[2])
    runs[2].paths.last.write_bytes(runs[2].paths.last.read_bytes()[:40])   # truncated: its job names it
    handed: list[str] = []

    def capture(fn, jobs, processes, desc, gpu=False, executor=None):
        handed.extend(j.name for j in jobs)
        return [{"epochs_run": 2, "best_epoch": 1, "stop_reason": "max_epochs"}] * len(jobs)

    monkeypatch.setattr(stage, "run_jobs", capture)
    stage.main(["--dataset", "A", "--params", str(params_path)])
    assert handed == [r.name for r in runs[1:]]


def test_finished_runs_hashes_no_cache_when_no_run_has_a_summary(tmp_path, monkeypatch):
    from compact_perception.learning.training import train

    params = parse_params(repo_params_dict())
    runs = [run_in(params, "compact_1l", tmp_path / "no-cache", tmp_path / "run")]
    monkeypatch.setattr(train, "cache_fingerprint", lambda _: pytest.fail("hashed a cache"))
    assert train.finished_runs(params, runs) == {}


# ----------------------------------------------------------------------------- the same bytes
def _tiny(tmp_path: Path):
    d = cap_epochs(repo_params_dict(), 2)
    d["train"].update(batch_size=2, num_workers=0, device="cpu")
    return parse_params(d), make_cache(tmp_path / "cache", size=16, counts=(4, 2, 2))


def _same_run(a: Path, b: Path) -> None:
    import torch

    assert (a / "best.pt").read_bytes() == (b / "best.pt").read_bytes()
    last = [torch.load(p / "last.pt", weights_only=True) for p in (a, b)]
    assert all(torch.equal(last[0]["model"][k], last[1]["model"][k]) for k in last[0]["model"])
    assert last[0]["history"] == last[1]["history"]
    keep = lambda s: {k: v for k, v in s.items() if k not in ("train_seconds",)}  # noqa: E731
    assert keep(json.loads((a / "summary.json").read_text())) == keep(json.loads((b / "summary.json").read_text()))


@pytest.mark.slow
def test_a_run_trained_as_a_local_submitit_job_has_the_pools_bytes(jobs_env):
    """compact_1l seed 0 trained by the pool (in this process) and as a job of submitit's local
    executor (another process, started by submitit): best.pt byte for byte, last.pt's network and
    history, the summary but its wall time."""
    from pipeline.train import train_one

    params, cache = _tiny(jobs_env)
    pooled, job = jobs_env / "pooled", jobs_env / "job"
    fn = partial(train_one, params, progress=False)
    run_jobs(fn, [Job("pool", run_in(params, "compact_1l", cache, pooled))], 1, desc="pool")
    facts = run_jobs(fn, [Job("job", run_in(params, "compact_1l", cache, job))], 1, desc="local",
                     executor=_submitit("local", jobs_env))
    assert facts[0]["stop_reason"] == "max_epochs"
    _same_run(pooled, job)


def _preempted_once(params, run) -> dict:
    """A job preempted after its run's first epoch: SLURM's signal (USR2) reaches the job, submitit
    checkpoints and requeues it; the requeued job resumes the run from its last.pt."""
    from compact_perception.learning.training.train import train_run
    from pipeline.train import train_one

    marker = run.paths.run_dir.parent / f"{run.paths.run_dir.name}.preempted"
    if not marker.exists():
        marker.write_text("")
        try:
            train_run(params, run, stop_after_epochs=1, progress=False)
        except InterruptedError:
            pass
        os.kill(os.getpid(), signal.SIGUSR2)
        time.sleep(120)  # the signal handler requeues and exits first
        raise AssertionError("not requeued")
    return train_one(params, run, progress=False)


@pytest.mark.slow
def test_a_requeued_job_resumes_its_run_to_the_uninterrupted_bytes(jobs_env):
    from pipeline.train import train_one

    params, cache = _tiny(jobs_env)
    alone, requeued = jobs_env / "alone", jobs_env / "requeued"
    train_one(params, run_in(params, "compact_1l", cache, alone), progress=False)
    facts = run_jobs(partial(_preempted_once, params), [Job("requeued", run_in(params, "compact_1l", cache, requeued))],
                     1, desc="requeue", executor=_submitit("local", jobs_env))
    assert facts[0]["epochs_run"] == 2
    logs = "".join(p.read_text() for p in (jobs_env / "jobs").rglob("*.err"))
    assert "requeued, it resumes from its last finished epoch" in logs and "resuming after epoch 1" in logs
    _same_run(alone, requeued)


# ----------------------------------------------------------------------------- a multi-GPU workstation
def test_the_workers_are_spread_over_the_gpus_round_robin():
    assert pool.device_plan(5, ["0", "1"]) == ["0", "1", "0", "1", "0"]
    assert pool.device_plan(3, ["2", "3", "5"]) == ["2", "3", "5"]
    assert pool.device_plan(3, []) == []


def test_visible_gpus_keep_this_processs_own_list(monkeypatch):
    monkeypatch.setattr(pool, "gpu_count", lambda: 2)
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "3,5")
    assert pool.visible_gpus() == ["3", "5"]
    monkeypatch.delenv("CUDA_VISIBLE_DEVICES")
    assert pool.visible_gpus() == ["0", "1"]


def _my_gpu(x: int) -> tuple:
    time.sleep(0.5)  # every worker takes a job
    return os.getpid(), os.environ.get("CUDA_VISIBLE_DEVICES")


def test_a_pool_on_two_stand_in_gpus_gives_each_worker_one(monkeypatch):
    """With two visible GPUs (a stand-in count on this CPU machine) the pool's two workers each see
    one GPU, a different one; every job of a worker runs on its GPU."""
    monkeypatch.setattr(pool, "gpu_count", lambda: 2)
    monkeypatch.delenv("CUDA_VISIBLE_DEVICES", raising=False)
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1})
    out = run_jobs(_my_gpu, [Job(str(i), i) for i in range(4)], 2, desc="gpus", gpu=True)
    by_worker = {}
    for pid, device in out:
        by_worker.setdefault(pid, set()).add(device)
    assert all(len(devices) == 1 for devices in by_worker.values())
    assert set().union(*by_worker.values()) == {"0", "1"} and len(by_worker) == 2


def test_auto_takes_the_measured_share_of_every_gpu(monkeypatch):
    from compact_perception.learning.training import parallel

    monkeypatch.setattr("compact_perception.core.machine.usable_cores", lambda: 64)
    monkeypatch.setattr(parallel, "gpu_count", lambda: 4)
    assert parallel.runs_side_by_side("auto", "cuda", 1) == 4 * parallel.CUDA_RUNS_PER_GPU


def test_auto_on_a_cpu_says_the_count_it_chose_and_why(monkeypatch, caplog):
    from types import SimpleNamespace

    from compact_perception.learning.training import parallel

    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(6)))
    with caplog.at_level("INFO"):
        assert parallel.stage_processes(SimpleNamespace(device="cpu", parallel_runs="auto", num_threads=2)) == (3, False)
    lines = [r.getMessage() for r in caplog.records if "parallel_runs" in r.getMessage()]
    assert lines == ["train.parallel_runs auto: 3 side by side (6 usable CPU cores over train.num_threads 2)"]
    caplog.clear()
    parallel.stage_processes(SimpleNamespace(device="cpu", parallel_runs=2, num_threads=1))
    assert not [r for r in caplog.records if "parallel_runs" in r.getMessage()]   # a count as written: no line


# ----------------------------------------------------------------------------- a job that dies without a result
class _StandInJob:
    def __init__(self, job_id: str, folder: Path) -> None:
        from types import SimpleNamespace

        self.job_id = job_id
        self.paths = SimpleNamespace(result_pickle=folder / f"{job_id}_result.pkl")


def test_the_controller_s_word_ends_the_wait_for_a_job_that_left_no_result(monkeypatch, tmp_path):
    """squeue (a stand-in here; the real one in test_slurm_service.py) says 7_0 FAILED and lists
    no 7_2 any more: each counts as dead once it has been so for DEAD_AFTER_S with no result file;
    7_1 running, and 7_3 COMPLETED with its result file, are not."""
    from subprocess import CompletedProcess

    from compact_perception.execution import submitit_backend as sb

    said = "7_0|FAILED\n7_1|RUNNING\n7_3|COMPLETED\n"
    asked = []

    def squeue(cmd, **kw):
        asked.append(cmd)
        return CompletedProcess(cmd, 0, said, "")

    monkeypatch.setattr(sb.subprocess, "run", squeue)
    now = [100.0]
    watch = sb.QueueWatch(dead_after_s=30, clock=lambda: now[0])
    subs = [_StandInJob(f"7_{i}", tmp_path) for i in range(4)]
    (tmp_path / "7_3_result.pkl").write_bytes(b"")
    assert watch.dead(subs) == {}                               # just seen ended: the result may follow
    now[0] = 131.0
    assert {s.job_id: state for s, state in watch.dead(subs).items()} == {"7_0": "FAILED", "7_2": "gone"}
    assert asked[0][:5] == ["squeue", "--noheader", "--array", "--states=all", "--format=%i|%T"]
    assert asked[0][-1] == "7_0,7_1,7_2,7_3"


def test_a_requeued_job_is_not_dead_and_no_answer_judges_nothing(monkeypatch, tmp_path):
    from subprocess import CompletedProcess

    from compact_perception.execution import submitit_backend as sb

    answers = iter(["7_0|TIMEOUT\n", "7_0|PENDING\n", "7_0|TIMEOUT\n"])
    monkeypatch.setattr(sb.subprocess, "run", lambda cmd, **kw: CompletedProcess(cmd, 0, next(answers), ""))
    now = [0.0]
    watch = sb.QueueWatch(dead_after_s=30, clock=lambda: now[0])
    job = _StandInJob("7_0", tmp_path)
    watch.dead([job])
    now[0] = 20.0
    watch.dead([job])                    # requeued: pending again, its clock restarts
    now[0] = 40.0
    assert watch.dead([job]) == {}       # ended 0 s ago, not 40
    monkeypatch.setattr(sb.subprocess, "run", lambda cmd, **kw: CompletedProcess(cmd, 1, "", "slurm_load_jobs error: "
                                                                                             "Unable to contact slurm controller"))
    now[0] = 100.0
    assert watch.dead([job]) == {}       # the controller did not answer: nothing is judged
