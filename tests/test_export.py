"""ONNX export and ONNX Runtime timing (issue 15), Table III's ONNX Runtime columns, and the
device-generic inference timing of the GPU benchmark path, on the CPU."""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest
import torch
from torch import nn

pytest.importorskip("onnxruntime")
pytest.importorskip("onnx")

from compact_perception.learning.onnx_export import export_onnx, onnxruntime_latency  # noqa: E402
from compact_perception.learning.models import build_model  # noqa: E402
from compact_perception.evaluation import efficiency as eff  # noqa: E402
from compact_perception.report.tables.table3 import build_table3, table3_csv, table3_markdown  # noqa: E402
from compact_perception.evaluation.timing import Variant, benchmark_variants, build_inference, default_variants  # noqa: E402

#: |ONNX Runtime - PyTorch| on the compact model at 32 px (float32 both sides; measured ~2e-6:
#: operator fusion and summation order only).
ONNX_ATOL = 1e-4
SIZE = 32


class TinyDict(nn.Module):
    """A dict-in / dict-out stand-in for the compact model (inputs rgb, dvs, lidar)."""

    has_dvs = True

    def __init__(self) -> None:
        super().__init__()
        self.conv = nn.Conv2d(3 + 2 + 1, 4, 3, padding=1)
        self.bn = nn.BatchNorm2d(4)

    def forward(self, b: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        x = torch.cat([b["rgb"][:, 0], b["dvs"][:, 0], b["lidar"][:, :1]], dim=1)
        y = torch.relu(self.bn(self.conv(x)))
        return {"seg": torch.sigmoid(y), "depth": y.mean(dim=1, keepdim=True)}


def _tiny_batch(size: int = 8) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(0)
    return {"rgb": torch.rand(1, 4, 3, size, size, generator=g), "dvs": torch.rand(1, 4, 2, size, size, generator=g),
            "lidar": torch.rand(1, 15, size, size, generator=g)}


@pytest.fixture(scope="module")
def compact_export(tmp_path_factory: pytest.TempPathFactory) -> tuple[nn.Module, dict, dict]:
    torch.manual_seed(0)
    model = build_model("compact_15l", "A")                 # left in train mode on purpose
    batch = eff.dummy_batch(model, n_seg=23, has_dvs=True, resolution=SIZE)
    info = export_onnx(model, batch, tmp_path_factory.mktemp("onnx") / "compact_15l.onnx")
    return model, batch, info


def test_export_compact_matches_pytorch(compact_export: tuple) -> None:
    model, batch, info = compact_export
    assert Path(info["path"]).is_file() and info["inputs"] == ["rgb", "dvs", "lidar"]
    assert info["outputs"] == ["de", "ss", "ls", "bevp"]
    assert set(info["max_abs_diff"]) == set(info["outputs"])
    assert 0.0 <= info["max_abs_diff_all"] < ONNX_ATOL, info["max_abs_diff"]
    assert model.training                                     # the caller's model is untouched
    assert not list(Path(info["path"]).parent.glob(".*.tmp"))  # no temporary left behind


def test_export_is_deterministic_and_no_dvs_model(compact_export: tuple, tmp_path: Path) -> None:
    model, batch, info = compact_export
    again = export_onnx(model, batch, tmp_path / "again.onnx")
    digest = [hashlib.sha256(Path(p).read_bytes()).hexdigest() for p in (info["path"], again["path"])]
    assert digest[0] == digest[1]
    torch.manual_seed(0)
    nus = build_model("compact_1l", "nuscenes")              # no DVS: inputs rgb, lidar
    b = eff.dummy_batch(nus, n_seg=32, has_dvs=False, resolution=16)
    r = export_onnx(nus, b, tmp_path / "nus.onnx")
    assert r["inputs"] == ["rgb", "lidar"] and r["max_abs_diff_all"] < ONNX_ATOL


def test_onnxruntime_latency(compact_export: tuple) -> None:
    _, batch, info = compact_export
    med = onnxruntime_latency(info["path"], batch, warmup=1, runs=3)
    times = onnxruntime_latency(info["path"], batch, warmup=0, runs=3, return_all=True)
    assert isinstance(med, float) and med > 0 and len(times) == 3  # type: ignore[arg-type]
    with pytest.raises(KeyError, match="missing"):
        onnxruntime_latency(info["path"], {"rgb": batch["rgb"]}, warmup=0, runs=1)
    with pytest.raises(ValueError):
        onnxruntime_latency(info["path"], batch, warmup=0, runs=0)


def test_measure_onnx_keys_and_ratio() -> None:
    torch.manual_seed(0)
    r = eff.measure_onnx(TinyDict(), _tiny_batch(), warmup=1, runs=3, pytorch_cpu_latency_ms=2.0)
    assert r["onnx_latency_ms"] > 0 and r["onnx_fps"] == pytest.approx(1e3 / r["onnx_latency_ms"])
    assert r["onnx_speedup"] == pytest.approx(2.0 / r["onnx_latency_ms"])
    assert r["onnx_max_abs_diff"] < ONNX_ATOL and r["onnx_device"].startswith("CPU (")
    bad = eff.measure_onnx(TinyDict(), {"rgb": torch.rand(1, 4, 3, 8, 8)}, warmup=0, runs=1)
    assert "onnx_error" in bad                                 # reported, not raised


def test_table3_has_onnx_columns() -> None:
    base = {"params": 10, "size_mb": 0.1, "peak_memory_mb": 1.0, "fps": 50.0, "latency_ms": 20.0, "device": "CPU (2 threads)"}
    models = {m: dict(base) for m in ("compact_1l", "compact_15l", "polarnet")}
    models["compact_15l"].update(onnx_fps=200.0, onnx_latency_ms=5.0, onnx_max_abs_diff=2e-6, onnxruntime="1.x",
                                 onnx_device="CPU (2 threads)", onnx_opset=17)
    effj = {"device": "CPU (2 threads)", "is_gpu": False, "resolution": 32, "warmup": 1, "runs": 3,
            "memory_method": "hooks", "models": {"A": models}}
    tables = build_table3(json.loads(json.dumps(effj)))
    rows = {r.row_id: r for r in tables["A"]}
    assert rows["compact_15l"].value("onnx_fps") == 200.0 and rows["compact_1l"].value("onnx_fps") is None
    md = table3_markdown(tables, effj)
    assert "ONNX Runtime FPS (CPU)" in md and "| 200.00 | 5.00 |" in md and "ONNX Runtime 1.x" in md
    header = md.splitlines()[0].count("|")
    assert all(line.count("|") == header for line in md.splitlines()[:6])
    assert "onnx_latency_ms" in table3_csv(tables, effj).splitlines()[0]


# ----------------------------------------------------------------------------- timing (GPU path, on CPU)
def test_build_inference_on_cpu_skips_cuda_graphs() -> None:
    fn, info, b = build_inference(TinyDict(), _tiny_batch(), "cpu", Variant("g", cuda_graph=True, channels_last=True))
    assert info["cuda_graph"] is False and "CUDA graphs need a CUDA device" in info["note"]
    with torch.inference_mode():
        out = fn(b)
    assert out["seg"].shape == (1, 4, 8, 8)
    assert [v.name for v in default_variants("cpu")] == ["fp32", "bf16", "channels_last", "bf16+channels_last"]


def test_benchmark_variants_on_cpu() -> None:
    torch.manual_seed(0)
    variants = [Variant("fp32"), Variant("bf16", "bf16"), Variant("channels_last", channels_last=True),
                Variant("bad", "fp8")]
    res = {r["name"]: r for r in benchmark_variants(TinyDict(), _tiny_batch(), "cpu", variants, warmup=1, runs=3)}
    assert res["fp32"]["max_abs_diff"] == 0.0 and res["fp32"]["speedup"] == pytest.approx(1.0)
    assert res["bf16"]["max_abs_diff"] < 0.05 and res["bf16"]["latency_ms"] > 0
    assert res["channels_last"]["max_abs_diff"] < 1e-5
    assert "error" in res["bad"] and "speedup" not in res["bad"]
