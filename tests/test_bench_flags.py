"""The benchmark scripts' flags (benchmarks/flags.py): a count of 0 or less, a size no network
takes, a rate that is not a finite positive number, an unknown id is one line ``error: --flag: ...``
and exit status 1 before any work, as the pipeline's inputs are (issue 56, item 7)."""
from __future__ import annotations

import argparse
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "benchmarks"
sys.path.insert(0, str(BENCH))
from flags import Parser, count, frame_size, number  # noqa: E402

#: Scripts whose flags are checked elsewhere (bench_census.py, gpu_check.py, the records' writers).
ELSEWHERE = {"bench_census.py", "gpu_check.py", "record_plateau.py", "record_full.py", "flags.py"}


def _parse(*argv: str) -> tuple[int, str]:
    ap = Parser(prog="x")
    ap.add_argument("--n", type=count(1, 10))
    ap.add_argument("--size", type=frame_size(32))
    ap.add_argument("--rate", type=number(0, 1))
    try:
        ap.parse_args(list(argv))
    except SystemExit as exc:
        return exc.code, ""
    return 0, ""


@pytest.mark.parametrize("argv,message", [
    (["--n", "0"], "error: --n: expected a whole number from 1 to 10 (got '0')"),
    (["--n", "-3"], "error: --n: expected a whole number from 1 to 10 (got '-3')"),
    (["--n", "1e3"], "error: --n: expected a whole number from 1 to 10 (got '1e3')"),
    (["--size", "100000"], "error: --size: expected a frame size in px, a multiple of 32 from 32 to 1024 (got '100000')"),
    (["--size", "48"], "error: --size: expected a frame size in px, a multiple of 32 from 32 to 1024 (got '48')"),
    (["--rate", "nan"], "error: --rate: expected a finite number above 0 and at most 1 (got 'nan')"),
    (["--rate", "inf"], "error: --rate: expected a finite number above 0 and at most 1 (got 'inf')"),
    (["--rate", "0"], "error: --rate: expected a finite number above 0 and at most 1 (got '0')"),
    (["--rate", "x" * 100], "error: --rate: expected a finite number above 0 and at most 1 (got "
                            f"'{'x' * 40}'... (100 characters))"),
    (["--what"], "error: unrecognized arguments: --what"),
])
def test_a_bad_flag_is_one_line_and_exit_1(capsys, argv, message):
    assert _parse(*argv)[0] == 1
    err = capsys.readouterr().err
    assert err == message + "\n"


def test_good_values_pass():
    ap = Parser(prog="x")
    ap.add_argument("--n", type=count(0, 10), nargs="+")
    ap.add_argument("--size", type=frame_size(16))
    ap.add_argument("--rate", type=number(0, 1))
    args = ap.parse_args(["--n", "0", "10", "--size", "16", "--rate", "1"])
    assert (args.n, args.size, args.rate) == ([0, 10], 16, 1.0)


def _scripts() -> list[Path]:
    return [p for p in sorted(BENCH.glob("*.py")) if p.name not in ELSEWHERE]


@pytest.mark.parametrize("script", _scripts(), ids=lambda p: p.name)
def test_every_benchmark_checks_its_numeric_flags(script: Path):
    """Each script's parser is flags.Parser and no numeric flag is a bare ``type=int``/``type=float``
    (which takes 0, negatives and absurd sizes, and whose error is argparse's usage block, exit 2)."""
    text = script.read_text()
    if "add_argument(" not in text:
        return
    assert "argparse.ArgumentParser(" not in text, f"{script.name}: build the parser as flags.Parser"
    bare = re.findall(r'add_argument\("(--[\w-]+)"[^)]*type=(?:int|float)\b', text)
    assert not bare, f"{script.name}: numeric flags without a checked type (flags.count/frame_size/number): {bare}"


@pytest.mark.parametrize("script,argv,message", [
    ("bench_gpu.py", ["--resolution", "0"], "--resolution: expected a frame size in px, a multiple of 32 from 32 "
                                            "to 1024 (got '0')"),
    ("bench_gpu.py", ["--model", "nope"], "--model: invalid choice: 'nope' (choose from 'compact_1l', "),
    ("bench_batched_seeds.py", ["--k", "4", "0"], "--k: expected a whole number from 1 to 64 (got '0')"),
    ("bench_batched_seeds.py", ["--size", "100000"], "--size: expected a frame size in px, a multiple of 16 from 16 "
                                                     "to 1024 (got '100000')"),
    ("bench_train.py", ["--batch", "0"], "--batch: expected a whole number from 1 to 256 (got '0')"),
    ("bench_fastpath.py", ["--rounds", "-1"], "--rounds: expected a whole number from 1 to 100000 (got '-1')"),
    ("bench_loader.py", ["--util", "nan"], "--util: expected a finite number above 0 and at most 1 (got 'nan')"),
    ("bench_loader.py", ["--workers", "0,-2"], "--workers: expected comma-separated counts from 0 to 256, got '0,-2'"),
    ("bench_preprocess.py", ["--workers", "0"], "--workers: expected a whole number from 1 to 256 (got '0')"),
    ("bench_nuscenes.py", ["--scenes", "0"], "--scenes: expected a whole number from 1 to 10000 (got '0')"),
    ("bench_run_costs.py", ["--repeats", "0"], "--repeats: expected a whole number from 1 to 1000 (got '0')"),
    ("bench_world.py", ["--frames", "0"], "--frames: expected a whole number from 1 to 10000 (got '0')"),
    ("diagnose_gradnorm_segnet.py", ["--epochs", "0"], "--epochs: expected a whole number from 1 to 10000 (got '0')"),
])
def test_each_script_refuses_a_bad_flag_in_one_line(script, argv, message):
    proc = subprocess.run([sys.executable, str(BENCH / script), *argv], cwd=ROOT, capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 1 and proc.stdout == "", (proc.returncode, proc.stdout, proc.stderr)
    assert proc.stderr.startswith(f"error: {message}") and proc.stderr.count("\n") == 1, proc.stderr


def test_argparse_type_errors_name_the_flag():
    """The one-line form keeps argparse's own ``argument --flag:`` naming, without the word."""
    with pytest.raises(argparse.ArgumentTypeError, match=r"expected a whole number from 1 to 2 \(got '3'\)"):
        count(1, 2)("3")
