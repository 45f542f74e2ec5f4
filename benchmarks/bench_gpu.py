"""GPU benchmark path (issue 15): batch-1 inference of a model with device synchronisation,
warm-up, bf16/fp16 autocast, channels-last and CUDA graphs (optionally torch.compile).

    .venv/bin/python benchmarks/bench_gpu.py [--model compact_15l] [--dataset A] [--resolution 128]
        [--warmup 10] [--runs 50] [--compile] [--fold-bn] [--device auto|cpu|cuda]

On a CUDA device it times float32, fp16 and (where supported) bf16 autocast, the fastest
precision with channels-last, CUDA graphs of float32 and of the fastest precision, and batch
normalisation folded into the convolutions (float32, with and without a CUDA graph). On a
machine without a GPU the same code path runs on the CPU (float32, bf16 autocast,
channels-last; CUDA graphs need CUDA and are skipped) and the output says "no GPU: CPU figures".
Timing: :func:`compact_perception.evaluation.timing.benchmark_variants` (warm-up calls untimed, the device
synchronised before and after every timed call, median latency); each variant's outputs are
compared with float32 eager (max abs difference). The determinism and precision policy is
params.yaml's (``train.tf32``, ``train.deterministic``), as in every stage: "fp32" is float32, not TF32.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

from compact_perception.core.catalog import dataset_ids, model_ids
from compact_perception.core.params import load_params
from compact_perception.core.determinism import apply_policy
from compact_perception.learning.models import DATASET_SPECS, build_model
from compact_perception.learning.training.precision import cpu_has_native_bf16
from compact_perception.evaluation.efficiency import device_name, dummy_batch
from compact_perception.evaluation.timing import Variant, benchmark_variants, default_variants

sys.path.insert(0, str(Path(__file__).resolve().parent))
from flags import MAX_WORKERS, Parser, count, frame_size  # noqa: E402


def main() -> None:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default="compact_15l", choices=model_ids())
    ap.add_argument("--dataset", default="A", choices=dataset_ids())
    ap.add_argument("--resolution", type=frame_size(), default=128)
    ap.add_argument("--warmup", type=count(0), default=10)
    ap.add_argument("--runs", type=count(1), default=50)
    ap.add_argument("--compile", action="store_true", help="add torch.compile variants")
    ap.add_argument("--fold-bn", action="store_true",
                    help="on a CPU, add batch norm folded into the convolutions (a GPU's list has it)")
    ap.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"])
    ap.add_argument("--threads", type=count(1, MAX_WORKERS), default=None, help="torch intra-op threads on a CPU")
    ap.add_argument("--json", default=None, help="also write the results to this JSON file")
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    if args.device == "cuda" and not torch.cuda.is_available():
        raise SystemExit("error: --device cuda but no CUDA device is available")
    device = torch.device("cuda" if args.device != "cpu" and torch.cuda.is_available() else "cpu")
    train = load_params(Path(__file__).resolve().parents[1] / "params.yaml").train
    apply_policy(device, train)  # the stages' policy: "fp32" is fp32 unless train.tf32 (docs/gpu.md)
    spec = DATASET_SPECS[args.dataset]
    torch.manual_seed(0)
    model = build_model(args.model, args.dataset).eval()
    batch = dummy_batch(model, n_seg=spec.n_seg, has_dvs=spec.has_dvs, resolution=args.resolution, device=device)
    variants = default_variants(device)
    if args.compile:
        best = variants[-1].precision if device.type == "cuda" else "fp32"
        variants += [Variant("fp32+compile", compile=True), Variant(f"{best}+compile", best, compile=True)]
    if args.fold_bn and device.type == "cpu":
        variants += [Variant("fp32+fold_bn", fold_bn=True),
                     Variant("channels_last+fold_bn", channels_last=True, fold_bn=True)]
    if device.type == "cpu":
        print(f"no GPU: CPU figures ({device_name(device)}, {torch.backends.cpu.get_cpu_capability()}, "
              f"native bf16: {cpu_has_native_bf16()})")
    else:
        print(f"GPU: {device_name(device)} (compute capability {'.'.join(map(str, torch.cuda.get_device_capability()))})")
    print(f"{args.model} on {args.dataset}, batch 1, {args.resolution}x{args.resolution} px, "
          f"{args.warmup} warm-up + median of {args.runs} runs, torch {torch.__version__}, params.yaml's "
          f"train.tf32 {str(train.tf32).lower()}, train.deterministic {str(train.deterministic).lower()}")
    t0 = time.perf_counter()
    results = benchmark_variants(model, batch, device, variants, args.warmup, args.runs)
    print(f"  {'variant':<34s} {'latency ms':>10s} {'FPS':>9s} {'vs fp32':>8s} {'max|diff|':>10s}")
    for r in results:
        if "error" in r:
            print(f"  {r['name']:<34s} failed: {r['error']}")
            continue
        note = " " + r["note"] if r.get("note") else ""
        if r.get("compile") and not r.get("compiled"):
            note += " (torch.compile unavailable: eager)"
        print(f"  {r['name']:<34s} {r['latency_ms']:10.2f} {r['fps']:9.2f} {r.get('speedup', float('nan')):7.2f}x "
              f"{r['max_abs_diff']:10.2e}{note}")
    ok = [r for r in results if "fps" in r and r["name"] != "fp32"]
    if ok:
        best_r = max(ok, key=lambda r: r["fps"])
        print(f"fastest/float32 batch-1 ratio: {best_r.get('speedup', float('nan')):.2f} ({best_r['name']})")
    print(f"(total {time.perf_counter() - t0:.0f} s)")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"device": device_name(device), "is_gpu": device.type == "cuda", "results": results}, fh, indent=1)


if __name__ == "__main__":
    main()
