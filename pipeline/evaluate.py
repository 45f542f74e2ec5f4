"""DVC stage evaluate@<dataset>-<model>: score the best checkpoint on the test split.

    python -m pipeline.evaluate --dataset A --model compact_15l_mgn
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from compact_perception.cache import CacheError
from compact_perception.config import DATASET_IDS, MODEL_IDS
from compact_perception.evaluate import evaluate_run
from compact_perception.train import RunError

from ._common import start


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--dataset", required=True, choices=DATASET_IDS)
    ap.add_argument("--model", required=True, choices=MODEL_IDS)
    ap.add_argument("--params", default="params.yaml")
    args = ap.parse_args(argv)
    params = start(args.params)
    run = Path("runs") / args.dataset / args.model
    try:  # bad input (a truncated cache, no checkpoint): one line naming the file, exit 1
        evaluate_run(
            args.dataset, args.model, Path("data/cache") / args.dataset, run,
            Path("results") / args.dataset / args.model / "metrics.json",
            Path("data/eval") / args.dataset / args.model,
            device_pref=params.train.device, save_predictions=params.evaluate.save_predictions,
            num_threads=params.train.num_threads,
        )
    except (CacheError, RunError, FileNotFoundError) as err:
        sys.exit(f"error: {err}")


if __name__ == "__main__":
    main()
