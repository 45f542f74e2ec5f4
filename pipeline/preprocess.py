"""Stage preprocess@<ds>: data/raw/<ds>/ (or the authors' dataset) -> data/cache/<ds>/ (SPEC 4).

Thin wrapper around :func:`compact_perception.data.preprocess.preprocess_dataset`; also draws
``reports/figures/lidar_preprocessing_<ds>.png`` (Fig. 5-like).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from compact_perception.core.cache import CacheError
from compact_perception.core.catalog import sim_dataset_ids
from compact_perception.core.errors import RecordError, os_error_line
from compact_perception.core.layout import CACHE_ROOT
from compact_perception.data.preprocess import preprocess_dataset

from ._common import stage, start


@stage
def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--dataset", required=True, choices=sim_dataset_ids())
    ap.add_argument("--params", default="params.yaml")
    ap.add_argument("--raw-root", default="data/raw")
    ap.add_argument("--cache-root", default=str(CACHE_ROOT))
    ap.add_argument("--figures", default="reports/figures")
    args = ap.parse_args(argv)
    params = start(args.params, workers=("preprocess.workers",))
    try:
        preprocess_dataset(
            params,
            args.dataset,
            raw_root=args.raw_root,
            cache_root=args.cache_root,
            figure_path=Path(args.figures) / f"lidar_preprocessing_{args.dataset}.png",
        )
    except (RecordError, CacheError) as err:
        sys.exit(f"error: {err}")
    except OSError as err:  # a full disk: the cache is built in a temporary folder, removed on failure
        sys.exit(f"error: {os_error_line(err, Path(args.cache_root) / args.dataset)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
