"""Fast path (issue 15): training-step throughput of compact_15l_mgn in float32, the ``auto``
precision, bf16 autocast, channels-last, both, and torch.compile; and ONNX Runtime vs PyTorch
at batch 1. Every figure comes from this one run on this machine.

    .venv/bin/python benchmarks/bench_fastpath.py [--resolutions 64 128] [--batch 6] [--rounds 3]
        [--threads N] [--compile] [--full] [--no-onnx]

A training step is the training loop's: zero_grad, forward under the config's autocast and
memory format, losses on float32 outputs, the MGN hook of an ordinary step (no weight update;
the update happens once per epoch), scaled backward, SGD step. The configs are timed in
interleaved rounds (one step of each config per round, after one untimed warm-up step each), so
a change of the machine's load hits all of them alike; samples/s = batch / median step time.

To stay within a few minutes on a small CPU: where the CPU has no native bf16 (bf16 autocast is
emulated there, ~10-20x slower than float32), the bf16 configs run at the first resolution
only, with one timed step (``--full`` times them everywhere like the others); the compiled
config (``--compile``, float32 at the first resolution) is opt-in on a CPU, on by default on a
GPU (Inductor's first training step takes minutes on a 2-core CPU).

Prints samples/s per config and resolution, then

    fast path/float32 training ratio: X      (best of bf16 / channels-last / both, vs float32, first resolution)
    onnxruntime/pytorch batch-1 ratio: X     (compact_15l FPS, ONNX Runtime / PyTorch, CPU, same threads)
"""
from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from compact_perception.core.catalog import dataset_ids, model_ids
from compact_perception.core.params import load_params
from compact_perception.learning.models import build_model
from compact_perception.learning.training.precision import (autocast_context, batch_to_channels_last, cpu_has_native_bf16,
                                          float_outputs, make_grad_scaler, maybe_compile, resolve_precision,
                                          to_channels_last)
from compact_perception.learning.weighting import build_weighting

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_train import synthetic_batch  # noqa: E402
from flags import MAX_BATCH, MAX_WORKERS, Parser, count, frame_size  # noqa: E402


@dataclass
class Config:
    name: str
    precision: str = "fp32"
    channels_last: bool = False
    compile: bool = False
    rounds: int | None = None  # timed steps (None: --rounds)


class Stepper:
    """One model + optimiser + weighting trained with one config (the training loop's step)."""

    def __init__(self, cfg: Config, model_id: str, dataset_id: str, batch: int, size: int, device: torch.device) -> None:
        params = load_params()
        torch.manual_seed(0)
        self.cfg, self.device, self.batch = cfg, device, batch
        self.model = build_model(model_id, dataset_id).to(device).train()
        data = synthetic_batch(self.model, dataset_id, batch, size, device, torch.float32)
        if cfg.channels_last:
            to_channels_last(self.model)
            data = batch_to_channels_last(data)
        self.data = data
        self.weighting = build_weighting(params.train.models[model_id], self.model.tasks, self.model,
                                         plateau_patience=params.train.plateau_patience,
                                         plateau_factor=params.train.plateau_factor)
        self.opt = torch.optim.SGD(self.model.parameters(), lr=1e-3, momentum=0.9, weight_decay=1e-4)
        self.scaler = make_grad_scaler(device, cfg.precision)
        self.fwd = maybe_compile(self.model, cfg.compile)
        self.times: list[float] = []

    def step(self) -> float:
        if self.device.type == "cuda":
            torch.cuda.synchronize()
        t0 = time.perf_counter()
        self.opt.zero_grad(set_to_none=True)
        with autocast_context(self.device, self.cfg.precision):
            out = self.fwd(self.data)
        losses = self.model.compute_losses(float_outputs(out), self.data)
        self.weighting.grad_scale = self.scaler.get_scale() if self.scaler.is_enabled() else 1.0
        self.weighting.before_backward(1, 3, losses, self.model)  # an ordinary step of an epoch
        self.scaler.scale(self.weighting.total(losses)).backward()
        self.scaler.unscale_(self.opt)
        self.scaler.step(self.opt)
        self.scaler.update()
        if self.device.type == "cuda":
            torch.cuda.synchronize()
        return time.perf_counter() - t0

    def samples_per_s(self) -> float:
        return self.batch / statistics.median(self.times)


def train_figures(args: argparse.Namespace, device: torch.device, size: int, configs: list[Config]) -> dict[str, Any]:
    steppers = {c.name: Stepper(c, args.model, args.dataset, args.batch, size, device) for c in configs}
    first: dict[str, float] = {}
    for name, s in steppers.items():  # warm-up (and compilation) step, untimed
        first[name] = s.step()
    for k in range(args.rounds):
        for s in steppers.values():
            if s.cfg.rounds is None or k < s.cfg.rounds:
                s.times.append(s.step())
    out = {}
    for name, s in steppers.items():
        out[name] = {"samples_per_s": s.samples_per_s(), "first_step_s": first[name], "steps": len(s.times),
                     "compiled": bool(getattr(s.fwd, "compiled", False))}
    return out


def onnx_figures(args: argparse.Namespace) -> dict[str, float]:
    from compact_perception.learning.onnx_export import export_onnx, onnxruntime_latency
    from compact_perception.learning.models import DATASET_SPECS
    from compact_perception.evaluation.efficiency import dummy_batch, measure_fps

    spec = DATASET_SPECS[args.dataset]
    torch.manual_seed(0)
    model = build_model("compact_15l", args.dataset).eval()
    batch = dummy_batch(model, n_seg=spec.n_seg, has_dvs=spec.has_dvs, resolution=args.onnx_resolution)
    with tempfile.TemporaryDirectory() as tmp:
        info = export_onnx(model, batch, Path(tmp) / "compact_15l.onnx")
        # interleaved: PyTorch, ONNX Runtime, PyTorch, ... (the median of each)
        pt, ort = [], []
        for _ in range(args.onnx_rounds):
            pt.append(measure_fps(model, batch, "cpu", warmup=1, runs=3)["latency_ms"])
            ort.append(onnxruntime_latency(info["path"], batch, warmup=1, runs=3) * 1e3)  # type: ignore[operator]
    return {"pytorch_ms": statistics.median(pt), "onnxruntime_ms": statistics.median(ort),
            "max_abs_diff": info["max_abs_diff_all"], "onnxruntime": info["onnxruntime"]}


def main() -> None:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default="compact_15l_mgn", choices=model_ids())
    ap.add_argument("--dataset", default="A", choices=dataset_ids())
    ap.add_argument("--resolutions", type=frame_size(), nargs="+", default=[64, 128])
    ap.add_argument("--batch", type=count(1, MAX_BATCH), default=6)
    ap.add_argument("--rounds", type=count(1), default=3, help="timed steps per config (interleaved)")
    ap.add_argument("--threads", type=count(1, MAX_WORKERS), default=None, help="torch intra-op threads (default: torch's)")
    ap.add_argument("--compile", action=argparse.BooleanOptionalAction, default=None,
                    help="time the torch.compile config at the first resolution (default: on a GPU only)")
    ap.add_argument("--full", action="store_true", help="time emulated bf16 at every resolution, every round")
    ap.add_argument("--no-onnx", action="store_true")
    ap.add_argument("--onnx-resolution", type=frame_size(), default=128)
    ap.add_argument("--onnx-rounds", type=count(1), default=5)
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    t_start = time.perf_counter()
    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    auto = resolve_precision("auto", device)
    low = "bf16" if device.type == "cpu" or torch.cuda.is_bf16_supported(including_emulation=False) else "fp16"
    if device.type == "cuda":
        where = torch.cuda.get_device_name()
    else:
        where = (f"CPU {torch.backends.cpu.get_cpu_capability()}, native bf16: {cpu_has_native_bf16()}, "
                 f"{torch.get_num_threads()} threads (no GPU: CPU figures)")
    print(f"device: {where}; torch {torch.__version__}; {args.model} on {args.dataset}; batch {args.batch}; "
          f"{args.rounds} timed steps per config; auto -> {auto}")
    do_compile = args.compile if args.compile is not None else device.type == "cuda"
    emulated = device.type == "cpu" and not cpu_has_native_bf16() and not args.full
    ratios: dict[int, tuple[str, float]] = {}
    for i, size in enumerate(args.resolutions):
        configs = [Config("fp32"), Config("channels_last", channels_last=True)]
        if not emulated or i == 0:
            r = 1 if emulated else None
            configs += [Config(low, low, rounds=r), Config(f"{low}+channels_last", low, channels_last=True, rounds=r)]
        if auto not in ("fp32", low):
            configs.append(Config(f"auto ({auto})", auto))
        if do_compile and i == 0:
            configs.append(Config("compiled (fp32)", compile=True))
        res = train_figures(args, device, size, configs)
        base = res["fp32"]["samples_per_s"]
        print(f"\n{size}x{size} px")
        for name, r in res.items():
            extra = (f"  first step {r['first_step_s']:.1f} s, {r['steps']} timed"
                     + (" (compiled)" if r["compiled"] else " (eager fallback)" if "compiled" in name else "")
                     + (" (bf16 emulated: no native bf16)" if emulated and low in name else ""))
            print(f"  {name:<22s} {r['samples_per_s']:8.3f} samples/s  x{r['samples_per_s'] / base:5.2f}{extra}")
        if auto in ("fp32", low):
            print(f"  {'auto (' + auto + ')':<22s} = {auto} above")
        if emulated and i > 0:
            print(f"  {low}, {low}+channels_last: not timed at {size} px (emulated bf16; --full times them)")
        if not do_compile and i == 0:
            print("  compiled: not timed (--compile)")
        fast = {k: v["samples_per_s"] for k, v in res.items() if k in (low, "channels_last", f"{low}+channels_last")}
        best = max(fast, key=fast.get)  # type: ignore[arg-type]
        ratios[size] = (best, fast[best] / base)
        print(f"  fast path/float32 training ratio ({size} px): {fast[best] / base:.2f} (best: {best})")
    size0 = args.resolutions[0]
    print(f"\nfast path/float32 training ratio: {ratios[size0][1]:.2f}  ({ratios[size0][0]} vs fp32, {size0} px)")
    if not args.no_onnx:
        o = onnx_figures(args)
        print(f"compact_15l batch 1, {args.onnx_resolution} px, CPU {torch.get_num_threads()} threads: PyTorch "
              f"{o['pytorch_ms']:.1f} ms ({1e3 / o['pytorch_ms']:.2f} FPS), ONNX Runtime {o['onnxruntime']} "
              f"{o['onnxruntime_ms']:.1f} ms ({1e3 / o['onnxruntime_ms']:.2f} FPS); max |diff| {o['max_abs_diff']:.2e}")
        print(f"onnxruntime/pytorch batch-1 ratio: {o['pytorch_ms'] / o['onnxruntime_ms']:.2f}")
    print(f"(total {time.perf_counter() - t_start:.0f} s)")


if __name__ == "__main__":
    main()
