"""DVC stage benchmark: Table III quantities of every model at batch 1.

    python -m pipeline.benchmark [--params params.yaml] [--datasets A nuscenes]

For each model id and dataset (A stands for the simulated sets, which share the networks;
nuscenes for the nuScenes variants) builds the untrained network, and measures parameters,
state_dict size, peak memory and FPS (params.benchmark.warmup / runs) at
world.resolution at the params scale, on the GPU when there is one (train.device), else on
the CPU. Writes results/benchmark/efficiency.json atomically.
"""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

import torch

from compact_perception import io
from compact_perception.config import MODEL_IDS
from compact_perception.models import DATASETS, build_model
from compact_perception.report.efficiency import (CPU_MEMORY_METHOD, CUDA_MEMORY_METHOD, device_name,
                                                   dummy_batch, measure_model)

from ._common import start

log = logging.getLogger("pipeline.benchmark")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--params", default="params.yaml")
    ap.add_argument("--datasets", nargs="+", default=["A", "nuscenes"], choices=["A", "B", "C", "nuscenes"])
    ap.add_argument("--models", nargs="+", default=list(MODEL_IDS), choices=list(MODEL_IDS))
    ap.add_argument("--out", default="results/benchmark/efficiency.json")
    args = ap.parse_args(argv)
    params = start(args.params)
    pref = params.train.device
    if pref == "cuda" and not torch.cuda.is_available():
        raise SystemExit("error: params train.device is 'cuda' but no CUDA device is available")
    device = torch.device("cuda" if pref != "cpu" and torch.cuda.is_available() else "cpu")
    torch.manual_seed(params.seed)
    S = params.world.resolution.at(params.scale)
    bp = params.benchmark
    out: dict = {
        "device": device_name(device), "is_gpu": device.type == "cuda", "resolution": S, "scale": params.scale,
        "batch_size": 1, "warmup": bp.warmup, "runs": bp.runs, "torch": torch.__version__,
        "memory_method": CUDA_MEMORY_METHOD if device.type == "cuda" else CPU_MEMORY_METHOD, "models": {},
    }
    for ds in args.datasets:
        spec = DATASETS[ds]
        out["models"][ds] = {}
        for m in args.models:
            model = build_model(m, ds)
            batch = dummy_batch(model, n_seg=spec.n_seg, has_dvs=spec.has_dvs, resolution=S,
                                n_views=spec.n_views, device=device, seed=params.seed)
            out["models"][ds][m] = measure_model(model, batch, device, bp.warmup, bp.runs)
            del model, batch
            if device.type == "cuda":
                torch.cuda.empty_cache()
    io.write_json(Path(args.out), out)
    log.info("wrote %s", args.out)


if __name__ == "__main__":
    main()
