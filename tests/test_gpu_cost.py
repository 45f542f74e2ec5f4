"""benchmarks/gpu_cost.py: the runs and training frames it counts per dataset are params.yaml's,
computed by hand here, and its hours are samples over the rate."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from scripts import load_script

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "gpu_cost.py"


def _module():
    return load_script("gpu_cost")


def test_runs_and_frames_are_the_params_ones():
    from compact_perception.core.params import load_params

    mod = _module()
    full = load_params(ROOT / "params.yaml").model_copy(update={"scale": "full"})
    # set A at full: 500 frames split 6:1:3 -> 300 training frames; 4 compact models x 3 seeds and
    # the study's 9 arms x 3 seeds (set A is full's study set); 3 baselines x 3 seeds
    assert mod.train_frames(full, "A") == 300
    runs = mod.runs_of(full, "A")
    assert len(runs["compact"]) == 4 * 3 + 9 * 3 and len(runs["baseline"]) == 3 * 3
    assert {cap for _, cap in runs["compact"] + runs["baseline"]} == {100}
    assert len(mod.runs_of(full, "B")["compact"]) == 12  # no study on B at full
    # simulated nuScenes at full: 30 scenes, 3:1:1 -> 18 training scenes of 10 samples
    assert mod.train_frames(full, "nuscenes") == 180


def test_the_hours_are_samples_over_the_rate():
    out = subprocess.run([sys.executable, str(SCRIPT), "--epochs", "45", "--rate", "full=430"], cwd=ROOT,
                         capture_output=True, text=True, timeout=120, check=True).stdout
    full = out[out.index("scale full"):out.index("scale paper")]
    row = next(line for line in full.splitlines() if line.startswith("A "))
    hours = 39 * 300 * 45 / 430 / 3600  # 0.34 h
    assert f"{hours:6.1f} [" in row and f"{39 * 300 * 100 / 430 / 3600:7.1f}]" in row
    assert "in all:" in full


def test_a_bad_rate_is_one_line():
    proc = subprocess.run([sys.executable, str(SCRIPT), "--rate", "full=fast"], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 1 and proc.stderr.strip() == "error: --rate 'full=fast': expected SCALE=SAMPLES_PER_S, e.g. full=430"


@pytest.mark.parametrize("argv,message", [
    (["--rate", "full=-1"], "--rate 'full=-1': expected samples/s above 0 and at most 1e+06, e.g. full=430"),
    (["--rate", "full=0"], "--rate 'full=0': expected samples/s above 0 and at most 1e+06, e.g. full=430"),
    (["--rate", "paper=nan"], "--rate 'paper=nan': expected samples/s above 0 and at most 1e+06, e.g. full=430"),
    (["--rate", "full=inf"], "--rate 'full=inf': expected samples/s above 0 and at most 1e+06, e.g. full=430"),
    (["--rate", "fulll=430"], "--rate 'fulll=430': unknown scale 'fulll' (expected full or paper), e.g. full=430"),
    (["--rate", "default=430"], "--rate 'default=430': unknown scale 'default' (expected full or paper), e.g. full=430"),
    (["--epochs", "0"], "--epochs: expected a whole number from 1 to 10000 (got '0')"),
    (["--epochs", "many"], "--epochs: expected a whole number from 1 to 10000 (got 'many')"),
])
def test_a_rate_or_count_no_gpu_has_is_refused_in_one_line(argv, message):
    """Issue 56: rates -1 and nan printed negative and nan hours, 0 a ZeroDivisionError traceback, and
    an unknown scale was ignored; each is now one line, exit 1, and nothing printed to stdout."""
    proc = subprocess.run([sys.executable, str(SCRIPT), *argv], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert (proc.returncode, proc.stdout, proc.stderr) == (1, "", f"error: {message}\n")
