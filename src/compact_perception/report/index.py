"""Build everything under ``reports/`` and ``reports/index.md`` (SPEC 8).

:func:`build_reports` reads the pipeline outputs of every run of the seeds of params.yaml (see
:mod:`.collect`; ``seeds`` for the compact models, ``baseline_seeds`` for the baselines), writes

    reports/index.md
    reports/metrics.json                        (the headline numbers, :func:`headline_metrics`)
    reports/tables/{table2,table3,paper_vs_reproduced}.{md,tex,csv}
    reports/tables/claims.{md,csv}              (the claims scorecard, :mod:`.claims`)
    reports/tables/extra_metrics.{md,csv}, extra_metrics_per_class.csv   (metrics beyond the paper's)
    reports/tables/weighting.{md,csv}           (the loss-balancing study, :mod:`.study`; with ``study``)
    reports/figures/report/loss_weights_<ds>.png, curves_<ds>.png, qualitative_<ds>.png
    reports/figures/report/loss_weights_study_<ds>.png   (every study method's loss weights)
    reports/plots/val_tm.csv, loss_weights.csv  (every run's curves for ``dvc plots``, :mod:`.plots`)

into a staging directory and moves each into place only once everything is built: a failed
report leaves the previous files untouched. Other stages own the rest of ``reports/figures/``
(the world's Fig. 1-like figures and the LiDAR preprocessing figures); the index links them.

The steps, each its own function: :func:`read_inputs` (every input, read once),
:func:`write_tables` (each table built once, its Markdown kept for the index), the plots' CSV
files, the study's report, :func:`headline_metrics`, :func:`write_figures`, then
:func:`index_markdown` from the :class:`ReportParts` they return.
"""
from __future__ import annotations

import logging
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Sequence

from ..core import io
from ..core.catalog import MODELS, STOP_PLATEAU, compact_model_ids, dataset_ids, metric_of, model_ids
from ..core.io import read_json
from ..core.layout import RunPaths
from .claims import build_claims, claims_files, coverage_text, exact_counts, verdict_counts
from .collect import (DatasetScale, ModelResult, SeedSpec, collect_scale, list_runs, load_npz, load_results,
                      load_row_frames, seeds_for)
from .gate import BELOW, Gate, dataset_gate
from .figures import plot_loss_weights, plot_qualitative, plot_training_curves
from .paper import PaperNumbers, load_paper_numbers
from .plateau import PlateauEvidence, recorded_sentence
from .plots import write_plot_data
from .schema import DATASET_LABEL, FLOOR_LABEL, METRIC_TASK, MGN_FORMS, ROW_LABEL, ROW_ORDER
from .selection import selected_efficiency
from .study import StudyOutputs, study_run_dirs, write_study_report
from .tables.comparison import SPLITS, comparison_files, scale_lines
from .tables.extra import build_extra_rows, extra_files
from .tables.formats import md_table, write_files
from .tables.table2 import RowFrames, build_table2, table2_files
from .tables.table3 import build_table3, table3_files

log = logging.getLogger(__name__)

#: The model of the headline TM in ``reports/metrics.json``: the paper's proposed model (15L+MGN)
#: in the form that produced the paper's Table II, the authors' public code.
HEADLINE_MODEL = "compact_15l_mgn_authors"
HEADLINE_KEY = "tm_mgn_authors"
HEADLINE_DECIMALS = 4
#: The dataset whose compact models' TM margins over the floor the headline gives (the first:
#: set A, where issue 23's acceptance asks every compact variant to be above the floor).
MARGIN_DATASET = dataset_ids()[0]
MARGIN_KEY = f"tm_margin_{MARGIN_DATASET}"
#: At most this many numbers (flattened keys) in ``reports/metrics.json``: `dvc exp show` fits a terminal.
HEADLINE_MAX_KEYS = 20
#: Figures of the index per dataset: key -> title (``world`` and ``lidar`` come from other stages).
FIGURE_TITLES: dict[str, str] = {
    "world": "One frame of the simulated world, all sensors and ground truths (Fig. 1)",
    "lidar": "LiDAR preprocessing: 14 height layers and the flattened layer (Fig. 5)",
    "loss_weights": "Loss weights of 15L+MGN per epoch, both MGN forms, mean over seeds (Fig. 8)",
    "curves": "Validation TM per epoch, mean over seeds",
    "qualitative": "Qualitative results, one test frame, each model's first seed (Fig. 6/7)",
}
#: The figures other stages write under ``reports/figures/`` (key -> file name of dataset ``ds``).
STAGE_FIGURES: dict[str, str] = {"world": "world_{ds}.png", "lidar": "lidar_preprocessing_{ds}.png"}


# ----------------------------------------------------------------------------- what the report is made of
@dataclass
class ReportInputs:
    """Every input of the report, read once (:func:`read_inputs`)."""

    root: Path
    datasets: list[str]
    models: list[str]
    seeds: SeedSpec
    paper: PaperNumbers
    results: dict[str, dict[str, ModelResult]]       # dataset -> model -> its runs over the seeds
    frames: dict[str, RowFrames]                     # dataset -> row id -> per-frame scores per run
    efficiency: Optional[dict[str, Any]]             # results/benchmark/efficiency.json (None: not run)
    scales: dict[str, DatasetScale]
    gates: dict[str, Gate] = field(default_factory=dict)   # dataset -> its floor and the rows' margins


@dataclass
class ReportParts:
    """The parts of ``reports/index.md`` (:func:`index_markdown`): what the tables, the study and
    the figures wrote, as Markdown and paths relative to the index. ``table3_md`` is ``None``
    without a benchmark; ``claims_md``, ``extra_md``, ``headline`` and ``study`` are left out
    where ``None``."""

    scale_name: str
    results: dict[str, dict[str, ModelResult]]
    scales: dict[str, DatasetScale]
    scale_text: list[str]
    table2_md: str
    table3_md: Optional[str] = None
    efficiency: Optional[dict[str, Any]] = None
    claims_md: Optional[str] = None
    extra_md: Optional[str] = None
    headline: Optional[dict[str, Any]] = None
    gates: dict[str, Gate] = field(default_factory=dict)
    study: Optional[StudyOutputs] = None
    study_figures: dict[str, str] = field(default_factory=dict)
    figures: dict[str, dict[str, str]] = field(default_factory=dict)
    plateau: Optional[PlateauEvidence] = None
    plateau_link: str = ""


def read_inputs(root: Path, datasets: Sequence[str], models: Sequence[str], seeds: SeedSpec,
                paper: PaperNumbers) -> ReportInputs:
    """Every run's metrics and per-frame scores of the seeds ``seeds``, the benchmark's file,
    each dataset's scale and trivial predictors (:mod:`.collect`), and its gate (:mod:`.gate`)."""
    root = Path(root)
    results = load_results(root, list(datasets), list(models), seeds)
    eff_path = root / "results" / "benchmark" / "efficiency.json"
    efficiency = selected_efficiency(read_json(eff_path), datasets, models) if eff_path.is_file() else None
    if efficiency is None:
        log.warning("%s missing: Table III skipped", eff_path)
    frames = {ds: load_row_frames(root, ds, list(models), seeds) for ds in datasets}
    gates = {ds: dataset_gate(root, ds, frames[ds]) for ds in datasets}
    return ReportInputs(root, list(datasets), list(models), seeds, paper, results, frames, efficiency,
                        collect_scale(root, list(datasets), list(models), results, seeds), gates)


def _flat_keys(obj: Any) -> int:
    """The number of leaves of a nested dict (the columns `dvc exp show` gives it)."""
    return sum(_flat_keys(v) for v in obj.values()) if isinstance(obj, dict) else 1


def headline_metrics(results: dict[str, dict[str, ModelResult]], claim_rows: Sequence[Any],
                     gates: Optional[dict[str, Gate]] = None) -> dict[str, Any]:
    """``reports/metrics.json`` (at most :data:`HEADLINE_MAX_KEYS` numbers): ``claims``, the verdict
    counts of the claims judged on test scores (reproduced, contradicted, inconclusive: the rows
    the run can decide; and not_decidable); ``exact_counts``, Table III's apart; ``tm_margin_<A>``,
    the TM margin over the floor (positive = better) of every compact model of
    :data:`MARGIN_DATASET`, mean over its seeds; TM of :data:`HEADLINE_MODEL` per dataset (mean
    over its seeds); 4 decimals; datasets and models without results left out."""
    tm = {}
    for ds, res in results.items():
        r = res.get(HEADLINE_MODEL)
        cell = r.scores.get("tm") if r is not None else None
        if cell is not None:
            tm[ds] = round(float(cell.mean), HEADLINE_DECIMALS)
    out: dict[str, Any] = {"claims": verdict_counts(claim_rows), "exact_counts": exact_counts(claim_rows)}
    gate = (gates or {}).get(MARGIN_DATASET)
    margins = {m: gate.margin(m, "tm").estimate for m in compact_model_ids()} if gate is not None else {}
    margins = {m: round(v, HEADLINE_DECIMALS) for m, v in margins.items() if v is not None}
    if margins:
        out[MARGIN_KEY] = margins
    out[HEADLINE_KEY] = tm
    if _flat_keys(out) > HEADLINE_MAX_KEYS:
        raise ValueError(f"reports/metrics.json: {_flat_keys(out)} numbers, expected at most {HEADLINE_MAX_KEYS}")
    return out


# ----------------------------------------------------------------------------- index.md
def _sources_section(parts: ReportParts) -> list[str]:
    """Per dataset: data source, frames, test frames, resolution, DVS and the models with results;
    then this run's scale beside the paper's."""
    rows = []
    for ds, sc in parts.scales.items():
        counts = "/".join(str(sc.counts.get(k, "?")) for k in SPLITS) if sc.counts else "?"
        mods = ", ".join(ROW_LABEL.get(m, m) for m in parts.results.get(ds, {})) or "none"
        dvs = "?" if sc.has_dvs is None else ("yes" if sc.has_dvs else "no")
        n_test = "/".join(map(str, sc.n_test_frames)) or "?"
        rows.append([DATASET_LABEL.get(ds, ds), f"{sc.source or 'unknown'}", counts, n_test,
                     f"{sc.resolution or '?'}", dvs, mods])
    table = md_table(["Dataset", "Data source", "Frames train/val/test", "Test frames per run", "Resolution", "DVS",
                      "Models with results"], rows)
    return ["## Data sources and scale", ""] + table.split("\n") + [f"- {s}" for s in parts.scale_text] + [""]


def _seeds_overview(results: dict[str, dict[str, ModelResult]], scales: dict[str, DatasetScale]) -> list[str]:
    """Lines stating the seeds of every model and the test frames of every dataset."""
    per_model: dict[str, set] = {}
    for res in results.values():
        for m, r in res.items():
            per_model.setdefault(m, set()).add(tuple(r.seeds))
    out = ["## Seeds and test frames", ""]
    if per_model:
        out += ["Every (dataset, model) is trained once per training seed (params.yaml `seeds` for the compact models, "
                "`baseline_seeds` for the baselines; seed folders of other seeds are ignored). Every metric in the "
                "tables is the mean ± sample sd over those seeds; the paper's per-frame variance is kept beside it.", ""]
        rows = [[ROW_LABEL.get(m, m), "; ".join(sorted({", ".join("?" if k is None else str(k) for k in ks)
                                                         + f" ({len(ks)})" for ks in per_model[m]}))]
                for m in [m for m in ROW_ORDER if m in per_model] + [m for m in per_model if m not in ROW_ORDER]]
        out += md_table(["Model", "Seeds (runs)"], rows).split("\n")
    frames = [f"{DATASET_LABEL.get(ds, ds)} {'/'.join(map(str, sc.n_test_frames)) or '?'}"
              for ds, sc in scales.items()]
    out += [f"Test frames scored per run: {', '.join(frames)}.", ""]
    return out


def _counts(counts: dict[str, int]) -> str:
    return ", ".join(f"{v} {k.replace('_', ' ')}" for k, v in counts.items())


def _headline_section(parts: ReportParts) -> list[str]:
    """The headline numbers of ``metrics.json`` in words, with the TM margins' intervals."""
    head = parts.headline
    if head is None:
        return []
    tm = head.get(HEADLINE_KEY) or {}
    counts = dict(head.get("claims") or {})
    undecided = counts.pop("not_decidable", 0)
    out = ["## Headline", "",
           f"[`metrics.json`](metrics.json) (the pipeline's one DVC metrics file, `dvc metrics show` / "
           f"`dvc exp show`). `claims`: the claims judged on test scores that this run can decide (every model "
           f"compared above the trivial-predictor floor on the claim's metrics, at least 3 seeds a side): "
           f"{_counts(counts) or 'none'}; {undecided} not decidable (the scorecard's notes say why). "
           f"`exact_counts`: Table III's parameter, size, memory and FPS rows, apart: "
           f"{_counts(head.get('exact_counts') or {}) or 'none'}.", ""]
    gate = parts.gates.get(MARGIN_DATASET)
    if MARGIN_KEY in head and gate is not None:
        margins = [f"{ROW_LABEL.get(m, m)} {gate.margin(m, 'tm').text()}" for m in head[MARGIN_KEY]]
        out += [f"`{MARGIN_KEY}`: TM margin over the floor on {DATASET_LABEL.get(MARGIN_DATASET, MARGIN_DATASET)} "
                "(floor TM − TM, positive = better than the trivial predictor; mean over the seeds, 95% interval): "
                + "; ".join(margins) + ".", ""]
    out += [f"`{HEADLINE_KEY}`: TM of {ROW_LABEL.get(HEADLINE_MODEL, HEADLINE_MODEL)} (the paper's proposed model "
            "in the form that produced its Table II), mean over its seeds, per dataset: "
            + (", ".join(f"{DATASET_LABEL.get(d, d)} {v:.4f}" for d, v in tm.items()) or "none")
            + ". Every run's scores: `results/<ds>/<model>/seed<k>/metrics.json`.", ""]
    return out


def _floor_sentence(ds: str, gate: Gate, models: Sequence[str]) -> str:
    """One sentence: the floor's TM and which models are above it on every task they perform."""
    label = DATASET_LABEL.get(ds, ds)
    if not gate.has_floor:
        return f"{label}: no trivial-predictor results, no floor: no model is shown above it."
    floor = gate.floor
    src = floor.source("tm") if floor else None
    tm = f"floor TM {floor.value()['tm']:.3f} ({FLOOR_LABEL.get(src, src)})" if floor and src else "no floor TM"
    above, below = [], []
    for m in models:
        failing = gate.failing(m, [metric_of(t) for t in MODELS[m].tasks])
        if not failing:
            above.append(ROW_LABEL.get(m, m))
        else:
            below.append(f"{ROW_LABEL.get(m, m)} ({', '.join(f'{METRIC_TASK[x.metric]} {x.reason()}' for x in failing)})")
    return (f"{label} ({tm}): above the floor on every task it performs: {', '.join(above) or 'none'}"
            + (f"; not: {'; '.join(below)}" if below else "") + ".")


def _learning_status(facts: Sequence[dict[str, Any]], failing: Sequence[Any]) -> str:
    """How a model's runs on one dataset stopped and where that leaves them against the floor."""
    below = [x for x in failing if x.status == BELOW]
    if below:
        where = "below the floor on " + "/".join(METRIC_TASK[x.metric] for x in below)
    elif failing:
        where = ("better than the floor, not shown above it ("
                 + "; ".join(f"{METRIC_TASK[x.metric]} {x.reason()}" for x in failing) + ")")
    else:
        where = "above the floor"
    capped = [f for f in facts if f.get("stop_reason") != STOP_PLATEAU]
    if capped:
        epochs = sorted({int(f["epochs_run"]) for f in capped if f.get("epochs_run") is not None})
        n = "/".join(map(str, epochs)) or "?"
        return (f"stopped by its epoch cap after {n} epoch{'' if epochs == [1] else 's'}, not trained to a plateau, "
                f"{where}" + (": undecided whether it can learn" if below else ""))
    if below:
        return f"trained to a plateau and still {where}: it does not learn at these settings"
    return f"trained to a plateau and {where}" + ("" if failing else ": it learns")


def _learning_sentence(parts: ReportParts, baselines: Sequence[str]) -> Optional[str]:
    """Per baseline of ``baselines``: whether its runs were trained to a plateau (``summary.json``
    ``stop_reason``) and, so, whether its place against the floor says it learns at this scale's settings."""
    per_model = []
    for m in baselines:
        by_status: dict[str, list[str]] = {}
        for ds, gate in parts.gates.items():
            facts = parts.scales[ds].epochs.get(m) if ds in parts.scales else None
            if m not in parts.results.get(ds, {}) or not facts or not gate.has_floor:
                continue
            status = _learning_status(facts, gate.failing(m, [metric_of(t) for t in MODELS[m].tasks]))
            by_status.setdefault(status, []).append(DATASET_LABEL.get(ds, ds))
        if by_status:
            per_model.append(f"{ROW_LABEL.get(m, m)}: " + "; ".join(f"{', '.join(d)}: {s}" for s, d in by_status.items()))
    if not per_model:
        return None
    return ("Do the baselines learn at this scale? " + ". ".join(per_model) + ". A run stopped by its cap says "
            "nothing about whether the network can learn; what each baseline does when trained to its plateau is "
            "in the next line where a record of such runs exists, and in "
            "[docs/results.md](../docs/results.md#do-the-baselines-learn).")


def _floor_section(parts: ReportParts) -> list[str]:
    """Per dataset, one sentence naming the models above the floor (Table II has the margins), then
    one on whether the baselines were trained long enough for their place to mean they cannot learn."""
    if not parts.gates:
        return []
    out = ["## Above the floor", "",
           "A model is above the floor on a task when the 95% interval of its margin over the better trivial "
           "predictor (fitted on the train split, input-blind; Table II's first rows) lies above 0, with at least 3 "
           "seeds; no claim is judged, no value bolded, no Δm reported for a model that is not.", ""]
    for ds, gate in parts.gates.items():
        models = [m for m in ROW_ORDER if m in parts.results.get(ds, {})]
        if models or gate.has_floor:
            out.append(f"- {_floor_sentence(ds, gate, models)}")
    baselines = [m for m in ROW_ORDER if m in MODELS and MODELS[m].group == "baseline"
                 and any(m in r for r in parts.results.values())]
    lines = [_learning_sentence(parts, baselines),
             recorded_sentence(parts.plateau, baselines, list(parts.results), parts.plateau_link)]
    return out + [f"- {line}" for line in lines if line] + [""]


def _body(markdown: str) -> str:
    """A table's Markdown without its own ``# `` title line."""
    return markdown.split("\n", 1)[1].lstrip("\n") if markdown.startswith("# ") else markdown


def _tables_section(parts: ReportParts) -> list[str]:
    """Table II, the claims scorecard, the metrics beyond the paper's, Table III and the link to
    the paper-vs-reproduced table."""
    out = ["## Table II: test comparison", "",
           "Files: [Markdown](tables/table2.md), [LaTeX](tables/table2.tex), [CSV](tables/table2.csv).", "",
           parts.table2_md, ""]
    if parts.claims_md is not None:
        out += ["## Claims scorecard", "",
                "Files: [Markdown](tables/claims.md), [CSV](tables/claims.csv).", "", _body(parts.claims_md), ""]
    if parts.extra_md is not None:
        out += ["## Metrics beyond the paper's", "",
                "Per-class IoU / mIoU (SS, LS, BEVP) and depth AbsRel, RMSE, δ<1.25 on metric depth. Files: "
                "[Markdown](tables/extra_metrics.md), [CSV](tables/extra_metrics.csv), per class: "
                "[CSV](tables/extra_metrics_per_class.csv).", "", parts.extra_md, ""]
    out += ["## Table III: efficiency", ""]
    if parts.table3_md is None:
        out += ["No `results/benchmark/efficiency.json`: the benchmark stage has not run.", ""]
    else:
        out += [f"Device: {parts.efficiency.get('device') if parts.efficiency else '?'}. "
                "Files: [Markdown](tables/table3.md), [LaTeX](tables/table3.tex), [CSV](tables/table3.csv).", "",
                parts.table3_md, ""]
    return out + ["## Paper vs reproduced", "",
                  "Every cell available on either side: [Markdown](tables/paper_vs_reproduced.md), "
                  "[LaTeX](tables/paper_vs_reproduced.tex), [CSV](tables/paper_vs_reproduced.csv). "
                  + ("" if parts.scale_name == "paper" else
                     "This run is at a reduced scale (frames, epochs, resolution above), so its numbers are not "
                     "expected to match the paper's."), ""]


def _study_section(parts: ReportParts) -> list[str]:
    if parts.study is None:
        return []
    out = ["## Loss-balancing study (beyond the paper)", "",
           "Every loss-weighting method on the compact 15L network, with Δm against single-task networks. "
           "Files: [Markdown](tables/weighting.md), [CSV](tables/weighting.csv).", "",
           _body(parts.study.markdown_text).replace("\n## ", "\n### "), ""]
    for ds, fig in parts.study_figures.items():
        title = f"Loss weights per epoch of every adaptive method, {DATASET_LABEL.get(ds, ds)}"
        out += [f"**{title}**", "", f"![{title}]({fig})", ""]
    return out


PLOTS_SECTION: list[str] = [
    "## Training curves of every run (DVC plots)", "",
    "Long-format CSV files, one line per run (`run` = `<dataset>/<model>/seed<k>`), rendered by `dvc plots "
    "show` with the templates in `.dvc/plots/`: [plots/val_tm.csv](plots/val_tm.csv) (`epoch, run, val_tm`: "
    "validation TM per epoch of every run; a baseline's is its own tasks' share of TM) and "
    "[plots/loss_weights.csv](plots/loss_weights.csv) (`epoch, run, task, weight`: every run whose loss "
    "weighting logs weights).", ""]


def _figures_section(parts: ReportParts) -> list[str]:
    out = ["## Figures", ""]
    for ds, figs in parts.figures.items():
        if not figs:
            continue
        out += [f"### {DATASET_LABEL.get(ds, ds)} ({parts.scales[ds].source or 'unknown source'})", ""]
        for key, title in FIGURE_TITLES.items():
            if key in figs:
                out += [f"**{title}**", "", f"![{title}]({figs[key]})", ""]
    return out


def index_markdown(parts: ReportParts) -> str:
    """The text of ``reports/index.md``, section by section."""
    out = ["# Reproduction report: Natan & Miura (2022), compact multi-task perception", ""]
    out += [f"Generated by the `report` stage (`pipeline/report.py`) at params scale `{parts.scale_name or '?'}`. "
            "The paper's published numbers are kept as data in `src/compact_perception/paper_numbers.yaml`.", ""]
    out += _sources_section(parts) + _seeds_overview(parts.results, parts.scales) + _headline_section(parts)
    out += _floor_section(parts)
    out += _tables_section(parts) + _study_section(parts) + PLOTS_SECTION + _figures_section(parts)
    return "\n".join(out).rstrip() + "\n"


# ----------------------------------------------------------------------------- the steps
def write_tables(inp: ReportInputs, out_dir: Path, scale_name: str) -> tuple[ReportParts, list[Path]]:
    """Table II, the metrics beyond the paper's, the claims scorecard, Table III and the
    paper-vs-reproduced table under ``out_dir``, each built once; returns the parts of the index
    they give (the headline metrics included) and the written paths."""
    t2 = build_table2(inp.results, inp.frames, gates=inp.gates,
                      training={ds: sc.epochs for ds, sc in inp.scales.items()})
    t3 = None if inp.efficiency is None else build_table3(inp.efficiency)
    claim_ds = [ds for ds in inp.datasets if inp.results.get(ds) or inp.frames.get(ds)]
    claim_rows = build_claims(inp.root, claim_ds, inp.paper, frames=inp.frames, seeds=inp.seeds,
                              efficiency=inp.efficiency, table3=t3, gates=inp.gates)
    coverage = coverage_text({ds: inp.frames.get(ds, {}) for ds in claim_ds})
    lines = scale_lines(inp.scales, inp.paper, scale_name=scale_name, device=(inp.efficiency or {}).get("device", ""))
    floors = {ds: g.floor.results for ds, g in inp.gates.items() if g.floor is not None}
    files = {**table2_files(t2), **extra_files(build_extra_rows(inp.results, floors, inp.gates)),
             **claims_files(claim_rows, coverage), **({} if t3 is None else table3_files(t3, inp.efficiency or {})),
             **comparison_files(inp.paper, t2, t3, lines)}
    parts = ReportParts(scale_name, inp.results, inp.scales, lines, files["table2.md"],
                        table3_md=files.get("table3.md"), efficiency=inp.efficiency, claims_md=files["claims.md"],
                        extra_md=files["extra_metrics.md"],
                        headline=headline_metrics(inp.results, claim_rows, inp.gates), gates=inp.gates)
    return parts, write_files(out_dir, files)


def write_study(inp: ReportInputs, study: Optional[Any], parts: ReportParts, tables_dir: Path, figures_dir: Path,
                base: Path) -> list[Path]:
    """The loss-balancing study's table and figures (:func:`.study.write_study_report`; left out
    without ``study``), recorded in ``parts`` (figures relative to ``base``); returns the paths."""
    if study is None:
        log.info("no study params given: the loss-balancing study's report is left out")
        return []
    parts.study = write_study_report(inp.root, study, tables_dir, figures_dir,
                                     floors={ds: g.floor for ds, g in inp.gates.items() if g.floor is not None})
    parts.study_figures = {ds: _rel(p, base) for ds, p in parts.study.figures.items()}
    return parts.study.paths


def _run_dirs(runs: Sequence[RunPaths]) -> list[Path]:
    return [r.run_dir for r in runs if r.run_dir.is_dir()]


def _qualitative_figure(inp: ReportInputs, ds: str, runs: dict[str, list[RunPaths]], out_png: Path,
                        frame: int) -> Optional[Path]:
    """The Fig. 6/7 grid of ``ds`` from the first run with saved inputs and each model's first
    run with saved predictions (``None`` without saved inputs)."""
    found = [r.eval_dir / "inputs.npz" for m in inp.models for r in runs[m] if (r.eval_dir / "inputs.npz").is_file()]
    if not found:
        return None
    preds, shown = {}, {}
    for m in inp.models:
        for r in runs[m]:
            arr = load_npz(r.eval_dir / "predictions.npz")
            if arr is not None:
                preds[m], shown[m] = arr, r.seed
                break
    seed_txt = ", ".join(sorted({f"seed {k}" for k in shown.values()}))
    title = (f"{DATASET_LABEL.get(ds, ds)}, data: {inp.scales[ds].source or 'unknown source'}"
             + (f" (each model's first run: {seed_txt})" if seed_txt else ""))
    return plot_qualitative(ds, load_npz(found[0]) or {}, preds, out_png, frame=frame,
                            models=[m for m in ROW_ORDER if m in preds], labels=ROW_LABEL, title=title)


def _dataset_figures(inp: ReportInputs, ds: str, figures_dir: Path, frame: int) -> dict[str, Path]:
    """The figures of one dataset this stage draws: both MGN forms' loss weights (Fig. 8), the
    validation curves and the qualitative grid, each where its inputs exist."""
    label = DATASET_LABEL.get(ds, ds)
    runs = {m: list_runs(inp.root, ds, m, seeds_for(inp.seeds, m, ds)) for m in inp.models}
    out: dict[str, Optional[Path]] = {}
    mgn = {ROW_LABEL.get(m, m): dirs for m in MGN_FORMS if m in runs and (dirs := _run_dirs(runs[m]))}
    if mgn:
        out["loss_weights"] = plot_loss_weights(mgn, figures_dir / f"loss_weights_{ds}.png",
                                                f"Loss weights update on {label} (15L+MGN)")
    run_dirs = {m: dirs for m, rs in runs.items() if (dirs := _run_dirs(rs))}
    if run_dirs:
        out["curves"] = plot_training_curves(run_dirs, figures_dir / f"curves_{ds}.png",
                                             f"{label}: validation TM per epoch")
    out["qualitative"] = _qualitative_figure(inp, ds, runs, figures_dir / f"qualitative_{ds}.png", frame)
    return {k: p for k, p in out.items() if p}


def write_figures(inp: ReportInputs, out_dir: Path, figures_dir: Path, base: Path, frame: int
                  ) -> tuple[dict[str, dict[str, str]], list[Path]]:
    """Every dataset's figures (:func:`_dataset_figures`) and those other stages wrote under
    ``out_dir/figures``: dataset -> key -> path relative to the index (``base``), and the paths written."""
    figures: dict[str, dict[str, str]] = {}
    written: list[Path] = []
    for ds in inp.datasets:
        drawn = _dataset_figures(inp, ds, figures_dir, frame)
        written += list(drawn.values())
        figures[ds] = {k: _rel(p, base) for k, p in drawn.items()}
        for key, name in STAGE_FIGURES.items():
            if (out_dir / "figures" / name.format(ds=ds)).is_file():
                figures[ds][key] = f"figures/{name.format(ds=ds)}"
    return figures, written


def _replace_dir(new: Path, target: Path) -> None:
    """Move the built directory ``new`` onto ``target`` (the old one is removed first)."""
    target.parent.mkdir(parents=True, exist_ok=True)
    if target.exists():
        shutil.rmtree(target)
    if new.exists():
        os.replace(new, target)


def _publish(stage: Path, out_dir: Path) -> None:
    """Move everything built in ``stage`` into ``out_dir``."""
    for sub in ("tables", "figures/report", "plots"):
        _replace_dir(stage / sub, out_dir / sub)
    for name in ("metrics.json", "index.md"):
        os.replace(stage / name, out_dir / name)


def _rel(p: Path, base: Path) -> str:
    return Path(p).relative_to(base).as_posix()


def build_reports(root: Path, out_dir: Path, *, datasets: Sequence[str] = dataset_ids(),
                  models: Sequence[str] = model_ids(), scale_name: str = "", figure_frame: int = 0,
                  paper: Optional[PaperNumbers] = None, seeds: SeedSpec = None,
                  study: Optional[Any] = None, plateau: Optional[PlateauEvidence] = None) -> list[str]:
    """Write all tables, figures, plots data, the headline metrics and ``index.md`` under
    ``out_dir`` (atomic swap).

    ``seeds``: the training seeds per model (params ``seeds`` / ``baseline_seeds``; see
    :func:`.collect.list_runs`): only those seeds' runs count. ``study``: the validated params
    (``scale``, ``seeds``, ``study.*``) or a :class:`.study.StudySpec`, for the loss-balancing
    study's table and figures (:func:`.study.write_study_report`); ``None`` leaves them out.
    ``plateau``: a record of runs trained to their plateau at a larger scale
    (:mod:`.plateau`), for the floor section's line on whether the baselines learn.
    Missing inputs are tolerated (logged; the tables say ``n/a``, figures are skipped); a
    malformed input raises :class:`~.collect.ReportInputError` naming the file. Returns the
    written paths relative to ``out_dir``.
    """
    root, out_dir = Path(root), Path(out_dir)
    inp = read_inputs(root, datasets, models, seeds, paper or load_paper_numbers())
    out_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=out_dir, prefix=".report-") as stage:
        tmp = Path(stage)
        tables_dir, figures_dir = tmp / "tables", tmp / "figures" / "report"
        parts, written = write_tables(inp, tables_dir, scale_name)
        if plateau is not None:
            parts.plateau = plateau
            parts.plateau_link = Path(os.path.relpath(Path(plateau.record.path).resolve(), out_dir.resolve())).as_posix()
        written += write_plot_data(root, inp.datasets, inp.models, tmp / "plots", seeds,
                                   study_run_dirs(root, study) if study is not None else ())
        written += write_study(inp, study, parts, tables_dir, figures_dir, tmp)
        parts.figures, drawn = write_figures(inp, out_dir, figures_dir, tmp, figure_frame)
        io.write_json(tmp / "metrics.json", parts.headline)
        io.write_text(tmp / "index.md", index_markdown(parts))
        rel = [_rel(p, tmp) for p in [*written, *drawn, tmp / "metrics.json", tmp / "index.md"]]
        _publish(tmp, out_dir)
    log.info("wrote %d report files under %s", len(rel), out_dir)
    return rel
