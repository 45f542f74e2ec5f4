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
from compact_perception.core.params import parse_params
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


#: What can change a run's bytes, and so enters its digest (learning/training/provenance.py): every
#: module a training run can execute (the run's module and what it imports, lazily too) and the
#: stage package's start-up (its numeric pins). Not the executor layer, the stage's planning, the
#: evaluation or the report: editing those restarts no run.
FINGERPRINTED = {
    *(f"compact_perception/core/{m}.py" for m in (
        "__init__", "cache", "catalog", "classes", "depth", "depth_metrics", "determinism", "errors",
        "io", "layout", "machine", "registry", "scores")),
    *(f"compact_perception/core/params/{m}.py" for m in (
        "__init__", "base", "errors", "file", "former", "recipe", "schema", "sources")),
    "compact_perception/__init__.py", "compact_perception/data/__init__.py", "compact_perception/data/loader.py",
    *(f"compact_perception/learning/{m}.py" for m in (
        "__init__", "losses", "metrics", "onnx_export", "plan", "schedule", "views")),
    *(f"compact_perception/learning/models/{m}.py" for m in (
        "__init__", "base", "blocks", "chen", "compact", "polarnet", "segnet")),
    *(f"compact_perception/learning/training/{m}.py" for m in (
        "__init__", "capture", "checkpoint", "distributed", "epoch", "precision", "provenance", "state", "train")),
    *(f"compact_perception/learning/weighting/{m}.py" for m in (
        "__init__", "base", "cagrad", "dwa", "gradients", "gradnorm", "mgn", "pcgrad", "single", "static", "uw")),
    "pipeline/__init__.py",
}


def test_the_fingerprint_covers_what_can_change_a_runs_bytes():
    """The files in a run's digest are those a training run can execute, listed above: no module of
    the executor layer, of the stage's planning (pipeline/train.py), of evaluation or of the report."""
    files = set(provenance.fingerprinted_files())
    assert files == FINGERPRINTED, f"added: {sorted(files - FINGERPRINTED)}, gone: {sorted(FINGERPRINTED - files)}"
    assert not [f for f in files if f.startswith(("compact_perception/execution/", "compact_perception/report/",
                                                  "compact_perception/evaluation/", "compact_perception/stats/"))]
    assert "pipeline/train.py" not in files and "compact_perception/learning/training/parallel.py" not in files


def _tree_copy(tmp_path, monkeypatch):
    """A copy of the package and pipeline/ that the fingerprint reads instead of the tree."""
    import shutil

    repo = Path(__file__).resolve().parents[1]
    assert provenance.PACKAGE_ROOT == repo / "src" / "compact_perception"
    skip = shutil.ignore_patterns("__pycache__")
    package = tmp_path / "src" / "compact_perception"
    shutil.copytree(provenance.PACKAGE_ROOT, package, ignore=skip)
    shutil.copytree(repo / "pipeline", tmp_path / "pipeline", ignore=skip)
    return package


def _fingerprint() -> str:
    provenance.source_fingerprint.cache_clear()
    return provenance.source_fingerprint()


def test_source_fingerprint_moves_with_the_code_a_run_executes(tmp_path, monkeypatch):
    """Editing a module a run executes (the params schema, a loss weighting, the metrics, the
    stage package's pins) in a copy of the tree changes the code digest; editing the stage's
    planning, the pool or the report does not."""
    package = _tree_copy(tmp_path, monkeypatch)
    try:
        real = _fingerprint()
        monkeypatch.setattr(provenance, "PACKAGE_ROOT", package)
        assert _fingerprint() == real  # the copy is read like the tree itself
        for edited, moves in ((package / "core" / "params" / "schema.py", True),
                              (package / "learning" / "weighting" / "uw.py", True),
                              (package / "learning" / "metrics.py", True), (tmp_path / "pipeline" / "__init__.py", True),
                              (tmp_path / "pipeline" / "train.py", False), (package / "execution" / "pool.py", False),
                              (package / "learning" / "training" / "parallel.py", False),
                              (package / "report" / "index.py", False)):
            text = edited.read_text()
            edited.write_text(text + "\n# edited\n")
            assert (_fingerprint() != real) is moves, edited.relative_to(tmp_path)
            edited.write_text(text)
            assert _fingerprint() == real
    finally:
        monkeypatch.undo()
        provenance.source_fingerprint.cache_clear()


def test_adding_a_module_to_the_executor_layer_leaves_every_digest_unchanged(tmp_path, monkeypatch, params_dict):
    """A new executor backend (a module of execution/, imported by the seam) restarts no run: the run
    digest of every planned run is the same before and after."""
    from compact_perception.learning.plan import dataset_runs
    from compact_perception.learning.training.train import run_digest

    package = _tree_copy(tmp_path, monkeypatch)
    params = parse_params(params_dict)
    runs = dataset_runs(params, "A")

    def digests() -> list[str]:
        provenance.source_fingerprint.cache_clear()
        return [run_digest(params, r, 1, "data", 1) for r in runs]

    try:
        monkeypatch.setattr(provenance, "PACKAGE_ROOT", package)
        before = digests()
        (package / "execution" / "ray_backend.py").write_text("from ..core.machine import usable_cores\n")
        seam = package / "execution" / "executor.py"
        seam.write_text(seam.read_text() + "\n\ndef _ray():\n    from .ray_backend import usable_cores\n")
        assert digests() == before
        (package / "learning" / "losses.py").write_text((package / "learning" / "losses.py").read_text() + "\n#\n")
        assert digests() != before   # the checker sees a change that matters
    finally:
        monkeypatch.undo()
        provenance.source_fingerprint.cache_clear()
