"""benchmarks/gpu_measure.sh, the one prepared script of GPU measurements: every benchmark it runs
exists with every flag it passes, and its parse of the side-by-side rate reads the line
bench_census.py prints."""
from __future__ import annotations

import re
import subprocess
from pathlib import Path

from test_docs_commands import check_command

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "gpu_measure.sh"


def test_every_command_names_what_exists():
    text = SCRIPT.read_text()
    subprocess.run(["bash", "-n", str(SCRIPT)], check=True)
    steps = re.findall(r'^\s*step \w+ \d+ "\$py" (benchmarks/\S+\.py[^\n]*)$', text, re.M)
    assert len(steps) == 6
    assert {s.split()[0] for s in steps} == {"benchmarks/gpu_check.py", "benchmarks/bench_census.py",
                                              "benchmarks/bench_gpu.py", "benchmarks/bench_batched_seeds.py",
                                              "benchmarks/gpu_cost.py"}
    for cmd in steps:
        cmd = re.sub(r'"[^"]*"', "X", cmd)  # shell values ("$out/table3.json", "full=$rate32")
        assert check_command(f"python {cmd}") == [], cmd


def test_the_rate_parse_reads_bench_census_line():
    census = (ROOT / "benchmarks" / "bench_census.py").read_text()
    assert 'side by side: {min(each):.1f}-{max(each):.1f} samples/s each, "' in census
    assert 'f"{sum(each):.1f} together"' in census
    line = "12 x compact_15l side by side: 34.0-37.2 samples/s each, 431.5 together\n"
    pattern = re.search(r"sed -n '(s/.* side by side: [^']*)'", SCRIPT.read_text())[1]
    got = subprocess.run(["sed", "-n", pattern], input=line, capture_output=True, text=True, check=True).stdout
    assert got.strip() == "431.5"


def _measure(out: Path, *python: str, env: dict | None = None) -> tuple[int, str, float]:
    """The script run as a user runs it; its process group ended if it outlives 60 s (the old
    script spent about 5 minutes without a GPU)."""
    import os
    import signal
    import time

    t0 = time.monotonic()
    proc = subprocess.Popen(["bash", str(SCRIPT), str(out), *python], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True,
                            env={**os.environ, **(env or {})})
    try:
        stdout, stderr = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        raise AssertionError("gpu_measure.sh still running after 60 s") from None
    return proc.returncode, stdout + stderr, time.monotonic() - t0


def test_without_a_cuda_gpu_it_says_so_at_once_and_writes_nothing(tmp_path):
    """No CUDA GPU (hidden here, on any machine): one line, exit 1, no OUT_DIR (issue 56)."""
    import sys

    rc, output, seconds = _measure(tmp_path / "out", sys.executable, env={"CUDA_VISIBLE_DEVICES": ""})
    assert rc == 1 and output.strip().count("\n") == 0, output
    assert output.startswith(f"error: no CUDA GPU: torch under {sys.executable} sees none"), output
    assert not (tmp_path / "out").exists() and seconds < 60


def test_a_python_without_torch_is_one_line(tmp_path):
    rc, output, _ = _measure(tmp_path / "out", "/bin/false")
    assert rc == 1 and output.strip() == ("error: /bin/false: could not import torch (expected the project's "
                                          "Python: .venv/bin/python, or python3 with the project on PYTHONPATH)")
    assert not (tmp_path / "out").exists()
