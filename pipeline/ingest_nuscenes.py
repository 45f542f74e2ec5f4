"""Stage ingest_nuscenes: a nuScenes-lidarseg dataroot (real, or the simulated export) ->
data/cache/nuscenes/ (paper section IV-B, SPEC 3.2).

Thin wrapper around :func:`compact_perception.data.nuscenes.ingest.ingest_from_params`. Missing or
corrupt input (dataroot, lidarseg folder, sweeps, images, label files; a truncated sweep or label
.bin) stops with a one-line message naming it before anything is written (exit status 1).
"""
from __future__ import annotations

import argparse
import sys

from ._common import stage, start

from compact_perception.core.errors import os_error_line
from compact_perception.data.nuscenes.ingest import NuScenesInputError, ingest_from_params


@stage
def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--params", default="params.yaml")
    ap.add_argument("--sim-root", default="data/raw/nuscenes_sim", help="dataroot used when datasets.nuscenes.dataroot is null")
    ap.add_argument("--out", default="data/cache/nuscenes")
    args = ap.parse_args(argv)
    params = start(args.params, workers=("preprocess.workers",))
    try:
        ingest_from_params(params, args.out, sim_root=args.sim_root)
    except NuScenesInputError as err:
        sys.exit(f"error: {err}")
    except OSError as err:  # a full disk, a read-only data/cache/: the cache is written atomically
        sys.exit(f"error: {os_error_line(err, args.out)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
