"""Fast path (issue 15): precision rules, autocast, gradient scaler, channels-last, compile
fallback, and MGN / GradNorm gradient norms in float32 under bf16 autocast (on the CPU)."""
from __future__ import annotations

import logging
import warnings

import pytest
import torch
from torch import nn

from compact_perception.learning.training import precision as P
from compact_perception.learning.models import build_model
from compact_perception.learning.weighting import GradNormWeighting, MGNWeighting

#: bf16 vs fp32 after one weight update (compact 15L, 16 px, batch 2): the gradient norms agree
#: within 15 % (relative; a bf16 forward keeps ~3 significant digits per op, compounded over
#: ~30 conv layers: measured up to 7 %) and the loss weights (sum 4) within 0.01 absolute
#: (measured <= 0.003).
NORM_RTOL = 0.15
WEIGHT_ATOL = 0.01
SIZE = 16  # px: small enough for emulated bf16 on a CPU; at 8 px the bottleneck is 1x1 and BN over 2 values amplifies rounding


def _batch(model: nn.Module, size: int, n: int = 2, seed: int = 0) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)

    def onehot(lead: tuple[int, ...], c: int) -> torch.Tensor:
        idx = torch.randint(0, c, (*lead, size, size), generator=g)
        return nn.functional.one_hot(idx, c).movedim(-1, len(lead)).float()

    return {
        "rgb": torch.rand(n, 4, 3, size, size, generator=g),
        "dvs": (torch.rand(n, 4, 2, size, size, generator=g) > 0.9).float(),
        "lidar": torch.rand(n, model.lidar_channels, size, size, generator=g),
        "de": torch.rand(n, 4, 1, size, size, generator=g),
        "ss": onehot((n, 4), model.n_seg),
        "ls": onehot((n,), model.n_seg),
        "bevp": (torch.rand(n, model.n_bev, size, size, generator=g) > 0.8).float(),
    }


# ----------------------------------------------------------------------------- resolve_precision
def _fake_cuda(monkeypatch: pytest.MonkeyPatch, cc: tuple[int, int], bf16: bool) -> None:
    monkeypatch.setattr(P, "_cuda_capability", lambda device: cc)
    monkeypatch.setattr(torch.cuda, "is_bf16_supported", lambda including_emulation=True: bf16)
    monkeypatch.setattr(torch.cuda, "get_device_name", lambda device=None: "Fake GPU")


@pytest.mark.parametrize("flags,expected", [
    (frozenset({"avx2", "fma"}), "fp32"),                       # AVX2-only: bf16 would be emulated
    (frozenset({"avx2", "avx512f", "avx512bw"}), "fp32"),       # AVX-512 without BF16
    (frozenset({"avx512f", "avx512_bf16"}), "bf16"),
    (frozenset({"avx512f", "amx_tile", "amx_bf16"}), "bf16"),   # Sapphire Rapids and later (AMX)
    (frozenset({"asimd", "bf16"}), "bf16"),                     # Armv8.6 BF16
])
def test_auto_on_cpu_follows_native_bf16(monkeypatch: pytest.MonkeyPatch, flags: frozenset, expected: str) -> None:
    monkeypatch.setattr(P, "cpu_flags", lambda: flags)
    assert P.resolve_precision("auto", "cpu") == expected
    assert P.resolve_precision("fp32", "cpu") == "fp32"


@pytest.mark.parametrize("cc,bf16,expected", [((9, 0), True, "bf16"), ((8, 0), True, "bf16"),
                                               ((7, 5), False, "fp16"), ((7, 0), False, "fp16"),
                                               ((6, 1), False, "fp32")])
def test_auto_on_cuda(monkeypatch: pytest.MonkeyPatch, cc: tuple[int, int], bf16: bool, expected: str) -> None:
    _fake_cuda(monkeypatch, cc, bf16)
    assert P.resolve_precision("auto", "cuda") == expected
    assert P.resolve_precision("fp16", "cuda") == "fp16"


def test_explicit_choices_and_errors(monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    monkeypatch.setattr(P, "cpu_flags", lambda: frozenset({"avx2"}))
    with caplog.at_level(logging.WARNING, logger="compact_perception.learning.training.precision"):
        assert P.resolve_precision("bf16", "cpu") == "bf16"        # honoured, with a warning
    assert "emulated" in caplog.text
    with pytest.raises(ValueError, match="train.precision"):
        P.resolve_precision("float16", "cpu")
    _fake_cuda(monkeypatch, (7, 5), False)
    with pytest.raises(ValueError, match="no native bfloat16"):
        P.resolve_precision("bf16", "cuda")


def test_cpu_flags_parse_this_machine() -> None:
    flags = P.cpu_flags()
    assert isinstance(flags, frozenset)
    assert P.cpu_has_native_bf16() == bool(flags & P.CPU_BF16_FLAGS)


# ----------------------------------------------------------------------------- autocast / scaler
def test_autocast_contexts_on_cpu() -> None:
    conv = nn.Conv2d(3, 4, 3, padding=1)
    x = torch.rand(1, 3, 8, 8)
    with P.autocast_context("cpu", "fp32"):
        assert conv(x).dtype == torch.float32 and not torch.is_autocast_enabled("cpu")
    with P.autocast_context("cpu", "bf16"):
        y = conv(x)
    assert y.dtype == torch.bfloat16
    assert torch.allclose(y.float(), conv(x), atol=0.05)
    with pytest.raises(ValueError, match="resolve 'auto' first"):
        P.autocast_context("cpu", "auto")
    out = P.float_outputs({"a": y, "b": x, "i": torch.arange(3)})
    assert out["a"].dtype == torch.float32 and out["b"] is x and out["i"].dtype == torch.int64


def test_grad_scaler_only_for_fp16() -> None:
    assert not P.make_grad_scaler("cpu", "fp32").is_enabled()
    assert not P.make_grad_scaler("cpu", "bf16").is_enabled()
    assert P.make_grad_scaler("cpu", "fp16").is_enabled()
    # disabled: the float32 loop is unchanged (scale is the identity, step is optimiser.step)
    p = nn.Parameter(torch.ones(2))
    opt = torch.optim.SGD([p], lr=0.5)
    s = P.make_grad_scaler("cpu", "fp32")
    loss = (p * 2).sum()
    assert s.scale(loss) is loss
    loss.backward()
    s.unscale_(opt)
    s.step(opt)
    s.update()
    assert torch.equal(p.detach(), torch.zeros(2))


# ----------------------------------------------------------------------------- channels-last
def test_channels_last_conversion_keeps_values_and_outputs() -> None:
    x4, x5 = torch.rand(2, 3, 8, 8), torch.rand(2, 4, 3, 8, 8)
    b = P.batch_to_channels_last({"a": x4, "b": x5, "i": torch.arange(2)})
    assert torch.equal(b["a"], x4) and b["a"].is_contiguous(memory_format=torch.channels_last)
    assert torch.equal(b["b"], x5)
    for v in range(4):                                   # every view has NHWC strides (C fastest, then W, H)
        st = b["b"][:, v].stride()
        assert (st[1], st[3], st[2]) == (1, 3, 8 * 3) and st[0] >= 8 * 8 * 3
    torch.manual_seed(0)
    model = build_model("compact_15l", "A").eval()
    batch = _batch(model, SIZE, n=1)
    with torch.no_grad():
        ref = model(batch)
        P.to_channels_last(model)
        assert model.enc_rgb.level0[0].conv1.weight.is_contiguous(memory_format=torch.channels_last)
        got = model(P.batch_to_channels_last(batch))
    for k in ref:
        assert torch.allclose(got[k], ref[k], atol=1e-5), k


def test_channels_last_on_the_inputs_only_leaves_the_targets_as_they_are() -> None:
    """``train.channels_last: inputs``: the network's inputs in NHWC, every target map untouched
    (the same tensor, no copy)."""
    batch = {"rgb": torch.rand(2, 4, 3, 8, 8), "dvs": torch.rand(2, 4, 2, 8, 8), "lidar": torch.rand(2, 5, 8, 8),
             "de": torch.rand(2, 4, 1, 8, 8), "ss": torch.rand(2, 4, 3, 8, 8), "ls": torch.rand(2, 3, 8, 8),
             "bevp": torch.rand(2, 2, 8, 8), "index": torch.arange(2)}
    b = P.batch_to_channels_last(batch, inputs_only=True)
    assert set(P.INPUT_KEYS) == {"rgb", "dvs", "lidar"}
    assert b["lidar"].is_contiguous(memory_format=torch.channels_last) and not b["lidar"].is_contiguous()
    st = b["rgb"][:, 0].stride()                         # each view NHWC, as for true
    assert (st[1], st[3], st[2]) == (1, 3, 8 * 3)
    assert all(torch.equal(b[k], batch[k]) for k in batch)
    assert all(b[k] is batch[k] for k in ("de", "ss", "ls", "bevp", "index"))


def test_channels_last_inputs_is_a_setting_and_trains(tmp_path, params_dict) -> None:
    """``train.channels_last`` takes true, false or 'inputs' (one message otherwise); a step with
    'inputs' leaves the targets in their own layout and its losses equal true's but in their last
    bits (the sums run in another order), and so do the gradients (the loss's gradient reaches the
    network in the targets' layout: another kernel path)."""
    from compact_perception.core.params import ParamsError, parse_params

    params_dict["train"]["channels_last"] = "no"
    with pytest.raises(ParamsError, match=r"train\.channels_last: .*boolean.*'inputs'"):
        parse_params(params_dict)
    from test_capture import _params, _run  # a run built by the training loop's own setup
    from synthetic import make_cache

    cache = make_cache(tmp_path / "cache", size=16, counts=(2, 1, 1))
    out = {}
    for layout in (True, "inputs"):
        params = _params(params_dict, channels_last=layout)
        run, batches = _run(params, "compact_15l", None, cache, tmp_path / str(layout))
        from compact_perception.learning.training.epoch import prepare_batch, train_step

        ready = prepare_batch(run, batches[0])
        assert ready["bevp"].is_contiguous(memory_format=torch.channels_last) == (layout is True)
        assert ready["lidar"].is_contiguous(memory_format=torch.channels_last)
        values, _ = train_step(run, batches[0], 0, 3)
        out[layout] = (values, [p.grad.clone() for p in run.model.parameters()])
    (v1, g1), (v2, g2) = out[True], out["inputs"]
    assert all(torch.allclose(v1[k], v2[k], rtol=1e-6, atol=0) for k in v1)
    assert all(torch.allclose(a, b, rtol=1e-4, atol=1e-7) for a, b in zip(g1, g2))


# ----------------------------------------------------------------------------- compile fallback
class _Dict(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.lin = nn.Linear(3, 2)

    def forward(self, batch: dict) -> dict:
        if batch["x"].shape[-1] != 3:
            raise ValueError("model error: x must have 3 features")
        return {"y": self.lin(batch["x"])}


def test_compile_disabled_returns_the_model() -> None:
    m = _Dict()
    assert P.maybe_compile(m, False) is m


def test_compile_fallback_warns_once(monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    monkeypatch.setattr(P, "_warned", set())

    def broken_compile(model, **kw):
        raise RuntimeError("Compiler: cc not found")

    monkeypatch.setattr(torch, "compile", broken_compile)
    m1, m2 = _Dict(), _Dict()
    x = {"x": torch.rand(4, 3)}
    with warnings.catch_warnings(record=True) as rec, caplog.at_level(logging.WARNING, "compact_perception.learning.training.precision"):
        warnings.simplefilter("always")
        f1, f2 = P.maybe_compile(m1, True), P.maybe_compile(m2, True)
        assert torch.equal(f1(x)["y"], m1(x)["y"]) and torch.equal(f2(x)["y"], m2(x)["y"])
    assert not f1.compiled and "cc not found" in f1.fallback_reason
    assert sum("torch.compile is unavailable" in str(w.message) for w in rec) == 1
    assert caplog.text.count("torch.compile is unavailable") == 1
    assert f1.lin is m1.lin                              # attributes reach the eager model


def test_compile_failure_at_first_call_falls_back(monkeypatch: pytest.MonkeyPatch) -> None:
    """A missing toolchain shows at the first (compiling) call: one warning, eager from then on;
    the model's own errors still propagate."""
    from torch._inductor.exc import InvalidCxxCompiler

    monkeypatch.setattr(P, "_warned", set())
    calls = {"n": 0}

    def lazy_compile(model, **kw):
        def fn(*a, **k):
            calls["n"] += 1
            raise InvalidCxxCompiler()
        return fn

    monkeypatch.setattr(torch, "compile", lazy_compile)
    m = _Dict()
    f = P.maybe_compile(m, True)
    assert f.compiled
    x = {"x": torch.rand(2, 3)}
    with pytest.warns(RuntimeWarning, match="torch.compile is unavailable"):
        y = f(x)
    assert torch.equal(y["y"], m(x)["y"]) and not f.compiled
    f(x)
    assert calls["n"] == 1                               # never tried again
    g = P.maybe_compile(_Dict(), True)
    with pytest.raises(ValueError, match="model error"):  # not a compiler failure: propagated
        monkeypatch.setattr(torch, "compile", lambda model, **kw: model)
        P.maybe_compile(_Dict(), True)({"x": torch.rand(2, 4)})
    assert g.compiled


# ----------------------------------------------------------------------------- MGN / GradNorm under autocast
# The settings of params.yaml's recipes (Algorithm 1: alpha 1.5, lr 0.1; GradNorm: lr 0.025).
_PLATEAU = {"plateau_patience": 4, "plateau_factor": 0.5, "plateau_rule": "paper"}
_MGN = {"alpha": 1.5, "lr": 0.1, "lr_min": 1e-4, **_PLATEAU}
WEIGHTINGS = {"mgn": (MGNWeighting, _MGN), "gradnorm": (GradNormWeighting, {"alpha": 1.5, "lr": 0.025, **_PLATEAU}),
              "mgn_authors": (MGNWeighting, {**_MGN, "authors_mode": True})}


def _updates(precision: str) -> dict[str, MGNWeighting]:
    """One forward of the compact model in ``precision`` and one weight update of each weighting
    on its losses (the graph is retained, so they share it); for bf16 the updates are called
    inside the autocast context. The losses always come from float32 outputs: in bf16 the BCE
    clamp 1 - 1e-7 rounds to 1 and log(1 - p) is -inf, so losses on bf16 outputs are NaN."""
    torch.manual_seed(0)
    model = build_model("compact_15l", "A").train()
    batch = _batch(model, SIZE)
    torch.manual_seed(1)                                  # the same dropout masks in both runs
    out: dict[str, MGNWeighting] = {}
    with P.autocast_context("cpu", precision):
        losses = model.compute_losses(P.float_outputs(model(batch)), batch)
        for name, (cls, kw) in WEIGHTINGS.items():
            out[name] = cls(model.tasks, model.shared_layers(), **kw)
            out[name].before_backward(0, 1, losses, model)
            out[name].after_backward()
    return out


def test_weights_bf16_autocast_match_fp32() -> None:
    ref, got = _updates("fp32"), _updates("bf16")
    for name in WEIGHTINGS:
        r, g = ref[name], got[name]
        assert torch.isfinite(g.w).all() and float(g.w.sum()) == pytest.approx(4.0), name
        assert torch.allclose(g.w, r.w, atol=WEIGHT_ATOL, rtol=0), (name, g.w, r.w)
        key = "norms" if "norms" in r.last else "G"     # authors' mode: G_i built in float32
        assert g.last[key].dtype == torch.float64
        assert torch.allclose(g.last[key], r.last[key], rtol=NORM_RTOL, atol=0), (name, g.last[key], r.last[key])


def test_grad_scale_is_undone() -> None:
    """With a float16 GradScaler's scale the norms are those of the unscaled losses."""
    torch.manual_seed(0)
    model = build_model("compact_15l", "A").train()
    batch = _batch(model, SIZE, n=1)
    losses = model.compute_losses(model(batch), batch)
    a = MGNWeighting(model.tasks, model.shared_layers(), **_MGN)
    b = MGNWeighting(model.tasks, model.shared_layers(), **_MGN)
    b.grad_scale = 2.0 ** 16
    na, nb = a._grad_norms(losses, model), b._grad_norms(losses, model)
    assert torch.allclose(na, nb, rtol=1e-6, atol=0)
