"""`make gpu-check` on a CPU (benchmarks/gpu_check.py --device cpu --size 32): every check runs
(a precision the CPU only emulates trains the compact models and skips the baselines), the table
is printed and the exit status is 0."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "gpu_check.py"


@pytest.mark.slow
def test_gpu_check_runs_on_a_cpu():
    proc = subprocess.run([sys.executable, str(SCRIPT), "--device", "cpu", "--size", "32"], cwd=ROOT,
                          capture_output=True, text=True, timeout=900)
    out = proc.stdout
    assert proc.returncode == 0, out[-3000:] + proc.stderr[-3000:]
    table = out[out.index("\ncheck "):]
    assert "check" in table and "precision" in table and "seconds" in table and "result" in table
    for model in ("compact_1l", "compact_15l", "compact_15l_mgn_authors (MGN authors update)", "gradnorm_segnet",
                  "polarnet", "chen_bev"):
        assert f"train_step {model}" in table
    assert "MGN w " in table
    rows = [line for line in table.splitlines() if line.startswith("train_step compact_15l_mgn_authors")]
    fp16 = [line for line in rows if " fp16 " in line]
    assert len(fp16) == 1 and "skipped: " not in fp16[0] and "MGN" in fp16[0]  # the authors' update under the scaler
    assert "skipped: emulated fp16" in table       # all but the MGN models: slow in emulated fp16
    captured = [line for line in table.splitlines() if line.startswith("captured step ")]
    assert {line.split()[2] for line in captured} == {"compact_15l_mgn", "chen_bev"}
    assert all("network = eager run's, bit for bit" in line or "skipped: emulated bf16" in line for line in captured)
    assert "pipeline.train (resume, ONNX)" in table and "resumed after epoch 1" in table
    assert "resumed = uninterrupted network (equal values)" in table
    assert "torchrun DDP steps (gloo, every weighting)" in table and "backend gloo" in table
    assert "10 weightings: static, none, mgn, mgn (authors), gradnorm, uw, dwa, pcgrad, cagrad, single" in table
    assert "Table III FPS" in table and "benchmark stage" in table
    assert "skipped: needs CUDA" not in table
    assert " 0 failed" in out


def test_gpu_check_refuses_cuda_without_a_gpu_in_one_line():
    import torch

    if torch.cuda.is_available():
        pytest.skip("a CUDA device is present")
    proc = subprocess.run([sys.executable, str(SCRIPT), "--device", "cuda"], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode != 0
    assert proc.stderr.strip().startswith("error:") and len(proc.stderr.strip().splitlines()) == 1


def _gpu_check():
    import importlib

    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        return importlib.import_module("gpu_check")
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))


def test_one_batch_is_loaded_as_training_loads_it(tmp_path, stand_in_pinning):
    """Issue 55 item 8: gpu-check's batch is pinned on a GPU, as the training stage's loader pins
    it, with the labelled-pixel lists the run's network asks for; on a CPU nothing is pinned. The
    CPU build cannot pin: a stand-in accelerator and ``Tensor.pin_memory`` (a pinned copy, marked)."""
    from types import SimpleNamespace

    import torch

    from synthetic import make_cache

    gc = _gpu_check()
    pinned = stand_in_pinning
    cache = make_cache(tmp_path / "cache", size=16, counts=(2, 1, 1))
    on_cpu = gc.one_batch(cache, "compact_15l", 2)
    assert id(on_cpu["rgb"]) not in pinned and "labelled" not in on_cpu
    on_gpu = gc.one_batch(cache, "compact_15l", 2, torch.device("cuda"))
    assert id(on_gpu["rgb"]) in pinned
    run = SimpleNamespace(spec=SimpleNamespace(device=torch.device("cuda")),
                          model=SimpleNamespace(labelled_maps=("ls",)))  # PolarNet's run on a GPU
    polar = gc.one_batch(cache, "polarnet", 2, run=run)
    assert id(polar["rgb"]) in pinned and set(polar["labelled"]) == {"ls"}
    assert all(id(v) in pinned for v in polar["labelled"]["ls"].views)
