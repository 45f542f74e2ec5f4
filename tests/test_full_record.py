"""The records of runs at ``scale: full`` (version 2 of core/plateau_record.py, written by
benchmarks/record_full.py) and the report built from them (report/full.py): a record keeps every
file of a run the report reads, the report built from a record equals the report built from the
run tree it was recorded from, incomplete runs and unrecorded datasets are named, and bad records
are one line."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml

from compact_perception.core.params import load_params, parse_params
from compact_perception.core.errors import ReportInputError
from compact_perception.core.plateau_record import (NEUTRAL_KEYS, STATUS_INCOMPLETE, changed_keys, record_problem,
                                                    record_runs, write_tree)
from compact_perception.report.full import build_full_report, load_records
from compact_perception.report.index import read_inputs, write_tables
from compact_perception.report.paper import load_paper_numbers
from compact_perception.report.plateau import load_record
from report_fixture import COMPACT, build_tree
from scripts import load_script

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "record_full.py"


def _full_params(**top):
    data = yaml.safe_load((ROOT / "params.yaml").read_text())
    data.update({"scale": "full", **top})
    return parse_params(data)


def _tree(root: Path, ds: str = "B") -> None:
    """A finished run tree of the compact models on ``ds`` at three seeds, with its floor."""
    build_tree(root, (ds,), n_frames=40, models=COMPACT, seeds=(0, 1, 2))


def _record(root: Path, ds: str = "B", models=COMPACT, seeds=(0, 1, 2)) -> dict:
    return record_runs(root, _full_params(), ds, {m: list(seeds) for m in models},
                       {"commit": "abc123", "machine": "a CPU (family 6 model 167), 2 cores", "command": "x"},
                       run_command=lambda m, k, arm: f"record {m} {k}")


def test_a_record_holds_every_file_the_report_reads_and_writes_them_back(tmp_path: Path) -> None:
    _tree(tmp_path / "tree")
    rec = _record(tmp_path / "tree")
    assert record_problem(json.loads(json.dumps(rec))) is None
    assert rec["version"] == 2 and rec["dataset"] == "B" and len(rec["runs"]) == 12
    run = next(r for r in rec["runs"] if r["model"] == "compact_15l_mgn" and r["seed"] == 1)
    assert run["command"] == "record compact_15l_mgn 1" and run["status"] == "complete"
    assert set(run["curves"]) >= {"w_de", "w_ss", "w_ls", "w_bevp", "val_score"}     # Fig. 8's weights
    assert run["per_frame"]["columns"][0] == "frame_id" and len(run["per_frame"]["rows"]) == 40
    write_tree(rec, tmp_path / "back")
    for rel in ("results/B/compact_15l_mgn/seed1/metrics.json", "runs/B/compact_15l_mgn/seed1/summary.json",
                "results/B/floor_pixel/metrics.json", "data/cache/B/meta.json"):
        assert json.loads((tmp_path / "back" / rel).read_text()) == json.loads((tmp_path / "tree" / rel).read_text())
    for rel in ("data/eval/B/compact_1l/seed2/per_frame.csv", "data/eval/B/floor_global/per_frame.csv"):
        import pandas as pd
        pd.testing.assert_frame_equal(pd.read_csv(tmp_path / "back" / rel), pd.read_csv(tmp_path / "tree" / rel))


def test_the_report_from_a_record_equals_the_report_from_its_tree(tmp_path: Path) -> None:
    """Table II and the claims of the record's tree are those of the run tree it was recorded from."""
    _tree(tmp_path / "tree")
    path = tmp_path / "records" / "B_compact.json"
    path.parent.mkdir()
    path.write_text(json.dumps(_record(tmp_path / "tree")))
    params = _full_params()
    build_full_report(load_records(tmp_path / "records"), params, tmp_path / "full")
    seeds = {"B": {m: [0, 1, 2] for m in COMPACT}}
    inp = read_inputs(tmp_path / "tree", ["B"], list(COMPACT), seeds, load_paper_numbers())
    write_tables(inp, tmp_path / "direct", "full")
    for name in ("table2.md", "claims.csv", "extra_metrics.csv"):
        assert (tmp_path / "full/tables" / name).read_text() == (tmp_path / "direct" / name).read_text(), name
    page = (tmp_path / "full/index.md").read_text()
    assert "| Set B | 15L+MGN (Alg. 1) | 0, 1, 2 | [B_compact.json]" in page
    assert "[B_compact.json](../../benchmarks/records/full/B_compact.json) | abc123 |" in page
    # what no record holds is listed, never silently absent
    not_recorded = page.split("## Not recorded yet", 1)[1].split("##", 1)[0]
    assert "Set A:" in not_recorded and "nuScenes" in not_recorded and "Set B:" in not_recorded
    assert "GradNorm" in not_recorded.split("Set B:", 1)[1].split("\n", 1)[0]
    assert json.loads((tmp_path / "full/metrics.json").read_text())["claims"]


def test_an_incomplete_run_is_recorded_without_numbers_and_named(tmp_path: Path) -> None:
    _tree(tmp_path / "tree")
    shutil.rmtree(tmp_path / "tree/results/B/compact_1l/seed2")
    (tmp_path / "tree/runs/B/compact_1l/seed2/summary.json").unlink()
    (tmp_path / "tree/runs/B/compact_1l/seed2/last.pt").write_bytes(b"x")
    rec = _record(tmp_path / "tree")
    run = next(r for r in rec["runs"] if r["model"] == "compact_1l" and r["seed"] == 2)
    assert run["status"] == STATUS_INCOMPLETE and "stopped before it finished" in run["reason"]
    assert not {"metrics", "per_frame", "floor_margin", "epochs_run"} & set(run)
    (tmp_path / "records").mkdir()
    (tmp_path / "records/B.json").write_text(json.dumps(rec))
    build_full_report(load_records(tmp_path / "records"), _full_params(), tmp_path / "full")
    page = (tmp_path / "full/index.md").read_text()
    assert "Set B, compact_1l seed 2: stopped before it finished" in page
    assert "1L (seeds 2)" in page.split("## Not recorded yet", 1)[1].split("##", 1)[0]


def test_two_records_of_one_run_or_of_different_floors_are_refused(tmp_path: Path) -> None:
    _tree(tmp_path / "tree")
    rec = _record(tmp_path / "tree")
    (tmp_path / "records").mkdir()
    (tmp_path / "records/B_a.json").write_text(json.dumps(rec))
    (tmp_path / "records/B_b.json").write_text(json.dumps(rec))
    with pytest.raises(ReportInputError, match=r"B_b.json: compact_1l seed 0 on B is also in .*B_a.json"):
        build_full_report(load_records(tmp_path / "records"), _full_params(), tmp_path / "full")
    other = json.loads(json.dumps(rec))
    other["runs"] = [r for r in other["runs"] if r["model"] == "compact_1l"]
    rec["runs"] = [r for r in rec["runs"] if r["model"] != "compact_1l"]
    other["floor"]["floor_pixel"]["metrics"]["tm"] = {"mean": 9.0, "var": 0.0}
    (tmp_path / "records/B_a.json").write_text(json.dumps(rec))
    (tmp_path / "records/B_b.json").write_text(json.dumps(other))
    with pytest.raises(ReportInputError, match="the records' floors differ"):
        build_full_report(load_records(tmp_path / "records"), _full_params(), tmp_path / "full")


@pytest.mark.parametrize("change, problem", [
    (lambda r: r.update(machine="x" * 100_000), "machine: expected one line of at most 500 characters"),
    (lambda r: r.update(commit="a\nb"), "commit: expected one line"),
    (lambda r: r.update(device="tpu"), "device: expected one of ['cpu', 'cuda']"),
    (lambda r: r["runs"][0]["per_frame"]["rows"].append(["f", 1.0]), "runs[0].per_frame: rows[40]: expected a frame id"),
    (lambda r: r["runs"][0]["curves"].update(w_de=[[0, float("nan")]]), "runs[0].curves: w_de: expected [[step, finite"),
    (lambda r: r["runs"][0].update(status="done"), "runs[0].status: expected 'complete' or 'incomplete'"),
    (lambda r: r["runs"][1].update(seed=0, model=r["runs"][0]["model"]), "runs[1]: compact_1l seed 0 recorded twice"),
    (lambda r: r["runs"][0].update(dataset="A"), "runs[0].dataset: expected the record's 'B'"),
])
def test_a_bad_record_is_one_line_naming_the_field(tmp_path: Path, change, problem) -> None:
    _tree(tmp_path / "tree")
    rec = _record(tmp_path / "tree")
    change(rec)
    _assert_refused(rec, tmp_path / "B.json", problem)


def _assert_refused(rec: dict, path: Path, problem: str) -> None:
    """``rec`` written to ``path`` is refused by the report's reader in one line naming ``problem``."""
    path.write_text(json.dumps(rec))
    with pytest.raises(ReportInputError) as exc:
        load_record(path)
    assert str(exc.value).startswith(f"{path}: {problem}")
    assert len(str(exc.value)) < 700 and "\n" not in str(exc.value)


def test_keys_that_cannot_change_a_recorded_run_are_not_flagged() -> None:
    """A CPU record made before `train.deterministic`, `train.tf32` and `evaluate.batch_size`
    existed was flagged against all three, though none changes that run: a CUDA-only key never
    changes a CPU run, and a key added since at the value the code had before it changes nothing."""
    now = {"train.deterministic": True, "train.tf32": False, "evaluate.batch_size": 1, "train.lr": 0.1}
    assert changed_keys({"train.lr": 0.1}, now, "cpu") == []
    assert changed_keys({"train.lr": 0.1}, {**now, "evaluate.batch_size": 4}, "cpu") == ["evaluate.batch_size"]
    assert changed_keys({"train.lr": 0.1}, now, "cuda") == ["train.deterministic", "train.tf32"]
    assert changed_keys({"train.lr": 0.2}, now, "cpu") == ["train.lr"]


def test_the_committed_records_read_and_name_nothing_that_cannot_change_them() -> None:
    params = load_params(ROOT / "params.yaml")
    records = [load_record(ROOT / "benchmarks/records/full_plateau.json"), *load_records(ROOT / "benchmarks/records/full")]
    assert len(records) >= 2, "no record of scale: full is committed"
    from compact_perception.report.plateau import evidence
    for rec in records:
        ev = evidence(rec, params)
        assert all(not ({"evaluate.batch_size", "train.deterministic", "train.tf32"} & set(keys))
                   for keys in ev.changed.values()), rec.path


def _script(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, cwd=ROOT)


def test_the_script_records_a_copy_and_checks_a_rerun_against_a_record(tmp_path: Path) -> None:
    copy = tmp_path / "copy"
    _tree(copy)
    data = yaml.safe_load((ROOT / "params.yaml").read_text())
    data.update({"scale": "full", "dataset_ids": ["B"], "model_ids": list(COMPACT)})
    (copy / "params.yaml").write_text(yaml.safe_dump(data, sort_keys=False))
    out = tmp_path / "B_compact.json"
    done = _script("--dataset", "B", "--part", "compact", "--root", str(copy), "--machine", "m", "--out", str(out))
    assert done.returncode == 0, done.stderr
    rec = json.loads(out.read_text())
    assert rec["machine"] == "m" and rec["scale"] == "full" and len(rec["runs"]) == 12
    assert rec["runs"][0]["command"].startswith("python benchmarks/record_full.py --dataset B --commit ")
    assert "--check benchmarks/records/full/B_compact.json" in rec["runs"][0]["command"]
    again = tmp_path / "again.json"
    done = _script("--dataset", "B", "--root", str(copy), "--models", "compact_1l", "--out", str(again),
                   "--check", str(out))
    assert done.returncode == 0 and "every recorded number equals" in done.stderr, done.stderr
    per_frame = copy / "data/eval/B/compact_1l/seed0/per_frame.csv"
    per_frame.write_text(per_frame.read_text().replace("0.", "0.9", 1))
    done = _script("--dataset", "B", "--root", str(copy), "--models", "compact_1l", "--out", str(again),
                   "--check", str(out))
    assert done.returncode == 1 and "compact_1l seed 0: per_frame differs" in done.stderr
    assert "Traceback" not in done.stderr
    for bad, says in ((["--seeds", "-1"], "--seeds: expected integers of at least 0"),
                      (["--part", "a/b"], "--part: expected a short name"),
                      (["--parallel-runs", "0"], "--parallel-runs: expected an integer of at least 1"),
                      (["--models", "nope"], "--models: ['nope']")):
        done = _script("--dataset", "B", "--root", str(copy), "--out", str(tmp_path / "x.json"), *bad)
        assert done.returncode == 1 and done.stderr.strip().splitlines()[-1].startswith(f"error: {says}"), done.stderr
        assert not (tmp_path / "x.json").exists()


def test_the_script_records_a_copy_at_a_commit_whose_params_are_in_a_former_layout(tmp_path: Path) -> None:
    """A part resumed, or a run re-created, at a commit before datasets.<ds>.source became a
    section: its params.yaml (written as such commits wrote it) is read in today's layout, and
    the record's settings carry today's keys, so the report compares them with today's params."""
    copy = tmp_path / "copy"
    _tree(copy)
    data = yaml.safe_load((ROOT / "params.yaml").read_text())
    data.update({"scale": "full", "dataset_ids": ["B"], "model_ids": list(COMPACT)})
    for section in data["datasets"].values():
        if "source" in section:
            section.update({"source": "sim", "authors_root": None,
                            "authors_splits": {"train": "Tr2", "val": "Va1", "test": "Te1"}})
    del data["evaluate"]["batch_size"]
    (copy / "params.yaml").write_text(yaml.safe_dump(data, sort_keys=False))
    out = tmp_path / "B_compact.json"
    done = _script("--dataset", "B", "--root", str(copy), "--models", "compact_1l", "--out", str(out))
    assert done.returncode == 0, done.stderr
    assert "former layout read as today's: datasets.B.source: 'sim' -> {id: sim, ...} (dropped authors_root" \
        in done.stderr
    settings = json.loads(out.read_text())["runs"][0]["settings"]
    assert settings["datasets.B.source.id"] == "sim" and "datasets.B.source" not in settings
    assert settings["evaluate.batch_size"] == 1


def test_records_of_one_cache_agree_though_one_was_made_before_the_meta_held_its_hashes(tmp_path: Path) -> None:
    """Set B's compact records (99ba736) hold a cache meta without ``sha256``, which the meta
    gained later; its baselines' record (6ca23b2) holds it. They are one cache: the report reads
    both and keeps the hashes. A cache that differs in any other key, or in the hashes where both
    hold them, is still refused."""
    _tree(tmp_path / "tree")
    rec = _record(tmp_path / "tree")
    (tmp_path / "records").mkdir()
    older = json.loads(json.dumps(rec))
    older["runs"] = [r for r in older["runs"] if r["model"] == "compact_1l"]
    rec["runs"] = [r for r in rec["runs"] if r["model"] != "compact_1l"]
    rec["cache_meta"]["sha256"] = {"test": {"de.npy": "ab" * 32}}
    older["cache_meta"].pop("sha256", None)
    (tmp_path / "records/B_a.json").write_text(json.dumps(older))
    (tmp_path / "records/B_b.json").write_text(json.dumps(rec))
    build_full_report(load_records(tmp_path / "records"), _full_params(), tmp_path / "full")
    rows = set(pd.read_csv(tmp_path / "full/tables/table2.csv").query("dataset == 'B'")["row_id"])
    assert set(COMPACT) <= rows  # 1L from the older record, the others from the newer
    tree = tmp_path / "written"
    for r in (older, rec):
        write_tree(r, tree)
    assert json.loads((tree / "data/cache/B/meta.json").read_text())["sha256"] == rec["cache_meta"]["sha256"]
    for change in (lambda m: m.update(sha256={"test": {"de.npy": "cd" * 32}}),
                   lambda m: m.update(resolution=16)):
        other = json.loads(json.dumps(older))
        other["cache_meta"]["sha256"] = dict(rec["cache_meta"]["sha256"])
        change(other["cache_meta"])
        (tmp_path / "records/B_a.json").write_text(json.dumps(other))
        with pytest.raises(ReportInputError, match="the records' caches differ"):
            build_full_report(load_records(tmp_path / "records"), _full_params(), tmp_path / "full2")


def test_a_part_sets_the_copys_params_to_its_runs_alone(tmp_path: Path) -> None:
    """A part of set A ran the study's 27 arms beside its own runs (train@A trains both at full):
    the copy's params now hold this part's dataset, models and seeds and no study arm."""
    module = load_script("record_full")
    path = tmp_path / "params.yaml"
    shutil.copy(ROOT / "params.yaml", path)
    assert load_params(path).model_copy(update={"scale": "full"}).study_datasets == ["A"]
    module.set_params(path, "A", ["chen_bev", "polarnet"], [1])
    params = load_params(path)
    assert (params.scale, params.dataset_ids, params.model_ids) == ("full", ["A"], ["chen_bev", "polarnet"])
    assert params.study_datasets == [] and params.seeds_of("baseline", "A") == [1]
    assert "# beyond the paper" in path.read_text()  # DVC's writer keeps the comments
    assert params.train.parallel_runs == load_params(ROOT / "params.yaml").train.parallel_runs
    module.set_params(path, "A", ["gradnorm_segnet"], None, parallel_runs=3)
    assert load_params(path).train.parallel_runs == 3 and load_params(path).model_ids == ["gradnorm_segnet"]
    assert "train.parallel_runs" in NEUTRAL_KEYS  # so no record's settings hold it, and none is flagged by it


# ----------------------------------------------------------------------------- the loss-balancing study at full
ARMS = ("uw", "single_de")


def _study_tree(root: Path) -> None:
    """Set A's compact runs and two study arms at seeds 0-2: each arm's run is a compact_15l run
    of the fixture, moved into the study's folders (runs/A/study/<arm>/seed<k>/ and its results)."""
    _tree(root, "A")
    for i, arm in enumerate(ARMS):
        src = root.parent / f"arm_{arm}"
        build_tree(src, ("A",), n_frames=40, models=("compact_15l",), seeds=(0, 1, 2), bases=None,
                   noise=0.01 + 0.002 * i)
        for top in ("runs", "results", "data/eval"):
            for k in (0, 1, 2):
                dest = root / top / "A" / "study" / arm / f"seed{k}"
                dest.parent.mkdir(parents=True, exist_ok=True)
                shutil.move(str(src / top / "A" / "compact_15l" / f"seed{k}"), str(dest))


def _study_record(root: Path) -> dict:
    return record_runs(root, _full_params(), "A", {}, {"commit": "def456", "machine": "m", "command": "y"},
                       run_command=lambda m, k, arm: f"record {m} {arm} {k}", arms={a: [0, 1, 2] for a in ARMS})


def test_a_study_part_records_its_arms_and_the_report_at_full_shows_the_study(tmp_path: Path) -> None:
    """A record of study arms (record_full.py --arms) holds each arm's run under its arm, on the
    base model, with the arm's settings; written back, each lands in the study's folders; the
    report at full builds the study's table from it beside the compact record and lists the arms
    of the params no record holds."""
    tree = tmp_path / "tree"
    _study_tree(tree)
    study = _study_record(tree)
    assert record_problem(json.loads(json.dumps(study))) is None
    assert {(r["model"], r["arm"], r["seed"]) for r in study["runs"]} == {
        ("compact_15l", a, k) for a in ARMS for k in (0, 1, 2)}
    run = next(r for r in study["runs"] if r["arm"] == "uw" and r["seed"] == 1)
    assert run["command"] == "record compact_15l uw 1"
    assert run["settings"]["study.arms.uw.weighting"] == "uw" and run["settings"]["study.base_model"] == "compact_15l"
    assert not any(k.startswith("train.models.") for k in run["settings"])
    written = write_tree(study, tmp_path / "back")
    assert ("compact_15l", 2, "single_de") in written
    rel = "results/A/study/uw/seed1/metrics.json"
    assert json.loads((tmp_path / "back" / rel).read_text()) == json.loads((tree / rel).read_text())
    assert (tmp_path / "back/data/eval/A/study/single_de/seed0/per_frame.csv").is_file()

    records = tmp_path / "records"
    records.mkdir()
    (records / "A_compact.json").write_text(json.dumps(_record(tree, "A")))
    (records / "A_study_a.json").write_text(json.dumps(study))
    params = _full_params()
    build_full_report(load_records(records), params, tmp_path / "full")
    page = (tmp_path / "full/index.md").read_text()
    assert "| Set A | study arm `uw` | 0, 1, 2 | [A_study_a.json](../../benchmarks/records/full/A_study_a.json) | def456 |" \
        in page
    not_recorded = page.split("## Not recorded yet", 1)[1].split("\n## ", 1)[0]
    set_a = not_recorded.split("Set A:", 1)[1].split("\n", 1)[0]
    assert "the loss-balancing study's arms `gradnorm`, `dwa`" in set_a and "`uw`" not in set_a
    assert "`single_de`" not in set_a and "15L+MGN" not in set_a
    weighting = pd.read_csv(tmp_path / "full/tables/weighting.csv")
    assert {"compact_15l", "compact_15l_mgn", "uw", "single_de"} <= set(weighting["method"])
    assert "## Loss-balancing study" in page and (tmp_path / "full/figures").is_dir()
    # the same arm in two records is refused, like any run
    (records / "A_study_b.json").write_text(json.dumps(study))
    with pytest.raises(ReportInputError, match=r"A_study_b.json: study:uw seed 0 on A is also in .*A_study_a.json"):
        build_full_report(load_records(records), params, tmp_path / "full2")


@pytest.mark.parametrize("change, problem", [
    (lambda r: r["runs"][0].update(arm="Bad arm"), "runs[0].arm: expected a study arm's id"),
    (lambda r: r["runs"][1].update(seed=0), "runs[1]: study:uw seed 0 recorded twice"),
])
def test_a_bad_study_record_is_one_line_naming_the_field(tmp_path: Path, change, problem) -> None:
    _study_tree(tmp_path / "tree")
    rec = _study_record(tmp_path / "tree")
    change(rec)
    _assert_refused(rec, tmp_path / "A.json", problem)


def test_a_study_arm_is_flagged_by_its_own_keys_and_the_base_models() -> None:
    from compact_perception.report.plateau import PlateauRun, changed_settings
    from compact_perception.core.plateau_record import settings_at

    params = _full_params()
    run = PlateauRun("A", "compact_15l", 0, 5, 3, 100, "plateau", 1.0, {"tm": 0.1},
                     settings_at(params, "compact_15l", "A", "full", "uw"), arm="uw")
    assert changed_settings(run, params, "full") == []
    data = yaml.safe_load((ROOT / "params.yaml").read_text())
    data["study"]["arms"]["uw"]["uw"]["lr"] = 0.05
    data["study"]["arms"]["dwa"]["dwa"]["temperature"] = 3.0   # another arm's: not this run's
    assert changed_settings(run, parse_params({**data, "scale": "full"}), "full") == ["study.arms.uw.uw.lr"]
    data = yaml.safe_load((ROOT / "params.yaml").read_text())
    del data["study"]["arms"]["uw"]
    data["study"]["arm_ids"].remove("uw")
    assert changed_settings(run, parse_params({**data, "scale": "full"}), "full") == ["study.arms.uw"]


def test_a_study_part_sets_the_copys_params_to_its_arms_and_the_base_model(tmp_path: Path) -> None:
    """A study part trains its arms (and the base model, which the study compares them with and
    which the train stage skips where the clone has it complete): the copy's params run the study
    on the part's dataset with these arms alone; an unknown arm is one line, nothing written."""
    module = load_script("record_full")
    path = tmp_path / "params.yaml"
    shutil.copy(ROOT / "params.yaml", path)
    module.set_params(path, "A", ["chen_bev"], None, ["pcgrad", "cagrad"])
    params = load_params(path)
    assert (params.scale, params.model_ids, params.study_datasets) == ("full", ["compact_15l"], ["A"])
    assert params.study.arm_ids == ["pcgrad", "cagrad"] and sorted(params.study.arms) == ["cagrad", "pcgrad"]
    copy = tmp_path / "copy"
    _study_tree(copy)
    data = yaml.safe_load((ROOT / "params.yaml").read_text())
    data.update({"scale": "full", "dataset_ids": ["A"]})
    (copy / "params.yaml").write_text(yaml.safe_dump(data, sort_keys=False))
    out = tmp_path / "A_study.json"
    done = _script("--dataset", "A", "--part", "study", "--arms", *ARMS, "--root", str(copy), "--out", str(out))
    assert done.returncode == 0, done.stderr
    rec = json.loads(out.read_text())
    assert {(r["arm"], r["seed"]) for r in rec["runs"]} == {(a, k) for a in ARMS for k in (0, 1, 2)}
    assert "--arms uw single_de" in rec["command"]
    assert "--arms uw --seeds 0" in next(r for r in rec["runs"] if r["arm"] == "uw" and r["seed"] == 0)["command"]
    done = _script("--dataset", "A", "--arms", "uw", "--root", str(copy), "--out", str(tmp_path / "again.json"),
                   "--check", str(out))
    assert done.returncode == 0 and "every recorded number equals" in done.stderr, done.stderr
    for bad in (["--arms", "nope"], ["--arms", "uw", "uw"]):
        done = _script("--dataset", "A", "--root", str(copy), "--out", str(tmp_path / "x.json"), *bad)
        assert done.returncode == 1 and done.stderr.strip().splitlines()[-1].startswith(
            "error: --arms: expected distinct arms of study.arms in"), done.stderr
        assert not (tmp_path / "x.json").exists()


def test_the_seeds_each_inconclusive_claim_needs_are_counted_per_dataset() -> None:
    """claims.csv's seeds_to_decide is a count, ">100" or empty: binned by hand below, per dataset
    in the order given, decided and not-decidable rows left out, a dataset without one absent."""
    from compact_perception.report.full import seeds_needed

    claims = pd.DataFrame({
        "dataset": ["C", "B", "B", "B", "B", "B", "C", "A"],
        "verdict": ["inconclusive", "inconclusive", "inconclusive", "inconclusive", "inconclusive", "reproduced",
                    "not decidable", "reproduced"],
        "seeds_to_decide": ["3", "10", "11", ">100", None, "4", "5", "3"],
    })
    assert seeds_needed(claims, ["A", "B", "C"]) == {
        "B": {"at_most_10": 1, "11_to_100": 1, "over_100": 1, "no_count": 1},
        "C": {"at_most_10": 1, "11_to_100": 0, "over_100": 0, "no_count": 0}}
    assert list(seeds_needed(claims, ["C", "B"])) == ["C", "B"]
