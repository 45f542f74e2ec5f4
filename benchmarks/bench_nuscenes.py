"""Ingestion speed of the nuScenes path (paper IV-B) on the simulated nuScenes-format set.

Exports a small simulated dataroot (the world's ``render_episode``), then times
``ingest_sample`` (devkit records -> rgb, lidar 15L, de, ss, ls, bevp) per sample at the default
and the paper resolution, and estimates the time for the 34,149-sample trainval set. Real
nuScenes images are 1600 x 900 JPEGs (the simulated ones are small PNGs), so a second estimate
replaces the measured image cost by the measured cost of decoding + resizing four 1600 x 900
JPEGs; real sweeps (~34,700 points, 32 beams) are smaller than the simulated ones (~58,000).

Usage: ``.venv/bin/python benchmarks/bench_nuscenes.py [--scenes 3] [--samples 4]``;
prints a summary and writes ``benchmarks/out/bench_nuscenes.json``.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from compact_perception.config import load_params
from compact_perception.nuscenes.export import export_nuscenes_sim
from compact_perception.nuscenes.ingest import ingest_sample, load_nuscenes, plan_ingestion

TRAINVAL_SAMPLES = 34149
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
    t0 = time.perf_counter()
    for tok in tokens:
        s = nusc.get("sample", tok)
        for ch in ("CAM_FRONT", "CAM_FRONT_LEFT", "CAM_FRONT_RIGHT", "CAM_BACK"):
            img = cv2.imread(str(Path(nusc.dataroot) / nusc.get("sample_data", s["data"][ch])["filename"]))
            cv2.resize(img, (size, size), interpolation=cv2.INTER_AREA)
    return (time.perf_counter() - t0) / len(tokens)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--params", default=str(ROOT / "params.yaml"))
    ap.add_argument("--scenes", type=int, default=3)
    ap.add_argument("--samples", type=int, default=4, help="samples per scene")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "out" / "bench_nuscenes.json"))
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    params = load_params(args.params)
    d = params.model_dump()
    d["datasets"]["nuscenes"]["sim_samples_per_scene"] = args.samples
    params = type(params).model_validate(d)
    results: dict = {"scenes": args.scenes, "samples_per_scene": args.samples, "by_resolution": {}}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "nuscenes_sim"
        t0 = time.perf_counter()
        export_nuscenes_sim(params, root, n_scenes=args.scenes)
        results["export_s"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        nusc = load_nuscenes(root, params.datasets.nuscenes.version)
        results["devkit_load_s"] = time.perf_counter() - t0
        tokens = [tok for pairs in plan_ingestion(nusc, 0).values() for _, tok in pairs]
        for size in sorted({params.world.resolution.at("default"), params.world.resolution.at("paper")}):
            ingest_sample(nusc, tokens[0], size, params.preprocess)  # warm-up
            t0 = time.perf_counter()
            for tok in tokens:
                ingest_sample(nusc, tok, size, params.preprocess)
            per = (time.perf_counter() - t0) / len(tokens)
            real_per = per - _png_cost(nusc, tokens, size) + _jpeg_cost(size)
            results["by_resolution"][str(size)] = {
                "samples_per_s": 1.0 / per,
                "trainval_estimate_h": TRAINVAL_SAMPLES * per / 3600.0,
                "trainval_estimate_real_images_h": TRAINVAL_SAMPLES * real_per / 3600.0,
                "samples_per_s_real_images": 1.0 / real_per,
            }
    n = len(tokens)
    print(f"simulated nuScenes set: {args.scenes} scenes x {args.samples} samples ({n}); export {results['export_s']:.1f} s, "
          f"devkit load {results['devkit_load_s']:.2f} s")
    for size, r in results["by_resolution"].items():
        print(f"S={size}: {r['samples_per_s']:.1f} samples/s (1 process) -> 34,149 trainval samples ~ "
              f"{r['trainval_estimate_h']:.2f} h; with 1600x900 JPEG decoding ~ {r['samples_per_s_real_images']:.1f} samples/s "
              f"-> ~ {r['trainval_estimate_real_images_h']:.2f} h")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=2, sort_keys=True) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
