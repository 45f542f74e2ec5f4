"""The loss-balancing study's report (report/study.py): Δm by hand, mean ± sd rows over seeds
from a fake tree of runs (tests/report_fixture.py), the CSV columns, the loss-weight figure and
the link from reports/index.md."""
from __future__ import annotations

import csv
import logging
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from compact_perception.core import catalog
from compact_perception.report.index import build_reports
from compact_perception.report.study import StudySpec, delta_m, paper_forms, study_methods, write_study_report
from repo_params import repo_params
from report_fixture import build_tree, write_study_run

PAPER = ("compact_15l", "compact_15l_mgn", "compact_15l_mgn_authors")
ARMS = ("gradnorm", "uw", "dwa", "pcgrad", "cagrad", "single_de", "single_ss", "single_ls", "single_bevp")
WEIGHTING = {"gradnorm": "gradnorm", "uw": "uw", "dwa": "dwa", "pcgrad": "pcgrad", "cagrad": "cagrad",
             **{f"single_{t}": "single" for t in ("de", "ss", "ls", "bevp")}}
#: The paper forms' weightings (params.yaml train.models.<id>.weighting; StudySpec.from_params reads them).
PAPER_FORMS = {"compact_15l": "static", "compact_15l_mgn": "mgn", "compact_15l_mgn_authors": "mgn"}
SPEC = StudySpec(("A",), {"A": (0, 1, 2)}, ARMS, WEIGHTING, {f"single_{t}": t for t in ("de", "ss", "ls", "bevp")},
                 PAPER_FORMS)
OTHER = 0.1    # the single-task arms' metrics of the tasks they did not train
W = {"w_de": [1.0, 1.2, 1.4], "w_ss": [1.0, 0.9, 0.8], "w_ls": [1.0, 1.0, 1.1], "w_bevp": [1.0, 0.9, 0.7]}


def _means(de: float, ss: float, ls: float, bevp: float) -> dict[str, float]:
    return {"mae_de": de, "iou_ss": ss, "iou_ls": ls, "iou_bevp": bevp}


def _tree(root: Path, *, single_bevp: bool = True) -> None:
    """Main runs of the paper forms (report_fixture BASES: 15L at seed k has MAE_DE 0.09 - s_k and
    IoUs 0.65 / 0.50 / 0.55 + s_k, s = -0.01, 0, +0.02; train_seconds 1.0 over 3, 4, 5 epochs)
    and the study arms:

    - single-task references (own task, mean over seeds): MAE_DE 0.10 (0.09, 0.10, 0.11),
      IoU_SS 0.50 (0.49, 0.50, 0.51), IoU_LS 0.50, IoU_BEVP 0.50 (0.45, 0.50, 0.55);
    - gradnorm at seeds 0, 1 (seed 2 missing); uw at seed 0 only; pcgrad at seed 0 without
      weight logs; dwa at three seeds, IoU_BEVP 0.30 (below the floor's 0.35, report_fixture
      FLOOR_BASES); cagrad without runs.
    """
    build_tree(root, ("A",), n_frames=20, models=PAPER)
    refs = {"de": (0.09, 0.10, 0.11), "ss": (0.49, 0.50, 0.51), "ls": (0.50, 0.50, 0.50), "bevp": (0.45, 0.50, 0.55)}
    for t, vals in refs.items():
        if t == "bevp" and not single_bevp:
            continue
        for k, v in enumerate(vals):
            m = {c: OTHER for c in ("mae_de", "iou_ss", "iou_ls", "iou_bevp")}
            m[{"de": "mae_de", "ss": "iou_ss", "ls": "iou_ls", "bevp": "iou_bevp"}[t]] = v
            write_study_run(root, f"single_{t}", k, "A", m, weights={"w_" + t: [1.0, 1.0, 1.0]})
    write_study_run(root, "gradnorm", 0, "A", _means(0.12, 0.55, 0.50, 0.50), weights=W, train_seconds=10.0,
                    epochs_run=5)
    write_study_run(root, "gradnorm", 1, "A", _means(0.08, 0.60, 0.55, 0.45), weights=W, train_seconds=12.0,
                    epochs_run=4)
    write_study_run(root, "uw", 0, "A", _means(0.10, 0.50, 0.50, 0.50), weights=W)
    write_study_run(root, "pcgrad", 0, "A", _means(0.10, 0.50, 0.50, 0.50))
    for k in SPEC.seeds["A"]:
        write_study_run(root, "dwa", k, "A", _means(0.10, 0.55, 0.55, 0.30), weights=W)


def _rows(path: Path) -> dict[str, dict[str, str]]:
    return {r["method"]: r for r in csv.DictReader(path.open())}


# ----------------------------------------------------------------------------- Δm
def test_delta_m_by_hand() -> None:
    # MAE_DE (lower is better): 0.12 against 0.10 -> -(0.12 - 0.10) / 0.10 = -0.20
    # IoU_SS (higher is better): 0.55 against 0.50 -> +(0.55 - 0.50) / 0.50 = +0.10
    # Δm = (-0.20 + 0.10) / 2 * 100 = -5.0 %
    ref = {"mae_de": 0.10, "iou_ss": 0.50}
    assert delta_m({"mae_de": 0.12, "iou_ss": 0.55}, ref, ("mae_de", "iou_ss")) == pytest.approx(-5.0)
    # better on both: -(0.08 - 0.10) / 0.10 = +0.20, (0.60 - 0.50) / 0.50 = +0.20 -> +20.0 %
    assert delta_m({"mae_de": 0.08, "iou_ss": 0.60}, ref, ("mae_de", "iou_ss")) == pytest.approx(20.0)
    assert delta_m(ref, ref, ("mae_de", "iou_ss")) == 0.0
    # all four metrics (the default K = 4): gradnorm seed 1 of the fake tree
    # +0.20 (DE) + 0.20 (SS) + (0.55 - 0.50) / 0.50 = +0.10 (LS) + (0.45 - 0.50) / 0.50 = -0.10 (BEVP) -> 0.40 / 4
    four = {"mae_de": 0.10, "iou_ss": 0.50, "iou_ls": 0.50, "iou_bevp": 0.50}
    assert delta_m(_means(0.08, 0.60, 0.55, 0.45), four) == pytest.approx(10.0)
    # a missing or zero reference: NaN
    assert math.isnan(delta_m({"mae_de": 0.1, "iou_ss": 0.5}, {"mae_de": 0.1}, ("mae_de", "iou_ss")))
    assert math.isnan(delta_m({"mae_de": 0.1}, {"mae_de": 0.0}, ("mae_de",)))


def test_spec_from_repo_params_and_method_order() -> None:
    p = repo_params()
    spec = StudySpec.from_params(p)
    assert spec.arm_ids == tuple(p.study.arm_ids) and spec.datasets == tuple(p.study.datasets.at(p.scale))
    assert spec.seeds == {ds: tuple(p.seeds_of("compact", ds)) for ds in spec.datasets}
    assert set(spec.single_task.values()) <= {"de", "ss", "ls", "bevp"}
    assert spec.paper == PAPER_FORMS and list(spec.paper) == list(PAPER)    # from each model's recipe
    methods = study_methods(spec)
    assert [m.id for m in methods] == list(PAPER) + list(p.study.arm_ids)
    labels = {m.id: m.label for m in methods}
    assert labels["compact_15l_mgn"] == "15L+MGN (Alg. 1)" and labels.get("single_de") == "Single-task (DE)"
    assert [m.id for m in methods if m.adaptive][:2] == ["compact_15l_mgn", "compact_15l_mgn_authors"]
    assert not any(m.adaptive for m in methods if m.weighting in ("static", "single"))


def test_paper_forms_follow_the_model_recipes() -> None:
    """The paper forms' weightings are read from train.models.<id>, not kept in the report."""
    p = repo_params()
    models = {**p.train.models, "compact_15l_mgn": SimpleNamespace(weighting="uw")}
    fake = SimpleNamespace(study=SimpleNamespace(base_model="compact_15l"), train=SimpleNamespace(models=models))
    assert paper_forms(fake) == {**PAPER_FORMS, "compact_15l_mgn": "uw"}
    fake.study.base_model = "compact_1l"                          # the 1-layer input: only compact_1l
    assert paper_forms(fake) == {"compact_1l": "static"}


# ----------------------------------------------------------------------------- table and figure
def test_rows_mean_sd_csv_and_figure(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    _tree(tmp_path)
    with caplog.at_level(logging.INFO, logger="compact_perception.report.study"):
        out = write_study_report(tmp_path, SPEC, tmp_path / "tables", tmp_path / "figures")
    rows = _rows(out.csv)
    header = out.csv.read_text().splitlines()[0].split(",")
    metrics = catalog.metric_keys() + tuple(catalog.SCORES.keys()) + ("dm", "sec_per_epoch")
    assert metrics[:6] == ("mae_de", "iou_ss", "iou_ls", "iou_bevp", "tm", "mv")
    assert header == (["dataset", "method", "label", "n_seeds"] + [f"{k}_{s}" for k in metrics for s in ("mean", "sd")]
                      + ["above_floor"])
    # paper forms first, then the arms with runs, in arm order; cagrad has none
    assert list(rows) == list(PAPER) + ["gradnorm", "uw", "dwa", "pcgrad", "single_de", "single_ss", "single_ls",
                                        "single_bevp"]
    # 15L: Δm per seed = 12.5 + 400 s_k (seed 1: (+0.1 + 0.3 + 0 + 0.1) / 4 = 12.5 %; a shift s adds
    # 10 s (DE) + 3 x 2 s (IoUs), / 4 -> 4 s): 8.5, 12.5, 20.5 -> mean 13.8333, sd sqrt(74.667 / 2) = 6.1101
    r = rows["compact_15l"]
    assert r["label"] == "15L (equal static weights)" and r["n_seeds"] == "3" and r["above_floor"] == "yes"
    assert float(r["dm_mean"]) == pytest.approx(41.5 / 3, abs=1e-4)
    assert float(r["dm_sd"]) == pytest.approx(math.sqrt(74.6667 / 2), abs=1e-4)
    assert float(r["mae_de_mean"]) == pytest.approx((0.10 + 0.09 + 0.07) / 3, abs=1e-6)
    assert float(r["sec_per_epoch_mean"]) == pytest.approx((1 / 3 + 1 / 4 + 1 / 5) / 3, abs=1e-5)
    tm = [0.09 - s + 3 - (0.65 + s) - (0.50 + s) - (0.55 + s) for s in (-0.01, 0.0, 0.02)]
    assert float(r["tm_mean"]) == pytest.approx(np.mean(tm), abs=1e-6)
    assert float(r["tm_sd"]) == pytest.approx(np.std(tm, ddof=1), abs=1e-6)
    # gradnorm, seeds 0 and 1: 2 seeds, not shown above the floor (fewer than 3): no Δm;
    # s / epoch 10 / 5 = 2.0 and 12 / 4 = 3.0 -> 2.5 ± 0.7071; MAE_DE 0.12, 0.08 -> 0.10 ± 0.02828
    g = rows["gradnorm"]
    assert g["label"] == "GradNorm (Chen et al. 2018)" and g["n_seeds"] == "2"
    assert g["dm_mean"] == ""
    assert g["above_floor"].startswith("no: DE (not shown above: 2 seeds), SS (not shown above: 2 seeds)")
    assert float(g["sec_per_epoch_mean"]) == pytest.approx(2.5) and float(g["sec_per_epoch_sd"]) == pytest.approx(
        math.sqrt(0.5))
    assert float(g["mae_de_sd"]) == pytest.approx(0.04 / math.sqrt(2), abs=1e-6)
    # one seed: no sd, not above the floor; three seeds but IoU_BEVP below the floor's: no Δm either
    assert rows["uw"]["n_seeds"] == "1" and rows["uw"]["dm_sd"] == "" and rows["uw"]["dm_mean"] == ""
    dwa = rows["dwa"]
    assert dwa["n_seeds"] == "3" and dwa["dm_mean"] == "" and dwa["above_floor"] == "no: BEVP (below)"
    # the references: Δm empty, each checked on its own task only
    assert rows["single_de"]["label"] == "Single-task (DE)" and rows["single_de"]["dm_mean"] == ""
    assert rows["single_de"]["above_floor"] == "yes"
    assert float(rows["single_de"]["mae_de_mean"]) == pytest.approx(0.10)
    md = out.markdown.read_text()
    assert "Δm" in md and "LibMTL" in md and "training.seeds`: Set A: 0, 1, 2" in md and "**" not in md.split("## Set A")[1]
    assert "±2 sd are not separated" in md and "No runs yet: CAGrad (Liu et al. 2021)." in md
    assert "| GradNorm (Chen et al. 2018) | 2 | 0.100 ± 0.028 |" in md and "below floor | 2.50 ± 0.71 |" in md
    assert "| Uncertainty weighting (Kendall et al. 2018) | 1 | 0.100 ± — |" in md
    assert ("Not above the floor on every task (Δm not reported): GradNorm (Chen et al. 2018) "
            "(DE (not shown above: 2 seeds)") in md
    assert "DWA (Liu et al. 2019) (BEVP (below))" in md and "above the trivial-predictor floor on every task" in md
    assert "Reference (single-task, own task, mean over seeds): MAE_DE 0.100, IoU_SS 0.500" in md
    # the figure: MGN first, gradnorm and uw beside it; pcgrad logged no weights (skipped, logged)
    png = out.figures["A"]
    assert png == tmp_path / "figures" / "loss_weights_study_A.png" and png.read_bytes()[:4] == b"\x89PNG"
    assert any("PCGrad" in m and "no weights" in m for m in caplog.messages)
    assert any("gradnorm" in m and "seed(s) [2]" in m for m in caplog.messages)
    assert set(out.paths) == {out.markdown, out.csv, png}


def test_missing_reference_gives_na_with_note(tmp_path: Path) -> None:
    _tree(tmp_path, single_bevp=False)
    out = write_study_report(tmp_path, SPEC, tmp_path / "tables", tmp_path / "figures")
    rows = _rows(out.csv)
    assert rows["compact_15l"]["dm_mean"] == "" and rows["gradnorm"]["dm_mean"] == ""
    assert rows["compact_15l"]["tm_mean"] != ""
    md = out.markdown.read_text()
    assert "Δm n/a: no single-task reference for IoU_BEVP (single_bevp: no runs)." in md
    assert "| n/a | 0.26 ± 0.07 |" in md          # 15L: above the floor, but no reference
    assert "| below floor | 2.50 ± 0.71 |" in md  # gradnorm: the gate first


def test_nothing_trained_yet_writes_empty_tables(tmp_path: Path) -> None:
    out = write_study_report(tmp_path, SPEC, tmp_path / "tables", tmp_path / "figures")
    assert out.rows == [] and out.figures == {}
    assert out.csv.read_text().startswith("dataset,method,label,n_seeds,mae_de_mean")
    assert "No runs on this dataset yet." in out.markdown.read_text()


def test_index_links_the_study(tmp_path: Path) -> None:
    _tree(tmp_path)
    seeds = {m: [0, 1, 2] for m in PAPER}
    rel = build_reports(tmp_path, tmp_path / "reports", datasets=("A",), models=PAPER, scale_name="default",
                        seeds=seeds, study=SPEC)
    for name in ("tables/weighting.md", "tables/weighting.csv", "figures/report/loss_weights_study_A.png"):
        assert name in rel and (tmp_path / "reports" / name).is_file()
    index = (tmp_path / "reports" / "index.md").read_text()
    assert "## Loss-balancing study (beyond the paper)" in index
    assert "(tables/weighting.md)" in index and "(figures/report/loss_weights_study_A.png)" in index
    assert "### Set A" in index and "| GradNorm (Chen et al. 2018) | 2 |" in index


def test_plots_csv_has_every_study_run(tmp_path: Path) -> None:
    """dvc plots cover the study too: each study run with logged weights appears in
    loss_weights.csv as study/<arm>/seed<k>/<ds>."""
    _tree(tmp_path)
    build_reports(tmp_path, tmp_path / "reports", datasets=("A",), models=PAPER, scale_name="default",
                  seeds={m: [0, 1, 2] for m in PAPER}, study=SPEC)
    rows = list(csv.DictReader((tmp_path / "reports/plots/loss_weights.csv").open()))
    runs = {r["run"] for r in rows}
    assert {"study/gradnorm/seed0/A", "study/gradnorm/seed1/A", "study/uw/seed0/A"} <= runs
    assert "study/pcgrad/seed0/A" not in runs            # logged no weights in the fixture
    g0 = [float(r["weight"]) for r in rows if r["run"] == "study/gradnorm/seed0/A" and r["task"] == "de"]
    assert g0 == W["w_de"]
