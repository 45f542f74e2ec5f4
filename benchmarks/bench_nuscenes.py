"""Ingestion speed of the nuScenes path (paper IV-B) at 128 px, projected to real trainval.

Exports a small simulated nuScenes-format dataroot (the world's ``render_episode``), then runs
the stage's own function, :func:`compact_perception.data.nuscenes.ingest.ingest_nuscenes`, end to end
(devkit load, input check, ingestion, cache write) at ``--size`` px (default 128, the paper's)
with the stage's workers (``preprocess.workers`` if the ingest takes a ``workers`` argument,
else the one process it uses), and times ``ingest_sample`` per sample.

Projection to the 34,149 key frames of v1.0-trainval: real images are 1600 x 900 JPEGs (the
simulated ones are small PNGs), so the per-sample cost is corrected by the measured cost of
decoding + INTER_AREA-resizing four 1600 x 900 JPEGs minus that of the simulated PNGs, then
divided by the workers. Real sweeps (~34,700 points, 32 beams) are smaller than the simulated
ones (~58,000), so the LiDAR part is, if anything, overestimated. Not included: the devkit's
load of the trainval tables (a one-off, about a minute) and disk reads slower than page cache.

Usage: ``.venv/bin/python benchmarks/bench_nuscenes.py [--scenes 4] [--samples 8] [--size 128]``
(about 30 s on 2 cores); prints a summary and writes ``benchmarks/out/bench_nuscenes.json``.
"""
from __future__ import annotations

import argparse
import inspect
import json
import logging
import os
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from compact_perception.core.params import load_params
from compact_perception.data.nuscenes.export import export_nuscenes_sim
from compact_perception.data.nuscenes.ingest import ingest_nuscenes, ingest_sample, load_nuscenes, plan_ingestion

sys.path.insert(0, str(Path(__file__).resolve().parent))
from flags import Parser, count, frame_size  # noqa: E402

TRAINVAL_KEY_FRAMES = 34149  #: key-frame samples of nuScenes v1.0-trainval (850 scenes)
ROOT = Path(__file__).resolve().parents[1]


def _jpeg_cost(size: int, reps: int = 5) -> float:
    """Seconds to decode + INTER_AREA-resize four 1600 x 900 JPEGs (one nuScenes sample)."""
    rng = np.random.default_rng(0)
    base = cv2.GaussianBlur(rng.integers(0, 256, (900, 1600, 3), dtype=np.uint8), (0, 0), 3)
    ok, buf = cv2.imencode(".jpg", base, [cv2.IMWRITE_JPEG_QUALITY, 90])
    assert ok
    t0 = time.perf_counter()
    for _ in range(reps * 4):
        img = cv2.imdecode(buf, cv2.IMREAD_COLOR)
        cv2.resize(img, (size, size), interpolation=cv2.INTER_AREA)
    return (time.perf_counter() - t0) / reps


def _png_cost(nusc, tokens: list[str], size: int) -> float:
    """Seconds per sample to read + resize the four simulated camera PNGs."""
    t0 = time.perf_counter()
    for tok in tokens:
        s = nusc.get("sample", tok)
        for ch in ("CAM_FRONT", "CAM_FRONT_LEFT", "CAM_FRONT_RIGHT", "CAM_BACK"):
            img = cv2.imread(str(Path(nusc.dataroot) / nusc.get("sample_data", s["data"][ch])["filename"]))
            cv2.resize(img, (size, size), interpolation=cv2.INTER_AREA)
    return (time.perf_counter() - t0) / len(tokens)


def main(argv: list[str] | None = None) -> int:
    ap = Parser(description=__doc__)
    ap.add_argument("--params", default=str(ROOT / "params.yaml"))
    ap.add_argument("--scenes", type=count(1, 10_000), default=4)
    ap.add_argument("--samples", type=count(1, 1000), default=8, help="samples per scene")
    ap.add_argument("--size", type=frame_size(), default=128, help="ingest resolution in px (the paper's: 128)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "out" / "bench_nuscenes.json"))
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    params = load_params(args.params)
    d = params.model_dump()
    d["datasets"]["nuscenes"]["sim_samples_per_scene"] = args.samples
    params = type(params).model_validate(d)
    ns, size = params.datasets.nuscenes, int(args.size)
    takes_workers = "workers" in inspect.signature(ingest_nuscenes).parameters
    workers = max(1, int(params.preprocess.workers)) if takes_workers else 1
    res: dict = {"scenes": args.scenes, "samples_per_scene": args.samples, "size": size, "workers": workers,
                 "ingest_takes_workers": takes_workers, "cpus": os.cpu_count(), "trainval_key_frames": TRAINVAL_KEY_FRAMES}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "nuscenes_sim"
        t0 = time.perf_counter()
        export_nuscenes_sim(params, root, n_scenes=args.scenes)
        res["export_s"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        ingest_nuscenes(root, ns.version, Path(tmp) / "cache", resolution=size, preprocess=params.preprocess,
                        split_seed=ns.split_seed, **({"workers": workers} if takes_workers else {}))
        res["stage_s"] = time.perf_counter() - t0

        nusc = load_nuscenes(root, ns.version)
        tokens = [tok for pairs in plan_ingestion(nusc, ns.split_seed).values() for _, tok in pairs]
        n = res["samples"] = len(tokens)
        ingest_sample(nusc, tokens[0], size, params.preprocess)  # warm-up
        t0 = time.perf_counter()
        for tok in tokens:
            ingest_sample(nusc, tok, size, params.preprocess)
        per = (time.perf_counter() - t0) / n
        real_per = per - _png_cost(nusc, tokens, size) + _jpeg_cost(size)
    res["stage_samples_per_s"] = n / res["stage_s"]  # includes the devkit load of the small set
    res["sample_s_one_process"] = per
    res["sample_s_real_images_one_process"] = real_per
    res["samples_per_s_real_images"] = workers / real_per
    res["trainval_estimate_h"] = TRAINVAL_KEY_FRAMES * real_per / workers / 3600.0
    print(f"simulated nuScenes set: {args.scenes} scenes x {args.samples} samples ({n}); export {res['export_s']:.1f} s")
    print(f"ingest_nuscenes at {size} px, {workers} worker(s){'' if takes_workers else ' (the ingest runs in one process)'}: "
          f"{n} samples in {res['stage_s']:.1f} s = {res['stage_samples_per_s']:.1f} samples/s end to end; "
          f"ingest_sample {1 / per:.1f} samples/s per process")
    print(f"with 4 x 1600x900 JPEG decoding per sample: {res['samples_per_s_real_images']:.1f} samples/s -> "
          f"{TRAINVAL_KEY_FRAMES:,} trainval key frames ~ {res['trainval_estimate_h']:.2f} h "
          f"(+ the devkit's one-off table load)")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(res, indent=2, sort_keys=True) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
