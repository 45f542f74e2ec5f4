"""DVC stage report: tables, figures, plots data, the headline metrics and reports/index.md
from every run's outputs.

    python -m pipeline.report [--params params.yaml] [--out reports]

Reads, for every run of the seeds params.yaml lists (``datasets.<ds>.training.seeds`` for the
compact models, ``baseline_seeds`` for the baselines; seed folders of other seeds are ignored):
results/<ds>/<model>/seed<k>/metrics.json, data/eval/<ds>/<model>/seed<k>/{per_frame.csv, *.npz},
runs/<ds>/<model>/seed<k>/{summary.json, live/plots/metrics/*.tsv}; and
results/benchmark/efficiency.json, data/cache/<ds>/meta.json. Writes reports/index.md,
reports/metrics.json, reports/tables/, reports/figures/report/ and reports/plots/, atomically
(compact_perception.report.index.build_reports).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from compact_perception.core.catalog import MODELS, dataset_ids, model_ids
from compact_perception.report.collect import ReportInputError
from compact_perception.report.index import build_reports

from ._common import start


def seed_lists(params: Any) -> dict[str, dict[str, list[int]]]:
    """The training seeds of every model on every dataset (``Params.seeds_of``: the dataset's
    ``training.seeds`` for a compact model, ``baseline_seeds`` for a baseline)."""
    return {ds: {m: [int(k) for k in params.seeds_of(MODELS[m].group, ds)] for m in model_ids()}
            for ds in dataset_ids()}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--params", default="params.yaml")
    ap.add_argument("--root", default=".", help="directory holding results/, runs/, data/")
    ap.add_argument("--out", default="reports")
    args = ap.parse_args(argv)
    params = start(args.params)
    try:
        build_reports(Path(args.root), Path(args.out), datasets=dataset_ids(), models=model_ids(),
                      scale_name=params.scale, figure_frame=params.evaluate.figure_frame,
                      seeds=seed_lists(params), study=params)
    except ReportInputError as err:
        sys.exit(f"error: {err}")


if __name__ == "__main__":
    main()
