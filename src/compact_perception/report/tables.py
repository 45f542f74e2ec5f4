"""Table II (test comparison), Table III (efficiency) and the paper-vs-reproduced table.

Every table is written as Markdown, LaTeX (booktabs) and CSV. Markdown/LaTeX show
``mean ± variance`` rounded to 3 decimals as the paper prints them (a variance below 0.0005
prints as ``<0.001``); the CSV holds the raw numbers (separate mean / variance columns).

Table II rows per dataset: Chen et al., PolarNet, GradNorm, Combination, 1L, 15L, 15L+MGN.
The combination takes GradNorm's DE/SS, PolarNet's LS and Chen et al.'s BEVP, and its TM and
MV are computed from those four means with :mod:`compact_perception.metrics` (eq. 6-7), like
every compact row's (its metrics file holds TM and MV of its four test-set means), so all
rows compare with each other and with the paper.

Bold (lowest MAE / TM / MV, highest IoU) marks the best value of a column only where the
paired bootstrap over test frames (and seeds; :mod:`compact_perception.stats`) separates it
from the runner-up: the 95% interval of the difference excludes 0. Otherwise the best cell
is not bold and gets a dagger and an "inconclusive" note. The combination's task cells are
copies of its source models' and take no part in the task columns' comparison.

``extra_metrics.{md,csv}`` holds the metrics beyond the paper's (per-class IoU / mIoU of SS,
LS, BEVP; depth AbsRel, RMSE, delta < 1.25), from the ``class_iou`` / ``depth`` blocks of
the metrics files.
"""
from __future__ import annotations

import csv
import io as _io
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Optional

import pandas as pd

from .. import io
from ..metrics import scores_from_means
from ..stats import REPRODUCED, BootstrapResult, paired_bootstrap, stat_mean, stat_mv, stat_tm, verdict
from .collect import COMBINATION_SOURCE, Cell, DatasetScale, ModelResult, ReportInputError, align
from .paper import PaperCell, PaperNumbers

log = logging.getLogger(__name__)

TASK_COLUMNS: tuple[str, ...] = ("mae_de", "iou_ss", "iou_ls", "iou_bevp")
TABLE2_COLUMNS: tuple[str, ...] = TASK_COLUMNS + ("tm", "mv")
LOWER_IS_BETTER: frozenset[str] = frozenset({"mae_de", "tm", "mv"})
BASELINES: tuple[str, ...] = ("chen_bev", "polarnet", "gradnorm_segnet")
COMPACT: tuple[str, ...] = ("compact_1l", "compact_15l", "compact_15l_mgn")
ROW_ORDER: tuple[str, ...] = BASELINES + ("combination",) + COMPACT
ROW_LABEL: dict[str, str] = {
    "chen_bev": "Chen et al.", "polarnet": "PolarNet", "gradnorm_segnet": "GradNorm",
    "combination": "Combination", "compact_1l": "1L", "compact_15l": "15L", "compact_15l_mgn": "15L+MGN",
}
DATASET_LABEL: dict[str, str] = {"A": "Set A", "B": "Set B", "C": "Set C", "nuscenes": "nuScenes"}
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


def fmt_cell(col: str, cell: Optional[Cell], latex: bool = False) -> str:
    """``mean ± var`` for a task column, the mean alone for TM / MV."""
    if cell is None:
        return NOT_APPLICABLE
    text = fmt_num(cell.mean)
    if col in TASK_COLUMNS and cell.var is not None:
        text += (" $\\pm$ " if latex else " ± ") + fmt_var(cell.var, latex=latex)
    return text


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
    TM/MV do not apply); ``available`` is False when the row's inputs are missing."""

    dataset: str
    row_id: str
    label: str
    cells: dict[str, Optional[Cell]]
    available: bool = True
    bold: set[str] = field(default_factory=set)
    #: column -> why the best value of that column is not bold (bootstrap inconclusive / untested)
    notes: dict[str, str] = field(default_factory=dict)


def combination_row(dataset: str, results: dict[str, ModelResult]) -> Table2Row:
    """GradNorm DE/SS + PolarNet LS + Chen BEVP; TM and MV (eq. 6-7) from those four means."""
    cells: dict[str, Optional[Cell]] = {}
    for col, src in COMBINATION_SOURCE.items():
        res = results.get(src)
        cells[col] = res.scores.get(col) if res else None
    if all(cells[c] is not None for c in TASK_COLUMNS):
        derived = scores_from_means({c: cells[c].mean for c in TASK_COLUMNS})  # type: ignore[union-attr]
        cells["tm"], cells["mv"] = Cell(derived["tm"]), Cell(derived["mv"])
    else:
        cells["tm"] = cells["mv"] = None
    available = all(b in results for b in BASELINES)
    if not available:
        log.warning("%s: combination incomplete (missing %s)", dataset, [b for b in BASELINES if b not in results])
    return Table2Row(dataset, "combination", ROW_LABEL["combination"], cells, available)


def model_row(dataset: str, model: str, result: Optional[ModelResult]) -> Table2Row:
    """A model's row from its metrics file (all ``None`` and unavailable if there is none).

    TM and MV are (re)computed from the row's four task means (eq. 6-7), exactly as for the
    combination; a metrics file whose ``mv`` differs (an older file holding the mean of a
    per-frame MV) is logged, and the table shows the paper's definition."""
    if result is None:
        return Table2Row(dataset, model, ROW_LABEL[model], {c: None for c in TABLE2_COLUMNS}, available=False)
    cells: dict[str, Optional[Cell]] = {c: result.scores.get(c) for c in TASK_COLUMNS}
    derived = scores_from_means({c: cell.mean for c, cell in cells.items() if cell is not None})
    for c in ("tm", "mv"):
        s = result.scores.get(c)
        if c in derived:
            if s is not None and abs(s.mean - derived[c]) > 1e-9:
                log.warning("results/%s/%s/metrics.json: %s %.6g is not eq. %s of the four means (%.6g); "
                            "the table shows the latter (re-run evaluate)", dataset, model, c, s.mean,
                            "6" if c == "tm" else "7", derived[c])
            cells[c] = Cell(derived[c])
        else:
            cells[c] = None if s is None else Cell(s.mean)
    return Table2Row(dataset, model, ROW_LABEL[model], cells)


def column_bootstrap(best: str, other: str, col: str, frames: RowFrames) -> Optional[BootstrapResult]:
    """Paired bootstrap of "row ``best`` beats row ``other`` on column ``col``" (positive =
    it does) from their per-frame scores; ``None`` if either has no per-frame scores for it."""
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
    texts = []
    for col in TABLE2_COLUMNS:
        if not row.available and row.cells.get(col) is None:
            texts.append(NOT_AVAILABLE)
            continue
        t = fmt_cell(col, row.cells.get(col), latex)
        if col in row.notes:
            t += "$^\\dagger$" if latex else INCONCLUSIVE_MARK
        texts.append(_bold(t, latex) if col in row.bold else t)
    return texts


def table2_notes(tables: dict[str, list[Table2Row]]) -> list[str]:
    """One line per best value left without bold, sorted by dataset order and column."""
    return [f"{DATASET_LABEL.get(ds, ds)}, {r.label}: {r.notes[c]}"
            for ds, rows in tables.items() for c in TABLE2_COLUMNS for r in rows if c in r.notes]


def table2_markdown(tables: dict[str, list[Table2Row]]) -> str:
    header = ["Dataset", "Model"] + [COLUMN_MD[c] for c in TABLE2_COLUMNS]
    body = []
    for ds, rows in tables.items():
        for i, r in enumerate(rows):
            body.append([DATASET_LABEL.get(ds, ds) if i == 0 else "", r.label] + _row_texts(r, False))
    note = ("\nmean ± variance over test frames. TM = MAE_DE + Σ(1 − IoU) of the four test-set means (eq. 6; "
            "equal to the mean of the per-frame TM); MV = population variance of those four mean terms (eq. 7), one "
            "number per row, computed the same way for every row. Combination = GradNorm (DE, SS) + PolarNet (LS) + "
            "Chen et al. (BEVP), TM and MV from those four means. **Bold**: the best value of the column (lowest "
            "MAE_DE, TM, MV; highest IoU) where a paired bootstrap over the test frames (and seeds) puts the 95% "
            "interval of its difference to the runner-up above 0; "
            f"`{INCONCLUSIVE_MARK}`: the best value, not separated from the runner-up (inconclusive, not bold). "
            f"`{NOT_APPLICABLE}`: task not performed; `{NOT_AVAILABLE}`: no result.\n")
    notes = table2_notes(tables)
    if notes:
        note += "\n" + "".join(f"- {INCONCLUSIVE_MARK} {n}\n" for n in notes)
    return _md_table(header, body, ["---", "---"] + ["---:"] * len(TABLE2_COLUMNS)) + note


def table2_latex(tables: dict[str, list[Table2Row]]) -> str:
    lines = ["% Table II (reproduced). Requires \\usepackage{booktabs}.",
             "\\begin{tabular}{ll" + "c" * len(TABLE2_COLUMNS) + "}", "\\toprule",
             "Dataset & Model & " + " & ".join(COLUMN_TEX[c] for c in TABLE2_COLUMNS) + " \\\\", "\\midrule"]
    for k, (ds, rows) in enumerate(tables.items()):
        if k:
            lines.append("\\midrule")
        for i, r in enumerate(rows):
            first = tex_escape(DATASET_LABEL.get(ds, ds)) if i == 0 else ""
            lines.append(f"{first} & {tex_escape(r.label)} & " + " & ".join(_row_texts(r, True)) + " \\\\")
    lines += ["\\bottomrule", "\\end{tabular}", ""]
    lines += [f"% $^\\dagger$ {tex_escape(n)}" for n in table2_notes(tables)]
    return "\n".join(lines) + ("\n" if table2_notes(tables) else "")


def table2_csv(tables: dict[str, list[Table2Row]]) -> str:
    header = ["dataset", "row_id", "label", "available"]
    for c in TASK_COLUMNS:
        header += [f"{c}_mean", f"{c}_var"]
    header += ["tm", "mv", "bold", "best_inconclusive"]
    body = []
    for ds, rows in tables.items():
        for r in rows:
            line: list[Any] = [ds, r.row_id, r.label, int(r.available)]
            for c in TASK_COLUMNS:
                cell = r.cells.get(c)
                line += [None, None] if cell is None else [cell.mean, cell.var]
            for c in ("tm", "mv"):
                cell = r.cells.get(c)
                line.append(None if cell is None else cell.mean)
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
    """One (dataset, row, column) with the paper's and this run's numbers."""

    dataset: str
    table: str
    row_id: str
    column: str
    paper: Optional[float]
    paper_var: Optional[float] = None
    paper_var_below: bool = False
    ours: Optional[float] = None
    ours_var: Optional[float] = None


def compare(paper: PaperNumbers, table2: dict[str, list[Table2Row]],
            table3: Optional[dict[str, list[Table3Row]]] = None) -> list[Comparison]:
    """Paper numbers beside this run's, for every cell either side has."""
    out: list[Comparison] = []
    for ds, rows in table2.items():
        for r in rows:
            prow = paper.table2_row(ds, r.row_id)
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
                                      cell.mean if cell else None, cell.var if cell else None))
    for ds, rows3 in (table3 or {}).items():
        for r in rows3:
            prow3 = paper.table3_row(ds, r.row_id)
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
                                      ours=None if ov is None else float(ov)))
    return out


def scale_lines(scales: dict[str, DatasetScale], paper: PaperNumbers, *, scale_name: str = "",
                device: str = "") -> list[str]:
    """Sentences stating this run's scale beside the paper's, per dataset."""
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
        ep = ", ".join(f"{ROW_LABEL.get(m, m)} {e.get('epochs_run')} (best {e.get('best_epoch')})"
                       for m, e in sc.epochs.items()) or "no runs"
        lines.append(f"{DATASET_LABEL.get(ds, ds)}: source {sc.source or 'unknown'}; frames train/val/test "
                     f"{counts} (paper {pcounts}); resolution {sc.resolution or '?'} px "
                     f"(paper {t1.get('resolution', 128)}); epochs run (best epoch): {ep}.")
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


def _diff(c: Comparison) -> str:
    """Table II: this run minus the paper; Table III: ratio this run / paper."""
    if c.paper is None or c.ours is None:
        return ""
    if c.table == "III":
        return f"x{c.ours / c.paper:.3g}" if c.paper else ""
    return f"{c.ours - c.paper:+.3f}"


def comparison_markdown(rows: list[Comparison], lines: list[str]) -> str:
    head = "\n".join(f"- {s}" for s in lines) + "\n\n" if lines else ""
    body = [[DATASET_LABEL.get(c.dataset, c.dataset), c.table, ROW_LABEL.get(c.row_id, c.row_id),
             COLUMN_MD.get(c.column, c.column), _cmp_text(c.paper, c.paper_var, c.paper_var_below, c.column),
             _cmp_text(c.ours, c.ours_var, False, c.column),
             _diff(c)]
            for c in rows]
    note = ("\nTable II cells: mean ± variance over test frames. The paper's combination TM/MV are printed on "
            "its PolarNet line; its combination task cells are the baselines' own. Table III: paper memory is "
            "'GPU usage' on an NVIDIA GTX 1080 Ti (probably including the CUDA context); sizes in MB.\n")
    return head + _md_table(["Dataset", "Table", "Model", "Metric", "Paper", "This run", "Diff (II: -, III: ratio)"], body,
                            ["---"] * 4 + ["---:"] * 3) + note


def comparison_latex(rows: list[Comparison], lines: list[str]) -> str:
    out = ["% Paper vs reproduced. Requires \\usepackage{booktabs}."] + [f"% {tex_escape(s)}" for s in lines]
    out += ["\\begin{tabular}{llllrrr}", "\\toprule",
            "Dataset & Table & Model & Metric & Paper & This run & Diff \\\\", "\\midrule"]
    for c in rows:
        diff = _diff(c).replace("x", "$\\times$")
        out.append(" & ".join([tex_escape(DATASET_LABEL.get(c.dataset, c.dataset)), c.table,
                               tex_escape(ROW_LABEL.get(c.row_id, c.row_id)),
                               COLUMN_TEX.get(c.column, tex_escape(c.column)),
                               _cmp_text(c.paper, c.paper_var, c.paper_var_below, c.column, True).replace(",", "{,}"),
                               _cmp_text(c.ours, c.ours_var, False, c.column, True).replace(",", "{,}"), diff]) + " \\\\")
    out += ["\\bottomrule", "\\end{tabular}", ""]
    return "\n".join(out)


def comparison_csv(rows: list[Comparison]) -> str:
    header = ["dataset", "table", "row_id", "column", "paper", "paper_var", "paper_var_below", "reproduced",
              "reproduced_var"]
    return _csv_text(header, [[c.dataset, c.table, c.row_id, c.column, c.paper, c.paper_var,
                               int(c.paper_var_below), c.ours, c.ours_var] for c in rows])


def write_comparison(paper: PaperNumbers, table2: dict[str, list[Table2Row]],
                     table3: Optional[dict[str, list[Table3Row]]], lines: list[str], out_dir: Path) -> list[Path]:
    rows = compare(paper, table2, table3)
    return write_table(out_dir, "paper_vs_reproduced", comparison_markdown(rows, lines),
                       comparison_latex(rows, lines), comparison_csv(rows))


# ----------------------------------------------------------------------------- metrics beyond the paper
EXTRA_TASKS: tuple[str, ...] = ("ss", "ls", "bevp")
EXTRA_DEPTH: tuple[str, ...] = ("abs_rel", "rmse_m", "delta_1.25")
EXTRA_MD: dict[str, str] = {"ss": "mIoU_SS", "ls": "mIoU_LS", "bevp": "mIoU_BEVP", "abs_rel": "AbsRel",
                            "rmse_m": "RMSE (m)", "delta_1.25": "δ<1.25"}


@dataclass
class ExtraRow:
    """One model's metrics beyond the paper's: mIoU (and classes counted) per segmentation
    task; depth errors as (mean, variance over frames)."""

    dataset: str
    row_id: str
    label: str
    miou: dict[str, Optional[float]] = field(default_factory=dict)
    n_classes: dict[str, int] = field(default_factory=dict)
    per_class: dict[str, dict[str, Optional[float]]] = field(default_factory=dict)
    depth: dict[str, Optional[Cell]] = field(default_factory=dict)


def _opt_float(v: Any, where: str) -> Optional[float]:
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
        raise ReportInputError(f"{where}: expected a finite number or null, got {v!r}")
    return float(v)


def build_extra_rows(results: dict[str, dict[str, ModelResult]]) -> list[ExtraRow]:
    """Rows (dataset order, then :data:`ROW_ORDER`) of the models whose metrics files carry a
    ``class_iou`` or ``depth`` block."""
    out: list[ExtraRow] = []
    for ds, res in results.items():
        for rid in ROW_ORDER:
            r = res.get(rid)
            if r is None or not r.extra:
                continue
            where = f"results/{ds}/{rid}/metrics.json"
            row = ExtraRow(ds, rid, ROW_LABEL.get(rid, rid))
            for t in EXTRA_TASKS:
                blk = (r.extra.get("class_iou") or {}).get(t)
                if not isinstance(blk, dict):
                    continue
                row.miou[t] = _opt_float(blk.get("miou"), f"{where}: class_iou.{t}.miou")
                row.n_classes[t] = int(blk.get("n_classes_in_miou") or 0)
                row.per_class[t] = {str(k): _opt_float(v, f"{where}: class_iou.{t}.classes.{k}")
                                    for k, v in (blk.get("classes") or {}).items()}
            dep = r.extra.get("depth") or {}
            for k in EXTRA_DEPTH:
                v = dep.get(k)
                mean = _opt_float(v.get("mean"), f"{where}: depth.{k}.mean") if isinstance(v, dict) else None
                if mean is not None:
                    row.depth[k] = Cell(mean, _opt_float(v.get("var"), f"{where}: depth.{k}.var"))
            out.append(row)
    return out


def _extra_texts(r: ExtraRow) -> list[str]:
    texts = []
    for t in EXTRA_TASKS:
        if t not in r.miou:
            texts.append(NOT_APPLICABLE)
        else:
            v = r.miou[t]
            texts.append(NOT_AVAILABLE if v is None else f"{v:.3f} ({r.n_classes[t]})")
    for k in EXTRA_DEPTH:
        c = r.depth.get(k)
        if c is None:
            texts.append(NOT_APPLICABLE)
        else:
            nd = 2 if k == "rmse_m" else 3
            texts.append(f"{c.mean:.{nd}f}" + ("" if c.var is None else f" ± {c.var:.{nd}f}"))
    return texts


def extra_markdown(rows: list[ExtraRow]) -> str:
    header = ["Dataset", "Model"] + [EXTRA_MD[c] for c in EXTRA_TASKS + EXTRA_DEPTH]
    body, last = [], None
    for r in rows:
        body.append([DATASET_LABEL.get(r.dataset, r.dataset) if r.dataset != last else "", r.label] + _extra_texts(r))
        last = r.dataset
    note = ("\nMetrics the field reports, beside the paper's (not in the paper; Table II's columns are unchanged). "
            "mIoU: per-class IoU = TP / (TP + FP + FN) from counts summed over all test frames, averaged over the "
            "classes present; in brackets the number of classes counted: a class absent from both prediction and "
            "ground truth has no IoU and is left out. SS and LS: predicted class = arg-max, pixels without a label "
            "left out; BEVP: each class a binary mask (> 0.5). Depth: metric depth d = 1000 m · exp((x − 1) · 5.70378) "
            "decoded from the cache's CARLA log depth x ∈ [0, 1] (the world's and the nuScenes ingest's encoding; "
            "prediction clamped to [0, 1], i.e. 3.33 m to 1000 m); pixels with ground truth x = 0 (no depth) or "
            "x = 1 (1000 m far clip, sky) left out; AbsRel, RMSE and δ<1.25 per frame over the valid pixels of the "
            "four views, shown as mean ± variance over frames. Per-class IoUs: `extra_metrics_per_class.csv`. "
            f"`{NOT_APPLICABLE}`: task not performed; `{NOT_AVAILABLE}`: no class present.\n")
    return _md_table(header, body, ["---", "---"] + ["---:"] * (len(header) - 2)) + note


def extra_csv(rows: list[ExtraRow]) -> str:
    header = ["dataset", "row_id", "label"]
    header += [f"miou_{t}" for t in EXTRA_TASKS] + [f"n_classes_{t}" for t in EXTRA_TASKS]
    for k in EXTRA_DEPTH:
        header += [f"{k}_mean", f"{k}_var"]
    body = []
    for r in rows:
        line: list[Any] = [r.dataset, r.row_id, r.label]
        line += [r.miou.get(t) for t in EXTRA_TASKS] + [r.n_classes.get(t) for t in EXTRA_TASKS]
        for k in EXTRA_DEPTH:
            c = r.depth.get(k)
            line += [None, None] if c is None else [c.mean, c.var]
        body.append(line)
    return _csv_text(header, body)


def extra_per_class_csv(rows: list[ExtraRow]) -> str:
    body = [[r.dataset, r.row_id, t, i, name, v] for r in rows for t in EXTRA_TASKS
            for i, (name, v) in enumerate((r.per_class.get(t) or {}).items())]
    return _csv_text(["dataset", "row_id", "task", "class_index", "class", "iou"], body)


def write_extra_metrics(results: dict[str, dict[str, ModelResult]], out_dir: Path) -> list[Path]:
    """``extra_metrics.{md,csv}`` and ``extra_metrics_per_class.csv``; returns the paths."""
    rows = build_extra_rows(results)
    out = {Path(out_dir) / "extra_metrics.md": extra_markdown(rows), Path(out_dir) / "extra_metrics.csv": extra_csv(rows),
           Path(out_dir) / "extra_metrics_per_class.csv": extra_per_class_csv(rows)}
    for path, text in out.items():
        io.write_text(path, text)
    return list(out)
