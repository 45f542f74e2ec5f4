"""The claims scorecard (compact_perception.report.claims) on synthetic per-frame scores."""
from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Optional

import numpy as np
import pandas as pd
import pytest

from compact_perception import io
from compact_perception.report.claims import (CLAIMS, MV_MARGIN, NO_DATA, build_claims, claims_for_dataset,
                                              mgn_weight_margins, write_claims)
from compact_perception.report.collect import (ReportInputError, align, combination_frames, list_runs,
                                               load_row_frames, read_per_frame)
from compact_perception.report.paper import load_paper_numbers

TASKS = {
    "compact_1l": ("mae_de", "iou_ss", "iou_ls", "iou_bevp"), "compact_15l": ("mae_de", "iou_ss", "iou_ls", "iou_bevp"),
    "compact_15l_mgn": ("mae_de", "iou_ss", "iou_ls", "iou_bevp"), "gradnorm_segnet": ("mae_de", "iou_ss"),
    "polarnet": ("iou_ls",), "chen_bev": ("iou_bevp",),
}
#: 15L beats 1L clearly (TM 1.6 -> 1.39); 15L+MGN equals 15L (same scores); the combination
#: (TM 1.1) beats both; PolarNet has the highest IoU_LS.
BASES = {
    "chen_bev": {"iou_bevp": 0.70},
    "polarnet": {"iou_ls": 0.90},
    "gradnorm_segnet": {"mae_de": 0.20, "iou_ss": 0.50},
    "compact_1l": {"mae_de": 0.10, "iou_ss": 0.60, "iou_ls": 0.40, "iou_bevp": 0.50},
    "compact_15l": {"mae_de": 0.09, "iou_ss": 0.65, "iou_ls": 0.50, "iou_bevp": 0.55},
    "compact_15l_mgn": {"mae_de": 0.09, "iou_ss": 0.65, "iou_ls": 0.50, "iou_bevp": 0.55},
}
N = 60


def _frames(ds: str, model: str, seed: int = 0, bases: Optional[dict] = None, noise: float = 0.01) -> pd.DataFrame:
    rng = np.random.default_rng(1000 * seed + 10 * list(TASKS).index(model) + len(ds))
    difficulty = np.random.default_rng(7).normal(0, 0.03, N)
    df = pd.DataFrame({"frame_id": [f"{ds}-{i:04d}" for i in range(N)]})
    for c in TASKS[model]:
        e = rng.normal(0, noise, N)
        # centred noise: equal bases give exactly equal means (a true difference of 0)
        df[c] = (bases or BASES)[model][c] + (1 if c == "mae_de" else -1) * difficulty + e - e.mean()
    if len(TASKS[model]) == 4:
        df["tm"] = df["mae_de"] + 3 - df["iou_ss"] - df["iou_ls"] - df["iou_bevp"]
    return df


def _write(root: Path, ds: str, model: str, df: pd.DataFrame, sub: str = "") -> None:
    d = root / "data/eval" / ds / model / sub
    io.write_text(d / "per_frame.csv", df.to_csv(index=False, float_format="%.8f"))
    io.write_json(root / "results" / ds / model / sub / "metrics.json", {"n_frames": len(df)})


def _summary(root: Path, ds: str, weights: dict, sub: str = "") -> None:
    io.write_json(root / "runs" / ds / "compact_15l_mgn" / sub / "summary.json",
                  {"best_epoch": 3, "final_weights": weights})


def _tree(root: Path, datasets: tuple[str, ...] = ("A",)) -> None:
    for ds in datasets:
        for m in TASKS:
            _write(root, ds, m, _frames(ds, m))
            (root / "runs" / ds / m).mkdir(parents=True, exist_ok=True)
        _summary(root, ds, {"w_de": 1.6, "w_ss": 0.8, "w_ls": 1.1, "w_bevp": 0.5})


def _by(rows, claim: str, ds: str = "A"):
    out = [r for r in rows if r.claim == claim and r.dataset == ds]
    assert len(out) == 1
    return out[0]


def test_scorecard_verdicts_and_paper_differences(tmp_path: Path) -> None:
    _tree(tmp_path, ("A", "C"))
    rows = build_claims(tmp_path, ["A", "C"], load_paper_numbers(), n_boot=500)
    assert [(r.claim, r.dataset) for r in rows] == [(c, ds) for c, _ in CLAIMS for ds in ("A", "C")]
    lt = _by(rows, "lidar-tm")
    assert lt.verdict == "reproduced" and lt.paper == pytest.approx(0.004) and lt.n_test_frames == N
    assert lt.measured == pytest.approx(1.6 - 1.39, abs=0.02) and lt.ci_low <= lt.measured <= lt.ci_high
    assert lt.n_seeds == 1
    assert _by(rows, "lidar-ls").verdict == "reproduced" and _by(rows, "lidar-ls").paper == pytest.approx(0.018)
    mt = _by(rows, "mgn-tm")                      # 15L+MGN = 15L: no difference
    assert mt.measured == pytest.approx(0.0, abs=1e-6)
    assert mt.verdict == "inconclusive" and mt.ci_low < 0 < mt.ci_high and mt.paper == pytest.approx(0.055)
    assert _by(rows, "mgn-mv").paper == pytest.approx(0.005) and _by(rows, "mgn-mv").margin is None
    vc = _by(rows, "vs-combination")              # the combination is far better here
    assert vc.verdict == "contradicted" and vc.paper == pytest.approx(1.430 - 1.393)
    vc_c = _by(rows, "vs-combination", "C")       # on C the paper says the combination wins
    assert vc_c.verdict == "reproduced" and vc_c.paper == pytest.approx(0.999 - 0.976)
    assert "combination has a lower TM" in vc_c.statement
    pl = _by(rows, "polarnet-ls")
    assert pl.verdict == "reproduced" and pl.paper == pytest.approx(0.483 - 0.470)
    assert pl.measured == pytest.approx(0.90 - 0.50, abs=0.02)
    mw = _by(rows, "mgn-weights")                 # one seed: a single observation
    assert mw.verdict == "inconclusive" and mw.measured == pytest.approx(0.5) and mw.ci_low is None
    assert mw.paper is None and "1 seed(s) < 3" in mw.note


def test_mv_claim_uses_the_mv_of_the_means(tmp_path: Path) -> None:
    _tree(tmp_path)
    frames = load_row_frames(tmp_path, "A", list(TASKS))
    row = _by(claims_for_dataset(tmp_path, "A", load_paper_numbers(), frames, n_boot=300), "mgn-mv")

    def mv(df: pd.DataFrame) -> float:
        m = df[["mae_de", "iou_ss", "iou_ls", "iou_bevp"]].mean()
        return float(np.var([m["mae_de"], 1 - m["iou_ss"], 1 - m["iou_ls"], 1 - m["iou_bevp"]]))

    assert row.measured == pytest.approx(mv(frames["compact_15l"][0]) - mv(frames["compact_15l_mgn"][0]), abs=1e-12)


def test_nuscenes_mv_is_an_equality_claim(tmp_path: Path) -> None:
    _tree(tmp_path, ("nuscenes",))
    row = _by(build_claims(tmp_path, ["nuscenes"], load_paper_numbers(), n_boot=300), "mgn-mv", "nuscenes")
    assert row.margin == MV_MARGIN and row.paper == pytest.approx(0.0) and "equal MV" in row.statement
    assert -MV_MARGIN <= row.ci_low <= row.ci_high <= MV_MARGIN and row.verdict == "reproduced"


def test_seed_layout_and_weights_over_seeds(tmp_path: Path) -> None:
    _tree(tmp_path)
    # three MGN seeds replace the single run
    for k, w_de in enumerate((1.5, 1.7, 1.6)):
        _write(tmp_path, "A", "compact_15l_mgn", _frames("A", "compact_15l_mgn", seed=k), f"seed{k}")
        _summary(tmp_path, "A", {"w_de": w_de, "w_ss": 0.8, "w_ls": 1.1, "w_bevp": 0.5}, f"seed{k}")
    runs = list_runs(tmp_path, "A", "compact_15l_mgn")
    assert [r.seed for r in runs] == [0, 1, 2]
    assert runs[1].eval_dir == tmp_path / "data/eval/A/compact_15l_mgn/seed1"
    assert runs[1].metrics_path == tmp_path / "results/A/compact_15l_mgn/seed1/metrics.json"
    assert [r.seed for r in list_runs(tmp_path, "A", "compact_15l")] == [None]
    assert list_runs(tmp_path, "A", "no_such_model") == []
    assert mgn_weight_margins(tmp_path, "A") == pytest.approx([0.4, 0.6, 0.5])
    rows = build_claims(tmp_path, ["A"], load_paper_numbers(), n_boot=300)
    mw = _by(rows, "mgn-weights")
    assert mw.verdict == "reproduced" and mw.n_seeds == 3 and 0.4 - 1e-9 <= mw.ci_low <= mw.ci_high <= 0.6 + 1e-9
    mt = _by(rows, "mgn-tm")
    assert mt.n_seeds == 1                         # the smaller of 3 (15L+MGN) and 1 (15L)
    # DE not the largest in one of three seeds: inconclusive
    _summary(tmp_path, "A", {"w_de": 0.9, "w_ss": 0.8, "w_ls": 1.1, "w_bevp": 0.5}, "seed2")
    assert _by(build_claims(tmp_path, ["A"], load_paper_numbers(), n_boot=300), "mgn-weights").verdict == "inconclusive"


def test_missing_inputs_give_no_data_rows(tmp_path: Path) -> None:
    _tree(tmp_path)
    (tmp_path / "data/eval/A/polarnet/per_frame.csv").unlink()
    (tmp_path / "runs/A/compact_15l_mgn/summary.json").unlink()
    rows = build_claims(tmp_path, ["A"], load_paper_numbers(), n_boot=200)
    for claim in ("vs-combination", "polarnet-ls", "mgn-weights"):
        r = _by(rows, claim)
        assert r.verdict == NO_DATA and r.measured is None
    assert "PolarNet" in _by(rows, "polarnet-ls").note
    assert _by(rows, "lidar-tm").verdict == "reproduced"


def test_bad_inputs_name_the_file(tmp_path: Path) -> None:
    _tree(tmp_path)
    _summary(tmp_path, "A", {"w_de": 1.0})
    with pytest.raises(ReportInputError, match=r"compact_15l_mgn/summary.json: final_weights"):
        build_claims(tmp_path, ["A"], load_paper_numbers(), n_boot=50)
    bad = tmp_path / "data/eval/A/compact_1l/per_frame.csv"
    bad.write_text("frame_id,mae_de,iou_ss,iou_ls,iou_bevp,tm\nf0,0.1,x,0.5,0.5,1.0\n")
    with pytest.raises(ReportInputError, match=r"compact_1l/per_frame.csv: column 'iou_ss'"):
        read_per_frame(bad)
    bad.write_text("frame_id,mae_de\nf0,0.1\nf0,0.2\n")
    with pytest.raises(ReportInputError, match="per_frame.csv: duplicate frame_id"):
        read_per_frame(bad)


def test_combination_frames_join_sources_per_frame(tmp_path: Path) -> None:
    _tree(tmp_path)
    frames = load_row_frames(tmp_path, "A", list(TASKS))
    comb = frames["combination"][0]
    assert list(comb.columns) == ["mae_de", "iou_ss", "iou_ls", "iou_bevp"] and len(comb) == N
    assert comb["iou_ls"].equals(frames["polarnet"][0]["iou_ls"])
    assert comb["mae_de"].equals(frames["gradnorm_segnet"][0]["mae_de"])
    # frames only some models scored are dropped when pairing
    short = {**frames, "chen_bev": [frames["chen_bev"][0].iloc[:10]]}
    assert len(combination_frames(short)[0]) == 10
    a, b = align([frames["compact_1l"], short["chen_bev"]], ["iou_bevp"])
    assert a[0].shape == b[0].shape == (10, 1)


def test_outputs_deterministic_and_rule_stated(tmp_path: Path) -> None:
    _tree(tmp_path)
    p = load_paper_numbers()
    first = [x.read_bytes() for x in write_claims(tmp_path, ["A"], p, tmp_path / "o1", n_boot=300)]
    second = [x.read_bytes() for x in write_claims(tmp_path, ["A"], p, tmp_path / "o2", n_boot=300)]
    assert first == second
    md = (tmp_path / "o1/claims.md").read_text()
    assert "Verdict rule" in md and "equivalence margin" in md and "fewer than 3 seeds" in md
    rows = list(csv.DictReader((tmp_path / "o1/claims.csv").open()))
    assert set(rows[0]) >= {"dataset", "claim", "paper", "measured", "ci_low", "ci_high", "n_seeds",
                            "n_test_frames", "verdict"}
    assert {r["verdict"] for r in rows} <= {"reproduced", "contradicted", "inconclusive", NO_DATA}
    assert json.loads(json.dumps(rows))                       # plain strings only
