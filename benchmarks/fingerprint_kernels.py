"""Which kernel makes two machines disagree? A per-layer fingerprint of one training step.

    .venv/bin/python benchmarks/fingerprint_kernels.py [--cache data/cache/A] \
        [--models compact_15l polarnet gradnorm_segnet] [--out /tmp/fp.json] \
        [--compare benchmarks/fingerprints/intel_xeon_2core.json]

With the numeric libraries pinned exactly as every stage pins them
(``determinism.pin_numeric_libraries``, ``train.num_threads`` from params.yaml), one training
batch of the cache (the first of the unshuffled train split, ``train.batch_size`` frames) goes
through each model: the SHA-256 of every leaf module's forward output (in call order), of every
parameter's gradient after ``backward`` of the summed task losses, and, for the models with
shared layers, of every gradient after a second-order step (the norm of the first shared
layer's gradient, taken with ``create_graph=True``, backpropagated: what MGN's authors' form
and GradNorm do). ``--compare`` prints, per model and phase, the first entry whose hash differs
from a fingerprint recorded on another machine, and how many differ.

Why: the committed results differ between a 2-core AMD EPYC (AVX2) and a 2-core Intel Xeon
(AVX-512, pinned to AVX2) for the 15L+MGN authors' form, GradNorm SegNet and PolarNet runs,
while the other models' runs are byte-identical (README "Reproducibility"). A fingerprint from
each machine names the first layer where they part. ``benchmarks/fingerprints/`` holds the ones
recorded so far (the cache bytes are machine-independent: the data stages' hashes agree).
"""
from __future__ import annotations

from compact_perception.core.determinism import pin_numeric_libraries

pin_numeric_libraries()  # before numpy/torch run anything, as every stage does

import argparse  # noqa: E402
import hashlib  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
from pathlib import Path  # noqa: E402

import torch  # noqa: E402
from torch import Tensor, nn  # noqa: E402

from compact_perception.core.config import load_params  # noqa: E402
from compact_perception.data import make_loader, to_device  # noqa: E402
from compact_perception.core.determinism import set_threads  # noqa: E402
from compact_perception.models import DATASETS, build_model, lidar_channels  # noqa: E402


def _hash(t: Tensor) -> str:
    return hashlib.sha256(t.detach().contiguous().cpu().numpy().tobytes()).hexdigest()[:16]


def _cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def fingerprint(model: nn.Module, batch: dict[str, Tensor]) -> dict[str, dict[str, str]]:
    """Forward outputs, first-order and (with shared layers) second-order gradients, hashed."""
    forward: dict[str, str] = {}
    calls: dict[str, int] = {}

    def hook(name: str):
        def record(_mod: nn.Module, _inp: object, out: object) -> None:
            outs = out if isinstance(out, (tuple, list)) else [out]
            k = calls[name] = calls.get(name, -1) + 1
            for i, o in enumerate(outs):
                if isinstance(o, Tensor):
                    forward[f"{name}#{k}.{i}"] = _hash(o)
        return record

    handles = [m.register_forward_hook(hook(n)) for n, m in model.named_modules() if not list(m.children())]
    model.train()
    losses = model.compute_losses(model(batch), batch)
    for h in handles:
        h.remove()
    total = sum(losses.values())
    params = dict(model.named_parameters())
    grads = torch.autograd.grad(total, list(params.values()), retain_graph=True, allow_unused=True)
    first = {n: _hash(g) for (n, _), g in zip(params.items(), grads) if g is not None}
    out = {"forward": forward, "grad": first, "loss": {k: repr(float(v.detach())) for k, v in losses.items()}}
    shared = [name for names in model.shared_layers().values() for name in names]
    if shared:
        w = model.get_submodule(shared[0]).weight
        (g,) = torch.autograd.grad(total, [w], create_graph=True)
        grads2 = torch.autograd.grad(g.norm(), list(params.values()), allow_unused=True)
        out["grad2"] = {n: _hash(g2) for (n, _), g2 in zip(params.items(), grads2) if g2 is not None}
    return out


def compare(mine: dict, other: dict) -> None:
    print(f"this machine: {mine['cpu']}\nother:        {other['cpu']}")
    for model, phases in mine["models"].items():
        theirs = other["models"].get(model)
        if theirs is None:
            print(f"{model}: not in the other fingerprint")
            continue
        for phase, entries in phases.items():
            diff = [k for k, v in entries.items() if theirs.get(phase, {}).get(k) != v]
            where = f"first at {diff[0]}" if diff else "identical"
            print(f"{model:>16} {phase:>7}: {len(diff):4d} of {len(entries):4d} differ; {where}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cache", default="data/cache/A")
    ap.add_argument("--dataset", default="A", help="the dataset id of --cache (class counts)")
    ap.add_argument("--models", nargs="+", default=["compact_15l", "polarnet", "gradnorm_segnet", "chen_bev"])
    ap.add_argument("--out", type=Path, default=None, help="write the fingerprint as JSON here")
    ap.add_argument("--compare", type=Path, default=None, help="a fingerprint recorded on another machine")
    args = ap.parse_args()

    if not (Path(args.cache) / "meta.json").is_file():
        raise SystemExit(f"error: {args.cache}: no cache (meta.json) there; build it with "
                         f"`bin/venv dvc repro preprocess@{args.dataset}` or pass --cache")
    if args.compare and not args.compare.is_file():
        raise SystemExit(f"error: {args.compare}: file not found (a JSON written by --out)")
    params = load_params()
    set_threads(params.train.num_threads)
    result = {"cpu": _cpu_name(), "torch": torch.__version__, "threads": params.train.num_threads, "models": {}}
    for model_id in args.models:
        loader = make_loader(args.cache, "train", lidar_channels=lidar_channels(model_id),
                             batch_size=params.train.batch_size)
        batch = to_device(next(iter(loader)), "cpu", DATASETS[args.dataset].n_seg)
        torch.manual_seed(0)
        result["models"][model_id] = fingerprint(build_model(model_id, args.dataset), batch)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=1, sort_keys=True) + "\n")
    if args.compare:
        compare(result, json.loads(args.compare.read_text()))
    else:
        for model_id, phases in result["models"].items():
            print(model_id, {p: len(v) for p, v in phases.items()})


if __name__ == "__main__":
    main()
