"""The GPU check: every path past the CPU default, in minutes, on the first GPU (`make gpu-check`).

    .venv/bin/python benchmarks/gpu_check.py [--device cuda|cpu] [--size 128] [--steps 3]

On a CUDA device (the default) it runs, at the paper's 128 px:

- ``train_step``: training steps of every registered model (core/catalog.py) in fp32, bf16 and
  fp16 (fp16 with the GradScaler), through the project's own step
  (:func:`compact_perception.learning.training.epoch.train_step` on a run built by the training loop's
  setup step); compact_15l_mgn_authors (MGN, ``authors_mode: true``) does its weight update under
  autocast on the last step and the check asserts the weights stay finite and moved, unless the
  GradScaler skipped that step (the update is then dropped with it, and the row says so);
- ``captured step``: the training step replayed as a CUDA graph (``train.cuda_graphs``,
  learning/training/capture.py) for an MGN network (SGD) and Chen et al. (fused Adam), fp32 and
  bf16: two epochs of four steps, the two between each epoch's first and last replayed, against
  the same run stepped eagerly twice; the captured network must be as close to the eager one as the
  second eager one is (the same bytes where the two eager runs agree, as on a CPU, where the same
  buffer path runs uncaptured; within their spread where a GPU's atomic adds make them differ);
- ``pipeline.train``: the real stage on a tiny synthetic cache (tests/synthetic.py) with a params
  file in a temporary folder: one epoch interrupted, then ``python -m pipeline.train`` resumes it,
  finishes, and writes best.pt, last.pt and the ONNX export's summary (checked); the same run
  uninterrupted beside it, and the two runs' networks compared (equal bytes, or the largest
  difference, which the GPU determinism policy allows: docs/gpu.md);
- ``ddp``: ``torchrun --standalone --nproc_per_node=1`` training steps with the process group on
  nccl (gloo on a CPU), one per loss weighting of the registry, through the gradient / weight /
  scalar all-reduces of training/distributed.py;
- ``fps``: Table III's batch-1 inference FPS with device synchronisation, as the benchmark stage
  measures it (:func:`compact_perception.evaluation.efficiency.measure_model`) and for each variant
  (:func:`compact_perception.evaluation.timing.benchmark_variants`: fp32, fp16, bf16, channels-last, CUDA graphs).

It prints one table (check, device, precision, seconds, result) and exits 1 if any check failed.
``--device cpu --size 32`` runs the same code on a CPU (one step each, gloo); a precision the CPU
only emulates (fp16 always, bf16 without AMX/AVX-512-BF16) trains the two MGN models, whose weight
update under autocast is what matters, and skips the others (slow there); the slow test suite
runs it so (tests/test_gpu_check.py).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import textwrap
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # tests/synthetic.py: the synthetic cache writer

import torch  # noqa: E402
import yaml  # noqa: E402

from compact_perception.core import catalog  # noqa: E402
from compact_perception.core.params import load_params  # noqa: E402
from compact_perception.data.loader import make_loader  # noqa: E402
from compact_perception.learning.training import distributed as ddp  # noqa: E402
from compact_perception.learning.training.capture import (CapturedStep, Uncaptured, capture_blocker,  # noqa: E402
                                                          replay_difference)
from compact_perception.learning.training.epoch import epoch_means, train_step  # noqa: E402
from compact_perception.learning.training.precision import cpu_has_native_bf16  # noqa: E402
from compact_perception.learning.plan import planned_run  # noqa: E402
from compact_perception.learning.training.standalone import standalone_run  # noqa: E402

PRECISIONS = ("fp32", "bf16", "fp16")
SKIP_CUDA = "skipped: needs CUDA"


@dataclass
class Row:
    check: str
    device: str
    precision: str
    seconds: float
    result: str
    status: str  # ok | FAIL | skip


class CheckFailed(AssertionError):
    pass


def _expect(cond: bool, msg: str) -> None:
    if not cond:
        raise CheckFailed(msg)


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def run_check(rows: list[Row], check: str, device: torch.device, precision: str, fn) -> None:
    """Time ``fn()`` (its return: the result text) into a row; an exception is a failed row."""
    t0 = time.perf_counter()
    try:
        result, status = fn(), "ok"
        _sync(device)
    except Exception as err:  # noqa: BLE001 - every failure is a row, the check goes on
        first = str(err).strip().splitlines()[0] if str(err).strip() else ""
        result, status = f"FAIL {type(err).__name__}: {first}"[:160], "FAIL"
        if os.environ.get("GPU_CHECK_TRACEBACK"):
            traceback.print_exc()
    rows.append(Row(check, device.type, precision, time.perf_counter() - t0, result, status))
    print(f"  {check} [{precision}] {rows[-1].seconds:.1f} s: {result}", flush=True)


def skip(rows: list[Row], check: str, device: torch.device, precision: str, why: str = SKIP_CUDA) -> None:
    rows.append(Row(check, device.type, precision, 0.0, why, "skip"))
    print(f"  {check} [{precision}]: {why}", flush=True)


# ----------------------------------------------------------------------------- training steps
def params_for(device: torch.device, precision: str, batch: int):
    """params.yaml with the check's device, precision and batch (no file written)."""
    params = load_params(ROOT / "params.yaml")
    train = params.train.model_copy(update={"precision": precision, "device": device.type, "batch_size": batch,
                                            "compile": False})
    return params.model_copy(update={"train": train})


def build_run(params, model_id: str, device: torch.device, cache: Path, out: Path, dist: ddp.Dist | None = None,
              arm: str | None = None):
    """A run as the training loop builds it (train._setup): model, weighting, optimiser, scaler;
    ``arm``: a study arm's recipe on the model's network."""
    planned = planned_run(params, "A", model_id, 0, arm).moved(cache_dir=cache, run_dir=out)
    return standalone_run(params, planned, device, digest="gpu-check", dist=dist)


def one_batch(cache: Path, model_id: str, batch: int, device: torch.device | None = None, run=None) -> dict:
    """The first training batch of ``model_id``, loaded as the training stage loads it: pinned when
    the device (``device``, else ``run``'s, else the CPU) is a GPU, so its copies to the GPU do not
    block, with the labelled-pixel lists ``run``'s network asks for."""
    if device is None:
        device = run.spec.device if run is not None else torch.device("cpu")
    labelled = getattr(run.model, "labelled_maps", ()) if run is not None else ()
    loader = make_loader(cache, "train", catalog.MODELS[model_id].lidar_channels, batch, shuffle=False,
                         labelled=labelled, pin_memory=device.type == "cuda")
    return next(iter(loader))


def steps_of(run, batch: dict, steps: int) -> str:
    """``steps`` optimiser steps of the project's train_step (the last one is the epoch's last:
    MGN updates its weights there); checks finite losses and moved parameters."""
    before = [p.detach().clone() for p in run.model.parameters()]
    w0 = run.weighting.w.detach().clone() if hasattr(run.weighting, "w") else None
    values, updates0, skipped = {}, getattr(run.weighting, "n_updates", 0), 0
    for step in range(steps):
        scale = run.scaler.get_scale() if run.scaler.is_enabled() else 1.0
        values, _ = train_step(run, batch, step, steps)
        skipped += run.scaler.is_enabled() and run.scaler.get_scale() < scale
    _expect(math.isfinite(values["loss_total"]), f"loss_total {values['loss_total']}")
    moved = sum(int(not torch.equal(a, p.detach())) for a, p in zip(before, run.model.parameters()))
    _expect(moved > 0 or skipped == steps, "no parameter changed")
    out = f"loss {values['loss_total']:.4g}, {moved} tensors updated"
    if run.scaler.is_enabled():
        out += f", GradScaler scale {run.scaler.get_scale():.0f} ({skipped} of {steps} steps skipped)"
    if run.spec.planned.recipe.weighting == "mgn":
        w = run.weighting.w.detach().float()
        _expect(bool(torch.isfinite(w).all()), f"MGN weights not finite: {w.tolist()}")
        if run.weighting.n_updates > updates0:
            _expect(not torch.equal(w, w0.float()), "MGN weights did not move on the epoch's last step")
            out += ", MGN w " + "/".join(f"{x:.3f}" for x in w.tolist())
        else:  # the GradScaler skipped the epoch's last step: its weight update went with it
            _expect(run.scaler.is_enabled() and torch.equal(w, w0.float()), "MGN weights changed without an update")
            out += ", MGN update dropped with the step the GradScaler skipped"
    return out


def check_train_steps(rows, device, cache, args) -> None:
    for precision in PRECISIONS:
        params = params_for(device, precision, args.batch)
        emulated = device.type == "cpu" and (precision == "fp16" or precision == "bf16" and not cpu_has_native_bf16())
        for model_id in catalog.model_ids():
            name = f"train_step {model_id}"
            if emulated and params.train.models[model_id].weighting != "mgn":  # MGN's update: what matters there
                skip(rows, name, device, precision, f"skipped: emulated {precision} on this CPU (slow); runs on CUDA")
                continue
            recipe = params.train.models[model_id]
            if recipe.weighting == "mgn" and (recipe.mgn or {}).get("authors_mode"):
                name += " (MGN authors update)"

            def fn(model_id=model_id):
                with tempfile.TemporaryDirectory() as tmp:
                    run = build_run(params, model_id, device, cache, Path(tmp))
                    _expect(run.precision == precision, f"resolved precision {run.precision}")
                    return steps_of(run, one_batch(cache, model_id, args.batch, run=run), args.steps)

            run_check(rows, name, device, precision, fn)


def check_captured_steps(rows, device, cache, args) -> None:
    """Two epochs of four steps replayed as a CUDA graph (on a CPU: the same buffers, uncaptured)
    against the same run stepped eagerly, twice: the captured run's network must be as close to the
    eager run's as a second eager run is (:func:`replay_difference`: the same bytes where the two
    eager runs agree, as on a CPU; within the eager runs' own spread where atomic adds make them differ)."""
    for precision in ("fp32", "bf16"):
        for model_id in ("compact_15l_mgn", "chen_bev"):
            name = f"captured step {model_id}"
            if device.type == "cpu" and precision == "bf16" and not cpu_has_native_bf16():
                skip(rows, name, device, precision, "skipped: emulated bf16 on this CPU (slow); runs on CUDA")
                continue
            params = params_for(device, precision, args.batch)

            def fn(model_id=model_id, params=params):
                batch, n = one_batch(cache, model_id, args.batch, device), 4
                with tempfile.TemporaryDirectory() as tmp:
                    nets = {}
                    for how in ("eager", "eager again", "captured"):  # one after the other: each draws its own dropout masks
                        run = build_run(params, model_id, device, cache, Path(tmp) / how.replace(" ", "_"))
                        step = train_step
                        if how == "captured":
                            step = run.captured if device.type == "cuda" else CapturedStep(run, Uncaptured())
                            _expect(step is not None, f"not captured: {capture_blocker(run)}")
                        for _ in range(2):
                            for k in range(n):
                                step(run, batch, k, n)
                            epoch_means(run)
                        nets[how] = [t.detach().clone() for t in run.model.state_dict().values()]
                    _expect(step.failed is None, f"fell back: {step.failed}")
                    _expect(step.replays == 2 * (n - 2), f"{step.replays} replays, expected {2 * (n - 2)}")
                    why = replay_difference(nets["captured"], nets["eager"], nets["eager again"])
                    _expect(why is None, f"the captured run's network: {why}")
                    exact = all(torch.equal(a, b) for a, b in zip(nets["captured"], nets["eager"]))
                    how = "CUDA graph" if device.type == "cuda" else "uncaptured buffers"
                    return (f"{step.replays} steps replayed ({how}); network = eager run's, "
                            + ("bit for bit" if exact else "within two eager runs' own spread"))

            run_check(rows, name, device, precision, fn)


# ----------------------------------------------------------------------------- pipeline.train
INTERRUPTED_RUN = textwrap.dedent("""
    import sys
    from pathlib import Path
    import pipeline  # noqa: F401  the stage package's numeric pins, as the resuming stage has them
    from compact_perception.core.params import load_params
    from compact_perception.learning.plan import planned_run
    from compact_perception.learning.training.train import train_run
    params = load_params(sys.argv[1])
    run = planned_run(params, "A", "compact_15l", 0).moved(cache_dir=Path(sys.argv[2]), run_dir=Path(sys.argv[3]))
    try:
        train_run(params, run, stop_after_epochs=1, progress=False)
    except InterruptedError as err:
        print("interrupted:", err)
        sys.exit(0)
    sys.exit("error: the run was not interrupted")
""")


def network_difference(a: Path, b: Path) -> float:
    """The largest absolute difference between two checkpoints' networks (0.0: equal values)."""
    sa = torch.load(a, map_location="cpu", weights_only=True)["model"]
    sb = torch.load(b, map_location="cpu", weights_only=True)["model"]
    _expect(sa.keys() == sb.keys(), f"{a} and {b} hold different networks")
    return max((float((sa[k].double() - sb[k].double()).abs().max()) for k in sa if sa[k].numel()), default=0.0)


def write_params(path: Path, device: torch.device, size: int, precision: str) -> Path:
    raw = yaml.safe_load((ROOT / "params.yaml").read_text())
    raw["scale"] = "default"
    raw["world"]["resolution"] = {"default": size, "full": size, "paper": size}
    raw["datasets"]["A"]["training"] = {"seeds": {"default": [0], "full": [0], "paper": [0]},
                                        "max_epochs": {"default": 2, "full": 2, "paper": 2}}
    raw["train"].update(device=device.type, precision=precision, parallel_runs=1, num_workers=0, compile=False)
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return path


def _run(cmd: list[str], timeout: float) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout)
    if proc.returncode != 0:
        tail = (proc.stderr or proc.stdout).strip().splitlines()
        raise CheckFailed(f"{' '.join(cmd[:4])}... exit {proc.returncode}: {tail[-1] if tail else ''}")
    return proc


def check_pipeline_train(rows, device, cache, work: Path, args) -> None:
    precision = "auto" if device.type == "cuda" else "fp32"

    def fn() -> str:
        params = write_params(work / "params.yaml", device, args.size, precision)
        out = work / "run"
        _run([sys.executable, "-c", INTERRUPTED_RUN, str(params), str(cache), str(out)], args.timeout)
        _expect((out / "last.pt").exists() and (out / "best.pt").exists(), "no last.pt/best.pt after epoch 1")
        _expect(not (out / "summary.json").exists(), "summary.json written by an interrupted run")
        stage = [sys.executable, "-m", "pipeline.train", "--dataset", "A", "--model", "compact_15l", "--seed", "0",
                 "--params", str(params), "--cache", str(cache), "--out", str(out)]
        proc = _run(stage, args.timeout)
        _expect("resuming after epoch 1" in proc.stderr + proc.stdout, "the stage did not resume after epoch 1")
        summary = json.loads((out / "summary.json").read_text())
        _expect(summary["epochs_run"] == 2, f"epochs_run {summary['epochs_run']}")
        onnx = summary.get("onnx") or {}
        _expect((out / onnx.get("file", "model.onnx")).exists(), "no ONNX export in the summary / folder")
        diff = float(onnx["max_abs_diff"])
        _expect(math.isfinite(diff) and diff < 1e-2, f"ONNX max abs diff {diff}")
        whole = work / "uninterrupted"  # the stage's own process (its numeric pins), as the resumed epoch had
        _run([*stage[:-1], str(whole)], args.timeout)
        same = (out / "last.pt").read_bytes() == (whole / "last.pt").read_bytes()  # holds the timings: rarely
        gap = network_difference(out / "last.pt", whole / "last.pt")
        _expect(device.type == "cuda" or gap == 0.0, f"resumed network differs from the uninterrupted one by {gap:.3g}")
        versus = "resumed = uninterrupted network (equal values)" if gap == 0.0 else \
            f"resumed vs uninterrupted network: max|diff| {gap:.2e}"
        return (f"resumed after epoch 1, 2 epochs, best epoch {summary['best_epoch'] + 1}, best.pt+last.pt, "
                f"ONNX max|diff| {diff:.1e}; {versus}{' (same last.pt bytes)' if same else ''}")

    run_check(rows, "pipeline.train (resume, ONNX)", device, precision, fn)


# ----------------------------------------------------------------------------- torchrun DDP
class _OneRankGroup(ddp.Dist):
    """A one-process group that still takes the all-reduce path (Dist.enabled is world_size > 1)."""

    @property
    def enabled(self) -> bool:
        return True


#: One run per loss weighting of the registry (model, study arm): the compact 15L network where the
#: method is a study arm, so that no VGG16 SegNet is needed for GradNorm.
WEIGHTING_RUNS = {
    "static": ("compact_15l", None), "none": ("polarnet", None), "mgn": ("compact_15l_mgn", None),
    "mgn (authors)": ("compact_15l_mgn_authors", None), "gradnorm": ("compact_15l", "gradnorm"),
    "uw": ("compact_15l", "uw"), "dwa": ("compact_15l", "dwa"), "pcgrad": ("compact_15l", "pcgrad"),
    "cagrad": ("compact_15l", "cagrad"), "single": ("compact_15l", "single_ss"),
}


def ddp_worker(args) -> None:
    """Inside torchrun: join the group (nccl on CUDA, gloo on a CPU), one training step per loss
    weighting through the data-parallel path, then an all-reduce of the scalars."""
    import torch.distributed as dist

    device = torch.device(args.device)
    backend = "nccl" if device.type == "cuda" else "gloo"
    rank, world, local = (int(os.environ[k]) for k in ("RANK", "WORLD_SIZE", "LOCAL_RANK"))
    if device.type == "cuda":
        torch.cuda.set_device(local)
        device = torch.device("cuda", local)
    dist.init_process_group(backend=backend)
    group = _OneRankGroup(rank=rank, world_size=world, local_rank=local)
    params = params_for(device, "fp32", args.batch)
    done = []
    for name, (model_id, arm) in WEIGHTING_RUNS.items():
        with tempfile.TemporaryDirectory() as tmp:
            run = build_run(params, model_id, device, Path(args.cache), Path(tmp), group, arm)
            steps_of(run, one_batch(Path(args.cache), model_id, args.batch, run=run), 2)
        done.append(name)
    mean = ddp.average_scalars({"x": 2.0}, group)["x"]
    ddp.barrier(group)
    _expect(abs(mean - 2.0) < 1e-9, f"all-reduce mean {mean}")
    print(f"ddp ok: backend {dist.get_backend()}, world {world}, {len(done)} weightings: {', '.join(done)}")
    ddp.shutdown(group)


def check_ddp(rows, device, cache, args) -> None:
    backend = "nccl" if device.type == "cuda" else "gloo"

    def fn() -> str:
        proc = _run([sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=1",
                     str(Path(__file__).resolve()), "--ddp-worker", "--device", device.type, "--cache", str(cache),
                     "--batch", str(args.batch)], args.timeout)
        line = next((ln for ln in proc.stdout.splitlines() if ln.startswith("ddp ok")), None)
        _expect(line is not None, "the torchrun worker printed no result")
        return line.split(": ", 1)[1]

    run_check(rows, f"torchrun DDP steps ({backend}, every weighting)", device, "fp32", fn)


# ----------------------------------------------------------------------------- Table III FPS
def check_fps(rows, device, args) -> None:
    from compact_perception.learning.models import DATASET_SPECS, build_model
    from compact_perception.evaluation.efficiency import dummy_batch, measure_model
    from compact_perception.evaluation.timing import benchmark_variants, default_variants

    params = load_params(ROOT / "params.yaml")
    warmup, runs = (params.benchmark.warmup, params.benchmark.runs) if device.type == "cuda" else (1, 3)

    def fn() -> str:
        spec = DATASET_SPECS["A"]
        torch.manual_seed(0)
        model = build_model("compact_15l", "A").eval()
        batch = dummy_batch(model, n_seg=spec.n_seg, has_dvs=spec.has_dvs, resolution=args.size, device=device)
        stage = measure_model(model, batch, device, warmup, runs)  # what the benchmark stage records
        _expect(stage["fps"] > 0 and math.isfinite(stage["fps"]), f"benchmark stage FPS {stage['fps']}")
        results = benchmark_variants(model, batch, device, default_variants(device), warmup, runs)
        bad = [r["name"] for r in results if "error" in r]
        good = [r for r in results if "fps" in r]
        _expect(any(r["name"] == "fp32" for r in good), "fp32 inference failed")
        _expect(not bad, f"variants failed: {', '.join(bad)}")
        best = max(good, key=lambda r: r["fps"])
        fp32 = next(r for r in good if r["name"] == "fp32")
        return (f"compact_15l batch 1: benchmark stage {stage['fps']:.0f} FPS, fp32 {fp32['fps']:.0f} FPS, best "
                f"{best['name']} {best['fps']:.0f} FPS ({len(good)} variants, synchronised, median of {runs})")

    run_check(rows, "Table III FPS", device, "all", fn)


# ----------------------------------------------------------------------------- main
def print_table(rows: list[Row]) -> None:
    w = max(len(r.check) for r in rows)
    print(f"\n{'check':<{w}}  {'device':<6}  {'precision':<9}  {'seconds':>7}  result")
    for r in rows:
        print(f"{r.check:<{w}}  {r.device:<6}  {r.precision:<9}  {r.seconds:7.1f}  {r.result}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cuda", choices=["cuda", "cpu"])
    ap.add_argument("--size", type=int, default=128, help="frame size in px (the paper: 128)")
    ap.add_argument("--steps", type=int, default=None, help="training steps per model (default: 3 on CUDA, 1 on CPU)")
    ap.add_argument("--batch", type=int, default=6)
    ap.add_argument("--timeout", type=float, default=300.0, help="seconds allowed to each subprocess")
    ap.add_argument("--ddp-worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--cache", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.size < 16 or args.size % 16:
        sys.exit(f"error: --size must be a multiple of 16 and at least 16, got {args.size}")
    if args.batch < 1:
        sys.exit(f"error: --batch must be at least 1, got {args.batch}")
    if args.device == "cuda" and not torch.cuda.is_available():
        sys.exit("error: --device cuda but no CUDA device is available (use --device cpu for the CPU run)")
    if args.ddp_worker:
        ddp_worker(args)
        return
    args.steps = args.steps or (3 if args.device == "cuda" else 1)
    device = torch.device(args.device)
    from compact_perception.core.determinism import apply_policy

    apply_policy(device, load_params(ROOT / "params.yaml").train)  # the stages' fp32 and determinism (docs/gpu.md)
    where = torch.cuda.get_device_name(device) if device.type == "cuda" else f"CPU ({torch.get_num_threads()} threads)"
    print(f"gpu-check on {where}, torch {torch.__version__}, {args.size} px, batch {args.batch}, "
          f"{args.steps} step(s) per model", flush=True)
    from tests.synthetic import make_cache

    t0, rows = time.perf_counter(), []
    with tempfile.TemporaryDirectory(prefix="gpu_check_") as tmp:
        work = Path(tmp)
        cache = make_cache(work / "cache", "A", size=args.size, counts=(max(args.batch, 6), 3, 1))
        check_train_steps(rows, device, cache, args)
        check_captured_steps(rows, device, cache, args)
        check_pipeline_train(rows, device, cache, work, args)
        check_ddp(rows, device, cache, args)
        check_fps(rows, device, args)
    print_table(rows)
    failed = [r for r in rows if r.status == "FAIL"]
    print(f"\n{len(rows) - len(failed)} of {len(rows)} checks passed or skipped, {len(failed)} failed "
          f"({time.perf_counter() - t0:.0f} s)")
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
