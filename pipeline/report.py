"""DVC stage report: tables, figures and reports/index.md from every run's outputs.

    python -m pipeline.report [--params params.yaml] [--out reports]

Reads results/<ds>/<model>/metrics.json, results/benchmark/efficiency.json,
runs/<ds>/<model>/{summary.json, live/plots/metrics/*.tsv, eval/*.npz} and
data/cache/<ds>/meta.json; writes reports/ as a whole, atomically
(compact_perception.report.index.build_reports).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from compact_perception.config import DATASET_IDS, MODEL_IDS
from compact_perception.report.collect import ReportInputError
from compact_perception.report.index import build_reports

from ._common import start


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--params", default="params.yaml")
    ap.add_argument("--root", default=".", help="directory holding results/, runs/, data/")
    ap.add_argument("--out", default="reports")
    args = ap.parse_args(argv)
    params = start(args.params)
    try:
        build_reports(Path(args.root), Path(args.out), datasets=DATASET_IDS, models=MODEL_IDS,
                      scale_name=params.scale, figure_frame=params.evaluate.figure_frame)
    except ReportInputError as err:
        sys.exit(f"error: {err}")


if __name__ == "__main__":
    main()
