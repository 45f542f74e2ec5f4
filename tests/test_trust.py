"""Issue 56 items 1, 2 and 4 (part), each reproduced as a hostile user would: a damaged copy in a
DVC remote, a checkpoint or cache array changed after it was written, params.yaml edited while a
stage runs, and a JSON input nested 100,000 levels deep. Every one ends in one line
``error: <file>: <what was expected>`` (exit status 1) before anything is written.
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml

from compact_perception.core.cache import CacheError
from compact_perception.core.errors import ReportInputError
from compact_perception.core.io import read_json

from repo_params import ROOT, repo_params_dict
from test_errors import _eval_tree, _exit_message, _files
from test_pipeline_e2e import dvc_env, run
from test_reliability import _params_file, _tiny, _train_main, stage_params
from synthetic import make_cache

MODEL = "compact_1l"
RUN = Path("runs") / "A" / MODEL / "seed0"


def _flip(path: Path, offset: int = -1) -> None:
    """Flip one byte of ``path`` (the last by default) in place, keeping its size, mode and mtime:
    what a damaged disk or remote copy looks like (a read-only file stays read-only)."""
    st = path.stat()
    os.chmod(path, st.st_mode | 0o200)
    data = bytearray(path.read_bytes())
    data[offset] ^= 0xFF
    path.write_bytes(bytes(data))
    os.chmod(path, st.st_mode)
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))


# ----------------------------------------------------------------------------- item 1: a damaged remote
def _documented_remote_setup(remote: Path) -> list[list[str]]:
    """The ``dvc remote`` commands of docs/sharing.md's "Set up the remote once", on ``remote``."""
    section = (ROOT / "docs/sharing.md").read_text().split("## Set up the remote once", 1)[1].split("\n## ", 1)[0]
    block = re.search(r"```bash\n(.*?)```", section, re.S).group(1)
    cmds = []
    for line in block.splitlines():
        line = line.split("#", 1)[0].strip()
        if line.startswith("bin/venv dvc remote "):
            cmds.append(line.removeprefix("bin/venv ").replace("/srv/dvc/compact-perception", str(remote)).split())
    assert cmds and cmds[0][:3] == ["dvc", "remote", "add"], block
    return cmds


def test_the_documented_remote_refuses_a_damaged_copy_on_pull(tmp_path):
    """A byte flipped in the remote's copy of a checkpoint (the file stays read-only, as DVC left
    it): a fresh clone's ``dvc pull`` checked it out silently; with docs/sharing.md's set-up
    (``verify true``) the pull fails and leaves no damaged file in the workspace."""
    env = dvc_env(tmp_path)
    env.pop("COMPACT_PERCEPTION_PARAMS_AUDIT")
    repo, remote, clone = tmp_path / "repo", tmp_path / "dvc-remote", tmp_path / "clone"
    repo.mkdir()
    remote.mkdir()
    (repo / "best.pt").write_bytes(np.random.default_rng(0).bytes(4096))
    for cmd in (["git", "init", "-q"], ["dvc", "init", "-q"], ["dvc", "add", "best.pt"], *_documented_remote_setup(remote),
                ["dvc", "push"], ["git", "add", "-A"], ["git", "commit", "-qm", "x"]):
        run(cmd, repo, env)
    [copy] = [p for p in remote.rglob("*") if p.is_file()]
    _flip(copy, 100)
    run(["git", "clone", "-q", str(repo), str(clone)], tmp_path, env)
    proc = subprocess.run(["dvc", "pull"], cwd=clone, env=env, capture_output=True, text=True)
    assert proc.returncode != 0, proc.stdout + proc.stderr
    assert not (clone / "best.pt").exists()


# ----------------------------------------------------------------------------- item 1: hashes recorded when written
def test_a_run_records_its_best_checkpoints_hash(tmp_path):
    """summary.json's ``best_sha256``: the SHA-256 of best.pt as the finished run left it."""
    cache = make_cache(tmp_path / "cache", size=16, counts=(4, 2, 2))
    params = _params_file(tmp_path, _tiny(repo_params_dict(), epochs=1))
    from pipeline.train import main

    run_dir = tmp_path / "run"
    main(["--dataset", "A", "--model", MODEL, "--seed", "0", "--params", str(params), "--cache", str(cache),
          "--out", str(run_dir)])
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["best_sha256"] == hashlib.sha256((run_dir / "best.pt").read_bytes()).hexdigest()


def test_a_cache_records_the_hash_of_every_file_of_its_splits(tmp_path):
    from compact_perception.core.cache import verify_cache

    cache = make_cache(tmp_path / "cache", size=16, counts=(3, 2, 2))
    recorded = json.loads((cache / "meta.json").read_text())["sha256"]
    assert recorded == {split: {p.name: hashlib.sha256(p.read_bytes()).hexdigest()
                                for p in sorted((cache / split).iterdir())} for split in ("train", "val", "test")}
    assert verify_cache(cache)
    _flip(cache / "val" / "frame_ids.json", 3)
    with pytest.raises(CacheError, match=re.escape(f"{cache / 'val' / 'frame_ids.json'}: does not match the hash "
                                                   "recorded when it was written (SHA-256 ")):
        verify_cache(cache)


def _with_recorded_hash(root: Path) -> Path:
    """_eval_tree's run with the summary.json its training writes (the hash of its best.pt)."""
    best = root / RUN / "best.pt"
    (root / RUN / "summary.json").write_text(json.dumps({"best_sha256": hashlib.sha256(best.read_bytes()).hexdigest()}))
    return best


@pytest.mark.parametrize("victim", [RUN / "best.pt", Path("data/cache/A/test/rgb.npy"),
                                    Path("data/cache/A/train/ss.npy")])
def test_evaluate_refuses_a_file_changed_since_it_was_written(tmp_path, monkeypatch, victim):
    """One byte of a checkpoint's tensors, or of a cache array's frames (its header and size
    intact): evaluate scored it and wrote other metrics, without a word."""
    from pipeline.evaluate import main

    root = _eval_tree(tmp_path)
    _with_recorded_hash(root)
    _flip(root / victim)
    before = _files(root)
    monkeypatch.chdir(root)
    msg = _exit_message(main, ["--dataset", "A", "--params", "params.yaml"])
    assert msg.startswith(f"error: {victim}: does not match the hash recorded when it was written (SHA-256 "), msg
    assert _files(root) == before


def test_a_run_and_a_cache_from_before_hashes_were_recorded_still_evaluate(tmp_path, monkeypatch, caplog):
    from pipeline.evaluate import main

    root = _eval_tree(tmp_path)             # its run has no summary.json
    meta_path = root / "data/cache/A/meta.json"
    meta = json.loads(meta_path.read_text())
    meta.pop("sha256", None)
    meta_path.write_text(json.dumps(meta))
    monkeypatch.chdir(root)
    with caplog.at_level(logging.INFO):
        main(["--dataset", "A", "--params", "params.yaml"])
    assert (root / "results" / "A" / MODEL / "seed0" / "metrics.json").is_file()
    assert f"{RUN / 'best.pt'}: no hash recorded when it was written" in caplog.text
    assert "data/cache/A: no hashes recorded when it was written" in caplog.text


# ----------------------------------------------------------------------------- item 2: params edited mid-stage
def _edit_seed(params: Path, comment_only: bool = False) -> None:
    """What a user does in another terminal while the stage runs: a new ``seed`` (or a comment)."""
    if comment_only:
        params.write_text("# tried 7 first\n" + params.read_text())
        return
    d = yaml.safe_load(params.read_text())
    d["seed"] += 1
    params.write_text(yaml.safe_dump(d))


class _Source:
    """generate's data source whose writing edits params.yaml."""

    def __init__(self, edit) -> None:
        self.edit = edit

    def write_raw(self, *_a, **_k) -> None:
        self.edit()

    def draw_example(self, *_a, **_k) -> None:
        pass


# stage -> (the step that runs while the user edits, what it returns, argv)
_STEPS = {
    "generate": ("pipeline.generate.data_source", "source", ["--dataset", "A"]),
    "preprocess": ("pipeline.preprocess.preprocess_dataset", None, ["--dataset", "A"]),
    "nuscenes_sim": ("pipeline.nuscenes_sim.export_nuscenes_sim", None, []),
    "ingest_nuscenes": ("pipeline.ingest_nuscenes.ingest_from_params", None, []),
    "train": ("pipeline.train.run_jobs", [], ["--dataset", "A"]),
    "evaluate": ("pipeline.evaluate.run_jobs", [], ["--dataset", "A"]),
    "report": ("pipeline.report.build_reports", None, []),
    "benchmark": ("pipeline.benchmark.measure_model", {}, ["--datasets", "A", "--models", MODEL, "--no-onnx",
                                                          "--out", "out/efficiency.json"]),
}


def _stage_editing_params(tmp_path: Path, monkeypatch, stage: str, comment_only: bool = False):
    """``(main, argv)`` of ``stage`` in ``tmp_path``, its work replaced by an edit of its params file."""
    import importlib

    params = stage_params(tmp_path, stage)
    if stage == "evaluate":
        monkeypatch.setattr("pipeline.evaluate.evaluate_floors", lambda *a, **k: {})
    monkeypatch.chdir(tmp_path)
    target, returns, argv = _STEPS[stage]
    module, name = target.rsplit(".", 1)

    def edit(*_a, **_k):
        _edit_seed(params, comment_only)
        return returns

    if returns == "source":
        monkeypatch.setattr(importlib.import_module(module), name, lambda *_a, **_k: _Source(edit))
    else:
        monkeypatch.setattr(importlib.import_module(module), name, edit)
    return importlib.import_module(f"pipeline.{stage}").main, [*argv, "--params", str(params)], params


@pytest.mark.parametrize("stage", list(_STEPS))
def test_every_stage_fails_when_params_change_while_it_runs(tmp_path, monkeypatch, stage):
    """seed 0 -> 1 while the stage runs: it finished with status 0 and DVC recorded seed 1 for
    outputs made at seed 0 (``dvc status``: up to date)."""
    main, argv, params = _stage_editing_params(tmp_path, monkeypatch, stage)
    msg = _exit_message(main, argv)
    assert msg == f"error: {params}: changed while the stage ran (seed); run it again", msg


def test_every_stage_checks_its_params_at_its_end():
    """Every module of pipeline/ that reads params through ``start`` has its ``main`` wrapped in
    ``_common.stage`` (the check above), a stage added later too."""
    unchecked = [p.name for p in sorted((ROOT / "pipeline").glob("*.py"))
                 if p.name != "_common.py" and re.search(r"\bstart\(", p.read_text())
                 and not re.search(r"^@stage\ndef main\(", p.read_text(), re.M)]
    assert not unchecked, f"stages whose main is not wrapped in @stage: {unchecked}"


def test_a_comment_added_while_a_stage_runs_changes_nothing(tmp_path, monkeypatch):
    main, argv, _ = _stage_editing_params(tmp_path, monkeypatch, "report", comment_only=True)
    main(argv)


# ----------------------------------------------------------------------------- item 4: records nested too deeply
def test_read_json_names_a_file_nested_too_deeply(tmp_path):
    """100,000 nested lists (990 suffice under pytest): a RecursionError traceback."""
    path = tmp_path / "full_plateau.json"
    path.write_text('{"machine": ' + "[" * 100_000 + "]" * 100_000 + "}")
    with pytest.raises(ReportInputError) as err:
        read_json(path)
    assert str(err.value) == f"{path}: not valid JSON (nested too deeply to read)"


def test_the_report_names_a_plateau_record_nested_too_deeply(tmp_path, monkeypatch):
    from pipeline.report import main

    record = tmp_path / "full_plateau.json"
    record.write_text('{"machine": ' + "[" * 100_000 + "]" * 100_000 + "}")
    params = _params_file(tmp_path, repo_params_dict())
    monkeypatch.chdir(tmp_path)
    msg = _exit_message(main, ["--params", str(params), "--plateau-record", str(record), "--out", "reports"])
    assert msg == f"error: {record}: not valid JSON (nested too deeply to read)"
    assert not (tmp_path / "reports").exists()
