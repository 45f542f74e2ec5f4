"""Batch normalisation folded into the convolutions for inference (timing.fold_batchnorm): the folded
compact network equals the unfolded one within FOLD_TOLERANCE, on the CPU; a batch norm whose
convolution's output is read elsewhere too is not folded, or the fold is refused."""
from __future__ import annotations

import pytest
import torch
from torch import nn

from compact_perception.evaluation.efficiency import dummy_batch
from compact_perception.learning.models import DATASET_SPECS, build_model
from compact_perception.learning.models.blocks import ConvBlock
from compact_perception.evaluation.timing import FOLD_TOLERANCE, Variant, build_inference, fold_batchnorm, max_abs_diff


def _trained_statistics(model: nn.Module, batch: dict) -> nn.Module:
    """The network with running statistics away from their initial 0 / 1 and affine terms away
    from 1 / 0, as a trained network has them."""
    g = torch.Generator().manual_seed(1)
    for m in model.modules():
        if isinstance(m, nn.BatchNorm2d):
            with torch.no_grad():
                m.weight.copy_(0.5 + torch.rand(m.weight.shape, generator=g))
                m.bias.copy_(torch.randn(m.bias.shape, generator=g) * 0.1)
    model.train()
    with torch.no_grad():
        model(batch)
        model(batch)
    return model.eval()


@pytest.mark.parametrize("model_id", ["compact_15l", "compact_1l"])
def test_the_folded_compact_network_equals_the_unfolded_one(model_id):
    torch.manual_seed(0)
    spec = DATASET_SPECS["A"]
    model = build_model(model_id, "A")
    batch = dummy_batch(model, n_seg=spec.n_seg, has_dvs=spec.has_dvs, resolution=32)
    model = _trained_statistics(model, batch)
    before = {k: v.clone() for k, v in model.state_dict().items()}
    folded, n = fold_batchnorm(model, batch)
    blocks = sum(isinstance(m, ConvBlock) for m in model.modules())
    assert n == 2 * blocks and n > 0  # every batch norm of the network follows a convolution
    assert not any(isinstance(m, nn.BatchNorm2d) for m in folded.modules())
    with torch.no_grad():
        diff = max_abs_diff(folded(batch), model(batch))
    assert diff <= FOLD_TOLERANCE
    assert diff > 0  # the merged weights round differently: equal within the tolerance, not bit for bit
    assert all(torch.equal(v, model.state_dict()[k]) for k, v in before.items())  # the original is untouched
    other = dummy_batch(model, n_seg=spec.n_seg, has_dvs=spec.has_dvs, resolution=64)  # any input, not just the probe
    with torch.no_grad():
        assert max_abs_diff(folded(other), model(other)) <= FOLD_TOLERANCE


class _SharedOutput(nn.Module):
    """A convolution whose output a batch norm and another module both read."""

    def __init__(self) -> None:
        super().__init__()
        self.conv, self.bn, self.tap = nn.Conv2d(3, 4, 3, padding=1), nn.BatchNorm2d(4), nn.Conv2d(4, 4, 1)

    def forward(self, batch: dict) -> dict:
        y = self.conv(batch["rgb"])
        return {"out": self.bn(y) + self.tap(y)}


class _Residual(_SharedOutput):
    """A convolution whose output a batch norm and a plain addition read (no module to see it)."""

    def forward(self, batch: dict) -> dict:
        y = self.conv(batch["rgb"])
        return {"out": self.bn(y) + y}


def test_a_convolution_read_elsewhere_too_is_not_folded():
    torch.manual_seed(0)
    batch = {"rgb": torch.randn(2, 3, 8, 8)}
    shared = _trained_statistics(_SharedOutput(), batch)
    folded, n = fold_batchnorm(shared, batch)
    assert n == 0 and isinstance(folded.bn, nn.BatchNorm2d)
    with pytest.raises(ValueError, match="changes the outputs"):
        fold_batchnorm(_trained_statistics(_Residual(), batch), batch)


def test_a_fold_bn_variant_runs_on_the_cpu():
    torch.manual_seed(0)
    spec = DATASET_SPECS["A"]
    model = build_model("compact_1l", "A").eval()
    batch = dummy_batch(model, n_seg=spec.n_seg, has_dvs=spec.has_dvs, resolution=32)
    fn, info, b = build_inference(model, batch, "cpu", Variant("fp32+fold_bn+channels_last", channels_last=True,
                                                                fold_bn=True))
    assert info["bn_folded"] > 0
    with torch.inference_mode():
        assert max_abs_diff(fn(b), model(batch)) <= FOLD_TOLERANCE
    assert any(isinstance(m, nn.BatchNorm2d) for m in model.modules())


# ----------------------------------------------------------------------------- Table III at the hardware's pace
def test_fastest_exact_picks_the_fastest_within_the_tolerance():
    from compact_perception.evaluation.timing import EXACT_TOLERANCE, fastest_exact

    results = [{"name": "fp32", "fps": 10.0, "max_abs_diff": 0.0},
               {"name": "bf16_weights", "fps": 50.0, "max_abs_diff": 4e-3},          # faster, not exact
               {"name": "fp32+fold_bn", "fps": 14.0, "max_abs_diff": 2e-6},
               {"name": "fp32+fold_bn+cuda_graph", "error": "RuntimeError: no CUDA"},
               {"name": "fp32+cuda_graph", "fps": 30.0, "max_abs_diff": EXACT_TOLERANCE * 2}]
    assert fastest_exact(results)["name"] == "fp32+fold_bn"
    assert fastest_exact(results, tolerance=1e-2)["name"] == "bf16_weights"
    assert fastest_exact([{"name": "x", "error": "e"}]) is None


def test_table3_inference_on_a_cpu_times_every_variant_and_names_the_fastest_exact():
    """The benchmark stage's CUDA path, on a CPU (no CUDA graphs): float32 eager beside the fastest
    variant within the exact tolerance; the network cast to bf16 (weights and inputs, no autocast)
    runs and is reported, but its outputs are too far from float32 to count as exact."""
    from compact_perception.evaluation.efficiency import dummy_batch
    from compact_perception.learning.models import build_model
    from compact_perception.evaluation.timing import EXACT_TOLERANCE, table3_inference, table3_variants

    torch.manual_seed(0)
    model = build_model("compact_15l", "A").eval()
    batch = dummy_batch(model, n_seg=23, has_dvs=True, resolution=32, device="cpu")
    names = [v.name for v in table3_variants("cpu")]
    assert names[0] == "fp32" and not any("cuda_graph" in n for n in names) and "bf16_weights+fold_bn" in names
    out = table3_inference(model, batch, "cpu", warmup=1, runs=2)
    assert out["eager_fp32"]["name"] == "fp32" and out["eager_fp32"]["max_abs_diff"] == 0.0
    best = out["fastest_exact"]
    assert best["max_abs_diff"] <= EXACT_TOLERANCE and best["fps"] >= out["eager_fp32"]["fps"]
    low = next(r for r in out["variants"] if r["name"] == "bf16_weights+fold_bn")
    assert "error" not in low and low["max_abs_diff"] > EXACT_TOLERANCE
    assert next(p for p in model.parameters()).dtype == torch.float32  # the caller's network is left as it was
