"""Table II (test comparison), Table III (efficiency) and the paper-vs-reproduced table.

Every table is written as Markdown, LaTeX (booktabs) and CSV. Every model is trained once per
training seed (params ``seeds``; the baselines ``baseline_seeds``), so each Table II metric is
shown twice, each labelled:

- ``mean ± sd``: the mean over the seeds of the run-level value (a run's test-set mean; TM and
  MV of the run's four test-set means, eq. 6-7 via :func:`compact_perception.metrics.scores_from_means`)
  ± the sample standard deviation (n - 1) over the seeds; with one seed the mean and ``(n=1)``;
- ``var (frames)``: the paper's ``±`` column, the variance over test frames of the per-frame
  score, averaged over the seeds (a variance below 0.0005 prints as ``<0.001`` as in the paper).

The CSVs hold the raw numbers (``<col>_mean``, ``<col>_std``, ``<col>_var`` columns), the number
of seeds and of test frames per row.

Table II rows per dataset: Chen et al., PolarNet, GradNorm, Combination, 1L, 15L, 15L+MGN
(Alg. 1), 15L+MGN (authors' code). The combination takes GradNorm's DE/SS, PolarNet's LS and
Chen et al.'s BEVP of the same training seed, and its TM and MV per seed are computed from
those four means (eq. 6-7), like every compact run's, so all rows compare with each other and
with the paper. The paper prints one 15L+MGN row; its Table II came from the authors' public
code, and both of this run's MGN rows are compared with it.

Bold (lowest MAE / TM / MV, highest IoU) marks the best value of a column only where the
paired bootstrap over the seeds and test frames (:mod:`compact_perception.stats`) separates it
from the runner-up: the 95% interval of the difference excludes 0. Otherwise the best cell
is not bold and gets a dagger and an "inconclusive" note. The combination's task cells are
copies of its source models' and take no part in the task columns' comparison.

``extra_metrics.{md,csv}`` holds the metrics beyond the paper's (per-class IoU / mIoU of SS,
LS, BEVP; depth AbsRel, RMSE, delta < 1.25), from the ``class_iou`` / ``depth`` blocks of
the metrics files, as mean ± sd over the seeds.
"""
from __future__ import annotations

import csv
import io as _io
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Optional, Sequence

import numpy as np
import pandas as pd

from ..core import catalog, io
from ..metrics import DEPTH_METRICS, scores_from_means
from ..stats import REPRODUCED, BootstrapResult, paired_bootstrap, stat_mean, stat_mv, stat_tm, verdict
from .collect import (COMBINATION_SOURCE, Cell, DatasetScale, ModelResult, ReportInputError, aggregate_cells, align,
                      pair_by_seed)
from .paper import PaperCell, PaperNumbers

log = logging.getLogger(__name__)

TASK_COLUMNS: tuple[str, ...] = ("mae_de", "iou_ss", "iou_ls", "iou_bevp")
TABLE2_COLUMNS: tuple[str, ...] = TASK_COLUMNS + ("tm", "mv")
LOWER_IS_BETTER: frozenset[str] = frozenset({"mae_de", "tm", "mv"})
#: The baselines in the paper's row order.
BASELINES: tuple[str, ...] = ("chen_bev", "polarnet", "gradnorm_segnet")
COMPACT: tuple[str, ...] = catalog.compact_model_ids()
ROW_ORDER: tuple[str, ...] = BASELINES + ("combination",) + COMPACT
ROW_LABEL: dict[str, str] = {**{m: catalog.model_label(m) for m in catalog.model_ids()}, "combination": "Combination"}
DATASET_LABEL: dict[str, str] = {d: catalog.DATASETS[d].label for d in catalog.dataset_ids()}
#: The two MGN rows: Algorithm 1 as printed, and MGN as in the authors' public code.
MGN_MODELS: tuple[str, ...] = tuple(m for m in ("compact_15l_mgn", "compact_15l_mgn_authors") if m in ROW_LABEL)
#: The paper's Table II row a model's row is compared with (the paper prints one 15L+MGN row).
PAPER_ROW: dict[str, str] = {"compact_15l_mgn_authors": "compact_15l_mgn"}
MGN_NOTE = ("The paper prints one 15L+MGN row. Its Table II came from the authors' public code (SPEC 7: their "
            "weight gradients, Huber scale and plateau rule), so both of this run's MGN rows are compared with it: "
            "15L+MGN (Alg. 1) trains with Algorithm 1 as the paper prints it, 15L+MGN (authors' code) as the "
            "authors' code runs it.")
COLUMN_MD: dict[str, str] = {
    "mae_de": "MAE_DE", "iou_ss": "IoU_SS", "iou_ls": "IoU_LS", "iou_bevp": "IoU_BEVP", "tm": "TM", "mv": "MV",
}
COLUMN_TEX: dict[str, str] = {
    "mae_de": "$MAE_{DE}$", "iou_ss": "$IoU_{SS}$", "iou_ls": "$IoU_{LS}$", "iou_bevp": "$IoU_{BEVP}$",
    "tm": "$TM$", "mv": "$MV$",
}
DECIMALS = 3
NOT_APPLICABLE = "-"
NOT_AVAILABLE = "n/a"
INCONCLUSIVE_MARK = "†"
#: Per-frame scores of every row of one dataset: row id -> runs (seeds), frame_id-indexed.
RowFrames = dict[str, list[pd.DataFrame]]


# ----------------------------------------------------------------------------- formatting
def fmt_num(x: Optional[float], decimals: int = DECIMALS) -> str:
    return "" if x is None else f"{x:.{decimals}f}"


def fmt_var(v: Optional[float], decimals: int = DECIMALS, latex: bool = False) -> str:
    """A variance as the paper prints it: ``<0.001`` when it rounds to zero."""
    if v is None:
        return ""
    if v < 0.5 * 10 ** (-decimals):
        return ("$<$" if latex else "<") + f"{10 ** (-decimals):.{decimals}f}"
    return f"{v:.{decimals}f}"


def fmt_seeds(cell: Optional[Cell], latex: bool = False, decimals: int = DECIMALS) -> str:
    """``mean ± sd`` over the seeds (sample sd), or ``mean (n=1)`` for a single seed."""
    if cell is None:
        return NOT_APPLICABLE
    text = fmt_num(cell.mean, decimals)
    if cell.std is not None:
        return text + (" $\\pm$ " if latex else " ± ") + fmt_num(cell.std, decimals)
    return text + f" (n={cell.n_seeds})"


def fmt_cell(col: str, cell: Optional[Cell], latex: bool = False) -> str:
    """The seed cell of a column (:func:`fmt_seeds`)."""
    return fmt_seeds(cell, latex)


def _bold(text: str, latex: bool) -> str:
    return f"\\textbf{{{text}}}" if latex else f"**{text}**"


def tex_escape(text: str) -> str:
    """Escape LaTeX specials in plain text."""
    out = text
    for a, b in (("\\", "\\textbackslash{}"), ("&", "\\&"), ("%", "\\%"), ("_", "\\_"), ("#", "\\#"),
                 ("$", "\\$"), ("{", "\\{"), ("}", "\\}")):
        out = out.replace(a, b)
    return out


def _md_table(header: list[str], rows: list[list[str]], align: Optional[list[str]] = None) -> str:
    align = align or ["---"] * len(header)
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(align) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def _csv_text(header: list[str], rows: Iterable[list[Any]]) -> str:
    buf = _io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    for r in rows:
        w.writerow(["" if v is None else (repr(v) if isinstance(v, float) else v) for v in r])
    return buf.getvalue()


# ----------------------------------------------------------------------------- Table II
@dataclass
class Table2Row:
    """One row of Table II. ``cells[col] is None``: the model does not perform that task (or
    TM/MV do not apply); ``available`` is False when the row's inputs are missing. Every cell
    is over the row's ``n_seeds`` runs (:class:`~.collect.Cell`)."""

    dataset: str
    row_id: str
    label: str
    cells: dict[str, Optional[Cell]]
    available: bool = True
    bold: set[str] = field(default_factory=set)
    #: column -> why the best value of that column is not bold (bootstrap inconclusive / untested)
    notes: dict[str, str] = field(default_factory=dict)
    n_seeds: int = 0
    seeds: tuple[Optional[int], ...] = ()
    n_frames: Optional[int] = None


def combination_row(dataset: str, results: dict[str, ModelResult]) -> Table2Row:
    """GradNorm DE/SS + PolarNet LS + Chen BEVP. Task cells: the source models' own; TM and MV
    (eq. 6-7) per training seed from the four means of the three baselines' runs of that seed
    (:func:`~.collect.pair_by_seed`), then mean ± sd over those seeds."""
    cells: dict[str, Optional[Cell]] = {}
    for col, src in COMBINATION_SOURCE.items():
        res = results.get(src)
        cells[col] = res.scores.get(col) if res else None
    available = all(b in results for b in BASELINES)
    cells["tm"] = cells["mv"] = None
    seeds: tuple[Optional[int], ...] = ()
    if available:
        sources = sorted(set(COMBINATION_SOURCE.values()))
        groups = pair_by_seed([results[m].per_run() for m in sources], lambda r: r.seed)
        tms, mvs = [], []
        for group in groups:
            run = dict(zip(sources, group))
            means = {c: run[m].scores[c].mean for c, m in COMBINATION_SOURCE.items() if c in run[m].scores}
            derived = scores_from_means(means)
            if derived:
                tms.append(Cell(derived["tm"]))
                mvs.append(Cell(derived["mv"]))
        if tms:
            cells["tm"], cells["mv"] = aggregate_cells(tms), aggregate_cells(mvs)
            seeds = tuple(g[0].seed for g in groups)
    else:
        log.warning("%s: combination incomplete (missing %s)", dataset, [b for b in BASELINES if b not in results])
    frames = sorted({r.n_frames for m in BASELINES if m in results for r in results[m].per_run() if r.n_frames})
    return Table2Row(dataset, "combination", ROW_LABEL["combination"], cells, available, n_seeds=len(seeds),
                     seeds=seeds, n_frames=frames[0] if frames else None)


def model_row(dataset: str, model: str, result: Optional[ModelResult]) -> Table2Row:
    """A model's row from its runs' metrics files, aggregated over seeds by
    :func:`~.collect.aggregate_runs` (TM and MV recomputed per run from the run's four task
    means, eq. 6-7, exactly as for the combination); all ``None`` and unavailable if there is none."""
    label = ROW_LABEL.get(model, model)
    if result is None:
        return Table2Row(dataset, model, label, {c: None for c in TABLE2_COLUMNS}, available=False)
    cells: dict[str, Optional[Cell]] = {c: result.scores.get(c) for c in TABLE2_COLUMNS}
    return Table2Row(dataset, model, label, cells, n_seeds=result.n_seeds, seeds=result.seeds,
                     n_frames=result.n_frames)


def column_bootstrap(best: str, other: str, col: str, frames: RowFrames) -> Optional[BootstrapResult]:
    """Paired bootstrap (seeds, then test frames) of "row ``best`` beats row ``other`` on
    column ``col``" (positive = it does) from their per-frame scores; ``None`` if either has no
    per-frame scores for it."""
    cols = [col] if col in TASK_COLUMNS else list(TASK_COLUMNS)
    runs = [frames.get(best) or [], frames.get(other) or []]
    if not all(runs) or not all(all(c in df.columns for c in cols) for g in runs for df in g):
        return None
    try:
        a, b = align(runs, cols)
    except ReportInputError as err:
        log.warning("Table II %s: %s vs %s: %s", col, best, other, err)
        return None
    stat = stat_mean if col in TASK_COLUMNS else stat_tm if col == "tm" else stat_mv
    return paired_bootstrap(a, b, stat, lower_is_better=col in LOWER_IS_BETTER)


def mark_best(rows: list[Table2Row], frames: Optional[RowFrames] = None) -> None:
    """Bold the best value of each column where the bootstrap separates it from the runner-up
    (95% interval of the difference above 0); otherwise note why it is not bold."""
    frames = frames or {}
    for col in TABLE2_COLUMNS:
        cands = [r for r in rows if r.available and r.cells.get(col) is not None
                 and not (r.row_id == "combination" and col in TASK_COLUMNS)]
        if not cands:
            continue
        sign = 1.0 if col in LOWER_IS_BETTER else -1.0
        order = sorted(cands, key=lambda r: sign * r.cells[col].mean)  # type: ignore[union-attr]
        best = order[0]
        if len(order) == 1:
            best.bold.add(col)
            continue
        runner = order[1]
        res = column_bootstrap(best.row_id, runner.row_id, col, frames)
        if res is None:
            best.notes[col] = f"best {COLUMN_MD[col]}, not tested against {runner.label} (no per-frame scores): not bold"
        elif verdict(res.ci_low, res.ci_high) == REPRODUCED:
            best.bold.add(col)
        else:
            best.notes[col] = (f"best {COLUMN_MD[col]} inconclusive against {runner.label}: difference "
                               f"{res.estimate:.4f}, 95% CI [{res.ci_low:.4f}, {res.ci_high:.4f}]: not bold")


def build_table2(results: dict[str, dict[str, ModelResult]],
                 frames: Optional[dict[str, RowFrames]] = None) -> dict[str, list[Table2Row]]:
    """Rows per dataset in :data:`ROW_ORDER` (datasets with no results at all are skipped);
    ``frames[ds]``: per-frame scores per row id (``combination`` included) for the bold marks."""
    out: dict[str, list[Table2Row]] = {}
    for ds, res in results.items():
        if not res:
            continue
        rows = [combination_row(ds, res) if rid == "combination" else model_row(ds, rid, res.get(rid))
                for rid in ROW_ORDER]
        mark_best(rows, (frames or {}).get(ds))
        out[ds] = rows
    return out


def _row_texts(row: Table2Row, latex: bool) -> list[str]:
    """Per column: the seed cell (``mean ± sd``, bold / dagger marks) and, for a task column,
    the per-frame variance cell after it."""
    texts = []
    for col in TABLE2_COLUMNS:
        cell = row.cells.get(col)
        if not row.available and cell is None:
            texts += [NOT_AVAILABLE] * (2 if col in TASK_COLUMNS else 1)
            continue
        t = fmt_seeds(cell, latex)
        if col in row.notes:
            t += "$^\\dagger$" if latex else INCONCLUSIVE_MARK
        texts.append(_bold(t, latex) if col in row.bold else t)
        if col in TASK_COLUMNS:
            texts.append(NOT_APPLICABLE if cell is None else (fmt_var(cell.var, latex=latex) or NOT_AVAILABLE))
    return texts


def table2_notes(tables: dict[str, list[Table2Row]]) -> list[str]:
    """One line per best value left without bold, sorted by dataset order and column."""
    return [f"{DATASET_LABEL.get(ds, ds)}, {r.label}: {r.notes[c]}"
            for ds, rows in tables.items() for c in TABLE2_COLUMNS for r in rows if c in r.notes]


def _seed_text(seeds: Sequence[Optional[int]]) -> str:
    ks = [k for k in seeds if k is not None]
    return f"{len(seeds)} ({', '.join(map(str, ks))})" if ks else str(len(seeds))


def table2_scale(tables: dict[str, list[Table2Row]]) -> str:
    """The seeds of every row kind and the test frames of every dataset, as one sentence."""
    seeds: dict[tuple, list[str]] = {}
    for rows in tables.values():
        for r in rows:
            if r.available and r.row_id != "combination" and r.seeds:
                key = tuple(r.seeds)
                if r.label not in seeds.setdefault(key, []):
                    seeds[key].append(r.label)
    seed_txt = "; ".join(f"{', '.join(labels)}: {_seed_text(k)}" for k, labels in seeds.items()) or "none"
    frames = []
    for ds, rows in tables.items():
        n = sorted({r.n_frames for r in rows if r.n_frames})
        frames.append(f"{DATASET_LABEL.get(ds, ds)} {'/'.join(map(str, n)) or '?'}")
    return f"Seeds (trainings) per row: {seed_txt}. Test frames per run: {', '.join(frames)}."


def table2_caption(tables: dict[str, list[Table2Row]]) -> str:
    return (f"{table2_scale(tables)} "
            "Each metric column: **mean ± sd over the seeds** of the run-level value (a run's test-set mean; TM "
            "and MV of the run's four test-set means), sd the sample standard deviation (n − 1) over the seeds; "
            "`(n=1)`: a single seed, no sd. Each `var (frames)` column: the paper's ± (**variance over the test "
            "frames** of the per-frame score, population), averaged over the seeds. TM = MAE_DE + Σ(1 − IoU) of "
            "the four test-set means (eq. 6; equal to the mean of the per-frame TM); MV = population variance of "
            "those four mean terms (eq. 7), one number per run. Combination = GradNorm (DE, SS) + PolarNet (LS) + "
            "Chen et al. (BEVP) of the same seed, TM and MV from those four means. " + MGN_NOTE + " **Bold**: the "
            "best value of the column (lowest MAE_DE, TM, MV; highest IoU) where a paired bootstrap over the seeds "
            "and test frames puts the 95% interval of its difference to the runner-up above 0; "
            f"`{INCONCLUSIVE_MARK}`: the best value, not separated from the runner-up (inconclusive, not bold). "
            f"`{NOT_APPLICABLE}`: task not performed; `{NOT_AVAILABLE}`: no result.")


def _t2_header(latex: bool) -> list[str]:
    out = ["Dataset", "Model", "Seeds"]
    for c in TABLE2_COLUMNS:
        name = COLUMN_TEX[c] if latex else COLUMN_MD[c]
        out.append(f"{name} (mean $\\pm$ sd)" if latex else f"{name} (mean ± sd)")
        if c in TASK_COLUMNS:
            out.append("var (frames)")
    return out


def table2_markdown(tables: dict[str, list[Table2Row]]) -> str:
    header = _t2_header(False)
    body = []
    for ds, rows in tables.items():
        for i, r in enumerate(rows):
            body.append([DATASET_LABEL.get(ds, ds) if i == 0 else "", r.label, str(r.n_seeds) if r.n_seeds else ""]
                        + _row_texts(r, False))
    note = "\n" + table2_caption(tables) + "\n"
    notes = table2_notes(tables)
    if notes:
        note += "\n" + "".join(f"- {INCONCLUSIVE_MARK} {n}\n" for n in notes)
    return _md_table(header, body, ["---", "---", "---:"] + ["---:"] * (len(header) - 3)) + note


def table2_latex(tables: dict[str, list[Table2Row]]) -> str:
    header = _t2_header(True)
    lines = ["% Table II (reproduced). Requires \\usepackage{booktabs}.",
             "% " + tex_escape(table2_caption(tables).replace("**", "").replace("`", "")),
             "\\begin{tabular}{llr" + "c" * (len(header) - 3) + "}", "\\toprule",
             " & ".join(h if "$" in h else tex_escape(h) for h in header) + " \\\\", "\\midrule"]
    for k, (ds, rows) in enumerate(tables.items()):
        if k:
            lines.append("\\midrule")
        for i, r in enumerate(rows):
            first = tex_escape(DATASET_LABEL.get(ds, ds)) if i == 0 else ""
            lines.append(f"{first} & {tex_escape(r.label)} & {r.n_seeds or ''} & " + " & ".join(_row_texts(r, True))
                         + " \\\\")
    lines += ["\\bottomrule", "\\end{tabular}", ""]
    lines += [f"% $^\\dagger$ {tex_escape(n)}" for n in table2_notes(tables)]
    return "\n".join(lines) + ("\n" if table2_notes(tables) else "")


def table2_csv(tables: dict[str, list[Table2Row]]) -> str:
    """Raw numbers: per task column ``_mean`` (over seeds), ``_std`` (sample sd over seeds,
    empty for one seed), ``_var`` (per-frame variance, mean over seeds); ``tm``/``mv`` (mean over
    seeds) with ``tm_std``/``mv_std``."""
    header = ["dataset", "row_id", "label", "available", "n_seeds", "seeds", "n_test_frames"]
    for c in TASK_COLUMNS:
        header += [f"{c}_mean", f"{c}_std", f"{c}_var"]
    header += ["tm", "tm_std", "mv", "mv_std", "bold", "best_inconclusive"]
    body = []
    for ds, rows in tables.items():
        for r in rows:
            line: list[Any] = [ds, r.row_id, r.label, int(r.available), r.n_seeds,
                               ";".join("" if k is None else str(k) for k in r.seeds), r.n_frames]
            for c in TASK_COLUMNS:
                cell = r.cells.get(c)
                line += [None, None, None] if cell is None else [cell.mean, cell.std, cell.var]
            for c in ("tm", "mv"):
                cell = r.cells.get(c)
                line += [None, None] if cell is None else [cell.mean, cell.std]
            line.append(";".join(c for c in TABLE2_COLUMNS if c in r.bold))
            line.append(";".join(c for c in TABLE2_COLUMNS if c in r.notes))
            body.append(line)
    return _csv_text(header, body)


def write_table(out_dir: Path, stem: str, md: str, tex: str, csv_text: str) -> list[Path]:
    """Write ``<stem>.md``, ``.tex``, ``.csv`` atomically; returns the paths."""
    paths = [Path(out_dir) / f"{stem}.{ext}" for ext in ("md", "tex", "csv")]
    for p, text in zip(paths, (md, tex, csv_text)):
        io.write_text(p, text)
    return paths


def write_table2(results: dict[str, dict[str, ModelResult]], out_dir: Path,
                 frames: Optional[dict[str, RowFrames]] = None) -> list[Path]:
    tables = build_table2(results, frames)
    return write_table(out_dir, "table2", table2_markdown(tables), table2_latex(tables), table2_csv(tables))


# ----------------------------------------------------------------------------- Table III
@dataclass
class Table3Row:
    dataset: str
    row_id: str
    label: str
    params: Optional[int] = None
    total_params: Optional[int] = None
    size_mb: Optional[float] = None
    total_size_mb: Optional[float] = None
    peak_memory_mb: Optional[float] = None
    fps: Optional[float] = None
    latency_ms: Optional[float] = None
    device: Optional[str] = None
    available: bool = True
    onnx_fps: Optional[float] = None            # ONNX Runtime, batch 1, CPU (compact models; issue 15)
    onnx_latency_ms: Optional[float] = None


TABLE3_FIELDS: tuple[str, ...] = ("params", "total_params", "size_mb", "total_size_mb", "peak_memory_mb",
                                  "fps", "latency_ms", "onnx_fps", "onnx_latency_ms", "device")


def build_table3(efficiency: dict[str, Any]) -> dict[str, list[Table3Row]]:
    """Rows per measured dataset from ``efficiency.json`` (see ``pipeline/benchmark.py``).

    The combination sums the three baselines' parameters, sizes, peak memories and latencies
    (the models run one after the other on the same frame); its FPS is 1000 / summed latency.
    ONNX Runtime FPS / latency come from the ``onnx_*`` keys (compact models) where measured.
    """
    out: dict[str, list[Table3Row]] = {}
    for ds, models in (efficiency.get("models") or {}).items():
        rows: list[Table3Row] = []
        for rid in ROW_ORDER:
            if rid == "combination":
                parts = [models.get(b) for b in BASELINES]
                if all(parts):
                    lat = sum(p["latency_ms"] for p in parts)  # type: ignore[index]
                    n = sum(int(p["params"]) for p in parts)  # type: ignore[index]
                    size = sum(float(p["size_mb"]) for p in parts)  # type: ignore[index]
                    rows.append(Table3Row(ds, rid, "Combination (sum of the three)", n, n, size, size,
                                          sum(float(p["peak_memory_mb"]) for p in parts),  # type: ignore[index]
                                          1e3 / lat if lat > 0 else None, lat, parts[0].get("device")))  # type: ignore[union-attr]
                else:
                    rows.append(Table3Row(ds, rid, "Combination (sum of the three)", available=False))
                continue
            m = models.get(rid)
            label = ROW_LABEL[rid] + (" (4 views)" if rid == "gradnorm_segnet" else "")
            if m is None:
                rows.append(Table3Row(ds, rid, label, available=False))
                continue
            own = rid in COMPACT
            rows.append(Table3Row(ds, rid, label, int(m["params"]), int(m["params"]) if own else None,
                                  float(m["size_mb"]), float(m["size_mb"]) if own else None,
                                  float(m["peak_memory_mb"]), float(m["fps"]), float(m["latency_ms"]), m.get("device"),
                                  onnx_fps=None if m.get("onnx_fps") is None else float(m["onnx_fps"]),
                                  onnx_latency_ms=None if m.get("onnx_latency_ms") is None else float(m["onnx_latency_ms"])))
        out[ds] = rows
    return out


def _t3_texts(r: Table3Row) -> list[str]:
    if not r.available:
        return [NOT_AVAILABLE] * len(TABLE3_FIELDS)
    return [
        "" if r.params is None else f"{r.params:,}", "" if r.total_params is None else f"{r.total_params:,}",
        fmt_num(r.size_mb), fmt_num(r.total_size_mb), fmt_num(r.peak_memory_mb, 1), fmt_num(r.fps, 2),
        fmt_num(r.latency_ms, 2), fmt_num(r.onnx_fps, 2), fmt_num(r.onnx_latency_ms, 2), r.device or "",
    ]


def _t3_header(efficiency: dict[str, Any]) -> list[str]:
    gpu = bool(efficiency.get("is_gpu"))
    mem = "GPU memory (MB)" if gpu else "Peak memory, CPU estimate (MB)"
    return ["Params", "Total params", "Size (MB)", "Total size (MB)", mem,
            "FPS" if gpu else "FPS (CPU)", "Latency (ms)", "ONNX Runtime FPS (CPU)", "ONNX Runtime latency (ms)",
            "Device"]


def _t3_note(efficiency: dict[str, Any]) -> str:
    gpu = bool(efficiency.get("is_gpu"))
    s = (f"Batch 1 at {efficiency.get('resolution')}x{efficiency.get('resolution')} px; "
         f"{efficiency.get('warmup')} warm-up iterations excluded, median of {efficiency.get('runs')} timed runs"
         f"{', device synchronised before each clock read' if gpu else ''}. Size = serialised state_dict / 2^20. "
         f"Memory: {efficiency.get('memory_method', '')}.")
    if not gpu:
        s += (" **No GPU on this machine**: FPS and latency are CPU figures, not comparable with the paper's "
              "GPU (NVIDIA GTX 1080 Ti) numbers.")
    onnx = [m for models in (efficiency.get("models") or {}).values() for m in models.values()
            if isinstance(m, dict) and m.get("onnx_latency_ms") is not None]
    if onnx:
        worst = max(float(m.get("onnx_max_abs_diff") or 0.0) for m in onnx)
        s += (f" ONNX Runtime {onnx[0].get('onnxruntime', '')} (CPU execution provider, "
              f"{onnx[0].get('onnx_device', 'CPU')}, opset {onnx[0].get('onnx_opset', '')}): the compact models "
              f"exported to ONNX, same batch-1 protocol; largest |ONNX Runtime - PyTorch| output difference "
              f"{worst:.1e}.")
    return s


def table3_markdown(tables: dict[str, list[Table3Row]], efficiency: dict[str, Any]) -> str:
    header = ["Dataset", "Model"] + _t3_header(efficiency)
    body = []
    for ds, rows in tables.items():
        for i, r in enumerate(rows):
            body.append([_t3_group_label(ds) if i == 0 else "", r.label] + _t3_texts(r))
    return _md_table(header, body, ["---", "---"] + ["---:"] * 9 + ["---"]) + "\n" + _t3_note(efficiency) + "\n"


def _t3_group_label(ds: str) -> str:
    return "Simulation (measured on A)" if ds in ("A", "B", "C") else DATASET_LABEL.get(ds, ds)


def table3_latex(tables: dict[str, list[Table3Row]], efficiency: dict[str, Any]) -> str:
    header = ["Dataset", "Model"] + _t3_header(efficiency)
    lines = ["% Table III (reproduced). Requires \\usepackage{booktabs}.",
             "% " + _t3_note(efficiency).replace("**", ""),
             "\\begin{tabular}{ll" + "r" * 9 + "l}", "\\toprule",
             " & ".join(tex_escape(h) for h in header) + " \\\\", "\\midrule"]
    for k, (ds, rows) in enumerate(tables.items()):
        if k:
            lines.append("\\midrule")
        for i, r in enumerate(rows):
            first = tex_escape(_t3_group_label(ds)) if i == 0 else ""
            lines.append(f"{first} & {tex_escape(r.label)} & " + " & ".join(tex_escape(t) for t in _t3_texts(r)) + " \\\\")
    lines += ["\\bottomrule", "\\end{tabular}", ""]
    return "\n".join(lines)


def table3_csv(tables: dict[str, list[Table3Row]], efficiency: dict[str, Any]) -> str:
    header = ["dataset", "row_id", "label", "available", *TABLE3_FIELDS, "is_gpu", "resolution"]
    body = [[ds, r.row_id, r.label, int(r.available), *(getattr(r, f) for f in TABLE3_FIELDS),
             int(bool(efficiency.get("is_gpu"))), efficiency.get("resolution")]
            for ds, rows in tables.items() for r in rows]
    return _csv_text(header, body)


def write_table3(efficiency: dict[str, Any], out_dir: Path) -> list[Path]:
    tables = build_table3(efficiency)
    return write_table(out_dir, "table3", table3_markdown(tables, efficiency), table3_latex(tables, efficiency),
                       table3_csv(tables, efficiency))


# ----------------------------------------------------------------------------- paper vs reproduced
@dataclass
class Comparison:
    """One (dataset, row, column) with the paper's and this run's numbers. ``ours``: mean over
    the seeds, ``ours_std`` the sample sd over them, ``ours_var`` the per-frame variance (mean
    over seeds); ``paper_row`` the paper's row it is compared with."""

    dataset: str
    table: str
    row_id: str
    column: str
    paper: Optional[float]
    paper_var: Optional[float] = None
    paper_var_below: bool = False
    ours: Optional[float] = None
    ours_var: Optional[float] = None
    ours_std: Optional[float] = None
    n_seeds: Optional[int] = None
    paper_row: Optional[str] = None


def compare(paper: PaperNumbers, table2: dict[str, list[Table2Row]],
            table3: Optional[dict[str, list[Table3Row]]] = None) -> list[Comparison]:
    """Paper numbers beside this run's, for every cell either side has. Both MGN rows are
    compared with the paper's one 15L+MGN row (:data:`PAPER_ROW`)."""
    out: list[Comparison] = []
    for ds, rows in table2.items():
        for r in rows:
            prid = PAPER_ROW.get(r.row_id, r.row_id)
            prow = paper.table2_row(ds, prid)
            for col in TABLE2_COLUMNS:
                pv: Optional[float] = None
                pc: Optional[PaperCell] = None
                if prow is not None:
                    pv = prow.value(col)
                    pc = prow.cells.get(col) if col in TASK_COLUMNS else None
                if r.row_id == "combination" and pv is None and col in TASK_COLUMNS:
                    src = paper.table2_row(ds, COMBINATION_SOURCE[col])
                    pc = src.cells.get(col) if src else None
                    pv = pc.mean if pc else None
                cell = r.cells.get(col) if r.available or r.cells.get(col) is not None else None
                if pv is None and cell is None:
                    continue
                out.append(Comparison(ds, "II", r.row_id, col, pv, pc.var if pc else None,
                                      bool(pc.var_below) if pc else False,
                                      cell.mean if cell else None, cell.var if cell else None,
                                      cell.std if cell else None, cell.n_seeds if cell else None,
                                      prid if prow is not None else None))
    for ds, rows3 in (table3 or {}).items():
        for r in rows3:
            prid = PAPER_ROW.get(r.row_id, r.row_id)
            prow3 = paper.table3_row(ds, prid)
            if prow3 is None:
                continue
            pairs = {
                "params": (prow3.params * prow3.copies if prow3.params is not None else prow3.total_params, r.params),
                "size_mb": (prow3.size_mb * prow3.copies if prow3.size_mb is not None else prow3.total_size_mb, r.size_mb),
                "memory_mb": (prow3.gpu_memory_mb, r.peak_memory_mb),
                "fps": (prow3.fps, r.fps),
            }
            for col, (pv3, ov) in pairs.items():
                if pv3 is None and ov is None:
                    continue
                out.append(Comparison(ds, "III", r.row_id, col, None if pv3 is None else float(pv3),
                                      ours=None if ov is None else float(ov), paper_row=prid))
    return out


def _join(values: Sequence[Any]) -> str:
    vals = ["?" if v is None else str(v) for v in values]
    return vals[0] if len(set(vals)) == 1 else "/".join(vals)


def scale_lines(scales: dict[str, DatasetScale], paper: PaperNumbers, *, scale_name: str = "",
                device: str = "") -> list[str]:
    """Sentences stating this run's scale beside the paper's, per dataset: frames, test frames
    scored, seeds and epochs run per seed."""
    t1 = paper.raw.get("text", {}).get("table1", {})
    lines = []
    if scale_name:
        lines.append(f"Run scale: `{scale_name}` (params.yaml `scale`); paper resolution {t1.get('resolution', 128)} px.")
    if device:
        lines.append(f"Evaluation/benchmark device: {device}.")
    for ds, sc in scales.items():
        counts = "/".join(str(sc.counts.get(k, "?")) for k in ("train", "val", "test")) if sc.counts else "unknown"
        pfs = t1.get("frames_per_split", {}).get(ds)
        pcounts = "/".join(str(pfs[k]) for k in ("train", "val", "test")) if pfs else "?"
        ep = "; ".join(f"{ROW_LABEL.get(m, m)} {_join([e.get('epochs_run') for e in es])} "
                       f"(best {_join([e.get('best_epoch') for e in es])})"
                       for m, es in sc.epochs.items()) or "no runs"
        n_test = "/".join(map(str, sc.n_test_frames)) or "?"
        seeds = {}
        for m, ks in sc.seeds.items():
            seeds.setdefault(len(ks), []).append(ROW_LABEL.get(m, m))
        seed_txt = "; ".join(f"{n} for {', '.join(ms)}" for n, ms in sorted(seeds.items(), reverse=True)) or "?"
        lines.append(f"{DATASET_LABEL.get(ds, ds)}: source {sc.source or 'unknown'}; frames train/val/test "
                     f"{counts} (paper {pcounts}); test frames scored per run {n_test}; seeds (trainings) "
                     f"{seed_txt}; resolution {sc.resolution or '?'} px (paper {t1.get('resolution', 128)}); "
                     f"epochs run (best epoch), per seed: {ep}.")
    return lines


def _cmp_text(v: Optional[float], var: Optional[float] = None, below: bool = False, col: str = "",
              latex: bool = False) -> str:
    if v is None:
        return NOT_APPLICABLE
    if col == "params":
        return f"{int(round(v)):,}"
    if col in ("memory_mb", "fps", "size_mb"):
        return f"{v:.2f}" if col == "fps" else f"{v:.1f}" if col == "memory_mb" else f"{v:.3f}"
    t = fmt_num(v)
    if var is not None:
        pm = " $\\pm$ " if latex else " ± "
        t += pm + ((("$<$" if latex else "<") + f"{var:.3f}") if below else fmt_var(var, latex=latex))
    return t


def _ours_text(c: Comparison, latex: bool = False) -> str:
    """Table II: mean ± sd over seeds (``(n=1)`` for one seed); Table III: the number."""
    if c.table != "II" or c.ours is None:
        return _cmp_text(c.ours, col=c.column, latex=latex)
    return fmt_seeds(Cell(c.ours, c.ours_var, c.ours_std, c.n_seeds or 1), latex)


def _diff(c: Comparison) -> str:
    """Table II: this run (mean over seeds) minus the paper; Table III: ratio this run / paper."""
    if c.paper is None or c.ours is None:
        return ""
    if c.table == "III":
        return f"x{c.ours / c.paper:.3g}" if c.paper else ""
    return f"{c.ours - c.paper:+.3f}"


def _cmp_label(c: Comparison) -> str:
    label = ROW_LABEL.get(c.row_id, c.row_id)
    if c.paper_row and c.paper_row != c.row_id:
        label += f" (paper: {ROW_LABEL.get(c.paper_row, c.paper_row).split(' (')[0]})"
    return label


CMP_NOTE = ("Paper: Table II cells mean ± variance over test frames as printed. This run: **mean ± sd over the "
            "seeds** (sample sd, n − 1; `(n=1)` for one seed) of the run-level value, and separately the **variance "
            "over test frames** (mean over the seeds), the paper's ± column. The paper's combination TM/MV are "
            "printed on its PolarNet line; its combination task cells are the baselines' own. " + MGN_NOTE +
            " Table III: paper memory is 'GPU usage' on an NVIDIA GTX 1080 Ti (probably including the CUDA "
            "context); sizes in MB.")


def comparison_markdown(rows: list[Comparison], lines: list[str]) -> str:
    head = "\n".join(f"- {s}" for s in lines) + "\n\n" if lines else ""
    body = [[DATASET_LABEL.get(c.dataset, c.dataset), c.table, _cmp_label(c),
             COLUMN_MD.get(c.column, c.column), _cmp_text(c.paper, c.paper_var, c.paper_var_below, c.column),
             _ours_text(c), "" if c.table != "II" or c.ours_var is None else fmt_var(c.ours_var),
             _diff(c)]
            for c in rows]
    header = ["Dataset", "Table", "Model", "Metric", "Paper (mean ± var frames)", "This run (mean ± sd over seeds)",
              "This run: var (frames)", "Diff (II: -, III: ratio)"]
    return head + _md_table(header, body, ["---"] * 4 + ["---:"] * 4) + "\n" + CMP_NOTE + "\n"


def comparison_latex(rows: list[Comparison], lines: list[str]) -> str:
    out = ["% Paper vs reproduced. Requires \\usepackage{booktabs}."] + [f"% {tex_escape(s)}" for s in lines]
    out += [f"% {tex_escape(CMP_NOTE.replace('**', ''))}"]
    out += ["\\begin{tabular}{llllrrrr}", "\\toprule",
            "Dataset & Table & Model & Metric & Paper (mean $\\pm$ var frames) & This run (mean $\\pm$ sd seeds) "
            "& This run var (frames) & Diff \\\\", "\\midrule"]
    for c in rows:
        diff = _diff(c).replace("x", "$\\times$")
        out.append(" & ".join([tex_escape(DATASET_LABEL.get(c.dataset, c.dataset)), c.table,
                               tex_escape(_cmp_label(c)),
                               COLUMN_TEX.get(c.column, tex_escape(c.column)),
                               _cmp_text(c.paper, c.paper_var, c.paper_var_below, c.column, True).replace(",", "{,}"),
                               _ours_text(c, True).replace(",", "{,}"),
                               "" if c.table != "II" or c.ours_var is None else fmt_var(c.ours_var, latex=True),
                               diff]) + " \\\\")
    out += ["\\bottomrule", "\\end{tabular}", ""]
    return "\n".join(out)


def comparison_csv(rows: list[Comparison]) -> str:
    header = ["dataset", "table", "row_id", "paper_row", "column", "paper", "paper_var", "paper_var_below",
              "reproduced", "reproduced_std", "reproduced_var", "n_seeds"]
    return _csv_text(header, [[c.dataset, c.table, c.row_id, c.paper_row, c.column, c.paper, c.paper_var,
                               int(c.paper_var_below), c.ours, c.ours_std, c.ours_var, c.n_seeds] for c in rows])


def write_comparison(paper: PaperNumbers, table2: dict[str, list[Table2Row]],
                     table3: Optional[dict[str, list[Table3Row]]], lines: list[str], out_dir: Path) -> list[Path]:
    rows = compare(paper, table2, table3)
    return write_table(out_dir, "paper_vs_reproduced", comparison_markdown(rows, lines),
                       comparison_latex(rows, lines), comparison_csv(rows))


# ----------------------------------------------------------------------------- metrics beyond the paper
EXTRA_TASKS: tuple[str, ...] = ("ss", "ls", "bevp")
EXTRA_DEPTH: tuple[str, ...] = tuple(DEPTH_METRICS.keys())
EXTRA_MD: dict[str, str] = {**{t: f"mIoU_{catalog.TASKS[t].label}" for t in EXTRA_TASKS},
                            **{k: DEPTH_METRICS[k].label for k in EXTRA_DEPTH}}


@dataclass
class ExtraRow:
    """One model's metrics beyond the paper's, over its seeds: mIoU per segmentation task
    (mean ± sd over seeds, and the classes counted per seed); per-class IoU (mean over the seeds
    where the class has one); depth errors (mean ± sd over seeds, per-frame variance mean over seeds)."""

    dataset: str
    row_id: str
    label: str
    miou: dict[str, Optional[Cell]] = field(default_factory=dict)
    n_classes: dict[str, tuple[int, ...]] = field(default_factory=dict)
    per_class: dict[str, dict[str, Optional[float]]] = field(default_factory=dict)
    depth: dict[str, Optional[Cell]] = field(default_factory=dict)
    n_seeds: int = 1


def _opt_float(v: Any, where: str) -> Optional[float]:
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
        raise ReportInputError(f"{where}: expected a finite number or null, got {v!r}")
    return float(v)


def _where(r: ModelResult) -> str:
    return f"results/{r.dataset}/{r.model}" + ("" if r.seed is None else f"/seed{r.seed}") + "/metrics.json"


def build_extra_rows(results: dict[str, dict[str, ModelResult]]) -> list[ExtraRow]:
    """Rows (dataset order, then :data:`ROW_ORDER`) of the models whose metrics files carry a
    ``class_iou`` or ``depth`` block, aggregated over the model's runs (seeds)."""
    out: list[ExtraRow] = []
    for ds, res in results.items():
        for rid in ROW_ORDER:
            agg = res.get(rid)
            if agg is None:
                continue
            runs = [r for r in agg.per_run() if r.extra]
            if not runs:
                continue
            row = ExtraRow(ds, rid, ROW_LABEL.get(rid, rid), n_seeds=len(runs))
            for t in EXTRA_TASKS:
                blks = [((r.extra.get("class_iou") or {}).get(t), _where(r)) for r in runs]
                blks = [(b, w) for b, w in blks if isinstance(b, dict)]
                if not blks:
                    continue
                mious = [_opt_float(b.get("miou"), f"{w}: class_iou.{t}.miou") for b, w in blks]
                vals = [v for v in mious if v is not None]
                row.miou[t] = aggregate_cells([Cell(v) for v in vals]) if vals else None
                row.n_classes[t] = tuple(int(b.get("n_classes_in_miou") or 0) for b, _ in blks)
                classes: dict[str, list[float]] = {}
                for b, w in blks:
                    for k, v in (b.get("classes") or {}).items():
                        fv = _opt_float(v, f"{w}: class_iou.{t}.classes.{k}")
                        classes.setdefault(str(k), [])
                        if fv is not None:
                            classes[str(k)].append(fv)
                row.per_class[t] = {k: (float(np.mean(v)) if v else None) for k, v in classes.items()}
            for k in EXTRA_DEPTH:
                cells = []
                for r in runs:
                    v = (r.extra.get("depth") or {}).get(k)
                    mean = _opt_float(v.get("mean"), f"{_where(r)}: depth.{k}.mean") if isinstance(v, dict) else None
                    if mean is not None:
                        cells.append(Cell(mean, _opt_float(v.get("var"), f"{_where(r)}: depth.{k}.var")))
                if cells:
                    row.depth[k] = aggregate_cells(cells)
            out.append(row)
    return out


def _extra_texts(r: ExtraRow) -> list[str]:
    texts = []
    for t in EXTRA_TASKS:
        if t not in r.miou:
            texts.append(NOT_APPLICABLE)
        else:
            c = r.miou[t]
            n = r.n_classes[t]
            ncls = str(n[0]) if len(set(n)) == 1 else "/".join(map(str, n))
            texts.append(NOT_AVAILABLE if c is None else f"{fmt_seeds(c)} ({ncls} cl.)")
    for k in EXTRA_DEPTH:
        c = r.depth.get(k)
        if c is None:
            texts += [NOT_APPLICABLE, NOT_APPLICABLE]
        else:
            nd = DEPTH_METRICS[k].decimals
            texts += [fmt_seeds(c, decimals=nd), "" if c.var is None else f"{c.var:.{nd}f}"]
    return texts


def _and(words: Sequence[str]) -> str:
    """``a, b and c``."""
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]


def extra_markdown(rows: list[ExtraRow]) -> str:
    header = ["Dataset", "Model", "Seeds"] + [f"{EXTRA_MD[c]} (mean ± sd)" for c in EXTRA_TASKS]
    for k in EXTRA_DEPTH:
        header += [f"{EXTRA_MD[k]} (mean ± sd)", "var (frames)"]
    body, last = [], None
    for r in rows:
        body.append([DATASET_LABEL.get(r.dataset, r.dataset) if r.dataset != last else "", r.label, str(r.n_seeds)]
                    + _extra_texts(r))
        last = r.dataset
    note = ("\nMetrics the field reports, beside the paper's (not in the paper; Table II's columns are unchanged). "
            "Every value: **mean ± sd over the seeds** (sample sd, n − 1; `(n=1)`: one seed) of the run-level value; "
            "depth also the **variance over test frames** (mean over the seeds). "
            "mIoU: per-class IoU = TP / (TP + FP + FN) from counts summed over all test frames of a run, averaged over "
            "the classes present; `cl.`: the number of classes counted (per seed where they differ): a class absent "
            "from both prediction and ground truth has no IoU and is left out. SS and LS: predicted class = arg-max, "
            "pixels without a label left out; BEVP: each class a binary mask (> 0.5). Depth: metric depth "
            "d = 1000 m · exp((x − 1) · 5.70378) decoded from the cache's CARLA log depth x ∈ [0, 1] (the world's and "
            "the nuScenes ingest's encoding; prediction clamped to [0, 1], i.e. 3.33 m to 1000 m); pixels with ground "
            "truth x = 0 (no depth) or x = 1 (1000 m far clip, sky) left out; "
            f"{_and([EXTRA_MD[k] for k in EXTRA_DEPTH])} per frame over the valid pixels of the four views "
            f"({'; '.join(DEPTH_METRICS[k].definition for k in EXTRA_DEPTH)}). "
            "Per-class IoUs (mean over the seeds where the class has one): "
            f"`extra_metrics_per_class.csv`. `{NOT_APPLICABLE}`: task not performed; `{NOT_AVAILABLE}`: no class "
            "present.\n")
    return _md_table(header, body, ["---", "---", "---:"] + ["---:"] * (len(header) - 3)) + note


def extra_csv(rows: list[ExtraRow]) -> str:
    header = ["dataset", "row_id", "label", "n_seeds"]
    header += [f"miou_{t}" for t in EXTRA_TASKS] + [f"miou_{t}_std" for t in EXTRA_TASKS]
    header += [f"n_classes_{t}" for t in EXTRA_TASKS]
    for k in EXTRA_DEPTH:
        header += [f"{k}_mean", f"{k}_std", f"{k}_var"]
    body = []
    for r in rows:
        line: list[Any] = [r.dataset, r.row_id, r.label, r.n_seeds]
        line += [None if r.miou.get(t) is None else r.miou[t].mean for t in EXTRA_TASKS]  # type: ignore[union-attr]
        line += [None if r.miou.get(t) is None else r.miou[t].std for t in EXTRA_TASKS]  # type: ignore[union-attr]
        line += [";".join(map(str, r.n_classes[t])) if t in r.n_classes else None for t in EXTRA_TASKS]
        for k in EXTRA_DEPTH:
            c = r.depth.get(k)
            line += [None, None, None] if c is None else [c.mean, c.std, c.var]
        body.append(line)
    return _csv_text(header, body)


def extra_per_class_csv(rows: list[ExtraRow]) -> str:
    body = [[r.dataset, r.row_id, t, i, name, v, r.n_seeds] for r in rows for t in EXTRA_TASKS
            for i, (name, v) in enumerate((r.per_class.get(t) or {}).items())]
    return _csv_text(["dataset", "row_id", "task", "class_index", "class", "iou", "n_seeds"], body)


def write_extra_metrics(results: dict[str, dict[str, ModelResult]], out_dir: Path) -> list[Path]:
    """``extra_metrics.{md,csv}`` and ``extra_metrics_per_class.csv``; returns the paths."""
    rows = build_extra_rows(results)
    out = {Path(out_dir) / "extra_metrics.md": extra_markdown(rows), Path(out_dir) / "extra_metrics.csv": extra_csv(rows),
           Path(out_dir) / "extra_metrics_per_class.csv": extra_per_class_csv(rows)}
    for path, text in out.items():
        io.write_text(path, text)
    return list(out)
