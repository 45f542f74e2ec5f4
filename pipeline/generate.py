"""Stage generate@<ds>: the dataset's ``data/raw/<ds>/`` and the example frame
``reports/figures/world_<ds>.png`` (SPEC 3.1).

Thin wrapper: parse args, load params, look ``datasets.<ds>.source.id`` up
(:mod:`compact_perception.data.sources`) and call it: ``sim`` renders the set with the embedded world,
``authors`` checks the authors' release and writes a manifest pointing at it, ``carla`` checks the
recording at ``datasets.<ds>.source.root`` (pipeline.collect_carla) and copies it into data/raw/<ds>.
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from compact_perception.core.catalog import sim_dataset_ids
from compact_perception.core.params import ParamsError
from compact_perception.core.errors import RecordError, RunError, os_error_line
from compact_perception.data.sources import data_source

from ._common import stage, start


@stage
def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--dataset", required=True, choices=sim_dataset_ids())
    ap.add_argument("--params", default="params.yaml")
    ap.add_argument("--out", default="data/raw", help="parent of the dataset directory")
    ap.add_argument("--figure-dir", default="reports/figures")
    args = ap.parse_args(argv)
    params = start(args.params, workers=("world.workers",))
    source = data_source(params.dataset(args.dataset).source.id)
    out = Path(args.out) / args.dataset
    figure = Path(args.figure_dir) / f"world_{args.dataset}.png"
    try:
        source.write_raw(params, args.dataset, out)
    except (ParamsError, RunError, RecordError) as err:  # RunError: the free disk cannot hold the dataset
        sys.exit(f"error: {err}")
    except OSError as err:  # a full disk: atomic_dir has removed the partial dataset
        sys.exit(f"error: {os_error_line(err, out)}")
    try:
        source.draw_example(params, args.dataset, out, figure)
    except RecordError as err:
        sys.exit(f"error: {err}")
    except OSError as err:
        sys.exit(f"error: {os_error_line(err, figure)}")
    logging.getLogger("generate").info("wrote %s and the figure", out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
