"""Table II (test comparison): per dataset, the trivial predictors of the floor first (SPEC 8,
:data:`~..schema.FLOOR_IDS`), then one row per model of the catalog and the combination of
baselines (:data:`~..schema.ROW_ORDER`), one column per Table II column
(:data:`~..schema.TABLE2_COLUMNS`: the task metrics, then TM and MV), written as Markdown,
LaTeX (booktabs) and CSV.

One scoring rule for every row: eq. (5) on the raw outputs (a class counts where its output
exceeds 0.5), the paper's, for the compact networks' sigmoid heads and the softmax baselines
alike, with the class maps' unlabelled pixels (an LS cell no LiDAR point reached) left out for
every row (:func:`compact_perception.learning.metrics.labelled_only`); the arg-max rule sits beside it in
the extra metrics (``extra_metrics.md``).

Every model is trained once per training seed (params ``seeds``; the baselines
``baseline_seeds``), so each metric is shown twice, each labelled:

- ``mean ± sd``: the mean over the seeds of the run-level value (a run's test-set mean; TM and
  MV of the run's four test-set means, eq. 6-7 via :func:`compact_perception.core.catalog.scores_from_means`)
  ± the sample standard deviation (n - 1) over the seeds; with one seed the mean and ``(n=1)``;
  a trivial predictor is deterministic: its one value;
- ``var (frames)``: the paper's ``±`` column, the variance over test frames of the per-frame
  score, averaged over the seeds (a variance below 0.0005 prints as ``<0.001`` as in the paper).

Each model row also says how deep it trained (epochs run, best epoch, why training stopped:
``summary.json``) and whether it is above the floor (:mod:`..gate`); a cell no better than the
floor is marked ``↓``, a better one whose margin's interval is not above 0 ``°``.

The CSV holds the raw numbers (``<col>_mean``, ``<col>_std``, ``<col>_var`` columns), the number
of seeds and of test frames per row, the gate and the training facts.

The combination takes each task from the model that gives it (GradNorm's DE/SS, PolarNet's LS
and Chen et al.'s BEVP) of the same training seed, and its TM and MV per seed are computed from
those four means (eq. 6-7), like every compact run's, so all rows compare with each other and
with the paper. The paper prints one 15L+MGN row; its Table II came from the authors' public
code, and both of this run's MGN rows are compared with it.

Bold (lowest MAE / TM / MV, highest IoU) marks the best value of a column only where that row
is above the floor on the column's metrics (TM and MV: all four task metrics) and the interval of
:func:`compact_perception.stats.interval` (seed-paired where both rows share seeds, the test
episodes or scenes as clusters, at least three seeds a side) separates it from the runner-up:
the 95% interval of the difference above 0. Otherwise the best cell is not bold and gets a dagger
and a note saying why. The combination's task cells are copies of its source models' and take
no part in the task columns' comparison; the floor rows take none at all.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any, Mapping, Optional, Sequence

import pandas as pd

from ...core.catalog import scores_from_means
from ...stats import REPRODUCED, IntervalResult, MIN_SEEDS, interval, verdict
from ..collect import Cell, ModelResult, ReportInputError, aggregate_cells, frame_comparison, pair_by_seed
from ..gate import ABOVE, BELOW, NO_FLOOR, UNSHOWN, DatasetFloor, Gate
from ..schema import (COLUMN_MD, COLUMN_TEX, COMBINATION, COMBINATION_MODELS, COMBINATION_SOURCE, DATASET_LABEL,
                      FLOOR_IDS, FLOOR_LABEL, LOWER_IS_BETTER, METRIC_TASK, ROW_LABEL, ROW_ORDER, TABLE2_COLUMNS,
                      TASK_COLUMNS, beats, column_stat, stat_columns)
from .formats import (BELOW_FLOOR_MARK, BELOW_FLOOR_TEX, INCONCLUSIVE_MARK, NOT_APPLICABLE, NOT_AVAILABLE, booktabs,
                      UNSHOWN_MARK, UNSHOWN_TEX, bold, csv_text, fmt_num, fmt_seeds, fmt_var, md_table, table_files,
                      tex_escape, training_text)

log = logging.getLogger(__name__)

MGN_NOTE = ("The paper prints one 15L+MGN row. Its Table II came from the authors' public code (SPEC 7: their "
            "weight gradients, Huber scale and plateau rule), so both of this run's MGN rows are compared with it: "
            "15L+MGN (Alg. 1) trains with Algorithm 1 as the paper prints it, 15L+MGN (authors' code) as the "
            "authors' code runs it.")
#: The one scoring rule of Table II, and where the other one is.
SCORING_RULE = ("**Scoring rule, every row**: eq. (5) on the raw outputs (a class counts where its output exceeds "
                "0.5), the paper's, for the compact networks' sigmoid heads and the softmax baselines (GradNorm's SS, "
                "PolarNet's LS) alike; pixels and cells without a label (an LS cell no LiDAR point reached, a nuScenes camera pixel no point "
                "projects to) count for no row, as LiDAR segmentation is scored at the points (PolarSeg, "
                "SemanticKITTI); the arg-max rule (each pixel's highest-scoring class, labelled pixels only) is "
                "in the extra metrics (`extra_metrics.md`, `IoU_SS (arg-max)`, `IoU_LS (arg-max)`).")
#: Per-frame scores of every row of one dataset: row id -> runs (seeds), frame_id-indexed.
RowFrames = dict[str, list[pd.DataFrame]]
#: A dataset's training facts: model -> one ``summary.json`` fact dict per run (``collect.DatasetScale.epochs``).
Training = Mapping[str, Sequence[Mapping[str, Any]]]
#: The TM and MV columns (the scores over the task metrics), in table order.
_SCORE_COLUMNS: tuple[str, ...] = tuple(c for c in TABLE2_COLUMNS if c not in TASK_COLUMNS)
#: The columns whose cells carry the floor marks: the task metrics and TM (MV has no floor).
FLOOR_COLUMNS: tuple[str, ...] = TASK_COLUMNS + ("tm",)
FLOOR_KIND, MODEL_KIND, COMBINATION_KIND = "floor", "model", "combination"
#: The ``summary.json`` facts of the CSV, one value per seed.
_FACTS: tuple[str, ...] = ("epochs_run", "best_epoch", "stop_reason")


@dataclass
class Table2Row:
    """One row of Table II. ``cells[col] is None``: the model does not perform that task (or
    TM/MV do not apply); ``available`` is False when the row's inputs are missing. Every cell
    is over the row's ``n_seeds`` runs (:class:`~..collect.Cell`). ``kind``: ``floor`` (a
    trivial predictor), ``model`` or ``combination``; ``floor``: column -> gate status
    (:mod:`..gate`); ``above_floor``: ``yes``, ``no: LS, BEVP`` (the tasks not above it) or empty
    (a floor row); ``training``: epochs run (best epoch), stop reason."""

    dataset: str
    row_id: str
    label: str
    cells: dict[str, Optional[Cell]]
    available: bool = True
    bold: set[str] = field(default_factory=set)
    #: column -> why the best value of that column is not bold (below the floor, not separated, untested)
    notes: dict[str, str] = field(default_factory=dict)
    n_seeds: int = 0
    seeds: tuple[Optional[int], ...] = ()
    n_frames: Optional[int] = None
    kind: str = MODEL_KIND
    floor: dict[str, str] = field(default_factory=dict)
    above_floor: str = ""
    training: str = ""
    facts: tuple[Mapping[str, Any], ...] = ()


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
                     seeds=seeds, n_frames=frames[0] if frames else None, kind=COMBINATION_KIND)


def model_row(dataset: str, model: str, result: Optional[ModelResult],
              facts: Sequence[Mapping[str, Any]] = ()) -> Table2Row:
    """A model's row from its runs' metrics files, aggregated over seeds by
    :func:`~..collect.aggregate_runs` (TM and MV recomputed per run from the run's four task
    means, eq. 6-7, exactly as for the combination); all ``None`` and unavailable if there is
    none. ``facts``: its runs' ``summary.json`` facts (how deep they trained)."""
    label = ROW_LABEL.get(model, model)
    if result is None:
        return Table2Row(dataset, model, label, {c: None for c in TABLE2_COLUMNS}, available=False)
    cells: dict[str, Optional[Cell]] = {c: result.scores.get(c) for c in TABLE2_COLUMNS}
    return Table2Row(dataset, model, label, cells, n_seeds=result.n_seeds, seeds=result.seeds,
                     n_frames=result.n_frames, training=training_text(facts), facts=tuple(facts))


def floor_row(dataset: str, trivial_id: str, result: ModelResult) -> Table2Row:
    """A trivial predictor's row: its one deterministic run (no seed, nothing trained)."""
    cells: dict[str, Optional[Cell]] = {c: result.scores.get(c) for c in TABLE2_COLUMNS}
    return Table2Row(dataset, trivial_id, FLOOR_LABEL[trivial_id], cells, n_frames=result.n_frames, kind=FLOOR_KIND)


def column_interval(best: str, other: str, col: str, frames: RowFrames) -> Optional[IntervalResult]:
    """The interval (:func:`compact_perception.stats.interval`) of "row ``best`` beats row
    ``other`` on column ``col``" (positive = it does) from their per-frame scores; ``None`` if
    either has no per-frame scores for it."""
    cols = stat_columns(col)
    runs = [frames.get(best) or [], frames.get(other) or []]
    if not all(runs) or not all(all(c in df.columns for c in cols) for g in runs for df in g):
        return None
    try:
        comp = frame_comparison(runs, cols)
    except ReportInputError as err:
        log.warning("Table II %s: %s vs %s: %s", col, best, other, err)
        return None
    return interval(comp, column_stat(col), beats(col))


def mark_floor(rows: list[Table2Row], gate: Gate) -> None:
    """Each trained row's gate status per column of :data:`FLOOR_COLUMNS` it has, and whether it is
    above the floor on every task it performs (:mod:`..gate`)."""
    for r in rows:
        if r.kind == FLOOR_KIND or not r.available:
            continue
        cols = [c for c in FLOOR_COLUMNS if r.cells.get(c) is not None]
        r.floor = {c: gate.margin(r.row_id, c).status for c in cols}
        if not gate.has_floor:
            r.above_floor = "no floor"
            continue
        failing = [c for c in cols if c in TASK_COLUMNS and r.floor[c] != ABOVE]
        r.above_floor = "no: " + ", ".join(METRIC_TASK[c] for c in failing) if failing else "yes"


def _not_separated(res: Optional[IntervalResult], col: str, runner: Table2Row) -> Optional[str]:
    """Why the interval does not separate the best from the runner-up (``None``: it does)."""
    what = f"best {COLUMN_MD[col]}"
    if res is None:
        return f"{what}, not tested against {runner.label} (no per-frame scores): not bold"
    if not res.decidable:
        seeds = " vs ".join(str(n) for n in res.n_seeds)
        return f"{what} against {runner.label}: not decidable ({seeds} seeds, fewer than {MIN_SEEDS}): not bold"
    if verdict(res.ci_low, res.ci_high) == REPRODUCED:
        return None
    return (f"{what} inconclusive against {runner.label}: difference {res.estimate:.4f}, 95% CI "
            f"[{res.ci_low:.4f}, {res.ci_high:.4f}]: not bold")


def mark_best(rows: list[Table2Row], frames: Optional[RowFrames] = None, gate: Optional[Gate] = None) -> None:
    """Bold the best value of each column where that row is above the floor on the column's
    metrics and the interval separates it from the runner-up; otherwise note why it is not bold."""
    frames = frames or {}
    gate = gate if gate is not None else Gate(None, frames)
    for col in TABLE2_COLUMNS:
        cands = [r for r in rows if r.kind != FLOOR_KIND and r.available and r.cells.get(col) is not None
                 and not (r.row_id == COMBINATION and col in TASK_COLUMNS)]
        if not cands:
            continue
        sign = 1.0 if col in LOWER_IS_BETTER else -1.0
        order = sorted(cands, key=lambda r: sign * r.cells[col].mean)  # type: ignore[union-attr]
        best = order[0]
        failing = gate.failing(best.row_id, stat_columns(col))
        if failing:
            why = "no floor results" if any(m.status == NO_FLOOR for m in failing) else \
                "not above the floor on " + ", ".join(f"{METRIC_TASK[m.metric]} ({m.reason()})" for m in failing)
            best.notes[col] = f"best {COLUMN_MD[col]}, {why}: not bold"
            continue
        if len(order) == 1:
            best.bold.add(col)
            continue
        why = _not_separated(column_interval(best.row_id, order[1].row_id, col, frames), col, order[1])
        if why is None:
            best.bold.add(col)
        else:
            best.notes[col] = why


def build_table2(results: dict[str, dict[str, ModelResult]], frames: Optional[dict[str, RowFrames]] = None, *,
                 floors: Optional[Mapping[str, DatasetFloor]] = None, gates: Optional[Mapping[str, Gate]] = None,
                 training: Optional[Mapping[str, Training]] = None) -> dict[str, list[Table2Row]]:
    """Rows per dataset: the floor's trivial predictors, then :data:`~..schema.ROW_ORDER` (datasets
    with no results at all are skipped). ``frames[ds]``: per-frame scores per row id (the
    combination included) for the bold marks and the gate; ``floors[ds]``: the trivial predictors;
    ``gates[ds]``: the gate already built (else built from ``floors`` and ``frames``);
    ``training[ds]``: model -> its runs' ``summary.json`` facts."""
    out: dict[str, list[Table2Row]] = {}
    for ds, res in results.items():
        if not res:
            continue
        floor = (floors or {}).get(ds)
        gate = (gates or {}).get(ds) or Gate(floor, (frames or {}).get(ds))
        facts = (training or {}).get(ds, {})
        rows = [floor_row(ds, t, r) for t, r in (gate.floor.results.items() if gate.floor else ())]
        rows += [combination_row(ds, res) if rid == COMBINATION else model_row(ds, rid, res.get(rid), facts.get(rid, ()))
                 for rid in ROW_ORDER]
        mark_floor(rows, gate)
        mark_best(rows, (frames or {}).get(ds), gate)
        out[ds] = rows
    return out


# ----------------------------------------------------------------------------- text
_FLOOR_MARKS: dict[str, tuple[str, str]] = {BELOW: (BELOW_FLOOR_MARK, BELOW_FLOOR_TEX), UNSHOWN: (UNSHOWN_MARK, UNSHOWN_TEX)}


def _cell_text(row: Table2Row, col: str, latex: bool) -> str:
    """A metric cell: ``mean ± sd`` (a floor row: its one value), its floor mark, dagger and bold."""
    cell = row.cells.get(col)
    t = fmt_num(cell.mean) if row.kind == FLOOR_KIND and cell is not None else fmt_seeds(cell, latex)
    mark = _FLOOR_MARKS.get(row.floor.get(col, ""))
    if mark:
        t += mark[1] if latex else mark[0]
    if col in row.notes:
        t += "$^\\dagger$" if latex else INCONCLUSIVE_MARK
    return bold(t, latex) if col in row.bold else t


def _row_texts(row: Table2Row, latex: bool) -> list[str]:
    """Per column: the seed cell (``mean ± sd``, floor, bold and dagger marks) and, for a task
    column, the per-frame variance cell after it; then whether the row is above the floor."""
    texts = []
    for col in TABLE2_COLUMNS:
        cell = row.cells.get(col)
        if not row.available and cell is None:
            texts += [NOT_AVAILABLE] * (2 if col in TASK_COLUMNS else 1)
            continue
        texts.append(_cell_text(row, col, latex))
        if col in TASK_COLUMNS:
            texts.append(NOT_APPLICABLE if cell is None else (fmt_var(cell.var, latex=latex) or NOT_AVAILABLE))
    return texts + [row.above_floor or NOT_APPLICABLE]


def _lead(row: Table2Row) -> tuple[str, str]:
    """The Seeds and Trained cells: ``fixed`` and ``-`` for a trivial predictor (nothing trained)."""
    if row.kind == FLOOR_KIND:
        return "fixed", NOT_APPLICABLE
    return (str(row.n_seeds) if row.n_seeds else ""), row.training


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
            if r.available and r.kind == MODEL_KIND and r.seeds:
                key = tuple(r.seeds)
                if r.label not in seeds.setdefault(key, []):
                    seeds[key].append(r.label)
    seed_txt = "; ".join(f"{', '.join(labels)}: {_seed_text(k)}" for k, labels in seeds.items()) or "none"
    frames = []
    for ds, rows in tables.items():
        n = sorted({r.n_frames for r in rows if r.n_frames})
        frames.append(f"{DATASET_LABEL.get(ds, ds)} {'/'.join(map(str, n)) or '?'}")
    return f"Seeds (trainings) per row: {seed_txt}. Test frames per run: {', '.join(frames)}."


FLOOR_TEXT = (
    "**The floor** (SPEC 8): the first rows of every dataset are input-blind predictors fitted on the train split "
    "and scored on the test split with the same metric code: " + " and ".join(FLOOR_LABEL[t] for t in FLOOR_IDS)
    + " (`fixed`: deterministic, no seed). The floor of a task metric is the better of their means (of TM, the "
    "better of their TMs). A model's **margin** over it: its value minus the floor's, signed so that positive is "
    "better, mean over its seeds, with the 95% interval of the report's method (seed-cluster-t: the model's seeds "
    "and the test episodes or scenes as the random factors; the predictor fixed). A cell is above the floor when "
    f"that interval lies above 0 and the model has at least {MIN_SEEDS} seeds; `{BELOW_FLOOR_MARK}`: **below the "
    f"floor**, the mean is no better than the floor's; `{UNSHOWN_MARK}`: better than the floor's but not shown "
    "above it (the interval reaches 0, or fewer seeds). `Above floor`: `yes` when the row is above the floor on "
    "every task it performs, else the tasks where it is not. `Trained`: epochs run (best epoch) per seed and why "
    "training stopped (`plateau`: early stopping; `max_epochs`: the cap), from each run's `summary.json`.")


def table2_caption(tables: dict[str, list[Table2Row]]) -> str:
    return (f"{table2_scale(tables)} {SCORING_RULE} "
            "Each metric column: **mean ± sd over the seeds** of the run-level value (a run's test-set mean; TM "
            "and MV of the run's four test-set means), sd the sample standard deviation (n − 1) over the seeds; "
            "`(n=1)`: a single seed, no sd. Each `var (frames)` column: the paper's ± (**variance over the test "
            "frames** of the per-frame score, population), averaged over the seeds. TM = MAE_DE + Σ(1 − IoU) of "
            "the four test-set means (eq. 6; equal to the mean of the per-frame TM); MV = population variance of "
            "those four mean terms (eq. 7), one number per run. Combination = GradNorm (DE, SS) + PolarNet (LS) + "
            "Chen et al. (BEVP) of the same seed, TM and MV from those four means. " + MGN_NOTE + " " + FLOOR_TEXT
            + " **Bold**: the best value of the column (lowest MAE_DE, TM, MV; highest IoU), only where its row is "
            "above the floor on the column's metrics (TM and MV: all four tasks) and the 95% interval of its "
            "difference to the runner-up (seed-cluster-t, seed-paired where the rows share seeds, at least "
            f"{MIN_SEEDS} seeds a side) lies above 0; `{INCONCLUSIVE_MARK}`: the best value, not bold (the note "
            f"says why). `{NOT_APPLICABLE}`: task not performed; `{NOT_AVAILABLE}`: no result.")


def _header(latex: bool) -> list[str]:
    out = ["Dataset", "Model", "Seeds", "Trained"]
    for c in TABLE2_COLUMNS:
        name = COLUMN_TEX[c] if latex else COLUMN_MD[c]
        out.append(f"{name} (mean $\\pm$ sd)" if latex else f"{name} (mean ± sd)")
        if c in TASK_COLUMNS:
            out.append("var (frames)")
    return out + ["Above floor"]


def table2_markdown(tables: dict[str, list[Table2Row]]) -> str:
    header = _header(False)
    body = []
    for ds, rows in tables.items():
        for i, r in enumerate(rows):
            body.append([DATASET_LABEL.get(ds, ds) if i == 0 else "", r.label, *_lead(r)] + _row_texts(r, False))
    note = "\n" + table2_caption(tables) + "\n"
    notes = table2_notes(tables)
    if notes:
        note += "\n" + "".join(f"- {INCONCLUSIVE_MARK} {n}\n" for n in notes)
    return md_table(header, body, ["---", "---", "---:", "---"] + ["---:"] * (len(header) - 5) + ["---"]) + note


def table2_latex(tables: dict[str, list[Table2Row]]) -> str:
    header = _header(True)

    def row(first: str, r: Table2Row) -> str:
        texts = _row_texts(r, True)
        lead = " & ".join(tex_escape(t) for t in _lead(r))
        return f"{first} & {tex_escape(r.label)} & {lead} & " + " & ".join(texts[:-1]) + f" & {tex_escape(texts[-1])}"

    lines = booktabs(["Table II (reproduced). Requires \\usepackage{booktabs}.",
                      tex_escape(table2_caption(tables).replace("**", "").replace("`", ""))],
                     "llrl" + "c" * (len(header) - 5) + "l",
                     " & ".join(h if "$" in h else tex_escape(h) for h in header),
                     [[row(tex_escape(DATASET_LABEL.get(ds, ds)) if i == 0 else "", r) for i, r in enumerate(rows)]
                      for ds, rows in tables.items()])
    lines += [f"% $^\\dagger$ {tex_escape(n)}" for n in table2_notes(tables)]
    return "\n".join(lines) + ("\n" if table2_notes(tables) else "")


def table2_csv(tables: dict[str, list[Table2Row]]) -> str:
    """Raw numbers: per task column ``_mean`` (over seeds), ``_std`` (sample sd over seeds,
    empty for one seed), ``_var`` (per-frame variance, mean over seeds); per score (TM, MV) its
    mean over seeds and ``_std``; the row's ``kind`` (floor, model, combination), the gate
    (``above_floor``; the columns ``below_floor`` and ``not_shown_above_floor``) and, per seed,
    ``epochs_run``, ``best_epoch``, ``stop_reason``."""
    header = ["dataset", "row_id", "label", "available", "n_seeds", "seeds", "n_test_frames"]
    for c in TASK_COLUMNS:
        header += [f"{c}_mean", f"{c}_std", f"{c}_var"]
    for c in _SCORE_COLUMNS:
        header += [c, f"{c}_std"]
    header += ["bold", "best_inconclusive", "kind", "above_floor", "below_floor", "not_shown_above_floor",
               *_FACTS]
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
            line += [r.kind, r.above_floor, *(";".join(c for c in FLOOR_COLUMNS if r.floor.get(c) == s)
                                               for s in (BELOW, UNSHOWN))]
            line += [";".join("" if f.get(k) is None else str(f.get(k)) for f in r.facts) for k in _FACTS]
            body.append(line)
    return csv_text(header, body)


def table2_files(tables: dict[str, list[Table2Row]]) -> dict[str, str]:
    """``table2.{md,tex,csv}`` of the built table (file name -> text)."""
    return table_files("table2", table2_markdown(tables), table2_latex(tables), table2_csv(tables))
