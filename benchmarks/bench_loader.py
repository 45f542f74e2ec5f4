"""Training-loader throughput beside what the training step demands, on this CPU and on a GPU.

    .venv/bin/python benchmarks/bench_loader.py [--cache DIR] [--frames 240] [--size 128]
        [--workers 0,2,4] [--gpu-tflops 100] [--util 0.4] [--quick]

It measures the training loader (:func:`compact_perception.data.loader.make_loader`, batch 6, shuffled,
as a training run opens it) in samples/s over one epoch of a cache at 128 px (built from
tests/synthetic.py's ``make_cache`` unless ``--cache`` names one), with 0, 2 and 4 worker
processes and pinned memory off and on (pinning needs CUDA; without it torch leaves it off), beside

(a) the demand of compact_15l's training step on this CPU (the project's train_step, batch 6:
    batch / median step time), and
(b) the demand of a GPU: the step's FLOPs (``torch.utils.flop_counter.FlopCounterMode`` over one
    training step, forward and backward) against ``--gpu-tflops`` at ``--util`` utilisation:
    samples/s = tflops x 1e12 x util / FLOPs per sample.

It ends with the verdict "loader keeps up / does not (by N x), limited by ...". ``--quick`` (the
test): 4 batches per loader setting, workers 0 and 2, one timed step.
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import torch  # noqa: E402
from torch.utils.flop_counter import FlopCounterMode  # noqa: E402

from compact_perception.core import catalog  # noqa: E402
from compact_perception.core.cache import read_meta  # noqa: E402
from compact_perception.data.loader import make_loader  # noqa: E402
from compact_perception.learning.training.epoch import train_step  # noqa: E402
from flags import MAX_BATCH, MAX_WORKERS, Parser, count, frame_size, number  # noqa: E402

from gpu_check import build_run, one_batch, params_for  # noqa: E402  (the run as the loop sets it up)


def loader_rate(cache: Path, channels: int, batch: int, workers: int, pin: bool, max_batches: int | None) -> tuple[float, float]:
    """(samples/s after the first batch, seconds to the first batch: worker start-up included)."""
    loader = make_loader(cache, "train", channels, batch, shuffle=True, seed=0, num_workers=workers,
                         drop_last=True, pin_memory=pin)
    t0 = time.perf_counter()
    it = iter(loader)
    next(it)
    t1 = time.perf_counter()
    n = 0
    for i, b in enumerate(it):
        n += next(iter(b.values())).shape[0]
        if max_batches is not None and i + 2 >= max_batches:
            break
    t2 = time.perf_counter()
    del it, loader
    return (n / (t2 - t1) if n else float("nan")), t1 - t0


def step_demand(cache: Path, model_id: str, batch: int, steps: int) -> tuple[float, float]:
    """(samples/s one CPU training step consumes, FLOPs per sample of one training step)."""
    device = torch.device("cpu")
    params = params_for(device, "fp32", batch)
    with tempfile.TemporaryDirectory() as tmp:
        run = build_run(params, model_id, device, cache, Path(tmp))
        data = one_batch(cache, model_id, batch)
        with FlopCounterMode(display=False) as counter:
            train_step(run, data, 0, steps + 2)
        flops = counter.get_total_flops()
        times = []
        for s in range(steps):
            t0 = time.perf_counter()
            train_step(run, data, s + 1, steps + 2)
            times.append(time.perf_counter() - t0)
    return batch / statistics.median(times), flops / batch


def main() -> None:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache", type=Path, default=None, help="an existing cache (default: build a synthetic one)")
    ap.add_argument("--frames", type=count(1), default=240, help="training frames of the synthetic cache")
    ap.add_argument("--size", type=frame_size(16), default=128, help="frame size of the synthetic cache (px)")
    ap.add_argument("--batch", type=count(1, MAX_BATCH), default=6)
    ap.add_argument("--workers", default="0,2,4", help="comma-separated loader worker counts")
    ap.add_argument("--model", default="compact_15l", choices=catalog.model_ids())
    ap.add_argument("--steps", type=count(1), default=3, help="timed training steps on this CPU")
    ap.add_argument("--gpu-tflops", type=number(0, 1e5), default=100.0,
                    help="effective GPU throughput in TFLOP/s (default 100: bf16 dense on an H100-class GPU, "
                         "a conservative share of its ~990 peak)")
    ap.add_argument("--util", type=number(0, 1), default=0.4, help="utilisation of --gpu-tflops the step reaches")
    ap.add_argument("--quick", action="store_true", help="4 batches per setting, workers 0,2, one step (the test)")
    args = ap.parse_args()
    try:
        workers = [int(w) for w in args.workers.split(",")]
    except ValueError:
        sys.exit(f"error: --workers: expected comma-separated integers, got {args.workers!r}")
    if not workers or any(not 0 <= w <= MAX_WORKERS for w in workers):
        sys.exit(f"error: --workers: expected comma-separated counts from 0 to {MAX_WORKERS}, got {args.workers!r}")
    if args.cache is not None and not (args.cache / "train").is_dir():
        sys.exit(f"error: --cache {args.cache}: no train/ split (expected a cache as docs/data-formats.md describes)")
    max_batches, steps = (4, 1) if args.quick else (None, args.steps)
    if args.quick and args.workers == "0,2,4":
        workers = [0, 2]
    torch.set_num_threads(max(1, torch.get_num_threads()))
    with tempfile.TemporaryDirectory(prefix="bench_loader_") as tmp:
        cache = args.cache
        if cache is None:
            from tests.synthetic import make_cache

            t0 = time.perf_counter()
            cache = make_cache(Path(tmp) / "cache", "A", size=args.size, counts=(args.frames, 1, 1))
            print(f"built a synthetic cache: {args.frames} training frames at {args.size} px "
                  f"({time.perf_counter() - t0:.1f} s)")
        meta = read_meta(cache)
        n_train = meta.get("counts", {}).get("train", "?")
        cuda = torch.cuda.is_available()
        print(f"cache {cache} ({n_train} training frames, {meta.get('resolution')} px); "
              f"CPU cores {os.cpu_count()}, torch threads {torch.get_num_threads()}, CUDA {'yes' if cuda else 'no'}")
        channels = catalog.MODELS[args.model].lidar_channels
        rows = []
        for w in workers:
            for pin in (False, True):
                rate, first = loader_rate(cache, channels, args.batch, w, pin and cuda, max_batches)
                note = "" if (cuda or not pin) else " (no CUDA: pinning off)"
                rows.append((w, pin, rate, first, note))
        cpu_rate, flops_per_sample = step_demand(cache, args.model, args.batch, steps)
    gpu_rate = args.gpu_tflops * 1e12 * args.util / flops_per_sample
    print(f"\n{'loader setting':<28s} {'samples/s':>10s} {'first batch s':>14s}")
    for w, pin, rate, first, note in rows:
        print(f"{f'workers {w}, pin_memory {pin}':<28s} {rate:10.1f} {first:14.2f}{note}")
    best = max(rows, key=lambda r: r[2])
    print(f"\n{args.model} training step, batch {args.batch}, {meta.get('resolution')} px:")
    print(f"  FLOPs per sample (forward+backward): {flops_per_sample / 1e9:.2f} GFLOP")
    print(f"  (a) demand on this CPU:  {cpu_rate:10.1f} samples/s (median of {steps} step(s))")
    print(f"  (b) demand of a GPU:     {gpu_rate:10.1f} samples/s ({args.gpu_tflops:g} TFLOP/s x {args.util:.0%} "
          "utilisation)")
    print(f"  best loader:             {best[2]:10.1f} samples/s (workers {best[0]}, pin_memory {best[1]})")
    for label, demand in (("this CPU's step", cpu_rate), ("the GPU's step", gpu_rate)):
        ratio = best[2] / demand
        if ratio >= 1:
            print(f"verdict vs {label}: loader keeps up (by {ratio:.1f}x), limited by the training step")
        else:
            print(f"verdict vs {label}: loader does not keep up (by {1 / ratio:.1f}x), limited by the loader "
                  f"(reading and converting frames on {os.cpu_count()} CPU cores, best at {best[0]} workers)")


if __name__ == "__main__":
    main()
