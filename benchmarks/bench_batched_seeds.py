"""Several seeds of one model trained as one batched network (torch.func) against separate runs,
and against a compiled step: which gives fewer, larger kernels per sample.

    .venv/bin/python benchmarks/bench_batched_seeds.py [--model compact_15l] [--k 1 4 12] [--batch 6]
        [--size 32] [--steps 5] [--compile]

A GPU that shares one GPU among k processes time-slices their kernels; what a launch-bound step
needs is fewer launches per sample. Two ways to get them:

- **batched seeds**: k runs of one model (each its own initial weights, batch-norm statistics and
  dropout masks) stacked into one network with ``torch.func.stack_module_state`` and stepped with
  ``vmap(grad_and_value(loss))``: each op runs once for the k runs, on k times the data, and one
  SGD update (foreach) covers every run's tensors;
- **a compiled step**: ``torch.compile`` of the network (inductor fuses elementwise chains).

Each mode takes ``--steps`` timed steps of one training step (forward, the sum of the task
losses, backward, SGD with momentum; static weights: the loss weightings are not vmapped) on one
synthetic batch, after two warm-up steps. Printed per k: aten ops per step and per sample (the
census, :mod:`compact_perception.learning.training.census`; about one kernel launch each on a
GPU), samples/s, and, with dropout off, how far run i of the batched network is from the same
run stepped alone (its outputs, one step's gradients and batch-norm statistics: the batched
kernels sum in another order, so a batched run is not the bytes of a run alone). ``--compile``
adds the compiled step's samples/s and its compile time (its fused kernels are not aten ops, so
no census).
"""
from __future__ import annotations

import argparse
import copy
import sys
import time
from pathlib import Path

import torch
from torch import nn

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_train import synthetic_batch  # noqa: E402
from flags import MAX_BATCH, Parser, count, frame_size  # noqa: E402

from compact_perception.core.catalog import model_ids  # noqa: E402
from compact_perception.learning.models import build_model  # noqa: E402
from compact_perception.learning.training.census import Census  # noqa: E402

LR, MOMENTUM = 0.01, 0.9


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def make_models(model_id: str, k: int, device: torch.device, dropout: bool = True) -> list[nn.Module]:
    """k networks, seeds 0..k-1 (each its own initial weights), in training mode."""
    out = []
    for seed in range(k):
        torch.manual_seed(seed)
        m = build_model(model_id, "A").to(device).train()
        if not dropout:
            for mod in m.modules():
                if isinstance(mod, nn.Dropout):
                    mod.p = 0.0
        out.append(m)
    return out


def total_loss(model: nn.Module, out: dict, batch: dict) -> torch.Tensor:
    return sum(model.compute_losses(out, batch).values())


class Separate:
    """k runs stepped one after the other, each its own SGD (foreach)."""

    def __init__(self, models: list[nn.Module]) -> None:
        self.models = models
        self.opts = [torch.optim.SGD(m.parameters(), lr=LR, momentum=MOMENTUM, foreach=True) for m in models]

    def step(self, batch: dict) -> None:
        for m, opt in zip(self.models, self.opts):
            opt.zero_grad(set_to_none=True)
            total_loss(m, m(batch), batch).backward()
            opt.step()


class Batched:
    """The k runs as one network: stacked parameters and buffers, one vmapped gradient, one SGD."""

    def __init__(self, models: list[nn.Module]) -> None:
        from torch.func import functional_call, grad_and_value, stack_module_state, vmap

        self.template = models[0]
        base = copy.deepcopy(models[0]).to("meta")
        params, self.buffers = stack_module_state(models)
        self.names = list(params)
        self.params = [params[n] for n in self.names]
        self.opt = torch.optim.SGD(self.params, lr=LR, momentum=MOMENTUM, foreach=True)

        def forward(p: dict, b: dict, batch: dict) -> dict:
            return functional_call(base, (p, b), (batch,))

        def loss(p: dict, b: dict, batch: dict) -> torch.Tensor:
            return total_loss(self.template, forward(p, b, batch), batch)

        self.forward = vmap(forward, in_dims=(0, 0, None), randomness="different")
        self.grad = vmap(grad_and_value(loss), in_dims=(0, 0, None), randomness="different")

    def _stacked(self) -> dict:
        return {n: p.detach() for n, p in zip(self.names, self.params)}

    def outputs(self, batch: dict) -> dict:
        """Every run's outputs (stacked on a new first dimension), without a gradient."""
        with torch.no_grad():
            return self.forward(self._stacked(), self.buffers, batch)

    def gradients(self, batch: dict) -> dict:
        g, _ = self.grad(self._stacked(), self.buffers, batch)
        return g

    def step(self, batch: dict) -> None:
        g = self.gradients(batch)
        for n, p in zip(self.names, self.params):
            p.grad = g[n]
        self.opt.step()


def census_and_rate(runner, batch: dict, samples: int, steps: int, device: torch.device) -> tuple[int, float]:
    """(aten ops of one step, samples/s over ``steps`` steps after two warm-up steps)."""
    for _ in range(2):
        runner.step(batch)
    with Census(device) as c:
        runner.step(batch)
    _sync(device)
    t0 = time.perf_counter()
    for _ in range(steps):
        runner.step(batch)
    _sync(device)
    return c.ops, samples * steps / (time.perf_counter() - t0)


def distance(model_id: str, k: int, batch: dict, device: torch.device) -> tuple[float, float, float]:
    """Largest |difference| between run i of the batched network and run i alone, dropout off:
    (the outputs, relative to their largest value; one step's gradients, relative to their largest;
    the batch-norm running statistics after that step). The outputs differ by rounding (the
    batched kernels sum in another order); the gradients by more where a sigmoid output is near 1:
    the losses' gradients there scale with 1 / (1 - p)."""
    alone = make_models(model_id, k, device, dropout=False)
    outs, grads, stats = [], [], []
    for m in alone:
        out = m(batch)
        outs.append({t: v.detach() for t, v in out.items()})
        total_loss(m, out, batch).backward()
        grads.append({n: p.grad for n, p in m.named_parameters()})
        stats.append({n: b for n, b in m.named_buffers() if b.is_floating_point()})
    top = max(float(v.abs().max()) for d in outs for v in d.values())
    # a copy of its own: the forward moves its batch-norm statistics
    o = Batched(make_models(model_id, k, device, dropout=False)).outputs(batch)
    do = max(float((o[t][i] - outs[i][t]).abs().max()) for i in range(k) for t in outs[i]) / top
    batched = Batched(make_models(model_id, k, device, dropout=False))
    g = batched.gradients(batch)
    scale = max(float(t.abs().max()) for d in grads for t in d.values())
    dg = max(float((g[n][i] - grads[i][n]).abs().max()) for i in range(k) for n in grads[i]) / scale
    ds = max(float((batched.buffers[n][i] - stats[i][n]).abs().max()) for i in range(k) for n in stats[i])
    return do, dg, ds


def compiled_rate(model_id: str, batch: dict, samples: int, steps: int, device: torch.device) -> tuple[float, float]:
    """(compile seconds of the first two steps, samples/s after them) of one compiled run."""
    model = make_models(model_id, 1, device)[0]
    forward = torch.compile(model)
    opt = torch.optim.SGD(model.parameters(), lr=LR, momentum=MOMENTUM, foreach=True)

    def step() -> None:
        opt.zero_grad(set_to_none=True)
        total_loss(model, forward(batch), batch).backward()
        opt.step()

    t0 = time.perf_counter()
    for _ in range(2):
        step()
    _sync(device)
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    for _ in range(steps):
        step()
    _sync(device)
    return first, samples * steps / (time.perf_counter() - t0)


def main() -> None:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default="compact_15l", choices=model_ids())
    ap.add_argument("--k", type=count(1, 64), nargs="+", default=[1, 4, 12], help="runs (seeds) stepped together")
    ap.add_argument("--batch", type=count(1, MAX_BATCH), default=6)
    ap.add_argument("--size", type=frame_size(16), default=32)
    ap.add_argument("--steps", type=count(1), default=5, help="timed steps per mode")
    ap.add_argument("--compile", action="store_true", help="also time a torch.compile'd step (slow to compile)")
    args = ap.parse_args()
    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    where = torch.cuda.get_device_name() if device.type == "cuda" else f"CPU, {torch.get_num_threads()} threads"
    print(f"device: {where}; torch {torch.__version__}; {args.model}, fp32, {args.size} px, batch {args.batch} a run")
    batch = synthetic_batch(build_model(args.model, "A"), "A", args.batch, args.size, device, torch.float32)
    print(f"{'k':>3s} {'mode':<9s} {'ops/step':>9s} {'ops/sample':>11s} {'samples/s':>10s}")
    for k in args.k:
        samples = k * args.batch
        for name, runner in (("separate", Separate(make_models(args.model, k, device))),
                             ("batched", Batched(make_models(args.model, k, device)))):
            ops, rate = census_and_rate(runner, batch, samples, args.steps, device)
            print(f"{k:3d} {name:<9s} {ops:9d} {ops / samples:11.1f} {rate:10.1f}", flush=True)
        do, dg, ds = distance(args.model, k, batch, device)
        print(f"    run i batched against alone (dropout off): outputs {do:.1e} of their largest, gradients "
              f"{dg:.1e} of theirs, batch-norm statistics {ds:.1e}", flush=True)
    if args.compile:
        first, rate = compiled_rate(args.model, batch, args.batch, args.steps, device)
        print(f"  1 compiled  first two steps {first:.1f} s, then {rate:.1f} samples/s", flush=True)


if __name__ == "__main__":
    main()
