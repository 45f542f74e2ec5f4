"""DVC stage train@<dataset>-<model>: train one model on one dataset's cache.

    python -m pipeline.train --dataset A --model compact_15l_mgn
    torchrun --standalone --nproc_per_node=2 -m pipeline.train --dataset A --model compact_15l
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from compact_perception.config import DATASET_IDS, MODEL_IDS
from compact_perception.cache import CacheError
from compact_perception.train import RunError, train_run

from ._common import start


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--dataset", required=True, choices=DATASET_IDS)
    ap.add_argument("--model", required=True, choices=MODEL_IDS)
    ap.add_argument("--params", default="params.yaml")
    ap.add_argument("--cache", type=Path, default=None, help="default data/cache/<dataset>")
    ap.add_argument("--out", type=Path, default=None, help="default runs/<dataset>/<model>")
    args = ap.parse_args(argv)
    params = start(args.params)
    if args.model not in params.train.models:
        raise SystemExit(f"error: params.yaml has no train.models.{args.model} recipe")
    try:
        train_run(
            params, args.dataset, args.model,
            args.cache or Path("data/cache") / args.dataset,
            args.out or Path("runs") / args.dataset / args.model,
        )
    except (RunError, CacheError) as err:
        sys.exit(f"error: {err}")


if __name__ == "__main__":
    main()
