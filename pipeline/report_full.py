"""DVC stage report_full: the report at `scale: full`, from the records of runs trained there.

    python -m pipeline.report_full [--params params.yaml] [--records benchmarks/records/full] [--out reports/full]

Reads every record of --records (one per dataset and part, written by benchmarks/record_full.py:
each run's test scores per frame, its floor and the settings it was trained under) and writes
reports/full/ (index.md, metrics.json, tables/) with Table II, the metrics beyond the paper's,
the claims scorecard and the paper comparison at `full`, every row naming the record (commit,
machine) it comes from, the datasets and models the params train at `full` that no record holds,
and the keys of today's params that would train a recorded run differently
(compact_perception.report.full). It needs no run of this checkout: the records are its data. A bad
record is one line naming it and the field; the previous reports/full/ stays in place.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from compact_perception.core.errors import ReportInputError, os_error_line
from compact_perception.report.full import build_full_report, load_records

from ._common import stage, start


@stage
def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--params", default="params.yaml")
    ap.add_argument("--records", default="benchmarks/records/full")
    ap.add_argument("--out", default="reports/full")
    args = ap.parse_args(argv)
    params = start(args.params)
    try:
        build_full_report(load_records(Path(args.records)), params, Path(args.out))
    except ReportInputError as err:
        sys.exit(f"error: {err}")
    except OSError as err:
        sys.exit(f"error: {os_error_line(err, args.out)}")


if __name__ == "__main__":
    main()
