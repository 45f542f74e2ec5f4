"""Table II (test comparison), Table III (efficiency) and the paper-vs-reproduced table.

Every table is written as Markdown, LaTeX (booktabs) and CSV. Markdown/LaTeX show
``mean ± variance`` rounded to 3 decimals as the paper prints them (a variance below 0.0005
prints as ``<0.001``); the CSV holds the raw numbers (separate mean / variance columns).

Table II rows per dataset: Chen et al., PolarNet, GradNorm, Combination, 1L, 15L, 15L+MGN.
The combination takes GradNorm's DE/SS, PolarNet's LS and Chen et al.'s BEVP, and its TM and
MV are computed from those four means (SPEC 6: TM = MAE + sum(1 - IoU), MV = population
variance of the four terms). A compact row's TM / MV are the means in its metrics file.
The best value per column is bold (lowest MAE / TM / MV, highest IoU), compared at the
printed precision so printed ties are all bold.
"""
from __future__ import annotations

import csv
import io as _io
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Optional

from .. import io
from .collect import Cell, DatasetScale, ModelResult
from .paper import PaperCell, PaperNumbers, combination_terms

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
#: The model each task of the combination comes from (paper section V-D).
COMBINATION_SOURCE: dict[str, str] = {
    "mae_de": "gradnorm_segnet", "iou_ss": "gradnorm_segnet", "iou_ls": "polarnet", "iou_bevp": "chen_bev",
}
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


def combination_row(dataset: str, results: dict[str, ModelResult]) -> Table2Row:
    """GradNorm DE/SS + PolarNet LS + Chen BEVP; TM and MV from those four means."""
    cells: dict[str, Optional[Cell]] = {}
    for col, src in COMBINATION_SOURCE.items():
        res = results.get(src)
        cells[col] = res.scores.get(col) if res else None
    if all(cells[c] is not None for c in TASK_COLUMNS):
        tm, mv = combination_terms(*(cells[c].mean for c in TASK_COLUMNS))  # type: ignore[union-attr]
        cells["tm"], cells["mv"] = Cell(tm), Cell(mv)
    else:
        cells["tm"] = cells["mv"] = None
    available = all(b in results for b in BASELINES)
    if not available:
        log.warning("%s: combination incomplete (missing %s)", dataset, [b for b in BASELINES if b not in results])
    return Table2Row(dataset, "combination", ROW_LABEL["combination"], cells, available)


def model_row(dataset: str, model: str, result: Optional[ModelResult]) -> Table2Row:
    """A model's row from its metrics file (all ``None`` and unavailable if there is none)."""
    if result is None:
        return Table2Row(dataset, model, ROW_LABEL[model], {c: None for c in TABLE2_COLUMNS}, available=False)
    cells: dict[str, Optional[Cell]] = {c: result.scores.get(c) for c in TASK_COLUMNS}
    for c in ("tm", "mv"):
        s = result.scores.get(c)
        cells[c] = None if s is None else Cell(s.mean)
    return Table2Row(dataset, model, ROW_LABEL[model], cells)


def mark_best(rows: list[Table2Row], decimals: int = DECIMALS) -> None:
    """Bold the best value per column (ties at the printed precision all bold)."""
    for col in TABLE2_COLUMNS:
        vals = [(r, round(r.cells[col].mean, decimals)) for r in rows  # type: ignore[union-attr]
                if r.available and r.cells.get(col) is not None]
        if not vals:
            continue
        target = min(v for _, v in vals) if col in LOWER_IS_BETTER else max(v for _, v in vals)
        for r, v in vals:
            if v == target:
                r.bold.add(col)


def build_table2(results: dict[str, dict[str, ModelResult]]) -> dict[str, list[Table2Row]]:
    """Rows per dataset in :data:`ROW_ORDER` (datasets with no results at all are skipped)."""
    out: dict[str, list[Table2Row]] = {}
    for ds, res in results.items():
        if not res:
            continue
        rows = [combination_row(ds, res) if rid == "combination" else model_row(ds, rid, res.get(rid))
                for rid in ROW_ORDER]
        mark_best(rows)
        out[ds] = rows
    return out


def _row_texts(row: Table2Row, latex: bool) -> list[str]:
    texts = []
    for col in TABLE2_COLUMNS:
        if not row.available and row.cells.get(col) is None:
            texts.append(NOT_AVAILABLE)
            continue
        t = fmt_cell(col, row.cells.get(col), latex)
        texts.append(_bold(t, latex) if col in row.bold else t)
    return texts


def table2_markdown(tables: dict[str, list[Table2Row]]) -> str:
    header = ["Dataset", "Model"] + [COLUMN_MD[c] for c in TABLE2_COLUMNS]
    body = []
    for ds, rows in tables.items():
        for i, r in enumerate(rows):
            body.append([DATASET_LABEL.get(ds, ds) if i == 0 else "", r.label] + _row_texts(r, False))
    note = ("\nmean ± variance over test frames; best per column in **bold** (lowest MAE_DE, TM, MV; "
            "highest IoU). Combination = GradNorm (DE, SS) + PolarNet (LS) + Chen et al. (BEVP), TM and MV "
            f"computed from those four scores. `{NOT_APPLICABLE}`: task not performed; `{NOT_AVAILABLE}`: no result.\n")
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
    return "\n".join(lines)


def table2_csv(tables: dict[str, list[Table2Row]]) -> str:
    header = ["dataset", "row_id", "label", "available"]
    for c in TASK_COLUMNS:
        header += [f"{c}_mean", f"{c}_var"]
    header += ["tm", "mv", "bold"]
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
            body.append(line)
    return _csv_text(header, body)


def write_table(out_dir: Path, stem: str, md: str, tex: str, csv_text: str) -> list[Path]:
    """Write ``<stem>.md``, ``.tex``, ``.csv`` atomically; returns the paths."""
    paths = [Path(out_dir) / f"{stem}.{ext}" for ext in ("md", "tex", "csv")]
    for p, text in zip(paths, (md, tex, csv_text)):
        io.write_text(p, text)
    return paths


def write_table2(results: dict[str, dict[str, ModelResult]], out_dir: Path) -> list[Path]:
    tables = build_table2(results)
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


TABLE3_FIELDS: tuple[str, ...] = ("params", "total_params", "size_mb", "total_size_mb", "peak_memory_mb",
                                  "fps", "latency_ms", "device")


def build_table3(efficiency: dict[str, Any]) -> dict[str, list[Table3Row]]:
    """Rows per measured dataset from ``efficiency.json`` (see ``pipeline/benchmark.py``).

    The combination sums the three baselines' parameters, sizes, peak memories and latencies
    (the models run one after the other on the same frame); its FPS is 1000 / summed latency.
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
                                  float(m["peak_memory_mb"]), float(m["fps"]), float(m["latency_ms"]), m.get("device")))
        out[ds] = rows
    return out


def _t3_texts(r: Table3Row) -> list[str]:
    if not r.available:
        return [NOT_AVAILABLE] * len(TABLE3_FIELDS)
    return [
        "" if r.params is None else f"{r.params:,}", "" if r.total_params is None else f"{r.total_params:,}",
        fmt_num(r.size_mb), fmt_num(r.total_size_mb), fmt_num(r.peak_memory_mb, 1), fmt_num(r.fps, 2),
        fmt_num(r.latency_ms, 2), r.device or "",
    ]


def _t3_header(efficiency: dict[str, Any]) -> list[str]:
    gpu = bool(efficiency.get("is_gpu"))
    mem = "GPU memory (MB)" if gpu else "Peak memory, CPU estimate (MB)"
    return ["Params", "Total params", "Size (MB)", "Total size (MB)", mem,
            "FPS" if gpu else "FPS (CPU)", "Latency (ms)", "Device"]


def _t3_note(efficiency: dict[str, Any]) -> str:
    gpu = bool(efficiency.get("is_gpu"))
    s = (f"Batch 1 at {efficiency.get('resolution')}x{efficiency.get('resolution')} px; "
         f"{efficiency.get('warmup')} warm-up iterations excluded, median of {efficiency.get('runs')} timed runs"
         f"{', device synchronised before each clock read' if gpu else ''}. Size = serialised state_dict / 2^20. "
         f"Memory: {efficiency.get('memory_method', '')}.")
    if not gpu:
        s += (" **No GPU on this machine**: FPS and latency are CPU figures, not comparable with the paper's "
              "GPU (NVIDIA GTX 1080 Ti) numbers.")
    return s


def table3_markdown(tables: dict[str, list[Table3Row]], efficiency: dict[str, Any]) -> str:
    header = ["Dataset", "Model"] + _t3_header(efficiency)
    body = []
    for ds, rows in tables.items():
        for i, r in enumerate(rows):
            body.append([_t3_group_label(ds) if i == 0 else "", r.label] + _t3_texts(r))
    return _md_table(header, body, ["---", "---"] + ["---:"] * 7 + ["---"]) + "\n" + _t3_note(efficiency) + "\n"


def _t3_group_label(ds: str) -> str:
    return "Simulation (measured on A)" if ds in ("A", "B", "C") else DATASET_LABEL.get(ds, ds)


def table3_latex(tables: dict[str, list[Table3Row]], efficiency: dict[str, Any]) -> str:
    header = ["Dataset", "Model"] + _t3_header(efficiency)
    lines = ["% Table III (reproduced). Requires \\usepackage{booktabs}.",
             "% " + _t3_note(efficiency).replace("**", ""),
             "\\begin{tabular}{ll" + "r" * 7 + "l}", "\\toprule",
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
