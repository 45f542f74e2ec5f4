"""How close to this CPU's limit a training step runs: FLOPs per sample of the project's
``train_step`` (forward, backward and the weighting's extra gradients) for each model, its
measured step time, the GFLOP/s that gives, and that against the machine's fp32 limit measured
in the same run (a large matrix product and a 3x3 convolution at the step's thread count).

    .venv/bin/python benchmarks/bench_step_flops.py [--models compact_15l gradnorm_segnet]
        [--size 32] [--batch 6] [--steps 5] [--threads 1]

The step is the training loop's own (``gpu_check.build_run``: the run as ``train._setup`` builds
it, on a synthetic cache of ``--size`` px), counted with ``torch.utils.flop_counter.FlopCounterMode``
and timed as the median of ``--steps`` steps after one warm-up. For a weighted run the FLOPs of its
weighting alone (GradNorm's per-task gradient norms) are the step's minus the same network's step
under static weights. ``--threads`` is ``train.num_threads`` (one per run at the default: the
pipeline trains runs side by side). Prints one table; nothing is written.
"""
from __future__ import annotations

import argparse
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
from compact_perception.learning.training.epoch import train_step  # noqa: E402
from flags import MAX_BATCH, MAX_WORKERS, Parser, count, frame_size  # noqa: E402

from gpu_check import build_run, one_batch, params_for  # noqa: E402  (the run as the loop sets it up)


def _static(params, model_id: str):
    """``params`` with ``model_id``'s weighting replaced by static weights (its network and loss kept)."""
    recipe = params.train.models[model_id].model_copy(update={"weighting": "static"})
    train = params.train.model_copy(update={"models": {**params.train.models, model_id: recipe}})
    return params.model_copy(update={"train": train})


def step_cost(params, model_id: str, cache: Path, batch: int, steps: int) -> tuple[float, float]:
    """(FLOPs per sample of one training step, median seconds per step)."""
    with tempfile.TemporaryDirectory() as tmp:
        run = build_run(params, model_id, torch.device("cpu"), cache, Path(tmp))
        data = one_batch(cache, model_id, batch)
        train_step(run, data, 0, steps + 3)                       # warm-up (and a first weighting step)
        with FlopCounterMode(display=False) as counter:
            train_step(run, data, 1, steps + 3)
        times = []
        for s in range(steps):
            t0 = time.perf_counter()
            train_step(run, data, s + 2, steps + 3)
            times.append(time.perf_counter() - t0)
    return counter.get_total_flops() / batch, statistics.median(times)


def machine_limit(repeats: int = 5) -> dict[str, float]:
    """This CPU's attainable fp32 GFLOP/s at the current thread count: a 1024^3 matrix product and
    a 3x3 convolution of 64 to 64 channels at 64x64 px, batch 6 (best of ``repeats``)."""
    g = torch.Generator().manual_seed(0)
    a, b = torch.rand(1024, 1024, generator=g), torch.rand(1024, 1024, generator=g)
    x, w = torch.rand(6, 64, 64, 64, generator=g), torch.rand(64, 64, 3, 3, generator=g)
    out = {}
    for name, fn, flops in (("matmul", lambda: a @ b, 2 * 1024 ** 3),
                            ("conv3x3", lambda: torch.nn.functional.conv2d(x, w, padding=1),
                             2 * 6 * 64 * 64 * 64 * 64 * 9)):
        fn()
        best = min(_timed(fn) for _ in range(repeats))
        out[name] = flops / best / 1e9
    return out


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> None:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--models", nargs="+", default=["compact_15l", "gradnorm_segnet"], choices=catalog.model_ids())
    ap.add_argument("--size", type=frame_size(32), default=32, help="frame size (px); the default's and full's: 32")
    ap.add_argument("--batch", type=count(1, MAX_BATCH), default=6)
    ap.add_argument("--steps", type=count(1, 1000), default=5, help="timed steps per model")
    ap.add_argument("--threads", type=count(1, MAX_WORKERS), default=1, help="torch threads (train.num_threads)")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    params = params_for(torch.device("cpu"), "fp32", args.batch)
    from tests.synthetic import make_cache

    with tempfile.TemporaryDirectory(prefix="bench_step_flops_") as tmp:
        cache = make_cache(Path(tmp) / "cache", "A", size=args.size, counts=(max(args.batch, 6), 1, 1))
        limit = machine_limit()
        rows = []
        for m in args.models:
            flops, seconds = step_cost(params, m, cache, args.batch, args.steps)
            extra = None
            if params.train.models[m].weighting not in ("static", "none"):
                extra = flops - step_cost(_static(params, m), m, cache, args.batch, 1)[0]
            rows.append((m, flops, seconds, extra))
    print(f"fp32, {args.threads} thread(s), batch {args.batch}, {args.size} px; this CPU's limit: "
          f"matmul {limit['matmul']:.1f} GFLOP/s, 3x3 convolution {limit['conv3x3']:.1f} GFLOP/s")
    print(f"{'model':<26s} {'GFLOP/sample':>13s} {'of it weighting':>16s} {'s/step':>8s} {'GFLOP/s':>8s} "
          f"{'% of matmul':>12s} {'% of conv':>10s}")
    for m, flops, seconds, extra in rows:
        rate = flops * args.batch / seconds / 1e9
        print(f"{m:<26s} {flops / 1e9:13.3f} {'-' if extra is None else f'{extra / 1e9:.3f}':>16s} {seconds:8.3f} "
              f"{rate:8.1f} {rate / limit['matmul']:12.0%} {rate / limit['conv3x3']:10.0%}")
    base = next((r for r in rows if r[0] == "compact_15l"), None)
    for m, flops, seconds, _ in rows:
        if base is not None and m != base[0]:
            print(f"{m} against compact_15l: {flops / base[1]:.1f}x the FLOPs per sample, "
                  f"{seconds / base[2]:.1f}x the time per step")


if __name__ == "__main__":
    main()
