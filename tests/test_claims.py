"""The claims scorecard (compact_perception.report.claims) on synthetic per-frame scores, three
training seeds per run (tests/report_fixture.py writes the documented seed<k> layout, the
floor's trivial predictors and every run's summary with its stop reason)."""
from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from compact_perception.report.claims import (BEVP_MARGIN, CLAIM_MODELS, CLAIMS, MGN_CLAIMS, MV_MARGIN, NO_DATA,
                                              SIMULATED_ONLY, build_claims, claims_files, claims_for_dataset,
                                              coverage_text, exact_counts, mgn_weight_runs, verdict_counts)
from compact_perception.report.collect import (ReportInputError, combination_frames, common_frames, list_runs,
                                               load_row_frames, read_per_frame)
from compact_perception.report.paper import load_paper_numbers
from compact_perception.report.schema import MGN_FORMS
from compact_perception.report.tables.formats import write_files
from compact_perception.stats import METHOD, MIN_SEEDS, VERDICTS
from report_fixture import (COMPACT, MGN, MODELS, SEEDS, bases_with, build_tree, per_frame, run_dirs, seed_map,
                            write_json, write_run)

N = 60
SEEDMAP = seed_map()
#: Each run's own shift (report_fixture.jitter_of): paired differences vary over the seeds.
JITTER = 0.004
DECIDED = ("reproduced", "contradicted", "inconclusive")


def _tree(root: Path, datasets: tuple[str, ...] = ("A",), **kw) -> dict:
    kw.setdefault("jitter", JITTER)
    return build_tree(root, datasets, n_frames=N, curves=False, **kw)


def _claims(root: Path, datasets: list[str], seeds=SEEDMAP):
    return build_claims(root, datasets, load_paper_numbers(), seeds=seeds)


def _write_claims(root: Path, datasets: list[str], out_dir: Path, seeds) -> list[Path]:
    """``claims.md`` and ``claims.csv`` as the report writes them (index.write_tables: build_claims,
    coverage_text, claims_files)."""
    frames = {ds: load_row_frames(root, ds, CLAIM_MODELS, seeds) for ds in datasets}
    rows = build_claims(root, datasets, load_paper_numbers(), frames=frames, seeds=seeds)
    return write_files(out_dir, claims_files(rows, coverage_text(frames)))


def _by(rows, claim: str, ds: str = "A", model: str = ""):
    out = [r for r in rows if r.claim == claim and r.dataset == ds and (not model or r.model == model)]
    assert len(out) == 1, (claim, ds, model, out)
    return out[0]


def _summary(root: Path, ds: str, model: str, seed: int, weights: dict, stop_reason: str = "plateau") -> None:
    run, _, _ = run_dirs(root, ds, model, seed)
    write_json(run / "summary.json", {"best_epoch": 3, "final_weights": weights, "stop_reason": stop_reason})


def _mean(mets: dict, ds: str, model: str, col: str) -> float:
    return float(np.mean([mets[(ds, model, k)][col]["mean"] for k in SEEDS]))


def test_scorecard_verdicts_and_paper_differences(tmp_path: Path) -> None:
    mets = _tree(tmp_path, ("A", "C"))
    rows = _claims(tmp_path, ["A", "C"])
    expected = []
    for c, _ in CLAIMS:
        if c.startswith("efficiency/"):                       # only with the benchmark's file
            continue
        for ds in ("A", "C"):
            expected += [(c, ds, m) for m in MGN_FORMS] if c in MGN_CLAIMS else [(c, ds, None)]
    assert [(r.claim, r.dataset, r.model if r.variant else None) for r in rows] == expected
    assert {r.verdict for r in rows} <= set(VERDICTS) and {r.above_floor for r in rows} == {"yes"}
    lt = _by(rows, "lidar-tm")
    assert lt.verdict == "reproduced" and lt.paper == pytest.approx(0.004) and lt.n_test_frames == N
    assert lt.measured == pytest.approx(_mean(mets, "A", "compact_1l", "tm") - _mean(mets, "A", "compact_15l", "tm"))
    assert lt.ci_low < lt.measured < lt.ci_high and 0 < lt.mde < lt.measured
    assert lt.n_seeds == 3 and lt.seeds_per_model == (3, 3) and lt.variant == ""
    assert _by(rows, "lidar-ls").verdict == "reproduced" and _by(rows, "lidar-ls").paper == pytest.approx(0.018)
    # fixture: 1L MAE 0.10 / IoU_SS 0.60 / IoU_BEVP 0.50, 15L 0.09 / 0.65 / 0.55 (+ each run's jitter);
    # paper A: 0.090 -> 0.083, 0.619 -> 0.636, BEVP 1L 0.613 vs 15L 0.575
    de, ss = _by(rows, "lidar-de-ss/de"), _by(rows, "lidar-de-ss/ss")
    assert ss.verdict == "reproduced" and de.paper == pytest.approx(0.007) and ss.paper == pytest.approx(0.017)
    assert de.measured == pytest.approx(_mean(mets, "A", "compact_1l", "mae_de") - _mean(mets, "A", "compact_15l", "mae_de"))
    bevp = _by(rows, "lidar-bevp")                      # about 0.05 apart: outside the 0.04 margin
    assert bevp.margin == BEVP_MARGIN and bevp.ci_low > BEVP_MARGIN and bevp.verdict == "contradicted"
    assert bevp.paper == pytest.approx(0.575 - 0.613)
    for mgn, variant in (("compact_15l_mgn", "Alg. 1"), ("compact_15l_mgn_authors", "authors' code")):
        mt = _by(rows, "mgn-tm", model=mgn)                 # 15L+MGN = 15L but for each run's jitter
        assert mt.variant == variant and mt.statement.startswith(("15L+MGN (Alg. 1)", "15L+MGN (authors' code)"))
        assert mt.verdict == "inconclusive" and mt.ci_low < 0 < mt.ci_high and abs(mt.measured) < mt.mde
        assert mt.paper == pytest.approx(0.055)            # the paper's one 15L+MGN row, for both forms
        assert _by(rows, "mgn-mv", model=mgn).paper == pytest.approx(0.005)
        assert _by(rows, "mgn-mv", model=mgn).margin is None
        for claim in ("mgn-tradeoff/ls", "mgn-tradeoff/bevp", "mgn-tradeoff/de", "mgn-tradeoff/ss"):
            row = _by(rows, claim, model=mgn)
            assert row.verdict == "inconclusive" and abs(row.measured) < 0.01, claim
        assert _by(rows, "mgn-tradeoff/ls", model=mgn).paper == pytest.approx(0.470 - 0.424)
        assert _by(rows, "mgn-tradeoff/de", model=mgn).paper == pytest.approx(0.084 - 0.083)
        vc = _by(rows, "vs-combination", model=mgn)         # the combination is far better here
        assert vc.verdict == "contradicted" and vc.paper == pytest.approx(1.430 - 1.393)
        vc_c = _by(rows, "vs-combination", "C", model=mgn)  # on C the paper says the combination wins
        assert vc_c.verdict == "reproduced" and vc_c.paper == pytest.approx(0.999 - 0.976)
        assert "combination has a lower TM" in vc_c.statement
        mw = _by(rows, "mgn-weights", model=mgn)           # three seeds, converged, DE the largest in each
        assert mw.verdict == "reproduced" and mw.n_seeds == 3 and mw.measured == pytest.approx(0.3)
        assert mw.paper is None and "at convergence" in mw.statement
    pl = _by(rows, "polarnet-ls")
    assert pl.verdict == "reproduced" and pl.paper == pytest.approx(0.483 - 0.470)
    best = max(_mean(mets, "A", m, "iou_ls") for m in COMPACT)
    assert pl.measured == pytest.approx(_mean(mets, "A", "polarnet", "iou_ls") - best, abs=1e-6)
    assert "15L+MGN (authors' code)" in pl.note


def test_simulated_only_claims_have_no_nuscenes_row(tmp_path: Path) -> None:
    _tree(tmp_path, ("nuscenes",))
    rows = _claims(tmp_path, ["nuscenes"])
    assert not [r for r in rows if r.claim in SIMULATED_ONLY]
    assert _by(rows, "lidar-bevp", "nuscenes").margin == BEVP_MARGIN


def test_tradeoff_rows_point_each_way(tmp_path: Path) -> None:
    """MGN better on LS, worse on DE: the LS row is reproduced, the DE row (15L wins) too."""
    _tree(tmp_path, bases=bases_with(compact_15l_mgn={"iou_ls": 0.60, "mae_de": 0.12}))
    rows = _claims(tmp_path, ["A"])
    ls, de = (_by(rows, f"mgn-tradeoff/{t}", model="compact_15l_mgn") for t in ("ls", "de"))
    assert ls.verdict == "reproduced" and ls.measured == pytest.approx(0.10, abs=0.01)
    assert de.verdict == "reproduced" and de.measured == pytest.approx(0.03, abs=0.01)
    assert de.statement == "15L has a lower MAE_DE than 15L+MGN (Alg. 1)"


def test_mgn_variants_differ_where_their_scores_do(tmp_path: Path) -> None:
    """Each MGN form is scored on its own runs: authors' code better than 15L, Alg. 1 equal."""
    _tree(tmp_path, bases=bases_with(compact_15l_mgn_authors={"iou_ls": 0.60, "iou_bevp": 0.60}))
    rows = _claims(tmp_path, ["A"])
    alg1, authors = _by(rows, "mgn-tm", model="compact_15l_mgn"), _by(rows, "mgn-tm", model="compact_15l_mgn_authors")
    assert alg1.verdict == "inconclusive" and authors.verdict == "reproduced"
    assert authors.measured == pytest.approx(0.15, abs=0.02)
    counts = verdict_counts(rows)
    assert list(counts) == ["reproduced", "contradicted", "inconclusive", "not_decidable"]
    assert sum(counts.values()) == len(rows) and counts["reproduced"] == sum(r.verdict == "reproduced" for r in rows)


def test_mv_claim_uses_the_mv_of_the_means_over_seeds(tmp_path: Path) -> None:
    _tree(tmp_path)
    frames = load_row_frames(tmp_path, "A", MODELS, SEEDMAP)
    rows = claims_for_dataset(tmp_path, "A", load_paper_numbers(), frames, seeds=SEEDMAP)
    row = _by(rows, "mgn-mv", model="compact_15l_mgn")

    def mv(df: pd.DataFrame) -> float:
        m = df[["mae_de", "iou_ss", "iou_ls", "iou_bevp"]].mean()
        return float(np.var([m["mae_de"], 1 - m["iou_ss"], 1 - m["iou_ls"], 1 - m["iou_bevp"]]))

    assert len(frames["compact_15l"]) == 3
    want = np.mean([mv(df) for df in frames["compact_15l"]]) - np.mean([mv(df) for df in frames["compact_15l_mgn"]])
    assert row.measured == pytest.approx(want, abs=1e-12)


def test_nuscenes_mv_is_an_equality_claim(tmp_path: Path) -> None:
    _tree(tmp_path, ("nuscenes",))
    rows = _claims(tmp_path, ["nuscenes"])
    for mgn in MGN:
        row = _by(rows, "mgn-mv", "nuscenes", model=mgn)
        assert row.margin == MV_MARGIN and row.paper == pytest.approx(0.0) and "equal MV" in row.statement
        assert -MV_MARGIN <= row.ci_low <= row.ci_high <= MV_MARGIN and row.verdict == "reproduced"


def test_seed_list_selects_the_runs_and_stale_seed_folders_are_ignored(tmp_path: Path) -> None:
    _tree(tmp_path)
    # a stale run of a seed no longer in params (seed 7): far worse MGN and an inverted weight order
    df = per_frame("A", "compact_15l_mgn", 7, N, bases_with(compact_15l_mgn={"mae_de": 0.9, "iou_ls": 0.0}))
    write_run(tmp_path, "A", "compact_15l_mgn", 7, df, weights={"w_de": 0.1, "w_ss": 2.0, "w_ls": 1.0, "w_bevp": 0.9},
              curves=False)
    runs = list_runs(tmp_path, "A", "compact_15l_mgn", SEEDS)
    assert [r.seed for r in runs] == [0, 1, 2]
    assert runs[1].eval_dir == tmp_path / "data/eval/A/compact_15l_mgn/seed1"
    assert runs[1].metrics_path == tmp_path / "results/A/compact_15l_mgn/seed1/metrics.json"
    assert runs[1].run_dir == tmp_path / "runs/A/compact_15l_mgn/seed1"
    assert [r.seed for r in list_runs(tmp_path, "A", "compact_15l_mgn")] == [0, 1, 2, 7]   # no list: every folder
    assert [r.seed for r in list_runs(tmp_path, "A", "compact_15l_mgn", [0, 2, 5])] == [0, 2]  # seed 5 never ran
    assert list_runs(tmp_path, "A", "no_such_model", SEEDS) == []
    assert [m for m, _ in mgn_weight_runs(tmp_path, "A", "compact_15l_mgn", SEEDS)] == pytest.approx([0.3, 0.3, 0.3])
    rows = _claims(tmp_path, ["A"])
    mw, mt = _by(rows, "mgn-weights", model="compact_15l_mgn"), _by(rows, "mgn-tm", model="compact_15l_mgn")
    assert mw.verdict == "reproduced" and mw.n_seeds == 3
    assert mt.n_seeds == 3 and abs(mt.measured) < 0.02                      # seed 7 did not count
    # without the seed list the stale run counts (and pulls MGN below the floor on LS): not vacuous
    stale = _by(_claims(tmp_path, ["A"], seeds=None), "mgn-tm", model="compact_15l_mgn")
    assert stale.seeds_per_model == (4, 3) and stale.measured < -0.1
    # per-dataset seed lists are read too ({ds: {model: seeds}})
    per_ds = _by(_claims(tmp_path, ["A"], seeds={"A": SEEDMAP}), "mgn-tm", model="compact_15l_mgn")
    assert per_ds.seeds_per_model == (3, 3) and per_ds.measured == pytest.approx(mt.measured)
    # DE not the largest in one of three seeds: inconclusive
    _summary(tmp_path, "A", "compact_15l_mgn", 2, {"w_de": 0.9, "w_ss": 0.8, "w_ls": 1.1, "w_bevp": 0.5})
    assert _by(_claims(tmp_path, ["A"]), "mgn-weights", model="compact_15l_mgn").verdict == "inconclusive"


def test_one_seed_is_not_decidable(tmp_path: Path) -> None:
    _tree(tmp_path, seeds=(0,), baseline_seeds=(0,))
    rows = _claims(tmp_path, ["A"], seeds=seed_map((0,), (0,)))
    assert {r.verdict for r in rows} == {"not decidable"}
    mw = _by(rows, "mgn-weights", model="compact_15l_mgn_authors")
    assert mw.measured == pytest.approx(0.3) and mw.ci_low is None and mw.mde is None
    assert mw.note.startswith("1 seed: 15L+MGN (authors' code)")
    lt = _by(rows, "lidar-tm")
    assert lt.n_seeds == 1 and lt.note.startswith("1 seed: 15L; 1 seed: 1L") and lt.measured is not None
    # a model with one seed is not shown above the floor either
    assert lt.above_floor.startswith("no: 15L DE/SS/LS/BEVP, 1L DE/SS/LS/BEVP") and "below floor: 15L" in lt.note


@pytest.mark.parametrize("n_base", [2, 3])
def test_three_seeds_decide_two_do_not(tmp_path: Path, n_base: int) -> None:
    """Compact models at seeds 0-2; baselines at ``n_base`` seeds: the combination's comparisons
    are decided with 3 seeds a side and not with 2; the compact models' own ones always."""
    base = SEEDS[:n_base]
    mets = _tree(tmp_path, baseline_seeds=base)
    rows = _claims(tmp_path, ["A"], seeds=seed_map(SEEDS, base))
    vc = _by(rows, "vs-combination", model="compact_15l_mgn")
    assert vc.seeds_per_model == (3, n_base) and vc.n_seeds == n_base
    assert _by(rows, "lidar-tm").verdict == "reproduced"
    if n_base < MIN_SEEDS:
        assert vc.verdict == "not decidable" and vc.note.startswith("2 seeds: the combination")
        assert _by(rows, "polarnet-ls").verdict == "not decidable" and "2 seeds: PolarNet" in _by(rows, "polarnet-ls").note
    else:
        assert vc.verdict == "contradicted" and vc.above_floor == "yes"
        comb = np.mean([mets[("A", "gradnorm_segnet", k)]["mae_de"]["mean"] + 3 - mets[("A", "gradnorm_segnet", k)]["iou_ss"]
                        ["mean"] - mets[("A", "polarnet", k)]["iou_ls"]["mean"] - mets[("A", "chen_bev", k)]["iou_bevp"]
                        ["mean"] for k in base])
        assert vc.measured == pytest.approx(comb - _mean(mets, "A", "compact_15l_mgn", "tm"), abs=1e-9)


def test_a_model_at_the_floor_makes_the_claims_on_its_metrics_not_decidable(tmp_path: Path) -> None:
    """1L's IoU_LS equals the floor's (0.20, report_fixture FLOOR_BASES): below the floor on LS.
    The claims on LS and on TM (all four tasks) are not decidable; those on DE and BEVP are."""
    _tree(tmp_path, bases=bases_with(compact_1l={"iou_ls": 0.20}), jitter=0.0)
    rows = _claims(tmp_path, ["A"])
    for claim in ("lidar-ls", "lidar-tm", "polarnet-ls"):
        r = _by(rows, claim)
        assert r.verdict == "not decidable" and r.above_floor == "no: 1L LS", claim
        assert r.note.startswith("below floor: 1L LS") and r.measured is not None and r.mde is not None
    for claim in ("lidar-de-ss/de", "lidar-de-ss/ss", "lidar-bevp"):
        assert _by(rows, claim).verdict in DECIDED and _by(rows, claim).above_floor == "yes", claim
    assert _by(rows, "mgn-tm", model="compact_15l_mgn").verdict in DECIDED      # 1L is not compared there


def test_no_floor_no_verdict(tmp_path: Path) -> None:
    _tree(tmp_path, floors=None)
    rows = _claims(tmp_path, ["A"])
    assert {r.verdict for r in rows} == {"not decidable"} and {r.above_floor for r in rows} == {"no floor"}
    assert all("no floor results for Set A" in r.note for r in rows)


def test_mgn_weights_need_every_run_converged(tmp_path: Path) -> None:
    _tree(tmp_path, stop_reason="max_epochs")
    rows = _claims(tmp_path, ["A"])
    mw = _by(rows, "mgn-weights", model="compact_15l_mgn")
    assert mw.verdict == "not decidable" and mw.note.startswith("not converged: max_epochs (3 of 3 runs)")
    assert mw.measured == pytest.approx(0.3) and _by(rows, "lidar-tm").verdict == "reproduced"
    _summary(tmp_path, "A", "compact_15l_mgn", 0, {"w_de": 1.5, "w_ss": 0.8, "w_ls": 1.2, "w_bevp": 0.5})
    _summary(tmp_path, "A", "compact_15l_mgn", 1, {"w_de": 1.5, "w_ss": 0.8, "w_ls": 1.2, "w_bevp": 0.5})
    mw = _by(_claims(tmp_path, ["A"]), "mgn-weights", model="compact_15l_mgn")
    assert mw.verdict == "not decidable" and mw.note.startswith("not converged: max_epochs (1 of 3 runs)")
    _summary(tmp_path, "A", "compact_15l_mgn", 2, {"w_de": 1.5, "w_ss": 0.8, "w_ls": 1.2, "w_bevp": 0.5})
    assert _by(_claims(tmp_path, ["A"]), "mgn-weights", model="compact_15l_mgn").verdict == "reproduced"


def test_missing_inputs_give_not_decidable_rows(tmp_path: Path) -> None:
    _tree(tmp_path)
    for k in SEEDS:
        (tmp_path / f"data/eval/A/polarnet/seed{k}/per_frame.csv").unlink()
        (tmp_path / f"runs/A/compact_15l_mgn/seed{k}/summary.json").unlink()
    shutil.rmtree(tmp_path / "data/eval/A/compact_15l_mgn_authors")
    rows = _claims(tmp_path, ["A"])
    for claim, model in (("vs-combination", "compact_15l_mgn"), ("polarnet-ls", ""), ("mgn-weights", "compact_15l_mgn"),
                         ("mgn-tm", "compact_15l_mgn_authors")):
        r = _by(rows, claim, model=model)
        assert r.verdict == "not decidable" and r.measured is None and r.note.startswith(f"{NO_DATA}: "), claim
    assert "PolarNet" in _by(rows, "polarnet-ls").note
    assert _by(rows, "lidar-tm").verdict == "reproduced"
    assert _by(rows, "mgn-weights", model="compact_15l_mgn_authors").verdict == "not decidable"   # no per-frame: no gate
    assert "below floor: 15L+MGN (authors' code)" in _by(rows, "mgn-weights", model="compact_15l_mgn_authors").note


def test_bad_inputs_name_the_file(tmp_path: Path) -> None:
    _tree(tmp_path)
    _summary(tmp_path, "A", "compact_15l_mgn", 1, {"w_de": 1.0})
    with pytest.raises(ReportInputError, match=r"compact_15l_mgn/seed1/summary.json: final_weights"):
        _claims(tmp_path, ["A"])
    bad = tmp_path / "data/eval/A/compact_1l/seed0/per_frame.csv"
    bad.write_text("frame_id,mae_de,iou_ss,iou_ls,iou_bevp,tm\nf0,0.1,x,0.5,0.5,1.0\n")
    with pytest.raises(ReportInputError, match=r"compact_1l/seed0/per_frame.csv: column 'iou_ss'"):
        read_per_frame(bad)
    bad.write_text("frame_id,mae_de\nf0,0.1\nf0,0.2\n")
    with pytest.raises(ReportInputError, match="per_frame.csv: duplicate frame_id"):
        read_per_frame(bad)


def test_combination_frames_join_sources_per_seed_and_frame(tmp_path: Path) -> None:
    _tree(tmp_path)
    frames = load_row_frames(tmp_path, "A", MODELS, SEEDMAP)
    assert [df.attrs["seed"] for df in frames["combination"]] == [0, 1, 2]
    comb = frames["combination"][1]
    assert list(comb.columns) == ["mae_de", "iou_ss", "iou_ls", "iou_bevp"] and len(comb) == N
    assert comb["iou_ls"].equals(frames["polarnet"][1]["iou_ls"])
    assert comb["mae_de"].equals(frames["gradnorm_segnet"][1]["mae_de"])
    # runs pair by seed value: a baseline without seed 1 leaves seeds 0 and 2
    no1 = {**frames, "chen_bev": [frames["chen_bev"][0], frames["chen_bev"][2]]}
    assert [df.attrs["seed"] for df in combination_frames(no1)] == [0, 2]
    # frames only some models scored are dropped when pairing
    short = {**frames, "chen_bev": [df.iloc[:10] for df in frames["chen_bev"]]}
    for df, k in zip(short["chen_bev"], SEEDS):
        df.attrs["seed"] = k
    assert len(combination_frames(short)[0]) == 10
    assert len(common_frames([frames["compact_1l"], short["chen_bev"]])) == 10


def test_outputs_deterministic_and_rule_stated(tmp_path: Path) -> None:
    _tree(tmp_path, baseline_seeds=(0,))
    seeds = seed_map(SEEDS, (0,))
    first = [x.read_bytes() for x in _write_claims(tmp_path, ["A"], tmp_path / "o1", seeds)]
    second = [x.read_bytes() for x in _write_claims(tmp_path, ["A"], tmp_path / "o2", seeds)]
    assert first == second
    md = (tmp_path / "o1/claims.md").read_text()
    assert "Verdict rule" in md and "equivalence margin" in md and "fewer than 3 training seeds" in md
    assert "authors' code" in md and "Alg. 1" in md and "MDE (80%)" in md and "Above floor" in md
    # the method and its coverage at this run's design (3 seeds, 6 episodes of 10 frames), one line
    cover = [line for line in md.splitlines() if line.startswith("**Method and measured coverage**")]
    assert len(cover) == 1 and f"intervals: {METHOD}; coverage " in cover[0]
    assert "at nominal 95% in 400 simulations at 3 seeds, 6 clusters (Set A)" in cover[0]
    rows = list(csv.DictReader((tmp_path / "o1/claims.csv").open()))
    assert set(rows[0]) >= {"dataset", "claim", "model", "variant", "paper", "measured", "ci_low", "ci_high", "mde",
                            "above_floor", "n_seeds", "n_test_frames", "verdict"}
    assert {r["verdict"] for r in rows} <= {"reproduced", "contradicted", "inconclusive", "not decidable"}
    # the acceptance: no row with fewer than 3 seeds on either side is reproduced or contradicted
    few = [r for r in rows if r["seeds_per_model"] and min(map(int, r["seeds_per_model"].split(";"))) < MIN_SEEDS]
    assert few and all(r["verdict"] == "not decidable" for r in few)           # the baselines' comparisons
    assert {r["verdict"] for r in rows if r["n_seeds"] == "3"} & {"reproduced", "contradicted"}
    mgn_rows = [r for r in rows if r["claim"] == "mgn-tm"]
    assert [(r["model"], r["variant"]) for r in mgn_rows] == [("compact_15l_mgn", "Alg. 1"),
                                                             ("compact_15l_mgn_authors", "authors' code")]
    assert json.loads(json.dumps(rows))                       # plain strings only
    assert set(COMPACT) <= set(MODELS)


def test_efficiency_claims_by_hand() -> None:
    """15L+MGN: 10 params, 1 MB, 2 MB memory, latency 10 ms (fastest 8, p90 12); each baseline:
    100 params, 10 MB, 20 MB, 20 ms (18, 22). Combination = sums: 300, 30, 60, 60 ms (54, 66).
    params 300 - 10 = 290, size 29, memory 58 (exact: interval = value); FPS 1000/10 - 1000/60 =
    83.333, range [1000/12 - 1000/54, 1000/8 - 1000/66] = [64.815, 109.848]."""
    from compact_perception.report.claims import efficiency_claims

    def model(params, size, mem, lat, lo, hi):
        return {"params": params, "size_mb": size, "peak_memory_mb": mem, "latency_ms": lat, "fps": 1e3 / lat,
                "latency_ms_min": lo, "latency_ms_p90": hi, "device": "CPU (2 threads)"}

    eff = {"models": {"A": {"compact_15l_mgn": model(10, 1.0, 2.0, 10.0, 8.0, 12.0),
                            **{b: model(100, 10.0, 20.0, 20.0, 18.0, 22.0)
                               for b in ("chen_bev", "polarnet", "gradnorm_segnet")}}}}
    rows = {r.claim: r for r in efficiency_claims(eff, load_paper_numbers())}
    assert [c for c, _ in CLAIMS if c.startswith("efficiency/")] == list(rows)
    for claim, value in (("efficiency/params", 290.0), ("efficiency/size", 29.0), ("efficiency/memory", 58.0)):
        r = rows[claim]
        assert r.measured == r.ci_low == r.ci_high == pytest.approx(value) and r.verdict == "reproduced", claim
        assert r.exact and r.above_floor == "n/a" and r.mde is None
    fps = rows["efficiency/fps"]
    assert fps.measured == pytest.approx(1000 / 10 - 1000 / 60)
    assert (fps.ci_low, fps.ci_high) == pytest.approx((1000 / 12 - 1000 / 54, 1000 / 8 - 1000 / 66))
    assert rows["efficiency/params"].paper == pytest.approx(136728752 - 2521504)   # Table III, simulation
    assert fps.paper == pytest.approx(54.428 - 44.472)
    # the exact counts are apart: not in the verdict counts of the claims judged on test scores
    all_rows = list(rows.values())
    assert verdict_counts(all_rows) == {"reproduced": 0, "contradicted": 0, "inconclusive": 0, "not_decidable": 0}
    assert exact_counts(all_rows) == {"reproduced": 4, "contradicted": 0, "inconclusive": 0, "not_decidable": 0}
    slow = efficiency_claims({"models": {"A": {**eff["models"]["A"],
                                               "compact_15l_mgn": model(10, 1.0, 2.0, 100.0, 90.0, 110.0)}}},
                             load_paper_numbers())
    assert {r.claim: r.verdict for r in slow}["efficiency/fps"] == "contradicted"   # 10 FPS vs 16.7
    missing = efficiency_claims({"models": {"A": {"compact_15l_mgn": eff["models"]["A"]["compact_15l_mgn"]}}},
                                load_paper_numbers())
    assert {r.verdict for r in missing} == {"not decidable"} and all(r.note.startswith(NO_DATA) for r in missing)
