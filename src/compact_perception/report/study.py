"""The loss-balancing study's report (beyond the paper): ``reports/tables/weighting.{md,csv}`` and
``reports/figures/report/loss_weights_study_<ds>.png``.

Methods, per dataset of ``study.datasets`` (at ``scale``), in this order:

- the paper's own weighting forms, the main runs (:func:`paper_forms`): the compact models with
  the base model's input, each with the weighting of its recipe (params.yaml
  ``train.models.<id>.weighting``): ``compact_15l`` (equal static weights), ``compact_15l_mgn``
  (MGN, Algorithm 1), ``compact_15l_mgn_authors`` (MGN as the authors' code runs it), read
  through :func:`.collect.list_runs`;
- every study arm in ``study.arm_ids`` order (``runs/<ds>/study/<arm>/seed<k>/``,
  ``results/<ds>/study/<arm>/seed<k>/metrics.json``; :func:`compact_perception.core.layout.study_paths`),
  the single-task arms (weighting ``single``) included: they are Δm's reference.

Per run (one training seed of params ``seeds``): the four task metrics (test-set means), TM and MV
of those means (eq. 6-7, :func:`.collect.with_derived`), Δm against the single-task reference
(:func:`delta_m`) and the training time per epoch (``summary.json``: ``train_seconds /
epochs_run``). Per (dataset, method): mean and sample sd (n - 1) over its seeds
(:func:`.collect.aggregate_cells`). Missing runs are logged and left out; a malformed file raises
:class:`~.collect.ReportInputError` naming it, like every other report input.

Δm is reported only for a method above the trivial-predictor floor on every task (:mod:`.gate`:
the 95% interval of its margin above 0 from its runs' per-frame scores, at least three seeds);
otherwise its Δm cell says ``below floor`` (a difference between networks that learned nothing
from their inputs measures nothing). A single-task arm is checked on its own task.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.ticker import MaxNLocator  # noqa: E402

from ..core import catalog, io  # noqa: E402
from ..core.layout import RunPaths, study_paths  # noqa: E402
from .collect import (Cell, aggregate_cells, list_runs, run_frames,  # noqa: E402
                      read_metrics, read_summary, with_derived)
from .figures import mean_curve, read_weight_curves, save_figure  # noqa: E402
from .gate import DatasetFloor, Gate, Margin, dataset_floor  # noqa: E402
from .schema import DATASET_LABEL, METRIC_TASK  # noqa: E402
from .tables.formats import csv_text, fmt_seeds, md_table  # noqa: E402

log = logging.getLogger(__name__)

__all__ = [
    "paper_forms", "StudySpec", "StudyMethod", "SeedResult", "StudyRow", "StudyOutputs", "delta_m",
    "study_methods", "collect_seed_results", "reference_means", "build_rows", "weighting_csv",
    "weighting_markdown", "plot_study_weights", "write_study_report", "study_run_dirs",
]

#: The scores of a run: Table II's columns (the task metrics, TM, MV; eq. 6-7).
RUN_SCORES: tuple[str, ...] = catalog.table2_columns()
#: Every score column of a row, in table order.
STUDY_SCORES: tuple[str, ...] = RUN_SCORES + ("dm", "sec_per_epoch")
#: Column headers: the label and which way is better; MV (the balance of the tasks) has no arrow.
SCORE_MD: dict[str, str] = {
    **{k: f"{catalog.column_label(k)} {'↓' if catalog.lower_is_better(k) else '↑'}" for k in RUN_SCORES},
    "mv": catalog.column_label("mv"), "dm": "Δm (%) ↑", "sec_per_epoch": "s / epoch",
}
DECIMALS: dict[str, int] = {"dm": 1, "sec_per_epoch": 2}
NO_SD = "—"
NOT_AVAILABLE = "n/a"
BELOW_FLOOR = "below floor"
MD_NAME, CSV_NAME = "weighting.md", "weighting.csv"


# ----------------------------------------------------------------------------- what the study is
@dataclass(frozen=True)
class StudySpec:
    """What the report needs of params.yaml: ``datasets`` (``study.datasets`` at ``scale``), the
    training ``seeds`` per dataset (the base model's: ``Params.seeds_of``), the arms in
    ``study.arm_ids`` order with their weighting id, the task of each single-task arm and the
    paper's forms (:func:`paper_forms`: model id -> the weighting of its recipe)."""

    datasets: tuple[str, ...]
    seeds: Mapping[str, tuple[int, ...]]
    arm_ids: tuple[str, ...]
    arm_weighting: Mapping[str, str]
    single_task: Mapping[str, str] = field(default_factory=dict)
    paper: Mapping[str, str] = field(default_factory=dict)

    @classmethod
    def from_params(cls, params: Any) -> "StudySpec":
        """From validated (possibly audited) params: ``scale``, the base model's seeds on each study
        dataset, ``study.datasets``, ``study.arm_ids``, ``study.arms``."""
        if isinstance(params, StudySpec):
            return params
        study = params.study
        arms = study.arms
        arm_ids = tuple(str(a) for a in study.arm_ids)
        weighting = {a: str(arms[a]["weighting"]) for a in arm_ids}
        single = {a: str(arms[a]["single"]["task"]) for a in arm_ids if weighting[a] == "single"}
        datasets = tuple(params.study_datasets)
        group = catalog.MODELS[study.base_model].group
        seeds = {ds: tuple(int(k) for k in params.seeds_of(group, ds)) for ds in datasets}
        return cls(datasets, seeds, arm_ids, weighting, single, paper_forms(params))


@dataclass(frozen=True)
class StudyMethod:
    """One row of the study per dataset: a paper form (``kind`` ``paper``, ``id`` the model id) or
    a study arm (``study``; ``single`` for a single-task arm, ``task`` its task)."""

    id: str
    label: str
    kind: str
    weighting: str
    task: Optional[str] = None

    @property
    def adaptive(self) -> bool:
        """Its weights change during training (a panel in the loss-weight figure)."""
        return catalog.weighting_info(self.weighting).adaptive


def paper_forms(params: Any) -> dict[str, str]:
    """The paper's weighting forms, whose main runs the study shows: model id -> the weighting of
    its recipe (``train.models.<id>.weighting``), for every compact model (catalog order) with the
    LiDAR input of ``study.base_model``."""
    base = catalog.MODELS[params.study.base_model]
    return {m: str(params.train.models[m].weighting) for m in catalog.compact_model_ids()
            if catalog.MODELS[m].lidar_channels == base.lidar_channels}


def study_methods(spec: StudySpec) -> list[StudyMethod]:
    """The paper forms (:attr:`StudySpec.paper`), then every arm in ``study.arm_ids`` order."""
    out = [StudyMethod(m, catalog.model_label(m) + (" (equal static weights)" if w == "static" else ""), "paper", w)
           for m, w in spec.paper.items()]
    for arm in spec.arm_ids:
        w = spec.arm_weighting[arm]
        if w == "single":
            task = spec.single_task[arm]
            out.append(StudyMethod(arm, f"Single-task ({catalog.TASKS[task].label})", "single", w, task))
        else:
            out.append(StudyMethod(arm, catalog.weighting_info(w).label, "study", w))
    return out


# ----------------------------------------------------------------------------- Δm
def delta_m(scores: Mapping[str, float], reference: Mapping[str, float],
            metrics: Sequence[str] = catalog.metric_keys()) -> float:
    """Δm as LibMTL defines it (Lin & Zhang), in percent, positive = better than the reference:
    ``(1/K) sum_k (-1)^{d_k} (M_m,k - M_b,k) / M_b,k * 100`` over the K ``metrics``, ``d_k = 1``
    when lower is better (``catalog.higher_is_better``). NaN when a metric or its reference is
    missing, not finite, or the reference is 0."""
    if not metrics:
        return math.nan
    total = 0.0
    for k in metrics:
        m, b = scores.get(k), reference.get(k)
        if m is None or b is None or not math.isfinite(m) or not math.isfinite(b) or b == 0:
            return math.nan
        sign = 1.0 if catalog.higher_is_better(k) else -1.0
        total += sign * (m - b) / b
    return 100.0 * total / len(metrics)


# ----------------------------------------------------------------------------- collecting
@dataclass(frozen=True)
class SeedResult:
    """One run of a method: ``scores`` holds the task metrics, ``tm``, ``mv`` (what the run has),
    ``sec_per_epoch`` is ``None`` without a usable ``summary.json``."""

    dataset: str
    method: str
    seed: Optional[int]
    scores: Mapping[str, float]
    sec_per_epoch: Optional[float]
    run_dir: Path
    eval_dir: Optional[Path] = None


def _method_runs(root: Path, ds: str, method: StudyMethod, seeds: Sequence[int]) -> list[RunPaths]:
    """The paths (:class:`~compact_perception.core.layout.RunPaths`) of every run of ``method`` on
    ``ds`` with any output."""
    if method.kind == "paper":
        return list_runs(root, ds, method.id, seeds)
    paths = [study_paths(method.id, k, ds, root) for k in seeds]
    return [p for p in paths if p.run_dir.is_dir() or p.metrics_path.is_file()]


def study_run_dirs(root: Path, params: Any) -> list[tuple[str, Path]]:
    """(``study/<arm>/seed<k>/<ds>``, run folder) of every study run present, in ``study.arm_ids``,
    seed, dataset order (the plots' CSV rows)."""
    spec = StudySpec.from_params(params)
    out = []
    for arm in spec.arm_ids:
        for ds in spec.datasets:
            for k in spec.seeds[ds]:
                p = study_paths(arm, k, ds, root)
                if p.run_dir.is_dir():
                    out.append((f"study/{arm}/seed{k}/{ds}", p.run_dir))
    return out


def _sec_per_epoch(run_dir: Path) -> Optional[float]:
    summ = read_summary(run_dir) or {}
    secs, epochs = summ.get("train_seconds"), summ.get("epochs_run")
    if isinstance(secs, (int, float)) and isinstance(epochs, int) and epochs > 0:
        return float(secs) / epochs
    return None


def collect_seed_results(root: Path, spec: StudySpec, methods: Optional[Sequence[StudyMethod]] = None
                         ) -> dict[str, dict[str, list[SeedResult]]]:
    """dataset -> method id -> its runs with a ``metrics.json`` (seed order); runs without one
    and methods without any run are logged and left out."""
    root = Path(root)
    methods = list(methods) if methods is not None else study_methods(spec)
    out: dict[str, dict[str, list[SeedResult]]] = {}
    for ds in spec.datasets:
        out[ds] = {}
        for m in methods:
            found, missing = [], []
            for p in _method_runs(root, ds, m, spec.seeds[ds]):
                if not p.metrics_path.is_file():
                    missing.append(p.seed)
                    continue
                res = with_derived(read_metrics(p.metrics_path, ds, m.id), f"{ds}/{m.id}/seed{p.seed}")
                scores = {k: c.mean for k, c in res.scores.items() if k in STUDY_SCORES}
                found.append(SeedResult(ds, m.id, p.seed, scores, _sec_per_epoch(p.run_dir), p.run_dir, p.eval_dir))
            absent = [k for k in spec.seeds[ds] if k not in {r.seed for r in found} and k not in missing]
            if missing or (found and absent):
                log.warning("study %s/%s: no metrics for seed(s) %s; left out", ds, m.id, sorted(missing + absent))
            if found:
                out[ds][m.id] = found
            else:
                log.warning("study %s/%s: no runs with metrics (seeds %s); row left out", ds, m.id,
                            list(spec.seeds[ds]))
    return out


def reference_means(results: Mapping[str, Sequence[SeedResult]], methods: Sequence[StudyMethod]
                    ) -> tuple[dict[str, float], dict[str, str]]:
    """Δm's reference of one dataset: metric -> the single-task arm's own-task metric, mean over
    its seeds; and metric -> a note for each task metric without one."""
    ref: dict[str, float] = {}
    notes: dict[str, str] = {}
    for t in catalog.task_ids():
        metric = catalog.metric_of(t)
        arms = [m for m in methods if m.kind == "single" and m.task == t]
        vals = [r.scores[metric] for m in arms for r in results.get(m.id, ()) if metric in r.scores]
        if vals:
            ref[metric] = float(sum(vals) / len(vals))
        else:
            which = ", ".join(m.id for m in arms) or f"no single-task arm for {t} in study.arms"
            notes[metric] = f"no single-task reference for {catalog.TASKS[t].metric_label} ({which}: no runs)"
    return ref, notes


#: (dataset, method id) -> the margins over the floor on which the method does not pass the gate.
Failing = Mapping[tuple[str, str], Sequence[Margin]]


def gate_methods(results: Mapping[str, Mapping[str, Sequence[SeedResult]]], methods: Sequence[StudyMethod],
                 floors: Mapping[str, DatasetFloor]) -> dict[tuple[str, str], list[Margin]]:
    """Per (dataset, method with runs): the task metrics on which it is not above the floor
    (:mod:`.gate`; a single-task arm: its own task only; no floor or no per-frame scores: fails)."""
    out: dict[tuple[str, str], list[Margin]] = {}
    for ds, per_method in results.items():
        gate = Gate(floors.get(ds))
        for m in methods:
            runs = per_method.get(m.id)
            if runs:
                frames = run_frames(runs)
                metrics = [catalog.metric_of(m.task)] if m.kind == "single" and m.task else catalog.metric_keys()
                out[(ds, m.id)] = [g for g in (gate.margin_of(frames, c) for c in metrics) if not g.above]
    return out


@dataclass
class StudyRow:
    """One (dataset, method): every score of :data:`STUDY_SCORES` as a :class:`~.collect.Cell` over
    its seeds (absent when no run has it; Δm absent for a single-task arm and for a method not
    above the floor); ``below``: the margins on which it is not above the floor."""

    dataset: str
    method: StudyMethod
    seeds: tuple[Optional[int], ...]
    cells: dict[str, Cell]
    below: tuple[Margin, ...] = ()

    @property
    def n_seeds(self) -> int:
        return len(self.seeds)

    @property
    def above_floor(self) -> str:
        """``yes``, or ``no: LS (below), SS (not shown above: 2 seeds), ...``."""
        if not self.below:
            return "yes"
        return "no: " + ", ".join(f"{METRIC_TASK.get(g.metric, g.metric)} ({g.reason()})" for g in self.below)


def build_rows(results: Mapping[str, Mapping[str, Sequence[SeedResult]]], methods: Sequence[StudyMethod],
               references: Mapping[str, Mapping[str, float]], failing: Optional[Failing] = None) -> list[StudyRow]:
    """Rows per dataset in ``methods`` order (methods without runs left out); Δm per seed
    against ``references[ds]`` (:func:`delta_m`; NaN without a full reference), then over seeds,
    only for a method that passes the gate (``failing``: :func:`gate_methods`; ``None``: no gate)."""
    rows = []
    for ds, per_method in results.items():
        ref = references.get(ds, {})
        for m in methods:
            runs = per_method.get(m.id)
            if not runs:
                continue
            below = tuple((failing or {}).get((ds, m.id), ()))
            values: dict[str, list[float]] = {}
            for r in runs:
                for k in RUN_SCORES:
                    if k in r.scores:
                        values.setdefault(k, []).append(r.scores[k])
                if m.kind != "single" and not below:
                    values.setdefault("dm", []).append(delta_m(r.scores, ref))
                if r.sec_per_epoch is not None:
                    values.setdefault("sec_per_epoch", []).append(r.sec_per_epoch)
            cells = {k: aggregate_cells([Cell(v) for v in vals]) for k, vals in values.items()}
            rows.append(StudyRow(ds, m, tuple(r.seed for r in runs), cells, below))
    return rows


# ----------------------------------------------------------------------------- tables
def _csv_value(cell: Optional[Cell], std: bool) -> float:
    if cell is None:
        return math.nan
    v = cell.std if std else cell.mean
    return math.nan if v is None else float(v)


def weighting_csv(rows: Sequence[StudyRow]) -> str:
    """``weighting.csv``: one line per (dataset, method); empty cells = not available (sd: one seed;
    Δm: a reference, or a method below the floor); ``above_floor``: the gate (:attr:`StudyRow.above_floor`)."""
    records = []
    for r in rows:
        rec: dict[str, Any] = {"dataset": r.dataset, "method": r.method.id, "label": r.method.label,
                               "n_seeds": r.n_seeds}
        for k in STUDY_SCORES:
            rec[f"{k}_mean"] = _csv_value(r.cells.get(k), False)
            rec[f"{k}_sd"] = _csv_value(r.cells.get(k), True)
        rec["above_floor"] = r.above_floor
        records.append(rec)
    columns = (["dataset", "method", "label", "n_seeds"] + [f"{k}_{s}" for k in STUDY_SCORES for s in ("mean", "sd")]
               + ["above_floor"])
    return csv_text(columns, [[rec[c] for c in columns] for rec in records], float_format="%.10g")


def _fmt(cell: Optional[Cell], key: str) -> str:
    if cell is None or not math.isfinite(cell.mean):
        return NOT_AVAILABLE
    d = DECIMALS.get(key, 3)
    finite_sd = cell.std is not None and math.isfinite(cell.std)
    shown = replace(cell, mean=round(cell.mean, d) + 0.0, std=cell.std if finite_sd else None)  # + 0.0: no "-0.0"
    return fmt_seeds(shown, decimals=d, no_sd=NO_SD if cell.std is None else NOT_AVAILABLE)


def _cell(r: StudyRow, key: str) -> str:
    """A score cell; Δm: ``—`` for a reference, ``below floor`` for a method not above the floor."""
    if key == "dm" and r.method.kind == "single":
        return NO_SD
    if key == "dm" and r.below:
        return BELOW_FLOOR
    return _fmt(r.cells.get(key), key)


def weighting_markdown(rows: Sequence[StudyRow], spec: StudySpec, references: Mapping[str, Mapping[str, float]],
                       notes: Mapping[str, Sequence[str]], dataset_label: Mapping[str, str]) -> str:
    """``weighting.md``: a header explaining Δm, its reference and the seeds; one table per dataset."""
    seeds = "; ".join(f"{dataset_label.get(ds, ds)}: {', '.join(str(k) for k in spec.seeds[ds])}"
                      for ds in spec.datasets)
    out = ["# Loss-balancing study (beyond the paper)", "",
           "The compact 15L network trained with each loss-weighting method, everything else equal (the "
           "`compact_15l` recipe with its weighting replaced, params.yaml `study`). The paper's own forms are the "
           "main runs: 15L (equal static weights), 15L+MGN (Alg. 1) and 15L+MGN (authors' code).", "",
           "- **Δm** (LibMTL's definition): the mean over the K = 4 task metrics of the relative change against the "
           "single-task reference, signed so that positive = better: Δm = (1/K) Σ_k (−1)^d_k (M_m,k − M_b,k) / "
           "M_b,k × 100, d_k = 1 for MAE_DE (lower is better), 0 for the IoUs.",
           "- **Reference** M_b,k: the single-task network of task k (the 15L layout built for that task alone: "
           "encoders, bottleneck 1 and the task's decoder; for BEVP the whole network, its DE/SS/LS decoders "
           "without a loss; arm `single_<task>`), its own task's metric, mean over its seeds on the same dataset. "
           "The single-task rows are the references (Δm —).",
           f"- **Seeds**: every cell is the mean ± sample sd (n − 1) over the training seeds (params.yaml `datasets.<ds>.training.seeds`: "
           f"{seeds}); {NO_SD} for the sd of one seed. Δm is computed per seed, then averaged. TM (eq. 6) and MV "
           "(eq. 7) are of each run's four test-set means.",
           "- **s / epoch**: `train_seconds / epochs_run` of each run's `summary.json`, mean ± sd over seeds "
           "(wall-clock on the machine that trained it).",
           "- No value is marked best: with this few seeds, differences within ±2 sd are not separated.",
           f"- **Floor**: Δm is reported only for a method above the trivial-predictor floor on every task (the 95% "
           f"interval of its margin over the floor above 0, with at least 3 seeds: Table II's rule); the others show "
           f"`{BELOW_FLOOR}`, and the line under the table names the tasks. A single-task reference is checked on "
           "its own task.", ""]
    cols = list(STUDY_SCORES)
    for ds in spec.datasets:
        label = dataset_label.get(ds, ds)
        out += [f"## {label}", ""]
        ref = references.get(ds, {})
        if ref:
            out += ["Reference (single-task, own task, mean over seeds): " + ", ".join(
                f"{SCORE_MD[k].split()[0]} {v:.3f}" for k, v in ref.items()) + ".", ""]
        ds_rows = [r for r in rows if r.dataset == ds]
        if not ds_rows:
            out += ["No runs on this dataset yet.", ""]
        else:
            table = md_table(["Method", "Seeds", *(SCORE_MD[k] for k in cols)],
                             [[r.method.label, str(r.n_seeds), *(_cell(r, k) for k in cols)] for r in ds_rows])
            out += table.split("\n")
            gated = [f"{r.method.label} ({r.above_floor[4:]})" for r in ds_rows if r.below]
            if gated:
                out += ["Not above the floor on every task (Δm not reported): " + "; ".join(gated) + ".", ""]
        out += [f"- {n}" for n in notes.get(ds, ())]
        if notes.get(ds):
            out.append("")
    return "\n".join(out).rstrip() + "\n"


# ----------------------------------------------------------------------------- figure
def plot_study_weights(panels: Mapping[str, Sequence[Path]], out_png: Path, title: str = "") -> Optional[Path]:
    """Loss weights per epoch, one small panel per method (``panels``: label -> run folders of its
    seeds, in order; the first is the reference drawn dotted in every other panel): per task the
    mean over seeds (thick) and each seed (thin). Methods without weight logs are skipped (logged);
    ``None`` if none has any."""
    data: dict[str, list[dict[str, pd.Series]]] = {}
    for name, dirs in panels.items():
        curves = [c for c in (read_weight_curves(Path(d)) for d in dirs) if c]
        if curves:
            data[name] = curves
        else:
            log.info("loss-weight figure %s: %s logged no weights; panel skipped", Path(out_png).name, name)
    if not data:
        log.warning("no loss-weight logs for %s; skipping %s", list(panels), out_png)
        return None
    tasks = list(catalog.task_ids())
    for curves in data.values():
        tasks += [t for c in curves for t in c if t not in tasks]
    colour = {t: f"C{i % 10}" for i, t in enumerate(tasks)}
    means = {name: {t: mean_curve([c[t] for c in curves if t in c]) for t in tasks if any(t in c for c in curves)}
             for name, curves in data.items()}
    ref_name = next(iter(data))
    n = len(data)
    ncols = min(4, n)
    nrows = -(-n // ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(3.4 * ncols, 2.7 * nrows), squeeze=False)
    for ax, (name, curves) in zip(axes.flat, data.items()):
        for t, m in means[name].items():
            if len(curves) > 1:
                for c in curves:
                    if t in c:
                        ax.plot(c[t].index, c[t].values, color=colour[t], linewidth=0.6, alpha=0.35)
            ax.plot(m.index, m.values, color=colour[t], linewidth=1.8)
        if name != ref_name:
            for t, m in means[ref_name].items():
                ax.plot(m.index, m.values, color=colour[t], linewidth=1.0, linestyle=":", alpha=0.8)
        ax.set_title(f"{name} ({len(curves)} seed{'s' if len(curves) > 1 else ''})", fontsize=8)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.tick_params(labelsize=7)
        ax.set_xlabel("epoch", fontsize=8)
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[n:]:
        ax.set_visible(False)
    for ax in axes[:, 0]:
        ax.set_ylabel("loss weight", fontsize=8)
    handles = [Line2D([], [], color=colour[t], linewidth=1.8,
                      label=catalog.TASKS[t].label if t in catalog.TASKS else t.upper()) for t in tasks
               if any(t in means[k] for k in means)]
    handles += [Line2D([], [], color="grey", linewidth=0.6, alpha=0.6, label="each seed"),
                Line2D([], [], color="grey", linewidth=1.0, linestyle=":", label=f"{ref_name}, mean")]
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=8, frameon=False,
               bbox_to_anchor=(0.5, -0.02))
    fig.suptitle(title or "Loss weights per epoch (mean over seeds)", fontsize=10)
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    return save_figure(fig, out_png)


# ----------------------------------------------------------------------------- entry
@dataclass(frozen=True)
class StudyOutputs:
    """What :func:`write_study_report` wrote: the tables, the figure per dataset (datasets without
    any weight log have none), the Markdown text, and the rows."""

    markdown: Path
    csv: Path
    figures: dict[str, Path]
    markdown_text: str
    rows: list[StudyRow]

    @property
    def paths(self) -> list[Path]:
        return [self.markdown, self.csv, *self.figures.values()]


def write_study_report(root: Path, params: Any, out_tables: Path, out_figures: Path,
                       floors: Optional[Mapping[str, DatasetFloor]] = None) -> StudyOutputs:
    """Write ``<out_tables>/weighting.{md,csv}`` and ``<out_figures>/loss_weights_study_<ds>.png``
    from the study's and the paper forms' runs under ``root``. ``params``: validated params (or a
    :class:`StudySpec`); ``floors``: each dataset's trivial predictors (read under ``root`` where
    not given). Missing runs are logged and left out, never an error."""
    spec = StudySpec.from_params(params)
    methods = study_methods(spec)
    results = collect_seed_results(Path(root), spec, methods)
    floors = dict(floors or {})
    for ds in spec.datasets:
        if ds not in floors:
            floors[ds] = dataset_floor(Path(root), ds)
    references: dict[str, dict[str, float]] = {}
    notes: dict[str, list[str]] = {}
    for ds in spec.datasets:
        ref, ref_notes = reference_means(results.get(ds, {}), methods)
        references[ds] = ref
        notes[ds] = []
        if ref_notes and any(m.kind != "single" for m in methods if m.id in results.get(ds, {})):
            notes[ds].append("Δm n/a: " + "; ".join(ref_notes.values()) + ".")
            log.warning("study %s: %s; Δm n/a", ds, "; ".join(ref_notes.values()))
        absent = [m.label for m in methods if m.id not in results.get(ds, {})]
        if absent:
            notes[ds].append("No runs yet: " + ", ".join(absent) + ".")
    rows = build_rows(results, methods, references, gate_methods(results, methods, floors))
    text = weighting_markdown(rows, spec, references, notes, DATASET_LABEL)
    md_path, csv_path = Path(out_tables) / MD_NAME, Path(out_tables) / CSV_NAME
    io.write_text(md_path, text)
    io.write_text(csv_path, weighting_csv(rows))
    figures: dict[str, Path] = {}
    for ds in spec.datasets:
        panels = {m.label: [r.run_dir for r in results[ds][m.id] if r.run_dir.is_dir()]
                  for m in methods if m.adaptive and m.id in results.get(ds, {})}
        panels = {k: v for k, v in panels.items() if v}
        if not panels:
            log.warning("study %s: no adaptive method has runs; no loss-weight figure", ds)
            continue
        p = plot_study_weights(panels, Path(out_figures) / f"loss_weights_study_{ds}.png",
                               f"{DATASET_LABEL.get(ds, ds)}: loss weights per epoch of every adaptive method "
                               "(thick: mean over seeds)")
        if p is not None:
            figures[ds] = p
    log.info("study report: %d rows, %d figure(s)", len(rows), len(figures))
    return StudyOutputs(md_path, csv_path, figures, text, rows)
