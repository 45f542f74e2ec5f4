"""Preprocessing and loading benchmarks (SPEC 4, 9: "loading must keep up with training").

Prints:
1. the eq. (2)-(5) 15-layer projection of a 100k-point cloud (median ms over many runs);
2. loader throughput (frames/s) from a synthetic cache (default 600 frames at S = 128)
   with 2 worker processes, batch 6, shuffled;
3. the per-frame cache footprint vs the authors' per-frame storage (float64 one-hot SS x4,
   LS, BEV and the float64 15-layer LiDAR tensor, plus their uint8 RGB/DVS/depth images),
   and the ratio.

Usage: python benchmarks/bench_preprocess.py [--frames 600] [--size 128] [--runs 50]
"""
from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import time
from pathlib import Path
from typing import Iterator

import numpy as np

from compact_perception.core.cache import read_cache, write_cache
from compact_perception.core.classes import BEV_NAMES, CARLA_NAMES
from compact_perception.data.loader import make_loader
from compact_perception.data.geometry import VIEWS
from compact_perception.data.lidar import topview_15l

sys.path.insert(0, str(Path(__file__).resolve().parent))
from flags import MAX_WORKERS, Parser, count, frame_size  # noqa: E402


def random_cloud(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.stack(
        [rng.uniform(-40, 40, n), rng.uniform(-40, 40, n), rng.uniform(-2.5, 11.5, n), rng.uniform(0, 1, n)], axis=1
    ).astype(np.float32)


def bench_projection(n_points: int = 100_000, runs: int = 50, size: int = 128) -> float:
    pts = random_cloud(n_points)
    topview_15l(pts, 32.0, size)  # warm-up
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        topview_15l(pts, 32.0, size)
        times.append(time.perf_counter() - t0)
    return float(np.median(times) * 1e3)


def synthetic_frames(n: int, size: int, seed: int = 0) -> Iterator[dict]:
    rng = np.random.default_rng(seed)
    v = len(VIEWS)
    base = {
        "rgb": rng.integers(0, 256, (v, 3, size, size), dtype=np.uint8),
        "dvs": rng.integers(0, 2, (v, 2, size, size), dtype=np.uint8),
        "lidar": rng.random((15, size, size)).astype(np.float16),
        "de": rng.random((v, 1, size, size)).astype(np.float16),
        "ss": rng.integers(0, 23, (v, size, size), dtype=np.uint8),
        "ls": rng.choice(np.array([0, 7, 255], np.uint8), (size, size)),
        "bevp": rng.integers(0, 2, (9, size, size), dtype=np.uint8),
    }
    for i in range(n):
        f = {k: np.roll(a, i, axis=-1) for k, a in base.items()}
        f["frame_id"] = f"s{i:06d}"
        yield f


def bench_loader(cache_dir: Path, workers: int = 2, batch_size: int = 6) -> float:
    dl = make_loader(cache_dir, "train", 15, batch_size=batch_size, shuffle=True, seed=0, num_workers=workers)
    it = iter(dl)
    for _ in range(3):  # start the workers, warm the page cache path
        next(it)
    n, t0 = 0, time.perf_counter()
    for batch in it:
        n += batch["rgb"].shape[0]
    dt = time.perf_counter() - t0
    return n / dt


def footprints(cache_dir: Path, size: int) -> tuple[int, int]:
    cache = read_cache(cache_dir)
    ours = sum(int(np.prod(k["shape"])) * np.dtype(k["dtype"]).itemsize for k in cache.meta["keys"]["train"].values())
    px, v = size * size, len(VIEWS)
    n_seg, n_bev = len(CARLA_NAMES), len(BEV_NAMES)
    authors_f64 = (v * n_seg + n_seg + n_bev + 15) * px * 8  # SS x4, LS, BEV one-hot + 15-layer LiDAR, float64
    authors_images = (v * 3 + v * 3 + v * 1) * px  # RGB, DVS colour, depth images (uint8, uncompressed)
    return ours, authors_f64 + authors_images


def main() -> None:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=count(1), default=600)
    ap.add_argument("--size", type=frame_size(), default=128)
    ap.add_argument("--runs", type=count(1), default=50)
    ap.add_argument("--workers", type=count(1, MAX_WORKERS), default=2)
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)

    ms = bench_projection(runs=args.runs, size=args.size)
    print(f"15L projection, 100k points, S={args.size}: {ms:.2f} ms (median of {args.runs})")
    with tempfile.TemporaryDirectory(prefix="bench_cache_") as tmp:
        cache_dir = Path(tmp) / "cache"
        meta = {"dataset": "bench", "source": "synthetic", "seg_classes": list(CARLA_NAMES), "bev_classes": list(BEV_NAMES),
                "has_dvs": True, "resolution": args.size, "views": list(VIEWS)}
        t0 = time.perf_counter()
        write_cache(cache_dir, {"train": synthetic_frames(args.frames, args.size)}, meta)
        print(f"cache write: {args.frames} frames in {time.perf_counter() - t0:.1f} s")
        fps = bench_loader(cache_dir, args.workers)
        print(f"loader throughput ({args.workers} workers, batch 6, shuffled): {fps:.0f} frames/s")
        ours, authors = footprints(cache_dir, args.size)
    print(f"per-frame footprint: cache {ours} B, authors' float64 storage {authors} B, ratio {authors / ours:.1f}x smaller")


if __name__ == "__main__":
    main()
