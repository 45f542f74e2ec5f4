"""Issue 55 item 2: one determinism and precision policy (``train.deterministic``, ``train.tf32``;
core/determinism.apply_policy) in every stage that runs a network, not only in training: the
evaluation, the benchmark stage's Table III and bench_gpu start with PyTorch's TF32 flags as the
policy says (PyTorch's own default lets cuDNN run float32 convolutions in TF32). The flags are
settable on a CPU; a stand-in stops each stage right after its start."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch
import yaml

ROOT = Path(__file__).resolve().parents[1]


class Started(Exception):
    """Raised by a stand-in where the stage would run its first network."""


def _stop(*_a, **_k):
    raise Started


@pytest.fixture()
def tf32_on():
    """PyTorch's defaults for a process that never applied the policy (cuDNN TF32 on), put back after."""
    saved = (torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32, torch.backends.cudnn.deterministic,
             torch.backends.cudnn.benchmark, torch.are_deterministic_algorithms_enabled(),
             torch.is_deterministic_algorithms_warn_only_enabled())
    torch.backends.cuda.matmul.allow_tf32 = True
    torch.backends.cudnn.allow_tf32 = True
    torch.backends.cudnn.deterministic = False
    torch.use_deterministic_algorithms(False)
    yield
    (torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32, torch.backends.cudnn.deterministic,
     torch.backends.cudnn.benchmark) = saved[:4]
    torch.use_deterministic_algorithms(saved[4], warn_only=saved[5])


def _as_policy_says(tf32: bool, deterministic: bool) -> None:
    """The policy's flags as a CPU stage sets them; ``use_deterministic_algorithms`` is left as it
    was on a CPU outside training (the fixture turned it off): its memory filling would slow a CPU
    forward for no change of output (``test_a_cpu_stage_keeps_its_speed``)."""
    assert torch.backends.cudnn.allow_tf32 is tf32 and torch.backends.cuda.matmul.allow_tf32 is tf32
    assert torch.backends.cudnn.deterministic is deterministic
    assert torch.are_deterministic_algorithms_enabled() is False


@pytest.mark.parametrize("tf32, deterministic", [(False, True), (True, False)])
def test_evaluation_starts_under_the_policy(params_dict, monkeypatch, tf32_on, tf32, deterministic):
    from compact_perception.core.params import parse_params
    from compact_perception.evaluation import evaluate
    from compact_perception.learning.plan import planned_run

    params_dict["train"].update(device="cpu", tf32=tf32, deterministic=deterministic)
    params = parse_params(params_dict)
    monkeypatch.setattr(evaluate, "read_meta", _stop)  # the run's first read: the network comes next
    with pytest.raises(Started):
        evaluate.evaluate_run(params, planned_run(params, "A", "compact_15l", 0))
    _as_policy_says(tf32, deterministic)


def test_the_benchmark_stage_starts_under_the_policy(params_dict, monkeypatch, tmp_path, tf32_on):
    import pipeline.benchmark as bench

    params_dict["train"].update(device="cpu", tf32=False, deterministic=True)
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(params_dict, sort_keys=False))
    monkeypatch.setattr(bench, "build_model", _stop)
    with pytest.raises((Started, SystemExit)) as err:
        bench.main(["--params", str(path), "--datasets", "A", "--models", "compact_1l", "--no-onnx",
                    "--out", str(tmp_path / "efficiency.json")])
    assert err.type is Started or err.value.code in (None, 0) or "Started" in str(err.value)
    _as_policy_says(False, True)


def test_bench_gpu_starts_under_the_policy(monkeypatch, tf32_on):
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        import bench_gpu
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    committed = yaml.safe_load((ROOT / "params.yaml").read_text())["train"]
    monkeypatch.setattr(bench_gpu, "build_model", _stop)
    monkeypatch.setattr(sys, "argv", ["bench_gpu.py", "--device", "cpu"])
    with pytest.raises(Started):
        bench_gpu.main()
    _as_policy_says(bool(committed["tf32"]), bool(committed["deterministic"]))


def test_a_cpu_stage_keeps_its_speed(tf32_on) -> None:
    """On a CUDA device the policy is set_determinism whole; on a CPU it leaves
    use_deterministic_algorithms off, so evaluation and Table III's CPU timings are as before."""
    from types import SimpleNamespace

    from compact_perception.core import determinism

    calls = []
    train = SimpleNamespace(deterministic=True, tf32=False)
    determinism.apply_policy(torch.device("cpu"), train)
    assert torch.are_deterministic_algorithms_enabled() is False
    real = determinism.set_determinism
    try:
        determinism.set_determinism = lambda *a: calls.append(a)
        determinism.apply_policy(torch.device("cuda"), train)
    finally:
        determinism.set_determinism = real
    assert calls == [(torch.device("cuda"), True, False)]
