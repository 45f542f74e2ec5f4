"""Record dataset A, B or C from a CARLA server into ``datasets.<ds>.source.root`` (docs/carla.md).

Not a DVC stage: it needs a running server and the optional ``carla`` client
(``pip install -e .[carla]``). It records what ``datasets.<ds>.source`` says (``{id: carla, root,
host, port, ...}``: set it first); then ``dvc repro``: generate@<ds> checks the recording and
copies it into data/raw/<ds>.

    python -m pipeline.collect_carla --dataset A [--host H] [--port P] [--root DIR] [--restart]

A rerun resumes at the first episode not yet complete; ``--restart`` records the set again.
Every failure is one line ``error: ...`` and exit status 1; no manifest is written over a
partial set.
"""
from __future__ import annotations

import argparse
import sys

import logging

from compact_perception.core.catalog import sim_dataset_ids
from compact_perception.core.params import ParamsError, load_params
from compact_perception.core.errors import RecordError, os_error_line


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", required=True, choices=sim_dataset_ids())
    ap.add_argument("--params", default="params.yaml")
    ap.add_argument("--host", help="overrides datasets.<ds>.source.host")
    ap.add_argument("--port", type=int, help="overrides datasets.<ds>.source.port")
    ap.add_argument("--root", help="overrides datasets.<ds>.source.root (the folder written)")
    ap.add_argument("--restart", action="store_true", help="discard what is recorded and record the set again")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        params = load_params(args.params)
    except ParamsError as err:
        sys.exit(f"error: {err}")
    from compact_perception.data.carla.recording import carla_settings

    try:
        cs = carla_settings(params, args.dataset)
    except ParamsError as err:
        sys.exit(f"error: {err}")
    host, port, root = args.host or cs.host, args.port if args.port is not None else cs.port, args.root or cs.root
    if not 1 <= port <= 65535:
        sys.exit(f"error: --port {port}: expected 1..65535")
    from compact_perception.data.carla.collector import CarlaError, collect, import_client

    try:
        n = collect(import_client(), params, args.dataset, root, host, port, restart=args.restart)
    except (CarlaError, RecordError) as err:
        sys.exit(f"error: {err}")
    except OSError as err:
        sys.exit(f"error: {os_error_line(err, root)}")
    except KeyboardInterrupt:
        sys.exit(f"error: interrupted; rerun the same command to resume (complete episodes in {root} are kept)")
    print(f"{root}: recorded {n} frame(s); dataset {args.dataset} complete "
          f"(datasets.{args.dataset}.source names it: dvc repro brings it in)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
