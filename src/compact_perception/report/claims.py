"""The claims scorecard: the paper's claims (``shared/CLAIMS.md``, section V-VI) tested on this
run's test scores, one row per claim, dataset and (for the claims about 15L+MGN) MGN form
(``reports/tables/claims.{md,csv}``).

Each claim is a difference oriented so that a positive value means the claim holds (e.g.
``TM(1L) - TM(15L)`` for "15L has a lower TM than 1L"). ``measured`` is that difference on
this run's test frames (each model's value the mean over its training seeds), ``ci_low`` /
``ci_high`` its 95% interval by :func:`compact_perception.stats.interval` (``seed-cluster-t``:
each model's runs keyed by training seed, paired where the models share seeds; the test frames'
episodes or scenes as clusters; the combination of baselines a derived model whose run of seed k
joins its three models' runs of seed k), ``mde`` the minimal detectable effect of that design at
80% power (:attr:`~compact_perception.stats.IntervalResult.mde`), ``paper`` the same difference
from the paper's printed Table II (``paper_numbers.yaml``).

Verdicts (:data:`compact_perception.stats.VERDICTS`): ``reproduced``, ``contradicted`` and
``inconclusive`` by :func:`compact_perception.stats.comparison_verdict`, only where the run can
decide the claim; otherwise ``not decidable`` with the reasons in the note:

- ``n seeds: <model>``: a model compared has fewer than :data:`~compact_perception.stats.MIN_SEEDS`
  training seeds (no verdict from a single run);
- ``below floor: 15L LS``: a model compared is not above the trivial-predictor floor on a metric
  the claim uses (:mod:`.gate`; TM and MV use all four task metrics), ``above_floor`` lists them;
- ``not converged: max_epochs``: ``mgn-weights`` is claimed at convergence, so every MGN run must
  have stopped early (``summary.json`` ``stop_reason`` ``plateau``);
- ``no data: ...``: an input the claim needs is missing.

The claims about 15L+MGN (``mgn-tm``, ``mgn-mv``, ``vs-combination``, ``mgn-weights``) are
tested once per MGN form: ``compact_15l_mgn`` (Algorithm 1 as printed, variant ``Alg. 1``) and
``compact_15l_mgn_authors`` (the authors' public code, variant ``authors' code``); the paper's
number is its one 15L+MGN row (which came from the authors' code) for both. The ``efficiency/*``
rows (Table III) are exact counts (and FPS's timed range), reported apart and left out of the
verdict counts (:func:`verdict_counts`, :func:`exact_counts`).

Per-frame scores come from ``data/eval/<ds>/<model>/seed<k>/per_frame.csv`` of every run that
:func:`..collect.list_runs` lists for the seeds of params.yaml; MGN's final weights and every
run's stop reason from ``runs/<ds>/<mgn model>/seed<k>/summary.json``.
"""
from __future__ import annotations

import functools
import math
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Optional, Sequence

import numpy as np
import pandas as pd

from ..core import catalog
from ..core.cache import frame_cluster
from ..stats import (METHOD, MIN_SEEDS, NOT_DECIDABLE, CoverageResult, Design, MAX_SEEDS_TO_DECIDE, IntervalResult,
                     comparison_verdict, coverage, coverage_line, interval,
                     seed_interval, seeds_to_decide, undecidable_reasons, verdict)
from .collect import (CONVERGED, ReportInputError, SeedSpec, frame_comparison, list_runs, load_row_frames,
                      read_summary, seeds_for)
from .gate import NO_FLOOR, Gate, Margin, dataset_gate, failing_text
from .paper import PaperNumbers
from .schema import (COMBINATION, COMBINATION_MODELS, COMPACT, DATASET_LABEL, LOWER_IS_BETTER, MGN_FORMS, PAPER_MGN,
                     ROW_LABEL, TASK_COLUMNS, WEIGHT_KEYS, beats, column_stat, stat_columns, weight_key)
from .scorecard import (FLOOR_NA, ClaimRow, claims_csv, claims_markdown, exact_counts,  # noqa: F401
                        verdict_counts)  # exact_counts, verdict_counts: the index imports them from here
from .tables.table3 import Table3Row, build_table3


LABEL: dict[str, str] = {**ROW_LABEL, COMBINATION: "the combination"}
CLAIM_MODELS: tuple[str, ...] = catalog.model_ids()  # the models whose per-frame scores the claims read
#: Equivalence margin of "15L+MGN and 15L have equal MV" (nuScenes): one unit of the paper's
#: printed precision (3 decimals), the smallest difference Table II could show.
MV_MARGIN = 1e-3
#: The note's prefix where an input the claim needs is missing (the verdict: ``not decidable``).
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
    ("mgn-weights", "MGN gives DE the largest final loss weight (at convergence)"),
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
    f"**`{NOT_DECIDABLE}`** instead of a verdict, with the reason in the note, where the run cannot decide the "
    f"claim: a model compared has fewer than {MIN_SEEDS} training seeds (`1 seed: <model>`: no verdict from a single "
    "run); a model compared is not above the trivial-predictor floor on a metric the claim uses (`below floor: 15L "
    "LS`; TM and MV use all four task metrics; `mgn-weights` all four of the MGN model): above means the 95% "
    "interval of its margin over the floor (same method, the floor's predictor fixed) lies above 0, see Table II; "
    "`mgn-weights` is claimed at convergence, so every MGN run must have been stopped by early stopping "
    "(`not converged: max_epochs` otherwise); `no data`: an input is missing. `Above floor`: `yes`, or the models "
    "and tasks below it. "
    "`lidar-de-ss` is claimed for the simulated sets only (the paper: DE degrades on nuScenes), so nuScenes has no row. "
    "`mgn-tradeoff` is one row per metric: 15L+MGN better on LS and BEVP, 15L better on DE and SS. "
    "`measured`: the difference of the models' values, each the mean over its training seeds (params.yaml `seeds`; "
    f"the baselines `baseline_seeds`) of the run's statistic on all test frames. **Intervals**: `{METHOD}` "
    "(compact_perception.stats): the contrast linearised over the runs' per-episode (nuScenes: per-scene) means, "
    "the variance over training seeds (paired where the models share seeds: a seed fixes the initial weights and "
    "the batch order of every model) and the variance over the test episodes (consecutive frames of one drive are "
    "not independent) each with its own t quantile; its measured coverage at this run's design is the line above "
    "the table. MV is one number per run (eq. 7 of the four test-set means), linearised the same way. "
    "**MDE**: the minimal detectable effect of the row's design, the true difference the interval would find "
    "with 80% power at two-sided 5% ((t_{0.975,df} + t_{0.8,df}) × SE); beside the paper's effect it tells whether "
    "`inconclusive` means no effect or an effect this run could not have seen. **Seeds to decide**: the training "
    "seeds per model at which the row's MDE falls to the paper's effect (|Paper|), found from this run's variance "
    "components: the seed part (the variance of the seeds' contrasts over the seeds) scaled to S seeds on S − 1 df, "
    "the test episodes' part net of the run × episode interaction unchanged (the same test frames), the same "
    f"interval as the row's; `>{MAX_SEEDS_TO_DECIDE}`: no seed count reaches it (the test episodes limit the design: "
    "more test frames, i.e. a larger scale, are needed); empty: no printed effect, a claim of equality, or a model "
    "with one seed (no seed variance to scale). "
    "The combination's per-frame scores join GradNorm (DE, SS), PolarNet (LS) and Chen et al. (BEVP) of the same "
    "seed on the same frame. `Seeds`: the number of runs of each model compared (the CSV's `n_seeds` is the "
    "smallest). The claims about 15L+MGN are tested for both MGN forms, one row each: `Alg. 1` = "
    "compact_15l_mgn (Algorithm 1 as the paper prints it), `authors' code` = compact_15l_mgn_authors (MGN as the "
    "authors' public code runs it); `paper` is the paper's one 15L+MGN row for both (its Table II came from the "
    "authors' code). `mgn-weights`: one observation per training seed, w_DE − max(w_SS, w_LS, w_BEVP) of the final "
    "weights (runs/<ds>/<MGN model>/seed<k>/summary.json), with the t interval over seeds. "
    "**Exact counts, apart**: `efficiency/*` (Table III, results/benchmark/efficiency.json): 15L+MGN against the "
    "combination, whose parameters, size, memory and latency are the sums of its three models; params and size are "
    "exact counts and the memory an exact estimate (forward hooks), so their interval is the value itself; FPS is "
    "timed, and its range (not a statistical interval) comes from each model's fastest and 90th-percentile latency "
    "of the timed runs; the paper's numbers come from a GTX 1080 Ti GPU, this run's from the benchmark's device. "
    "They are not counted with the claims judged on test scores. `paper`: the same difference from the paper's "
    "printed Table II (Fig. 8's weights are not printed)."
)


@dataclass(frozen=True)
class _Context:
    """One dataset's inputs: per-frame scores of every row (the combination included), the gate."""

    dataset: str
    frames: dict[str, list[pd.DataFrame]]
    gate: Gate
    paper: PaperNumbers


# ----------------------------------------------------------------------------- paper differences
def _pv(paper: PaperNumbers, ds: str, row: str, col: str) -> Optional[float]:
    r = paper.table2_row(ds, row)
    return None if r is None else r.value(col)


def _pdiff(a: Optional[float], b: Optional[float]) -> Optional[float]:
    """``a - b`` rounded to the paper's precision (printed numbers have 3 decimals)."""
    return None if a is None or b is None else round(a - b, 6)


def _paper_tm(paper: PaperNumbers, ds: str, row: str) -> Optional[float]:
    return _pv(paper, ds, row, "tm")


# ----------------------------------------------------------------------------- deciding a row
def _opt(v: float) -> Optional[float]:
    return float(v) if math.isfinite(v) else None


def seeds_needed(res: IntervalResult, paper: Optional[float], margin: Optional[float] = None) -> str:
    """The scorecard's ``seeds_to_decide``: the seeds per model at which the row's design detects the
    paper's effect with 80% power (:func:`~compact_perception.stats.seeds_to_decide`), ``>N`` where
    even :data:`~compact_perception.stats.MAX_SEEDS_TO_DECIDE` seeds do not (the test episodes limit
    it), empty where it cannot be said: no printed effect, a claim of equality (its margin, not an
    effect, decides it), or a trained model with one seed (no seed variance to scale)."""
    if paper is None or margin is not None or res.parts is None:
        return ""
    if not res.parts.seed or not all(math.isfinite(v) for v, _ in res.parts.seed):
        return ""
    n = seeds_to_decide(res, paper)
    return str(n) if n is not None else f">{MAX_SEEDS_TO_DECIDE}"


def _gate(ctx: _Context, uses: Sequence[tuple[str, Sequence[str]]]) -> tuple[str, Optional[str]]:
    """``above_floor`` of the models compared, each on the metrics the claim uses (``uses``:
    (row id, metrics)), and the reason the claim is not decidable because of it (``None``: every
    model is above the floor)."""
    failing: list[tuple[str, list[Margin]]] = [(r, ctx.gate.failing(r, metrics)) for r, metrics in uses]
    if not any(m for _, m in failing):
        return "yes", None
    if any(x.status == NO_FLOOR for _, ms in failing for x in ms):
        return "no floor", f"no floor results for {DATASET_LABEL.get(ctx.dataset, ctx.dataset)}"
    text = failing_text(failing, LABEL)
    return f"no: {text}", f"below floor: {text}"


def _decided(ctx: _Context, claim: str, statement: str, paper: Optional[float], res: IntervalResult,
             uses: Sequence[tuple[str, Sequence[str]]], margin: Optional[float] = None, *, model: str,
             note: str = "", extra_reasons: Sequence[str] = ()) -> ClaimRow:
    """A row from its interval: the verdict, or ``not decidable`` with its reasons (too few seeds,
    a model not above the floor, ``extra_reasons``) first in the note."""
    above, floor_reason = _gate(ctx, uses)
    reasons = undecidable_reasons(res, [LABEL.get(r, r) for r, _ in uses]) + list(extra_reasons) + ([floor_reason] if floor_reason else [])
    verdict_ = NOT_DECIDABLE if reasons else comparison_verdict(res, margin)
    note = "; ".join([*reasons, note] if note else reasons)
    variant = MGN_FORMS.get(model, "") if claim in MGN_CLAIMS else ""
    return ClaimRow(ctx.dataset, claim, statement, paper, _opt(res.estimate), _opt(res.ci_low), _opt(res.ci_high),
                    min(res.n_seeds), res.n_frames or None, verdict_, margin, note, model, variant,
                    tuple(res.n_seeds), _opt(res.mde), above, seeds_needed(res, paper, margin))


def _no_data(ds: str, claim: str, statement: str, paper: Optional[float], why: str, margin: Optional[float] = None,
             *, model: str, note: str = "", above: str = "") -> ClaimRow:
    """A row whose inputs are missing: ``not decidable``, the note says what is missing."""
    variant = MGN_FORMS.get(model, "") if claim in MGN_CLAIMS else ""
    text = f"{NO_DATA}: {why}" + (f"; {note}" if note else "")
    return ClaimRow(ds, claim, statement, paper, None, None, None, None, None, NOT_DECIDABLE, margin, text, model,
                    variant, above_floor=above)


def _missing(frames: dict[str, list[pd.DataFrame]], rows: Sequence[str]) -> str:
    miss = [LABEL.get(r, r) for r in rows if not frames.get(r)]
    return f"no per-frame scores for {', '.join(miss)}" if miss else "per-frame scores lack a column"


def _compare(ctx: _Context, claim: str, statement: str, rows: Sequence[str], col: str,
             contrast: Callable[[np.ndarray], np.ndarray], paper: Optional[float], margin: Optional[float] = None, *,
             model: str, note: str = "") -> ClaimRow:
    """The claim ``contrast`` of ``rows``' values on ``col`` (a task column, ``tm`` or ``mv``)."""
    cols = stat_columns(col)
    runs = [ctx.frames.get(r) or [] for r in rows]
    if not all(runs) or not all(c in df.columns for g in runs for df in g for c in cols):
        return _no_data(ctx.dataset, claim, statement, paper, _missing(ctx.frames, rows), margin, model=model,
                        note=note)
    try:
        comp = frame_comparison(runs, cols)
    except ReportInputError as err:
        return _no_data(ctx.dataset, claim, statement, paper, str(err), margin, model=model, note=note)
    res = interval(comp, column_stat(col), contrast)
    return _decided(ctx, claim, statement, paper, res, [(r, cols) for r in rows], margin, model=model, note=note)


def _pair(ctx: _Context, claim: str, statement: str, better: str, worse: str, col: str, paper: Optional[float],
          margin: Optional[float] = None, *, model: str, note: str = "") -> ClaimRow:
    """``better`` beats ``worse`` on ``col``; ``model``: whose claim."""
    return _compare(ctx, claim, statement, [better, worse], col, beats(col), paper, margin, model=model, note=note)


def _polarnet_ls(ctx: _Context) -> ClaimRow:
    """IoU_LS(PolarNet) - max over the compact models (all compared on the same frames)."""
    ds, paper = ctx.dataset, ctx.paper
    statement = dict(CLAIMS)["polarnet-ls"]
    others = [m for m in COMPACT if ctx.frames.get(m)]
    pv = _pv(paper, ds, "polarnet", "iou_ls")
    po = [v for v in (_pv(paper, ds, m, "iou_ls") for m in COMPACT) if v is not None]
    pdiff = _pdiff(pv, max(po)) if po else None
    if not others or not ctx.frames.get("polarnet"):
        return _no_data(ds, "polarnet-ls", statement, pdiff, _missing(ctx.frames, ["polarnet", *COMPACT]),
                        model="polarnet")
    return _compare(ctx, "polarnet-ls", statement, ["polarnet", *others], "iou_ls",
                    lambda v: v[..., 0] - v[..., 1:].max(axis=-1), pdiff, model="polarnet",
                    note=f"against the best of {', '.join(LABEL[m] for m in others)}")


# ----------------------------------------------------------------------------- MGN's final weights
def _weight_margin(path: Path, w: Any) -> float:
    """``w_de - max(w_ss, w_ls, w_bevp)`` of one ``final_weights`` block (errors name the file)."""
    if not isinstance(w, dict) or any(k not in w for k in WEIGHT_KEYS):
        raise ReportInputError(f"{path}: final_weights must hold {list(WEIGHT_KEYS)}, got {w!r}")
    try:
        vals = {k: float(w[k]) for k in WEIGHT_KEYS}
    except (TypeError, ValueError):
        raise ReportInputError(f"{path}: final_weights has a non-numeric value: {w!r}") from None
    if not all(math.isfinite(v) for v in vals.values()):
        raise ReportInputError(f"{path}: final_weights has a non-finite value: {w!r}")
    de = weight_key("de")
    return vals[de] - max(v for k, v in vals.items() if k != de)


def mgn_weight_runs(root: Path, ds: str, model: str = "compact_15l_mgn",
                    seeds: Optional[Sequence[int]] = None) -> list[tuple[float, Optional[str]]]:
    """Per MGN run with a ``summary.json`` (seed of ``seeds``, see :func:`..collect.list_runs`):
    ``w_de - max(w_ss, w_ls, w_bevp)`` of the final weights (every task's,
    :data:`~.schema.WEIGHT_KEYS`) and the run's ``stop_reason`` (``None`` if it has none)."""
    out = []
    for run in list_runs(root, ds, model, seeds):
        summ = read_summary(run.run_dir)
        if summ is not None:
            stop = summ.get("stop_reason")
            out.append((_weight_margin(run.run_dir / "summary.json", summ.get("final_weights")),
                        None if stop is None else str(stop)))
    return out


def _mgn_weights(ctx: _Context, root: Path, model: str, seeds: Optional[Sequence[int]] = None) -> ClaimRow:
    """DE has the largest final weight in every run, at convergence: decided only when every run
    stopped early (``stop_reason`` ``plateau``) and the MGN model is above the floor on every task."""
    statement = f"{LABEL[model]}: MGN gives DE the largest final loss weight (at convergence)"
    runs = mgn_weight_runs(root, ctx.dataset, model, seeds)
    if not runs:
        return _no_data(ctx.dataset, "mgn-weights", statement, None, f"no {LABEL[model]} summary.json", model=model)
    stops = Counter(s or "no stop_reason" for _, s in runs if s != CONVERGED)
    conv = ["not converged: " + ", ".join(f"{s} ({n} of {len(runs)} runs)" for s, n in sorted(stops.items()))] \
        if stops else []
    res = seed_interval([m for m, _ in runs])
    return _decided(ctx, "mgn-weights", statement, None, res, [(model, TASK_COLUMNS)], model=model,
                    note="paper: Fig. 8 legend values not printed in the text", extra_reasons=conv)


# ----------------------------------------------------------------------------- scorecard
def _lidar_rows(ctx: _Context, st: dict[str, str]) -> list[ClaimRow]:
    """The claims about the 15-layer LiDAR input (15L against 1L)."""
    ds, paper = ctx.dataset, ctx.paper
    rows = [
        _pair(ctx, "lidar-tm", st["lidar-tm"], "compact_15l", "compact_1l", "tm",
              _pdiff(_paper_tm(paper, ds, "compact_1l"), _paper_tm(paper, ds, "compact_15l")), model="compact_15l"),
        _pair(ctx, "lidar-ls", st["lidar-ls"], "compact_15l", "compact_1l", "iou_ls",
              _pdiff(_pv(paper, ds, "compact_15l", "iou_ls"), _pv(paper, ds, "compact_1l", "iou_ls")),
              model="compact_15l"),
    ]
    if ds in catalog.sim_dataset_ids():
        for claim, col in (("lidar-de-ss/de", "mae_de"), ("lidar-de-ss/ss", "iou_ss")):
            a, b = _pv(paper, ds, "compact_15l", col), _pv(paper, ds, "compact_1l", col)
            rows.append(_pair(ctx, claim, st[claim], "compact_15l", "compact_1l", col,
                              _pdiff(b, a) if col in LOWER_IS_BETTER else _pdiff(a, b), model="compact_15l"))
    rows.append(_pair(ctx, "lidar-bevp", st["lidar-bevp"], "compact_15l", "compact_1l", "iou_bevp",
                      _pdiff(_pv(paper, ds, "compact_15l", "iou_bevp"), _pv(paper, ds, "compact_1l", "iou_bevp")),
                      margin=BEVP_MARGIN, model="compact_15l"))
    return rows


def _mgn_rows(ctx: _Context, mgn: str) -> list[ClaimRow]:
    """The claims about 15L+MGN for one MGN form (the paper's number: its one 15L+MGN row)."""
    ds, paper, lab = ctx.dataset, ctx.paper, LABEL[mgn]
    note = "paper: its one 15L+MGN row (from the authors' code)"
    rows = [_pair(ctx, "mgn-tm", f"{lab} has a lower TM than 15L", mgn, "compact_15l", "tm",
                  _pdiff(_paper_tm(paper, ds, "compact_15l"), _paper_tm(paper, ds, PAPER_MGN)), model=mgn, note=note),
            _pair(ctx, "mgn-mv", f"{lab} and 15L have equal MV (paper, nuScenes)" if ds == "nuscenes" else
                  f"{lab} has a lower MV than 15L", mgn, "compact_15l", "mv",
                  _pdiff(_pv(paper, ds, "compact_15l", "mv"), _pv(paper, ds, PAPER_MGN, "mv")),
                  margin=MV_MARGIN if ds == "nuscenes" else None, model=mgn, note=note)]
    for claim, winner, col in TRADEOFF:
        better, worse = (mgn, "compact_15l") if winner == "mgn" else ("compact_15l", mgn)
        pb, pw = (_pv(paper, ds, PAPER_MGN if m == mgn else m, col) for m in (better, worse))
        low = col in LOWER_IS_BETTER
        text = (f"{LABEL[better] if winner == 'mgn' else '15L'} has a {'lower' if low else 'higher'} "
                f"{catalog.column_label(col)} than {'15L' if winner == 'mgn' else LABEL[worse]}")
        rows.append(_pair(ctx, claim, text, better, worse, col, _pdiff(pw, pb) if low else _pdiff(pb, pw),
                          model=mgn, note=note))
    if ds == "C":  # the paper: the combination wins on C (0.976 vs 0.999)
        rows.append(_pair(ctx, "vs-combination", f"the combination has a lower TM than {lab} (paper, set C)",
                          COMBINATION, mgn, "tm",
                          _pdiff(_paper_tm(paper, ds, PAPER_MGN), _paper_tm(paper, ds, COMBINATION)), model=mgn,
                          note=note))
    else:
        rows.append(_pair(ctx, "vs-combination", f"{lab} has a lower TM than the combination", mgn, COMBINATION, "tm",
                          _pdiff(_paper_tm(paper, ds, COMBINATION), _paper_tm(paper, ds, PAPER_MGN)), model=mgn,
                          note=note))
    return rows


def claims_for_dataset(root: Path, ds: str, paper: PaperNumbers, frames: Optional[dict[str, list[pd.DataFrame]]] = None,
                       *, seeds: SeedSpec = None, gate: Optional[Gate] = None) -> list[ClaimRow]:
    """Every claim of :data:`CLAIMS` on dataset ``ds`` but Table III's (in that order; the claims
    about 15L+MGN once per MGN form of :data:`~.schema.MGN_FORMS`). ``seeds``: the seed lists (see
    :func:`..collect.list_runs`); ``frames``: per-frame scores already loaded with them; ``gate``:
    the dataset's gate (:mod:`.gate`; built from the floor's outputs under ``root`` if ``None``)."""
    frames = load_row_frames(root, ds, CLAIM_MODELS, seeds) if frames is None else frames
    ctx = _Context(ds, frames, gate if gate is not None else dataset_gate(root, ds, frames), paper)
    rows = _lidar_rows(ctx, dict(CLAIMS))
    for mgn in MGN_FORMS:
        rows += _mgn_rows(ctx, mgn)
        rows.append(_mgn_weights(ctx, root, mgn, seeds_for(seeds, mgn, ds)))
    rows.append(_polarnet_ls(ctx))
    return rows


def build_claims(root: Path, datasets: Sequence[str], paper: PaperNumbers, *,
                 frames: Optional[dict[str, dict[str, list[pd.DataFrame]]]] = None, seeds: SeedSpec = None,
                 efficiency: Optional[Mapping[str, Any]] = None, table3: Optional[dict[str, list[Table3Row]]] = None,
                 gates: Optional[Mapping[str, Gate]] = None) -> list[ClaimRow]:
    """The scorecard, sorted by claim (order of :data:`CLAIMS`), then dataset (order given), then
    MGN form (order of :data:`~.schema.MGN_FORMS`). ``efficiency``: ``results/benchmark/efficiency.json``
    for the Table III claims (left out when None); ``table3``: its Table III if already built;
    ``gates``: per dataset, the gate already built."""
    rows: list[ClaimRow] = []
    for ds in datasets:
        rows += claims_for_dataset(root, ds, paper, (frames or {}).get(ds), seeds=seeds, gate=(gates or {}).get(ds))
    if efficiency is not None:
        rows += [r for r in efficiency_claims(efficiency, paper, table3=table3) if r.dataset in datasets]
    order = {c: i for i, (c, _) in enumerate(CLAIMS)}
    ds_order = {d: i for i, d in enumerate(datasets)}
    v_order = {m: i for i, m in enumerate(MGN_FORMS)}
    return sorted(rows, key=lambda r: (order[r.claim], ds_order[r.dataset], v_order.get(r.model, -1)))


#: The Table III claims: claim -> the column (:data:`~.schema.TABLE3_COLUMNS`) whose totals they compare.
EFFICIENCY_CLAIMS: dict[str, str] = {"efficiency/params": "total_params", "efficiency/size": "total_size_mb",
                                     "efficiency/memory": "peak_memory_mb", "efficiency/fps": "fps"}


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
        for claim, field in EFFICIENCY_CLAIMS.items():
            if mgn is None or comb is None or not (mgn.available and comb.available):
                rows.append(_no_data(ds, claim, st[claim], None, "no benchmark of 15L+MGN or of all three baselines",
                                     model=model, above=FLOOR_NA))
                continue
            sign = 1.0 if field == "fps" else -1.0
            measured = sign * (float(mgn.value(field)) - float(comb.value(field)))
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
            pa, pb = (pm.value(field) if pm else None), (pc.value(field) if pc else None)
            pdiff = None if pa is None or pb is None else round(sign * (float(pa) - float(pb)), 6)
            device = mgn.value("device") or "the benchmark's device"
            rows.append(ClaimRow(ds, claim, st[claim], pdiff, measured, None if math.isnan(lo) else lo,
                                 None if math.isnan(hi) else hi, None, None, verdict(lo, hi),
                                 note=f"measured on {device}" + ("; paper: GTX 1080 Ti" if claim in (
                                     "efficiency/memory", "efficiency/fps") else ""), model=model))
    return rows


# ----------------------------------------------------------------------------- coverage of the intervals
def _design(frames: Mapping[str, Sequence[pd.DataFrame]]) -> Optional[Design]:
    """This dataset's design for the coverage check: :data:`~compact_perception.stats.MIN_SEEDS`
    paired seeds and the test frames' clusters (episodes / scenes) of the first row with scores."""
    ids = next((g[0].index for m in CLAIM_MODELS if (g := frames.get(m))), None)
    if ids is None or len(ids) == 0:
        return None
    sizes = Counter(frame_cluster(str(f)) for f in ids)
    return Design(MIN_SEEDS, tuple(sizes[c] for c in sorted(sizes)), True)


@functools.lru_cache(maxsize=16)
def _coverage(design: Design) -> CoverageResult:
    return coverage(design)


def coverage_text(frames: Mapping[str, Mapping[str, Sequence[pd.DataFrame]]]) -> str:
    """The scorecard's one line on its intervals: the method and its coverage measured by
    simulation (:func:`compact_perception.stats.coverage`, deterministic) at each dataset's design."""
    designs: dict[Design, list[str]] = {}
    for ds, fr in frames.items():
        d = _design(fr)
        if d is not None and d.cluster_sizes and len(d.cluster_sizes) > 1:
            designs.setdefault(d, []).append(DATASET_LABEL.get(ds, ds))
    if not designs:
        return ""
    return "; ".join(f"{coverage_line(_coverage(d))} ({', '.join(labels)})" for d, labels in designs.items()) + "."


# ----------------------------------------------------------------------------- output
def claims_files(rows: list[ClaimRow], coverage: str = "") -> dict[str, str]:
    """The scorecard's ``claims.md`` and ``claims.csv`` (file name -> text); ``coverage``: the
    intervals' line (:func:`coverage_text`)."""
    return {"claims.md": claims_markdown(rows, coverage, RULE_TEXT), "claims.csv": claims_csv(rows)}
