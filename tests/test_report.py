"""Reports: paper numbers, efficiency measurement, Table II/III, paper-vs-reproduced, figures,
the plots' CSV files and the headline metrics, on fake pipeline outputs with three training seeds
per run (tests/report_fixture.py writes the documented seed<k> layout)."""
from __future__ import annotations

import csv
import dataclasses
import json
import math
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import nn

from compact_perception.core import catalog
from compact_perception.core.registry import Registry
from compact_perception.learning.metrics import scores_from_means
from compact_perception.evaluation import efficiency as eff
from compact_perception.report import schema
from compact_perception.report.collect import (ReportInputError, aggregate_cells, Cell, collect_scale,
                                               load_results, load_row_frames, read_metrics)
from compact_perception.report.gate import DatasetFloor, dataset_floor
from compact_perception.report.figures import plot_loss_weights, plot_qualitative, plot_training_curves
from compact_perception.report.index import HEADLINE_KEY, HEADLINE_MODEL, build_reports
from compact_perception.report.plots import write_plot_data
from compact_perception.report.paper import load_paper_numbers
from compact_perception.report.schema import ROW_ORDER, TASK_COLUMNS, paper_row
from compact_perception.report.tables.formats import fmt_seeds, write_files
from compact_perception.report.tables.table2 import build_table2, column_interval, table2_files, table2_markdown
from compact_perception.report.tables.table3 import build_table3
from report_fixture import (ARGMAX_GAIN, COMPACT, FLOORS, MGN, MODELS, SEEDS, TASKS, bases_with, build_tree, n_epochs,
                            per_frame, run_dirs, seed_map, write_json, write_run)

SEEDMAP = seed_map()
N_FRAMES = 40
#: Each run's own shift (report_fixture.jitter_of), where an interval between rows matters.
JITTER = 0.004
#: 15L+MGN (both forms) better than 15L on LS and BEVP, equal on DE and SS: IoU_LS (PolarNet),
#: IoU_BEVP (Chen) and TM (the combination, 1.1 against 15L+MGN's 1.24) have clear winners;
#: MAE_DE and IoU_SS of 15L and both MGN rows are equal (the best is not separated).
BASES = bases_with(compact_15l_mgn={"iou_ls": 0.60, "iou_bevp": 0.60},
                   compact_15l_mgn_authors={"iou_ls": 0.60, "iou_bevp": 0.60})
ROWS = ["chen_bev", "polarnet", "gradnorm_segnet", "combination", "compact_1l", "compact_15l", "compact_15l_mgn",
        "compact_15l_mgn_authors"]


# ----------------------------------------------------------------------------- paper numbers
def test_paper_numbers_complete_and_self_consistent() -> None:
    p = load_paper_numbers()
    assert set(p.table2) == {"A", "B", "C", "nuscenes"} <= set(catalog.dataset_ids())   # the paper's sets
    for ds in p.table2:
        rows = p.table2[ds]
        assert set(rows) == {paper_row(r) for r in ROWS}     # every row of the paper's models has its printed row
        # the printed combination TM / MV follow from the printed baseline cells (3-decimal rounding;
        # tests/test_losses_metrics.py checks MV at the printed precision row by row)
        s = scores_from_means({"mae_de": rows["gradnorm_segnet"].value("mae_de"),
                               "iou_ss": rows["gradnorm_segnet"].value("iou_ss"),
                               "iou_ls": rows["polarnet"].value("iou_ls"), "iou_bevp": rows["chen_bev"].value("iou_bevp")})
        assert s["tm"] == pytest.approx(rows["combination"].tm, abs=1.5e-3)
        assert s["mv"] == pytest.approx(rows["combination"].mv, abs=1.5e-3)
        for m in ("compact_1l", "compact_15l", "compact_15l_mgn"):
            s = scores_from_means({c: rows[m].value(c) for c in TASK_COLUMNS})
            assert s["tm"] == pytest.approx(rows[m].tm, abs=1.5e-3) and s["mv"] == pytest.approx(rows[m].mv, abs=1.5e-3)
    assert p.table2["A"]["compact_15l_mgn"].tm == 1.393 and p.table2["C"]["polarnet"].value("iou_ls") == 0.735
    assert p.table2["A"]["gradnorm_segnet"].cells["iou_ss"].var == 0.002
    assert p.table2["A"]["chen_bev"].cells["iou_bevp"].var_below
    for grp, rows3 in p.table3.items():
        parts = [rows3[b] for b in ("chen_bev", "polarnet", "gradnorm_segnet")]
        assert sum(r.value("params") for r in parts) == rows3["combination"].value("total_params")
        assert sum(r.value("size_mb") for r in parts) == pytest.approx(rows3["combination"].value("total_size_mb"),
                                                                       abs=1e-6)
        # the combination prints only its totals: its own parameters are those
        assert rows3["combination"].value("params") == rows3["combination"].value("total_params")
    sim = p.table3["simulation"]
    assert sim["compact_15l"].value("params") == 2521504 and p.table3_device == "NVIDIA GTX 1080 Ti"
    # 4xGradNorm: printed per copy (28,239,960 parameters, 226.116 MB), the row's value is the four copies'
    assert sim["gradnorm_segnet"].copies == 4 and sim["gradnorm_segnet"].value("params") == 4 * 28239960
    assert sim["gradnorm_segnet"].value("size_mb") == pytest.approx(4 * 226.116)
    assert sim["combination"].value("peak_memory_mb") == 1987 and sim["gradnorm_segnet"].value("fps") is None


# ----------------------------------------------------------------------------- rows and columns
def test_rows_and_columns_derive_from_the_registries(monkeypatch: pytest.MonkeyPatch) -> None:
    """Table rows: the catalog's models by ``table_order``, the combination right after the last
    model that gives it a task; Table II's columns: the task metrics, then TM and MV."""
    assert [r for r in ROW_ORDER if r in ROWS] == ROWS and schema.COMBINATION_MODELS == ("chen_bev", "polarnet", "gradnorm_segnet")
    assert schema.TABLE2_COLUMNS == TASK_COLUMNS + tuple(catalog.SCORES.keys()) and TASK_COLUMNS == catalog.metric_keys()
    assert tuple(catalog.SCORES.keys())[:2] == ("tm", "mv")
    assert schema.COLUMN_TEX["iou_bevp"] == "$IoU_{BEVP}$" and schema.COLUMN_TEX["tm"] == "$TM$"
    assert schema.LOWER_IS_BETTER == {"mae_de", "tm", "mv"}
    moved = Registry("model", ordered=True)      # PolarNet's row after every compact model
    for m in [m for m in catalog.model_ids() if m in ROWS]:   # the paper's models
        info = catalog.MODELS[m]
        moved.register(m)(dataclasses.replace(info, table_order=99) if m == "polarnet" else info)
    monkeypatch.setattr(catalog, "MODELS", moved)
    assert schema.row_ids() == ("chen_bev", "gradnorm_segnet", "compact_1l", "compact_15l", "compact_15l_mgn",
                                "compact_15l_mgn_authors", "polarnet", "combination")


# ----------------------------------------------------------------------------- efficiency
class _Sleeper:
    """Forward sleeps ``slow_s`` for the first ``n_slow`` calls, ``fast_s`` afterwards."""

    def __init__(self, n_slow: int, slow_s: float, fast_s: float) -> None:
        self.calls, self.n_slow, self.slow_s, self.fast_s = 0, n_slow, slow_s, fast_s

    def __call__(self, batch: object) -> None:
        self.calls += 1
        time.sleep(self.slow_s if self.calls <= self.n_slow else self.fast_s)


def test_measure_fps_excludes_warmup_and_uses_median() -> None:
    fn = _Sleeper(n_slow=3, slow_s=0.08, fast_s=0.005)
    r = eff.measure_fps(fn, None, "cpu", warmup=3, runs=9)
    assert fn.calls == 12
    assert 5.0 <= r["latency_ms"] < 40.0          # the 80 ms warm-up calls are not timed
    assert r["fps"] == pytest.approx(1000.0 / r["latency_ms"])
    assert 25.0 < r["fps"] <= 200.0
    assert r["device"].startswith("CPU (") and r["warmup"] == 3 and r["runs"] == 9


def test_measure_fps_synchronises_around_every_timed_call(monkeypatch: pytest.MonkeyPatch) -> None:
    events: list[str] = []
    monkeypatch.setattr(torch.cuda, "synchronize", lambda device=None: events.append("sync"))
    monkeypatch.setattr(torch.cuda, "get_device_name", lambda device=None: "NVIDIA Fake GPU")
    r = eff.measure_fps(lambda b: events.append("call"), None, "cuda", warmup=2, runs=4)
    calls = [i for i, e in enumerate(events) if e == "call"]
    assert len(calls) == 6
    for i in calls[2:]:                               # every timed call is bracketed by syncs
        assert events[i - 1] == "sync" and events[i + 1] == "sync"
    assert events.count("sync") >= 2 * 4 and r["device"] == "NVIDIA Fake GPU"


def test_measure_model_cpu_counts() -> None:
    model = nn.Sequential(nn.Conv2d(3, 4, 3, padding=1), nn.ReLU())
    batch = torch.zeros(1, 3, 8, 8)
    r = eff.measure_model(model, batch, "cpu", warmup=1, runs=3)
    assert r["params"] == 3 * 4 * 9 + 4
    assert r["size_mb"] > r["params"] * 4 / 2**20
    # parameters + input + conv output + relu output (forward-hook estimate)
    assert r["peak_memory_mb"] == pytest.approx((112 + 3 * 64 + 2 * 4 * 64) * 4 / 2**20)
    assert r["is_gpu"] is False and r["fps"] > 0


# ----------------------------------------------------------------------------- fake pipeline outputs
def _tree(root: Path, datasets: tuple[str, ...] = ("A", "nuscenes"), **kw) -> dict:
    kw.setdefault("bases", BASES)
    return build_tree(root, datasets, n_frames=N_FRAMES, predictions=True, efficiency=True, **kw)


def _results(root: Path, datasets: tuple[str, ...] = ("A", "nuscenes"), seeds=SEEDMAP) -> dict:
    return load_results(root, list(datasets), MODELS, seeds)


def _frames(root: Path, datasets: tuple[str, ...] = ("A", "nuscenes"), seeds=SEEDMAP) -> dict:
    return {ds: load_row_frames(root, ds, MODELS, seeds) for ds in datasets}


def _floors(root: Path, datasets: tuple[str, ...] = ("A", "nuscenes")) -> dict[str, DatasetFloor]:
    return {ds: dataset_floor(root, ds) for ds in datasets}


def _stale_run(root: Path, ds: str = "A", model: str = "compact_1l", seed: int = 9) -> None:
    """A run of a seed no longer in params: absurd scores that would show if it counted."""
    df = per_frame(ds, model, seed, N_FRAMES, bases_with(**{model: {"mae_de": 5.0, "iou_ss": 0.0, "iou_ls": 0.0,
                                                                   "iou_bevp": 0.0}}))
    write_run(root, ds, model, seed, df)


def test_mean_sd_over_seeds_by_hand(tmp_path: Path) -> None:
    """1L on set A: seed shifts -0.01, 0, +0.02 make the run-level means 0.11, 0.10, 0.08 (MAE_DE)
    and 0.59, 0.60, 0.62 (IoU_SS); TM 1.64, 1.60, 1.52; MV of the four means 0.035 in every seed."""
    mets = _tree(tmp_path, ("A",))
    _stale_run(tmp_path)
    write_files(tmp_path / "out", table2_files(build_table2(_results(tmp_path, ("A",)), _frames(tmp_path, ("A",)),
                                                            floors=_floors(tmp_path, ("A",)))))
    row = [r for r in csv.DictReader((tmp_path / "out/table2.csv").open()) if r["row_id"] == "compact_1l"][0]
    sd = math.sqrt(((0.11 - 0.29 / 3) ** 2 + (0.10 - 0.29 / 3) ** 2 + (0.08 - 0.29 / 3) ** 2) / 2)
    assert sd == pytest.approx(math.sqrt(7 / 30000))
    assert float(row["mae_de_mean"]) == pytest.approx(0.29 / 3, abs=1e-12)
    assert float(row["mae_de_std"]) == pytest.approx(sd, abs=1e-12)
    assert float(row["iou_ss_mean"]) == pytest.approx(1.81 / 3, abs=1e-12)
    assert float(row["iou_ss_std"]) == pytest.approx(sd, abs=1e-12)
    assert float(row["tm"]) == pytest.approx(4.76 / 3, abs=1e-12)
    assert float(row["tm_std"]) == pytest.approx(4 * sd, abs=1e-12)
    assert float(row["mv"]) == pytest.approx(0.035, abs=1e-12) and float(row["mv_std"]) == pytest.approx(0, abs=1e-12)
    # the paper's per-frame variance: the mean over the seeds of each run's
    for c in TASK_COLUMNS:
        assert float(row[f"{c}_var"]) == pytest.approx(np.mean([mets[("A", "compact_1l", k)][c]["var"] for k in SEEDS]),
                                                       abs=1e-15)
    assert row["n_seeds"] == "3" and row["seeds"] == "0;1;2" and row["n_test_frames"] == str(N_FRAMES)
    md = (tmp_path / "out/table2.md").read_text()
    assert f"| 1L | 3 |  | {0.29 / 3:.3f} ± {sd:.3f} |" in md         # no training facts given: Trained empty
    assert "mean ± sd over the seeds" in md and "variance over the test frames" in md and "var (frames)" in md
    assert f"Test frames per run: Set A {N_FRAMES}" in md and "1L, 15L, 15L+MGN (Alg. 1), 15L+MGN (authors' code)" in md
    # aggregate_cells is that computation
    c = aggregate_cells([Cell(0.11, 1.0), Cell(0.10, 2.0), Cell(0.08, 3.0)])
    assert (c.mean, c.std, c.var, c.n_seeds) == (pytest.approx(0.29 / 3), pytest.approx(sd), 2.0, 3)


def test_one_seed_prints_n1(tmp_path: Path) -> None:
    _tree(tmp_path, ("A",), seeds=(0,), baseline_seeds=(0,))
    tables = build_table2(_results(tmp_path, ("A",), seed_map((0,), (0,))))
    md = table2_markdown(tables)
    rows = {r.row_id: r for r in tables["A"]}
    assert rows["compact_1l"].cells["mae_de"].std is None and rows["compact_1l"].n_seeds == 1
    assert f"{0.11:.3f} (n=1)" in md and " ± " not in md.split("\n\n")[0].split("\n", 2)[2]


def test_one_mean_sd_format() -> None:
    """fmt_seeds is every table's ``mean ± sd`` (Table II, the study's ``weighting.md`` with ``no_sd``)."""
    assert fmt_seeds(Cell(0.1234, std=0.0106, n_seeds=3)) == "0.123 ± 0.011"
    assert fmt_seeds(Cell(0.1234, std=0.0106, n_seeds=3), latex=True) == "0.123 $\\pm$ 0.011"
    assert fmt_seeds(Cell(0.1234, n_seeds=1)) == "0.123 (n=1)" and fmt_seeds(None) == "-"
    assert fmt_seeds(Cell(12.34, n_seeds=1), decimals=1, no_sd="—") == "12.3 ± —"


def test_table2_numbers_bold_and_combination(tmp_path: Path) -> None:
    mets = _tree(tmp_path, jitter=JITTER)
    results = _results(tmp_path)
    training = {ds: sc.epochs for ds, sc in collect_scale(tmp_path, ("A", "nuscenes"), MODELS, results, SEEDMAP).items()}
    paths = write_files(tmp_path / "out", table2_files(build_table2(results, _frames(tmp_path), floors=_floors(tmp_path),
                                                                    training=training)))
    assert sorted(p.name for p in paths) == ["table2.csv", "table2.md", "table2.tex"] and all(p.is_file() for p in paths)
    rows = list(csv.DictReader((tmp_path / "out/table2.csv").open()))
    first = [r["row_id"] for r in rows if r["dataset"] == rows[0]["dataset"]]
    assert [r for r in first if r in (*FLOORS, *ROWS)] == list(FLOORS) + ROWS  # the floor first in every block
    assert first[:len(FLOORS)] == list(FLOORS)
    assert [r["kind"] for r in rows[:3]] == ["floor", "floor", "model"] and rows[3]["kind"] == "model"
    labels = {r["row_id"]: r["label"] for r in rows}
    assert labels["compact_15l_mgn"] == "15L+MGN (Alg. 1)" and labels["compact_15l_mgn_authors"] == "15L+MGN (authors' code)"
    assert labels["floor_pixel"] == "Floor (per-pixel prior)" and labels["floor_global"] == "Floor (global prior)"
    md = (tmp_path / "out/table2.md").read_text()
    tex = (tmp_path / "out/table2.tex").read_text()
    assert "| 15L+MGN (Alg. 1) |" in md and "| 15L+MGN (authors' code) |" in md and "authors' public code" in md
    assert "| Floor (per-pixel prior) | fixed | - | 0.300 |" in md                 # its one value, nothing trained
    assert "| 1L | 3 | 3/4/5 (best 1/2/3), plateau | " in md                       # how deep it trained
    assert "eq. (5) on the raw outputs" in md and "the arg-max rule" in md and "extra_metrics.md" in md

    def by_seed(ds: str, m: str, c: str) -> list[float]:
        return [mets[(ds, m, k)][c]["mean"] for k in SEEDS]

    for r in rows:
        ds, rid = r["dataset"], r["row_id"]
        if r["kind"] == "floor":
            assert float(r["mae_de_mean"]) == pytest.approx(mets[(ds, rid)]["mae_de"]["mean"]) and r["n_seeds"] == "0"
            assert r["above_floor"] == "" and r["bold"] == ""
            continue
        if rid not in ROWS:                           # a model registered after the paper's: no run here
            assert r["n_seeds"] in ("0", "") and r["bold"] == "", r
            continue
        assert r["above_floor"] == "yes" and r["below_floor"] == "" and r["not_shown_above_floor"] == ""
        if rid == "combination":
            src = {"mae_de": "gradnorm_segnet", "iou_ss": "gradnorm_segnet", "iou_ls": "polarnet", "iou_bevp": "chen_bev"}
            tms, mvs = [], []
            for k in SEEDS:                           # the combination of each seed's baselines
                terms = [mets[(ds, src["mae_de"], k)]["mae_de"]["mean"]] + [
                    1 - mets[(ds, src[c], k)][c]["mean"] for c in TASK_COLUMNS[1:]]
                tms.append(sum(terms))
                mvs.append(float(np.var(terms)))      # MV of the four means
            assert float(r["tm"]) == pytest.approx(np.mean(tms), abs=1e-12)
            assert float(r["tm_std"]) == pytest.approx(np.std(tms, ddof=1), abs=1e-12)
            assert float(r["mv"]) == pytest.approx(np.mean(mvs), abs=1e-12)
            for c in TASK_COLUMNS:
                assert float(r[f"{c}_mean"]) == pytest.approx(np.mean(by_seed(ds, src[c], c)), abs=1e-12)
            continue
        assert r["epochs_run"] == "3;4;5" and r["best_epoch"] == "1;2;3" and r["stop_reason"] == "plateau;plateau;plateau"
        for c in TASK_COLUMNS:                        # every cell present, equal to the metrics files
            if c in TASKS[rid]:
                assert float(r[f"{c}_mean"]) == pytest.approx(np.mean(by_seed(ds, rid, c)), abs=1e-12)
                assert float(r[f"{c}_std"]) == pytest.approx(np.std(by_seed(ds, rid, c), ddof=1), abs=1e-12)
                assert f"{float(r[f'{c}_mean']):.3f} ± {float(r[f'{c}_std']):.3f}" in md
                assert f"{float(r[f'{c}_mean']):.3f} $\\pm$ {float(r[f'{c}_std']):.3f}" in tex
            else:
                assert r[f"{c}_mean"] == ""
        if len(TASKS[rid]) == 4:                      # TM and MV of each run's four means, over seeds
            assert float(r["tm"]) == pytest.approx(np.mean([mets[(ds, rid, k)]["tm"]["mean"] for k in SEEDS]), abs=1e-12)
            assert float(r["mv"]) == pytest.approx(np.mean([mets[(ds, rid, k)]["mv"]["value"] for k in SEEDS]), abs=1e-12)
    # bold only where the row is above the floor and the interval separates it from the runner-up
    for ds in ("A", "nuscenes"):
        dsr = {r["row_id"]: r for r in rows if r["dataset"] == ds}
        bold = {c: [rid for rid, r in dsr.items() if c in r["bold"].split(";")] for c in
                ("mae_de", "iou_ss", "iou_ls", "iou_bevp", "tm", "mv")}
        assert bold["iou_ls"] == ["polarnet"] and bold["iou_bevp"] == ["chen_bev"] and bold["tm"] == ["combination"]
        assert bold["mae_de"] == [] and bold["iou_ss"] == []           # 15L and both MGN rows are not separated
        for c in ("mae_de", "iou_ss"):
            flagged = [rid for rid, r in dsr.items() if c in r["best_inconclusive"].split(";")]
            assert len(flagged) == 1 and flagged[0] in ("compact_15l", *MGN)
        assert len(bold["mv"]) <= 1
        assert not set(dsr["combination"]["bold"].split(";")) & set(TASK_COLUMNS)   # its task cells are copies
    assert "**" in md and "\\textbf{" in tex and "inconclusive against" in md and "$^\\dagger$" in tex
    assert "| Above floor |" in md and "| yes |" in md
    # without the floor nothing is bold and every best value says why
    plain = build_table2(results, _frames(tmp_path))
    assert not any(r.bold for rs in plain.values() for r in rs)
    assert any("no floor results" in n for rs in plain.values() for r in rs for n in r.notes.values())


def test_table2_bolds_nothing_below_the_floor_and_marks_it(tmp_path: Path) -> None:
    """Every IoU_SS is below the floor's 0.30 but GradNorm's (0.32, not shown above it: inside the
    seeds' spread) and 1L's IoU_LS is below it: no bold in SS, the cells marked; the rest as usual."""
    low = {m: {"iou_ss": 0.20} for m in ("compact_1l", "compact_15l", "compact_15l_mgn", "compact_15l_mgn_authors")}
    bases = bases_with(gradnorm_segnet={"iou_ss": 0.30}, **low)
    bases["compact_1l"]["iou_ls"] = 0.19
    _tree(tmp_path, ("A",), bases=bases, jitter=JITTER)
    rows = {r.row_id: r for r in build_table2(_results(tmp_path, ("A",)), _frames(tmp_path, ("A",)),
                                               floors=_floors(tmp_path, ("A",)))["A"]}
    gn, one = rows["gradnorm_segnet"], rows["compact_1l"]
    assert not any("iou_ss" in r.bold for r in rows.values())
    assert gn.notes["iou_ss"] == "best IoU_SS, not above the floor on SS (not shown above): not bold"
    assert gn.floor["iou_ss"] == "not shown above" and gn.above_floor == "no: SS"
    assert one.floor["iou_ss"] == one.floor["iou_ls"] == "below" and one.above_floor == "no: SS, LS"
    assert rows["polarnet"].bold == {"iou_ls"} and rows["chen_bev"].bold == {"iou_bevp"}
    assert "tm" not in rows["combination"].bold                       # the combination's SS is GradNorm's
    assert rows["combination"].notes["tm"] == "best TM, not above the floor on SS (not shown above): not bold"
    md = table2_markdown({"A": list(rows.values())})
    assert f"{gn.cells['iou_ss'].mean:.3f} ± {gn.cells['iou_ss'].std:.3f}°†" in md
    assert f"{one.cells['iou_ls'].mean:.3f} ± {one.cells['iou_ls'].std:.3f}↓" in md and "| no: SS, LS |" in md
    assert "**below the floor**" in md


def test_column_interval_matches_the_difference_of_means(tmp_path: Path) -> None:
    _tree(tmp_path, ("A",), jitter=JITTER)
    frames = _frames(tmp_path, ("A",))["A"]
    assert len(frames["compact_15l_mgn"]) == 3
    r = column_interval("compact_15l_mgn", "compact_15l", "iou_ls", frames)
    diff = np.mean([df["iou_ls"].mean() for df in frames["compact_15l_mgn"]]) - np.mean(
        [df["iou_ls"].mean() for df in frames["compact_15l"]])
    assert r is not None and r.estimate == pytest.approx(diff) and r.ci_low > 0 and r.n_seeds == (3, 3)
    assert r.paired and r.n_clusters == N_FRAMES // 10 and r.method == "seed-cluster-t"
    comb = column_interval("combination", "compact_15l_mgn_authors", "tm", frames)
    assert comb is not None and comb.ci_low > 0
    assert column_interval("polarnet", "compact_15l", "tm", frames) is None     # PolarNet has no TM


def test_training_text_says_how_deep_and_why_it_stopped() -> None:
    from compact_perception.report.tables.formats import training_text

    one = {"epochs_run": 12, "best_epoch": 8, "stop_reason": "plateau"}
    assert training_text([one, one, one]) == "12 (best 8), plateau"
    mixed = [one, {"epochs_run": 15, "best_epoch": 11, "stop_reason": "plateau"},
             {"epochs_run": 20, "best_epoch": 20, "stop_reason": "max_epochs"}]
    assert training_text(mixed) == "12/15/20 (best 8/11/20), max_epochs x1, plateau x2"
    assert training_text([{"epochs_run": 3, "best_epoch": 2}]) == "3 (best 2)"      # an older summary.json
    assert training_text([one, {"epochs_run": 12, "best_epoch": 8}]) == "12 (best 8), plateau x1"
    assert training_text([]) == ""


def test_table2_missing_model_row_is_na(tmp_path: Path) -> None:
    _tree(tmp_path, ("A",))
    for k in SEEDS:
        (tmp_path / f"results/A/polarnet/seed{k}/metrics.json").unlink()
    tables = build_table2(_results(tmp_path, ("A",)))
    rows = {r.row_id: r for r in tables["A"]}
    assert not rows["polarnet"].available and not rows["combination"].available
    assert rows["combination"].cells["tm"] is None and rows["combination"].cells["mae_de"] is not None
    assert "|  | PolarNet |  |  | n/a | n/a |" in table2_markdown(tables)


def test_bad_metrics_file_names_the_file(tmp_path: Path) -> None:
    p = tmp_path / "metrics.json"
    p.write_text(json.dumps({"mae_de": {"mean": "x", "var": 0.1}}))
    with pytest.raises(ReportInputError, match="metrics.json: mae_de.mean"):
        read_metrics(p)


def test_table3_combination_sums(tmp_path: Path) -> None:
    _tree(tmp_path, ("A",))
    effj = json.loads((tmp_path / "results/benchmark/efficiency.json").read_text())
    rows = {r.row_id: r for r in build_table3(effj)["A"]}
    comb = rows["combination"]
    assert comb.value("params") == comb.value("total_params") == 5000 + 6000 + 7000        # gradnorm, polarnet, chen
    assert comb.value("latency_ms") == pytest.approx(6 + 7 + 8) and comb.value("fps") == pytest.approx(1000 / 21)
    assert rows["compact_1l"].value("total_params") == rows["compact_1l"].value("params") == 1000
    assert rows["compact_15l_mgn_authors"].value("total_params") == 4000 and rows["polarnet"].value("total_params") is None


def test_table3_columns_are_defined_once(tmp_path: Path) -> None:
    """Table III's columns (schema.TABLE3_COLUMNS) are what the reproduced table prints (Markdown
    header, LaTeX column spec, CSV columns), what a paper row may print (paper_numbers.yaml's
    fields, an unknown one refused) and what the comparison and the claims compare."""
    import yaml

    from compact_perception.report.claims import EFFICIENCY_CLAIMS
    from compact_perception.report.paper import PaperNumbersError, parse_paper_numbers
    from compact_perception.report.tables.comparison import TABLE3_COMPARED
    from compact_perception.report.tables.table3 import table3_csv, table3_latex, table3_markdown

    cols = schema.TABLE3_COLUMNS
    _tree(tmp_path, ("A",))
    effj = json.loads((tmp_path / "results/benchmark/efficiency.json").read_text())
    tables = build_table3(effj)
    for gpu in (False, True):
        md = table3_markdown(tables, {**effj, "is_gpu": gpu}).splitlines()
        assert md[0] == "| " + " | ".join(["Dataset", "Model", *(c.header_on(gpu) for c in cols)]) + " |"
        assert md[1].count("---:") == sum(c.kind != "text" for c in cols)
    assert ("GPU memory (MB)" in md[0]) and ("Peak memory, CPU estimate (MB)" not in md[0])
    spec = "ll" + "".join("l" if c.kind == "text" else "r" for c in cols)
    assert "\\begin{tabular}{" + spec + "}" in table3_latex(tables, effj)
    header = table3_csv(tables, effj).splitlines()[0].split(",")
    assert header[4:4 + len(cols)] == [c.key for c in cols]
    # the paper's side: each printed field is a column's, and a row printing another is refused
    data = yaml.safe_load((Path(__file__).resolve().parents[1] / "src/compact_perception/paper_numbers.yaml").read_text())
    printed = {k for g in data["table3"]["groups"].values() for r in g["rows"].values() for k in r}
    assert printed - {"label", "copies", "printed_on"} == {c.paper for c in cols if c.paper}
    data["table3"]["groups"]["simulation"]["rows"]["compact_1l"]["latency_ms"] = 17.5
    with pytest.raises(PaperNumbersError, match=r"rows.compact_1l: unknown key\(s\) \['latency_ms'\]"):
        parse_paper_numbers(data)
    # what is compared: the columns the paper prints, each by its own key
    assert {c.key for c in TABLE3_COMPARED.values()} | set(EFFICIENCY_CLAIMS.values()) <= {c.key for c in cols if c.paper}
    assert list(TABLE3_COMPARED) == ["params", "size_mb", "memory_mb", "fps"]


def test_figures_write_pngs(tmp_path: Path) -> None:
    _tree(tmp_path, ("A",))
    runs = {m: [run_dirs(tmp_path, "A", m, k)[0] for k in SEEDS] for m in MODELS}
    two = plot_loss_weights({"15L+MGN (Alg. 1)": runs["compact_15l_mgn"],
                             "15L+MGN (authors' code)": runs["compact_15l_mgn_authors"]}, tmp_path / "f/w.png")
    assert two.stat().st_size > 0
    assert plot_loss_weights(runs["compact_15l_mgn"][0], tmp_path / "f/w1.png").stat().st_size > 0   # one run
    assert plot_loss_weights(runs["compact_1l"], tmp_path / "f/none.png") is None      # no weight logs
    assert plot_training_curves(runs, tmp_path / "f/c.png").stat().st_size > 0
    ev = {m: run_dirs(tmp_path, "A", m, 0)[2] for m in MODELS}
    inputs = dict(np.load(ev["compact_1l"] / "inputs.npz"))
    preds = {m: dict(np.load(ev[m] / "predictions.npz")) for m in MODELS}
    png = plot_qualitative("A", inputs, preds, tmp_path / "f/q.png", frame=1)
    assert png.read_bytes()[:4] == b"\x89PNG"


def test_build_reports_end_to_end(tmp_path: Path) -> None:
    mets = _tree(tmp_path)
    _stale_run(tmp_path)                                  # seed 9 is not in params: must not count
    rel = build_reports(tmp_path, tmp_path / "reports", datasets=("A", "nuscenes"), models=MODELS,
                        scale_name="default", seeds=SEEDMAP)
    out = tmp_path / "reports"
    for name in ("index.md", "metrics.json", "tables/table2.md", "tables/table3.tex", "tables/paper_vs_reproduced.csv",
                 "figures/report/loss_weights_A.png", "figures/report/curves_nuscenes.png",
                 "figures/report/qualitative_A.png", "plots/val_tm.csv", "plots/loss_weights.csv"):
        assert (out / name).is_file() and name in rel
    index = (out / "index.md").read_text()
    assert "simulated (embedded world)" in index and "simulated nuScenes-format" in index
    assert f"6/2/{N_FRAMES}" in index and "No GPU on this machine" in index
    assert f"Test frames scored per run: Set A {N_FRAMES}, nuScenes {N_FRAMES}." in index
    assert "| 15L+MGN (authors' code) | 0, 1, 2 (3) |" in index and "seed9" not in index
    for link in ("(tables/claims.md)", "(plots/val_tm.csv)", "(plots/loss_weights.csv)", "(metrics.json)"):
        assert link in index
    t2 = {(r["dataset"], r["row_id"]): r for r in csv.DictReader((out / "tables/table2.csv").open())}
    assert float(t2[("A", "compact_1l")]["mae_de_mean"]) == pytest.approx(0.29 / 3, abs=1e-12)   # not seed 9's 5.0
    assert t2[("A", "compact_1l")]["seeds"] == "0;1;2"
    cmp_rows = list(csv.DictReader((out / "tables/paper_vs_reproduced.csv").open()))
    for mgn in MGN:                                       # both MGN forms against the paper's one 15L+MGN row
        a_tm = [r for r in cmp_rows if r["dataset"] == "A" and r["row_id"] == mgn and r["column"] == "tm"]
        assert len(a_tm) == 1 and float(a_tm[0]["paper"]) == 1.393 and a_tm[0]["paper_row"] == "compact_15l_mgn"
        assert float(a_tm[0]["reproduced"]) == pytest.approx(np.mean([mets[("A", mgn, k)]["tm"]["mean"] for k in SEEDS]))
        assert a_tm[0]["n_seeds"] == "3" and float(a_tm[0]["reproduced_std"]) > 0
    comb = [r for r in cmp_rows if r["dataset"] == "nuscenes" and r["row_id"] == "combination" and r["column"] == "tm"]
    assert float(comb[0]["paper"]) == 1.124
    cmp_md = (out / "tables/paper_vs_reproduced.md").read_text()
    assert "15L+MGN (authors' code) (paper: 15L+MGN)" in cmp_md and "mean ± sd over the seeds" in cmp_md
    assert not list(out.glob(".report-*"))
    # the claims scorecard and the metrics beyond the paper's, linked from the index
    for name in ("tables/claims.md", "tables/claims.csv", "tables/extra_metrics.md", "tables/extra_metrics.csv",
                 "tables/extra_metrics_per_class.csv"):
        assert (out / name).is_file() and name in rel
        assert f"({name})" in index
    claims = list(csv.DictReader((out / "tables/claims.csv").open()))
    keys = {(r["claim"], r["dataset"], r["model"]) for r in claims}
    for ds in ("A", "nuscenes"):
        for c in ("mgn-tm", "mgn-mv", "vs-combination", "mgn-weights"):
            assert {(c, ds, m) for m in MGN} <= keys
        assert ("lidar-tm", ds, "compact_15l") in keys
    trained = [r for r in claims if r["verdict"] != "no data" and not r["claim"].startswith("efficiency/")]
    assert {r["n_seeds"] for r in trained} == {"3"}
    assert {r["n_seeds"] for r in claims if r["claim"].startswith("efficiency/")} == {""}   # measurements
    assert "Verdict rule" in index and "reproduced" in (out / "tables/claims.md").read_text()
    extra = list(csv.DictReader((out / "tables/extra_metrics.csv").open()))
    mgn = [r for r in extra if r["dataset"] == "A" and r["row_id"] == "compact_15l_mgn_authors"][0]
    assert float(mgn["miou_ss"]) == 0.5 and float(mgn["rmse_m_mean"]) == 12.5 and mgn["miou_ls"] == ""
    assert mgn["n_seeds"] == "3" and float(mgn["rmse_m_std"]) == 0.0 and float(mgn["rmse_m_var"]) == 4.0
    per_class = list(csv.DictReader((out / "tables/extra_metrics_per_class.csv").open()))
    water = [r for r in per_class if r["class"] == "water"]
    assert water and all(r["iou"] == "" for r in water)        # absent class: no IoU
    header = (out / "tables/table2.csv").read_text().splitlines()[0].split(",")
    assert header[:10] == ["dataset", "row_id", "label", "available", "n_seeds", "seeds", "n_test_frames",
                           "mae_de_mean", "mae_de_std", "mae_de_var"]
    # the arg-max rule beside eq. (5): the fixture's arg-max IoUs are ARGMAX_GAIN above, by hand
    gn = [r for r in extra if r["dataset"] == "A" and r["row_id"] == "gradnorm_segnet"][0]
    want = np.mean([mets[("A", "gradnorm_segnet", k)]["iou_ss"]["mean"] for k in SEEDS]) + ARGMAX_GAIN
    assert float(gn["iou_ss_argmax_mean"]) == pytest.approx(want, abs=1e-9) and gn["iou_ls_argmax_mean"] == ""
    pn = [r for r in extra if r["dataset"] == "A" and r["row_id"] == "polarnet"][0]
    assert float(pn["iou_ls_argmax_mean"]) == pytest.approx(0.90 + np.mean([-0.01, 0.0, 0.02]) + ARGMAX_GAIN)
    assert [r["row_id"] for r in extra[:2]] == list(FLOORS) and extra[0]["fixed"] == "1"
    extra_md = (out / "tables/extra_metrics.md").read_text()
    assert "IoU_SS (arg-max) (mean ± sd)" in extra_md and "**arg-max rule**" in extra_md


def test_headline_and_the_floor_in_the_index(tmp_path: Path) -> None:
    """reports/metrics.json holds at most 20 numbers: the verdict counts over the decidable rows,
    the exact counts apart, set A's compact models' TM margins over the floor (by hand: floor TM
    2.50 minus the model's), TM of 15L+MGN (authors' code); the index says it in words."""
    mets = _tree(tmp_path)
    build_reports(tmp_path, tmp_path / "reports", datasets=("A", "nuscenes"), models=MODELS, scale_name="default",
                  seeds=SEEDMAP)
    out = tmp_path / "reports"
    index = (out / "index.md").read_text()
    claims = list(csv.DictReader((out / "tables/claims.csv").open()))
    head = json.loads((out / "metrics.json").read_text())
    assert HEADLINE_MODEL == "compact_15l_mgn_authors"
    assert list(head) == ["claims", "exact_counts", "tm_margin_A", HEADLINE_KEY]
    assert sum(len(v) for v in head.values()) <= 20
    for ds in ("A", "nuscenes"):
        want = np.mean([mets[(ds, HEADLINE_MODEL, k)]["tm"]["mean"] for k in SEEDS])
        assert head[HEADLINE_KEY][ds] == round(want, 4)
    judged = [r for r in claims if not r["claim"].startswith("efficiency/")]
    assert head["claims"] == {v.replace(" ", "_"): sum(r["verdict"] == v for r in judged)
                              for v in ("reproduced", "contradicted", "inconclusive", "not decidable")}
    assert sum(head["exact_counts"].values()) == len(claims) - len(judged) == 8
    floor_tm = 0.30 + 3 - 0.30 - 0.20 - 0.30                                    # report_fixture FLOOR_BASES
    for m in COMPACT:
        tm = np.mean([mets[("A", m, k)]["tm"]["mean"] for k in SEEDS])
        assert head["tm_margin_A"][m] == pytest.approx(round(floor_tm - tm, 4), abs=1e-9)
    # the index: the headline in words, one sentence per dataset on the floor
    assert "## Above the floor" in index and "Set A (floor TM 2.500 (Floor (per-pixel prior))): above the floor " \
        "on every task it performs: Chen et al., PolarNet, GradNorm, 1L, 15L, 15L+MGN (Alg. 1), 15L+MGN " \
        "(authors' code)." in index
    assert "`tm_margin_A`: TM margin over the floor on Set A" in index
    assert "**Method and measured coverage**: intervals: seed-cluster-t" in index
    counts = head["claims"]
    assert (f"that this run can decide (every model compared above the trivial-predictor floor on the claim's metrics, "
            f"at least 3 seeds a side): {counts['reproduced']} reproduced, {counts['contradicted']} contradicted, "
            f"{counts['inconclusive']} inconclusive; {counts['not_decidable']} not decidable") in index


def test_index_says_whether_each_baseline_was_trained_long_enough_to_judge(tmp_path: Path) -> None:
    """The floor section's last line, per baseline, from its runs' stop_reason and its gate: trained
    to a plateau and above the floor (it learns); stopped by the cap while below the floor
    (undecided: a capped run says nothing about whether the network can learn)."""
    plateau, capped = tmp_path / "plateau", tmp_path / "capped"
    _tree(plateau, ("A",))
    build_reports(plateau, plateau / "reports", datasets=("A",), models=MODELS, scale_name="full", seeds=SEEDMAP)
    index = (plateau / "reports/index.md").read_text()
    for label in ("Chen et al.", "PolarNet", "GradNorm"):
        assert f"{label}: Set A: trained to a plateau and above the floor: it learns" in index
    _tree(capped, ("A",), stop_reason="max_epochs", bases=bases_with(polarnet={"iou_ls": 0.0}))
    build_reports(capped, capped / "reports", datasets=("A",), models=MODELS, scale_name="default", seeds=SEEDMAP)
    index = (capped / "reports/index.md").read_text()
    epochs = "/".join(str(e) for e in sorted({n_epochs("polarnet", k) for k in SEEDS}))
    assert (f"PolarNet: Set A: stopped by its epoch cap after {epochs} epochs, not trained to a plateau, below the "
            "floor on LS: undecided whether it can learn.") in index
    assert f"Chen et al.: Set A: stopped by its epoch cap after {epochs} epochs, not trained to a plateau, above the " \
        "floor." in index
    assert "[docs/results.md](../docs/results.md#do-the-baselines-learn)" in index


def test_plots_csv_one_row_per_run_and_epoch(tmp_path: Path) -> None:
    _tree(tmp_path, ("A", "nuscenes"), baseline_seeds=(0,))
    _stale_run(tmp_path, "nuscenes", "compact_15l_mgn")
    seeds = seed_map(SEEDS, (0,))
    paths = write_plot_data(tmp_path, ("A", "nuscenes"), MODELS, tmp_path / "plots", seeds)
    assert [p.name for p in paths] == ["val_tm.csv", "loss_weights.csv"]
    val = list(csv.DictReader((tmp_path / "plots/val_tm.csv").open()))
    assert list(val[0]) == ["epoch", "run", "val_tm"]
    want = {(f"{ds}/{m}/seed{k}", e) for ds in ("A", "nuscenes") for m in MODELS for k in seeds[m]
            for e in range(n_epochs(m, k))}
    got = [(r["run"], int(r["epoch"])) for r in val]
    assert len(got) == len(set(got)) and set(got) == want          # every run, every epoch, once
    assert {r.split("/")[1] for r, _ in got} == set(MODELS)
    assert float(next(r["val_tm"] for r in val if r["run"] == "A/compact_1l/seed2" and r["epoch"] == "1")) == \
        pytest.approx(1.5 - 0.1 + 0.02)
    w = list(csv.DictReader((tmp_path / "plots/loss_weights.csv").open()))
    assert list(w[0]) == ["epoch", "run", "task", "weight"]
    want_w = {(f"{ds}/{m}/seed{k}", t, e) for ds in ("A", "nuscenes") for m in MGN for k in SEEDS
              for t in ("de", "ss", "ls", "bevp") for e in range(n_epochs(m, k))}
    got_w = [(r["run"], r["task"], int(r["epoch"])) for r in w]
    assert len(got_w) == len(set(got_w)) and set(got_w) == want_w
    assert not any("seed9" in r for r, _ in got)
    # seed lists per dataset ({ds: {model: seeds}}, params.seeds_of(group, dataset)): set A at seed 0 only
    per_ds = {"A": seed_map((0,), (0,)), "nuscenes": seeds}
    write_plot_data(tmp_path, ("A", "nuscenes"), MODELS, tmp_path / "plots2", per_ds)
    runs2 = {r["run"] for r in csv.DictReader((tmp_path / "plots2/val_tm.csv").open())}
    assert {r for r in runs2 if r.startswith("A/")} == {f"A/{m}/seed0" for m in MODELS}
    assert {r for r in runs2 if r.startswith("nuscenes/")} == {r for r, _ in got if r.startswith("nuscenes/")}


@pytest.mark.parametrize("name,template,y,extra", [("val_tm.csv", "by_run", "val_tm", None),
                                                   ("loss_weights.csv", "weights_by_run", "weight", "task")])
def test_dvc_plot_templates_render_the_csv(tmp_path: Path, name: str, template: str, y: str, extra) -> None:
    """The custom templates in .dvc/plots/ (DVC anchors, colour by run) fill with the CSV rows as
    dvc's renderer does (`dvc plots show`; dvc.yaml: {template: <name>, x: epoch, y: <y>})."""
    from dvc_render import VegaRenderer

    root = Path(__file__).resolve().parents[1]
    text = (root / ".dvc/plots" / f"{template}.json").read_text()
    for anchor in ("<DVC_METRIC_DATA>", "<DVC_METRIC_X>", "<DVC_METRIC_Y>"):
        assert anchor in text
    _tree(tmp_path, ("A",), baseline_seeds=(0,))
    write_plot_data(tmp_path, ("A",), MODELS, tmp_path / "plots", seed_map(SEEDS, (0,)))
    rows = [{**r, "rev": "workspace"} for r in csv.DictReader((tmp_path / "plots" / name).open())]
    spec = VegaRenderer(rows, name, template=template, template_dir=str(root / ".dvc/plots"), x="epoch",
                        y=y).get_filled_template()
    assert spec["data"]["values"] == rows and "<DVC_METRIC" not in json.dumps(spec)
    enc = spec["encoding"]
    assert enc["x"]["field"] == "epoch" and enc["y"]["field"] == y and enc["color"]["field"] == "run"
    if extra:
        assert enc["strokeDash"]["field"] == extra


def test_read_metrics_mv_shapes(tmp_path: Path) -> None:
    """MV as evaluate writes it ({"value", "definition"}), and the older shapes."""
    p = tmp_path / "metrics.json"
    base = {"mae_de": {"mean": 0.1, "var": 0.0}}
    for mv, want in (({"value": 0.027, "definition": "eq. 7"}, 0.027), ({"mean": 0.03, "var": 0.001}, 0.03), (0.02, 0.02)):
        p.write_text(json.dumps({**base, "mv": mv}))
        assert read_metrics(p).scores["mv"].mean == want
    p.write_text(json.dumps({**base, "mv": {"value": "x"}}))
    with pytest.raises(ReportInputError, match="metrics.json: mv.value"):
        read_metrics(p)
    p.write_text(json.dumps({**base, "depth": [1, 2]}))
    with pytest.raises(ReportInputError, match="metrics.json: depth"):
        read_metrics(p)


def test_table2_mv_is_the_mv_of_the_means_for_every_row(tmp_path: Path) -> None:
    """An older metrics file holding the mean of a per-frame MV still shows eq. 7 of the means."""
    mets = _tree(tmp_path, ("A",), seeds=(0,), baseline_seeds=(0,))
    stale = dict(mets[("A", "compact_1l", 0)])
    stale["mv"] = {"mean": 0.5, "var": 0.01}
    write_json(run_dirs(tmp_path, "A", "compact_1l", 0)[1], stale)
    rows = {r.row_id: r for r in build_table2(_results(tmp_path, ("A",), seed_map((0,), (0,))))["A"]}
    means = {c: stale[c]["mean"] for c in TASK_COLUMNS}
    assert rows["compact_1l"].cells["mv"].mean == pytest.approx(scores_from_means(means)["mv"], abs=1e-15)
    assert rows["compact_1l"].cells["tm"].mean == pytest.approx(scores_from_means(means)["tm"], abs=1e-15)


# ----------------------------------------------------------------------------- what the params selected
def test_report_of_a_subset_shows_no_number_of_an_unselected_dataset_or_model(tmp_path: Path) -> None:
    """sim_ids [A], dataset_ids [A] and two models (the README's way to run a subset): results/ still
    holds set B's and nuScenes' files of an earlier full run (as git tracks them), with scores no set A
    run has; none of them, and no unselected model, reaches a table, a figure, the plots or the headline."""
    import yaml

    from pipeline import report as report_stage
    from repo_params import repo_params_dict

    _tree(tmp_path, ("A",))
    stale = bases_with(**{m: {"mae_de": 0.0777, "iou_ss": 0.7777, "iou_ls": 0.7777, "iou_bevp": 0.7777}
                          for m in MODELS})                  # 0.7777: a number only the other run's files hold
    build_tree(tmp_path, ("B", "nuscenes"), n_frames=N_FRAMES, bases=stale, noise=0.0)
    _tree(tmp_path, ("A",))                                  # efficiency.json as the benchmark writes it, ...
    eff_path = tmp_path / "results/benchmark/efficiency.json"
    effj = json.loads(eff_path.read_text())
    effj["models"]["nuscenes"] = {m: dict(v, params=777_777) for m, v in effj["models"]["A"].items()}
    write_json(eff_path, effj)                               # ... with nuScenes' networks measured too
    chosen = ["compact_15l_mgn_authors", "compact_1l"]
    d = repo_params_dict()
    d.update(sim_ids=["A"], dataset_ids=["A"], model_ids=chosen)
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump(d))
    report_stage.main(["--params", str(params), "--root", str(tmp_path), "--out", str(tmp_path / "reports")])
    out = tmp_path / "reports"
    head = json.loads((out / "metrics.json").read_text())
    assert list(head["tm_mgn_authors"]) == ["A"]             # the headline: set A only
    assert set(head.get("tm_margin_A", {})) <= set(chosen)
    files = [p for p in out.rglob("*") if p.is_file()]
    assert files and not [p for p in files if "nuscenes" in p.name or "_B." in p.name]
    for p in files:
        if p.suffix in (".md", ".csv", ".tex", ".json"):
            text = p.read_text()
            assert "0.7777" not in text and "0.777" not in text and "777,777" not in text and "777777" not in text, p
    index = (out / "index.md").read_text()
    for label in ("nuScenes", "Set B", "Set C"):               # no row, no figure section, no headline entry
        assert not [line for line in index.splitlines() if line.startswith((f"| {label}", f"### {label}"))], label
        assert f"{label} 0." not in index and f"{label} (floor" not in index
    t2 = list(csv.DictReader((out / "tables/table2.csv").open()))
    assert {r["dataset"] for r in t2} == {"A"}
    assert {r["row_id"] for r in t2 if r["available"] in ("1", "True", "true")} <= {*chosen, *FLOORS}
    runs = {r["run"] for r in csv.DictReader((out / "plots/val_tm.csv").open())}
    assert runs and {r.split("/")[0] for r in runs} == {"A"} and {r.split("/")[1] for r in runs} <= set(chosen)
    t3 = list(csv.DictReader((out / "tables/table3.csv").open()))
    assert t3 and {r.get("dataset") or r.get("Dataset") for r in t3} <= {"A", "Set A"}


def test_a_full_disk_while_the_report_writes_is_one_line_and_keeps_the_last_report(tmp_path: Path,
                                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """OSError [Errno 28] from report/tables/formats.py was a traceback; now one line naming the
    file, exit status 1, and the previous report is left as it was (the report is built aside)."""
    import errno

    import yaml

    from compact_perception.report.tables import formats
    from pipeline import report as report_stage
    from repo_params import repo_params_dict

    _tree(tmp_path, ("A",))
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump(repo_params_dict()))
    argv = ["--params", str(params), "--root", str(tmp_path), "--out", str(tmp_path / "reports")]
    report_stage.main(argv)
    before = {p: p.read_bytes() for p in (tmp_path / "reports").rglob("*") if p.is_file()}

    def full(path, text):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(formats.io, "write_text", full)
    with pytest.raises(SystemExit) as exc:
        report_stage.main(argv)
    msg = exc.value.code
    assert isinstance(msg, str) and msg.startswith("error: ") and "\n" not in msg
    assert msg.endswith("table2.md: could not write (No space left on device)"), msg
    after = {p: p.read_bytes() for p in (tmp_path / "reports").rglob("*") if p.is_file()}
    assert after == before and not list((tmp_path / "reports").glob(".report-*"))
