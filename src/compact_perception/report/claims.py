"""The claims scorecard: the paper's claims (``shared/CLAIMS.md``, section V-VI) tested on
this run's test scores, one row per claim, dataset and (for the claims about 15L+MGN) MGN form
(``reports/tables/claims.{md,csv}``).

Each claim is a difference oriented so that a positive value means the claim holds (e.g.
``TM(1L) - TM(15L)`` for "15L has a lower TM than 1L"). ``measured`` is that difference on
this run's test frames, averaged over the training seeds, ``ci_low`` / ``ci_high`` its 95%
paired bootstrap interval (:mod:`compact_perception.stats`: seeds resampled, then frames, the
same frames for every model), ``paper`` the same difference from the paper's printed Table II
(``paper_numbers.yaml``), and the verdict follows :func:`compact_perception.stats.verdict`.

The claims about 15L+MGN (``mgn-tm``, ``mgn-mv``, ``vs-combination``, ``mgn-weights``) are
tested once per MGN form: ``compact_15l_mgn`` (Algorithm 1 as printed, variant ``Alg. 1``) and
``compact_15l_mgn_authors`` (the authors' public code, variant ``authors' code``); the paper's
number is its one 15L+MGN row (which came from the authors' code) for both.

Per-frame scores come from ``data/eval/<ds>/<model>/seed<k>/per_frame.csv`` of every run that
:func:`..collect.list_runs` lists for the seeds of params.yaml; MGN's final weights from
``runs/<ds>/<mgn model>/seed<k>/summary.json`` (``final_weights``).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence

import numpy as np
import pandas as pd

from ..core import catalog
from ..stats import (MIN_SEEDS, N_BOOT, BootstrapResult, bootstrap_contrast, paired_bootstrap, seed_bootstrap,
                     stat_mean, verdict)
from .collect import ReportInputError, SeedSpec, align, list_runs, load_row_frames, read_summary, seeds_for
from .paper import PaperNumbers
from .schema import (COMBINATION, COMBINATION_MODELS, COMPACT, DATASET_LABEL, LOWER_IS_BETTER, MGN_FORMS, PAPER_MGN,
                     ROW_LABEL, WEIGHT_KEYS, column_stat, stat_columns, weight_key)
from .tables.formats import csv_text, write_files
from .tables.table3 import Table3Row, build_table3

log = logging.getLogger(__name__)

LABEL: dict[str, str] = {**ROW_LABEL, COMBINATION: "the combination"}
MODELS: tuple[str, ...] = catalog.model_ids()
#: Equivalence margin of "15L+MGN and 15L have equal MV" (nuScenes): one unit of the paper's
#: printed precision (3 decimals), the smallest difference Table II could show.
MV_MARGIN = 1e-3
NO_DATA = "no data"

#: (claim id, short statement) in scorecard order.
CLAIMS: tuple[tuple[str, str], ...] = (
    ("lidar-tm", "15L has a lower TM than 1L"),
    ("lidar-ls", "15L has a higher IoU_LS than 1L"),
    ("lidar-de-ss/de", "15L has a lower MAE_DE than 1L (simulated sets)"),
    ("lidar-de-ss/ss", "15L has a higher IoU_SS than 1L (simulated sets)"),
    ("lidar-bevp", "15L and 1L are comparable on IoU_BEVP"),
    ("mgn-tm", "15L+MGN has a lower TM than 15L"),
    ("mgn-mv", "15L+MGN has a lower MV than 15L (equal on nuScenes)"),
    ("mgn-tradeoff/ls", "15L+MGN has a higher IoU_LS than 15L"),
    ("mgn-tradeoff/bevp", "15L+MGN has a higher IoU_BEVP than 15L"),
    ("mgn-tradeoff/de", "15L has a lower MAE_DE than 15L+MGN"),
    ("mgn-tradeoff/ss", "15L has a higher IoU_SS than 15L+MGN"),
    ("vs-combination", "15L+MGN has a lower TM than the combination (the combination wins on C)"),
    ("polarnet-ls", "PolarNet has the highest IoU_LS"),
    ("mgn-weights", "MGN gives DE the largest final loss weight"),
    ("efficiency/params", "15L+MGN has fewer parameters than the combination"),
    ("efficiency/size", "15L+MGN has a smaller state-dict size than the combination"),
    ("efficiency/memory", "15L+MGN needs less memory than the combination"),
    ("efficiency/fps", "15L+MGN runs at a higher FPS than the combination"),
)
#: The claims tested once per MGN form.
MGN_CLAIMS: frozenset[str] = frozenset({"mgn-tm", "mgn-mv", "mgn-tradeoff/ls", "mgn-tradeoff/bevp", "mgn-tradeoff/de",
                                        "mgn-tradeoff/ss", "vs-combination", "mgn-weights"})
#: The claims the paper makes for the simulated sets only (CLAIMS.md: DE degrades on nuScenes).
SIMULATED_ONLY: frozenset[str] = frozenset({"lidar-de-ss/de", "lidar-de-ss/ss"})
#: Equivalence margin of "15L and 1L are comparable on BEVP" (IoU): the paper calls differences
#: of 0.014 to 0.038 (its Table II, both signs) comparable, so 0.04 covers its own usage.
BEVP_MARGIN = 0.04
#: mgn-tradeoff: (claim id, the model that should win: "mgn" or "15l", metric column).
TRADEOFF: tuple[tuple[str, str, str], ...] = (("mgn-tradeoff/ls", "mgn", "iou_ls"), ("mgn-tradeoff/bevp", "mgn", "iou_bevp"),
                                              ("mgn-tradeoff/de", "15l", "mae_de"), ("mgn-tradeoff/ss", "15l", "iou_ss"))

RULE_TEXT = (
    "**Verdict rule** (CLAIMS.md). Every difference is oriented so that a positive value means the claim holds. "
    "`reproduced`: the whole 95% interval lies above 0; `contradicted`: it lies wholly below 0; `inconclusive`: "
    "otherwise (an interval touching 0 included). Equality claims use an equivalence margin m: `reproduced` when "
    "the interval lies within [−m, m], `contradicted` when it lies wholly outside, `inconclusive` otherwise; "
    f"the margin for \"equal MV on nuScenes\" is m = {MV_MARGIN:g} (one unit of the paper's printed precision), for "
    f"\"15L and 1L are comparable on BEVP\" m = {BEVP_MARGIN:g} IoU (the paper calls differences up to 0.038 comparable). "
    "`lidar-de-ss` is claimed for the simulated sets only (the paper: DE degrades on nuScenes), so nuScenes has no row. "
    "`mgn-tradeoff` is one row per metric: 15L+MGN better on LS and BEVP, 15L better on DE and SS. "
    "`measured`: the difference of the models' values, each the mean over its training seeds (params.yaml `seeds`; "
    "the baselines `baseline_seeds`) of the run's statistic on all test frames. Intervals: paired percentile "
    f"bootstrap, {N_BOOT} replicates with a fixed RNG seed: the seeds (trainings) of each model are resampled, then "
    "the test frames within each seed, with the same resampled frames for every model compared. MV is one number "
    "per run (eq. 7 of the four test-set means), so its interval comes from recomputing MV from the resampled means. "
    "The combination's per-frame scores join GradNorm (DE, SS), PolarNet (LS) and Chen et al. (BEVP) of the same "
    "seed on the same frame. `Seeds`: the number of runs of each model compared (the CSV's `n_seeds` is the "
    "smallest). The claims about 15L+MGN are tested for both MGN forms, one row each: `Alg. 1` = "
    "compact_15l_mgn (Algorithm 1 as the paper prints it), `authors' code` = compact_15l_mgn_authors (MGN as the "
    "authors' public code runs it); `paper` is the paper's one 15L+MGN row for both (its Table II came from the "
    "authors' code). `efficiency/*` (Table III, results/benchmark/efficiency.json): 15L+MGN against the "
    "combination, whose parameters, size, memory and latency are the sums of its three models; params and size are "
    "exact counts and the memory an exact estimate (forward hooks), so their interval is the value itself; FPS is "
    "timed, and its range (not a bootstrap) comes from each model's fastest and 90th-percentile latency of the "
    "timed runs; the paper's numbers come from a GTX 1080 Ti GPU, this run's from the benchmark's device. "
    "`mgn-weights`: one observation per training seed, w_DE − max(w_SS, w_LS, w_BEVP) of the final "
    "weights (runs/<ds>/<MGN model>/seed<k>/summary.json); its interval is a bootstrap over seeds, and with fewer "
    f"than {MIN_SEEDS} seeds the verdict is `inconclusive` (one training is a single observation). "
    f"`{NO_DATA}`: an input the claim needs is missing. `paper`: the same difference from the paper's printed "
    "Table II (Fig. 8's weights are not printed)."
)


@dataclass(frozen=True)
class ClaimRow:
    """One line of the scorecard. ``model``: the model whose claim it is (the MGN form for the
    claims about 15L+MGN); ``variant``: the MGN form's label (empty for the other claims)."""

    dataset: str
    claim: str
    statement: str
    paper: Optional[float]
    measured: Optional[float]
    ci_low: Optional[float]
    ci_high: Optional[float]
    n_seeds: Optional[int]
    n_test_frames: Optional[int]
    verdict: str
    margin: Optional[float] = None
    note: str = ""
    model: str = ""
    variant: str = ""
    seeds_per_model: tuple[int, ...] = ()


# ----------------------------------------------------------------------------- paper differences
def _pv(paper: PaperNumbers, ds: str, row: str, col: str) -> Optional[float]:
    r = paper.table2_row(ds, row)
    return None if r is None else r.value(col)


def _pdiff(a: Optional[float], b: Optional[float]) -> Optional[float]:
    """``a - b`` rounded to the paper's precision (printed numbers have 3 decimals)."""
    return None if a is None or b is None else round(a - b, 6)


def _paper_tm(paper: PaperNumbers, ds: str, row: str) -> Optional[float]:
    return _pv(paper, ds, row, "tm")


# ----------------------------------------------------------------------------- helpers
def _row(ds: str, claim: str, statement: str, paper: Optional[float], res: Optional[BootstrapResult],
         margin: Optional[float] = None, note: str = "", model: str = "") -> ClaimRow:
    variant = MGN_FORMS.get(model, "") if claim in MGN_CLAIMS else ""
    if res is None:
        return ClaimRow(ds, claim, statement, paper, None, None, None, None, None, NO_DATA, margin, note, model,
                        variant)
    lo = None if math.isnan(res.ci_low) else res.ci_low
    hi = None if math.isnan(res.ci_high) else res.ci_high
    return ClaimRow(ds, claim, statement, paper, res.estimate, lo, hi, min(res.n_seeds), res.n_frames or None,
                    verdict(res.ci_low, res.ci_high, margin), margin, note, model, variant, tuple(res.n_seeds))


def _groups(frames: dict[str, list[pd.DataFrame]], rows: Sequence[str], cols: Sequence[str]
            ) -> Optional[list[list[np.ndarray]]]:
    """Aligned per-frame arrays of ``rows`` (None if one lacks per-frame scores or a column)."""
    runs = [frames.get(r) or [] for r in rows]
    if not all(runs) or not all(c in df.columns for g in runs for df in g for c in cols):
        return None
    return align(runs, cols)


def _missing(frames: dict[str, list[pd.DataFrame]], rows: Sequence[str]) -> str:
    miss = [LABEL.get(r, r) for r in rows if not frames.get(r)]
    return f"no per-frame scores for {', '.join(miss)}" if miss else "per-frame scores lack a column"


def _pair(ds: str, claim: str, statement: str, frames: dict[str, list[pd.DataFrame]], better: str, worse: str,
          col: str, paper: Optional[float], n_boot: int, margin: Optional[float] = None, *, model: str,
          note: str = "") -> ClaimRow:
    """``better`` beats ``worse`` on ``col`` (a task column, ``tm`` or ``mv``); ``model``: whose claim."""
    groups = _groups(frames, [better, worse], stat_columns(col))
    if groups is None:
        miss = _missing(frames, [better, worse])
        return _row(ds, claim, statement, paper, None, margin, f"{miss}; {note}" if note else miss, model)
    res = paired_bootstrap(groups[0], groups[1], column_stat(col), lower_is_better=col in LOWER_IS_BETTER,
                           n_boot=n_boot)
    return _row(ds, claim, statement, paper, res, margin, note, model)


def _polarnet_ls(ds: str, frames: dict[str, list[pd.DataFrame]], paper: PaperNumbers, n_boot: int) -> ClaimRow:
    """IoU_LS(PolarNet) - max over the compact models (all compared on the same frames)."""
    statement = dict(CLAIMS)["polarnet-ls"]
    others = [m for m in COMPACT if frames.get(m)]
    pv = _pv(paper, ds, "polarnet", "iou_ls")
    po = [v for v in (_pv(paper, ds, m, "iou_ls") for m in COMPACT) if v is not None]
    pdiff = _pdiff(pv, max(po)) if po else None
    groups = _groups(frames, ["polarnet"] + others, ["iou_ls"]) if others else None
    if groups is None:
        return _row(ds, "polarnet-ls", statement, pdiff, None, note=_missing(frames, ["polarnet", *COMPACT]),
                    model="polarnet")
    res = bootstrap_contrast(groups, stat_mean, lambda v: v[..., 0] - v[..., 1:].max(axis=-1), n_boot=n_boot)
    return _row(ds, "polarnet-ls", statement, pdiff, res,
                note=f"against the best of {', '.join(LABEL[m] for m in others)}", model="polarnet")


def mgn_weight_margins(root: Path, ds: str, model: str = "compact_15l_mgn",
                       seeds: Optional[Sequence[int]] = None) -> list[float]:
    """Per MGN run (seed of ``seeds``, see :func:`..collect.list_runs`): ``w_de - max(w_ss,
    w_ls, w_bevp)`` of the final weights (every task's, :data:`~.schema.WEIGHT_KEYS`; errors name
    the summary file)."""
    out = []
    for run in list_runs(root, ds, model, seeds):
        summ = read_summary(run.run_dir)
        if summ is None:
            continue
        path = run.run_dir / "summary.json"
        w = summ.get("final_weights")
        if not isinstance(w, dict) or any(k not in w for k in WEIGHT_KEYS):
            raise ReportInputError(f"{path}: final_weights must hold {list(WEIGHT_KEYS)}, got {w!r}")
        try:
            vals = {k: float(w[k]) for k in WEIGHT_KEYS}
        except (TypeError, ValueError):
            raise ReportInputError(f"{path}: final_weights has a non-numeric value: {w!r}") from None
        if not all(math.isfinite(v) for v in vals.values()):
            raise ReportInputError(f"{path}: final_weights has a non-finite value: {w!r}")
        de = weight_key("de")
        out.append(vals[de] - max(v for k, v in vals.items() if k != de))
    return out


def _mgn_weights(root: Path, ds: str, model: str, n_boot: int, seeds: Optional[Sequence[int]] = None) -> ClaimRow:
    statement = f"{LABEL[model]}: MGN gives DE the largest final loss weight"
    margins = mgn_weight_margins(root, ds, model, seeds)
    if not margins:
        return _row(ds, "mgn-weights", statement, None, None, note=f"no {LABEL[model]} summary.json", model=model)
    res = seed_bootstrap(margins, n_boot=n_boot)
    note = "paper: Fig. 8 legend values not printed in the text"
    if len(margins) < MIN_SEEDS:
        note = (f"{len(margins)} seed(s) < {MIN_SEEDS}: a single observation, no verdict; DE "
                f"{'is' if all(m > 0 for m in margins) else 'is not'} the largest weight in "
                f"{'every' if len(margins) > 1 else 'this'} run. " + note)
    return _row(ds, "mgn-weights", statement, None, res, note=note, model=model)


# ----------------------------------------------------------------------------- scorecard
def claims_for_dataset(root: Path, ds: str, paper: PaperNumbers, frames: Optional[dict[str, list[pd.DataFrame]]] = None,
                       *, n_boot: int = N_BOOT, seeds: SeedSpec = None) -> list[ClaimRow]:
    """Every claim of :data:`CLAIMS` on dataset ``ds`` (in that order; the claims about 15L+MGN
    once per MGN form of :data:`~.schema.MGN_FORMS`). ``seeds``: the seed lists (see
    :func:`..collect.list_runs`); ``frames``: per-frame scores already loaded with them."""
    frames = load_row_frames(root, ds, MODELS, seeds) if frames is None else frames
    st = dict(CLAIMS)
    paper_note = "paper: its one 15L+MGN row (from the authors' code)"
    rows = [
        _pair(ds, "lidar-tm", st["lidar-tm"], frames, "compact_15l", "compact_1l", "tm",
              _pdiff(_paper_tm(paper, ds, "compact_1l"), _paper_tm(paper, ds, "compact_15l")), n_boot,
              model="compact_15l"),
        _pair(ds, "lidar-ls", st["lidar-ls"], frames, "compact_15l", "compact_1l", "iou_ls",
              _pdiff(_pv(paper, ds, "compact_15l", "iou_ls"), _pv(paper, ds, "compact_1l", "iou_ls")), n_boot,
              model="compact_15l"),
    ]
    if ds in catalog.sim_dataset_ids():
        for claim, col in (("lidar-de-ss/de", "mae_de"), ("lidar-de-ss/ss", "iou_ss")):
            a, b = _pv(paper, ds, "compact_15l", col), _pv(paper, ds, "compact_1l", col)
            rows.append(_pair(ds, claim, st[claim], frames, "compact_15l", "compact_1l", col,
                              _pdiff(b, a) if col in LOWER_IS_BETTER else _pdiff(a, b), n_boot, model="compact_15l"))
    rows.append(_pair(ds, "lidar-bevp", st["lidar-bevp"], frames, "compact_15l", "compact_1l", "iou_bevp",
                      _pdiff(_pv(paper, ds, "compact_15l", "iou_bevp"), _pv(paper, ds, "compact_1l", "iou_bevp")),
                      n_boot, margin=BEVP_MARGIN, model="compact_15l"))
    for mgn in MGN_FORMS:
        lab = LABEL[mgn]
        rows.append(_pair(ds, "mgn-tm", f"{lab} has a lower TM than 15L", frames, mgn, "compact_15l", "tm",
                          _pdiff(_paper_tm(paper, ds, "compact_15l"), _paper_tm(paper, ds, PAPER_MGN)), n_boot,
                          model=mgn, note=paper_note))
        rows.append(_pair(ds, "mgn-mv", f"{lab} and 15L have equal MV (paper, nuScenes)" if ds == "nuscenes" else
                          f"{lab} has a lower MV than 15L", frames, mgn, "compact_15l", "mv",
                          _pdiff(_pv(paper, ds, "compact_15l", "mv"), _pv(paper, ds, PAPER_MGN, "mv")), n_boot,
                          margin=MV_MARGIN if ds == "nuscenes" else None, model=mgn, note=paper_note))
        for claim, winner, col in TRADEOFF:
            better, worse = (mgn, "compact_15l") if winner == "mgn" else ("compact_15l", mgn)
            pb, pw = (_pv(paper, ds, PAPER_MGN if m == mgn else m, col) for m in (better, worse))
            low = col in LOWER_IS_BETTER
            text = (f"{LABEL[better] if winner == 'mgn' else '15L'} has a {'lower' if low else 'higher'} "
                    f"{catalog.column_label(col)} than {'15L' if winner == 'mgn' else LABEL[worse]}")
            rows.append(_pair(ds, claim, text, frames, better, worse, col,
                              _pdiff(pw, pb) if low else _pdiff(pb, pw), n_boot, model=mgn,
                              note=paper_note))
        if ds == "C":  # the paper: the combination wins on C (0.976 vs 0.999)
            rows.append(_pair(ds, "vs-combination", f"the combination has a lower TM than {lab} (paper, set C)",
                              frames, COMBINATION, mgn, "tm",
                              _pdiff(_paper_tm(paper, ds, PAPER_MGN), _paper_tm(paper, ds, COMBINATION)), n_boot,
                              model=mgn, note=paper_note))
        else:
            rows.append(_pair(ds, "vs-combination", f"{lab} has a lower TM than the combination", frames,
                              mgn, COMBINATION, "tm",
                              _pdiff(_paper_tm(paper, ds, COMBINATION), _paper_tm(paper, ds, PAPER_MGN)), n_boot,
                              model=mgn, note=paper_note))
        rows.append(_mgn_weights(root, ds, mgn, n_boot, seeds_for(seeds, mgn)))
    rows.append(_polarnet_ls(ds, frames, paper, n_boot))
    return rows


def build_claims(root: Path, datasets: Sequence[str], paper: PaperNumbers, *,
                 frames: Optional[dict[str, dict[str, list[pd.DataFrame]]]] = None, n_boot: int = N_BOOT,
                 seeds: SeedSpec = None, efficiency: Optional[Mapping[str, Any]] = None,
                 table3: Optional[dict[str, list[Table3Row]]] = None) -> list[ClaimRow]:
    """The scorecard, sorted by claim (order of :data:`CLAIMS`), then dataset (order given), then
    MGN form (order of :data:`~.schema.MGN_FORMS`). ``efficiency``: ``results/benchmark/efficiency.json``
    for the Table III claims (left out when None); ``table3``: its Table III if already built."""
    rows: list[ClaimRow] = []
    for ds in datasets:
        rows += claims_for_dataset(root, ds, paper, (frames or {}).get(ds), n_boot=n_boot, seeds=seeds)
    if efficiency is not None:
        rows += [r for r in efficiency_claims(efficiency, paper, table3=table3) if r.dataset in datasets]
    order = {c: i for i, (c, _) in enumerate(CLAIMS)}
    ds_order = {d: i for i, d in enumerate(datasets)}
    v_order = {m: i for i, m in enumerate(MGN_FORMS)}
    return sorted(rows, key=lambda r: (order[r.claim], ds_order[r.dataset], v_order.get(r.model, -1)))


def efficiency_claims(efficiency: Mapping[str, Any], paper: PaperNumbers, model: str = PAPER_MGN, *,
                      table3: Optional[dict[str, list[Table3Row]]] = None) -> list[ClaimRow]:
    """The ``efficiency/*`` rows (Table III, ``table3`` or built from ``efficiency``) per
    benchmarked dataset, oriented so that positive means 15L+MGN is the more efficient:
    combination - 15L+MGN for parameters, size and memory, 15L+MGN - combination for FPS."""
    st = dict(CLAIMS)
    rows: list[ClaimRow] = []
    for ds, t3 in (build_table3(dict(efficiency)) if table3 is None else table3).items():
        by = {r.row_id: r for r in t3}
        mgn, comb = by.get(model), by.get(COMBINATION)
        raw = efficiency["models"][ds]
        pm, pc = paper.table3_row(ds, PAPER_MGN), paper.table3_row(ds, COMBINATION)
        for claim, field, paper_field in (("efficiency/params", "total_params", "total_params"),
                                          ("efficiency/size", "total_size_mb", "total_size_mb"),
                                          ("efficiency/memory", "peak_memory_mb", "gpu_memory_mb"),
                                          ("efficiency/fps", "fps", "fps")):
            if mgn is None or comb is None or not (mgn.available and comb.available):
                rows.append(ClaimRow(ds, claim, st[claim], None, None, None, None, None, None, NO_DATA,
                                     note="no benchmark of 15L+MGN or of all three baselines", model=model))
                continue
            sign = 1.0 if field == "fps" else -1.0
            measured = sign * (float(getattr(mgn, field)) - float(getattr(comb, field)))
            lo = hi = measured
            spread = all(k in raw[m] for m in (model, *COMBINATION_MODELS)
                         for k in ("latency_ms_min", "latency_ms_p90"))
            if field == "fps" and not spread:  # a benchmark file without the timed runs' spread
                lo = hi = math.nan
            elif field == "fps":  # range from the fastest and the 90th-percentile timed runs
                comb_min = sum(float(raw[b]["latency_ms_min"]) for b in COMBINATION_MODELS)
                comb_p90 = sum(float(raw[b]["latency_ms_p90"]) for b in COMBINATION_MODELS)
                lo = 1e3 / float(raw[model]["latency_ms_p90"]) - 1e3 / comb_min
                hi = 1e3 / float(raw[model]["latency_ms_min"]) - 1e3 / comb_p90
            pa, pb = (getattr(pm, paper_field, None) if pm else None), (getattr(pc, paper_field, None) if pc else None)
            pdiff = None if pa is None or pb is None else round(sign * (float(pa) - float(pb)), 6)
            device = mgn.device or "the benchmark's device"
            rows.append(ClaimRow(ds, claim, st[claim], pdiff, measured, None if math.isnan(lo) else lo,
                                 None if math.isnan(hi) else hi, None, None, verdict(lo, hi),
                                 note=f"measured on {device}" + ("; paper: GTX 1080 Ti" if claim in (
                                     "efficiency/memory", "efficiency/fps") else ""), model=model))
    return rows


def verdict_counts(rows: Sequence[ClaimRow]) -> dict[str, int]:
    """Rows per verdict: ``reproduced``, ``contradicted``, ``inconclusive``, ``no_data``."""
    keys = {"reproduced": "reproduced", "contradicted": "contradicted", "inconclusive": "inconclusive",
            NO_DATA: "no_data"}
    out = {v: 0 for v in keys.values()}
    for r in rows:
        out[keys[r.verdict]] += 1
    return out


# ----------------------------------------------------------------------------- output
def _f(v: Optional[float], nd: int = 4) -> str:
    return "" if v is None else f"{v:+.{nd}f}"


def _seeds_text(r: ClaimRow) -> str:
    if not r.seeds_per_model:
        return "" if r.n_seeds is None else str(r.n_seeds)
    return " vs ".join(map(str, r.seeds_per_model))


def claims_markdown(rows: list[ClaimRow]) -> str:
    """The scorecard as Markdown, with the verdict rule."""
    head = ["Claim", "Dataset", "MGN form", "Statement", "Paper", "Measured", "95% CI", "Seeds", "Test frames",
            "Verdict", "Note"]
    lines = ["# Claims scorecard", "",
             "The paper's claims (CLAIMS.md) tested on this run's test scores, over all training seeds; one row per "
             "claim and dataset, and for the claims about 15L+MGN one row per MGN form (`Alg. 1`: Algorithm 1 as "
             "printed, compact_15l_mgn; `authors' code`: compact_15l_mgn_authors).", "",
             "| " + " | ".join(head) + " |", "|" + "|".join(["---"] * 4 + ["---:"] * 5 + ["---"] * 2) + "|"]
    for r in rows:
        ci = "" if r.ci_low is None or r.ci_high is None else f"[{r.ci_low:+.4f}, {r.ci_high:+.4f}]"
        stmt = r.statement + (f" (margin ±{r.margin:g})" if r.margin is not None else "")
        lines.append("| " + " | ".join([
            f"`{r.claim}`", DATASET_LABEL.get(r.dataset, r.dataset), r.variant, stmt,
            _f(r.paper, 3) if r.paper is not None else "not printed", _f(r.measured), ci,
            _seeds_text(r), "" if r.n_test_frames is None else str(r.n_test_frames),
            f"**{r.verdict}**", r.note]) + " |")
    lines += ["", RULE_TEXT, ""]
    return "\n".join(lines)


def claims_csv(rows: list[ClaimRow]) -> str:
    header = ["dataset", "claim", "model", "variant", "statement", "paper", "measured", "ci_low", "ci_high", "margin",
              "n_seeds", "seeds_per_model", "n_test_frames", "verdict", "note"]
    return csv_text(header, [[r.dataset, r.claim, r.model, r.variant, r.statement, r.paper, r.measured, r.ci_low,
                              r.ci_high, r.margin, r.n_seeds, ";".join(map(str, r.seeds_per_model)), r.n_test_frames,
                              r.verdict, r.note] for r in rows])


def write_claims(root: Path, datasets: Sequence[str], paper: PaperNumbers, out_dir: Path, *,
                 frames: Optional[dict[str, dict[str, list[pd.DataFrame]]]] = None, n_boot: int = N_BOOT,
                 seeds: SeedSpec = None) -> list[Path]:
    """Write ``claims.md`` and ``claims.csv`` under ``out_dir``; returns the paths."""
    rows = build_claims(root, datasets, paper, frames=frames, n_boot=n_boot, seeds=seeds)
    log.info("claims: %s", {v: sum(r.verdict == v for r in rows) for v in sorted({r.verdict for r in rows})})
    return write_files(out_dir, claims_files(rows))


def claims_files(rows: list[ClaimRow]) -> dict[str, str]:
    """The scorecard's ``claims.md`` and ``claims.csv`` (file name -> text)."""
    return {"claims.md": claims_markdown(rows), "claims.csv": claims_csv(rows)}
