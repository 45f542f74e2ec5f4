"""DVC stage benchmark: Table III quantities of the selected models at batch 1.

    python -m pipeline.benchmark [--params params.yaml] [--datasets A nuscenes] [--models ...]

For each model of ``model_ids`` (as every other stage; ``--models`` names others) and dataset (A stands for the simulated sets, which share the networks;
nuscenes for the nuScenes variants) builds the untrained network, and measures parameters,
state_dict size, peak memory and FPS (params.benchmark.warmup / runs) at
world.resolution at the params scale, on the GPU when there is one (train.device), else on
the CPU. For the compact models it also exports the untrained network to a temporary ONNX
file and measures ONNX Runtime's batch-1 CPU latency beside PyTorch's (keys ``onnx_*``;
``onnx_speedup`` = PyTorch CPU latency / ONNX Runtime latency, both on the CPU with the same
threads; on a GPU machine PyTorch's CPU latency is measured for it as ``pytorch_cpu_latency_ms``);
``--no-onnx`` skips that. Writes results/benchmark/efficiency.json atomically.
"""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

import torch

from compact_perception.core import io
from compact_perception.core.catalog import dataset_ids, group_of, model_ids, sim_dataset_ids
from compact_perception.core.determinism import apply_policy
from compact_perception.core.errors import os_error_line
from compact_perception.learning.models import DATASET_SPECS, build_model
from compact_perception.evaluation.efficiency import (CPU_MEMORY_METHOD, CUDA_MEMORY_METHOD, device_name,
                                                   dummy_batch, measure_fps, measure_model, measure_onnx)

from compact_perception.evaluation.timing import table3_inference

from ._common import stage, start

log = logging.getLogger("pipeline.benchmark")


@stage
def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--params", default="params.yaml")
    # Table III: one simulated set stands for all (the same networks), and nuScenes (other class counts)
    default = [sim_dataset_ids()[0], *(d for d in dataset_ids() if d not in sim_dataset_ids())]
    ap.add_argument("--datasets", nargs="+", default=default, choices=dataset_ids())
    ap.add_argument("--models", nargs="+", default=None, choices=list(model_ids()),
                    help="default: params model_ids (in the registry's order)")
    ap.add_argument("--out", default="results/benchmark/efficiency.json")
    ap.add_argument("--no-onnx", action="store_true", help="skip the ONNX Runtime figures of the compact models")
    args = ap.parse_args(argv)
    params = start(args.params)
    models = args.models or [m for m in model_ids() if m in params.model_ids]  # the registry's order, as before
    pref = params.train.device
    if pref == "cuda" and not torch.cuda.is_available():
        raise SystemExit("error: params train.device is 'cuda' but no CUDA device is available")
    device = torch.device("cuda" if pref != "cpu" and torch.cuda.is_available() else "cpu")
    apply_policy(device, params.train)  # "eager fp32" is fp32, not TF32, as in training (docs/gpu.md)
    torch.manual_seed(params.seed)
    S = params.resolution
    bp = params.benchmark
    out: dict = {
        "device": device_name(device), "is_gpu": device.type == "cuda", "resolution": S, "scale": params.scale,
        "batch_size": 1, "warmup": bp.warmup, "runs": bp.runs, "torch": torch.__version__,
        "memory_method": CUDA_MEMORY_METHOD if device.type == "cuda" else CPU_MEMORY_METHOD, "models": {},
    }
    try:  # the ONNX export's temporary file, the output: a full disk or read-only folder is one line
        for ds in args.datasets:
            spec = DATASET_SPECS[ds]
            out["models"][ds] = {}
            for m in models:
                model = build_model(m, ds)
                batch = dummy_batch(model, n_seg=spec.n_seg, has_dvs=spec.has_dvs, resolution=S,
                                    n_views=spec.n_views, device=device, seed=params.seed)
                res = measure_model(model, batch, device, bp.warmup, bp.runs)
                if device.type == "cuda":  # Table III at the hardware's pace, eager fp32 (above) beside it
                    res["hardware_pace"] = table3_inference(model, batch, device, bp.warmup, bp.runs)
                if group_of(m).onnx and not args.no_onnx:
                    cpu_ms = res["latency_ms"]
                    if device.type != "cpu":  # the ratio compares the two runtimes on the same CPU
                        cpu_model, cpu_batch = model.to("cpu"), {k: v.cpu() for k, v in batch.items()}
                        cpu_ms = measure_fps(cpu_model, cpu_batch, "cpu", bp.warmup, bp.runs)["latency_ms"]
                        res["pytorch_cpu_latency_ms"] = cpu_ms
                    res.update(measure_onnx(model, batch, bp.warmup, bp.runs, pytorch_cpu_latency_ms=cpu_ms))
                out["models"][ds][m] = res
                del model, batch
                if device.type == "cuda":
                    torch.cuda.empty_cache()
        io.write_json(Path(args.out), out)
    except OSError as err:
        raise SystemExit(f"error: {os_error_line(err, args.out)}") from None
    log.info("wrote %s", args.out)


if __name__ == "__main__":
    main()
