"""`python -m pipeline.train_all` (issue 54 item 5): every dataset's unfinished runs handed to the
executor in one submission, between DVC's data stages and a `dvc repro` that then trains nothing.
At a tiny scale in a temporary copy (test_remote.py's: sets A and B, one seed, one epoch; here one
compact model), through submitit's ``local`` executor (subprocess jobs, as SLURM's would be)."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from test_pipeline_e2e import copy_project, dvc_env, ran_stages, retrained, run
from test_remote import DATASETS, snapshot, tiny as two_sets

MODELS = ("compact_1l",)

ROOT = Path(__file__).resolve().parents[1]


def test_the_train_stages_upstream_stages_are_the_data_stages():
    """Read from dvc.yaml's graph, not named by hand: each train stage's deps' producers."""
    from dvc.repo import Repo

    from pipeline.train_all import upstream_stages

    with Repo(str(ROOT)) as repo:
        assert upstream_stages(repo, ["A", "nuscenes"]) == ["preprocess@A", "ingest_nuscenes"]
        assert upstream_stages(repo, ["B", "C"]) == ["preprocess@B", "preprocess@C"]


@pytest.mark.slow
def test_every_datasets_runs_go_in_one_submission_and_dvc_repro_then_trains_nothing(tmp_path):
    repo = copy_project(ROOT, tmp_path / "repo", lambda p: {**two_sets(p), "model_ids": list(MODELS)})
    env = dvc_env(tmp_path)
    env.pop("COMPACT_PERCEPTION_PARAMS_AUDIT")
    (repo / "cluster.yaml").write_text(yaml.safe_dump({"executor": "local", "folder": str(tmp_path / "jobs"),
                                                       "poll_s": 0.2, "time_min": 20}))
    for cmd in (["git", "init", "-q"], ["git", "add", "-A"], ["git", "commit", "-qm", "tiny"]):
        run(cmd, repo, env)

    out = run([sys.executable, "-m", "pipeline.train_all", "--no-repro"], repo, env)
    assert ran_stages(out) == {f"{s}@{d}" for s in ("generate", "preprocess") for d in DATASETS}
    assert not (repo / "dvc.lock").exists() or "train@" not in (repo / "dvc.lock").read_text()
    names = {f"{d}/{m}/seed0" for d in DATASETS for m in MODELS}
    assert f"{len(names)} runs of 2 datasets: 0 complete, {len(names)} to train" in out
    submissions = list((tmp_path / "jobs" / "train_all").glob("*_submitted.pkl"))
    assert len(submissions) == len(names)                        # one submission: every dataset's runs
    assert re.search(rf"train all: {len(names)} jobs submitted to submitit's local executor", out)
    before = snapshot(repo, "runs")
    assert all((repo / "runs" / n / "summary.json").exists() for n in names)

    trains = [f"train@{d}" for d in DATASETS]                    # the stages that would train (evaluation: as usual)
    out = run([sys.executable, "-m", "dvc", "repro", *trains], repo, env)
    assert set(trains) <= ran_stages(out)                         # the train stages ran, and trained nothing
    assert retrained(out) == set() and "jobs submitted" not in out and "val score" not in out
    assert snapshot(repo, "runs") == before                      # not a byte, inode or mtime changed
    status = subprocess.run([sys.executable, "-m", "dvc", "status", "-q", *trains], cwd=repo, env=env)
    assert status.returncode == 0                                 # DVC records them up to date


def test_outside_a_dvc_repository_it_is_one_line_and_runs_nothing(tmp_path):
    (tmp_path / "params.yaml").write_bytes((ROOT / "params.yaml").read_bytes())
    env = {"PYTHONPATH": f"{ROOT / 'src'}:{ROOT}", "PATH": "/usr/bin:/bin", "DVC_NO_ANALYTICS": "1",
           "HOME": str(tmp_path)}
    proc = subprocess.run([sys.executable, "-m", "pipeline.train_all"], cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    assert f"error: {tmp_path}: not a DVC repository; run this from the project's root\n" in proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["params.yaml"]
