"""DVC stage train@<dataset>-<model>-<seed>: train one model on one dataset's cache with one of
params.yaml's ``seeds``, into runs/<dataset>/<model>/seed<seed>.

    python -m pipeline.train --dataset A --model compact_15l_mgn --seed 0
    torchrun --standalone --nproc_per_node=2 -m pipeline.train --dataset A --model compact_15l --seed 0
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from compact_perception.core.catalog import dataset_ids, model_ids
from compact_perception.core.cache import CacheError
from compact_perception.core.config import ParamsError
from compact_perception.core.layout import run_paths
from compact_perception.core.errors import RunError
from compact_perception.training.train import train_run
from compact_perception.weighting import weighting_settings

from ._common import start


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--dataset", required=True, choices=dataset_ids())
    ap.add_argument("--model", required=True, choices=model_ids())
    ap.add_argument("--seed", required=True, type=int, help="one of params.yaml's seeds")
    ap.add_argument("--params", default="params.yaml")
    ap.add_argument("--cache", type=Path, default=None, help="default data/cache/<dataset>")
    ap.add_argument("--out", type=Path, default=None, help="default runs/<dataset>/<model>/seed<seed>")
    args = ap.parse_args(argv)
    params = start(args.params)
    if args.model not in params.train.models:
        raise SystemExit(f"error: params.yaml has no train.models.{args.model} recipe")
    try:
        weighting_settings(params.train.models[args.model], args.params)  # before anything is written
        train_run(
            params, args.dataset, args.model, args.seed,
            args.cache or Path("data/cache") / args.dataset,
            args.out or run_paths(args.dataset, args.model, args.seed).run_dir,
        )
    except (RunError, CacheError, ParamsError) as err:
        sys.exit(f"error: {err}")


if __name__ == "__main__":
    main()
