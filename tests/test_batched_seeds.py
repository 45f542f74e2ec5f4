"""benchmarks/bench_batched_seeds.py runs on a CPU: k seeds as one vmapped network against k
separate runs, the census per step and per sample, and how far a batched run is from the run alone."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_batched_seeds_benchmark_prints_its_figures():
    out = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_batched_seeds.py"), "--k", "2",
                          "--steps", "1", "--size", "16"], cwd=ROOT, capture_output=True, text=True, timeout=600,
                         check=True).stdout
    rows = {m.group(2): (int(m.group(3)), float(m.group(4))) for m in
            re.finditer(r"^\s+(\d+) (separate|batched)\s+(\d+)\s+([\d.]+)\s+[\d.]+$", out, re.M)}
    assert set(rows) == {"separate", "batched"}
    ops, per_sample = rows["separate"]
    assert per_sample == round(ops / 12, 1)  # 2 runs of batch 6
    far = re.search(r"outputs ([\d.e+-]+) of their largest, gradients ([\d.e+-]+) of theirs", out)
    assert far and float(far.group(1)) < 1e-4  # the same network, summed in another order
