"""The whole pipeline, end to end, with `dvc repro` at a tiny scale in a temporary copy.

One module-scoped run (every dataset and model) serves several checks:
- every stage runs; every Table II cell and figure exists, the floor rows too; table numbers
  equal metrics files; every run's summary says why it stopped;
- a second `dvc repro` does nothing;
- a parameter only dataset C uses changes only C's first stage; a preprocessing parameter
  changes preprocessing and nothing before it; a dataset's training budget changes its training
  and evaluation, not its data;
- changing one MGN parameter reruns the train and evaluate stages, which retrain only the MGN
  runs (every other run is complete for its digest), then the report; one study arm's parameter
  retrains only that arm's runs;
- a training stage killed mid-run continues from its last finished epoch;
- every params key a stage reads is one of the stage's ``params:`` in dvc.yaml;
- the README's experiment command works from a fresh shell (the venv not on PATH);
- a change of library code reruns the stages that import it and changes their result.
"""
from __future__ import annotations

import csv
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from compact_perception.core.catalog import MODELS as MODEL_INFO, compact_model_ids, metric_of, model_ids

COMPACT_MODEL_IDS = compact_model_ids()

pytestmark = pytest.mark.slow

# The tiny copy runs one simulated set and the nuScenes path (dvc.yaml's lists are cut to
# these, see `pipeline`), every model, two seeds, the study on set A: the code paths of the full run.
DATASETS = ("A", "nuscenes")
SEEDS = (0, 1)           # the compact models'
BASELINE_SEEDS = (0,)
MODELS = model_ids()
# The study's arms in the copy: a loss-based method, a gradient-surgery one, one single-task net.
STUDY_ARMS = ("uw", "pcgrad", "single_de")
SCALES = ("default", "full", "paper")


def seeds_of(model: str) -> tuple[int, ...]:
    return SEEDS if model in COMPACT_MODEL_IDS else BASELINE_SEEDS


def every(value) -> dict:
    return {s: value for s in SCALES}
ALL_TASKS = {"mae_de", "iou_ss", "iou_ls", "iou_bevp", "tm", "mv"}


def task_keys(model: str) -> set[str]:
    """The metrics.json keys of a model (SPEC 2): its tasks' metrics, TM and MV when it does all four."""
    keys = {metric_of(t) for t in MODEL_INFO[model].tasks}
    return keys | {"tm", "mv"} if len(keys) == 4 else keys


TASK_KEYS = {m: task_keys(m) for m in model_ids()}
# A study arm scores all four tasks, a single-task network (arm single_<task>) its own task only.
ARM_KEYS = {"single_de": {"mae_de"}, "single_ss": {"iou_ss"}, "single_ls": {"iou_ls"}, "single_bevp": {"iou_bevp"}}


def tiny(params: dict) -> dict:
    """Shrink every scale knob so the whole pipeline runs in a few minutes on 2 cores."""
    params["world"]["resolution"] = every(32)
    params["world"]["lidar"]["horizontal_samples"] = 256
    params["world"]["frames_per_episode"] = 2
    params["world"]["workers"] = 1
    params["sim_ids"] = ["A"]                # the matrices' id lists (dvc.yaml reads them from params)
    params["dataset_ids"] = list(DATASETS)
    params["baseline_seeds"] = every(list(BASELINE_SEEDS))
    for ds in ("A", "B", "C"):
        params["datasets"][ds]["frames"]["default"] = 10   # 3 / 2 / 5 frames at 3:2:5
        params["datasets"][ds]["split_ratio"]["default"] = {"train": 3, "val": 2, "test": 5}
    params["datasets"]["nuscenes"]["sim_scenes"]["default"] = 5
    params["datasets"]["nuscenes"]["sim_samples_per_scene"] = 2
    for ds in params["datasets"].values():
        ds["training"] = {"seeds": every(list(SEEDS)), "max_epochs": every(2)}
    for recipe in params["train"]["models"].values():
        if "max_epochs" in recipe:
            recipe["max_epochs"] = every(2)
    params["preprocess"]["workers"] = 1
    params["train"]["batch_size"] = 2
    params["train"]["num_workers"] = 0
    params["benchmark"] = {"warmup": 1, "runs": 3}
    params["study"]["datasets"]["default"] = ["A"]
    params["study"]["arm_ids"] = list(STUDY_ARMS)
    params["study"]["arms"] = {arm: params["study"]["arms"][arm] for arm in STUDY_ARMS}
    return params


def copy_project(root: Path, dest: Path, shrink) -> Path:
    """The project's files as git knows them (tracked and not ignored), without the stages' outputs
    or dvc.lock, copied to ``dest`` with params.yaml passed through ``shrink`` (a tiny scale)."""
    files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=root, capture_output=True,
                           text=True, check=True).stdout.split()
    for f in files:
        src = root / f
        if src.is_file() and not f.startswith(("reports/", "data/", "runs/", "results/")) or f == "data/.gitignore":
            (dest / f).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / f)
    (dest / "dvc.lock").unlink(missing_ok=True)
    params = shrink(yaml.safe_load((dest / "params.yaml").read_text()))
    (dest / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    return dest


def dvc_env(tmp: Path) -> dict:
    env = dict(os.environ)
    env.update({
        "DVC_NO_ANALYTICS": "1", "HOME": str(tmp / "home"), "DVC_GLOBAL_CONFIG_DIR": str(tmp / "dvc-global"),
        "DVC_SYSTEM_CONFIG_DIR": str(tmp / "dvc-system"), "DVC_SITE_CACHE_DIR": str(tmp / "dvc-site"),
        "PATH": f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}",
        "GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@t", "GIT_COMMITTER_NAME": "t", "GIT_COMMITTER_EMAIL": "t@t",
    })
    env["PYTHONPATH"] = os.pathsep.join([str(tmp / "repo" / "src"), str(tmp / "repo")])
    env["COMPACT_PERCEPTION_PARAMS_AUDIT"] = str(tmp / "params_audit.jsonl")  # every key each stage reads
    return env


def run(cmd: list[str], cwd: Path, env: dict, check: bool = True) -> str:
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True)
    out = proc.stdout + proc.stderr
    if check and proc.returncode:
        raise AssertionError(f"{' '.join(cmd)} failed ({proc.returncode}):\n{out[-6000:]}")
    return out


def ran_stages(log: str) -> set[str]:
    return set(re.findall(r"Running stage '([^']+)'", log))


def set_param(repo: Path, path: tuple[str, ...], value) -> None:
    params = yaml.safe_load((repo / "params.yaml").read_text())
    node = params
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = value
    (repo / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))


def changed_stages(repo: Path, env: dict) -> set[str]:
    return set(json.loads(run(["dvc", "status", "--json"], repo, env)).keys())


@pytest.fixture(scope="module")
def pipeline(tmp_path_factory, root: Path):
    tmp = tmp_path_factory.mktemp("e2e")
    repo = copy_project(root, tmp / "repo", tiny)
    env = dvc_env(tmp)
    for cmd in (["git", "init", "-q"], ["git", "add", "-A"], ["git", "commit", "-qm", "tiny"]):
        run(cmd, repo, env)
    log = run(["dvc", "repro"], repo, env)
    yield repo, env, log
    # the baselines' checkpoints, in the workspace and the DVC cache, are ~13 GB at this tiny scale
    # (GradNorm SegNet is 4 full VGG16-BN SegNets): free them, so that test runs do not fill a disk
    for heavy in (repo / "runs", repo / ".dvc" / "cache"):
        shutil.rmtree(heavy, ignore_errors=True)


def test_every_stage_ran_and_outputs_exist(pipeline):
    repo, env, log = pipeline
    stages = ran_stages(log)
    for ds in DATASETS:
        assert {f"train@{ds}", f"evaluate@{ds}"} <= stages
        for floor in ("floor_pixel", "floor_global"):
            metrics = json.loads((repo / "results" / ds / floor / "metrics.json").read_text())
            assert {key for key in metrics if key in ALL_TASKS} == ALL_TASKS, (ds, floor)
        for m in MODELS:
            for k in seeds_of(m):
                metrics = json.loads((repo / "results" / ds / m / f"seed{k}" / "metrics.json").read_text())
                assert {key for key in metrics if key in ALL_TASKS} == TASK_KEYS[m], (ds, m, k)
                assert set(metrics["floor_margin"]) >= TASK_KEYS[m] - {"mv"}, (ds, m, k)
                summary = json.loads((repo / "runs" / ds / m / f"seed{k}" / "summary.json").read_text())
                assert summary["epochs_run"] and summary["stop_reason"] in ("plateau", "max_epochs")
    for ds in ("A",):
        assert f"generate@{ds}" in stages and (repo / "data/raw" / ds / "manifest.json").is_file()
        assert (repo / "reports/figures" / f"world_{ds}.png").is_file()
        assert (repo / "reports/figures" / f"lidar_preprocessing_{ds}.png").is_file()
    for name in ("index.md", "tables/table2.md", "tables/table2.tex", "tables/table2.csv", "tables/table3.md",
                 "tables/paper_vs_reproduced.md"):
        assert (repo / "reports" / name).is_file(), name
    assert (repo / "reports/metrics.json").is_file()
    for name in ("val_tm.csv", "loss_weights.csv"):
        runs = {row["run"] for row in csv.DictReader((repo / "reports/plots" / name).open())}
        if name == "val_tm.csv":
            assert runs == ({f"{ds}/{m}/seed{k}" for ds in DATASETS for m in MODELS for k in seeds_of(m)}
                            | {f"study/{arm}/seed{k}/A" for arm in STUDY_ARMS for k in SEEDS})
        else:
            assert {f"{ds}/compact_15l_mgn/seed{k}" for ds in DATASETS for k in SEEDS} <= runs
    for ds in DATASETS:
        for fig in (f"loss_weights_{ds}.png", f"qualitative_{ds}.png", f"curves_{ds}.png"):
            assert (repo / "reports/figures/report" / fig).is_file(), fig
    assert "simulated nuScenes-format" in (repo / "reports/index.md").read_text()
    for arm in STUDY_ARMS:
        for k in SEEDS:
            metrics = json.loads((repo / "results/A/study" / arm / f"seed{k}" / "metrics.json").read_text())
            assert {key for key in metrics if key in ALL_TASKS} == ARM_KEYS.get(arm, ALL_TASKS), (arm, k)


def test_table_numbers_equal_metrics_files(pipeline):
    """Table II's means are the means over the seeds of each run's metrics file."""
    repo, _, _ = pipeline
    rows = list(csv.DictReader((repo / "reports/tables/table2.csv").open()))
    checked = 0
    for row in rows:
        ds, model = row["dataset"], row["row_id"]
        if model not in MODELS:
            continue
        per_seed = [json.loads((repo / "results" / ds / model / f"seed{k}" / "metrics.json").read_text())
                    for k in seeds_of(model)]
        for key in TASK_KEYS[model] - {"tm", "mv"}:
            expected = sum(m[key]["mean"] for m in per_seed) / len(per_seed)
            assert float(row[f"{key}_mean"]) == pytest.approx(expected, abs=1e-9), (ds, model, key)
            checked += 1
    assert checked == len(DATASETS) * sum(len(TASK_KEYS[m] - {"tm", "mv"}) for m in MODELS)
    floors = [row for row in rows if row["row_id"] in ("floor_pixel", "floor_global")]
    assert len(floors) == 2 * len(DATASETS)


def test_second_repro_does_nothing(pipeline):
    repo, env, _ = pipeline
    assert ran_stages(run(["dvc", "repro"], repo, env)) == set()


def test_parameter_changes_touch_only_their_stages(pipeline):
    repo, env, _ = pipeline
    original = (repo / "params.yaml").read_text()
    try:
        # the reports read every setting that shapes a run too: they compare them with those of the
        # recorded runs (report/plateau.py, report/full.py) and name what changed (6 s, 2 s)
        set_param(repo, ("datasets", "A", "seed_offset"), 7)
        assert changed_stages(repo, env) == {"generate@A", "report", "report_full"}
        (repo / "params.yaml").write_text(original)
        set_param(repo, ("preprocess", "fill_neighbours"), False)
        assert changed_stages(repo, env) == {"preprocess@A", "ingest_nuscenes", "report", "report_full"}
        (repo / "params.yaml").write_text(original)
        # a training budget is not data: the seeds and epoch cap leave generate and preprocess alone
        set_param(repo, ("datasets", "A", "training", "max_epochs", "default"), 3)
        assert changed_stages(repo, env) == {"train@A", "evaluate@A", "report", "report_full"}
    finally:
        (repo / "params.yaml").write_text(original)
    assert changed_stages(repo, env) == set()


def retrained(log: str) -> set[str]:
    """The runs a train stage trained (the others are complete for their digest: skipped)."""
    done = set(re.findall(r"(\S+): already complete for this code, params and data", log))
    finished = set(re.findall(r"finished (\S+) \(", log))
    return {name for name in finished if not any(d.endswith(name) for d in done)}


def test_a_recipe_or_arm_parameter_retrains_only_its_runs(pipeline):
    """A change of one model's recipe (15L+MGN's alpha) and of one study arm's setting (uw's lr),
    reproduced together (one repro, as the two were the same stages' reruns): the train and
    evaluate stages of the datasets those runs live on rerun, and they retrain only those runs;
    every other run is complete for its digest and skipped."""
    repo, env, _ = pipeline
    set_param(repo, ("train", "models", "compact_15l_mgn", "mgn", "alpha"), 1.2)
    set_param(repo, ("study", "arms", "uw", "uw", "lr"), 0.01)
    log = run(["dvc", "repro"], repo, env)
    assert ran_stages(log) == ({f"train@{ds}" for ds in DATASETS} | {f"evaluate@{ds}" for ds in DATASETS}
                               | {"report", "report_full"})
    assert retrained(log) == ({f"{ds}/compact_15l_mgn/seed{k}" for ds in DATASETS for k in SEEDS}
                              | {f"A/study/uw/seed{k}" for k in SEEDS})


def test_killed_training_resumes_from_last_epoch(pipeline):
    repo, env, _ = pipeline
    set_param(repo, ("train", "models", "compact_1l", "lr"), 0.05)
    set_param(repo, ("train", "models", "compact_1l", "max_epochs"), every(4))
    last = repo / "runs/A/compact_1l/seed0/last.pt"
    before = last.stat().st_mtime_ns
    proc = subprocess.Popen(["dvc", "repro", "train@A"], cwd=repo, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.time() + 300
    while time.time() < deadline and (not last.exists() or last.stat().st_mtime_ns == before):
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    import torch

    epoch_done = torch.load(last, weights_only=True)["epoch"]
    assert epoch_done < 3, "the run finished before it could be killed"
    log = run(["dvc", "repro", "train@A"], repo, env)
    assert f"resuming after epoch {epoch_done + 1}" in log
    summary = json.loads((repo / "runs/A/compact_1l/seed0/summary.json").read_text())
    assert summary["epochs_run"] == 4
    steps = (repo / "runs/A/compact_1l/seed0/live/plots/metrics/lr.tsv").read_text().split()[2::2]
    assert steps == ["0", "1", "2", "3"]


def _declared_params(repo: Path) -> dict[str, list[str]]:
    """Each stage's resolved ``params:`` keys, as DVC itself expands dvc.yaml."""
    from dvc.dependency.param import ParamsDependency
    from dvc.repo import Repo

    with Repo(str(repo)) as dvc_repo:
        return {stage.name: [k for dep in stage.deps if isinstance(dep, ParamsDependency) for k in dep.params]
                for stage in dvc_repo.index.stages}


def test_every_params_key_a_stage_reads_is_declared(pipeline):
    repo, env, _ = pipeline
    declared = _declared_params(repo)
    audit = [json.loads(line) for line in Path(env["COMPACT_PERCEPTION_PARAMS_AUDIT"]).read_text().splitlines()]
    seen = set()
    for entry in audit:
        values = [a for a in entry["argv"] if not a.startswith("-")]
        stage = entry["stage"]
        name = stage + (f"@{'-'.join(values)}" if values else "")
        assert name in declared, f"audited stage {name} not in dvc.yaml"
        seen.add(name)
        undeclared = [k for k in entry["keys"]
                      if not any(k == d or k.startswith(d + ".") for d in declared[name])]
        assert not undeclared, f"{name} reads params it does not declare in dvc.yaml: {undeclared}"
    assert seen == set(declared), f"stages never audited: {sorted(set(declared) - seen)}"


def test_readme_experiment_command_works_from_a_fresh_shell(pipeline, root):
    """`bin/venv dvc exp run -S ...` as the README shows it, with no venv on PATH."""
    repo, env, _ = pipeline
    assert "bin/venv dvc exp run -S scale=paper" in (root / "README.md").read_text()
    (repo / ".venv").symlink_to(root / ".venv")
    # The copy shares this checkout's venv: its install inputs must not look newer than the
    # venv's stamp, or `make setup` would re-point the editable install at the copy.
    stamp = (root / ".venv/.installed").stat().st_mtime
    for name in ("requirements.txt", "pyproject.toml"):
        os.utime(repo / name, (stamp - 1, stamp - 1))
    fresh = {k: v for k, v in env.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    fresh["PATH"] = "/usr/local/bin:/usr/bin:/bin"
    # one target, so that what earlier tests left out of date elsewhere does not run here
    log = run(["bin/venv", "dvc", "exp", "run", "-S", "train.models.chen_bev.lr=0.0005", "evaluate@A"],
              repo, fresh)
    assert {"train@A", "evaluate@A"} <= ran_stages(log)
    assert retrained(log) >= {f"A/chen_bev/seed{k}" for k in BASELINE_SEEDS}


def test_library_code_change_reruns_and_changes_the_result(pipeline):
    """Halving the IoU in metrics.py: training and evaluation rerun, nothing is 'already complete',
    and the metrics file changes (the issue's first reproduction)."""
    repo, env, _ = pipeline
    metrics_py = repo / "src/compact_perception/learning/metrics.py"
    before = json.loads((repo / "results/A/compact_1l/seed0/metrics.json").read_text())
    text = metrics_py.read_text()
    assert text.count("def iou(") == 1
    metrics_py.write_text(text.replace("def iou(", "def _iou_exact(", 1) +
                          "\n\ndef iou(*args, **kwargs):\n    return 0.5 * _iou_exact(*args, **kwargs)\n")
    changed = changed_stages(repo, env)
    assert {f"train@{ds}" for ds in DATASETS} | {f"evaluate@{ds}" for ds in DATASETS} <= changed
    log = run(["dvc", "repro", "evaluate@A"], repo, env)
    assert {"train@A", "evaluate@A"} <= ran_stages(log)
    assert "already complete" not in log
    after = json.loads((repo / "results/A/compact_1l/seed0/metrics.json").read_text())
    assert after["iou_ss"]["mean"] != before["iou_ss"]["mean"]
