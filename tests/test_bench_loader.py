"""benchmarks/bench_loader.py --quick on a tiny cache prints the loader's samples/s per setting, the
step's demand on this CPU and on a GPU, and the verdict (fast: not slow)."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from synthetic import make_cache

pytestmark = pytest.mark.slow   # a 128 px training step and its FLOP count: about a minute on 2 shared cores

ROOT = Path(__file__).resolve().parents[1]
NUM = r"[0-9]+(?:\.[0-9]+)?"


def test_bench_loader_quick_prints_its_figures(tmp_path):
    cache = make_cache(tmp_path / "cache", "A", size=32, counts=(12, 1, 1))
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_loader.py"), "--quick", "--cache",
                           str(cache)], cwd=ROOT, capture_output=True, text=True, timeout=120)
    out = proc.stdout
    assert proc.returncode == 0, out + proc.stderr[-2000:]
    for w in (0, 2):
        for pin in (False, True):
            assert re.search(rf"workers {w}, pin_memory {pin}\s+{NUM}\s+{NUM}", out), out
    assert re.search(rf"FLOPs per sample \(forward\+backward\): {NUM} GFLOP", out), out
    assert re.search(rf"\(a\) demand on this CPU:\s+{NUM} samples/s", out), out
    assert re.search(rf"\(b\) demand of a GPU:\s+{NUM} samples/s", out), out
    assert re.search(r"verdict vs the GPU's step: loader (keeps up|does not keep up) \(by [0-9.]+x\), limited by",
                     out), out


def test_bench_loader_bad_cache_is_one_error_line(tmp_path):
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_loader.py"), "--quick", "--cache",
                           str(tmp_path / "nope")], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert proc.returncode != 0
    assert proc.stderr.strip().startswith("error:") and len(proc.stderr.strip().splitlines()) == 1
