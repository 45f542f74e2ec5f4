"""Sharing runs through a DVC remote (docs/sharing.md), end to end at a tiny scale.

A local folder is the DVC remote and a bare git repository the colleagues' git server. One
module-scoped set-up, as docs/sharing.md tells a team to do it: clone 1 adds the remote,
reproduces the pipeline, commits and pushes (git and DVC). Then:

- a fresh clone pulls every output and finds nothing to rerun; the run cache it pushed holds
  exactly the stages whose outputs are all in DVC's cache;
- in that clone, `dvc exp run -S` of one model's learning rate retrains only that model's runs
  (the other model's run files keep their bytes, inode and mtime) and reruns only the stages
  downstream of them;
- one pipeline spread over two machines: after a change that touches both datasets, one clone
  runs set A's stages and another set B's, each on its own branch, each pushing; a third merges
  both, pulls, and only the report runs.

The copy is as small as shows the point: sets A and B, two compact models, one seed, one epoch.
"""
from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
from pathlib import Path

import pytest
import yaml

from test_pipeline_e2e import copy_project, dvc_env, every, ran_stages, retrained, run, set_param

pytestmark = pytest.mark.slow

DATASETS = ("A", "B")
MODELS = ("compact_1l", "compact_15l")


def tiny(params: dict) -> dict:
    """Sets A and B, two compact models, one seed, one epoch, a handful of 32 px frames."""
    params["world"]["resolution"] = every(32)
    params["world"]["lidar"]["horizontal_samples"] = 256
    params["world"]["frames_per_episode"] = 2
    params["world"]["workers"] = 1
    params["sim_ids"] = list(DATASETS)
    params["dataset_ids"] = list(DATASETS)
    params["model_ids"] = list(MODELS)
    for ds in DATASETS:
        params["datasets"][ds]["frames"]["default"] = 10
        params["datasets"][ds]["split_ratio"]["default"] = {"train": 3, "val": 2, "test": 5}
        params["datasets"][ds]["training"] = {"seeds": every([0]), "max_epochs": every(1)}
    params["preprocess"]["workers"] = 1
    params["train"]["batch_size"] = 2
    params["train"]["num_workers"] = 0
    params["benchmark"] = {"warmup": 1, "runs": 3}
    return params


class Team:
    """The temporary folder: a bare git repository, a DVC remote, and the clones made from them."""

    def __init__(self, tmp: Path) -> None:
        self.tmp, self.git, self.remote = tmp, tmp / "git.git", tmp / "dvc-remote"

    def env(self, clone: Path) -> dict:
        env = dvc_env(self.tmp)
        env.pop("COMPACT_PERCEPTION_PARAMS_AUDIT")
        env["PYTHONPATH"] = os.pathsep.join([str(clone / "src"), str(clone)])  # each clone runs its own code
        return env

    def clone(self, name: str) -> tuple[Path, dict]:
        clone = self.tmp / name
        env = self.env(clone)
        run(["git", "clone", "-q", str(self.git), str(clone)], self.tmp, env)
        return clone, env


def snapshot(clone: Path, folder: str) -> dict[str, tuple[int, int, str]]:
    """Each file under ``folder``: (mtime, inode, md5)."""
    return {str(p.relative_to(clone)): (p.stat().st_mtime_ns, p.stat().st_ino, hashlib.md5(p.read_bytes()).hexdigest())
            for p in sorted((clone / folder).rglob("*")) if p.is_file()}


def run_cache_commands(remote: Path) -> set[str]:
    """The stage commands of the run-cache entries in a DVC remote (``runs/<xx>/<key>/<value>``)."""
    return {yaml.safe_load(p.read_text())["cmd"] for p in (remote / "runs").rglob("*") if p.is_file()}


@pytest.fixture(scope="module")
def team(tmp_path_factory, root: Path):
    """Clone 1 adds the remote, reproduces everything, and pushes to git and to the DVC remote."""
    team = Team(tmp_path_factory.mktemp("remote"))
    origin = copy_project(root, team.tmp / "origin", tiny)
    env = team.env(origin)
    for cmd in (["git", "init", "-q", "-b", "main"], ["git", "add", "-A"], ["git", "commit", "-qm", "tiny"],
                ["git", "init", "-q", "--bare", "-b", "main", str(team.git)],
                ["git", "remote", "add", "origin", str(team.git)], ["git", "push", "-q", "origin", "main"]):
        run(cmd, origin, env)
    shutil.rmtree(origin)

    c1, env = team.clone("clone1")
    # docs/sharing.md, "Set up the remote once", then "Share what you ran"
    team.remote.mkdir()
    run(["dvc", "remote", "add", "-d", "shared", str(team.remote)], c1, env)
    log = run(["dvc", "repro"], c1, env)
    run(["dvc", "push", "--run-cache"], c1, env)
    for cmd in (["git", "add", "-A"], ["git", "commit", "-qm", "results and the remote"],
                ["git", "push", "-q", "origin", "main"]):
        run(cmd, c1, env)
    yield team, c1, log
    # free the checkpoints and caches (a few hundred MB a clone), so that test runs do not fill a disk
    for heavy in (*team.tmp.glob("*/runs"), *team.tmp.glob("*/.dvc/cache"), team.remote):
        shutil.rmtree(heavy, ignore_errors=True)


def test_a_fresh_clone_pulls_every_output_and_has_nothing_to_rerun(team):
    team, c1, log = team
    assert {f"train@{ds}" for ds in DATASETS} | {"report"} <= ran_stages(log)
    c2, env = team.clone("clone2")
    assert not (c2 / "runs").exists()
    # before the pull the outputs are missing: every stage that has DVC-cached outputs would run
    assert {f"train@{ds}" for ds in DATASETS} <= set(yaml.safe_load(run(["dvc", "status", "--json"], c2, env)))
    run(["dvc", "pull"], c2, env)
    assert "Data and pipelines are up to date" in run(["dvc", "status"], c2, env)
    assert snapshot(c2, "runs").keys() == snapshot(c1, "runs").keys()
    assert all(a[2] == b[2] for a, b in zip(snapshot(c2, "runs").values(), snapshot(c1, "runs").values()))
    # `dvc repro` agrees: nothing runs, nothing is restored from elsewhere
    assert ran_stages(run(["dvc", "repro"], c2, env)) == set()


def test_the_run_cache_holds_only_the_stages_whose_outputs_are_all_cached(team):
    """docs/sharing.md: a stage with a git-committed (cache: false) output or a persistent one
    (train's runs/) is never in the run cache; here that leaves the nuScenes-format set's two."""
    team, _, _ = team
    assert run_cache_commands(team.remote) == {"python -m pipeline.nuscenes_sim", "python -m pipeline.ingest_nuscenes"}
    c2 = team.tmp / "clone2"
    assert not (c2 / ".dvc/cache/runs").exists()
    run(["dvc", "pull", "--run-cache"], c2, team.env(c2))
    entries = {p.relative_to(team.remote / "runs") for p in (team.remote / "runs").rglob("*") if p.is_file()}
    assert {p.relative_to(c2 / ".dvc/cache/runs") for p in (c2 / ".dvc/cache/runs").rglob("*") if p.is_file()} == entries


def test_an_experiment_on_one_models_lr_retrains_only_that_models_runs(team):
    team, _, _ = team
    c2 = team.tmp / "clone2"
    env = team.env(c2)
    before = snapshot(c2, "runs")
    results_before = snapshot(c2, "results")
    log = run(["dvc", "exp", "run", "-S", "+train.models.compact_1l.lr=0.05"], c2, env)
    assert ran_stages(log) == ({f"{stage}@{ds}" for stage in ("train", "evaluate") for ds in DATASETS}
                               | {"report", "report_full"})  # report_full: what today's params change of a record
    assert retrained(log) == {f"{ds}/compact_1l/seed0" for ds in DATASETS}
    after = snapshot(c2, "runs")
    assert after.keys() == before.keys()
    untouched = {k for k in before if "/compact_15l/" in k}
    assert untouched and all(after[k] == before[k] for k in untouched), "compact_15l's run files were rewritten"
    assert all(after[k][2] != before[k][2] for k in before if k.endswith("/compact_1l/seed0/best.pt"))
    results_after = snapshot(c2, "results")
    changed = {k for k in results_before if results_before[k][2] != results_after[k][2]}
    assert changed == {f"results/{ds}/compact_1l/seed0/metrics.json" for ds in DATASETS}


def test_two_machines_run_one_dataset_each_and_a_third_runs_only_the_report(team):
    """docs/sharing.md, "One pipeline on several machines": a change that touches both datasets'
    training, committed on main; clone 1 runs set A's stages, clone 3 set B's, each on a branch it
    pushes with its outputs; clone 4 merges both, pulls, and has only the report left to run."""
    team, c1, _ = team
    env1 = team.env(c1)
    set_param(c1, ("train", "models", "compact_15l"), {"lr": 0.05})
    for cmd in (["git", "commit", "-qam", "15L at lr 0.05"], ["git", "push", "-q", "origin", "main"]):
        run(cmd, c1, env1)

    outputs: dict[str, bytes] = {}
    c3, env3 = team.clone("clone3")
    for clone, env, ds in ((c1, env1, "A"), (c3, env3, "B")):
        run(["git", "checkout", "-q", "-b", f"runs-{ds}"], clone, env)
        run(["dvc", "pull"], clone, env)
        log = run(["dvc", "repro", f"train@{ds}", f"evaluate@{ds}"], clone, env)
        assert ran_stages(log) == {f"train@{ds}", f"evaluate@{ds}"}
        assert retrained(log) == {f"{ds}/compact_15l/seed0"}
        run(["dvc", "push"], clone, env)
        for cmd in (["git", "add", "-A"], ["git", "commit", "-qm", f"set {ds}'s runs"],
                    ["git", "push", "-q", "origin", f"runs-{ds}"]):
            run(cmd, clone, env)
        outputs[ds] = (clone / f"results/{ds}/compact_15l/seed0/metrics.json").read_bytes()

    c4, env4 = team.clone("clone4")
    run(["git", "merge", "-q", "--no-edit", "origin/runs-A", "origin/runs-B"], c4, env4)
    run(["dvc", "pull"], c4, env4)
    assert set(yaml.safe_load(run(["dvc", "status", "--json"], c4, env4))) == {"report", "report_full"}
    assert ran_stages(run(["dvc", "repro"], c4, env4)) == {"report", "report_full"}
    for ds in DATASETS:
        assert (c4 / f"results/{ds}/compact_15l/seed0/metrics.json").read_bytes() == outputs[ds]
    assert ran_stages(run(["dvc", "repro"], c4, env4)) == set()
