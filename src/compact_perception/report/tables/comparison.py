"""The paper's published numbers beside this run's (``paper_vs_reproduced.{md,tex,csv}``): every
cell of Table II and Table III either side has, each row of this run against the paper's row it
corresponds to (:func:`~..schema.paper_row`: both MGN forms against the paper's one 15L+MGN row),
headed by sentences stating this run's scale beside the paper's (:func:`scale_lines`)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator, Mapping, Optional, Sequence, TypeVar

from ..collect import Cell, DatasetScale
from ..paper import PaperCell, PaperNumbers
from ..schema import (COLUMN_MD, COLUMN_TEX, COMBINATION, COMBINATION_SOURCE, DATASET_LABEL, ROW_LABEL, TABLE2_COLUMNS,
                      TABLE3_COLUMNS, TASK_COLUMNS, Table3Column, paper_row)
from .formats import (NOT_APPLICABLE, booktabs, csv_text, fmt_num, fmt_seeds, fmt_var, md_table, table_files,
                      tex_escape,
                      training_text)
from .table2 import MGN_NOTE, Table2Row
from .table3 import Table3Row

SPLITS: tuple[str, ...] = ("train", "val", "test")
_Row = TypeVar("_Row", Table2Row, Table3Row)


@dataclass
class PaperComparison:
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


def _with_paper_rows(tables: Mapping[str, Sequence[_Row]]) -> Iterator[tuple[str, _Row, str]]:
    """(dataset, row, the paper's row id it is compared with) of every row of a built table."""
    for ds, rows in tables.items():
        for r in rows:
            yield ds, r, paper_row(r.row_id)


def _table2_comparisons(paper: PaperNumbers, table2: dict[str, list[Table2Row]]) -> list[PaperComparison]:
    """Table II: the paper's mean and frame variance beside this run's mean, sd and frame variance;
    the combination's task cells the paper leaves blank are its source models' printed cells."""
    out: list[PaperComparison] = []
    for ds, r, prid in _with_paper_rows(table2):
        prow = paper.table2_row(ds, prid)
        for col in TABLE2_COLUMNS:
            pv: Optional[float] = None
            pc: Optional[PaperCell] = None
            if prow is not None:
                pv = prow.value(col)
                pc = prow.cells.get(col) if col in TASK_COLUMNS else None
            if r.row_id == COMBINATION and pv is None and col in TASK_COLUMNS:
                src = paper.table2_row(ds, COMBINATION_SOURCE[col])
                pc = src.cells.get(col) if src else None
                pv = pc.mean if pc else None
            cell = r.cells.get(col) if r.available or r.cells.get(col) is not None else None
            if pv is None and cell is None:
                continue
            out.append(PaperComparison(ds, "II", r.row_id, col, pv, pc.var if pc else None,
                                  bool(pc.var_below) if pc else False,
                                  cell.mean if cell else None, cell.var if cell else None,
                                  cell.std if cell else None, cell.n_seeds if cell else None,
                                  prid if prow is not None else None))
    return out


#: The Table III columns compared with the paper's, by their name there (:attr:`~..schema.Table3Column.compared`).
TABLE3_COMPARED: dict[str, Table3Column] = {c.compared: c for c in TABLE3_COLUMNS if c.compared is not None}


def _table3_comparisons(paper: PaperNumbers, table3: dict[str, list[Table3Row]]) -> list[PaperComparison]:
    """Table III: parameters and size (the paper's per-copy numbers times its copies), memory, FPS:
    the columns of :data:`TABLE3_COMPARED`."""
    out: list[PaperComparison] = []
    for ds, r, prid in _with_paper_rows(table3):
        p3 = paper.table3_row(ds, prid)
        if p3 is None:
            continue
        for name, column in TABLE3_COMPARED.items():
            pv3, ov = p3.value(column.key), r.value(column.key)
            if pv3 is None and ov is None:
                continue
            out.append(PaperComparison(ds, "III", r.row_id, name, None if pv3 is None else float(pv3),
                                  ours=None if ov is None else float(ov), paper_row=prid))
    return out


def compare(paper: PaperNumbers, table2: dict[str, list[Table2Row]],
            table3: Optional[dict[str, list[Table3Row]]] = None) -> list[PaperComparison]:
    """Paper numbers beside this run's, for every cell either side has (Table II, then Table III)."""
    return _table2_comparisons(paper, table2) + _table3_comparisons(paper, table3 or {})


# ----------------------------------------------------------------------------- scale
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
        counts = "/".join(str(sc.counts.get(k, "?")) for k in SPLITS) if sc.counts else "unknown"
        pfs = t1.get("frames_per_split", {}).get(ds)
        pcounts = "/".join(str(pfs[k]) for k in SPLITS) if pfs else "?"
        ep = "; ".join(f"{ROW_LABEL.get(m, m)} {training_text(es)}" for m, es in sc.epochs.items()) or "no runs"
        n_test = "/".join(map(str, sc.n_test_frames)) or "?"
        seeds: dict[int, list[str]] = {}
        for m, ks in sc.seeds.items():
            seeds.setdefault(len(ks), []).append(ROW_LABEL.get(m, m))
        seed_txt = "; ".join(f"{n} for {', '.join(ms)}" for n, ms in sorted(seeds.items(), reverse=True)) or "?"
        lines.append(f"{DATASET_LABEL.get(ds, ds)}: source {sc.source or 'unknown'}; frames train/val/test "
                     f"{counts} (paper {pcounts}); test frames scored per run {n_test}; seeds (trainings) "
                     f"{seed_txt}; resolution {sc.resolution or '?'} px (paper {t1.get('resolution', 128)}); "
                     f"epochs run (best epoch), per seed, and why training stopped: {ep}.")
    return lines


# ----------------------------------------------------------------------------- text
def _cmp_text(v: Optional[float], var: Optional[float] = None, below: bool = False, col: str = "",
              latex: bool = False) -> str:
    if v is None:
        return NOT_APPLICABLE
    if col in TABLE3_COMPARED:
        return TABLE3_COMPARED[col].text(v)
    t = fmt_num(v)
    if var is not None:
        pm = " $\\pm$ " if latex else " ± "
        t += pm + ((("$<$" if latex else "<") + f"{var:.3f}") if below else fmt_var(var, latex=latex))
    return t


def _ours_text(c: PaperComparison, latex: bool = False) -> str:
    """Table II: mean ± sd over seeds (``(n=1)`` for one seed); Table III: the number."""
    if c.table != "II" or c.ours is None:
        return _cmp_text(c.ours, col=c.column, latex=latex)
    return fmt_seeds(Cell(c.ours, c.ours_var, c.ours_std, c.n_seeds or 1), latex)


def _ours_var(c: PaperComparison, latex: bool = False) -> str:
    """Table II: this run's variance over test frames (mean over seeds)."""
    return "" if c.table != "II" or c.ours_var is None else fmt_var(c.ours_var, latex=latex)


def _diff(c: PaperComparison) -> str:
    """Table II: this run (mean over seeds) minus the paper; Table III: ratio this run / paper."""
    if c.paper is None or c.ours is None:
        return ""
    if c.table == "III":
        return f"x{c.ours / c.paper:.3g}" if c.paper else ""
    return f"{c.ours - c.paper:+.3f}"


def _cmp_label(c: PaperComparison) -> str:
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


def comparison_markdown(rows: list[PaperComparison], lines: list[str]) -> str:
    head = "\n".join(f"- {s}" for s in lines) + "\n\n" if lines else ""
    body = [[DATASET_LABEL.get(c.dataset, c.dataset), c.table, _cmp_label(c),
             COLUMN_MD.get(c.column, c.column), _cmp_text(c.paper, c.paper_var, c.paper_var_below, c.column),
             _ours_text(c), _ours_var(c), _diff(c)]
            for c in rows]
    header = ["Dataset", "Table", "Model", "Metric", "Paper (mean ± var frames)", "This run (mean ± sd over seeds)",
              "This run: var (frames)", "Diff (II: -, III: ratio)"]
    return head + md_table(header, body, ["---"] * 4 + ["---:"] * 4) + "\n" + CMP_NOTE + "\n"


def comparison_latex(rows: list[PaperComparison], lines: list[str]) -> str:
    body = [" & ".join([tex_escape(DATASET_LABEL.get(c.dataset, c.dataset)), c.table, tex_escape(_cmp_label(c)),
                        COLUMN_TEX.get(c.column, tex_escape(c.column)),
                        _cmp_text(c.paper, c.paper_var, c.paper_var_below, c.column, True).replace(",", "{,}"),
                        _ours_text(c, True).replace(",", "{,}"), _ours_var(c, True),
                        _diff(c).replace("x", "$\\times$")])
            for c in rows]
    return "\n".join(booktabs(
        ["Paper vs reproduced. Requires \\usepackage{booktabs}.", *(tex_escape(s) for s in lines),
         tex_escape(CMP_NOTE.replace('**', ''))],
        "llllrrrr",
        "Dataset & Table & Model & Metric & Paper (mean $\\pm$ var frames) & This run (mean $\\pm$ sd seeds) "
        "& This run var (frames) & Diff", [body]))


def comparison_csv(rows: list[PaperComparison]) -> str:
    header = ["dataset", "table", "row_id", "paper_row", "column", "paper", "paper_var", "paper_var_below",
              "reproduced", "reproduced_std", "reproduced_var", "n_seeds"]
    return csv_text(header, [[c.dataset, c.table, c.row_id, c.paper_row, c.column, c.paper, c.paper_var,
                              int(c.paper_var_below), c.ours, c.ours_std, c.ours_var, c.n_seeds] for c in rows])


def comparison_files(paper: PaperNumbers, table2: dict[str, list[Table2Row]],
                     table3: Optional[dict[str, list[Table3Row]]], lines: list[str]) -> dict[str, str]:
    """``paper_vs_reproduced.{md,tex,csv}`` of the built tables, headed by ``lines`` (file name -> text)."""
    rows = compare(paper, table2, table3)
    return table_files("paper_vs_reproduced", comparison_markdown(rows, lines), comparison_latex(rows, lines),
                       comparison_csv(rows))
