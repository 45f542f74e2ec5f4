"""Three costs of the default run that the code shapes, each measured in one run here:

1. DVC's dvc.lock rewrite after every stage: DVC loads the whole lock with ruamel.yaml's
   round-trip (pure-Python) loader and dumps it again (``dvc.utils.serialize.modify_yaml``), so
   its cost grows with the lock's length; the shared modules are two dependencies
   (``core/``, ``training/``) to keep it short.
2. Adam's update on the GradNorm SegNet's 118 M parameters: torch's fused kernel against the
   default per-tensor loop.
3. A training step of the study's single-task networks (the 15L layout built for one task)
   against the whole multi-task network.

    .venv/bin/python benchmarks/bench_run_costs.py [--lock dvc.lock] [--repeats 5]

Prints seconds or milliseconds per item and the ratios.
"""
from __future__ import annotations

import argparse
import io
import statistics
import sys
import time
from pathlib import Path

import torch
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_train import synthetic_batch  # noqa: E402

from compact_perception.learning.models import build_model  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from flags import Parser, count  # noqa: E402


def lock_rewrite_seconds(path: Path, repeats: int) -> tuple[int, float]:
    """(lines, median seconds of one round-trip load + dump of ``path``, as DVC does per stage)."""
    from ruamel.yaml import YAML

    text = path.read_text()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        yaml = YAML()
        data = yaml.load(text)
        yaml.dump(data, io.StringIO())
        times.append(time.perf_counter() - t0)
    return text.count("\n"), statistics.median(times)


def adam_step_ms(params: list[torch.nn.Parameter], fused: bool, repeats: int) -> float:
    opt = torch.optim.Adam(params, lr=1e-4, weight_decay=1e-4, fused=fused)
    opt.step()  # the state is created on the first step
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        opt.step()
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1e3


def train_step_ms(tasks: tuple[str, ...], repeats: int, batch: int = 6, size: int = 32) -> float:
    torch.manual_seed(0)
    model = build_model("compact_15l", "A", tasks).train()
    opt = torch.optim.SGD(model.parameters(), lr=0.01, momentum=0.9)
    b = synthetic_batch(model, "A", batch, size, "cpu", torch.float32)
    times = []
    for i in range(repeats + 2):
        t0 = time.perf_counter()
        opt.zero_grad(set_to_none=True)
        sum(model.compute_losses(model(b), b).values()).backward()
        opt.step()
        if i >= 2:  # two warm-up steps
            times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1e3


def main() -> None:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--lock", type=Path, default=Path("dvc.lock"))
    ap.add_argument("--repeats", type=count(1, 1000), default=5)
    args = ap.parse_args()
    torch.set_num_threads(2)

    if args.lock.is_file():
        lines, sec = lock_rewrite_seconds(args.lock, max(1, args.repeats // 2))
        stages = len(yaml.safe_load(args.lock.read_text())["stages"])
        print(f"dvc.lock: {lines} lines, {stages} stages; one rewrite (ruamel round trip) {sec:.2f} s; "
              f"about {sec * stages / 60:.1f} min per full run")
    else:
        print(f"{args.lock}: no lock file (run `make repro` first); lock rewrite not measured")

    segnet = build_model("gradnorm_segnet", "A")
    g = torch.Generator().manual_seed(0)
    for p in segnet.parameters():
        p.grad = torch.randn(p.shape, generator=g)
    loop = adam_step_ms(list(segnet.parameters()), False, args.repeats)
    fused = adam_step_ms(list(segnet.parameters()), True, args.repeats)
    n = sum(p.numel() for p in segnet.parameters()) / 1e6
    print(f"Adam step on the GradNorm SegNet ({n:.0f} M parameters): per-tensor loop {loop:.0f} ms, fused {fused:.0f} ms")
    print(f"fused/loop Adam speed ratio: {loop / fused:.2f}")
    del segnet

    full = train_step_ms(("de", "ss", "ls", "bevp"), args.repeats)
    alone = {t: train_step_ms((t,), args.repeats) for t in ("de", "ss", "ls")}
    print(f"compact 15L training step, batch 6, 32 px: all four tasks {full:.0f} ms; "
          + "; ".join(f"{t} alone {ms:.0f} ms" for t, ms in alone.items()))
    print(f"single-task (DE) / multi-task training step time ratio: {alone['de'] / full:.2f}")


if __name__ == "__main__":
    main()
