"""The same commit gives the same bytes on any x86-64 machine (AVX2-only or AVX-512/AMX).

One machine plays two: the "other machine" is this one with the environment another CPU
would bring (OpenBLAS picking another core type's kernels, numpy without its AVX2 loops,
PyTorch's ATen and oneDNN on other instruction sets, other thread counts). A tiny pipeline
(generate, preprocess, the simulated nuScenes set and its ingestion, one training run and its
evaluation) runs under both, and every output file must have the same hash. A control run of
the other machine with the pins of :mod:`compact_perception.core.determinism` switched off shows
that the simulation is real: its bytes differ.
"""
from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from repo_params import cap_epochs, set_seeds

pytestmark = pytest.mark.slow

OTHER_MACHINE = {
    "OPENBLAS_CORETYPE": "Prescott",            # OpenBLAS: another core type's kernels
    "NPY_DISABLE_CPU_FEATURES": "AVX2 FMA3",    # numpy: an older CPU's loops
    "ATEN_CPU_CAPABILITY": "default",           # PyTorch: no vectorised ATen kernels
    "ONEDNN_MAX_CPU_ISA": "SSE41",              # oneDNN: other convolution kernels
    "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "2",  # other core counts
}
STAGES = (["generate", "--dataset", "A"], ["preprocess", "--dataset", "A"], ["nuscenes_sim"], ["ingest_nuscenes"],
          ["train", "--dataset", "A"], ["evaluate", "--dataset", "A"])


def _tiny_params(root: Path) -> dict:
    p = yaml.safe_load((root / "params.yaml").read_text())
    p["world"]["resolution"] = {"default": 32, "full": 32, "paper": 128}
    p["world"]["lidar"]["horizontal_samples"] = 256
    p["world"]["frames_per_episode"] = 2
    p["world"]["workers"] = 1
    p["datasets"]["A"]["frames"]["default"] = 10
    p["datasets"]["A"]["split_ratio"]["default"] = {"train": 3, "val": 2, "test": 5}
    p["datasets"]["nuscenes"]["sim_scenes"]["default"] = 5
    p["datasets"]["nuscenes"]["sim_samples_per_scene"] = 2
    cap_epochs(p, 1)
    p["train"]["batch_size"] = 2
    set_seeds(p, [0])
    p["model_ids"] = ["compact_15l"]           # one run: the stage trains and scores it alone
    return p


def _run_machine(root: Path, work: Path, extra_env: dict[str, str], stages=STAGES) -> dict[str, str]:
    work.mkdir(parents=True)
    (work / "params.yaml").write_text(yaml.safe_dump(_tiny_params(root)))
    env = {**os.environ, **extra_env, "PYTHONPATH": os.pathsep.join([str(root), str(root / "src")])}
    for args in stages:
        proc = subprocess.run([sys.executable, "-m", f"pipeline.{args[0]}", *args[1:]], cwd=work, env=env,
                              capture_output=True, text=True)
        assert proc.returncode == 0, f"{args}: {proc.stderr[-3000:]}"
    hashes = {}
    for folder in ("data", "results", "reports"):
        for path in sorted((work / folder).rglob("*")):
            if path.is_file():
                hashes[path.relative_to(work).as_posix()] = hashlib.md5(path.read_bytes()).hexdigest()
    return hashes


def test_other_machine_gives_the_same_bytes(tmp_path, root):
    here = _run_machine(root, tmp_path / "here", {})
    other = _run_machine(root, tmp_path / "other", OTHER_MACHINE)
    assert any(k.startswith("data/raw/nuscenes_sim") for k in here)
    assert "results/A/compact_15l/seed0/metrics.json" in here
    differ = sorted(k for k in here if here[k] != other.get(k))
    assert set(here) == set(other) and not differ, f"files that differ between machines: {differ}"

    # control: without the pins the simulated machine really computes other bytes
    unpinned = _run_machine(root, tmp_path / "unpinned", {**OTHER_MACHINE, "COMPACT_PERCEPTION_UNPINNED": "1"},
                            stages=(STAGES[0], STAGES[1], STAGES[4], STAGES[5]))
    assert any(unpinned[k] != here[k] for k in unpinned if k.startswith("data/raw/A/"))
    key = "results/A/compact_15l/seed0/metrics.json"
    assert unpinned[key] != here[key]


DEPTH_SCRIPT = """
import sys
from compact_perception.core.determinism import pin_numeric_libraries
pin_numeric_libraries()
import numpy as np, pandas as pd, torch, json
from compact_perception.evaluation.evaluate import summarise_depth
from compact_perception.learning.metrics import depth_errors_per_sample
rng = np.random.default_rng(5)                        # numpy's generators: the same numbers on every kernel
gt = torch.from_numpy(rng.random((40, 4, 1, 32, 32)).astype(np.float32))
pred = gt + torch.from_numpy((0.3 * rng.standard_normal((40, 4, 1, 32, 32))).astype(np.float32))  # some > 1, < 0
rows = []
for i in range(40):                                   # batch 1, as evaluation scores the test frames
    e = depth_errors_per_sample(pred[i:i + 1], gt[i:i + 1], 80.0)
    rows.append({k: float(v[0]) for k, v in e.items()})
print(json.dumps(summarise_depth(pd.DataFrame(rows), 80.0), sort_keys=True))
"""


def _depth_summary(root: Path, extra_env: dict[str, str]) -> str:
    env = {**os.environ, **extra_env, "PYTHONPATH": str(root / "src")}
    proc = subprocess.run([sys.executable, "-c", DEPTH_SCRIPT], env=env, capture_output=True, text=True, cwd=root)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout


def test_depth_metrics_reduction_is_the_same_on_another_machine(root):
    """The metric-depth errors (exp, log and sqrt of every pixel, then per-frame sums and the
    mean and variance over frames) write the same bytes under another machine's kernels: the
    per-frame errors come from one frame at a time in float64 and the summary is rounded to
    DEPTH_DIGITS significant digits, below which a last-bit difference of a sum cannot reach."""
    from compact_perception.evaluation.evaluate import DEPTH_DIGITS, _round_sig

    here = _depth_summary(root, {})
    other = _depth_summary(root, OTHER_MACHINE)
    assert '"rmse_m"' in here and '"rmse_log"' in here and here == other
    # and with the pins lifted: ATen's scalar kernels for exp, log and sqrt, numpy without AVX2
    assert _depth_summary(root, {**OTHER_MACHINE, "COMPACT_PERCEPTION_UNPINNED": "1"}) == here
    # a one-ulp change of a mean or variance leaves the written value as it was
    x = 125.60123456789012
    assert _round_sig(x) == _round_sig(float(np.nextafter(x, 0.0))) == _round_sig(float(np.nextafter(x, 1e9)))
    assert len(repr(_round_sig(x)).replace(".", "")) <= DEPTH_DIGITS
