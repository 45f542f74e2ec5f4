"""Reports: paper numbers, efficiency measurement, Table II/III, paper-vs-reproduced, figures."""
from __future__ import annotations

import csv
import json
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from torch import nn

from compact_perception import io
from compact_perception.evaluate import summarise
from compact_perception.metrics import scores_from_means
from compact_perception.report import efficiency as eff
from compact_perception.report.collect import ReportInputError, load_results, read_metrics
from compact_perception.report.figures import plot_loss_weights, plot_qualitative, plot_training_curves
from compact_perception.report.index import build_reports
from compact_perception.report.collect import load_row_frames
from compact_perception.report.paper import DATASETS, ROW_IDS, TASK_COLUMNS, load_paper_numbers
from compact_perception.report.tables import build_table2, build_table3, column_bootstrap, write_table2

MODELS = ("compact_1l", "compact_15l", "compact_15l_mgn", "gradnorm_segnet", "polarnet", "chen_bev")
TASKS = {
    "compact_1l": TASK_COLUMNS, "compact_15l": TASK_COLUMNS, "compact_15l_mgn": TASK_COLUMNS,
    "gradnorm_segnet": ("mae_de", "iou_ss"), "polarnet": ("iou_ls",), "chen_bev": ("iou_bevp",),
}


# ----------------------------------------------------------------------------- paper numbers
def test_paper_numbers_complete_and_self_consistent() -> None:
    p = load_paper_numbers()
    assert set(p.table2) == set(DATASETS)
    for ds in DATASETS:
        rows = p.table2[ds]
        assert set(rows) == set(ROW_IDS)
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
        assert sum(r.params * r.copies for r in parts) == rows3["combination"].total_params
        assert sum(r.size_mb * r.copies for r in parts) == pytest.approx(rows3["combination"].total_size_mb, abs=1e-6)
    assert p.table3["simulation"]["compact_15l"].params == 2521504 and p.table3_device == "NVIDIA GTX 1080 Ti"


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
#: Mean score per model and column of the fake test sets: IoU_LS (PolarNet), IoU_BEVP (Chen)
#: and TM (the combination, 1.1 against 15L+MGN's 1.24) have clear winners; MAE_DE and IoU_SS
#: of 15L and 15L+MGN are equal (the best is not separated from the runner-up).
BASES: dict[str, dict[str, float]] = {
    "chen_bev": {"iou_bevp": 0.70},
    "polarnet": {"iou_ls": 0.90},
    "gradnorm_segnet": {"mae_de": 0.20, "iou_ss": 0.50},
    "compact_1l": {"mae_de": 0.10, "iou_ss": 0.60, "iou_ls": 0.40, "iou_bevp": 0.50},
    "compact_15l": {"mae_de": 0.09, "iou_ss": 0.65, "iou_ls": 0.50, "iou_bevp": 0.55},
    "compact_15l_mgn": {"mae_de": 0.09, "iou_ss": 0.65, "iou_ls": 0.60, "iou_bevp": 0.60},
}
N_FRAMES = 30


def _per_frame(ds: str, model: str) -> pd.DataFrame:
    """Per-frame scores: shared frame difficulty + the model's base + its own noise."""
    seed = sum(map(ord, ds)) * 100 + MODELS.index(model)
    rng = np.random.default_rng(seed)
    difficulty = np.random.default_rng(sum(map(ord, ds))).normal(0, 0.03, N_FRAMES)
    df = pd.DataFrame({"frame_id": [f"f{i:03d}" for i in range(N_FRAMES)]})
    for c in TASKS[model]:
        sign = 1.0 if c == "mae_de" else -1.0
        df[c] = BASES[model][c] + sign * difficulty + rng.normal(0, 0.01, N_FRAMES)
    if len(TASKS[model]) == 4:
        df["tm"] = df["mae_de"] + 3 - df["iou_ss"] - df["iou_ls"] - df["iou_bevp"]
    return df


def _metrics(ds: str, model: str, frames: pd.DataFrame) -> dict:
    out: dict = dict(summarise(frames))
    if "iou_ss" in TASKS[model]:
        out["class_iou"] = {"ss": {"miou": 0.5, "n_classes_in_miou": 2, "classes": {"road": 0.75, "sky": 0.25,
                                                                                     "water": None}},
                            "definition": "test"}
    if "mae_de" in TASKS[model]:
        out["depth"] = {"abs_rel": {"mean": 0.25, "var": 0.01}, "rmse_m": {"mean": 12.5, "var": 4.0},
                        "delta_1.25": {"mean": 0.6, "var": 0.02}, "n_frames": N_FRAMES, "definition": "test"}
    out.update(n_frames=N_FRAMES, source="simulated (embedded world)" if ds != "nuscenes" else "simulated nuScenes-format",
               device="CPU")
    return out


def _tsv(path: Path, name: str, values: list[float]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    rows = "".join(f"{1700000000 + i}\t{i}\t{v}\n" for i, v in enumerate(values))
    path.write_text(f"timestamp\tstep\t{name}\n" + rows)


def _fake_tree(root: Path, datasets: tuple[str, ...] = ("A", "nuscenes"), S: int = 8) -> dict:
    all_metrics: dict = {}
    for ds in datasets:
        n_cls, n_bev, dvs = (32, 32, False) if ds == "nuscenes" else (23, 9, True)
        io.write_json(root / "data/cache" / ds / "meta.json",
                      {"counts": {"train": 6, "val": 2, "test": 2}, "resolution": S, "has_dvs": dvs, "source": "sim"})
        rng = np.random.default_rng(0)
        for k, m in enumerate(MODELS):
            frames = _per_frame(ds, m)
            met = _metrics(ds, m, frames)
            all_metrics[(ds, m)] = met
            io.write_json(root / "results" / ds / m / "metrics.json", met)
            io.write_text(root / "data/eval" / ds / m / "per_frame.csv", frames.to_csv(index=False, float_format="%.6f"))
            run = root / "runs" / ds / m
            metrics_dir = run / "live/plots/metrics"
            _tsv(metrics_dir / "val_score.tsv", "val_score", [1.5, 1.3, 1.2])
            if m == "compact_15l_mgn":
                for w, vals in {"w_de": [1, 1.3, 1.5], "w_ss": [1, 0.9, 0.8], "w_ls": [1, 1.1, 1.2],
                                "w_bevp": [1, 0.7, 0.5]}.items():
                    _tsv(metrics_dir / f"{w}.tsv", w, vals)
            io.write_json(run / "summary.json", {"best_epoch": 1, "epochs_run": 3, "train_seconds": 1.0,
                                                 "final_weights": {"w_de": 1.5, "w_ss": 0.8, "w_ls": 1.2, "w_bevp": 0.5}})
            preds: dict = {"frame_ids": np.array(["f0", "f1"])}
            if "de" in "".join(TASKS[m]):
                preds["de"] = rng.random((2, 4, 1, S, S)).astype(np.float16)
            if "iou_ss" in TASKS[m]:
                preds["ss"] = rng.integers(0, n_cls, (2, 4, S, S)).astype(np.uint8)
            if "iou_ls" in TASKS[m]:
                preds["ls"] = rng.integers(0, n_cls, (2, S, S)).astype(np.uint8)
            if "iou_bevp" in TASKS[m]:
                preds["bevp"] = (rng.random((2, n_bev, S, S)) > 0.5).astype(np.uint8)
            io.write_npz(root / "data/eval" / ds / m / "predictions.npz", preds)
        inputs = {"frame_ids": np.array(["f0", "f1"]), "rgb": rng.integers(0, 255, (2, 4, 3, S, S)).astype(np.uint8),
                  "lidar": rng.random((2, 15, S, S)).astype(np.float16),
                  "gt_de": rng.random((2, 4, 1, S, S)).astype(np.float16),
                  "gt_ss": rng.integers(0, n_cls, (2, 4, S, S)).astype(np.uint8),
                  "gt_ls": np.full((2, S, S), 255, np.uint8),
                  "gt_bevp": (rng.random((2, n_bev, S, S)) > 0.5).astype(np.uint8)}
        if dvs:
            inputs["dvs"] = rng.integers(0, 3, (2, 4, 2, S, S)).astype(np.uint8)
        io.write_npz(root / "data/eval" / ds / "compact_1l/inputs.npz", inputs)
    effj = {"device": "CPU (2 threads)", "is_gpu": False, "resolution": S, "warmup": 1, "runs": 3,
            "memory_method": "hooks", "models": {}}
    for ds in datasets:
        effj["models"][ds] = {m: {"params": 1000 * (k + 1), "size_mb": 0.5 * (k + 1), "peak_memory_mb": 10.0 + k,
                                  "fps": 1000.0 / (2.0 + k), "latency_ms": 2.0 + k, "device": "CPU (2 threads)"}
                              for k, m in enumerate(MODELS)}
    io.write_json(root / "results/benchmark/efficiency.json", effj)
    return all_metrics


def _frames(root: Path, datasets: tuple[str, ...] = ("A", "nuscenes")) -> dict:
    return {ds: load_row_frames(root, ds, MODELS) for ds in datasets}


def test_table2_numbers_bold_and_combination(tmp_path: Path) -> None:
    mets = _fake_tree(tmp_path)
    results = load_results(tmp_path / "results", ["A", "nuscenes"], MODELS)
    frames = _frames(tmp_path)
    paths = write_table2(results, tmp_path / "out", frames)
    assert sorted(p.name for p in paths) == ["table2.csv", "table2.md", "table2.tex"] and all(p.is_file() for p in paths)
    rows = list(csv.DictReader((tmp_path / "out/table2.csv").open()))
    assert [r["row_id"] for r in rows[:7]] == ["chen_bev", "polarnet", "gradnorm_segnet", "combination",
                                               "compact_1l", "compact_15l", "compact_15l_mgn"]
    md = (tmp_path / "out/table2.md").read_text()
    tex = (tmp_path / "out/table2.tex").read_text()
    for r in rows:
        ds, rid = r["dataset"], r["row_id"]
        if rid == "combination":
            src = {"mae_de": "gradnorm_segnet", "iou_ss": "gradnorm_segnet", "iou_ls": "polarnet", "iou_bevp": "chen_bev"}
            vals = [mets[(ds, src[c])][c]["mean"] for c in TASK_COLUMNS]
            terms = [vals[0]] + [1 - v for v in vals[1:]]
            assert float(r["tm"]) == pytest.approx(sum(terms), abs=1e-12)
            assert float(r["mv"]) == pytest.approx(float(np.var(terms)), abs=1e-12)   # MV of the four means
            for c, v in zip(TASK_COLUMNS, vals):
                assert float(r[f"{c}_mean"]) == v
            continue
        met = mets[(ds, rid)]
        for c in TASK_COLUMNS:                        # every cell present, equal to the metrics file
            if c in TASKS[rid]:
                assert float(r[f"{c}_mean"]) == met[c]["mean"] and float(r[f"{c}_var"]) == met[c]["var"]
                assert f"{met[c]['mean']:.3f} ±" in md and f"{met[c]['mean']:.3f} $\\pm$" in tex
            else:
                assert r[f"{c}_mean"] == ""
        if len(TASKS[rid]) == 4:
            # a compact row: TM and MV of its four means, computed like the combination's
            means = {c: met[c]["mean"] for c in TASK_COLUMNS}
            terms = [means["mae_de"]] + [1 - means[c] for c in TASK_COLUMNS[1:]]
            assert float(r["tm"]) == met["tm"]["mean"] == pytest.approx(sum(terms), abs=1e-12)
            assert float(r["mv"]) == met["mv"]["value"] == pytest.approx(float(np.var(terms)), abs=1e-12)
    # bold only where the bootstrap separates the best from the runner-up
    for ds in ("A", "nuscenes"):
        dsr = {r["row_id"]: r for r in rows if r["dataset"] == ds}
        bold = {c: [rid for rid, r in dsr.items() if c in r["bold"].split(";")] for c in
                ("mae_de", "iou_ss", "iou_ls", "iou_bevp", "tm", "mv")}
        assert bold["iou_ls"] == ["polarnet"] and bold["iou_bevp"] == ["chen_bev"] and bold["tm"] == ["combination"]
        assert bold["mae_de"] == [] and bold["iou_ss"] == []           # 15L and 15L+MGN are not separated
        for c in ("mae_de", "iou_ss"):
            flagged = [rid for rid, r in dsr.items() if c in r["best_inconclusive"].split(";")]
            assert len(flagged) == 1 and flagged[0] in ("compact_15l", "compact_15l_mgn")
        assert len(bold["mv"]) <= 1
        # the combination's task cells are copies: never bold, never compared
        assert dsr["combination"]["bold"] in ("", "tm", "mv", "tm;mv")
    assert "**" in md and "\\textbf{" in tex and "inconclusive against" in md and "$^\\dagger$" in tex
    # without per-frame scores nothing is bold and every best value says why
    plain = build_table2(results)
    assert not any(r.bold for rs in plain.values() for r in rs if len([x for x in rs if x.available]) > 1)
    assert any("no per-frame scores" in n for rs in plain.values() for r in rs for n in r.notes.values())


def test_column_bootstrap_matches_direct_bootstrap(tmp_path: Path) -> None:
    _fake_tree(tmp_path, ("A",))
    frames = _frames(tmp_path, ("A",))["A"]
    r = column_bootstrap("compact_15l_mgn", "compact_15l", "iou_ls", frames)
    diff = frames["compact_15l_mgn"][0]["iou_ls"].mean() - frames["compact_15l"][0]["iou_ls"].mean()
    assert r is not None and r.estimate == pytest.approx(diff) and r.ci_low > 0
    comb = column_bootstrap("combination", "compact_15l_mgn", "tm", frames)
    assert comb is not None and comb.ci_low > 0
    assert column_bootstrap("polarnet", "compact_15l", "tm", frames) is None     # PolarNet has no TM


def test_table2_missing_model_row_is_na(tmp_path: Path) -> None:
    _fake_tree(tmp_path, ("A",))
    (tmp_path / "results/A/polarnet/metrics.json").unlink()
    tables = build_table2(load_results(tmp_path / "results", ["A"], MODELS))
    rows = {r.row_id: r for r in tables["A"]}
    assert not rows["polarnet"].available and not rows["combination"].available
    assert rows["combination"].cells["tm"] is None and rows["combination"].cells["mae_de"] is not None


def test_bad_metrics_file_names_the_file(tmp_path: Path) -> None:
    p = tmp_path / "metrics.json"
    p.write_text(json.dumps({"mae_de": {"mean": "x", "var": 0.1}}))
    with pytest.raises(ReportInputError, match="metrics.json: mae_de.mean"):
        read_metrics(p)


def test_table3_combination_sums(tmp_path: Path) -> None:
    _fake_tree(tmp_path, ("A",))
    effj = json.loads((tmp_path / "results/benchmark/efficiency.json").read_text())
    rows = {r.row_id: r for r in build_table3(effj)["A"]}
    comb = rows["combination"]
    assert comb.params == comb.total_params == 4000 + 5000 + 6000        # gradnorm, polarnet, chen
    assert comb.latency_ms == pytest.approx(5 + 6 + 7) and comb.fps == pytest.approx(1000 / 18)
    assert rows["compact_1l"].total_params == rows["compact_1l"].params == 1000
    assert rows["polarnet"].total_params is None


def test_figures_write_pngs(tmp_path: Path) -> None:
    _fake_tree(tmp_path, ("A",))
    run = tmp_path / "runs/A"
    assert plot_loss_weights(run / "compact_15l_mgn", tmp_path / "f/w.png").stat().st_size > 0
    assert plot_loss_weights(run / "compact_1l", tmp_path / "f/none.png") is None      # no weight logs
    assert plot_training_curves({m: run / m for m in MODELS}, tmp_path / "f/c.png").stat().st_size > 0
    inputs = dict(np.load(tmp_path / "data/eval/A/compact_1l/inputs.npz"))
    preds = {m: dict(np.load(tmp_path / "data/eval/A" / m / "predictions.npz")) for m in MODELS}
    png = plot_qualitative("A", inputs, preds, tmp_path / "f/q.png", frame=1)
    assert png.read_bytes()[:4] == b"\x89PNG"


def test_build_reports_end_to_end(tmp_path: Path) -> None:
    _fake_tree(tmp_path)
    rel = build_reports(tmp_path, tmp_path / "reports", datasets=("A", "nuscenes"), models=MODELS, scale_name="default")
    out = tmp_path / "reports"
    for name in ("index.md", "tables/table2.md", "tables/table3.tex", "tables/paper_vs_reproduced.csv",
                 "figures/report/loss_weights_A.png", "figures/report/curves_nuscenes.png",
                 "figures/report/qualitative_A.png"):
        assert (out / name).is_file() and name in rel
    index = (out / "index.md").read_text()
    assert "simulated (embedded world)" in index and "simulated nuScenes-format" in index
    assert "6/2/2" in index and "No GPU on this machine" in index
    cmp_rows = list(csv.DictReader((out / "tables/paper_vs_reproduced.csv").open()))
    a_mgn_tm = [r for r in cmp_rows if r["dataset"] == "A" and r["row_id"] == "compact_15l_mgn" and r["column"] == "tm"]
    assert len(a_mgn_tm) == 1 and float(a_mgn_tm[0]["paper"]) == 1.393 and a_mgn_tm[0]["reproduced"] != ""
    comb = [r for r in cmp_rows if r["dataset"] == "nuscenes" and r["row_id"] == "combination" and r["column"] == "tm"]
    assert float(comb[0]["paper"]) == 1.124
    assert not list(out.glob(".report-*"))
    # the claims scorecard and the metrics beyond the paper's, linked from the index
    for name in ("tables/claims.md", "tables/claims.csv", "tables/extra_metrics.md", "tables/extra_metrics.csv",
                 "tables/extra_metrics_per_class.csv"):
        assert (out / name).is_file() and name in rel
        assert f"({name})" in index
    claims = list(csv.DictReader((out / "tables/claims.csv").open()))
    assert {(r["claim"], r["dataset"]) for r in claims} >= {(c, ds) for ds in ("A", "nuscenes") for c in
                                                            ("lidar-tm", "mgn-tm", "mgn-mv", "vs-combination", "mgn-weights")}
    assert "Verdict rule" in index and "reproduced" in (out / "tables/claims.md").read_text()
    extra = list(csv.DictReader((out / "tables/extra_metrics.csv").open()))
    mgn = [r for r in extra if r["dataset"] == "A" and r["row_id"] == "compact_15l_mgn"][0]
    assert float(mgn["miou_ss"]) == 0.5 and float(mgn["rmse_m_mean"]) == 12.5 and mgn["miou_ls"] == ""
    per_class = list(csv.DictReader((out / "tables/extra_metrics_per_class.csv").open()))
    water = [r for r in per_class if r["class"] == "water"]
    assert water and all(r["iou"] == "" for r in water)        # absent class: no IoU
    # Table II's columns are unchanged
    header = (out / "tables/table2.csv").read_text().splitlines()[0].split(",")
    assert header[:15] == ["dataset", "row_id", "label", "available"] + [f"{c}_{k}" for c in TASK_COLUMNS
                                                                        for k in ("mean", "var")] + ["tm", "mv", "bold"]


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
    mets = _fake_tree(tmp_path, ("A",))
    stale = dict(mets[("A", "compact_1l")])
    stale["mv"] = {"mean": 0.5, "var": 0.01}
    io.write_json(tmp_path / "results/A/compact_1l/metrics.json", stale)
    rows = {r.row_id: r for r in build_table2(load_results(tmp_path / "results", ["A"], MODELS))["A"]}
    means = {c: stale[c]["mean"] for c in TASK_COLUMNS}
    assert rows["compact_1l"].cells["mv"].mean == pytest.approx(scores_from_means(means)["mv"], abs=1e-15)
    assert rows["compact_1l"].cells["tm"].mean == pytest.approx(scores_from_means(means)["tm"], abs=1e-15)
