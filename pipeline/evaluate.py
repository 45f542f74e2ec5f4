"""DVC stage evaluate@<dataset>-<model>: score every seed's best checkpoint on the test split
(runs/<ds>/<model>/seed<k> for k in params.yaml's ``seeds`` of a compact model, ``baseline_seeds``
of a baseline; one process for all seeds).

    python -m pipeline.evaluate --dataset A --model compact_15l_mgn
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from compact_perception.core.cache import CacheError
from compact_perception.core.catalog import MODELS, dataset_ids, model_ids
from compact_perception.evaluate import evaluate_run
from compact_perception.core.layout import run_paths
from compact_perception.core.errors import RunError

from ._common import start


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--dataset", required=True, choices=dataset_ids())
    ap.add_argument("--model", required=True, choices=model_ids())
    ap.add_argument("--params", default="params.yaml")
    args = ap.parse_args(argv)
    params = start(args.params)
    try:  # bad input (a truncated cache, no checkpoint): one line naming the file, exit 1
        for seed in params.seeds_of(MODELS[args.model].group):
            paths = run_paths(args.dataset, args.model, seed)
            evaluate_run(
                args.dataset, args.model, Path("data/cache") / args.dataset, paths.run_dir,
                paths.metrics_path, paths.eval_dir,
                device_pref=params.train.device, save_predictions=params.evaluate.save_predictions,
                num_threads=params.train.num_threads,
            )
    except (CacheError, RunError, FileNotFoundError) as err:
        sys.exit(f"error: {err}")


if __name__ == "__main__":
    main()
