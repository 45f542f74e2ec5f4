"""The step census (training/census.py) counts what it says: aten ops, and every way the host reads
a device value, once each; the step counters PyTorch keeps on the host are not reads."""
from __future__ import annotations

import math
from pathlib import Path

import torch

from compact_perception.learning.training.census import Census, optimizer_step_counters


def test_every_kind_of_host_read_counts_once():
    x = torch.arange(6.0).reshape(2, 3)
    with Census("cpu") as c:
        s = x.sum()
        s.item()
        float(s)
        bool(s > 0)
        int(s)
        math.isfinite(s)
        x.tolist()
        x.numpy()
        x.cpu()
        x[x > 2]                       # boolean mask: nonzero underneath
        torch.nonzero(x)
    assert c.syncs == 10
    assert sum(c.sites.values()) == 10
    assert all(s.endswith("at (outside the package)") for s in c.sites)  # a site is code of the package
    assert c.ops > 5


def test_device_work_alone_is_no_sync():
    x = torch.randn(4, 4, requires_grad=True)
    acc = torch.zeros((), dtype=torch.float64)
    with Census("cpu") as c:
        y = (x @ x).relu().sum()
        y.backward()
        acc = acc + y.detach().double() * 3
        ok = torch.isfinite(acc)
        torch.where(ok, acc, torch.zeros_like(acc))
    assert c.syncs == 0 and c.ops > 5


def test_adam_step_counters_are_host_side():
    """A non-fused Adam reads its step counter with ``.item()``; PyTorch keeps that counter on the
    host in a GPU run too, so it is no device read. A fused Adam keeps it on the device and never
    reads it."""
    p = torch.nn.Parameter(torch.ones(3, dtype=torch.float64))
    opt = torch.optim.Adam([p], lr=0.1)
    p.grad = torch.ones(3, dtype=torch.float64)
    opt.step()
    with Census("cpu") as plain:
        opt.step()
    with Census("cpu", optimizer_step_counters(opt)) as exempt:
        opt.step()
    assert plain.syncs >= 1 and exempt.syncs == 0

    class Holder:  # a loss weighting holding its own optimiser
        def __init__(self) -> None:
            self.opt = opt

    with Census("cpu", optimizer_step_counters(Holder())) as held:
        opt.step()
    assert held.syncs == 0


# ----------------------------------------------------------------------------- no host sync inside a step
import pytest  # noqa: E402

from compact_perception.core import catalog  # noqa: E402
from compact_perception.core.params import parse_params  # noqa: E402
from compact_perception.core.errors import NonFinite  # noqa: E402
from compact_perception.data.loader import make_loader  # noqa: E402
from compact_perception.learning.plan import recipe_of  # noqa: E402
from compact_perception.learning.training.epoch import EpochSums, epoch_means, train_step  # noqa: E402
from compact_perception.learning.training.standalone import standalone_run  # noqa: E402
from compact_perception.learning.weighting import WEIGHTINGS  # noqa: E402

from repo_params import cap_epochs  # noqa: E402
from run_fixture import nudged_replay, run_in  # noqa: E402
from synthetic import make_cache  # noqa: E402

#: Every registered model with its own recipe, and the compact 15L network with each study arm
#: whose loss weighting no model's recipe uses.
STEP_RUNS = [(m, None) for m in catalog.MODELS.keys()] + [
    ("compact_15l", a) for a in ("gradnorm", "uw", "dwa", "pcgrad", "cagrad", "single_ss")]
#: Host reads an ordinary step makes, by design: CAGrad solves its inner problem on the host, from
#: the Gram matrix (one read; see weighting/cagrad.py).
ALLOWED = {"cagrad": 1}
SLOW = {"gradnorm_segnet"}  # four VGG16s at 32 px: minutes on a CPU


def _tiny(params_dict: dict, precision: str):
    cap_epochs(params_dict, 2)
    params_dict["train"].update(batch_size=2, num_workers=0, device="cpu", precision=precision)
    return parse_params(params_dict)


def _run(params, model: str, arm, cache, out):
    run = standalone_run(params, run_in(params, model, cache, out, arm=arm), torch.device("cpu"), digest="test")
    loader = make_loader(cache, "train", catalog.MODELS[model].lidar_channels, params.train.batch_size, shuffle=False,
                         labelled=getattr(run.model, "labelled_maps", ()))  # as the training loop's loader
    return run, next(iter(loader))


def _step_params():
    out = []
    for precision in ("fp32", "bf16"):
        for model, arm in STEP_RUNS:
            marks = [pytest.mark.slow] if model in SLOW else []
            out.append(pytest.param(model, arm, precision, marks=marks, id=f"{model}-{arm or 'own'}-{precision}"))
    return out


def test_the_step_runs_cover_every_model_and_weighting(params_dict):
    params = parse_params(params_dict)
    covered = {recipe_of(params, m, a).weighting for m, a in STEP_RUNS}
    assert covered == set(WEIGHTINGS.keys())
    assert {m for m, _ in STEP_RUNS} == set(catalog.MODELS.keys())


@pytest.mark.parametrize("model, arm, precision", _step_params())
def test_no_host_sync_inside_an_epoch(tmp_path, params_dict, model, arm, precision):
    """The real train_step of every model and weighting, fp32 and bf16, reads nothing from the
    device but at the epoch's last step (its divergence check) and in the epoch's one read of its
    sums and weights after it: an ordinary step counts 0 (CAGrad: its one documented read)."""
    params = _tiny(params_dict, precision)
    cache = make_cache(tmp_path / "cache", size=32 if model in SLOW else 16, counts=(2, 1, 1))
    run, batch = _run(params, model, arm, cache, tmp_path / "run")
    host_side = optimizer_step_counters(run.optimizer, run.weighting)
    n_steps, per_step = 3, []
    for step in range(n_steps):
        with Census("cpu", host_side) as c:
            values, frames = train_step(run, batch, step, n_steps)
        per_step.append(c)
    with Census("cpu", host_side) as end:
        means = epoch_means(run)
    allowed = ALLOWED.get(recipe_of(params, model, arm).weighting, 0)
    for c in per_step[:-1]:
        assert c.syncs == allowed, c.summary()
        assert c.ops > 100
    # the two checks of the sums; MGN's update reads its norms' and new weights' finiteness
    assert 2 <= per_step[-1].syncs <= allowed + 4, per_step[-1].summary()
    assert end.syncs == 1, end.summary()
    assert frames == 2 and math.isfinite(means["loss_total"]) and set(values) <= set(means)


def test_fp16_reads_only_the_grad_scaler(tmp_path, params_dict):
    """float16's one exception: the GradScaler's own reads (its scale, its check for an inf among
    the gradients before it steps). Nothing else of the step reads the device."""
    params = _tiny(params_dict, "fp16")
    cache = make_cache(tmp_path / "cache", size=16, counts=(2, 1, 1))
    run, batch = _run(params, "compact_15l", None, cache, tmp_path / "run")
    with Census("cpu", optimizer_step_counters(run.optimizer)) as c:
        train_step(run, batch, 0, 3)
    assert c.syncs >= 1
    assert all("training/epoch.py" in site for site in c.sites), c.summary()
    from compact_perception.learning.training import epoch as epoch_mod

    text = Path(epoch_mod.__file__).read_text().splitlines()
    lines = [text[int(site.rsplit(":", 1)[1]) - 1] for site in c.sites]
    assert all("scaler." in line for line in lines), lines


# ----------------------------------------------------------------------------- the epoch's sums
def test_device_sums_are_the_python_float_sums_bit_for_bit():
    """EpochSums adds what a Python float accumulation of every step's read value did, in the same
    IEEE operations (the training history's bytes depend on it)."""
    g = torch.Generator().manual_seed(0)
    values = [torch.randn((), generator=g) * 10 ** int(torch.randint(-8, 8, (), generator=g)) for _ in range(200)]
    values += [torch.tensor(-0.0), torch.tensor(1e-45), torch.tensor(3.4e38)]
    sums, py, n = EpochSums(), {}, 0.0
    for k, v in enumerate(values):
        frames = 1 + k % 6
        for key, x in (("a", v), ("b", v.double() * 1.0000001)):
            sums.add({key: x}, frames)
            py[key] = py.get(key, 0.0) + float(x) * frames
        sums.n += frames
        n += frames
    means, _ = sums.means()
    assert means == {k: s / n for k, s in py.items()}
    assert [math.copysign(1, means[k]) for k in means] == [math.copysign(1, py[k] / n) for k in py]


def test_a_nan_loss_mid_epoch_stops_at_the_last_step_before_its_update(tmp_path, params_dict, monkeypatch):
    """A nan loss at step 1 of 3 is not read there; the epoch's last step reads when each loss was
    first non-finite, names the task that was (as a check of every step would: ss, though every
    loss is nan by then) and stops before its weighting update and optimiser step."""
    from compact_perception.learning.training import epoch as epoch_mod

    params = _tiny(params_dict, "fp32")
    cache = make_cache(tmp_path / "cache", size=16, counts=(2, 1, 1))
    run, batch = _run(params, "compact_15l_mgn", None, cache, tmp_path / "run")
    real = epoch_mod.scale_de_loss
    poison = {"on": False}

    def scaled(losses, factor):
        out = real(losses, factor)
        return {k: v * float("nan") if poison["on"] and k == "ss" else v for k, v in out.items()}

    monkeypatch.setattr(epoch_mod, "scale_de_loss", scaled)
    train_step(run, batch, 0, 3)
    poison["on"] = True
    train_step(run, batch, 1, 3)  # no read: the run goes on
    poison["on"] = False
    params_before = [p.detach().clone() for p in run.model.parameters()]
    w_before, updates = run.weighting.w.clone(), run.weighting.n_updates
    with pytest.raises(NonFinite, match=r"^non-finite ss loss \(nan\)$"):
        train_step(run, batch, 2, 3)
    unchanged = [torch.allclose(a, p.detach(), rtol=0, atol=0, equal_nan=True)  # step 1's nan reached them
                 for a, p in zip(params_before, run.model.parameters())]
    assert all(unchanged)
    assert torch.equal(run.weighting.w, w_before) and run.weighting.n_updates == updates


def test_non_finite_weights_are_found_at_the_epoch_read(tmp_path, params_dict):
    params = _tiny(params_dict, "fp32")
    cache = make_cache(tmp_path / "cache", size=16, counts=(2, 1, 1))
    run, batch = _run(params, "compact_15l", "gradnorm", cache, tmp_path / "run")
    train_step(run, batch, 0, 1)
    run.weighting.set_weights(torch.tensor([1.0, float("nan"), 1.0, 1.0], dtype=torch.float64))
    with pytest.raises(NonFinite, match=r"^non-finite gradnorm loss weights \(\[1\.0, nan, 1\.0, 1\.0\]\)$"):
        epoch_means(run)


# ----------------------------------------------------------------------------- the baselines' losses
def _labelled_case(views: int | None, seed: int = 0):
    from compact_perception.data.loader import one_hot

    g = torch.Generator().manual_seed(seed)
    shape = (3, views, 8, 8) if views else (3, 8, 8)
    labels = torch.randint(0, 5, shape, generator=g, dtype=torch.uint8)
    labels[torch.rand(shape, generator=g) < 0.3] = 255
    labels[labels == 2] = 4  # class 2 absent: Lovasz leaves it out
    target = one_hot(labels, 5, dim=2 if views else 1)
    logits = torch.randn(target.shape, generator=g, requires_grad=True)
    return labels, target, logits


def test_losses_with_host_labelled_pixels_are_the_mask_path_bit_for_bit():
    """Cross entropy and Lovasz-softmax given the labelled pixels found on the host
    (data.labelled_pixels) compute the same values and gradients, bit for bit, as with the boolean
    mask they take on the device, without reading the device."""
    from compact_perception.learning import losses as L
    from compact_perception.data.loader import labelled_pixels

    for seed in range(3):
        labels, target, logits = _labelled_case(None, seed)
        lab = labelled_pixels(labels)
        assert lab.classes == tuple(sorted(set(labels[labels != 255].tolist())))
        for fn in (lambda *a: L.cross_entropy_onehot(logits, target, *a[:1]),
                   lambda *a: L.lovasz_softmax(torch.softmax(logits, 1), target, *a)):
            ref = fn()
            (g_ref,) = torch.autograd.grad(ref, logits)
            with Census("cpu") as c:
                got = fn(lab.views[0], lab.classes)
                (g_got,) = torch.autograd.grad(got, logits)
            assert c.syncs == 0, c.summary()
            assert torch.equal(got, ref) and torch.equal(g_got, g_ref)
    labels, target, logits = _labelled_case(4)  # per view (GradNorm's SegNet)
    lab = labelled_pixels(labels)
    for v in range(4):
        ref = L.cross_entropy_onehot(logits[:, v], target[:, v])
        assert torch.equal(L.cross_entropy_onehot(logits[:, v], target[:, v], lab.views[v]), ref)
    empty = labelled_pixels(torch.full((2, 4, 4), 255, dtype=torch.uint8))
    assert empty.views[0].numel() == 0 and empty.classes == ()
    assert float(L.cross_entropy_onehot(torch.zeros(2, 3, 4, 4), torch.zeros(2, 3, 4, 4), empty.views[0])) == 0.0


def test_the_loader_finds_the_labelled_pixels_a_model_asks_for(tmp_path):
    from compact_perception.data.loader import Labelled, to_device

    cache = make_cache(tmp_path / "cache", size=16, counts=(2, 1, 1))
    plain = next(iter(make_loader(cache, "train", 15, 2)))
    batch = next(iter(make_loader(cache, "train", 15, 2, labelled=("ls", "ss"))))
    assert "labelled" not in plain and set(batch["labelled"]) == {"ls", "ss"}
    lab = batch["labelled"]["ss"]
    assert isinstance(lab, Labelled) and len(lab.views) == batch["ss"].shape[1]
    assert all(torch.equal(plain[k], batch[k]) for k in plain)
    moved = to_device(batch, "cpu", 23)
    assert isinstance(moved["labelled"]["ls"], Labelled)
    assert torch.equal(moved["labelled"]["ls"].views[0], torch.nonzero(batch["ls"].reshape(-1) != 255).reshape(-1))


def test_a_pinning_loader_pins_the_labelled_pixel_lists(tmp_path, stand_in_pinning):
    """Issue 55 item 4: a DataLoader with ``pin_memory=True`` (as training builds it on a GPU) returns
    PolarNet's and GradNorm SegNet's labelled-pixel lists pinned, like the batch's tensors. The CPU
    build cannot pin: a stand-in accelerator and ``Tensor.pin_memory`` (a pinned copy, marked)."""
    from compact_perception.data.loader import Labelled, make_loader

    pinned = stand_in_pinning
    cache = make_cache(tmp_path / "cache", size=16, counts=(2, 1, 1))
    loader = make_loader(cache, "train", 15, 2, shuffle=False, pin_memory=True, labelled=("ss", "ls"))
    batch = next(iter(loader))
    assert id(batch["rgb"]) in pinned  # the loader pins (the stand-in works)
    for key in ("ss", "ls"):
        lab = batch["labelled"][key]
        assert isinstance(lab, Labelled) and lab.views
        assert all(id(v) in pinned for v in lab.views), f"{key}'s labelled pixels are not pinned"


def _bench_census():
    import importlib
    import sys as _sys

    root = Path(__file__).resolve().parents[1]
    _sys.path.insert(0, str(root / "benchmarks"))
    try:
        return importlib.import_module("bench_census")
    finally:
        _sys.path.remove(str(root / "benchmarks"))


def test_bench_census_times_real_replays_and_says_so(tmp_path, params_dict):
    """Issue 55 item 3: the census's captured rate is timed over replays after a warm-up epoch (a
    stand-in for the graph: the uncaptured buffer path), not eager steps of a fresh run; a step that
    falls back is reported as not captured, with no rate."""
    from compact_perception.learning.training.capture import CapturedStep, Uncaptured

    bc = _bench_census()
    cache = make_cache(tmp_path / "cache", size=16, counts=(2, 1, 1))
    params = bc.make_params(torch.device("cpu"), "fp32", 2)
    run = bc.build(params, "compact_15l", None, torch.device("cpu"), cache, tmp_path / "r")
    batch = bc.first_batch(cache, "compact_15l", 2, run, torch.device("cpu"))
    run.captured = CapturedStep(run, Uncaptured())
    rate, why = bc.captured_samples_per_s(run, batch, 3)
    assert rate is not None and rate > 0 and why == "" and run.captured.failed is None
    assert run.captured.replays == 4 + 1 + 3  # the warm-up epoch's 4, the recapture's checked one, 3 timed

    run2 = bc.build(params, "compact_15l", None, torch.device("cpu"), cache, tmp_path / "r2")
    run2.captured = CapturedStep(run2, nudged_replay(run2))
    rate, why = bc.captured_samples_per_s(run2, batch, 3)
    assert rate is None and "eager step's bytes" in why


@pytest.mark.parametrize("flags", [["--size", "0"], ["--batch", "0"], ["--side-by-side", "0"], ["--size", "100000"],
                                   ["--only", "no_such_model"]])
def test_bench_census_refuses_bad_flags_in_one_line(flags):
    """Issue 56 item 7: each bad flag is one line ``error: --flag: ...`` and exit 1, before any work."""
    import subprocess
    import sys as _sys

    root = Path(__file__).resolve().parents[1]
    proc = subprocess.run([_sys.executable, str(root / "benchmarks" / "bench_census.py"), *flags], cwd=root,
                          capture_output=True, text=True, timeout=120)
    lines = (proc.stdout + proc.stderr).strip().splitlines()
    assert proc.returncode == 1 and len(lines) == 1 and lines[0].startswith(f"error: {flags[0]}: "), lines
