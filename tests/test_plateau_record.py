"""The record of runs trained to their plateau (core/plateau_record.py, written by
benchmarks/record_plateau.py, read by report/plateau.py): what it keeps of a run, which of today's
settings it notices changed, what the report's floor section says from it, its errors, and that its
writer and reader share its one definition without importing each other."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from compact_perception.core.params import load_params, parse_params
from compact_perception.core.plateau_record import settings_at
from compact_perception.report.collect import ReportInputError
from compact_perception.report.index import build_reports
from compact_perception.report.plateau import (PlateauRecord, PlateauRun, changed_settings, evidence, load_record,
                                               recorded_sentence)
from imports import import_closure
from report_fixture import MODELS, bases_with, build_tree, seed_map

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "record_full.py"
BASELINES = ["chen_bev", "polarnet", "gradnorm_segnet"]


def _params(**changes):
    """The repository's params with ``changes`` applied (dotted key -> value)."""
    data = yaml.safe_load((ROOT / "params.yaml").read_text())
    for key, value in changes.items():
        node = data
        *path, last = key.split(".")
        for k in path:
            node = node[k]
        node[last] = value
    return parse_params(data)


def _run(model: str = "chen_bev", margin: dict | None = None, stop: str = "plateau", settings=None) -> PlateauRun:
    params = load_params(ROOT / "params.yaml")
    return PlateauRun("A", model, 0, 25, 16, 100, stop, 112.6, margin or {"iou_bevp": 0.025},
                      settings if settings is not None else settings_at(params, model, "A", "full"))


def _record(*runs: PlateauRun) -> PlateauRecord:
    return PlateauRecord("benchmarks/records/full_plateau.json", "full", "abc1234", "a 2-core CPU", "dvc repro",
                         tuple(runs))


def test_settings_are_the_values_that_shape_the_run_at_the_records_scale() -> None:
    params = load_params(ROOT / "params.yaml")
    s = settings_at(params, "chen_bev", "A", "full")
    assert params.scale == "default"                          # read at full whatever the file's own scale
    assert s["max_epochs"] == 100 and s["train.early_stop_patience"] == 8       # params.yaml's full values
    assert s["train.models.chen_bev.lr"] == 1.0e-4 and s["train.models.chen_bev.optimizer"] == "adam"
    assert s["datasets.A.frames"] == 500 and s["world.resolution"] == 32 and s["seed"] == 2022
    assert not any(k.startswith("train.models.polarnet") for k in s)               # another model's recipe
    # what changes no result, the seed list (kept per run) and another source's settings are left out
    assert not ({"train.num_workers", "train.parallel_runs", "world.workers", "preprocess.workers"} & set(s))
    assert not any(k.startswith(("datasets.A.training.seeds", "datasets.A.carla", "datasets.A.authors")) for k in s)
    assert settings_at(params, "chen_bev", "A", "default")["max_epochs"] == 1


def test_changed_settings_name_what_todays_params_change() -> None:
    run = _run()
    assert changed_settings(run, load_params(ROOT / "params.yaml"), "full") == []
    # the default's value of a key is not the record's business; full's is
    assert changed_settings(run, _params(**{"train.early_stop_patience.default": 2}), "full") == []
    assert changed_settings(run, _params(**{"train.models.chen_bev.lr": 3.0e-4}), "full") == ["train.models.chen_bev.lr"]
    assert changed_settings(run, _params(**{"train.num_workers": 2}), "full") == []     # changes no result
    assert changed_settings(run, _params(**{"datasets.A.frames.full": 800}), "full") == ["datasets.A.frames"]


def test_a_key_renamed_since_a_record_is_compared_under_its_name_today() -> None:
    """A record made when ``datasets.<ds>.source`` was the source's id holds ``datasets.A.source:
    sim``; today that is ``datasets.A.source.id``: the same value is no change, another is one."""
    from compact_perception.core.plateau_record import changed_keys

    now = {"datasets.A.source.id": "sim", "seed": 1}
    assert changed_keys({"datasets.A.source": "sim", "seed": 1}, now, "cpu") == []
    assert changed_keys({"datasets.A.source": "authors", "seed": 1}, now, "cpu") == ["datasets.A.source.id"]
    assert changed_keys({"datasets.A.source": "sim", "seed": 1}, {**now, "datasets.A.source.seed": 3}, "cpu") == \
        ["datasets.A.source.seed"]


def test_the_sentence_says_what_each_recorded_run_shows() -> None:
    params = load_params(ROOT / "params.yaml")
    ev = evidence(_record(_run(), _run("polarnet", {"iou_ls": -0.01}), _run("gradnorm_segnet", {"mae_de": 0.1},
                                                                            stop="max_epochs")), params)
    text = recorded_sentence(ev, BASELINES, ["A"], "../benchmarks/records/full_plateau.json")
    assert text.startswith("Trained to their plateau at `scale: full` (recorded in "
                           "[full_plateau.json](../benchmarks/records/full_plateau.json): abc1234, a 2-core CPU; 1 seed")
    assert ("Chen et al.: Set A, seed 0: trained to a plateau in 25 epochs (best 16), margin over the floor "
            "BEVP +0.025: it learns at these settings") in text
    assert "PolarNet: Set A, seed 0: trained to a plateau in 25 epochs (best 16), margin over the floor LS -0.010: " \
           "it does not learn at these settings" in text
    # a capped run answers nothing; a margin missing on one of the model's tasks is no "learns"
    assert "GradNorm: Set A, seed 0: stopped by its cap after 25 epochs, not at a plateau" in text
    assert "says nothing either way" in text
    half = evidence(_record(_run("gradnorm_segnet", {"mae_de": 0.1})), params)
    assert "DE +0.100: it does not learn" in recorded_sentence(half, BASELINES, ["A"], "x")
    # only the models and datasets the report shows; nothing without a record
    assert recorded_sentence(ev, ["chen_bev"], ["A"], "x").count("seed 0") == 1
    assert recorded_sentence(ev, BASELINES, ["B"], "x") is None
    assert recorded_sentence(None, BASELINES, ["A"], "x") is None
    # a record of settings today's params no longer use answers for its own settings only
    changed = evidence(_record(_run()), _params(**{"train.models.chen_bev.lr": 3.0e-4}))
    assert ("(today's params would train this run differently: `train.models.chen_bev.lr`; the record answers "
            "for its own settings only)") in recorded_sentence(changed, BASELINES, ["A"], "x")


def test_the_index_quotes_the_record_below_the_capped_runs(tmp_path: Path) -> None:
    build_tree(tmp_path, ("A",), n_frames=40, stop_reason="max_epochs", bases=bases_with(polarnet={"iou_ls": 0.0}))
    ev = evidence(_record(_run(), _run("polarnet", {"iou_ls": 0.199})), load_params(ROOT / "params.yaml"))
    build_reports(tmp_path, tmp_path / "reports", datasets=("A",), models=MODELS, scale_name="default",
                  seeds=seed_map(), plateau=ev)
    lines = (tmp_path / "reports/index.md").read_text().splitlines()
    capped = next(i for i, line in enumerate(lines) if line.startswith("- Do the baselines learn at this scale?"))
    assert "undecided whether it can learn" in lines[capped]
    assert lines[capped + 1].startswith("- Trained to their plateau at `scale: full`")
    assert "PolarNet: Set A, seed 0: trained to a plateau in 25 epochs (best 16), margin over the floor LS +0.199: " \
           "it learns at these settings" in lines[capped + 1]


def _finished_tree(root: Path, params_changes: dict) -> None:
    """A repository copy at ``scale: full`` with one finished run of Chen et al. on set A, in the
    documented layout: runs/A/chen_bev/seed0/summary.json, results/A/chen_bev/seed0/metrics.json."""
    data = yaml.safe_load((ROOT / "params.yaml").read_text())
    data.update({"scale": "full", "model_ids": ["chen_bev"], "baseline_seeds": {"default": [0], "full": [0],
                                                                              "paper": [0]}, **params_changes})
    root.mkdir(parents=True, exist_ok=True)
    (root / "params.yaml").write_text(yaml.safe_dump(data, sort_keys=False))
    run, res = root / "runs/A/chen_bev/seed0", root / "results/A/chen_bev/seed0"
    run.mkdir(parents=True)
    res.mkdir(parents=True)
    (run / "summary.json").write_text(json.dumps({"epochs_run": 25, "best_epoch": 16, "max_epochs": 100,
                                                  "stop_reason": "plateau", "train_seconds": 112.64}))
    (res / "metrics.json").write_text(json.dumps({"iou_bevp": {"mean": 0.29, "var": 0.01},
                                                  "floor_margin": {"iou_bevp": 0.0245}}))
    for folder in (root / "data/eval/A/chen_bev/seed0", root / "data/eval/A/floor_pixel"):
        folder.mkdir(parents=True)
        (folder / "per_frame.csv").write_text("frame_id,iou_bevp\ntown02_ep0001_000,0.29\n")
    (root / "results/A/floor_pixel").mkdir(parents=True)
    (root / "results/A/floor_pixel/metrics.json").write_text(json.dumps({"iou_bevp": {"mean": 0.26, "var": 0.0}}))
    (root / "data/cache/A").mkdir(parents=True)
    (root / "data/cache/A/meta.json").write_text(json.dumps({"counts": {"train": 300, "val": 50, "test": 150}}))


def _script(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, cwd=ROOT)


def test_the_script_records_a_finished_tree_and_the_report_reads_it(tmp_path: Path) -> None:
    _finished_tree(tmp_path / "copy", {})
    out = tmp_path / "record.json"
    done = _script("--dataset", "A", "--root", str(tmp_path / "copy"), "--machine", "a CPU", "--out", str(out))
    assert done.returncode == 0, done.stderr
    rec = load_record(out)
    assert (rec.scale, rec.commit, rec.machine) == ("full", "not a git checkout", "a CPU")
    assert rec.command.startswith("python benchmarks/record_full.py --dataset A --commit ")
    [run] = rec.runs
    assert (run.model, run.seed, run.epochs_run, run.best_epoch, run.stop_reason) == ("chen_bev", 0, 25, 16, "plateau")
    assert run.floor_margin == {"iou_bevp": 0.0245} and run.train_seconds == 112.64
    # the settings as today's params give them at full: nothing changed
    assert changed_settings(run, load_params(ROOT / "params.yaml"), "full") == []


def test_the_script_and_the_reader_refuse_bad_input_in_one_line(tmp_path: Path) -> None:
    _finished_tree(tmp_path / "copy", {})
    (tmp_path / "copy/runs/A/chen_bev/seed0/summary.json").write_text(json.dumps({"epochs_run": 25}))
    out = tmp_path / "record.json"
    done = _script("--dataset", "A", "--root", str(tmp_path / "copy"), "--out", str(out))
    assert done.returncode == 1 and not out.exists()
    assert done.stderr.strip().splitlines() == [
        f"error: {tmp_path}/copy/runs/A/chen_bev/seed0/summary.json: missing best_epoch, max_epochs, stop_reason, "
        "train_seconds"]
    done = _script("--dataset", "A", "--root", str(tmp_path / "copy"), "--models", "nope", "--out", str(out))
    assert done.returncode == 1 and "--models: ['nope']" in done.stderr and "Traceback" not in done.stderr
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"version": 1, "scale": "full", "runs": [{"dataset": "A", "model": "chen_bev"}]}))
    with pytest.raises(ReportInputError, match=r"bad.json: runs\[0\].seed: missing \(expected an integer of at least 0\)"):
        load_record(bad)
    good = {"dataset": "A", "model": "chen_bev", "seed": 0, "epochs_run": 25, "best_epoch": 16, "max_epochs": 100,
            "stop_reason": "plateau", "train_seconds": 1.0, "floor_margin": {"iou_bevp": 0.1}, "settings": {}}
    bad.write_text(json.dumps({"version": 1, "scale": "full", "runs": [{**good, "model": "segformer"}]}))
    with pytest.raises(ReportInputError, match=r"bad.json: runs\[0\].model: expected one of \[.*\] \(got 'segformer'\)"):
        load_record(bad)
    bad.write_text(json.dumps({"version": 1, "scale": "huge", "runs": [good]}))
    with pytest.raises(ReportInputError, match=r"bad.json: scale: expected one of"):
        load_record(bad)
    # a recorded model today's params no longer have: its recipe key is what changed
    data = yaml.safe_load((ROOT / "params.yaml").read_text())
    data["model_ids"] = [m for m in data["model_ids"] if m != "chen_bev"]
    del data["train"]["models"]["chen_bev"]
    assert changed_settings(PlateauRun(**good), parse_params(data), "full") == ["train.models.chen_bev"]
    bad.write_text("{")
    with pytest.raises(ReportInputError, match="bad.json: not valid JSON"):
        load_record(bad)
    assert load_record(tmp_path / "none.json") is None


@pytest.mark.parametrize("file, key, value, problem", [
    ("summary", "epochs_run", "three", "epochs_run: expected an integer of at least 1 (got 'three')"),
    ("summary", "best_epoch", 30, "best_epoch: expected below epochs_run (25) (got 30)"),
    ("summary", "epochs_run", 250, "epochs_run: expected at most max_epochs (100) (got 250)"),
    ("summary", "stop_reason", "bored", "stop_reason: expected 'plateau' or 'max_epochs' (got 'bored')"),
    ("summary", "train_seconds", float("nan"), "train_seconds: expected a finite number of at least 0 (got nan)"),
    ("metrics", "floor_margin", {"iou_bevp": "high"}, "floor_margin: expected a non-empty mapping of metric name "
                                                      "to a finite number (got {'iou_bevp': 'high'})"),
])
def test_a_run_that_lies_is_refused_before_the_record_is_written(tmp_path: Path, file, key, value, problem) -> None:
    """``epochs_run: "three"`` in a summary exited 0, overwrote the tracked record with one the report
    refused, with a logging traceback on the way; a non-numeric margin was a ValueError traceback.
    The writer and the reader check through one schema: the reader refuses the same value in the
    same words, so a record the script writes is one the report reads."""
    _finished_tree(tmp_path / "copy", {})
    name = {"summary": "runs/A/chen_bev/seed0/summary.json", "metrics": "results/A/chen_bev/seed0/metrics.json"}[file]
    path = tmp_path / "copy" / name
    path.write_text(json.dumps({**json.loads(path.read_text()), key: value}))
    out = tmp_path / "full_plateau.json"
    out.write_bytes((ROOT / "benchmarks/records/full_plateau.json").read_bytes())
    before = out.read_bytes()
    done = _script("--dataset", "A", "--root", str(tmp_path / "copy"), "--out", str(out))
    assert done.returncode == 1
    assert done.stderr.strip().splitlines() == [f"error: {path}: {problem}"], done.stderr
    assert out.read_bytes() == before                                 # the tracked record untouched
    good = json.loads(before)
    good["runs"][3][key] = value                                   # chen_bev: 25 of 100 epochs, as above
    out.write_text(json.dumps(good))
    with pytest.raises(ReportInputError) as exc:
        load_record(out)
    assert str(exc.value) == f"{out}: runs[3].{problem}"


def test_the_committed_record_reads_and_the_report_stage_depends_on_it() -> None:
    """The record the report stage depends on (dvc.yaml) loads and holds a run of each baseline
    trained to its plateau (whether today's params still train them that way, the report says)."""
    rec = load_record(ROOT / "benchmarks/records/full_plateau.json")
    assert rec is not None and rec.scale == "full"
    assert {r.model for r in rec.runs if r.stop_reason == "plateau"} >= set(BASELINES)
    dvc = yaml.safe_load((ROOT / "dvc.yaml").read_text())
    assert "benchmarks/records/full_plateau.json" in dvc["stages"]["report"]["deps"]


def test_the_script_and_the_report_share_the_record_module_and_nothing_else() -> None:
    """The record's one definition (core/plateau_record.py) sits below its writer and its reader:
    the script imports it and nothing of the report, and the report's reader reads with it."""
    record = ROOT / "src/compact_perception/core/plateau_record.py"
    script = import_closure(ROOT, SCRIPT)
    assert record in script
    assert not [p for p in script if (ROOT / "src/compact_perception/report") in p.parents]
    assert record in import_closure(ROOT, ROOT / "src/compact_perception/report/plateau.py")
    assert not (ROOT / "src/compact_perception/report/plateau_schema.py").exists()
