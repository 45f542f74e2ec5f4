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
"""
from __future__ import annotations

import logging
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any, Optional, Sequence

from ..core import io
from ..core.catalog import dataset_ids, model_ids
from .claims import build_claims, claims_csv, claims_markdown, verdict_counts
from .collect import (DatasetScale, ModelResult, SeedSpec, collect_scale, list_runs, load_npz, load_results,
                      load_row_frames, read_json, seeds_for)
from .figures import MODEL_LABEL, plot_loss_weights, plot_qualitative, plot_training_curves
from .paper import PaperNumbers, load_paper_numbers
from .plots import write_plot_data
from .study import StudyOutputs, study_run_dirs, write_study_report
from .tables import (DATASET_LABEL, MGN_MODELS, ROW_ORDER, build_extra_rows, build_table2, build_table3,
                     extra_markdown, scale_lines, table2_csv, table2_latex, table2_markdown, table3_markdown,
                     write_comparison, write_extra_metrics, write_table, write_table3)

log = logging.getLogger(__name__)

#: The model of the headline TM in ``reports/metrics.json``: the paper's proposed model (15L+MGN)
#: in the form that produced the paper's Table II, the authors' public code.
HEADLINE_MODEL = "compact_15l_mgn_authors"
HEADLINE_KEY = "tm_mgn_authors"
HEADLINE_DECIMALS = 4


def find_inputs(root: Path, dataset: str, models: Sequence[str], seeds: SeedSpec = None) -> Optional[Path]:
    """The first ``inputs.npz`` of a run (model order, then seed) that exists (every evaluation
    writes it beside its per-frame scores)."""
    for m in models:
        for run in list_runs(root, dataset, m, seeds_for(seeds, m)):
            p = run.eval_dir / "inputs.npz"
            if p.is_file():
                return p
    return None


def headline_metrics(results: dict[str, dict[str, ModelResult]], claim_rows: Sequence[Any]) -> dict[str, Any]:
    """``reports/metrics.json``: TM of :data:`HEADLINE_MODEL` per dataset (mean over its seeds,
    4 decimals; datasets without results left out) and the scorecard's verdict counts."""
    tm = {}
    for ds, res in results.items():
        r = res.get(HEADLINE_MODEL)
        cell = r.scores.get("tm") if r is not None else None
        if cell is not None:
            tm[ds] = round(float(cell.mean), HEADLINE_DECIMALS)
    return {HEADLINE_KEY: tm, "claims": verdict_counts(claim_rows)}


def _replace_dir(new: Path, target: Path) -> None:
    """Move the built directory ``new`` onto ``target`` (the old one is removed first)."""
    target.parent.mkdir(parents=True, exist_ok=True)
    if target.exists():
        shutil.rmtree(target)
    if new.exists():
        os.replace(new, target)


def _rel(p: Path, base: Path) -> str:
    return Path(p).relative_to(base).as_posix()


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
        out += ["| Model | Seeds (runs) |", "|---|---|"]
        for m in [m for m in ROW_ORDER if m in per_model] + [m for m in per_model if m not in ROW_ORDER]:
            texts = sorted({", ".join("?" if k is None else str(k) for k in ks) + f" ({len(ks)})"
                            for ks in per_model[m]})
            out.append(f"| {MODEL_LABEL.get(m, m)} | {'; '.join(texts)} |")
        out.append("")
    frames = [f"{DATASET_LABEL.get(ds, ds)} {'/'.join(map(str, sc.n_test_frames)) or '?'}"
              for ds, sc in scales.items()]
    out += [f"Test frames scored per run: {', '.join(frames)}.", ""]
    return out


def index_markdown(*, results: dict[str, dict[str, ModelResult]], scales: dict[str, DatasetScale],
                   table2_md: str, table3_md: Optional[str], scale_text: list[str],
                   figures: dict[str, dict[str, str]], efficiency: Optional[dict[str, Any]],
                   scale_name: str, claims_md: Optional[str] = None, extra_md: Optional[str] = None,
                   headline: Optional[dict[str, Any]] = None, study: Optional[StudyOutputs] = None,
                   study_figures: Optional[dict[str, str]] = None) -> str:
    """The text of ``reports/index.md`` (``study``: the loss-balancing study's outputs, its
    figures' paths relative to the index in ``study_figures``)."""
    out = ["# Reproduction report: Natan & Miura (2022), compact multi-task perception", ""]
    out += [f"Generated by the `report` stage (`pipeline/report.py`) at params scale `{scale_name or '?'}`. "
            "The paper's published numbers are kept as data in `src/compact_perception/paper_numbers.yaml`.", ""]
    out += ["## Data sources and scale", "",
            "| Dataset | Data source | Frames train/val/test | Test frames per run | Resolution | DVS | "
            "Models with results |",
            "|---|---|---|---|---|---|---|"]
    for ds, sc in scales.items():
        counts = "/".join(str(sc.counts.get(k, "?")) for k in ("train", "val", "test")) if sc.counts else "?"
        mods = ", ".join(MODEL_LABEL.get(m, m) for m in results.get(ds, {})) or "none"
        dvs = "?" if sc.has_dvs is None else ("yes" if sc.has_dvs else "no")
        n_test = "/".join(map(str, sc.n_test_frames)) or "?"
        out.append(f"| {DATASET_LABEL.get(ds, ds)} | {sc.source or 'unknown'} | {counts} | {n_test} | "
                   f"{sc.resolution or '?'} | {dvs} | {mods} |")
    out += [""] + [f"- {s}" for s in scale_text] + [""]
    out += _seeds_overview(results, scales)
    if headline is not None:
        tm = headline.get(HEADLINE_KEY) or {}
        counts = headline.get("claims") or {}
        out += ["## Headline", "",
                f"[`metrics.json`](metrics.json) (the pipeline's one DVC metrics file, `dvc metrics show` / "
                f"`dvc exp show`): `{HEADLINE_KEY}` = TM of {MODEL_LABEL.get(HEADLINE_MODEL, HEADLINE_MODEL)} "
                "(the paper's proposed model in the form that produced its Table II), mean over its seeds, per "
                "dataset: " + (", ".join(f"{DATASET_LABEL.get(d, d)} {v:.4f}" for d, v in tm.items()) or "none")
                + "; `claims`: scorecard rows per verdict: "
                + ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in counts.items()) + ". Every run's scores: "
                "`results/<ds>/<model>/seed<k>/metrics.json`.", ""]
    out += ["## Table II: test comparison", "",
            "Files: [Markdown](tables/table2.md), [LaTeX](tables/table2.tex), [CSV](tables/table2.csv).", "",
            table2_md, ""]
    if claims_md is not None:
        body = claims_md.split("\n", 1)[1].lstrip("\n") if claims_md.startswith("# ") else claims_md
        out += ["## Claims scorecard", "",
                "Files: [Markdown](tables/claims.md), [CSV](tables/claims.csv).", "", body, ""]
    if extra_md is not None:
        out += ["## Metrics beyond the paper's", "",
                "Per-class IoU / mIoU (SS, LS, BEVP) and depth AbsRel, RMSE, δ<1.25 on metric depth. Files: "
                "[Markdown](tables/extra_metrics.md), [CSV](tables/extra_metrics.csv), per class: "
                "[CSV](tables/extra_metrics_per_class.csv).", "", extra_md, ""]
    out += ["## Table III: efficiency", ""]
    if table3_md is None:
        out += ["No `results/benchmark/efficiency.json`: the benchmark stage has not run.", ""]
    else:
        out += [f"Device: {efficiency.get('device') if efficiency else '?'}. "
                "Files: [Markdown](tables/table3.md), [LaTeX](tables/table3.tex), [CSV](tables/table3.csv).", "",
                table3_md, ""]
    out += ["## Paper vs reproduced", "",
            "Every cell available on either side: [Markdown](tables/paper_vs_reproduced.md), "
            "[LaTeX](tables/paper_vs_reproduced.tex), [CSV](tables/paper_vs_reproduced.csv). "
            + ("" if scale_name == "paper" else
               "This run is at a reduced scale (frames, epochs, resolution above), so its numbers are not "
               "expected to match the paper's."), ""]
    if study is not None:
        body = study.markdown_text.split("\n", 1)[1].lstrip("\n") if study.markdown_text.startswith("# ") \
            else study.markdown_text
        body = body.replace("\n## ", "\n### ")
        out += ["## Loss-balancing study (beyond the paper)", "",
                "Every loss-weighting method on the compact 15L network, with Δm against single-task networks. "
                "Files: [Markdown](tables/weighting.md), [CSV](tables/weighting.csv).", "", body, ""]
        for ds, fig in (study_figures or {}).items():
            title = f"Loss weights per epoch of every adaptive method, {DATASET_LABEL.get(ds, ds)}"
            out += [f"**{title}**", "", f"![{title}]({fig})", ""]
    out += ["## Training curves of every run (DVC plots)", "",
            "Long-format CSV files, one line per run (`run` = `<dataset>/<model>/seed<k>`), rendered by `dvc plots "
            "show` with the templates in `.dvc/plots/`: [plots/val_tm.csv](plots/val_tm.csv) (`epoch, run, val_tm`: "
            "validation TM per epoch of every run; a baseline's is its own tasks' share of TM) and "
            "[plots/loss_weights.csv](plots/loss_weights.csv) (`epoch, run, task, weight`: every run whose loss "
            "weighting logs weights).", ""]
    out += ["## Figures", ""]
    for ds, figs in figures.items():
        if not figs:
            continue
        out += [f"### {DATASET_LABEL.get(ds, ds)} ({scales[ds].source or 'unknown source'})", ""]
        for key, title in (("world", "One frame of the simulated world, all sensors and ground truths (Fig. 1)"),
                           ("lidar", "LiDAR preprocessing: 14 height layers and the flattened layer (Fig. 5)"),
                           ("loss_weights", "Loss weights of 15L+MGN per epoch, both MGN forms, mean over seeds "
                                            "(Fig. 8)"),
                           ("curves", "Validation TM per epoch, mean over seeds"),
                           ("qualitative", "Qualitative results, one test frame, each model's first seed (Fig. 6/7)")):
            if key in figs:
                out += [f"**{title}**", "", f"![{title}]({figs[key]})", ""]
    return "\n".join(out).rstrip() + "\n"


def build_reports(root: Path, out_dir: Path, *, datasets: Sequence[str] = dataset_ids(),
                  models: Sequence[str] = model_ids(), scale_name: str = "", figure_frame: int = 0,
                  paper: Optional[PaperNumbers] = None, seeds: SeedSpec = None,
                  study: Optional[Any] = None) -> list[str]:
    """Write all tables, figures, plots data, the headline metrics and ``index.md`` under
    ``out_dir`` (atomic swap).

    ``seeds``: the training seeds per model (params ``seeds`` / ``baseline_seeds``; see
    :func:`.collect.list_runs`): only those seeds' runs count. ``study``: the validated params
    (``scale``, ``seeds``, ``study.*``) or a :class:`.study.StudySpec`, for the loss-balancing
    study's table and figures (:func:`.study.write_study_report`); ``None`` leaves them out.
    Missing inputs are tolerated
    (logged; the tables say ``n/a``, figures are skipped); a malformed input raises
    :class:`~.collect.ReportInputError` naming the file. Returns the written paths relative to
    ``out_dir``.
    """
    root, out_dir = Path(root), Path(out_dir)
    paper = paper or load_paper_numbers()
    results = load_results(root, list(datasets), list(models), seeds)
    eff_path = root / "results" / "benchmark" / "efficiency.json"
    efficiency = read_json(eff_path) if eff_path.is_file() else None
    if efficiency is None:
        log.warning("%s missing: Table III skipped", eff_path)
    scales = collect_scale(root, list(datasets), list(models), results, seeds)
    written: list[Path] = []
    out_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=out_dir, prefix=".report-") as stage:
        tmp = Path(stage)
        tdir, fdir, pdir = tmp / "tables", tmp / "figures" / "report", tmp / "plots"
        frames = {ds: load_row_frames(root, ds, list(models), seeds) for ds in datasets}
        t2 = build_table2(results, frames)
        t2_md = table2_markdown(t2)
        written += write_table(tdir, "table2", t2_md, table2_latex(t2), table2_csv(t2))
        written += write_extra_metrics(results, tdir)
        extra_md = extra_markdown(build_extra_rows(results))
        claim_ds = [ds for ds in datasets if results.get(ds) or frames.get(ds)]
        claim_rows = build_claims(root, claim_ds, paper, frames=frames, seeds=seeds, efficiency=efficiency)
        claims_md = claims_markdown(claim_rows)
        for name, text in (("claims.md", claims_md), ("claims.csv", claims_csv(claim_rows))):
            io.write_text(tdir / name, text)
            written.append(tdir / name)
        t3 = t3_md = None
        if efficiency is not None:
            t3 = build_table3(efficiency)
            t3_md = table3_markdown(t3, efficiency)
            written += write_table3(efficiency, tdir)
        lines = scale_lines(scales, paper, scale_name=scale_name,
                            device=(efficiency or {}).get("device", ""))
        written += write_comparison(paper, t2, t3, lines, tdir)
        written += write_plot_data(root, list(datasets), list(models), pdir, seeds,
                                   study_run_dirs(root, study) if study is not None else ())
        study_out: Optional[StudyOutputs] = None
        study_figs: dict[str, str] = {}
        if study is not None:
            study_out = write_study_report(root, study, tdir, fdir)
            written += study_out.paths
            study_figs = {ds: _rel(p, tmp) for ds, p in study_out.figures.items()}
        else:
            log.info("no study params given: the loss-balancing study's report is left out")
        headline = headline_metrics(results, claim_rows)
        io.write_json(tmp / "metrics.json", headline)
        written.append(tmp / "metrics.json")
        figures: dict[str, dict[str, str]] = {}
        for ds in datasets:
            figs: dict[str, str] = {}
            label = DATASET_LABEL.get(ds, ds)
            runs = {m: list_runs(root, ds, m, seeds_for(seeds, m)) for m in models}
            mgn = {MODEL_LABEL.get(m, m): [r.run_dir for r in runs[m] if r.run_dir.is_dir()]
                   for m in MGN_MODELS if m in runs}
            mgn = {k: v for k, v in mgn.items() if v}
            if mgn:
                p = plot_loss_weights(mgn, fdir / f"loss_weights_{ds}.png", f"Loss weights update on {label} (15L+MGN)")
                if p:
                    figs["loss_weights"] = _rel(p, tmp)
            run_dirs = {m: [r.run_dir for r in rs if r.run_dir.is_dir()] for m, rs in runs.items()}
            run_dirs = {m: v for m, v in run_dirs.items() if v}
            if run_dirs:
                p = plot_training_curves(run_dirs, fdir / f"curves_{ds}.png", f"{label}: validation TM per epoch")
                if p:
                    figs["curves"] = _rel(p, tmp)
            inp_path = find_inputs(root, ds, list(models), seeds)
            if inp_path is not None:
                inputs = load_npz(inp_path) or {}
                preds, shown = {}, {}
                for m in models:
                    for r in runs[m]:
                        arr = load_npz(r.eval_dir / "predictions.npz")
                        if arr is not None:
                            preds[m], shown[m] = arr, r.seed
                            break
                seed_txt = ", ".join(sorted({f"seed {k}" for k in shown.values() if k is not None}))
                p = plot_qualitative(ds, inputs, preds, fdir / f"qualitative_{ds}.png", frame=figure_frame,
                                     models=[m for m in ROW_ORDER if m in preds], labels=MODEL_LABEL,
                                     title=f"{label}, data: {scales[ds].source or 'unknown source'}"
                                           + (f" (each model's first run: {seed_txt})" if seed_txt else ""))
                if p:
                    figs["qualitative"] = _rel(p, tmp)
            for key, name in (("world", f"world_{ds}.png"), ("lidar", f"lidar_preprocessing_{ds}.png")):
                if (out_dir / "figures" / name).is_file():
                    figs[key] = f"figures/{name}"
            figures[ds] = figs
            written += [tmp / f for k, f in figs.items() if k not in ("world", "lidar")]
        text = index_markdown(results=results, scales=scales, table2_md=t2_md, table3_md=t3_md,
                              scale_text=lines, figures=figures, efficiency=efficiency, scale_name=scale_name,
                              claims_md=claims_md, extra_md=extra_md, headline=headline, study=study_out,
                              study_figures=study_figs)
        io.write_text(tmp / "index.md", text)
        written.append(tmp / "index.md")
        rel = [_rel(p, tmp) for p in written]
        for sub in ("tables", "figures/report", "plots"):
            _replace_dir(tmp / sub, out_dir / sub)
        os.replace(tmp / "metrics.json", out_dir / "metrics.json")
        os.replace(tmp / "index.md", out_dir / "index.md")
    log.info("wrote %d report files under %s", len(rel), out_dir)
    return rel
