"""DVC stage evaluate@<dataset>: the floor and every run of one dataset on its test split.

First the trivial predictors (compact_perception.evaluation.floor, SPEC 8: fitted on the train split) into
results/<ds>/floor_*/; then every run of compact_perception.learning.plan (each model at its seeds, the
study's arms) from its best checkpoint, frame by frame, in ``train.parallel_runs`` worker
processes (or as cluster jobs: compact_perception.execution, docs/cluster.md), into
results/<ds>/<model>/seed<k>/metrics.json (with its margin over the floor) and
data/eval/<ds>/<model>/seed<k>/. Before anything is written, every file of the cache and every
run's ``best.pt`` is checked against the SHA-256 recorded when it was written (meta.json's
``sha256``, summary.json's ``best_sha256``): a copy damaged in a DVC remote or on a disk is named in
one line, not scored; a cache or run from before hashes were recorded is evaluated unchecked (a log line).

    python -m pipeline.evaluate --dataset A
"""
from __future__ import annotations

import argparse
import logging
import sys
from functools import partial
from pathlib import Path
from typing import Mapping

from compact_perception.core.cache import CacheError, read_split, verify_cache
from compact_perception.core.catalog import MODELS, dataset_ids
from compact_perception.core import io
from compact_perception.core.params import Params
from compact_perception.core.errors import RunError, os_error_line
from compact_perception.core.layout import cache_dir, evaluation_folders, floor_paths
from compact_perception.evaluation.evaluate import check_best, evaluate_floors, evaluate_run, read_best
from compact_perception.evaluation.floor import TRIVIAL
from compact_perception.learning.plan import PlannedRun, dataset_runs
from compact_perception.execution.executor import chosen_executor, run_jobs
from compact_perception.execution.jobs import Job, JobError
from compact_perception.execution.settings import SettingsError
from compact_perception.learning.training.parallel import stage_processes

from ._common import stage, start, worker_logging

log = logging.getLogger("evaluate")

def evaluate_one(params: Params, run: PlannedRun, *, floor: Mapping[str, float]) -> dict:
    """Score one planned run's best checkpoint (in a worker process or in this one)."""
    worker_logging()
    return evaluate_run(params, run, floor)


@stage
def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--dataset", required=True, choices=dataset_ids())
    ap.add_argument("--params", default="params.yaml")
    args = ap.parse_args(argv)
    params = start(args.params, workers=("train.parallel_runs",), device=True)
    cache = cache_dir(args.dataset)
    try:  # bad input (a truncated cache, no checkpoint, a read-only results/): one line naming the file,
        executor = chosen_executor()               # exit 1, before any write
        runs = dataset_runs(params, args.dataset)
        for split in ("train", "test"):
            read_split(cache, split)
        if not verify_cache(cache):  # every file as it was written (a copy damaged in a DVC remote)
            log.info("%s: no hashes recorded when it was written (an older cache); evaluated unchecked", cache)
        for r in runs:  # every checkpoint is as written, exists and reads safely (its tensors mapped, not read)
            check_best(r)
            read_best(r, mmap=True)
        # the floor's and every run's results/ and data/eval/ folders: a read-only one stops it here
        io.check_writable(*evaluation_folders([*(floor_paths(args.dataset, t) for t in TRIVIAL.keys()),
                                               *(r.paths for r in runs)]))
        floor = evaluate_floors(params, args.dataset, ".")
        jobs = [Job(r.name, r, cost=MODELS[r.model].epoch_cost) for r in runs]
        # no memory probe (it would train): an evaluation holds a network and one frame, so on CUDA
        # under auto the count measured best for speed fits where the runs' training did
        processes, on_gpu = stage_processes(params.train)
        run_jobs(partial(evaluate_one, params, floor=floor), jobs, processes, desc=f"evaluate {args.dataset}",
                 gpu=on_gpu, executor=executor)
    except (JobError, CacheError, RunError, SettingsError) as err:
        sys.exit(f"error: {err}")
    except OSError as err:  # no checkpoint (its own message), a full disk, a read-only folder
        sys.exit(f"error: {os_error_line(err, Path('results') / args.dataset)}")


if __name__ == "__main__":
    main()
