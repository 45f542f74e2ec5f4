"""The report at ``scale: full``, read from the records of runs trained there
(``benchmarks/records/full/<ds>_<part>.json``, written by ``benchmarks/record_full.py``; version 2
of :mod:`compact_perception.core.plateau_record`).

A record holds the files the pipeline wrote for each run (``metrics.json``, ``per_frame.csv``,
``summary.json``, the loss-weight and validation series), the dataset's floor and cache meta.
:func:`build_full_report` writes them back as a run tree in a temporary folder
(:func:`~compact_perception.core.plateau_record.write_tree`) and builds Table II, the metrics
beyond the paper's, the claims scorecard and the paper comparison from it with the code that
builds them from the default's runs (:func:`.index.read_inputs`, :func:`.index.write_tables`), so
the two reports cannot score alike data differently. Where the params run the loss-balancing
study at ``full`` on a recorded dataset, its table is built likewise (:func:`.index.write_study`)
from the recorded study arms (a record's runs with an ``arm``) beside the paper's forms. The page
(``reports/full/index.md``) says, per dataset and model (or study arm), which record (commit,
machine) each row comes from and which of today's params keys would train it differently; a
dataset, model or study arm of the params with no record is listed as not recorded, and a run a
record has as incomplete is named.
"""
from __future__ import annotations

import logging
import os
import shutil
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Any, Optional, Sequence

import pandas as pd

from ..core import io
from ..core.catalog import MODELS
from ..core.errors import ReportInputError
from ..core.layout import study_arm, study_run_name
from ..core.plateau_record import STATUS_COMPLETE, run_name, write_tree
from ..stats import MAX_SEEDS_TO_DECIDE
from .index import (ReportInputs, _floor_section, _seeds_overview, _study_section, _tables_section, read_inputs,
                    write_study, write_tables)
from .paper import PaperNumbers, load_paper_numbers
from .plateau import PlateauRecord, changed_settings, load_record
from .schema import DATASET_LABEL, ROW_LABEL
from .study import StudySpec

__all__ = ["load_records", "build_full_report", "seeds_needed", "RECORD_GLOB", "SEEDS_NEEDED_BINS"]

log = logging.getLogger(__name__)

#: The records of ``scale: full`` in their folder (``benchmarks/records/full/``).
RECORD_GLOB = "*.json"


def load_records(folder: Path) -> list[PlateauRecord]:
    """Every record of ``folder`` (:data:`RECORD_GLOB`, sorted by name); a record its schema
    refuses raises :class:`ReportInputError` naming it."""
    out = []
    for path in sorted(Path(folder).glob(RECORD_GLOB)):
        rec = load_record(path)
        if rec is not None:
            out.append(rec)
    return out


def _label(name: str) -> str:
    """A model's row label, or "study arm" and the arm for a study run's name."""
    arm = study_arm(name)
    return f"study arm `{arm}`" if arm is not None else ROW_LABEL.get(name, name)


def _at_full(params: Any) -> Any:
    """``params`` read at ``scale: full`` (what the records were trained at), whatever its own ``scale``."""
    return params.model_copy(update={"scale": "full"})


def _provenance_rows(records: Sequence[PlateauRecord], params: Any) -> tuple[list[str], dict[tuple[str, str], str]]:
    """The table naming, per (dataset, model or study arm), the record, commit and machine its rows
    come from, and what today's params change of its runs; and each incomplete run's line."""
    lines = ["| dataset | model | seeds | record | commit | machine | today's params would change |",
             "|---|---|---|---|---|---|---|"]
    incomplete: dict[tuple[str, str], str] = {}
    for rec in records:
        assert rec.data is not None
        ds = rec.data["dataset"]
        by_model: dict[str, list[int]] = {}
        for run in rec.data["runs"]:
            if run["status"] == STATUS_COMPLETE:
                by_model.setdefault(run_name(run), []).append(run["seed"])
            else:
                incomplete[(ds, f"{run_name(run)} seed {run['seed']}")] = run["reason"]
        for model, seeds in by_model.items():
            changed = sorted({k for r in rec.runs if r.name == model
                              for k in changed_settings(r, params, rec.scale, rec.device)})
            shown = ", ".join(f"`{k}`" for k in changed[:4]) + (f" and {len(changed) - 4} more" if len(changed) > 4
                                                                  else "") or "nothing"
            lines.append(f"| {DATASET_LABEL.get(ds, ds)} | {_label(model)} | "
                         f"{', '.join(map(str, sorted(seeds)))} | [{Path(rec.path).name}]"
                         f"(../../benchmarks/records/full/{Path(rec.path).name}) | {rec.commit[:12]} | {rec.machine} | "
                         f"{shown} |")
    return lines, incomplete


def _not_recorded(records: Sequence[PlateauRecord], params: Any) -> list[str]:
    """Per dataset of the params, the models and study arms (and seeds) at ``full`` with no
    complete recorded run."""
    have = {(r.dataset, r.name, r.seed) for rec in records for r in rec.runs}
    full = _at_full(params)
    out = []
    for ds in params.dataset_ids:
        planned = [(m, params.seeds_of(MODELS[m].group, ds, "full")) for m in params.model_ids]
        if ds in full.study_datasets:
            base = params.seeds_of(MODELS[params.study.base_model].group, ds, "full")
            planned += [(study_run_name(arm), base) for arm in params.study.arm_ids]
        models, arms = [], []
        for m, want in planned:
            lacking = [k for k in want if (ds, m, k) not in have]
            if lacking:
                seeds = "" if len(lacking) == len(want) else f" (seeds {', '.join(map(str, lacking))})"
                if (arm := study_arm(m)) is not None:
                    arms.append(f"`{arm}`{seeds}")
                else:
                    models.append(ROW_LABEL.get(m, m) + seeds)
        if arms:
            models.append(f"the loss-balancing study's arms {', '.join(arms)}")
        if models:
            out.append(f"- {DATASET_LABEL.get(ds, ds)}: {', '.join(models)}")
    return out


#: How the seeds per model an inconclusive claim would need (claims.csv ``seeds_to_decide``) are
#: counted per dataset in ``metrics.json``'s ``seeds_to_decide``, with each bin's words.
_MANY = MAX_SEEDS_TO_DECIDE
SEEDS_NEEDED_BINS: dict[str, str] = {
    "at_most_10": "at most 10 seeds per model would detect the paper's effect",
    f"11_to_{_MANY}": f"11 to {_MANY} would",
    f"over_{_MANY}": f"more than {_MANY} (the test episodes limit them: more test frames, not seeds)",
    "no_count": "no count (a claim of equality, the loss weights' order, or no printed effect)",
}


def seeds_needed(claims: "pd.DataFrame", datasets: Sequence[str]) -> dict[str, dict[str, int]]:
    """Per dataset (in ``datasets`` order) with an inconclusive claim, how many of its inconclusive
    claims fall in each bin of :data:`SEEDS_NEEDED_BINS` by their ``seeds_to_decide``."""
    out: dict[str, dict[str, int]] = {}
    rows = claims[claims["verdict"] == "inconclusive"] if len(claims) else claims
    for ds in datasets:
        counts = dict.fromkeys(SEEDS_NEEDED_BINS, 0)
        for need in rows[rows["dataset"] == ds]["seeds_to_decide"] if len(rows) else ():
            text = "" if pd.isna(need) else str(need).strip()
            if not text:
                counts["no_count"] += 1
            elif text.startswith(">"):
                counts[f"over_{_MANY}"] += 1
            else:
                counts["at_most_10" if int(float(text)) <= 10 else f"11_to_{_MANY}"] += 1
        if sum(counts.values()):
            out[ds] = counts
    return out


def _decided_section(parts: Any, claims: "pd.DataFrame") -> list[str]:
    """The scorecard at ``full`` in words: the verdict counts (``metrics.json``), how many claims
    are not decidable for want of a recorded run, and each decided or inconclusive claim with its
    interval and the seeds per model it would need."""
    counts = dict((parts.headline or {}).get("claims") or {})
    no_data = int(claims["note"].fillna("").str.startswith("no data").sum()) if len(claims) else 0
    out = ["## What `full` decides so far", "",
           f"Of the claims judged on test scores for the recorded datasets ([metrics.json](metrics.json), "
           f"[claims](tables/claims.md)): {counts.get('reproduced', 0)} reproduced, "
           f"{counts.get('contradicted', 0)} contradicted, {counts.get('inconclusive', 0)} inconclusive and "
           f"{counts.get('not_decidable', 0)} not decidable, {no_data} of them for want of a recorded run (a model "
           "not recorded yet). Table III's exact-count claims are the default report's.", ""]
    needed = (parts.headline or {}).get("seeds_to_decide") or {}
    if needed:
        out += ["The seeds per model each inconclusive claim would need (at 80% power, the paper's effect; "
                "`seeds_to_decide` in [metrics.json](metrics.json)):", ""]
        out += [f"- {DATASET_LABEL.get(ds, ds)}: {sum(c.values())} inconclusive; "
                + "; ".join(f"{SEEDS_NEEDED_BINS[k]}: {c[k]}" for k in SEEDS_NEEDED_BINS if c[k])
                for ds, c in needed.items()]
        out += [""]
    decided = claims[claims["verdict"] != "not decidable"] if len(claims) else claims
    for _, row in decided.iterrows():
        need = row.get("seeds_to_decide")
        need_txt = ("" if row["verdict"] != "inconclusive" or pd.isna(need)
                    else f"; seeds per model that would detect the paper's effect: {need}")
        out.append(f"- {DATASET_LABEL.get(row['dataset'], row['dataset'])}, {row['statement']}: {row['verdict']}, "
                   f"measured {row['measured']:+.3f}, 95% interval [{row['ci_low']:+.3f}, {row['ci_high']:+.3f}]"
                   + ("" if pd.isna(row["paper"]) else f" (the paper: {row['paper']})") + need_txt)
    return out + [""]


def _page(records: Sequence[PlateauRecord], params: Any, parts: Any, claims: "pd.DataFrame") -> str:
    prov, incomplete = _provenance_rows(records, params)
    missing = _not_recorded(records, params)
    out = ["# Reproduction report at `scale: full`, from the recorded runs", "",
           "Generated by the `report_full` stage (`pipeline/report_full.py`) from the records of runs trained at `scale: full` "
           "in `benchmarks/records/full/` (`benchmarks/record_full.py`, one dataset and part at a time; each record holds "
           "every run's test scores per frame, its floor and the settings it was trained under). Every table below is "
           "built by the code that builds the default's report, from the recorded files.", "",
           "## Where each row comes from", "", *prov, ""]
    if incomplete:
        out += ["Runs a record has as incomplete (no number is recorded for them):", ""]
        out += [f"- {DATASET_LABEL.get(ds, ds)}, {what}: {why}" for (ds, what), why in incomplete.items()] + [""]
    out += ["## Not recorded yet", ""]
    out += (["At `scale: full` the params train these runs, which no record holds yet: their rows are absent "
             "from the tables below and the claims on them are not decidable here.", "", *missing, ""]
            if missing else ["Every dataset, model and seed of the params at `scale: full` is recorded.", ""])
    out += _seeds_overview(parts.results, parts.scales) + _decided_section(parts, claims)
    out += _floor_section(parts) + _tables_section(parts) + _study_section(parts)
    return "\n".join(out).rstrip() + "\n"


def build_full_report(records: Sequence[PlateauRecord], params: Any, out_dir: Path,
                      paper: Optional[PaperNumbers] = None) -> list[str]:
    """The report at ``full`` under ``out_dir`` (``index.md``, ``metrics.json``, ``tables/``; with
    the study, ``figures/``), replaced whole, from the version-2 ``records``. Table III and its exact-count claims are the
    default report's (the networks, not their training): left out here. Without a version-2
    record the page says so. Returns the written paths relative to ``out_dir``."""
    full = [r for r in records if r.data is not None]
    _check(full)
    out_dir = Path(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=out_dir.parent, prefix=".full-") as stage:
        tmp = Path(stage)
        tree, page = tmp / "tree", tmp / "page"
        page.mkdir()
        seeds: dict[str, dict[str, list[int]]] = {}
        for rec in full:
            assert rec.data is not None
            for model, seed, arm in write_tree(rec.data, tree):
                if arm is None:
                    seeds.setdefault(rec.data["dataset"], {}).setdefault(model, []).append(seed)
        datasets = [ds for ds in params.dataset_ids if ds in seeds] + sorted(set(seeds) - set(params.dataset_ids))
        models = [m for m in params.model_ids if any(m in s for s in seeds.values())]
        models += sorted({m for s in seeds.values() for m in s} - set(models))
        if not datasets:
            io.write_text(page / "index.md", "# Reproduction report at `scale: full`\n\nNo run at `scale: full` is "
                          "recorded yet (`benchmarks/records/full/`, written by `benchmarks/record_full.py`).\n")
            written = ["index.md"]
        else:
            inp: ReportInputs = read_inputs(tree, datasets, models, {ds: {m: sorted(k) for m, k in s.items()}
                                                                   for ds, s in seeds.items()},
                                            paper or load_paper_numbers())
            parts, paths = write_tables(inp, page / "tables", "full")
            claims = pd.read_csv(page / "tables" / "claims.csv")
            parts.headline = {**(parts.headline or {}), "seeds_to_decide": seeds_needed(claims, datasets)}
            spec = StudySpec.from_params(_at_full(params))
            spec = replace(spec, datasets=tuple(ds for ds in spec.datasets if ds in datasets))
            if spec.datasets:  # the study at full, on its recorded datasets
                paths += write_study(inp, spec, parts, page / "tables", page / "figures", page)
            io.write_json(page / "metrics.json", parts.headline)
            io.write_text(page / "index.md", _page(full, params, parts, claims))
            written = [Path(p).relative_to(page).as_posix() for p in paths] + ["metrics.json", "index.md"]
        if out_dir.exists():
            shutil.rmtree(out_dir)
        os.replace(page, out_dir)
    log.info("wrote the report at full (%d records) under %s", len(full), out_dir)
    return written


def _check(records: Sequence[PlateauRecord]) -> None:
    """Two records of one dataset holding the same run are refused (which would the report show?)."""
    seen: dict[tuple[str, str, int], str] = {}
    for rec in records:
        for r in rec.runs:
            key = (r.dataset, r.name, r.seed)
            if key in seen:
                raise ReportInputError(f"{rec.path}: {r.name} seed {r.seed} on {r.dataset} is also in {seen[key]}")
            seen[key] = rec.path
