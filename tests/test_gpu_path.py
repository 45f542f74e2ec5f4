"""The GPU path's correctness, caught on the CPU: what the first run on a real GPU broke.

- a checkpoint read onto another device (``meta`` exists on every machine) still resumes: it is
  read on the CPU, so the RNG state stays the byte tensor ``torch.set_rng_state`` takes;
- every collective stages its tensors on the process group's device: a fake nccl that refuses
  anything else, through the real ``train_step``, for every loss weighting;
- gradients are averaged before the GradScaler unscales them, so an inf on one rank skips the
  step on every rank, and the loss weights computed from that step are dropped with it;
- two ranks with different batches (a two-rank group in one process, a thread per rank) start
  every epoch with the same DWA weights and share MGN's and GradNorm's L_i(0);
- MGN's authors update in float16 (CPU autocast, ``GradScaler("cpu")``) and with an overflowing
  loss scale in float32 never produces a non-finite loss weight;
- torch.compile with a weighting that needs a double backward is refused in one line;
- the determinism policy of ``train.deterministic`` / ``train.tf32``.
"""
from __future__ import annotations

import dataclasses
import math
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import yaml

from compact_perception.core.params import ParamsError, parse_params
from compact_perception.core.errors import RunError
from compact_perception.learning.plan import recipe_of
from compact_perception.learning.training import distributed as ddp
from compact_perception.learning.training import train as train_mod
from compact_perception.learning.training.epoch import NonFinite, train_step
from compact_perception.learning.training.standalone import standalone_run
from compact_perception.learning.weighting import WEIGHTINGS, MGNWeighting, GradNormWeighting, weighting_settings

from repo_params import cap_epochs
from run_fixture import run_in
from synthetic import make_cache

SIZE = 16


def tiny(params_dict: dict, precision: str = "fp32", epochs: int = 2, batch: int = 2):
    cap_epochs(params_dict, epochs)
    params_dict["train"].update(batch_size=batch, num_workers=0, device="cpu", precision=precision)
    return parse_params(params_dict)


def build(params, model: str, cache: Path, out: Path, arm: str | None = None, dist: ddp.Dist | None = None):
    """A run as the training loop's setup step builds it."""
    return standalone_run(params, run_in(params, model, cache, out, arm=arm), torch.device("cpu"), digest="test",
                          dist=dist)


def batch_of(cache: Path, model: str, n: int) -> dict:
    from compact_perception.core import catalog
    from compact_perception.data.loader import make_loader

    return next(iter(make_loader(cache, "train", catalog.MODELS[model].lidar_channels, n, shuffle=False)))


#: One run per loss weighting of the registry: (model, study arm) on the compact 15L network where
#: the method is a study arm (GradNorm SegNet's 4 VGG16s would take minutes on a CPU).
WEIGHTING_RUNS = {
    "static": ("compact_15l", None), "none": ("polarnet", None), "mgn": ("compact_15l_mgn", None),
    "mgn_authors": ("compact_15l_mgn_authors", None), "gradnorm": ("compact_15l", "gradnorm"),
    "uw": ("compact_15l", "uw"), "dwa": ("compact_15l", "dwa"), "pcgrad": ("compact_15l", "pcgrad"),
    "cagrad": ("compact_15l", "cagrad"), "single": ("compact_15l", "single_ss"),
}


def test_every_registered_weighting_has_a_run_here():
    assert {k.split("_")[0] for k in WEIGHTING_RUNS} == set(WEIGHTINGS.keys())


# ----------------------------------------------------------------------------- resume on any device
def test_a_checkpoint_mapped_to_another_device_resumes(tmp_path, params_dict, monkeypatch):
    """``last.pt`` is read on the CPU whatever the run's device: a run whose device is ``meta`` (as a
    CUDA run's is ``cuda``) restores the CPU generator, the network and the optimiser."""
    params = tiny(params_dict)
    cache = make_cache(tmp_path / "cache", size=SIZE)
    with pytest.raises(InterruptedError):
        train_mod.train_run(params, run_in(params, "compact_1l", cache, tmp_path / "run", export_onnx=False),
                            stop_after_epochs=1)
    saved = torch.load(tmp_path / "run" / "last.pt", weights_only=True)
    specs = []
    monkeypatch.setattr(train_mod, "_train", lambda spec: specs.append(spec) or {})
    train_mod.train_run(params, run_in(params, "compact_1l", cache, tmp_path / "run", export_onnx=False))
    run = train_mod._setup(specs[0])
    run.spec = dataclasses.replace(specs[0], device=torch.device("meta"))
    assert train_mod._resume(run) is None
    assert run.next_epoch == 1
    assert torch.equal(torch.get_rng_state(), saved["torch_rng"])
    for name, value in run.model.state_dict().items():
        assert value.device.type == "cpu" and torch.equal(value, saved["model"][name]), name


def test_last_checkpoint_holds_the_scaler_and_refuses_another_precision(tmp_path, params_dict, monkeypatch):
    """An fp16 run's ``last.pt`` holds the GradScaler's state (restored on resume) and the resolved
    precision; a process resolving another precision refuses it in one line."""
    params = tiny(params_dict, precision="fp16")
    cache = make_cache(tmp_path / "cache", size=SIZE)
    with pytest.raises(InterruptedError):
        train_mod.train_run(params, run_in(params, "compact_1l", cache, tmp_path / "run", export_onnx=False),
                            stop_after_epochs=1)
    saved = torch.load(tmp_path / "run" / "last.pt", weights_only=True)
    assert saved["precision"] == "fp16" and saved["device"] == "cpu" and saved["cuda_rng"] is None
    assert saved["scaler"]["scale"] > 0
    specs = []
    monkeypatch.setattr(train_mod, "_train", lambda spec: specs.append(spec) or {})
    train_mod.train_run(params, run_in(params, "compact_1l", cache, tmp_path / "run", export_onnx=False))
    run = train_mod._setup(specs[0])
    run.scaler = torch.amp.GradScaler("cpu", init_scale=8.0)  # another scale: the checkpoint's must come back
    assert train_mod._resume(run) is None
    assert run.scaler.get_scale() == saved["scaler"]["scale"]
    run = train_mod._setup(specs[0])
    run.precision = "bf16"
    with pytest.raises(RunError) as err:
        train_mod._resume(run)
    assert "trained in fp16 on cpu" in str(err.value) and "\n" not in str(err.value)


# ----------------------------------------------------------------------------- collectives
class _Group(ddp.Dist):
    """A process group the step treats as data-parallel (``enabled``) at any world size."""

    @property
    def enabled(self) -> bool:
        return True


@pytest.mark.parametrize("weighting", sorted(WEIGHTING_RUNS))
def test_collectives_see_only_the_group_devices_tensors(tmp_path, params_dict, monkeypatch, weighting):
    """nccl reduces only tensors on the group's GPU (``No backend type associated with device type
    cpu`` otherwise). The group's device stands in as ``meta``: the fake refuses everything else,
    through the real train_step, and the loss weights travel only when they changed."""
    import torch.distributed as dist

    seen: list[tuple[str, int]] = []

    def fake_all_reduce(t, op=None):
        if t.device.type != "meta":
            raise RuntimeError(f"No backend type associated with device type {t.device.type}")
        seen.append((str(t.dtype), t.numel()))

    monkeypatch.setattr(dist, "all_reduce", fake_all_reduce)
    monkeypatch.setattr(dist, "get_backend", lambda *a: "nccl")
    monkeypatch.setattr(ddp, "group_device", lambda d: torch.device("meta"), raising=False)
    # the sum over one rank is the tensor itself: what comes back from the group's device
    monkeypatch.setattr(ddp, "_from_group", lambda staged, like: like.detach().clone(), raising=False)
    model, arm = WEIGHTING_RUNS[weighting]
    params = tiny(params_dict, batch=2)
    cache = make_cache(tmp_path / "cache", size=SIZE, counts=(2, 1, 1))
    run = build(params, model, cache, tmp_path / "run", arm, _Group(world_size=1))
    batch = batch_of(cache, model, 2)
    n_steps = 3
    weight_syncs = 0
    for step in range(n_steps):
        before = len(seen)
        w_synced, L0 = run.synced_w, getattr(run.weighting, "L0", None)
        values, _ = train_step(run, batch, step, n_steps)
        assert math.isfinite(values["loss_total"])
        weight_syncs += run.synced_w is not w_synced
        new_L0 = getattr(run.weighting, "L0", None) is not L0  # MGN's, GradNorm's L_i(0): the ranks' mean
        # the gradients, then any L_i(0) and any new weights
        assert len(seen) - before == 1 + new_L0 + (run.synced_w is not w_synced)
    assert weight_syncs >= 1  # the first step agrees on the starting weights
    if not run.weighting.adaptive:
        assert weight_syncs == 1
    before = len(seen)
    run.weighting.on_epoch_end(False)  # DWA sums its epoch's losses over the ranks: one all-reduce
    assert len(seen) - before == (weighting == "dwa")


def test_an_inf_on_one_rank_skips_the_step_on_every_rank(tmp_path, params_dict, monkeypatch):
    """The other rank's gradients hold an inf: averaged before the GradScaler unscales them, every
    rank finds it, skips the step, lowers its scale alike, and MGN's update from that step is dropped."""
    import torch.distributed as dist

    def other_rank_has_an_inf(t, op=None):
        other = t.clone()
        if t.numel() > 1000:  # the flat gradient buffer
            other[0] = float("inf")
        t.add_(other)

    monkeypatch.setattr(dist, "all_reduce", other_rank_has_an_inf)
    monkeypatch.setattr(dist, "get_backend", lambda *a: "gloo")
    params = tiny(params_dict, precision="fp16", batch=2)
    cache = make_cache(tmp_path / "cache", size=SIZE, counts=(2, 1, 1))
    run = build(params, "compact_15l_mgn_authors", cache, tmp_path / "run", None, _Group(world_size=2))
    assert run.scaler.is_enabled()
    before = [p.detach().clone() for p in run.model.parameters()]
    w0, scale0, updates0 = run.weighting.w.clone(), run.scaler.get_scale(), run.weighting.n_updates
    train_step(run, batch_of(cache, "compact_15l_mgn_authors", 2), 0, 1)  # the epoch's last step: MGN updates
    assert all(torch.equal(a, p.detach()) for a, p in zip(before, run.model.parameters()))
    assert run.scaler.get_scale() == scale0 / 2
    assert torch.equal(run.weighting.w, w0) and run.weighting.n_updates == updates0


class _TwoRanks:
    """A process group of two ranks in one process, one thread per rank (the stand-in for gloo):
    ``all_reduce`` (a sum) takes each rank's tensor, waits for the other's and gives both ranks
    the same sum, added in rank order."""

    def __init__(self, world_size: int = 2) -> None:
        import threading

        self.world_size = world_size
        self.barrier = threading.Barrier(world_size, timeout=300)
        self.slots: list[torch.Tensor | None] = [None] * world_size
        self.local = threading.local()

    def all_reduce(self, t: torch.Tensor, op=None) -> None:
        self.slots[self.local.rank] = t.detach().clone()
        self.barrier.wait()
        total = self.slots[0].clone()
        for other in self.slots[1:]:
            total += other
        self.barrier.wait()  # every rank has read every slot before the next collective fills them
        t.copy_(total)

    def run(self, fns: list) -> list:
        """``fns[r]()`` on rank r, each in its own thread; their results (the first error raised)."""
        import threading

        results, errors = [None] * self.world_size, []

        def target(rank: int) -> None:
            self.local.rank = rank
            try:
                results[rank] = fns[rank]()
            except BaseException as err:  # noqa: BLE001  (re-raised below)
                errors.append(err)
                self.barrier.abort()

        threads = [threading.Thread(target=target, args=(r,)) for r in range(self.world_size)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        if errors:
            raise errors[0]
        return results


def _two_ranks(tmp_path, params_dict, monkeypatch, model: str, arm: str | None):
    """Two ranks of one data-parallel run (the same initial network, as under torchrun), each with
    its own batch, so their losses differ; the fake group they share."""
    import itertools

    import torch.distributed as dist

    from compact_perception.core import catalog
    from compact_perception.data.loader import make_loader

    group = _TwoRanks()
    monkeypatch.setattr(dist, "all_reduce", group.all_reduce)
    monkeypatch.setattr(dist, "get_backend", lambda *a: "gloo")
    params = tiny(params_dict, batch=2)
    cache = make_cache(tmp_path / "cache", size=SIZE, counts=(4, 1, 1))
    loader = make_loader(cache, "train", catalog.MODELS[model].lidar_channels, 2, shuffle=False)
    batches = list(itertools.islice(iter(loader), 2))
    runs = [build(params, model, cache, tmp_path / f"rank{r}", arm, _Group(rank=r, world_size=2)) for r in range(2)]
    return group, runs, batches


def test_data_parallel_dwa_starts_every_epoch_with_the_same_weights(tmp_path, params_dict, monkeypatch):
    """Issue 55 item 7: two ranks whose batches differ close DWA's epoch means over both ranks'
    steps, so after the second epoch's end (the first that sets w) both hold the same weights
    before the third epoch's first step, not their own until that step's average."""
    group, runs, batches = _two_ranks(tmp_path, params_dict, monkeypatch, "compact_15l", "dwa")

    def two_epochs(rank: int):
        run = runs[rank]
        for _epoch in range(2):
            for step in range(2):
                train_step(run, batches[rank], step, 2)
            run.weighting.on_epoch_end(False)
        return run.weighting.w.clone(), [list(h) for h in run.weighting.history]

    (w0, h0), (w1, h1) = group.run([lambda: two_epochs(0), lambda: two_epochs(1)])
    assert not torch.equal(w0, torch.ones_like(w0))  # DWA set its weights
    assert torch.equal(w0, w1), (w0.tolist(), w1.tolist())  # the weights of the next epoch's first step
    assert h0 == h1  # the same epoch means: over both ranks' steps
    assert all(r.weighting.ranks is not None for r in runs)  # the trainer handed the group to the weighting


@pytest.mark.parametrize("model, arm", [("compact_15l_mgn", None), ("compact_15l", "gradnorm")])
def test_data_parallel_L0_is_the_mean_over_the_ranks(tmp_path, params_dict, monkeypatch, model, arm):
    """Issue 55 item 7: MGN's L_i(0) (recorded at every epoch's first step; GradNorm's at the run's
    first) is the mean of the two ranks' own losses at that step, the same on both ranks."""
    group, runs, batches = _two_ranks(tmp_path, params_dict, monkeypatch, model, arm)
    tasks = runs[0].weighting.tasks
    L0_step = 2 if model == "compact_15l_mgn" else 0  # the next epoch's first step; the run's first

    def steps(rank: int):
        run, losses = runs[rank], []
        for k, (step, n_steps) in enumerate([(0, 2), (1, 2), (0, 2)]):
            values, _ = train_step(run, batches[rank], step, n_steps)
            if k == L0_step:
                L0 = run.weighting.L0.clone()
                losses = torch.stack([values[f"loss_{t}"].detach().to(torch.float64) for t in tasks])
            if step == n_steps - 1:
                run.weighting.on_epoch_end(False)
        return L0, losses

    (L0_a, own_a), (L0_b, own_b) = group.run([lambda: steps(0), lambda: steps(1)])
    assert not torch.equal(own_a, own_b)  # the ranks' losses differ
    assert torch.equal(L0_a, L0_b), (L0_a.tolist(), L0_b.tolist())
    assert torch.equal(L0_a, (own_a + own_b) / 2)


def test_one_process_reduces_nothing(tmp_path, params_dict, monkeypatch):
    """Without a process group the weighting has no ``ranks``: no collective, the bytes of before."""
    import torch.distributed as dist

    def no_collective(*_a, **_k):
        raise AssertionError("a collective in a one-process run")

    monkeypatch.setattr(dist, "all_reduce", no_collective)
    params = tiny(params_dict, batch=2)
    cache = make_cache(tmp_path / "cache", size=SIZE, counts=(2, 1, 1))
    for model, arm in (("compact_15l", "dwa"), ("compact_15l_mgn", None), ("compact_15l", "gradnorm")):
        run = build(params, model, cache, tmp_path / f"{model}_{arm}", arm)
        assert run.weighting.ranks is None
        batch = batch_of(cache, model, 2)
        for step in range(2):
            train_step(run, batch, step, 2)
        run.weighting.on_epoch_end(False)


# ----------------------------------------------------------------------------- MGN under the GradScaler
def test_authors_update_in_fp16_keeps_the_weights_finite(tmp_path, params_dict):
    """float16 autocast with the GradScaler (2^16): the authors' update retries its gradient norms
    unscaled where the scaled backward overflows, and commits new weights only with a step taken."""
    params = tiny(params_dict, precision="fp16", batch=2)
    cache = make_cache(tmp_path / "cache", size=32, counts=(2, 1, 1))
    run = build(params, "compact_15l_mgn_authors", cache, tmp_path / "run")
    batch = batch_of(cache, "compact_15l_mgn_authors", 2)
    for step in range(3):
        train_step(run, batch, step, 3)
    w = run.weighting.w
    assert bool(torch.isfinite(w).all()), w
    assert float(w.sum()) == pytest.approx(4.0)
    taken = run.scaler.get_scale() >= 2.0 ** 16 / 4  # at most two of the three steps skipped
    assert taken


def _mgn_pair(authors: bool, cls=MGNWeighting, **kw):
    settings = dict(alpha=1.5, lr=0.1, plateau_patience=4, plateau_factor=0.5, plateau_rule="paper")
    if cls is MGNWeighting:
        settings.update(lr_min=1e-4, authors_mode=authors)
    return [cls(("de", "ss", "ls", "bevp"), **settings, **kw) for _ in range(2)]


@pytest.mark.parametrize("method", ["mgn", "mgn_authors", "gradnorm"])
def test_an_overflowing_loss_scale_gives_the_unscaled_update(tmp_path, method):
    """float32 with a loss scale that overflows the scaled losses (1e38): the norms are taken again
    unscaled, and the new weights equal those of the unscaled update."""
    from compact_perception.learning.models import build_model

    torch.manual_seed(0)
    cache = make_cache(tmp_path / "cache", size=SIZE, counts=(2, 1, 1))
    batch = {k: v for k, v in batch_of(cache, "compact_15l", 2).items()}
    from compact_perception.data.loader import to_device

    batch = to_device(batch, torch.device("cpu"), 23)
    cls = GradNormWeighting if method == "gradnorm" else MGNWeighting
    ref, scaled = _mgn_pair(method == "mgn_authors", cls)
    results = []
    for weighting, scale in ((ref, 1.0), (scaled, 1e38)):
        torch.manual_seed(0)
        model = build_model("compact_15l", "A")
        losses = model.compute_losses(model(batch), batch)
        weighting.grad_scale = scale
        weighting.before_backward(0, 1, losses, model)
        weighting.backward(losses, model)
        weighting.after_backward()
        results.append(weighting.w)
    assert bool(torch.isfinite(results[1]).all()), results[1]
    assert torch.allclose(results[1], results[0], rtol=1e-5, atol=1e-7)


def test_weights_of_a_skipped_step_are_dropped():
    """GradNorm and MGN commit the weights a step computed only with the step the scaler took:
    neither w nor GradNorm's own optimiser moves for a skipped one."""
    gn = _mgn_pair(False, GradNormWeighting)[0]
    w0 = gn.w.clone()
    gn._pending = torch.tensor([0.1, -0.2, 0.3, -0.1], dtype=torch.float64)
    gn.after_backward(taken=False)
    assert torch.equal(gn.w, w0) and gn.n_updates == 0 and not gn.opt.state
    mgn = _mgn_pair(True)[0]
    mgn._pending = torch.tensor([float("nan")] * 4, dtype=torch.float64)
    mgn.after_backward(taken=False)
    assert torch.equal(mgn.w, torch.ones(4, dtype=torch.float64)) and mgn.n_updates == 0


def test_a_non_finite_weight_on_a_step_taken_is_an_error_not_nan_weights():
    mgn = _mgn_pair(True)[0]
    mgn._pending = torch.tensor([1.0, float("nan"), 1.0, 1.0], dtype=torch.float64)
    with pytest.raises(NonFinite, match="non-finite mgn loss weights"):
        mgn.after_backward(taken=True)
    assert bool(torch.isfinite(mgn.w).all())


# ----------------------------------------------------------------------------- torch.compile
def test_compile_with_a_double_backward_weighting_is_refused_in_one_line(params_dict, tmp_path, root):
    params_dict["train"]["compile"] = True
    params = parse_params(params_dict)
    with pytest.raises(ParamsError) as err:
        weighting_settings(recipe_of(params, "compact_15l_mgn_authors", None), compiled=True)
    msg = str(err.value)
    assert "train.models.compact_15l_mgn_authors" in msg and "train.compile: false" in msg and "\n" not in msg
    for model, arm in WEIGHTING_RUNS.values():  # every other method compiles
        if model != "compact_15l_mgn_authors":
            weighting_settings(recipe_of(params, model, arm), compiled=True)
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(params_dict))
    proc = subprocess.run([sys.executable, "-m", "pipeline.train", "--dataset", "A", "--params",
                           str(tmp_path / "params.yaml"), "--cache", str(tmp_path / "none")], cwd=root,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 1
    errors = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "train.compile: true cannot train" in errors[0]
    assert "Traceback" not in proc.stderr


def test_compiled_forward_has_no_double_backward_but_first_order_grads_work():
    """Why the refusal: AOTAutograd (torch.compile's autograd) raises on a double backward; the
    first-order ``autograd.grad(..., retain_graph=True)`` the other methods take works. If a torch
    release lifts the limit, this fails and the refusal can go."""
    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Conv2d(3, 4, 3, padding=1), torch.nn.ReLU(), torch.nn.Conv2d(4, 2, 1))
    fwd = torch.compile(net, backend="aot_eager")
    out = fwd(torch.randn(2, 3, 8, 8))
    W = [net[0].weight]
    torch.autograd.grad(out[:, 0].mean(), W, retain_graph=True)
    out.mean().backward()
    g = torch.autograd.grad(fwd(torch.randn(2, 3, 8, 8)).pow(2).mean(), W, create_graph=True)[0]
    with pytest.raises(RuntimeError, match="double backward"):
        g.pow(2).sum().backward()


# ----------------------------------------------------------------------------- determinism policy
def test_determinism_policy(monkeypatch, params_dict):
    from compact_perception.core.determinism import CUBLAS_DETERMINISTIC, set_determinism

    params = parse_params(params_dict)
    assert params.train.deterministic is True and params.train.tf32 is False  # the committed policy
    monkeypatch.delenv("CUBLAS_WORKSPACE_CONFIG", raising=False)
    saved = (torch.are_deterministic_algorithms_enabled(), torch.is_deterministic_algorithms_warn_only_enabled(),
             torch.backends.cudnn.deterministic, torch.backends.cudnn.benchmark,
             torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32)
    try:
        set_determinism(torch.device("cpu"), True, False)
        import os

        assert "CUBLAS_WORKSPACE_CONFIG" not in os.environ  # a CPU run leaves CUDA's settings alone
        assert torch.are_deterministic_algorithms_enabled() and torch.backends.cudnn.deterministic
        assert not torch.backends.cudnn.benchmark
        assert not torch.backends.cuda.matmul.allow_tf32 and not torch.backends.cudnn.allow_tf32
        set_determinism(torch.device("cuda"), True, True)  # sets flags only: no CUDA needed
        assert os.environ["CUBLAS_WORKSPACE_CONFIG"] in CUBLAS_DETERMINISTIC
        assert torch.backends.cuda.matmul.allow_tf32 and torch.backends.cudnn.allow_tf32
        set_determinism(torch.device("cuda"), False, False)
        assert not torch.are_deterministic_algorithms_enabled() and torch.backends.cudnn.benchmark
    finally:
        torch.use_deterministic_algorithms(saved[0], warn_only=saved[1])
        (torch.backends.cudnn.deterministic, torch.backends.cudnn.benchmark, torch.backends.cuda.matmul.allow_tf32,
         torch.backends.cudnn.allow_tf32) = saved[2:]
