"""DVC stage study@<arm>-<seed>: one arm of the loss-balancing study (beyond the paper) at one
seed, trained and scored on every dataset of ``study.datasets`` (set A at the default scale).

    python -m pipeline.study --arm uw --seed 0
"""
from __future__ import annotations

import argparse
import sys

from compact_perception.core.cache import CacheError
from compact_perception.core.config import ParamsError
from compact_perception.core.errors import RunError
from compact_perception.study import run_arm
from compact_perception.weighting import weighting_settings

from ._common import start


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--arm", required=True, help="an arm of params.yaml's study.arms (listed in study.arm_ids)")
    ap.add_argument("--seed", required=True, type=int, help="one of params.yaml's seeds")
    ap.add_argument("--params", default="params.yaml")
    args = ap.parse_args(argv)
    params = start(args.params)
    if args.arm not in params.study.arms:  # reads study.arms.<arm> only (the stage's params)
        sys.exit(f"error: {args.params}: study.arms has no arm {args.arm!r}; known: {sorted(params.study.arms)}")
    try:
        weighting_settings(params.study_recipe(args.arm, args.params), args.params)  # before anything is written
        run_arm(params, args.arm, args.seed)
    except (RunError, CacheError, ParamsError, FileNotFoundError) as err:
        sys.exit(f"error: {err}")


if __name__ == "__main__":
    main()
