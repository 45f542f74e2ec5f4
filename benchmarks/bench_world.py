"""Benchmark of the embedded world (SPEC 3.1): full-sensor frames per second, single process.

A full-sensor frame = 4 cameras x (RGB, semantic, depth, DVS) + LiDAR + BEV + boxes.
Usage: python benchmarks/bench_world.py [--frames 10] [--town town03]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from compact_perception.core.params import TOWNS, load_params
from compact_perception.data.world.generate import render_episode
from compact_perception.data.world.town import build_town

sys.path.insert(0, str(Path(__file__).resolve().parent))
from flags import Parser, count  # noqa: E402


def fps(params, town: str, size: int, frames: int) -> float:
    build_town(town)
    it = render_episode(params.world, town, 1234, frames + 1, size)
    next(it)  # warm-up (includes the previous step rendered for DVS)
    t0 = time.perf_counter()
    n = sum(1 for _ in it)
    return n / (time.perf_counter() - t0)


def main() -> None:
    ap = Parser()
    ap.add_argument("--frames", type=count(1, 10_000), default=10)
    ap.add_argument("--town", default="town03", choices=TOWNS)
    ap.add_argument("--params", default="params.yaml")
    a = ap.parse_args()
    p = load_params(a.params)
    for s in (128, 64):
        print(f"{a.town} {s}x{s}: {fps(p, a.town, s, a.frames):.2f} full-sensor frames/s "
              f"(LiDAR {p.world.lidar.channels}x{p.world.lidar.horizontal_samples})")


if __name__ == "__main__":
    main()
