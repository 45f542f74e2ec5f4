"""The census of the training loop's own step: aten ops and host syncs per step, per model and per
loss weighting (:mod:`compact_perception.learning.training.census`), and on a GPU the samples/s of one run.

    .venv/bin/python benchmarks/bench_census.py [--size 32] [--batch 6] [--steps 3] [--precision fp32]
        [--only compact_15l/uw ...] [--sites] [--time-steps 10] [--side-by-side 4 12]

Every registered model trains with its own recipe (params.yaml), and the compact 15L network with
each study arm that brings another loss weighting (GradNorm, UW, DWA, PCGrad, CAGrad, a single-task
network). A run is built as the training loop builds it (``train._setup``) and takes ``--steps``
steps of ``training.epoch.train_step`` on one synthetic batch of the cache's format: step 0 (the
epoch's first: MGN records L_i(0)), the ordinary steps between, and the epoch's last (MGN updates
its weights; the epoch's losses and metrics are read there). Columns:

- ``ops``: aten ops of an ordinary step (each about one kernel launch on a GPU);
- ``syncs first / mid / last``: host reads of device values in the epoch's first step, in an
  ordinary step (the most of them) and in its last step (with the epoch's read of its sums and
  weights after it);
- on CUDA, ``samples/s``: ``--time-steps`` ordinary steps after the counted ones (the census
  itself slows a step down, so the timed steps run without it), eager and replayed as a CUDA
  graph (``train.cuda_graphs``; the reason where the run's step is not captured);
- ``--side-by-side k ...``: k processes training the first selected run at once on the device,
  each timed over ``--time-steps`` steps after they all warmed up (default on CUDA: 4 and 12), with
  the captured step where the run's step can be captured.

``--sites`` prints where in the code each sync of an ordinary step happens.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))  # synthetic.py: the synthetic cache writer

import torch  # noqa: E402

from compact_perception.core import catalog  # noqa: E402
from compact_perception.core.params import load_params  # noqa: E402
from compact_perception.data.loader import make_loader  # noqa: E402
from compact_perception.learning.plan import planned_run  # noqa: E402
from compact_perception.learning.training.capture import capture_blocker  # noqa: E402
from compact_perception.learning.training.census import Census, optimizer_step_counters  # noqa: E402
from compact_perception.learning.training.epoch import epoch_means, train_step  # noqa: E402
from compact_perception.learning.training.standalone import standalone_run  # noqa: E402

sys.path.insert(0, str(ROOT / "benchmarks"))
from flags import MAX_BATCH, MAX_WORKERS, Parser, count, frame_size  # noqa: E402

#: The compact 15L network with each study arm whose loss weighting no model's own recipe uses.
ARMS: tuple[str, ...] = ("gradnorm", "uw", "dwa", "pcgrad", "cagrad", "single_ss")


def runs() -> list[tuple[str, str | None]]:
    """(model, study arm) pairs: every registered model with its recipe, then the arms."""
    return [(m, None) for m in catalog.MODELS.keys()] + [("compact_15l", a) for a in ARMS]


def build(params, model: str, arm: str | None, device: torch.device, cache: Path, out: Path):
    planned = planned_run(params, "A", model, 0, arm).moved(cache_dir=cache, run_dir=out)
    return standalone_run(params, planned, device, digest="census")


def census_of(run, batch: dict, steps: int) -> list[Census]:
    """One census per step of an epoch of ``steps`` steps."""
    host_side = optimizer_step_counters(run.optimizer, run.weighting)
    out = []
    for step in range(steps):
        with Census(run.spec.device, host_side) as c:
            train_step(run, batch, step, steps)
        out.append(c)
    with Census(run.spec.device, host_side) as c:  # the epoch's read, as train_epoch does it
        epoch_means(run)
    out[-1].syncs += c.syncs
    out[-1].sites.update(c.sites)
    return out


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def samples_per_s(run, batch: dict, steps: int, n: int, step=train_step) -> float:
    """Samples per second over ``n`` ordinary steps of ``step`` (the device synchronised before
    and after)."""
    _sync(run.spec.device)
    t0 = time.perf_counter()
    for k in range(n):
        step(run, batch, 1 + k % max(steps - 2, 1), steps)
    _sync(run.spec.device)
    return n * run.spec.per_rank_batch / (time.perf_counter() - t0)


def captured_samples_per_s(run, batch: dict, n: int) -> tuple[float | None, str]:
    """Samples per second of ``n`` ordinary steps replayed as a CUDA graph (``train.cuda_graphs``:
    learning/training/capture.py), as a run replays them: after a warm-up epoch (its first step eager,
    the capture, its warm-up and its checked first replay at the second), in the next epoch, whose
    second step captures again (new epoch sums), untimed; then ``n`` replays timed. None and the
    reason where the step is not captured or any timed step was not a replay (never an eager rate
    under the captured column)."""
    step = run.captured  # train._setup's, per train.cuda_graphs
    if step is None:
        return None, capture_blocker(run) or "train.cuda_graphs: off"
    steps = n + 3  # first, capture, n timed, last
    for k in range(steps):  # the warm-up epoch
        step(run, batch, k, steps)
    epoch_means(run)
    step(run, batch, 0, steps)
    step(run, batch, 1, steps)  # captured again: this epoch's sums
    replays = step.replays
    rate = samples_per_s(run, batch, steps, n, step) if not step.failed else None
    timed = step.replays - replays
    step(run, batch, steps - 1, steps)
    epoch_means(run)
    if step.failed:
        return None, step.failed
    if timed != n:
        return None, f"{timed} of {n} timed steps were replays"
    return rate, ""


def make_params(device: torch.device, precision: str, batch: int):
    """params.yaml with the benchmark's device, precision and batch (no file written)."""
    params = load_params(ROOT / "params.yaml")
    train = params.train.model_copy(update={"precision": precision, "device": device.type, "batch_size": batch,
                                            "compile": False, "num_workers": 0})
    return params.model_copy(update={"train": train})


def _side_worker(job: tuple) -> tuple[float, str]:
    """One of k processes sharing the device: build, warm up, wait for the others, time. Returns its
    samples/s and how its step ran: "captured" (every timed step a replay) or "eager (why)"."""
    precision, batch_size, model, arm, cache, out, n, barrier = job
    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    params = make_params(device, precision, batch_size)
    run = build(params, model, arm, device, Path(cache), Path(out))
    batch = first_batch(Path(cache), model, params.train.batch_size, run, device)
    step, steps = run.captured, n + 3
    if step is not None:  # a warm-up epoch (the capture and its check), then this epoch's capture
        for k in range(steps):
            step(run, batch, k, steps)
        epoch_means(run)
        step(run, batch, 0, steps)
        step(run, batch, 1, steps)
    else:
        for _ in range(3):
            train_step(run, batch, 1, 3)
    barrier.wait()
    replays = step.replays if step is not None else 0
    rate = samples_per_s(run, batch, steps, n, step or train_step)
    if step is None:
        return rate, f"eager ({capture_blocker(run) or 'train.cuda_graphs: off'})"
    if step.failed or step.replays - replays != n:
        return rate, f"eager ({step.failed or 'not every timed step a replay'})"
    return rate, "captured"


def first_batch(cache: Path, model: str, batch_size: int, run, device: torch.device) -> dict:
    """The first training batch, loaded as the training stage loads it (pinned on a GPU, the
    labelled-pixel lists with it)."""
    loader = make_loader(cache, "train", catalog.MODELS[model].lidar_channels, batch_size, shuffle=False,
                         labelled=getattr(run.model, "labelled_maps", ()), pin_memory=device.type == "cuda")
    return next(iter(loader))


def side_by_side(params, model: str, arm: str | None, cache: Path, tmp: Path, k: int,
                 n: int) -> list[tuple[float, str]]:
    """Samples/s of each of ``k`` processes training ``model`` at once on one device, and how its step ran."""
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    with ctx.Manager() as mgr, ctx.Pool(k) as pool:
        barrier = mgr.Barrier(k)
        jobs = [(params.train.precision, params.train.batch_size, model, arm, str(cache), str(tmp / f"side{k}_{i}"),
                 n, barrier) for i in range(k)]
        return pool.map(_side_worker, jobs)


def main() -> None:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=frame_size(), default=32, help="image size of the synthetic cache (px)")
    ap.add_argument("--batch", type=count(1, MAX_BATCH), default=6)
    ap.add_argument("--steps", type=count(3), default=3, help="steps of the counted epoch (>= 3)")
    ap.add_argument("--precision", default="fp32", choices=("fp32", "bf16", "fp16"))
    ap.add_argument("--only", nargs="*", default=None, help="model or model/arm ids")
    ap.add_argument("--sites", action="store_true", help="where each sync of an ordinary step happens")
    ap.add_argument("--time-steps", type=count(1), default=10, help="timed steps per run on CUDA")
    ap.add_argument("--side-by-side", type=count(1, MAX_WORKERS), nargs="*", default=None,
                    help="k processes training the first run at once, samples/s each and together "
                         "(default on CUDA: 4 12; on a CPU only when given)")
    args = ap.parse_args()
    known = {m for m, _ in runs()} | {f"{m}/{a}" for m, a in runs() if a}
    unknown = [x for x in args.only or () if x not in known]
    if unknown:
        ap.error(f"--only: expected model or model/arm ids of {sorted(known)} (got {unknown[0]!r})")
    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    params = make_params(device, args.precision, args.batch)
    where = torch.cuda.get_device_name() if device.type == "cuda" else f"CPU, {torch.get_num_threads()} threads"
    print(f"device: {where}; torch {torch.__version__}; {args.precision}; {args.size} px; batch {args.batch}; "
          f"an epoch of {args.steps} steps of training.epoch.train_step")
    cols = f"{'run':<28s} {'ops':>6s} {'syncs first / mid / last':>26s}"
    print(cols + ("  samples/s eager / CUDA graph" if device.type == "cuda" else ""))
    from synthetic import make_cache

    with tempfile.TemporaryDirectory() as tmp:
        cache = make_cache(Path(tmp) / "cache", size=args.size, counts=(args.batch, 1, 1))
        for model, arm in runs():
            key = f"{model}/{arm}" if arm else model
            if args.only and key not in args.only and model not in args.only:
                continue
            run = build(params, model, arm, device, cache, Path(tmp) / key.replace("/", "_"))
            batch = first_batch(cache, model, args.batch, run, device)  # as train._open builds it
            counts = census_of(run, batch, args.steps)
            mid = max(counts[1:-1], key=lambda c: c.syncs)
            line = (f"{key:<28s} {counts[1].ops:6d} "
                    f"{counts[0].syncs:>12d} / {mid.syncs:>3d} / {counts[-1].syncs:>3d}")
            if device.type == "cuda":
                line += f"  {samples_per_s(run, batch, args.steps, args.time_steps):9.1f}"
                rate, why = captured_samples_per_s(run, batch, args.time_steps)
                line += f" / {rate:9.1f} (captured: every timed step a replay)" if rate is not None else \
                    f" / not captured: {why}"
            print(line, flush=True)
            if args.sites:
                for site, n in mid.sites.most_common():
                    print(f"    {n:3d}x {site}")
        side = args.side_by_side if args.side_by_side is not None else ([4, 12] if device.type == "cuda" else [])
        first = next(((m, a) for m, a in runs() if not args.only or m in args.only
                      or f"{m}/{a}" in args.only), None)
        for k in side if first else []:
            out = side_by_side(params, first[0], first[1], cache, Path(tmp), k, args.time_steps)
            each, hows = [r for r, _ in out], sorted({h for _, h in out})
            name = f"{first[0]}/{first[1]}" if first[1] else first[0]
            print(f"{k} x {name} side by side: {min(each):.1f}-{max(each):.1f} samples/s each, "
                  f"{sum(each):.1f} together" + ("" if device.type == "cuda" else " (CPU figures)")
                  + f"; step: {', '.join(hows)}", flush=True)
    if device.type != "cuda":
        print("GPU samples/s: not measured here (no GPU; a CPU's step time says nothing about a GPU's)")


if __name__ == "__main__":
    main()
