"""DVC stage report: tables, figures, plots data, the headline metrics and reports/index.md
from the outputs of the runs the params select.

    python -m pipeline.report [--params params.yaml] [--out reports]

Reads, for the datasets of ``dataset_ids`` and the models of ``model_ids`` only (a dataset or
model left out is absent from every table, figure and the headline; ``results/`` files of another
run's datasets are not read; compact_perception.report.selection), every run of the seeds
params.yaml lists (``datasets.<ds>.training.seeds`` for the compact models, ``baseline_seeds``
for the baselines; seed folders of other seeds are ignored):
results/<ds>/<model>/seed<k>/metrics.json, data/eval/<ds>/<model>/seed<k>/{per_frame.csv, *.npz},
runs/<ds>/<model>/seed<k>/{summary.json, live/plots/metrics/*.tsv}; and
results/benchmark/efficiency.json (the selected models), data/cache/<ds>/meta.json, and the record
of runs trained to their plateau at `scale: full` (--plateau-record,
benchmarks/records/full_plateau.json, written by benchmarks/record_plateau.py), which the floor
section quotes with what today's params change of those runs. Writes
reports/index.md, reports/metrics.json, reports/tables/, reports/figures/report/ and
reports/plots/, atomically (compact_perception.report.index.build_reports); a failed read or
write (a full disk, a read-only folder) is one line naming the file.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from compact_perception.core.errors import os_error_line
from compact_perception.report.collect import ReportInputError
from compact_perception.report.index import build_reports
from compact_perception.report.plateau import evidence, load_record
from compact_perception.report.selection import select

from ._common import stage, start


def seed_lists(params: Any) -> dict[str, dict[str, list[int]]]:
    """The training seeds of every selected model on every selected dataset (``Params.seeds_of``:
    the dataset's ``training.seeds`` for a compact model, ``baseline_seeds`` for a baseline)."""
    return select(params).seeds


@stage
def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--params", default="params.yaml")
    ap.add_argument("--root", default=".", help="directory holding results/, runs/, data/")
    ap.add_argument("--out", default="reports")
    ap.add_argument("--plateau-record", default="benchmarks/records/full_plateau.json",
                    help="runs trained to their plateau (benchmarks/record_plateau.py); absent: left out")
    args = ap.parse_args(argv)
    params = start(args.params)
    chosen = select(params)
    try:
        plateau = evidence(load_record(Path(args.plateau_record)), params)
        build_reports(Path(args.root), Path(args.out), datasets=chosen.datasets, models=chosen.models,
                      scale_name=params.scale, figure_frame=params.evaluate.figure_frame,
                      seeds=chosen.seeds, study=chosen.study, plateau=plateau)
    except ReportInputError as err:
        sys.exit(f"error: {err}")
    except OSError as err:  # a full disk, a read-only reports/: the previous report stays in place
        sys.exit(f"error: {os_error_line(err, args.out)}")


if __name__ == "__main__":
    main()
