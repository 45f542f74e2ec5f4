"""Metrics beyond the paper's (``extra_metrics.{md,csv}``, ``extra_metrics_per_class.csv``): the
class maps (SS, LS) scored by the other rule, arg-max (Table II scores every row by eq. (5) on the
raw outputs), per-class IoU and mIoU of the segmentation tasks (SS, LS, BEVP) and the depth errors
on metric depth (AbsRel, RMSE, delta < 1.25), from the ``argmax`` / ``class_iou`` / ``depth``
blocks of the metrics files, as mean ± sd over the seeds; the floor's trivial predictors first."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

from ...core import catalog
from ...metrics import ARGMAX_TASKS, DEPTH_METRICS
from ..collect import Cell, ModelResult, ReportInputError, aggregate_cells
from ..schema import DATASET_LABEL, FLOOR_LABEL, ROW_LABEL, ROW_ORDER
from .formats import NOT_APPLICABLE, NOT_AVAILABLE, and_list, csv_text, fmt_num, fmt_seeds, md_table

#: The tasks scored by IoU, in task order: evaluate writes their ``class_iou`` blocks.
EXTRA_TASKS: tuple[str, ...] = tuple(t for t in catalog.task_ids() if catalog.metric_of(t).startswith("iou_"))
EXTRA_DEPTH: tuple[str, ...] = tuple(DEPTH_METRICS.keys())
#: The class maps scored by the arg-max rule too (``argmax`` block: metric -> mean, var).
EXTRA_ARGMAX: tuple[str, ...] = tuple(catalog.metric_of(t) for t in ARGMAX_TASKS)
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
    _add_block(row.argmax, "argmax", EXTRA_ARGMAX, runs)
    return row


def build_extra_rows(results: dict[str, dict[str, ModelResult]],
                     floors: Optional[dict[str, dict[str, ModelResult]]] = None) -> list[ExtraRow]:
    """Rows (dataset order; the trivial predictors of ``floors[ds]`` first, then
    :data:`~..schema.ROW_ORDER`) of the models whose metrics files carry a block beyond the
    paper's, aggregated over the model's runs (seeds)."""
    out: list[ExtraRow] = []
    for ds, res in results.items():
        for tid, r in ((floors or {}).get(ds) or {}).items():
            if r.extra:
                out.append(_extra_row(ds, tid, FLOOR_LABEL.get(tid, tid), [r], fixed=True))
        for rid in ROW_ORDER:
            agg = res.get(rid)
            runs = [r for r in agg.per_run() if r.extra] if agg is not None else []
            if runs:
                out.append(_extra_row(ds, rid, ROW_LABEL.get(rid, rid), runs))
    return out


def _value(c: Cell, fixed: bool, decimals: int = 3) -> str:
    """``mean ± sd`` over the seeds, or a trivial predictor's one value."""
    return fmt_num(c.mean, decimals) if fixed else fmt_seeds(c, decimals=decimals)


def _with_var(c: Optional[Cell], fixed: bool, decimals: int) -> list[str]:
    """A value and its variance over test frames (mean over the seeds)."""
    if c is None:
        return [NOT_APPLICABLE, NOT_APPLICABLE]
    return [_value(c, fixed, decimals), "" if c.var is None else f"{c.var:.{decimals}f}"]


def _texts(r: ExtraRow) -> list[str]:
    texts = []
    for m in EXTRA_ARGMAX:
        texts += _with_var(r.argmax.get(m), r.fixed, 3)
    for t in EXTRA_TASKS:
        if t not in r.miou:
            texts.append(NOT_APPLICABLE)
        else:
            c = r.miou[t]
            n = r.n_classes[t]
            ncls = str(n[0]) if len(set(n)) == 1 else "/".join(map(str, n))
            texts.append(NOT_AVAILABLE if c is None else f"{_value(c, r.fixed)} ({ncls} cl.)")
    for k in EXTRA_DEPTH:
        texts += _with_var(r.depth.get(k), r.fixed, DEPTH_METRICS[k].decimals)
    return texts


ARGMAX_TEXT = (
    "**Two scoring rules for the class maps.** Table II scores every row by eq. (5) on the raw outputs (a class "
    "counts where its output exceeds 0.5: the paper's rule, which lets a sigmoid head predict nothing and leaves a "
    "softmax head below 0.5 where it is unsure). "
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
    note = ("\nMetrics the field reports, beside the paper's (not in the paper; Table II's columns are unchanged). "
            "Every value: **mean ± sd over the seeds** (sample sd, n − 1; `(n=1)`: one seed) of the run-level value; "
            "`fixed`: a trivial predictor of the floor (deterministic, its one value). " + ARGMAX_TEXT + " "
            "mIoU: per-class IoU = TP / (TP + FP + FN) from counts summed over all test frames of a run, averaged over "
            "the classes present; `cl.`: the number of classes counted (per seed where they differ): a class absent "
            "from both prediction and ground truth has no IoU and is left out. SS and LS: predicted class = arg-max, "
            "pixels without a label left out; BEVP: each class a binary mask (> 0.5). Depth: metric depth "
            "d = 1000 m · exp((x − 1) · 5.70378) decoded from the cache's CARLA log depth x ∈ [0, 1] (the world's and "
            "the nuScenes ingest's encoding; prediction clamped to [0, 1], i.e. 3.33 m to 1000 m); pixels with ground "
            "truth x = 0 (no depth) or x = 1 (1000 m far clip, sky) left out; "
            f"{and_list([EXTRA_MD[k] for k in EXTRA_DEPTH])} per frame over the valid pixels of the four views "
            f"({'; '.join(DEPTH_METRICS[k].definition for k in EXTRA_DEPTH)}). "
            "Per-class IoUs (mean over the seeds where the class has one): "
            f"`extra_metrics_per_class.csv`. `{NOT_APPLICABLE}`: task not performed; `{NOT_AVAILABLE}`: no class "
            "present.\n")
    return md_table(header, body, ["---", "---", "---:"] + ["---:"] * (len(header) - 3)) + note


def extra_csv(rows: list[ExtraRow]) -> str:
    header = ["dataset", "row_id", "label", "n_seeds"]
    header += [f"miou_{t}" for t in EXTRA_TASKS] + [f"miou_{t}_std" for t in EXTRA_TASKS]
    header += [f"n_classes_{t}" for t in EXTRA_TASKS]
    for k in EXTRA_DEPTH:
        header += [f"{k}_mean", f"{k}_std", f"{k}_var"]
    for m in EXTRA_ARGMAX:
        header += [f"{m}_argmax_mean", f"{m}_argmax_std", f"{m}_argmax_var"]
    header.append("fixed")
    body = []
    for r in rows:
        line: list[Any] = [r.dataset, r.row_id, r.label, r.n_seeds]
        line += [None if r.miou.get(t) is None else r.miou[t].mean for t in EXTRA_TASKS]  # type: ignore[union-attr]
        line += [None if r.miou.get(t) is None else r.miou[t].std for t in EXTRA_TASKS]  # type: ignore[union-attr]
        line += [";".join(map(str, r.n_classes[t])) if t in r.n_classes else None for t in EXTRA_TASKS]
        for c in [r.depth.get(k) for k in EXTRA_DEPTH] + [r.argmax.get(m) for m in EXTRA_ARGMAX]:
            line += [None, None, None] if c is None else [c.mean, c.std, c.var]
        body.append(line + [int(r.fixed)])
    return csv_text(header, body)


def extra_per_class_csv(rows: list[ExtraRow]) -> str:
    body = [[r.dataset, r.row_id, t, i, name, v, r.n_seeds] for r in rows for t in EXTRA_TASKS
            for i, (name, v) in enumerate((r.per_class.get(t) or {}).items())]
    return csv_text(["dataset", "row_id", "task", "class_index", "class", "iou", "n_seeds"], body)


def extra_files(rows: list[ExtraRow]) -> dict[str, str]:
    """``extra_metrics.{md,csv}`` and ``extra_metrics_per_class.csv`` of the built rows (file name -> text)."""
    return {"extra_metrics.md": extra_markdown(rows), "extra_metrics.csv": extra_csv(rows),
            "extra_metrics_per_class.csv": extra_per_class_csv(rows)}
