"""Issue 25 items 1-6, each reproduced as a hostile user would: a crafted pickle in a checkpoint,
a damaged ``last.pt``, a diverging lr, a cache outside the standard layout, a kill between
``mkstemp`` and the rename, and bad params (resolution 16, a key written twice, ``.inf``).
Every bad input ends in one line ``error: <file or key>: <what was expected>`` (exit status 1)
and leaves nothing half-written.
"""
from __future__ import annotations

import errno
import hashlib
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from compact_perception.core.params import ParamsError, load_params, parse_params
from compact_perception.core.errors import RunError

import authors_fixture as fx
from repo_params import cap_epochs, repo_params_dict
from run_fixture import run_in
from synthetic import make_cache
from test_authors import copy, release, stage_error, write_params  # noqa: F401 (fixtures)
from test_errors import _eval_tree, _exit_message, _files

MODEL = "compact_1l"


def _tiny(d: dict, epochs: int = 2) -> dict:
    """Params of a run of a few seconds (2 epochs, batch 2, one process, CPU)."""
    cap_epochs(d, epochs)
    d["train"]["batch_size"] = 2
    d["train"]["num_workers"] = 0
    d["train"]["device"] = "cpu"
    return d


def _params_file(tmp_path: Path, d: dict) -> Path:
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(d))
    return path


def _train_main(params: Path, cache: Path, run: Path, model: str = MODEL) -> str:
    """The training stage in-process; it must stop with a one-line error (returned)."""
    from pipeline.train import main

    return _exit_message(main, ["--dataset", "A", "--model", model, "--seed", "0", "--params", str(params),
                                "--cache", str(cache), "--out", str(run)])


def _snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` with its bytes."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture()
def cache(tmp_path: Path) -> Path:
    return make_cache(tmp_path / "cache", size=16, counts=(4, 2, 2))


# ----------------------------------------------------------------------------- item 1: crafted pickles
class _Payload:
    """Unpickling this runs a shell command that creates ``marker`` (what a crafted ``best.pt`` did)."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return os.system, (f"touch {shlex.quote(str(self.marker))}",)


def _crafted(path: Path, marker: Path, **state) -> Path:
    """A checkpoint whose unpickling with ``weights_only=False`` creates ``marker`` (checked here,
    so the tests below fail for the reason they name if a loader trusts the file)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save({**state, "model": _Payload(marker)}, path)
    torch.load(path, weights_only=False)
    assert marker.exists(), "the crafted pickle does not execute: the tests below would prove nothing"
    marker.unlink()
    return path


def test_crafted_last_pt_does_not_run_code_in_training(tmp_path, cache):
    run, marker = tmp_path / "run", tmp_path / "marker"
    last = _crafted(run / "last.pt", marker, digest="any", epoch=0)
    before = _snapshot(run)
    msg = _train_main(_params_file(tmp_path, _tiny(repo_params_dict())), cache, run)
    assert msg.startswith(f"error: {last}: unreadable checkpoint (it holds more than tensors and plain data"), msg
    assert msg.endswith("; delete it to retrain from scratch")
    assert not marker.exists()
    assert _snapshot(run) == before


@pytest.mark.parametrize("reader", ["load_resumable", "mark_finished", "read_checkpoint"])
def test_every_checkpoint_reader_refuses_a_crafted_pickle(tmp_path, reader):
    """``best.pt`` (the ONNX export at a run's end reads it through ``read_checkpoint``) and
    ``last.pt`` (resume, marking it finished)."""
    from compact_perception.learning.training import checkpoint

    marker = tmp_path / "marker"
    path = _crafted(tmp_path / "best.pt", marker, digest="d", epoch=0)
    call = {"load_resumable": lambda: checkpoint.load_resumable(path, "d"),
            "mark_finished": lambda: checkpoint.mark_finished(path),
            "read_checkpoint": lambda: checkpoint.read_checkpoint(path)}[reader]
    with pytest.raises(RunError, match=re.escape(f"{path}: unreadable checkpoint (it holds more than")):
        call()
    assert not marker.exists()


def test_crafted_best_pt_does_not_run_code_in_evaluation(tmp_path, monkeypatch):
    from pipeline.evaluate import main

    root, marker = _eval_tree(tmp_path), tmp_path / "marker"
    best = root / "runs" / "A" / MODEL / "seed0" / "best.pt"
    _crafted(best, marker, epoch=0)
    before = _files(root)
    monkeypatch.chdir(root)
    msg = _exit_message(main, ["--dataset", "A", "--params", "params.yaml"])
    assert msg.startswith(f"error: runs/A/{MODEL}/seed0/best.pt: not a checkpoint of {MODEL}"), msg
    assert not marker.exists()
    assert _files(root) == before


# ----------------------------------------------------------------------------- item 2: a damaged last.pt
def test_truncated_last_pt_of_a_finished_run_is_an_error_and_deletes_nothing(tmp_path, cache):
    """It used to log one INFO line, delete best.pt, summary.json and live/ and retrain."""
    from compact_perception.learning.training.train import train_run

    d = _tiny(repo_params_dict(), epochs=1)
    run, params = tmp_path / "run", parse_params(d)
    train_run(params, run_in(params, MODEL, cache, run))
    last = run / "last.pt"
    last.write_bytes(last.read_bytes()[: last.stat().st_size // 2])
    before = _snapshot(run)
    assert {"best.pt", "summary.json", "model.onnx"} <= set(before) and any(k.startswith("live/") for k in before)
    msg = _train_main(_params_file(tmp_path, d), cache, run)
    assert re.fullmatch(rf"error: {re.escape(str(last))}: unreadable checkpoint \([^\n]+\); "
                        r"delete it to retrain from scratch", msg), msg
    assert _snapshot(run) == before


# ----------------------------------------------------------------------------- item 3: divergence
@pytest.mark.parametrize("model", [MODEL, "chen_bev"])
def test_a_huge_lr_stops_the_run_naming_epoch_and_loss(tmp_path, cache, model):
    """lr 1e6 diverges in the first epoch: one line naming the run, the epoch and the loss (it
    was 'best.pt: could not write the run' for compact_1l and a raw RuntimeError for chen_bev),
    and a run that saved no epoch leaves nothing (no empty live/)."""
    d = _tiny(repo_params_dict(), epochs=1)
    d["train"]["models"][model]["lr"] = 1.0e6
    run = tmp_path / "run"
    msg = _train_main(_params_file(tmp_path, d), cache, run, model)
    assert re.fullmatch(rf"error: {re.escape(str(run))}: epoch \d+: non-finite [a-z ]+ loss \((nan|-?inf)\)", msg), msg
    assert not run.exists() or not any(run.iterdir())


def test_a_nan_loss_keeps_the_last_good_epoch_resumable(tmp_path, cache, monkeypatch):
    """A nan loss in epoch 2 stops before that step's update; last.pt, best.pt and the logs stay
    at epoch 1, and the run resumes from there."""
    from compact_perception.learning.training import epoch as epoch_mod
    from compact_perception.learning.training.train import train_run

    params, run, at = parse_params(_tiny(repo_params_dict())), tmp_path / "run", {"epoch": -1}
    real_set_epoch, real_scale = epoch_mod.set_epoch, epoch_mod.scale_de_loss

    def set_epoch(loader, epoch, seed):
        at["epoch"] = epoch
        return real_set_epoch(loader, epoch, seed)

    def poisoned(losses, factor):
        out = real_scale(losses, factor)
        return {k: v * float("nan") for k, v in out.items()} if at["epoch"] == 1 else out

    monkeypatch.setattr(epoch_mod, "set_epoch", set_epoch)
    monkeypatch.setattr(epoch_mod, "scale_de_loss", poisoned)
    with pytest.raises(RunError) as exc:
        train_run(params, run_in(params, MODEL, cache, run, export_onnx=False))
    assert str(exc.value) == f"{run}: epoch 2: non-finite de loss (nan)"
    assert torch.load(run / "last.pt", weights_only=True)["epoch"] == 0
    assert (run / "best.pt").is_file() and not (run / "summary.json").exists()
    logged = (run / "live" / "plots" / "metrics" / "lr.tsv").read_text().split()[2::2]
    assert logged == ["0"]
    monkeypatch.undo()
    assert train_run(params, run_in(params, MODEL, cache, run, export_onnx=False))["epochs_run"] == 2


@pytest.mark.parametrize("text", [".inf", ".nan", "-.inf"])
def test_non_finite_params_are_rejected_naming_the_key(tmp_path, text):
    """YAML's ``.inf`` passed ``lr``'s ``gt=0`` and diverged; every float of the schema is finite."""
    d = repo_params_dict()
    d["train"]["recipe"]["lr"] = "PLACEHOLDER"
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(d).replace("lr: PLACEHOLDER", f"lr: {text}"))
    with pytest.raises(ParamsError) as exc:
        load_params(path)
    msg = str(exc.value)
    assert "\n" not in msg and msg.startswith(f"{path}: train.recipe.lr: "), msg
    if text == ".inf":
        assert msg == f"{path}: train.recipe.lr: Input should be a finite number (got inf)"


def test_an_infinite_weighting_setting_stops_the_stage(tmp_path, cache):
    d = _tiny(repo_params_dict())
    d["train"]["models"]["compact_15l_mgn"]["mgn"]["lr"] = float("inf")
    path = _params_file(tmp_path, d)
    msg = _train_main(path, cache, tmp_path / "run", "compact_15l_mgn")
    assert msg == f"error: {path}: train.models.compact_15l_mgn.mgn.lr: Input should be a finite number (got inf)"
    assert not (tmp_path / "run").exists()


# ----------------------------------------------------------------------------- item 4: the data digest
def test_cache_fingerprint_sees_the_data_wherever_the_cache_is(tmp_path, cache):
    """A cache under a folder named ``test`` hashed nothing (the empty sha256), so changed
    training data went unnoticed by the resume digest."""
    from compact_perception.learning.training.train import cache_fingerprint

    moved = tmp_path / "some" / "test" / "A"
    shutil.copytree(cache, moved)
    digest = cache_fingerprint(moved)
    assert digest == cache_fingerprint(cache) != hashlib.sha256().hexdigest()
    arr = np.load(moved / "train" / "rgb.npy")
    arr[0, 0, 0, 0, 0] ^= 1
    np.save(moved / "train" / "rgb.npy", arr)
    changed = cache_fingerprint(moved)
    assert changed != digest
    shutil.rmtree(moved / "test")  # the test split is not training data
    assert cache_fingerprint(moved) == changed
    shutil.rmtree(moved / "val")
    with pytest.raises(RunError, match=re.escape(f"{moved}: no val files to fingerprint")):
        cache_fingerprint(moved)


# ----------------------------------------------------------------------------- item 5: leftovers of a kill
def test_a_run_resumed_after_a_kill_inside_a_save_leaves_no_temporary(tmp_path, cache):
    """A process killed between mkstemp and the rename of ``best.pt`` leaves a 0-byte
    ``.best.pt.<random>.tmp``; the run that takes the folder over removes it."""
    from compact_perception.learning.training.train import train_run

    params, run = parse_params(_tiny(repo_params_dict())), tmp_path / "run"
    with pytest.raises(InterruptedError):
        train_run(params, run_in(params, MODEL, cache, run, export_onnx=False), stop_after_epochs=1)
    code = ("import os, sys; from compact_perception.core import io\n"
            "with io.atomic_path(sys.argv[1]) as tmp:\n    os.kill(os.getpid(), 9)\n")
    proc = subprocess.run([sys.executable, "-c", code, str(run / "best.pt")], capture_output=True)
    assert proc.returncode == -9
    assert len(list(run.glob(".best.pt.*.tmp"))) == 1
    assert train_run(params, run_in(params, MODEL, cache, run, export_onnx=False))["epochs_run"] == 2
    assert not [p for p in run.rglob("*") if p.name.endswith(".tmp")]


# ----------------------------------------------------------------------------- item 6: bad params
@pytest.mark.parametrize("resolution", [16, 48, 2048])
def test_a_resolution_no_network_takes_is_rejected(tmp_path, resolution):
    from pipeline.generate import main

    d = repo_params_dict()
    d["world"]["resolution"]["default"] = resolution
    path = _params_file(tmp_path, d)
    msg = _exit_message(main, ["--dataset", "A", "--params", str(path), "--out", str(tmp_path / "raw"),
                               "--figure-dir", str(tmp_path / "figs")])
    assert msg.startswith(f"error: {path}: world.resolution: ") and "multiple of 32" in msg and str(resolution) in msg
    assert _files(tmp_path) == {Path("params.yaml")}


@pytest.mark.parametrize("resolution", [32, 64])
@pytest.mark.parametrize("model_id", ["gradnorm_segnet", "polarnet", "chen_bev", "compact_15l"])
def test_every_network_runs_at_the_resolutions_the_schema_allows(model_id, resolution):
    """The schema's smallest resolution, 32, and the next one, 64, run forward in every network
    (GradNorm SegNet failed at 16: 'Output size is too small')."""
    from compact_perception.learning.models import build_model
    from compact_perception.evaluation.efficiency import dummy_batch

    model = build_model(model_id, "A").eval()
    with torch.no_grad():
        out = model(dummy_batch(model, n_seg=23, has_dvs=True, resolution=resolution))
    assert all(v.shape[-2:] == (resolution, resolution) and torch.isfinite(v).all() for v in out.values())


def test_a_duplicate_key_in_params_is_an_error_naming_key_and_line(tmp_path):
    lines = (Path(__file__).resolve().parents[1] / "params.yaml").read_text().splitlines()
    at = next(i for i, line in enumerate(lines) if line.strip().startswith("lr: 0.1"))
    lines.insert(at + 1, lines[at].replace("0.1", "0.2"))
    path = tmp_path / "params.yaml"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ParamsError) as exc:
        load_params(path)
    assert str(exc.value) == f"{path}: duplicate key 'lr' at line {at + 2}"
    from pipeline.nuscenes_sim import main

    msg = _exit_message(main, ["--params", str(path), "--out", str(tmp_path / "out")])
    assert msg == f"error: {path}: duplicate key 'lr' at line {at + 2}"
    assert not (tmp_path / "out").exists()


def test_a_merge_key_and_the_same_key_in_other_mappings_are_not_duplicates():
    from compact_perception.core.params import UniqueKeyLoader

    text = "base: &b {lr: 0.1, momentum: 0.9}\nmodel:\n  <<: *b\n  lr: 0.2\nother: {lr: 0.3}\n"
    assert yaml.load(text, Loader=UniqueKeyLoader) == {
        "base": {"lr": 0.1, "momentum": 0.9}, "model": {"lr": 0.2, "momentum": 0.9}, "other": {"lr": 0.3}}


# ----------------------------------------------------------------------------- what held and must keep holding
@pytest.mark.parametrize("entry", ["../../etc/passwd", "/etc/passwd"])
def test_a_data_info_entry_outside_its_frame_folder_is_rejected(copy, tmp_path, entry):
    info = fx.set_info(copy, "Va2", val_idx=[entry])
    msg = stage_error("preprocess", write_params(repo_params_dict(), tmp_path, copy), tmp_path)
    assert msg.startswith(f"error: {info}: val_idx[0] is {entry!r}; expected a frame file name"), msg


def test_a_python_tag_in_data_info_is_rejected_unrun(copy, tmp_path):
    marker = tmp_path / "marker"
    info = fx.set_info(copy, "Va2", val_idx="TAGGED")
    tag = f"!!python/object/apply:os.system [{shlex.quote('touch ' + str(marker))}]"
    text = info.read_text().replace("TAGGED", tag)
    yaml.unsafe_load(text)
    assert marker.exists(), "the tag does not execute: the test would prove nothing"
    marker.unlink()
    fx.replace(info, lambda p: p.write_text(text))
    msg = stage_error("preprocess", write_params(repo_params_dict(), tmp_path, copy), tmp_path)
    assert msg.startswith(f"error: {info}: not valid YAML (") and "python/object/apply" in msg, msg
    assert not marker.exists()


# ----------------------------------------------------------------------------- issue 26: storms, stalls, tracebacks
def _set(d: dict, dotted: str, value) -> dict:
    node = d
    *head, last = dotted.split(".")
    for k in head:
        node = node[k]
    node[last] = value
    return d


def test_a_billion_frames_is_refused_at_once_naming_the_bound(tmp_path, monkeypatch):
    """``datasets.A.frames: 1000000000`` made generate build one dict per episode (680 MB after 40 s)."""
    import time

    from pipeline.generate import main

    params = _params_file(tmp_path, _set(repo_params_dict(), "datasets.A.frames.default", 1_000_000_000))
    monkeypatch.chdir(tmp_path)
    t0 = time.perf_counter()
    msg = _exit_message(main, ["--dataset", "A", "--params", str(params), "--out", "raw", "--figure-dir", "figs"])
    assert time.perf_counter() - t0 < 10
    assert msg == f"error: {params}: datasets.A.frames: default: 1000000000 exceeds 1000000 (frames a dataset may have)"
    assert _files(tmp_path) == {Path("params.yaml")}


@pytest.mark.parametrize("key, value, bound", [
    ("train.num_workers", 1000, "256"),              # the process storm of issue 26
    ("train.parallel_runs", 1000, "256"),
    ("train.num_threads", 1000, "256"),
    ("world.workers", 1000, "256"),
    ("preprocess.workers", 1000, "256"),
    ("train.batch_size", 100_000, "1024"),
    ("world.frames_per_episode", 100_000, "10000"),
    ("world.resolution.full", 4096, "1024"),
    ("datasets.nuscenes.sim_samples_per_scene", 1000, "100"),
    ("datasets.nuscenes.sim_scenes.paper", 10_000_000, "10000"),
    ("datasets.C.frames.paper", 2_000_000, "1000000"),
    ("evaluate.save_predictions", 10_000_000, "10000"),
])
def test_every_count_that_sizes_memory_processes_or_disk_has_an_upper_bound(key, value, bound):
    with pytest.raises(ParamsError) as exc:
        parse_params(_set(repo_params_dict(), key, value))
    msg = str(exc.value)
    parent = key.rsplit(".", 1)[0] if key.endswith((".full", ".paper", ".default")) else key
    assert f": {parent}: " in msg and bound in msg and str(value) in msg, msg


def test_generation_plans_its_episodes_lazily():
    """The most episodes the schema allows (1e6 frames, one per episode) start at once, and the lazy
    plan is the list plan, episode for episode (the same seeds, towns and order: the same bytes)."""
    import itertools
    import time

    from compact_perception.data.world import generate as gen

    d = _set(repo_params_dict(), "datasets.A.frames.default", 1_000_000)
    d["world"]["frames_per_episode"] = 1
    huge = parse_params(d)
    t0 = time.perf_counter()
    first = list(itertools.islice(gen.iter_episodes(huge, "A"), 3))
    assert time.perf_counter() - t0 < 1 and [e["index"] for e in first] == [0, 1, 2]
    assert gen.episode_count(huge, "A") == (1_000_000, 1_000_000)
    for ds in ("A", "B", "C"):
        p = parse_params(repo_params_dict())
        plan = gen.plan_episodes(p, ds)
        assert list(gen.iter_episodes(p, ds)) == plan
        assert gen.episode_count(p, ds) == (sum(e["frames"] for e in plan), len(plan))


def test_a_params_file_too_large_is_refused_at_once(tmp_path):
    """A 50 MB params file took 376 s to reach its error; anything over 1 MiB is refused unread."""
    import time

    from compact_perception.core.params import MAX_PARAMS_BYTES
    from pipeline.nuscenes_sim import main

    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(repo_params_dict()) + "# " + "x" * (2 * MAX_PARAMS_BYTES) + "\n")
    t0 = time.perf_counter()
    msg = _exit_message(main, ["--params", str(path), "--out", str(tmp_path / "out")])
    assert time.perf_counter() - t0 < 5
    assert msg == f"error: {path}: {path.stat().st_size} bytes, too large for a params file (at most {MAX_PARAMS_BYTES})"
    assert not (tmp_path / "out").exists()


def test_a_params_file_that_is_not_utf8_is_one_line(tmp_path):
    from pipeline.nuscenes_sim import main

    text = yaml.safe_dump(repo_params_dict()).encode()
    path = tmp_path / "params.yaml"
    path.write_bytes(b"# caf\xe9\n" + text)            # Latin-1, not UTF-8
    msg = _exit_message(main, ["--params", str(path), "--out", str(tmp_path / "out")])
    assert msg == f"error: {path}: not UTF-8 text (byte 0xe9 at line 1)"
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("err", [errno.EACCES, errno.EROFS])
@pytest.mark.parametrize("folder", ["results", "data/eval"])
def test_evaluate_checks_it_can_write_before_it_writes(tmp_path, monkeypatch, err, folder):
    """A read-only results/ gave a PermissionError traceback after data/eval/ had been rewritten.
    (Tests run as root, whom chmod does not stop: the OS's refusal is simulated where files are made.)"""
    from compact_perception.core import io as cio
    from pipeline.evaluate import main

    root = _eval_tree(tmp_path)
    real = cio.tempfile.mkstemp

    def refuse(*a, dir=None, **k):
        if dir is not None and Path(dir).resolve().is_relative_to((root / folder).resolve()):
            raise OSError(err, os.strerror(err), str(dir))
        return real(*a, dir=dir, **k)

    (root / folder / "A").mkdir(parents=True)            # the folder is there, read-only
    monkeypatch.setattr(cio.tempfile, "mkstemp", refuse)
    before = {p: p.stat().st_mtime_ns for p in root.rglob("*")}
    monkeypatch.chdir(root)
    msg = _exit_message(main, ["--dataset", "A", "--params", "params.yaml"])
    assert msg == f"error: {folder}/A/floor_pixel: could not write ({os.strerror(err)})", msg
    assert {p: p.stat().st_mtime_ns for p in root.rglob("*")} == before   # nothing new, nothing rewritten


def _readonly(*_a, **_k):
    raise OSError(errno.EROFS, os.strerror(errno.EROFS), "out/file")


def stage_params(tmp_path: Path, stage: str) -> Path:
    """The params file one stage reads in ``tmp_path`` as a test of that stage alone sets it up:
    evaluate's is a finished run tree's; the others', the repository's on the CPU, a short benchmark."""
    if stage == "evaluate":
        _eval_tree(tmp_path)
        return tmp_path / "params.yaml"
    d = repo_params_dict()
    d["benchmark"].update(warmup=0, runs=3)
    d["train"]["device"] = "cpu"
    return _params_file(tmp_path, d)


@pytest.mark.parametrize("stage, target, argv", [
    ("generate", "compact_perception.data.world.generate.generate_dataset", ["--dataset", "A"]),
    ("preprocess", "pipeline.preprocess.preprocess_dataset", ["--dataset", "A"]),
    ("nuscenes_sim", "pipeline.nuscenes_sim.export_nuscenes_sim", []),
    ("ingest_nuscenes", "pipeline.ingest_nuscenes.ingest_from_params", []),
    ("train", "pipeline.train.run_jobs", ["--dataset", "A"]),
    ("evaluate", "pipeline.evaluate.evaluate_floors", ["--dataset", "A"]),
    ("report", "pipeline.report.build_reports", []),
    ("benchmark", "compact_perception.core.io.write_json",
     ["--datasets", "A", "--models", "compact_1l", "--no-onnx"]),
])
def test_every_stage_turns_a_failed_write_into_one_line(tmp_path, monkeypatch, stage, target, argv):
    """A read-only file system (or a full disk) in any stage: one line with the path, exit status 1."""
    import importlib

    params = stage_params(tmp_path, stage)
    monkeypatch.chdir(tmp_path)
    module, name = target.rsplit(".", 1)
    monkeypatch.setattr(importlib.import_module(module), name, _readonly)
    main = importlib.import_module(f"pipeline.{stage}").main
    msg = _exit_message(main, [*argv, "--params", str(params)])
    assert msg == f"error: out/file: could not write ({os.strerror(errno.EROFS)})"


@pytest.mark.parametrize("reader", ["read_best", "read_checkpoint", "load_resumable", "mark_finished"])
def test_no_checkpoint_error_advises_an_unsafe_load(tmp_path, reader):
    """Evaluate's line used to repeat torch's advice to re-run torch.load with weights_only=False."""
    from compact_perception.evaluation.evaluate import read_best
    from compact_perception.learning.training import checkpoint

    marker = tmp_path / "marker"
    path = _crafted(tmp_path / "best.pt", marker, digest="d", epoch=0)
    params = parse_params(repo_params_dict())
    call = {"read_best": lambda: read_best(run_in(params, MODEL, tmp_path, tmp_path)),
            "read_checkpoint": lambda: checkpoint.read_checkpoint(path),
            "load_resumable": lambda: checkpoint.load_resumable(path, "d"),
            "mark_finished": lambda: checkpoint.mark_finished(path)}[reader]
    with pytest.raises(RunError) as exc:
        call()
    msg = str(exc.value)
    assert "it holds more than tensors and plain data, not loaded: unsupported GLOBAL" in msg, msg
    for advice in ("weights_only", "safe_globals", "trusted", "arbitrary code", "Re-running"):
        assert advice not in msg, msg
    assert not marker.exists()
