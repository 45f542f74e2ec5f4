"""Training-step throughput: float32 vs float64 (the authors' code trains in float64),
measured in one run on the same machine, and automatic mixed precision on a GPU.

    .venv/bin/python benchmarks/bench_train.py [--model compact_15l_mgn] [--resolution 128]

Prints samples/s per precision and the float32/float64 ratio (target on a CPU: >= 2).
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from contextlib import nullcontext
from pathlib import Path

import torch

from compact_perception.core.catalog import dataset_ids, model_ids
from compact_perception.core.params import load_params
from compact_perception.learning.models import build_model
from compact_perception.learning.weighting import build_weighting

sys.path.insert(0, str(Path(__file__).resolve().parent))
from flags import MAX_BATCH, Parser, count, frame_size  # noqa: E402


def synthetic_batch(model, dataset_id: str, batch: int, size: int, device, dtype) -> dict:
    g = torch.Generator().manual_seed(0)
    n_cls = 32 if dataset_id == "nuscenes" else 23
    n_bev = 32 if dataset_id == "nuscenes" else 9
    lidar_ch = getattr(model, "lidar_channels", 15)

    def onehot(shape_lead, c):
        idx = torch.randint(0, c, (*shape_lead, size, size), generator=g)
        return torch.nn.functional.one_hot(idx, c).movedim(-1, len(shape_lead))

    b = {
        "rgb": torch.rand(batch, 4, 3, size, size, generator=g),
        "dvs": (torch.rand(batch, 4, 2, size, size, generator=g) > 0.9).float(),
        "lidar": torch.rand(batch, lidar_ch, size, size, generator=g),
        "de": torch.rand(batch, 4, 1, size, size, generator=g),
        "ss": onehot((batch, 4), n_cls).float(),
        "ls": onehot((batch,), n_cls).float(),
        "bevp": (torch.rand(batch, n_bev, size, size, generator=g) > 0.8).float(),
    }
    if dataset_id == "nuscenes":
        del b["dvs"]
    return {k: v.to(device=device, dtype=dtype) for k, v in b.items()}


def time_steps(model_id, dataset_id, batch, size, device, dtype, steps, amp=False) -> float:
    params = load_params()
    torch.manual_seed(0)
    model = build_model(model_id, dataset_id).to(device=device, dtype=dtype).train()
    weighting = build_weighting(params.train.models[model_id], model.tasks, model,
                                plateau_patience=params.train.plateau_patience, plateau_factor=params.train.plateau_factor)
    opt = torch.optim.SGD(model.parameters(), lr=1e-3, momentum=0.9)
    data = synthetic_batch(model, dataset_id, batch, size, device, dtype)
    scaler = torch.amp.GradScaler("cuda", enabled=amp)
    times = []
    for i in range(steps + 1):
        if device.type == "cuda":
            torch.cuda.synchronize()
        t0 = time.perf_counter()
        opt.zero_grad(set_to_none=True)
        with torch.autocast("cuda", dtype=torch.float16) if amp else nullcontext():
            out = model(data)
            losses = model.compute_losses(out, data)
        losses = {k: v.float() for k, v in losses.items()}
        weighting.before_backward(1, 2, losses, model)  # a last step: MGN does its update too
        scaler.scale(weighting.total(losses)).backward()
        scaler.step(opt)
        scaler.update()
        if device.type == "cuda":
            torch.cuda.synchronize()
        if i:  # the first step is warm-up
            times.append(time.perf_counter() - t0)
    return batch / statistics.median(times)


def main() -> None:
    ap = Parser(description=__doc__)
    ap.add_argument("--model", default="compact_15l_mgn", choices=model_ids())
    ap.add_argument("--dataset", default="A", choices=dataset_ids())
    ap.add_argument("--resolution", type=frame_size(), default=128)
    ap.add_argument("--batch", type=count(1, MAX_BATCH), default=6)
    ap.add_argument("--steps", type=count(1), default=4)
    args = ap.parse_args()
    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    name = torch.cuda.get_device_name() if device.type == "cuda" else f"CPU ({torch.get_num_threads()} threads)"
    print(f"device: {name}; model {args.model} on {args.dataset}; {args.resolution}x{args.resolution}; batch {args.batch}")
    f32 = time_steps(args.model, args.dataset, args.batch, args.resolution, device, torch.float32, args.steps)
    f64 = time_steps(args.model, args.dataset, args.batch, args.resolution, device, torch.float64, args.steps)
    print(f"float32: {f32:8.2f} samples/s")
    print(f"float64: {f64:8.2f} samples/s")
    print(f"float32/float64 ratio: {f32 / f64:.2f}")
    if device.type == "cuda":
        amp = time_steps(args.model, args.dataset, args.batch, args.resolution, device, torch.float32, args.steps, amp=True)
        print(f"AMP (float16 autocast): {amp:8.2f} samples/s; AMP/float32 ratio: {amp / f32:.2f}")


if __name__ == "__main__":
    main()
