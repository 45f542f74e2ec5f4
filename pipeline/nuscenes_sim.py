"""Stage nuscenes_sim: the simulated world -> data/raw/nuscenes_sim/ (a nuScenes-format dataroot).

Only simulates when ``datasets.nuscenes.dataroot`` is null (SPEC 3.2); with a real dataroot it
writes only a manifest pointing at it (its DVC output), and a dataroot that is not there (no
folder, no ``<version>`` table folder) is a one-line error naming the key and the path, exit
status 1, nothing written. Thin wrapper around
:func:`compact_perception.data.nuscenes.export.export_nuscenes_sim`.
"""
from __future__ import annotations

import argparse
import logging
import sys

from ._common import stage, start

from compact_perception.core import io
from compact_perception.core.errors import os_error_line
from compact_perception.data.nuscenes import dataroot_problem
from compact_perception.data.nuscenes.export import export_nuscenes_sim


@stage
def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--params", default="params.yaml")
    ap.add_argument("--out", default="data/raw/nuscenes_sim")
    args = ap.parse_args(argv)
    params = start(args.params)
    log = logging.getLogger("nuscenes_sim")
    ns = params.datasets.nuscenes
    if ns.dataroot:  # real data: record what ingest_nuscenes will read instead of simulating
        problem = dataroot_problem(ns.dataroot, ns.version)
        if problem:
            sys.exit(f"error: {args.params}: datasets.nuscenes.dataroot: {problem}")
        log.info("datasets.nuscenes.dataroot is set (%s): no simulated set written", ns.dataroot)
    try:
        if ns.dataroot:
            with io.atomic_dir(args.out) as tmp:
                io.write_json(tmp / "manifest.json", {"source": "nuScenes-lidarseg", "dataroot": ns.dataroot,
                                                      "version": ns.version})
        else:
            export_nuscenes_sim(params, args.out)
    except OSError as err:  # a full disk, a read-only data/raw/: the dataroot is written atomically
        sys.exit(f"error: {os_error_line(err, args.out)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
