"""Inputs a hostile user tries that are not bad data but still must not hurt: a params file whose
YAML aliases expand to a billion values, a value too long to quote, a process count past the
machine's cores, a device the machine lacks, an operating-system error that is not a file's, a
disk too small for the data asked for, and what ``dvc exp run -S`` leaves behind when a stage
refuses the change. Each ends in one line naming what failed, exit status 1, nothing written."""
from __future__ import annotations

import json
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import yaml

from compact_perception.core.params import MAX_PARAMS_VALUES, ParamsError, load_params, parse_params
from repo_params import repo_params_dict

ROOT = Path(__file__).resolve().parents[1]


# ----------------------------------------------------------------------------- params that expand
def _bomb(levels: int) -> str:
    """A flow list of nested anchors: ``&a`` ten 1s, ``&b`` ten ``*a``, ... (10^levels leaves)."""
    names = "abcdefghijklmnop"[:levels]
    parts = ["&a [" + ", ".join(["1"] * 10) + "]"]
    parts += [f"&{n} [" + ", ".join([f"*{p}"] * 10) + "]" for p, n in zip(names, names[1:])]
    return "[" + ", ".join(parts) + "]"


def _bombed_params(path: Path, key: str, levels: int) -> Path:
    """The committed params.yaml with ``key`` (``seed`` or ``train.recipe.lr``) set to :func:`_bomb`."""
    text = (ROOT / "params.yaml").read_text()
    if key == "seed":
        text, n = re.subn(r"^seed: .*$", lambda _m: f"seed: {_bomb(levels)}", text, count=1, flags=re.M)
    else:
        text, n = re.subn(r"^(  recipe:.*\n(?:    .*\n)*?    lr: ).*$", lambda m: m.group(1) + _bomb(levels), text,
                          count=1, flags=re.M)
    assert n == 1
    path.write_text(text)
    return path


#: A stage started on the file in a process of at most 1 GiB address space (the bomb took 2.8 GB):
#: it prints how long reading the params took and the stage's exit message.
_PROBE = textwrap.dedent("""
    import json, resource, sys, time
    resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))
    from pipeline._common import start
    t0 = time.perf_counter()
    try:
        start(sys.argv[1])
        msg = None
    except SystemExit as exc:
        msg = exc.code
    print(json.dumps({"seconds": time.perf_counter() - t0, "message": msg}))
""")


@pytest.mark.parametrize("key, levels", [("train.recipe.lr", 9), ("seed", 9), ("seed", 5), ("train.recipe.lr", 5)])
def test_a_params_file_whose_aliases_expand_is_one_line_in_bounded_time_and_memory(tmp_path, key, levels):
    """Nested anchors (~10^9 values, and a 10^5 variant) used as ``train.recipe.lr`` and ``seed``
    used to reach a MemoryError after 49 s at 2.8 GB, a 2.2 GB repr, a 722,360-character line."""
    path = _bombed_params(tmp_path / "params.yaml", key, levels)
    done = subprocess.run([sys.executable, "-c", _PROBE, str(path)], capture_output=True, text=True, cwd=ROOT,
                          timeout=120)
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr[-2000:]
    out = json.loads(done.stdout.strip().splitlines()[-1])
    assert out["message"] == (f"error: {path}: {key}: more than {MAX_PARAMS_VALUES} values once the YAML aliases are "
                              "expanded (params.yaml holds under a thousand; an alias repeats everything its anchor "
                              "holds)")
    assert out["seconds"] < 1.0, out


def test_an_alias_inside_its_own_anchor_is_one_line(tmp_path):
    path = tmp_path / "params.yaml"
    path.write_text((ROOT / "params.yaml").read_text().replace("\nseed: 2022", "\nseed: &s [1, *s]", 1))
    with pytest.raises(ParamsError, match=r"params.yaml: an alias inside its own anchor at line \d+$"):
        load_params(path)


def test_aliases_that_stay_small_still_read(tmp_path):
    """An anchor reused a few times (a merge key, a shared list) is ordinary YAML and reads as before."""
    text = (ROOT / "params.yaml").read_text()
    ratio = "full: {train: 6, val: 1, test: 3}"
    text = text.replace(ratio, "full: &ratio {train: 6, val: 1, test: 3}", 1)
    assert "&ratio" in text and text.count(ratio) >= 2
    text = text.replace(ratio, "full: *ratio")          # every other set's full split ratio
    path = tmp_path / "params.yaml"
    path.write_text(text)
    assert text.count("*ratio") >= 2
    assert load_params(path) == load_params(ROOT / "params.yaml")


def test_an_integer_too_long_to_read_is_one_line(tmp_path):
    path = tmp_path / "params.yaml"
    path.write_text((ROOT / "params.yaml").read_text().replace("\nseed: 2022", "\nseed: " + "7" * 5000, 1))
    with pytest.raises(ParamsError) as exc:
        load_params(path)
    msg = str(exc.value)
    assert "\n" not in msg and len(msg) < 400 and "an integer of 5000 digits, too long to read" in msg, msg


@pytest.mark.parametrize("key, value, shown", [
    ("seed", list(range(50_000)), "(got [0, 1, 2, 3, ...] (list of 50000 items))"),
    ("train.device", "x" * 300_000, "(300000 characters)"),
    ("world.conditions.times", ["never"] * 50_000, "; and 49990 more"),
], ids=["a-long-list", "a-long-string", "many-problems"])
def test_every_params_error_is_bounded_in_length(key, value, shown):
    """A value under the expansion bound but long (a list of 50,000 items, a 300,000-character
    string, 50,000 bad items) is shown cut, with its size; at most ten problems are named."""
    d = repo_params_dict()
    node = d
    *head, last = key.split(".")
    for k in head:
        node = node[k]
    node[last] = value
    with pytest.raises(ParamsError) as exc:
        parse_params(d, "params.yaml")
    msg = str(exc.value)
    assert msg.startswith(f"params.yaml: ") and key in msg and shown in msg, msg[:500]
    assert "\n" not in msg and len(msg) < 4000, len(msg)


# ----------------------------------------------------------------------------- processes bounded by the machine
class _Refused(Exception):
    """Raised by a stand-in pool once it has recorded the size it was asked for."""


def _refusing_context(sizes: list[int]):
    """A stand-in for ``multiprocessing.get_context(...)`` whose ``Pool(n)`` records ``n`` and refuses."""
    class _Context:
        @staticmethod
        def Pool(n, *args, **kwargs):  # noqa: N802 (multiprocessing's name)
            sizes.append(n)
            raise _Refused(n)

    return lambda *_a, **_k: _Context()


@pytest.fixture()
def two_cores(monkeypatch):
    """This process may run on two cores (its affinity mask), whatever the machine has."""
    import os

    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1})


def test_every_worker_count_is_bounded_by_the_usable_cores(tmp_path, monkeypatch, two_cores):
    """``train.parallel_runs: 64`` with many runs could start 64 training processes on 2 cores (and
    every other worker count as many as it said). Each place that starts processes now takes at
    most the usable cores (os.sched_getaffinity)."""
    from compact_perception.data import authors, preprocess
    from compact_perception.data.nuscenes import ingest
    from compact_perception.learning.training import parallel
    from compact_perception.data.world import generate as gen
    from fixtures_raw import make_raw_dataset

    sizes: list[int] = []
    for module in (parallel, gen, preprocess, authors, ingest):
        monkeypatch.setattr(module.mp, "get_context", _refusing_context(sizes))
    with pytest.raises(_Refused):
        parallel.run_jobs(len, [parallel.Job(str(i), "ab") for i in range(5)], 64, desc="five jobs")
    d = repo_params_dict()
    d["world"]["workers"] = 8
    d["preprocess"]["workers"] = 8
    params = parse_params(d)
    with pytest.raises(_Refused):
        gen.generate_dataset(params, "A", tmp_path / "raw" / "A")
    raw, _ = make_raw_dataset(tmp_path / "raw" / "B", dataset="B")
    with pytest.raises(_Refused):
        preprocess.preprocess_sim(raw, tmp_path / "cache" / "B", "B", params.preprocess)
    with pytest.raises(_Refused):
        authors._pool(8)
    with pytest.raises(_Refused):
        list(ingest.iter_frames(None, [("a", "t1"), ("b", "t2")], 32, params.preprocess, workers=8))
    assert sizes == [2, 2, 2, 2, 2]
    assert not (tmp_path / "raw" / "A").exists() and not (tmp_path / "cache" / "B").exists()


def test_a_training_runs_loader_workers_are_bounded_by_the_usable_cores(tmp_path, monkeypatch, two_cores):
    from compact_perception.learning.training import train as train_mod
    from repo_params import cap_epochs
    from run_fixture import run_in
    from synthetic import make_cache

    asked: list[int] = []

    def loader(*args, num_workers=0, **kwargs):
        asked.append(num_workers)
        raise _Refused(num_workers)

    monkeypatch.setattr(train_mod, "make_loader", loader)
    d = repo_params_dict()
    cap_epochs(d, 1)
    d["train"].update(num_workers=8, device="cpu", batch_size=2)
    params = parse_params(d)
    run = run_in(params, "compact_1l", make_cache(tmp_path / "cache", size=32, counts=(4, 2, 2)), tmp_path / "run",
                 export_onnx=False)
    with pytest.raises(_Refused):
        train_mod.train_run(params, run, progress=False)
    assert asked == [2]


def test_a_stage_logs_one_line_naming_each_count_it_lowers(tmp_path, caplog, two_cores):
    import logging

    from pipeline._common import start

    d = repo_params_dict()
    d["train"].update(parallel_runs=64, num_workers=8)
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(d))
    with caplog.at_level(logging.INFO):
        params = start(path, workers=("train.parallel_runs", "train.num_workers"))
    lines = [r.getMessage() for r in caplog.records if "CPU core" in r.getMessage()]
    assert lines == ["this machine lends 2 CPU cores: train.parallel_runs 64 -> 2, train.num_workers 8 -> 2 "
                     "(a worker count changes no result)"]
    assert params.train.parallel_runs == 64          # the params keep what is written (the data stages record it)


@pytest.mark.parametrize("stage", ["train", "evaluate"])
def test_a_device_the_machine_lacks_is_refused_before_any_worker_starts(tmp_path, monkeypatch, stage):
    """``train.device: cuda`` without CUDA was one line, but only after the worker pool had started
    (each job checked the device on its own)."""
    import importlib

    import torch

    module = importlib.import_module(f"pipeline.{stage}")
    started: list = []
    monkeypatch.setattr(module, "run_jobs", lambda *a, **k: started.append(a))
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    d = repo_params_dict()
    d["train"]["device"] = "cuda"
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(d))
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        module.main(["--dataset", "A", "--params", str(path)])
    assert exc.value.code == f"error: {path}: train.device: 'cuda' but this machine has no CUDA device (use 'auto' or 'cpu')"
    assert started == [] and not (tmp_path / "runs").exists() and not (tmp_path / "results").exists()


# ----------------------------------------------------------------------------- errors that blame the right thing
def test_a_worker_that_cannot_start_is_not_blamed_on_the_output_folder(tmp_path, monkeypatch):
    """A pool worker that could not start read ``error: runs/A: could not write (Broken pipe)``."""
    import errno
    import os

    from compact_perception.learning.training import parallel
    from pipeline.train import main

    class _Context:
        @staticmethod
        def Pool(n, *args, **kwargs):  # noqa: N802
            raise BrokenPipeError(errno.EPIPE, os.strerror(errno.EPIPE))

    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2, 3})
    monkeypatch.setattr(parallel.mp, "get_context", lambda *_a: _Context())
    d = repo_params_dict()
    d["train"].update(device="cpu", parallel_runs=2)
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(d))
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        main(["--dataset", "A", "--params", str(path)])
    assert exc.value.code == "error: train A: could not start 2 worker processes (Broken pipe)"


def test_an_os_error_names_the_file_or_else_the_call_that_failed():
    import errno
    import os

    from compact_perception.core.errors import os_error_line

    def send_to_worker():
        raise BrokenPipeError(errno.EPIPE, os.strerror(errno.EPIPE))

    try:
        send_to_worker()
    except OSError as err:
        line = os_error_line(err, "runs/A")
    assert line == (f"{__name__}.test_an_os_error_names_the_file_or_else_the_call_that_failed.<locals>.send_to_worker "
                    "failed (Broken pipe; not a file of runs/A)")
    # a file the OS names, and a full disk it names none of, are as before
    assert os_error_line(OSError(errno.EROFS, os.strerror(errno.EROFS), "runs/A/x/last.pt"), "runs/A") == \
        "runs/A/x/last.pt: could not write (Read-only file system)"
    assert os_error_line(OSError(errno.ENOSPC, os.strerror(errno.ENOSPC)), "runs/A") == \
        "runs/A: could not write (No space left on device)"


# ----------------------------------------------------------------------------- recorded
@pytest.mark.parametrize("precision", [pytest.param("fp16", marks=pytest.mark.slow), "fp32"])  # fp16 is emulated: slow
def test_a_runs_summary_records_its_device_and_resolved_precision(tmp_path, precision):
    """A run in fp16 on the CPU trained (finite losses), but its summary.json did not say which
    precision or device it used. (A subprocess: a precision other than fp32 lifts the process's
    kernel pins.)"""
    from repo_params import cap_epochs
    from synthetic import make_cache

    d = cap_epochs(repo_params_dict(), 1)
    d["train"].update(precision=precision, device="auto", batch_size=2, num_workers=0)
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump(d))
    cache = make_cache(tmp_path / "cache", size=32, counts=(4, 2, 2))
    done = subprocess.run([sys.executable, "-m", "pipeline.train", "--dataset", "A", "--model", "compact_1l",
                           "--seed", "0", "--params", str(params), "--cache", str(cache), "--out", str(tmp_path / "run")],
                          capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert (summary["device"], summary["precision"]) == ("cpu", precision)   # no CUDA in a CPU torch
    assert summary["device_name"].startswith("CPU")


def test_generation_refuses_up_front_a_dataset_the_free_disk_cannot_hold(tmp_path, monkeypatch):
    """1e6 frames onto a 20 MB disk: one line after 9.5 s of writing, the partial dataset removed.
    Now the size is estimated from the first frames and refused before anything is written."""
    import shutil
    import time
    from collections import namedtuple

    from compact_perception.data.world import generate as gen
    from pipeline.generate import main

    def no_write(*_a, **_k):
        raise AssertionError("a frame was written")

    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda path: usage(20_000_000, 0, 20_000_000))
    monkeypatch.setattr(gen.io, "write_npz", no_write)
    d = repo_params_dict()
    d["datasets"]["A"]["frames"]["default"] = 1_000_000
    d["world"]["workers"] = 1
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(d))
    monkeypatch.chdir(tmp_path)
    t0 = time.perf_counter()
    with pytest.raises(SystemExit) as exc:
        main(["--dataset", "A", "--params", str(path), "--out", "raw", "--figure-dir", "figs"])
    assert time.perf_counter() - t0 < 30
    msg = exc.value.code
    assert re.fullmatch(r"error: raw/A: 1000000 frames need about [\d,]+ MB \(at least [\d,]+ MB, measured on the "
                        r"first frames\), 20 MB free on \.; free space or lower datasets\.A\.frames", msg), msg
    assert sorted(p.name for p in tmp_path.iterdir()) == ["params.yaml"]


def test_the_disk_estimate_is_near_what_generation_writes(tmp_path):
    from compact_perception.data.world import generate as gen

    d = repo_params_dict()
    d["datasets"]["A"]["frames"]["default"] = 40
    d["world"].update(workers=1, frames_per_episode=4)
    params = parse_params(d)
    about, at_least = gen.estimate_disk(params, "A")
    out = gen.generate_dataset(params, "A", tmp_path / "A")
    written = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
    assert at_least <= written and 0.7 * written <= about <= 1.5 * written, (at_least, about, written)


# ----------------------------------------------------------------------------- what dvc exp run -S leaves
@pytest.mark.slow
def test_what_dvc_exp_run_leaves_in_params_yaml_when_a_stage_refuses_and_how_to_undo_it(tmp_path):
    """``dvc exp run -S '+train.recipe.lrr=0.1'`` (a typo'd new key): the stage refuses it in one
    line, but DVC leaves the edit in params.yaml. docs/design.md says so and gives the undo; this
    runs real DVC on a one-stage copy to keep the doc true: the edit stays, ``git checkout
    params.yaml`` undoes it, ``dvc exp clean`` does not, and a queued run leaves the workspace alone."""
    import os
    import shutil

    doc = (ROOT / "docs" / "design.md").read_text()
    assert "`git checkout params.yaml`" in doc and "`dvc exp clean` does not" in doc
    repo = tmp_path / "repo"
    repo.mkdir()
    shutil.copy(ROOT / "params.yaml", repo / "params.yaml")
    shutil.copytree(ROOT / "pipeline", repo / "pipeline", ignore=shutil.ignore_patterns("__pycache__"))
    (repo / "dvc.yaml").write_text("stages:\n  check:\n    cmd: python -m pipeline.nuscenes_sim --out out\n"
                                   "    deps: [pipeline/nuscenes_sim.py]\n    params: [train.recipe]\n    outs: [out]\n")
    env = dict(os.environ, DVC_NO_ANALYTICS="1", HOME=str(tmp_path / "home"),
               DVC_GLOBAL_CONFIG_DIR=str(tmp_path / "dvc-global"), DVC_SYSTEM_CONFIG_DIR=str(tmp_path / "dvc-system"),
               DVC_SITE_CACHE_DIR=str(tmp_path / "dvc-site"), GIT_AUTHOR_NAME="t", GIT_AUTHOR_EMAIL="t@t",
               GIT_COMMITTER_NAME="t", GIT_COMMITTER_EMAIL="t@t",
               PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}")

    def run(*cmd: str) -> subprocess.CompletedProcess:
        return subprocess.run(cmd, cwd=repo, env=env, capture_output=True, text=True, timeout=300)

    for cmd in (["git", "init", "-q"], ["dvc", "init", "-q"], ["git", "add", "-A"], ["git", "commit", "-qm", "init"]):
        assert run(*cmd).returncode == 0, cmd
    committed = (repo / "params.yaml").read_bytes()
    done = run("dvc", "exp", "run", "-S", "+train.recipe.lrr=0.1")
    assert done.returncode != 0
    assert "error: params.yaml: train.recipe.lrr: unknown key" in done.stdout + done.stderr
    assert run("git", "status", "--porcelain", "params.yaml").stdout.strip() == "M params.yaml"
    assert "lrr: 0.1" in (repo / "params.yaml").read_text()        # what the doc says is left behind
    run("dvc", "exp", "clean")
    assert (repo / "params.yaml").read_bytes() != committed           # dvc exp clean does not undo it
    assert run("git", "checkout", "params.yaml").returncode == 0      # the doc's undo
    assert (repo / "params.yaml").read_bytes() == committed
    assert run("dvc", "exp", "run", "--queue", "-S", "+train.recipe.lrr=0.1").returncode == 0
    assert run("git", "status", "--porcelain", "params.yaml").stdout.strip() == ""
