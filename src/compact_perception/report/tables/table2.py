"""Table II (test comparison): one row per model of the catalog and the combination of baselines
(:data:`~..schema.ROW_ORDER`), one column per Table II column (:data:`~..schema.TABLE2_COLUMNS`:
the task metrics, then TM and MV), written as Markdown, LaTeX (booktabs) and CSV.

Every model is trained once per training seed (params ``seeds``; the baselines
``baseline_seeds``), so each metric is shown twice, each labelled:

- ``mean ± sd``: the mean over the seeds of the run-level value (a run's test-set mean; TM and
  MV of the run's four test-set means, eq. 6-7 via :func:`compact_perception.metrics.scores_from_means`)
  ± the sample standard deviation (n - 1) over the seeds; with one seed the mean and ``(n=1)``;
- ``var (frames)``: the paper's ``±`` column, the variance over test frames of the per-frame
  score, averaged over the seeds (a variance below 0.0005 prints as ``<0.001`` as in the paper).

The CSV holds the raw numbers (``<col>_mean``, ``<col>_std``, ``<col>_var`` columns), the number
of seeds and of test frames per row.

The combination takes each task from the model that gives it (GradNorm's DE/SS, PolarNet's LS
and Chen et al.'s BEVP) of the same training seed, and its TM and MV per seed are computed from
those four means (eq. 6-7), like every compact run's, so all rows compare with each other and
with the paper. The paper prints one 15L+MGN row; its Table II came from the authors' public
code, and both of this run's MGN rows are compared with it.

Bold (lowest MAE / TM / MV, highest IoU) marks the best value of a column only where the
paired bootstrap over the seeds and test frames (:mod:`compact_perception.stats`) separates it
from the runner-up: the 95% interval of the difference excludes 0. Otherwise the best cell
is not bold and gets a dagger and an "inconclusive" note. The combination's task cells are
copies of its source models' and take no part in the task columns' comparison.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Sequence

import pandas as pd

from ...metrics import scores_from_means
from ...stats import REPRODUCED, BootstrapResult, paired_bootstrap, verdict
from ..collect import Cell, ModelResult, ReportInputError, aggregate_cells, align, pair_by_seed
from ..schema import (COLUMN_MD, COLUMN_TEX, COMBINATION, COMBINATION_MODELS, COMBINATION_SOURCE, DATASET_LABEL,
                      LOWER_IS_BETTER, ROW_LABEL, ROW_ORDER, TABLE2_COLUMNS, TASK_COLUMNS, column_stat, stat_columns)
from .formats import (INCONCLUSIVE_MARK, NOT_APPLICABLE, NOT_AVAILABLE, bold, csv_text, fmt_seeds, fmt_var, md_table,
                      table_files, tex_escape, write_files)

log = logging.getLogger(__name__)

MGN_NOTE = ("The paper prints one 15L+MGN row. Its Table II came from the authors' public code (SPEC 7: their "
            "weight gradients, Huber scale and plateau rule), so both of this run's MGN rows are compared with it: "
            "15L+MGN (Alg. 1) trains with Algorithm 1 as the paper prints it, 15L+MGN (authors' code) as the "
            "authors' code runs it.")
#: Per-frame scores of every row of one dataset: row id -> runs (seeds), frame_id-indexed.
RowFrames = dict[str, list[pd.DataFrame]]
#: The TM and MV columns (the scores over the task metrics), in table order.
_SCORE_COLUMNS: tuple[str, ...] = tuple(c for c in TABLE2_COLUMNS if c not in TASK_COLUMNS)


@dataclass
class Table2Row:
    """One row of Table II. ``cells[col] is None``: the model does not perform that task (or
    TM/MV do not apply); ``available`` is False when the row's inputs are missing. Every cell
    is over the row's ``n_seeds`` runs (:class:`~..collect.Cell`)."""

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


# ----------------------------------------------------------------------------- rows
def combination_row(dataset: str, results: dict[str, ModelResult]) -> Table2Row:
    """The combination of baselines (:data:`~..schema.COMBINATION_SOURCE`). Task cells: the source
    models' own; TM and MV (eq. 6-7) per training seed from the four means of the source models'
    runs of that seed (:func:`~..collect.pair_by_seed`), then mean ± sd over those seeds."""
    cells: dict[str, Optional[Cell]] = {}
    for col, src in COMBINATION_SOURCE.items():
        res = results.get(src)
        cells[col] = res.scores.get(col) if res else None
    available = all(b in results for b in COMBINATION_MODELS)
    cells.update({c: None for c in _SCORE_COLUMNS})
    seeds: tuple[Optional[int], ...] = ()
    if available:
        sources = sorted(set(COMBINATION_SOURCE.values()))
        groups = pair_by_seed([results[m].per_run() for m in sources], lambda r: r.seed)
        per_seed: dict[str, list[Cell]] = {c: [] for c in _SCORE_COLUMNS}
        for group in groups:
            run = dict(zip(sources, group))
            means = {c: run[m].scores[c].mean for c, m in COMBINATION_SOURCE.items() if c in run[m].scores}
            derived = scores_from_means(means)
            for c in _SCORE_COLUMNS if derived else ():
                per_seed[c].append(Cell(derived[c]))
        if all(per_seed.values()):
            cells.update({c: aggregate_cells(v) for c, v in per_seed.items()})
            seeds = tuple(g[0].seed for g in groups)
    else:
        log.warning("%s: combination incomplete (missing %s)", dataset,
                    [b for b in COMBINATION_MODELS if b not in results])
    frames = sorted({r.n_frames for m in COMBINATION_MODELS if m in results for r in results[m].per_run()
                     if r.n_frames})
    return Table2Row(dataset, COMBINATION, ROW_LABEL[COMBINATION], cells, available, n_seeds=len(seeds),
                     seeds=seeds, n_frames=frames[0] if frames else None)


def model_row(dataset: str, model: str, result: Optional[ModelResult]) -> Table2Row:
    """A model's row from its runs' metrics files, aggregated over seeds by
    :func:`~..collect.aggregate_runs` (TM and MV recomputed per run from the run's four task
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
    cols = stat_columns(col)
    runs = [frames.get(best) or [], frames.get(other) or []]
    if not all(runs) or not all(all(c in df.columns for c in cols) for g in runs for df in g):
        return None
    try:
        a, b = align(runs, cols)
    except ReportInputError as err:
        log.warning("Table II %s: %s vs %s: %s", col, best, other, err)
        return None
    return paired_bootstrap(a, b, column_stat(col), lower_is_better=col in LOWER_IS_BETTER)


def mark_best(rows: list[Table2Row], frames: Optional[RowFrames] = None) -> None:
    """Bold the best value of each column where the bootstrap separates it from the runner-up
    (95% interval of the difference above 0); otherwise note why it is not bold."""
    frames = frames or {}
    for col in TABLE2_COLUMNS:
        cands = [r for r in rows if r.available and r.cells.get(col) is not None
                 and not (r.row_id == COMBINATION and col in TASK_COLUMNS)]
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
    """Rows per dataset in :data:`~..schema.ROW_ORDER` (datasets with no results at all are
    skipped); ``frames[ds]``: per-frame scores per row id (the combination included) for the bold marks."""
    out: dict[str, list[Table2Row]] = {}
    for ds, res in results.items():
        if not res:
            continue
        rows = [combination_row(ds, res) if rid == COMBINATION else model_row(ds, rid, res.get(rid))
                for rid in ROW_ORDER]
        mark_best(rows, (frames or {}).get(ds))
        out[ds] = rows
    return out


# ----------------------------------------------------------------------------- text
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
        texts.append(bold(t, latex) if col in row.bold else t)
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
            if r.available and r.row_id != COMBINATION and r.seeds:
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


def _header(latex: bool) -> list[str]:
    out = ["Dataset", "Model", "Seeds"]
    for c in TABLE2_COLUMNS:
        name = COLUMN_TEX[c] if latex else COLUMN_MD[c]
        out.append(f"{name} (mean $\\pm$ sd)" if latex else f"{name} (mean ± sd)")
        if c in TASK_COLUMNS:
            out.append("var (frames)")
    return out


def table2_markdown(tables: dict[str, list[Table2Row]]) -> str:
    header = _header(False)
    body = []
    for ds, rows in tables.items():
        for i, r in enumerate(rows):
            body.append([DATASET_LABEL.get(ds, ds) if i == 0 else "", r.label, str(r.n_seeds) if r.n_seeds else ""]
                        + _row_texts(r, False))
    note = "\n" + table2_caption(tables) + "\n"
    notes = table2_notes(tables)
    if notes:
        note += "\n" + "".join(f"- {INCONCLUSIVE_MARK} {n}\n" for n in notes)
    return md_table(header, body, ["---", "---", "---:"] + ["---:"] * (len(header) - 3)) + note


def table2_latex(tables: dict[str, list[Table2Row]]) -> str:
    header = _header(True)
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
    empty for one seed), ``_var`` (per-frame variance, mean over seeds); per score (TM, MV) its
    mean over seeds and ``_std``."""
    header = ["dataset", "row_id", "label", "available", "n_seeds", "seeds", "n_test_frames"]
    for c in TASK_COLUMNS:
        header += [f"{c}_mean", f"{c}_std", f"{c}_var"]
    for c in _SCORE_COLUMNS:
        header += [c, f"{c}_std"]
    header += ["bold", "best_inconclusive"]
    body = []
    for ds, rows in tables.items():
        for r in rows:
            line: list[Any] = [ds, r.row_id, r.label, int(r.available), r.n_seeds,
                               ";".join("" if k is None else str(k) for k in r.seeds), r.n_frames]
            for c in TASK_COLUMNS:
                cell = r.cells.get(c)
                line += [None, None, None] if cell is None else [cell.mean, cell.std, cell.var]
            for c in _SCORE_COLUMNS:
                cell = r.cells.get(c)
                line += [None, None] if cell is None else [cell.mean, cell.std]
            line.append(";".join(c for c in TABLE2_COLUMNS if c in r.bold))
            line.append(";".join(c for c in TABLE2_COLUMNS if c in r.notes))
            body.append(line)
    return csv_text(header, body)


def table2_files(tables: dict[str, list[Table2Row]]) -> dict[str, str]:
    """``table2.{md,tex,csv}`` of the built table (file name -> text)."""
    return table_files("table2", table2_markdown(tables), table2_latex(tables), table2_csv(tables))


def write_table2(results: dict[str, dict[str, ModelResult]], out_dir: Path,
                 frames: Optional[dict[str, RowFrames]] = None) -> list[Path]:
    """Build Table II and write ``table2.{md,tex,csv}`` under ``out_dir``; returns the paths."""
    return write_files(out_dir, table2_files(build_table2(results, frames)))
