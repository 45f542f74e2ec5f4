"""Metrics beyond the paper's (``extra_metrics.{md,csv}``, ``extra_metrics_per_class.csv``): the
class maps (SS, LS) scored by the other rule, arg-max (Table II scores every row by eq. (5) on the
raw outputs), per-class IoU and mIoU of the segmentation tasks (SS, LS, BEVP) and the depth errors
on metric depth (Eigen et al.'s standard set in the evaluated range), from the ``argmax`` /
``class_iou`` / ``depth`` blocks of the metrics files, as mean ± sd over the seeds; the floor's
trivial predictors first, every model cell marked against them as Table II marks its cells."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

import numpy as np

from ...core import catalog
from ...core.depth import DEPTH_NEAR_M
from ...core.depth_metrics import DEPTH_CONVENTION, DEPTH_METRICS
from ..collect import Cell, ModelResult, ReportInputError, aggregate_cells
from ..gate import ABOVE, BELOW, Gate, margin_on_column
from ..schema import DATASET_LABEL, FLOOR_LABEL, ROW_LABEL, ROW_ORDER, TASK_COLUMNS
from .formats import (BELOW_FLOOR_MARK, NOT_APPLICABLE, NOT_AVAILABLE, UNSHOWN_MARK, and_list, csv_text, fmt_num,
                      fmt_seeds, md_table)

#: The tasks scored by IoU, in task order: evaluate writes their ``class_iou`` blocks.
EXTRA_TASKS: tuple[str, ...] = tuple(t for t in catalog.task_ids() if catalog.metric_of(t).startswith("iou_"))
EXTRA_DEPTH: tuple[str, ...] = tuple(DEPTH_METRICS.keys())
#: The class maps scored by the arg-max rule too (``argmax`` block: metric -> mean, var).
EXTRA_ARGMAX: tuple[str, ...] = tuple(catalog.metric_of(t) for t in catalog.ARGMAX_TASKS)
EXTRA_MD: dict[str, str] = {**{t: f"mIoU_{catalog.TASKS[t].label}" for t in EXTRA_TASKS},
                            **{k: DEPTH_METRICS[k].label for k in EXTRA_DEPTH},
                            **{m: f"{catalog.column_label(m)} (arg-max)" for m in EXTRA_ARGMAX}}


@dataclass
class ExtraRow:
    """One model's (or trivial predictor's, ``fixed``) metrics beyond the paper's, over its seeds:
    the arg-max-rule IoUs and the depth errors (mean ± sd over seeds, per-frame variance mean over
    seeds); mIoU per segmentation task (mean ± sd over seeds, and the classes counted per seed);
    per-class IoU (mean over the seeds where the class has one)."""

    dataset: str
    row_id: str
    label: str
    miou: dict[str, Optional[Cell]] = field(default_factory=dict)
    n_classes: dict[str, tuple[int, ...]] = field(default_factory=dict)
    per_class: dict[str, dict[str, Optional[float]]] = field(default_factory=dict)
    depth: dict[str, Optional[Cell]] = field(default_factory=dict)
    argmax: dict[str, Optional[Cell]] = field(default_factory=dict)
    n_seeds: int = 1
    fixed: bool = False
    marks: dict[str, str] = field(default_factory=dict)      # metric key (:func:`metric_keys`) -> floor mark
    above_paper: Optional[bool] = None                        # above the floor on every Table II task it performs
    depth_max_m: Optional[float] = None                       # the evaluated maximum of its depth errors


def _opt_float(v: Any, where: str) -> Optional[float]:
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
        raise ReportInputError(f"{where}: expected a finite number or null, got {v!r}")
    return float(v)


def _where(r: ModelResult) -> str:
    return f"results/{r.dataset}/{r.model}" + ("" if r.seed is None else f"/seed{r.seed}") + "/metrics.json"


def _add_class_iou(row: ExtraRow, task: str, runs: list[ModelResult]) -> None:
    """mIoU (mean ± sd over the runs), classes counted per run and per-class IoU (mean over the
    runs where the class has one) of ``task`` from the runs' ``class_iou`` blocks."""
    blks = [((r.extra.get("class_iou") or {}).get(task), _where(r)) for r in runs]
    blks = [(b, w) for b, w in blks if isinstance(b, dict)]
    if not blks:
        return
    mious = [_opt_float(b.get("miou"), f"{w}: class_iou.{task}.miou") for b, w in blks]
    vals = [v for v in mious if v is not None]
    row.miou[task] = aggregate_cells([Cell(v) for v in vals]) if vals else None
    row.n_classes[task] = tuple(int(b.get("n_classes_in_miou") or 0) for b, _ in blks)
    classes: dict[str, list[float]] = {}
    for b, w in blks:
        for k, v in (b.get("classes") or {}).items():
            fv = _opt_float(v, f"{w}: class_iou.{task}.classes.{k}")
            classes.setdefault(str(k), [])
            if fv is not None:
                classes[str(k)].append(fv)
    row.per_class[task] = {k: (float(np.mean(v)) if v else None) for k, v in classes.items()}


def _add_block(cells: dict[str, Optional[Cell]], block: str, keys: tuple[str, ...], runs: list[ModelResult]) -> None:
    """Every key of the runs' ``block`` (``{key: {"mean", "var"}}``), mean ± sd over the runs that have it."""
    for k in keys:
        have = []
        for r in runs:
            v = (r.extra.get(block) or {}).get(k)
            mean = _opt_float(v.get("mean"), f"{_where(r)}: {block}.{k}.mean") if isinstance(v, dict) else None
            if mean is not None:
                have.append(Cell(mean, _opt_float(v.get("var"), f"{_where(r)}: {block}.{k}.var")))
        if have:
            cells[k] = aggregate_cells(have)


def _extra_row(ds: str, rid: str, label: str, runs: list[ModelResult], fixed: bool = False) -> ExtraRow:
    row = ExtraRow(ds, rid, label, n_seeds=len(runs), fixed=fixed)
    for t in EXTRA_TASKS:
        _add_class_iou(row, t, runs)
    _add_block(row.depth, "depth", EXTRA_DEPTH, runs)
    caps = {(r.extra.get("depth") or {}).get("max_m") for r in runs} - {None}
    row.depth_max_m = _opt_float(caps.pop(), f"{_where(runs[0])}: depth.max_m") if len(caps) == 1 else None
    _add_block(row.argmax, "argmax", EXTRA_ARGMAX, runs)
    return row


#: Every metric of the table with a floor mark: key -> (cell getter, per-frame column or None, higher is better).
def metric_keys() -> dict[str, tuple[Callable[[ExtraRow], Optional[Cell]], Optional[str], bool]]:
    """The table's metrics (``argmax:<metric>``, ``miou:<task>``, ``depth:<id>``): how to read a
    row's cell, the per-frame column its margin interval uses (``None``: mIoU, pooled counts, no
    per-frame value) and its direction."""
    out: dict[str, tuple[Callable[[ExtraRow], Optional[Cell]], Optional[str], bool]] = {}
    for m in EXTRA_ARGMAX:
        out[f"argmax:{m}"] = (lambda r, m=m: r.argmax.get(m), f"{m}_argmax", True)
    for t in EXTRA_TASKS:
        out[f"miou:{t}"] = (lambda r, t=t: r.miou.get(t), None, True)
    for k in EXTRA_DEPTH:
        out[f"depth:{k}"] = (lambda r, k=k: r.depth.get(k), k, DEPTH_METRICS[k].direction == "higher")
    return out


def _better(a: float, b: float, higher: bool) -> bool:
    return a > b if higher else a < b


def _mark_rows(rows: list[ExtraRow], gate: Optional[Gate]) -> None:
    """The floor marks of one dataset's model rows: ``↓`` where the mean over seeds is no better than
    the better trivial predictor's value, ``°`` where it is better but the margin's interval
    (:func:`~..gate.margin_on_column`, Table II's rule) is not above 0; mIoU (counts pooled over the
    frames, no per-frame value) gets ``↓`` only. Also whether each row is above the floor on the
    paper's metrics (``gate``)."""
    floors = [r for r in rows if r.fixed]
    for key, (get, column, higher) in metric_keys().items():
        values = [(get(f).mean, f.row_id) for f in floors if get(f) is not None]
        if not values:
            continue
        best, src = (max if higher else min)(values, key=lambda v: v[0])
        for r in rows:
            c = get(r)
            if r.fixed or c is None:
                continue
            if not _better(c.mean, best, higher):
                r.marks[key] = BELOW_FLOOR_MARK
            elif column is not None and gate is not None and gate.floor is not None and src in gate.floor.frames:
                m = margin_on_column(gate.frames.get(r.row_id) or [], src, gate.floor.frames[src], column, higher)
                if m.status != ABOVE:
                    r.marks[key] = BELOW_FLOOR_MARK if m.status == BELOW else UNSHOWN_MARK
            elif column is not None:
                r.marks[key] = UNSHOWN_MARK          # no per-frame scores to show it above
    if gate is not None:
        for r in rows:
            if not r.fixed:
                r.above_paper = gate.passes(r.row_id, [c for c in TASK_COLUMNS if gate.frames.get(r.row_id) and
                                                        c in gate.frames[r.row_id][0].columns])


def build_extra_rows(results: dict[str, dict[str, ModelResult]],
                     floors: Optional[dict[str, dict[str, ModelResult]]] = None,
                     gates: Optional[dict[str, Gate]] = None) -> list[ExtraRow]:
    """Rows (dataset order; the trivial predictors of ``floors[ds]`` first, then
    :data:`~..schema.ROW_ORDER`) of the models whose metrics files carry a block beyond the
    paper's, aggregated over the model's runs (seeds), each cell with its floor mark
    (:func:`_mark_rows`; ``gates``: each dataset's per-frame scores for the margins' intervals)."""
    out: list[ExtraRow] = []
    for ds, res in results.items():
        rows: list[ExtraRow] = []
        for tid, r in ((floors or {}).get(ds) or {}).items():
            if r.extra:
                rows.append(_extra_row(ds, tid, FLOOR_LABEL.get(tid, tid), [r], fixed=True))
        for rid in ROW_ORDER:
            agg = res.get(rid)
            runs = [r for r in agg.per_run() if r.extra] if agg is not None else []
            if runs:
                rows.append(_extra_row(ds, rid, ROW_LABEL.get(rid, rid), runs))
        _mark_rows(rows, (gates or {}).get(ds))
        out.extend(rows)
    return out


def below_floor_sentences(rows: list[ExtraRow]) -> list[str]:
    """One sentence per dataset: the models above the floor on the paper's metrics that are below
    it (``↓``) on a metric of this table, and on which."""
    labels = {k: (f"mIoU_{catalog.TASKS[k.split(':')[1]].label}" if k.startswith("miou:")
                  else EXTRA_MD[k.split(":", 1)[1]]) for k in metric_keys()}
    out = []
    for ds in dict.fromkeys(r.dataset for r in rows):
        models = [r for r in rows if r.dataset == ds and not r.fixed]
        name = DATASET_LABEL.get(ds, ds)
        above = [r for r in models if r.above_paper]
        if not above:
            out.append(f"{name}: no model is above the floor on every task of the paper's metrics, so none is "
                       "judged on these.")
            continue
        below = [(r, [labels[k] for k, v in r.marks.items() if v == BELOW_FLOOR_MARK]) for r in above]
        below = [(r, ks) for r, ks in below if ks]
        if not below:
            out.append(f"{name}: every model above the floor on the paper's metrics "
                       f"({and_list([r.label for r in above])}) is no worse than the floor on these too.")
        else:
            out.append(f"{name}: above the floor on the paper's metrics but below it here: "
                       + "; ".join(f"{r.label} on {and_list(ks)}" for r, ks in below) + ".")
    return out


def _value(c: Cell, fixed: bool, decimals: int = 3) -> str:
    """``mean ± sd`` over the seeds, or a trivial predictor's one value."""
    return fmt_num(c.mean, decimals) if fixed else fmt_seeds(c, decimals=decimals)


def _with_var(c: Optional[Cell], fixed: bool, decimals: int, mark: str = "") -> list[str]:
    """A value with its floor mark, and its variance over test frames (mean over the seeds)."""
    if c is None:
        return [NOT_APPLICABLE, NOT_APPLICABLE]
    return [_value(c, fixed, decimals) + mark, "" if c.var is None else f"{c.var:.{decimals}f}"]


def _texts(r: ExtraRow) -> list[str]:
    texts = []
    for m in EXTRA_ARGMAX:
        texts += _with_var(r.argmax.get(m), r.fixed, 3, r.marks.get(f"argmax:{m}", ""))
    for t in EXTRA_TASKS:
        if t not in r.miou:
            texts.append(NOT_APPLICABLE)
        else:
            c = r.miou[t]
            n = r.n_classes[t]
            ncls = str(n[0]) if len(set(n)) == 1 else "/".join(map(str, n))
            texts.append(NOT_AVAILABLE if c is None else f"{_value(c, r.fixed)}{r.marks.get(f'miou:{t}', '')} ({ncls} cl.)")
    for k in EXTRA_DEPTH:
        texts += _with_var(r.depth.get(k), r.fixed, DEPTH_METRICS[k].decimals, r.marks.get(f"depth:{k}", ""))
    return texts


ARGMAX_TEXT = (
    "**Two scoring rules for the class maps.** Table II scores every row by eq. (5) on the raw outputs (a class "
    "counts where its output exceeds 0.5: the paper's rule, which lets a sigmoid head predict nothing and leaves a "
    "softmax head below 0.5 where it is unsure), at the labelled pixels and cells. "
    + " and ".join(f"`{EXTRA_MD[m]}`" for m in EXTRA_ARGMAX)
    + " score the same outputs by the **arg-max rule**: each pixel's highest-scoring class, one-hot, under eq. (5), "
    "pixels without a ground-truth label left out, per view and averaged over the views; mean over the test frames "
    "(`var (frames)`: their variance), then mean ± sd over the seeds. Every model with an SS or LS head has both.")


def extra_markdown(rows: list[ExtraRow]) -> str:
    header = ["Dataset", "Model", "Seeds"]
    for m in EXTRA_ARGMAX:
        header += [f"{EXTRA_MD[m]} (mean ± sd)", "var (frames)"]
    header += [f"{EXTRA_MD[c]} (mean ± sd)" for c in EXTRA_TASKS]
    for k in EXTRA_DEPTH:
        header += [f"{EXTRA_MD[k]} (mean ± sd)", "var (frames)"]
    body, last = [], None
    for r in rows:
        body.append([DATASET_LABEL.get(r.dataset, r.dataset) if r.dataset != last else "", r.label,
                     "fixed" if r.fixed else str(r.n_seeds)] + _texts(r))
        last = r.dataset
    caps = sorted({r.depth_max_m for r in rows if r.depth_max_m is not None})
    cap = "/".join(f"{c:g}" for c in caps) if caps else "?"
    note = ("\nMetrics the field reports, beside the paper's (not in the paper; Table II's columns are unchanged). "
            "Every value: **mean ± sd over the seeds** (sample sd, n − 1; `(n=1)`: one seed) of the run-level value; "
            "`fixed`: a trivial predictor of the floor (deterministic, its one value). **Floor marks**, Table II's "
            f"rule on every metric here: `{BELOW_FLOOR_MARK}` the mean is no better than the better trivial "
            f"predictor's; `{UNSHOWN_MARK}` better, but the 95% interval of the margin (seed-cluster-t over the seeds "
            "and test episodes or scenes, the predictor fixed) reaches 0, or too few seeds; mIoU pools its counts over "
            f"the frames (no per-frame value, no interval), so it gets `{BELOW_FLOOR_MARK}` only. " + ARGMAX_TEXT + " "
            "mIoU: per-class IoU = TP / (TP + FP + FN) from counts summed over all test frames of a run, averaged over "
            "the classes present; `cl.`: the number of classes counted (per seed where they differ): a class absent "
            "from both prediction and ground truth has no IoU and is left out. SS and LS: predicted class = arg-max, "
            "pixels without a label left out; BEVP: each class a binary mask (> 0.5). **Depth**: metric depth "
            "d = 1000 m · exp((x − 1) · 5.70378) decoded from the cache's CARLA log depth x ∈ [0, 1] (the world's and "
            f"the nuScenes ingest's encoding), evaluated from {DEPTH_NEAR_M:.2f} m to {cap} m (params.yaml "
            f"`evaluate.depth_max_m`) by the field's convention, {DEPTH_CONVENTION}: the prediction clamped to that "
            "range; pixels whose ground truth is x = 0 (no depth: on nuScenes, a pixel no LiDAR point projects to), "
            f"x = 1 (1000 m far clip, sky) or deeper than {cap} m left out; "
            f"{and_list([EXTRA_MD[k] for k in EXTRA_DEPTH])} per frame over the valid pixels of the four views "
            f"({'; '.join(DEPTH_METRICS[k].definition for k in EXTRA_DEPTH)}), then the mean over the frames. "
            "Per-class IoUs (mean over the seeds where the class has one): "
            f"`extra_metrics_per_class.csv`. `{NOT_APPLICABLE}`: task not performed; `{NOT_AVAILABLE}`: no class "
            "present.\n")
    head = "".join(f"- {line}\n" for line in below_floor_sentences(rows))
    return (head + "\n" if head else "") + md_table(header, body, ["---", "---", "---:"] + ["---:"] * (len(header) - 3)) + note


def extra_csv(rows: list[ExtraRow]) -> str:
    header = ["dataset", "row_id", "label", "n_seeds"]
    header += [f"miou_{t}" for t in EXTRA_TASKS] + [f"miou_{t}_std" for t in EXTRA_TASKS]
    header += [f"n_classes_{t}" for t in EXTRA_TASKS]
    for k in EXTRA_DEPTH:
        header += [f"{k}_mean", f"{k}_std", f"{k}_var"]
    for m in EXTRA_ARGMAX:
        header += [f"{m}_argmax_mean", f"{m}_argmax_std", f"{m}_argmax_var"]
    header += ["fixed", "below_floor", "not_shown_above"]
    body = []
    for r in rows:
        line: list[Any] = [r.dataset, r.row_id, r.label, r.n_seeds]
        line += [None if r.miou.get(t) is None else r.miou[t].mean for t in EXTRA_TASKS]  # type: ignore[union-attr]
        line += [None if r.miou.get(t) is None else r.miou[t].std for t in EXTRA_TASKS]  # type: ignore[union-attr]
        line += [";".join(map(str, r.n_classes[t])) if t in r.n_classes else None for t in EXTRA_TASKS]
        for c in [r.depth.get(k) for k in EXTRA_DEPTH] + [r.argmax.get(m) for m in EXTRA_ARGMAX]:
            line += [None, None, None] if c is None else [c.mean, c.std, c.var]
        body.append(line + [int(r.fixed), ";".join(k for k, v in r.marks.items() if v == BELOW_FLOOR_MARK),
                            ";".join(k for k, v in r.marks.items() if v == UNSHOWN_MARK)])
    return csv_text(header, body)


def extra_per_class_csv(rows: list[ExtraRow]) -> str:
    body = [[r.dataset, r.row_id, t, i, name, v, r.n_seeds] for r in rows for t in EXTRA_TASKS
            for i, (name, v) in enumerate((r.per_class.get(t) or {}).items())]
    return csv_text(["dataset", "row_id", "task", "class_index", "class", "iou", "n_seeds"], body)


def extra_files(rows: list[ExtraRow]) -> dict[str, str]:
    """``extra_metrics.{md,csv}`` and ``extra_metrics_per_class.csv`` of the built rows (file name -> text)."""
    return {"extra_metrics.md": extra_markdown(rows), "extra_metrics.csv": extra_csv(rows),
            "extra_metrics_per_class.csv": extra_per_class_csv(rows)}
