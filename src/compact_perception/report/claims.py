"""The claims scorecard: the paper's claims (``shared/CLAIMS.md``, section V-VI) tested on
this run's test scores, one row per claim and dataset (``reports/tables/claims.{md,csv}``).

Each claim is a difference oriented so that a positive value means the claim holds (e.g.
``TM(1L) - TM(15L)`` for "15L has a lower TM than 1L"). ``measured`` is that difference on
this run's test frames, ``ci_low`` / ``ci_high`` its 95% paired bootstrap interval
(:mod:`compact_perception.stats`: seeds resampled, then frames, the same frames for every
model), ``paper`` the same difference from the paper's printed Table II
(``paper_numbers.yaml``), and the verdict follows :func:`compact_perception.stats.verdict`.

Per-frame scores come from ``data/eval/<ds>/<model>/per_frame.csv`` of every run that
:func:`..collect.list_runs` lists; MGN's final weights from ``runs/<ds>/compact_15l_mgn/
summary.json`` (``final_weights``).
"""
from __future__ import annotations

import csv
import io as _io
import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np
import pandas as pd

from .. import io
from ..stats import (MIN_SEEDS, N_BOOT, BootstrapResult, bootstrap_contrast, paired_bootstrap, seed_bootstrap,
                     stat_mean, stat_mv, stat_tm, verdict)
from .collect import TASK_METRICS, ReportInputError, align, list_runs, load_row_frames, read_summary
from .paper import PaperNumbers

log = logging.getLogger(__name__)

DATASET_LABEL: dict[str, str] = {"A": "Set A", "B": "Set B", "C": "Set C", "nuscenes": "nuScenes"}
LABEL: dict[str, str] = {"chen_bev": "Chen et al.", "polarnet": "PolarNet", "gradnorm_segnet": "GradNorm",
                         "combination": "the combination", "compact_1l": "1L", "compact_15l": "15L",
                         "compact_15l_mgn": "15L+MGN"}
MODELS: tuple[str, ...] = ("chen_bev", "polarnet", "gradnorm_segnet", "compact_1l", "compact_15l", "compact_15l_mgn")
#: Equivalence margin of "15L+MGN and 15L have equal MV" (nuScenes): one unit of the paper's
#: printed precision (3 decimals), the smallest difference Table II could show.
MV_MARGIN = 1e-3
NO_DATA = "no data"
WEIGHT_KEYS: tuple[str, ...] = ("w_de", "w_ss", "w_ls", "w_bevp")

#: (claim id, short statement) in scorecard order.
CLAIMS: tuple[tuple[str, str], ...] = (
    ("lidar-tm", "15L has a lower TM than 1L"),
    ("lidar-ls", "15L has a higher IoU_LS than 1L"),
    ("mgn-tm", "15L+MGN has a lower TM than 15L"),
    ("mgn-mv", "15L+MGN has a lower MV than 15L (equal on nuScenes)"),
    ("vs-combination", "15L+MGN has a lower TM than the combination (the combination wins on C)"),
    ("polarnet-ls", "PolarNet has the highest IoU_LS"),
    ("mgn-weights", "MGN gives DE the largest final loss weight"),
)

RULE_TEXT = (
    "**Verdict rule** (CLAIMS.md). Every difference is oriented so that a positive value means the claim holds. "
    "`reproduced`: the whole 95% interval lies above 0; `contradicted`: it lies wholly below 0; `inconclusive`: "
    "otherwise (an interval touching 0 included). Equality claims use an equivalence margin m: `reproduced` when "
    "the interval lies within [−m, m], `contradicted` when it lies wholly outside, `inconclusive` otherwise; "
    f"the margin for \"equal MV on nuScenes\" is m = {MV_MARGIN:g} (one unit of the paper's printed precision). "
    "Intervals: paired percentile bootstrap, "
    f"{N_BOOT} replicates with a fixed RNG seed: the seeds (trainings) of each model are resampled, then the test "
    "frames within each seed, with the same resampled frames for every model compared. MV is one number per run "
    "(eq. 7 of the four test-set means), so its interval comes from recomputing MV from the resampled means. "
    "The combination's per-frame scores join GradNorm (DE, SS), PolarNet (LS) and Chen et al. (BEVP) on the same "
    "frame. `mgn-weights`: one observation per training seed, w_DE − max(w_SS, w_LS, w_BEVP) of the final weights "
    f"(runs/<ds>/compact_15l_mgn/summary.json); its interval is a bootstrap over seeds, and with fewer than "
    f"{MIN_SEEDS} seeds the verdict is `inconclusive` (one training is a single observation). "
    f"`{NO_DATA}`: an input the claim needs is missing. `paper`: the same difference from the paper's printed "
    "Table II (Fig. 8's weights are not printed)."
)


@dataclass(frozen=True)
class ClaimRow:
    """One line of the scorecard."""

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
         margin: Optional[float] = None, note: str = "") -> ClaimRow:
    if res is None:
        return ClaimRow(ds, claim, statement, paper, None, None, None, None, None, NO_DATA, margin, note)
    lo = None if math.isnan(res.ci_low) else res.ci_low
    hi = None if math.isnan(res.ci_high) else res.ci_high
    return ClaimRow(ds, claim, statement, paper, res.estimate, lo, hi, min(res.n_seeds), res.n_frames or None,
                    verdict(res.ci_low, res.ci_high, margin), margin, note)


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
          col: str, paper: Optional[float], n_boot: int, margin: Optional[float] = None) -> ClaimRow:
    """``better`` beats ``worse`` on ``col`` (a task column, ``tm`` or ``mv``)."""
    cols = [col] if col in TASK_METRICS else list(TASK_METRICS)
    groups = _groups(frames, [better, worse], cols)
    if groups is None:
        return _row(ds, claim, statement, paper, None, margin, _missing(frames, [better, worse]))
    stat = stat_mean if col in TASK_METRICS else stat_tm if col == "tm" else stat_mv
    res = paired_bootstrap(groups[0], groups[1], stat, lower_is_better=col in ("mae_de", "tm", "mv"), n_boot=n_boot)
    return _row(ds, claim, statement, paper, res, margin)


def _polarnet_ls(ds: str, frames: dict[str, list[pd.DataFrame]], paper: PaperNumbers, n_boot: int) -> ClaimRow:
    """IoU_LS(PolarNet) - max over the other models performing LS (all compared on the same frames)."""
    statement = dict(CLAIMS)["polarnet-ls"]
    others = [m for m in ("compact_1l", "compact_15l", "compact_15l_mgn") if frames.get(m)]
    pv = _pv(paper, ds, "polarnet", "iou_ls")
    po = [v for v in (_pv(paper, ds, m, "iou_ls") for m in ("compact_1l", "compact_15l", "compact_15l_mgn"))
          if v is not None]
    pdiff = _pdiff(pv, max(po)) if po else None
    groups = _groups(frames, ["polarnet"] + others, ["iou_ls"]) if others else None
    if groups is None:
        return _row(ds, "polarnet-ls", statement, pdiff, None,
                    note=_missing(frames, ["polarnet", "compact_1l", "compact_15l", "compact_15l_mgn"]))
    res = bootstrap_contrast(groups, stat_mean, lambda v: v[..., 0] - v[..., 1:].max(axis=-1), n_boot=n_boot)
    return _row(ds, "polarnet-ls", statement, pdiff, res,
                note=f"against the best of {', '.join(LABEL[m] for m in others)}")


def mgn_weight_margins(root: Path, ds: str) -> list[float]:
    """Per MGN run (seed): ``w_de - max(w_ss, w_ls, w_bevp)`` of the final weights (errors
    name the summary file)."""
    out = []
    for run in list_runs(root, ds, "compact_15l_mgn"):
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
        out.append(vals["w_de"] - max(vals[k] for k in WEIGHT_KEYS[1:]))
    return out


def _mgn_weights(root: Path, ds: str, n_boot: int) -> ClaimRow:
    statement = dict(CLAIMS)["mgn-weights"]
    margins = mgn_weight_margins(root, ds)
    if not margins:
        return _row(ds, "mgn-weights", statement, None, None, note="no 15L+MGN summary.json")
    res = seed_bootstrap(margins, n_boot=n_boot)
    note = "paper: Fig. 8 legend values not printed in the text"
    if len(margins) < MIN_SEEDS:
        note = (f"{len(margins)} seed(s) < {MIN_SEEDS}: a single observation, no verdict; DE "
                f"{'is' if all(m > 0 for m in margins) else 'is not'} the largest weight in "
                f"{'every' if len(margins) > 1 else 'this'} run. " + note)
    return _row(ds, "mgn-weights", statement, None, res, note=note)


# ----------------------------------------------------------------------------- scorecard
def claims_for_dataset(root: Path, ds: str, paper: PaperNumbers, frames: Optional[dict[str, list[pd.DataFrame]]] = None,
                       *, n_boot: int = N_BOOT) -> list[ClaimRow]:
    """Every claim of :data:`CLAIMS` on dataset ``ds`` (in that order)."""
    frames = load_row_frames(root, ds, MODELS) if frames is None else frames
    st = dict(CLAIMS)
    rows = [
        _pair(ds, "lidar-tm", st["lidar-tm"], frames, "compact_15l", "compact_1l", "tm",
              _pdiff(_paper_tm(paper, ds, "compact_1l"), _paper_tm(paper, ds, "compact_15l")), n_boot),
        _pair(ds, "lidar-ls", st["lidar-ls"], frames, "compact_15l", "compact_1l", "iou_ls",
              _pdiff(_pv(paper, ds, "compact_15l", "iou_ls"), _pv(paper, ds, "compact_1l", "iou_ls")), n_boot),
        _pair(ds, "mgn-tm", st["mgn-tm"], frames, "compact_15l_mgn", "compact_15l", "tm",
              _pdiff(_paper_tm(paper, ds, "compact_15l"), _paper_tm(paper, ds, "compact_15l_mgn")), n_boot),
        _pair(ds, "mgn-mv", "15L+MGN and 15L have equal MV (paper, nuScenes)" if ds == "nuscenes" else
              "15L+MGN has a lower MV than 15L", frames, "compact_15l_mgn", "compact_15l", "mv",
              _pdiff(_pv(paper, ds, "compact_15l", "mv"), _pv(paper, ds, "compact_15l_mgn", "mv")), n_boot,
              margin=MV_MARGIN if ds == "nuscenes" else None),
    ]
    if ds == "C":  # the paper: the combination wins on C (0.976 vs 0.999)
        rows.append(_pair(ds, "vs-combination", "the combination has a lower TM than 15L+MGN (paper, set C)", frames,
                          "combination", "compact_15l_mgn", "tm",
                          _pdiff(_paper_tm(paper, ds, "compact_15l_mgn"), _paper_tm(paper, ds, "combination")), n_boot))
    else:
        rows.append(_pair(ds, "vs-combination", "15L+MGN has a lower TM than the combination", frames,
                          "compact_15l_mgn", "combination", "tm",
                          _pdiff(_paper_tm(paper, ds, "combination"), _paper_tm(paper, ds, "compact_15l_mgn")), n_boot))
    rows.append(_polarnet_ls(ds, frames, paper, n_boot))
    rows.append(_mgn_weights(root, ds, n_boot))
    return rows


def build_claims(root: Path, datasets: Sequence[str], paper: PaperNumbers, *,
                 frames: Optional[dict[str, dict[str, list[pd.DataFrame]]]] = None, n_boot: int = N_BOOT
                 ) -> list[ClaimRow]:
    """The scorecard, sorted by claim (order of :data:`CLAIMS`) then dataset (order given)."""
    rows: list[ClaimRow] = []
    for ds in datasets:
        rows += claims_for_dataset(root, ds, paper, (frames or {}).get(ds), n_boot=n_boot)
    order = {c: i for i, (c, _) in enumerate(CLAIMS)}
    ds_order = {d: i for i, d in enumerate(datasets)}
    return sorted(rows, key=lambda r: (order[r.claim], ds_order[r.dataset]))


# ----------------------------------------------------------------------------- output
def _f(v: Optional[float], nd: int = 4) -> str:
    return "" if v is None else f"{v:+.{nd}f}"


def claims_markdown(rows: list[ClaimRow]) -> str:
    """The scorecard as Markdown, with the verdict rule."""
    head = ["Claim", "Dataset", "Statement", "Paper", "Measured", "95% CI", "Seeds", "Test frames", "Verdict", "Note"]
    lines = ["# Claims scorecard", "",
             "The paper's claims (CLAIMS.md) tested on this run's test scores; one row per claim and dataset.", "",
             "| " + " | ".join(head) + " |", "|" + "|".join(["---"] * 3 + ["---:"] * 5 + ["---"] * 2) + "|"]
    for r in rows:
        ci = "" if r.ci_low is None or r.ci_high is None else f"[{r.ci_low:+.4f}, {r.ci_high:+.4f}]"
        stmt = r.statement + (f" (margin ±{r.margin:g})" if r.margin is not None else "")
        lines.append("| " + " | ".join([
            f"`{r.claim}`", DATASET_LABEL.get(r.dataset, r.dataset), stmt,
            _f(r.paper, 3) if r.paper is not None else "not printed", _f(r.measured), ci,
            "" if r.n_seeds is None else str(r.n_seeds), "" if r.n_test_frames is None else str(r.n_test_frames),
            f"**{r.verdict}**", r.note]) + " |")
    lines += ["", RULE_TEXT, ""]
    return "\n".join(lines)


def claims_csv(rows: list[ClaimRow]) -> str:
    header = ["dataset", "claim", "statement", "paper", "measured", "ci_low", "ci_high", "margin", "n_seeds",
              "n_test_frames", "verdict", "note"]
    buf = _io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    for r in rows:
        vals: list[Any] = [r.dataset, r.claim, r.statement, r.paper, r.measured, r.ci_low, r.ci_high, r.margin,
                           r.n_seeds, r.n_test_frames, r.verdict, r.note]
        w.writerow(["" if v is None else (repr(v) if isinstance(v, float) else v) for v in vals])
    return buf.getvalue()


def write_claims(root: Path, datasets: Sequence[str], paper: PaperNumbers, out_dir: Path, *,
                 frames: Optional[dict[str, dict[str, list[pd.DataFrame]]]] = None, n_boot: int = N_BOOT
                 ) -> list[Path]:
    """Write ``claims.md`` and ``claims.csv`` under ``out_dir``; returns the paths."""
    rows = build_claims(root, datasets, paper, frames=frames, n_boot=n_boot)
    out = {Path(out_dir) / "claims.md": claims_markdown(rows), Path(out_dir) / "claims.csv": claims_csv(rows)}
    for path, text in out.items():
        io.write_text(path, text)
    log.info("claims: %s", {v: sum(r.verdict == v for r in rows) for v in sorted({r.verdict for r in rows})})
    return list(out)
