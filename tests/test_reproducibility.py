"""A result follows from code, params and data only: not from worker counts, interruptions,
or a checkpoint of other code (issue: "Every result follows from ... dvc.lock records").

Each check trains a tiny run, scores it on the test split with the real evaluation, and
compares the bytes of ``metrics.json``.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from compact_perception.learning.training import provenance
from compact_perception.core.config import parse_params
from compact_perception.evaluation.evaluate import evaluate_run
from compact_perception.learning.plan import planned_run
from compact_perception.learning.training.train import train_run

from repo_params import cap_epochs
from run_fixture import run_in
from synthetic import make_cache

MODEL = "compact_15l_mgn"  # dropout, MGN weights and momentum: every stateful part of a run


def _params(params_dict: dict, *, epochs: int = 3, workers: int = 2):
    cap_epochs(params_dict, epochs)
    params_dict["train"]["batch_size"] = 2
    params_dict["train"]["num_workers"] = workers
    params_dict["train"]["device"] = "cpu"
    params_dict["train"]["models"][MODEL].pop("max_epochs", None)
    return parse_params(params_dict)


def _train(params, cache: Path, run: Path, **kwargs) -> dict:
    return train_run(params, run_in(params, MODEL, cache, run), **kwargs)


def _score(params, cache: Path, run: Path) -> bytes:
    planned = run_in(params, MODEL, cache, run)
    evaluate_run(params, planned)
    return planned.paths.metrics_path.read_bytes()


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> Path:
    return make_cache(tmp_path_factory.mktemp("cache") / "A", counts=(8, 3, 3))


@pytest.fixture(scope="module")
def reference(tmp_path_factory, cache) -> tuple[bytes, dict, bytes]:
    """One uninterrupted run with 2 loader workers: its metrics.json, summary and best.pt bytes."""
    with (Path(__file__).resolve().parents[1] / "params.yaml").open() as fh:
        params = _params(yaml.safe_load(fh))
    run = tmp_path_factory.mktemp("ref") / "run"
    summary = _train(params, cache, run)
    return _score(params, cache, run), summary, (run / "best.pt").read_bytes()


@pytest.mark.slow
def test_worker_count_does_not_change_the_result(tmp_path, params_dict, cache, reference):
    params = _params(params_dict, workers=0)
    summary = _train(params, cache, tmp_path / "run")
    assert summary["best_val_score"] == reference[1]["best_val_score"]
    assert _score(params, cache, tmp_path / "run") == reference[0]
    # the checkpoint too, byte for byte (written under another random temporary name)
    assert (tmp_path / "run" / "best.pt").read_bytes() == reference[2]


@pytest.mark.slow
@pytest.mark.parametrize("cut_after", [2])  # the SIGKILL test below cuts within the first epochs
def test_interrupted_run_resumes_to_the_same_bytes(tmp_path, params_dict, cache, reference, cut_after):
    params = _params(params_dict)  # num_workers 2, the default
    run = tmp_path / "run"
    with pytest.raises(InterruptedError):
        _train(params, cache, run, stop_after_epochs=cut_after)
    resumed = _train(params, cache, run)
    assert resumed["final_weights"] == reference[1]["final_weights"]
    assert _score(params, cache, run) == reference[0]
    steps = (run / "live" / "plots" / "metrics" / "val_score.tsv").read_text().splitlines()[1:]
    assert [line.split("\t")[0] for line in steps] == ["0", "1", "2"]  # each epoch logged once


@pytest.mark.slow
def test_sigkill_mid_run_resumes_to_the_same_bytes(tmp_path, params_dict, cache, reference, root):
    """A real kill (SIGKILL, mid-epoch) of the stage process, then the stage again."""
    params_dict = dict(params_dict)
    _params(params_dict)  # validates and fills the dict the stage will read
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(params_dict))
    run = tmp_path / "run"
    cmd = [sys.executable, "-m", "pipeline.train", "--dataset", "A", "--model", MODEL, "--seed", "0",
           "--params", str(tmp_path / "params.yaml"), "--cache", str(cache), "--out", str(run)]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(root), str(root / "src")])}
    proc = subprocess.Popen(cmd, cwd=root, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 120
    while not (run / "last.pt").exists() and time.time() < deadline and proc.poll() is None:
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not (run / "summary.json").exists(), "the run finished before it could be killed"
    subprocess.run(cmd, cwd=root, env=env, check=True, capture_output=True)
    assert _score(_params(params_dict), cache, run) == reference[0]


@pytest.mark.slow
def test_a_finished_run_of_other_code_is_retrained(tmp_path, params_dict, cache, monkeypatch, caplog):
    """The in-stage shortcut ('already complete') never outlives a change of code."""
    params = _params(params_dict, epochs=1, workers=0)
    first = _train(params, cache, tmp_path / "run")
    again = _train(params, cache, tmp_path / "run")
    assert again == first  # same code, params and data: the finished run stands
    monkeypatch.setattr(provenance, "source_fingerprint", lambda: "other code")
    monkeypatch.setattr("compact_perception.learning.training.train.source_fingerprint", lambda: "other code")
    with caplog.at_level("INFO"):
        rerun = _train(params, cache, tmp_path / "run")
    assert rerun["digest"] != first["digest"]
    assert "of other code, params or data" in caplog.text


def test_digest_covers_every_result_changing_train_param(params_dict):
    """Every train param but the worker count and device moves the digest."""
    from compact_perception.learning.training.train import run_digest

    def digest(params, data: str = "data") -> str:
        return run_digest(params, planned_run(params, "A", MODEL, 0), 1, data, 1)

    base = parse_params(params_dict)
    d0 = digest(base)
    changes = {
        ("num_threads",): 2, ("precision",): "bf16", ("channels_last",): False, ("compile",): True, ("deterministic",): False, ("tf32",): True, ("batch_size",): 3, ("plateau_patience",): 7,
        ("early_stop_patience", "default"): 9, ("models", MODEL, "lr"): 0.05, ("models", MODEL, "momentum"): 0.5,
    }
    for path, value in changes.items():
        d = yaml.safe_load(yaml.safe_dump(params_dict))
        node = d["train"]
        for key in path[:-1]:
            node = node[key]
        node[path[-1]] = value
        assert digest(parse_params(d)) != d0, path
    d = yaml.safe_load(yaml.safe_dump(params_dict))
    d["train"]["num_workers"] = 2
    d["train"]["parallel_runs"] = 1
    assert digest(parse_params(d)) == d0
    cap = d["datasets"]["A"]["training"]["max_epochs"]
    cap["default"] = cap["default"] + 1     # the run's cap is part of its result
    assert digest(parse_params(d)) != d0
    assert digest(base, "other data") != d0
    # the base recipe counts through the run's merged recipe: a base key the model inherits moves the
    # digest, one the model sets itself does not
    for key, value, moves in (("lr_min", 1.0e-6, True), ("weighting", "none", False)):
        d = yaml.safe_load(yaml.safe_dump(params_dict))
        d["train"]["recipe"][key] = value
        assert (digest(parse_params(d)) != d0) is moves, key


@pytest.mark.slow
def test_compact_run_is_exported_as_onnx_matching_pytorch(reference, tmp_path_factory):
    """The trained network is also written as ONNX beside its checkpoint, checked against PyTorch."""
    summary = reference[1]
    assert summary["onnx"]["file"] == "model.onnx"
    assert summary["onnx"]["max_abs_diff"] < 1e-4


def test_source_fingerprint_covers_the_whole_package_and_the_stage_modules(tmp_path, monkeypatch):
    """The training shortcut's code digest reads every .py of compact_perception (its subpackages
    too, not only its own) and of pipeline/: editing any of them in a copy of the tree changes it."""
    import shutil

    repo = Path(__file__).resolve().parents[1]
    assert provenance.PACKAGE_ROOT == repo / "src" / "compact_perception"
    skip = shutil.ignore_patterns("__pycache__")
    package = tmp_path / "src" / "compact_perception"
    shutil.copytree(provenance.PACKAGE_ROOT, package, ignore=skip)
    shutil.copytree(repo / "pipeline", tmp_path / "pipeline", ignore=skip)

    def fingerprint() -> str:
        provenance.source_fingerprint.cache_clear()
        return provenance.source_fingerprint()

    try:
        real = fingerprint()
        monkeypatch.setattr(provenance, "PACKAGE_ROOT", package)
        assert fingerprint() == real  # the copy is read like the tree itself
        for edited in (package / "core" / "config.py", package / "learning" / "weighting" / "uw.py",
                       package / "learning" / "metrics.py", tmp_path / "pipeline" / "train.py"):
            text = edited.read_text()
            edited.write_text(text + "\n# edited\n")
            assert fingerprint() != real, edited.relative_to(tmp_path)
            edited.write_text(text)
            assert fingerprint() == real
    finally:
        monkeypatch.undo()
        provenance.source_fingerprint.cache_clear()
