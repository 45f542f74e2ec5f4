"""Bad input gets a one-line error naming the file or key, exit status 1, no traceback, and
nothing half-written: params, a missing nuScenes dataroot, a truncated cache array, a
truncated nuScenes sweep or lidarseg label file.

Stages run in-process through their ``main([...])`` (``sys.exit("error: ...")`` is exit status
1), one through ``python -m`` to see the status and stderr for real.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from compact_perception.core.params import ParamsError, load_params

from repo_params import ROOT, cap_epochs, repo_params_dict, set_seeds
from synthetic import make_cache


def _write_params(path: Path, d: dict) -> Path:
    path.write_text(yaml.safe_dump(d))
    return path


def _exit_message(main, argv: list[str]) -> str:
    """Run a stage's main; it must exit with an error string (status 1), returned here."""
    with pytest.raises(SystemExit) as exc:
        main(argv)
    code = exc.value.code
    assert isinstance(code, str), f"exit code {code!r}: expected an error message (status 1)"
    assert code.startswith("error: ") and "\n" not in code, code
    assert "Traceback" not in code
    return code


def _files(root: Path) -> set[Path]:
    return {p.relative_to(root) for p in root.rglob("*")}


# ----------------------------------------------------------------------------- params
@pytest.mark.parametrize(
    "path, value, key",
    [
        (("train", "batch_size"), True, "train.batch_size"),
        (("datasets", "A", "training", "max_epochs", "default"), 0, "datasets.A.training.max_epochs"),
        (("train", "models", "gradnorm_segnet", "max_epochs"), {"default": 3, "full": 3, "paper": 0},
         "train.models.gradnorm_segnet.max_epochs"),
        (("train", "recipe", "lr_min"), None, "train.recipe.lr_min"),  # None: delete the key
        (("datasets", "A", "seed_offset"), None, "datasets.A.seed_offset"),
        (("preprocess", "fill_neighbours"), None, "preprocess.fill_neighbours"),
    ],
)
def test_load_params_names_the_bad_key(tmp_path, path, value, key):
    d = repo_params_dict()
    node = d
    for k in path[:-1]:
        node = node[k]
    if value is None:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    p = _write_params(tmp_path / "params.yaml", d)
    with pytest.raises(ParamsError) as exc:
        load_params(p)
    msg = str(exc.value)
    assert "\n" not in msg and msg.startswith(f"{p}: ") and f"{key}: " in msg, msg
    if value is None:
        assert "Field required" in msg


def test_bad_params_stop_a_stage_with_one_line(tmp_path):
    from pipeline.nuscenes_sim import main

    d = repo_params_dict()
    d["train"]["batch_size"] = True
    d["datasets"]["A"]["training"]["max_epochs"]["default"] = 0
    p = _write_params(tmp_path / "params.yaml", d)
    msg = _exit_message(main, ["--params", str(p), "--out", str(tmp_path / "out")])
    assert "train.batch_size" in msg and "datasets.A.training.max_epochs" in msg and str(p) in msg
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("where, value, message", [
    (("study", "arms", "uw", "uw", "lr"), "fast", "study.arms.uw.uw.lr: Input should be a valid number (got 'fast')"),
    (("train", "models", "compact_15l_mgn", "mgn", "alpha"), -1.0,
     "train.models.compact_15l_mgn.mgn.alpha: Input should be greater than or equal to 0 (got -1.0)"),
])
@pytest.mark.parametrize("argv", [[], ["--model", "compact_1l", "--seed", "0"]])
def test_bad_weighting_settings_stop_the_stage_before_it_writes(tmp_path, monkeypatch, where, value, message, argv):
    """Every recipe's and study arm's weighting settings are checked by the method's schema when
    a train stage starts, whether it trains them or not (the study's arms do not run at the
    default scale): one line naming the params file and the key, nothing written."""
    from pipeline.train import main

    d = repo_params_dict()
    node = d
    for key in where[:-1]:
        node = node[key]
    node[where[-1]] = value
    p = _write_params(tmp_path / "params.yaml", d)
    monkeypatch.chdir(tmp_path)
    msg = _exit_message(main, ["--dataset", "A", *argv, "--cache", str(tmp_path / "no_cache"), "--params", str(p)])
    assert msg == f"error: {p}: {message}", msg
    assert _files(tmp_path) == {Path("params.yaml")}


# ----------------------------------------------------------------------------- nuscenes_sim
def test_missing_nuscenes_dataroot_in_process(tmp_path):
    from pipeline.nuscenes_sim import main

    d = repo_params_dict()
    d["datasets"]["nuscenes"]["dataroot"] = str(tmp_path / "no_such_nuscenes")
    p = _write_params(tmp_path / "params.yaml", d)
    msg = _exit_message(main, ["--params", str(p), "--out", str(tmp_path / "raw" / "nuscenes_sim")])
    assert "datasets.nuscenes.dataroot" in msg and str(tmp_path / "no_such_nuscenes") in msg
    assert _files(tmp_path) == {Path("params.yaml")}


def test_nuscenes_dataroot_without_its_tables(tmp_path):
    from pipeline.nuscenes_sim import main

    d = repo_params_dict()
    (tmp_path / "nus").mkdir()
    d["datasets"]["nuscenes"]["dataroot"] = str(tmp_path / "nus")
    p = _write_params(tmp_path / "params.yaml", d)
    msg = _exit_message(main, ["--params", str(p), "--out", str(tmp_path / "raw" / "nuscenes_sim")])
    assert "datasets.nuscenes.dataroot" in msg and str(tmp_path / "nus" / "v1.0-trainval") in msg
    assert _files(tmp_path) == {Path("params.yaml"), Path("nus")}


def test_missing_nuscenes_dataroot_as_a_process(tmp_path):
    d = repo_params_dict()
    d["datasets"]["nuscenes"]["dataroot"] = "nowhere/nuscenes"  # relative: to the stage's cwd
    p = _write_params(tmp_path / "params.yaml", d)
    r = subprocess.run([sys.executable, "-m", "pipeline.nuscenes_sim", "--params", "params.yaml",
                        "--out", "data/raw/nuscenes_sim"], capture_output=True, text=True, timeout=300, cwd=tmp_path,
                       env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert r.returncode == 1, r.stderr
    errors = [line for line in r.stderr.splitlines() if line.startswith("error: ")]
    assert errors == ["error: params.yaml: datasets.nuscenes.dataroot: nuScenes dataroot not found: nowhere/nuscenes "
                      "(expected a folder holding the v1.0-trainval tables)"], r.stderr
    assert "Traceback" not in r.stderr
    assert _files(tmp_path) == {p.relative_to(tmp_path)}


# ----------------------------------------------------------------------------- truncated cache
def _train_params(tmp_path: Path) -> Path:
    d = repo_params_dict()
    cap_epochs(d, 1)
    d["train"]["batch_size"] = 2
    d["train"]["num_workers"] = 2  # loader workers: the error must come before them, without their noise
    d["train"]["device"] = "cpu"
    return _write_params(tmp_path / "params.yaml", d)


def _truncate(path: Path, drop: int = 7) -> None:
    data = path.read_bytes()
    path.write_bytes(data[:-drop])


@pytest.mark.parametrize("victim", ["train/lidar.npy", "val/ss.npy", "train/rgb.npy"])
def test_truncated_cache_stops_train(tmp_path, victim):
    from pipeline.train import main

    cache = make_cache(tmp_path / "cache", size=16, counts=(3, 2, 2))
    _truncate(cache / victim)
    params = _train_params(tmp_path)
    out = tmp_path / "runs" / "A" / "compact_1l"
    msg = _exit_message(main, ["--dataset", "A", "--model", "compact_1l", "--seed", "0", "--params", str(params),
                               "--cache", str(cache), "--out", str(out)])
    assert str(cache / victim) in msg and "truncated" in msg and "expected" in msg, msg
    assert not (tmp_path / "runs").exists()  # no checkpoint, no dvclive folder


def test_bad_npy_header_stops_train(tmp_path):
    from pipeline.train import main

    cache = make_cache(tmp_path / "cache", size=16, counts=(3, 2, 2))
    (cache / "train" / "ls.npy").write_bytes(b"\x93NUMPY")  # cut inside the header
    params = _train_params(tmp_path)
    msg = _exit_message(main, ["--dataset", "A", "--model", "compact_1l", "--seed", "0", "--params", str(params),
                               "--cache", str(cache), "--out", str(tmp_path / "run")])
    assert str(cache / "train" / "ls.npy") in msg and "not a readable .npy" in msg
    assert not (tmp_path / "run").exists()


def _eval_tree(tmp_path: Path) -> Path:
    """A cwd laid out like the repository: data/cache/A, runs/A/compact_1l/seed0/best.pt, params.yaml
    (seeds: [0])."""
    import torch

    from compact_perception.learning.models import build_model

    make_cache(tmp_path / "data" / "cache" / "A", size=16, counts=(3, 2, 2))
    run = tmp_path / "runs" / "A" / "compact_1l" / "seed0"
    run.mkdir(parents=True)
    torch.save({"model": build_model("compact_1l", "A").state_dict(), "epoch": 0}, run / "best.pt")
    d = repo_params_dict()
    d["train"]["device"] = "cpu"
    set_seeds(d, [0])
    d["model_ids"] = ["compact_1l"]
    _write_params(tmp_path / "params.yaml", d)
    return tmp_path


def test_truncated_cache_stops_evaluate(tmp_path, monkeypatch):
    from pipeline.evaluate import main

    root = _eval_tree(tmp_path)
    victim = root / "data" / "cache" / "A" / "test" / "bevp.npy"
    _truncate(victim, drop=1)
    before = _files(root)
    monkeypatch.chdir(root)
    msg = _exit_message(main, ["--dataset", "A", "--params", "params.yaml"])
    assert "data/cache/A/test/bevp.npy" in msg and "truncated" in msg
    assert _files(root) == before  # no results/, no data/eval/


def test_missing_checkpoint_stops_evaluate(tmp_path, monkeypatch):
    from pipeline.evaluate import main

    root = _eval_tree(tmp_path)
    (root / "runs" / "A" / "compact_1l" / "seed0" / "best.pt").unlink()
    before = _files(root)
    monkeypatch.chdir(root)
    msg = _exit_message(main, ["--dataset", "A", "--params", "params.yaml"])
    assert "runs/A/compact_1l/seed0/best.pt" in msg
    assert _files(root) == before


# ----------------------------------------------------------------------------- truncated nuScenes files
@pytest.fixture(scope="module")
def nus_root(tmp_path_factory) -> tuple[Path, dict]:
    """A tiny simulated nuScenes-format dataroot (fabricated episodes, as in test_nuscenes)."""
    from compact_perception.data.nuscenes.export import export_nuscenes_sim
    from test_nuscenes import _params, fake_episode

    d = repo_params_dict()
    params = _params(d)
    out = tmp_path_factory.mktemp("nus_errors") / "nuscenes"
    export_nuscenes_sim(params, out, episode_source=fake_episode)
    return out, d


def _ingest(tmp_path: Path, nus_root: tuple[Path, dict]) -> tuple[Path, Path, Path]:
    src, d = nus_root
    root = tmp_path / "nuscenes"
    shutil.copytree(src, root)
    d = yaml.safe_load(yaml.safe_dump(d))
    d["world"]["resolution"]["default"] = 32
    d["datasets"]["nuscenes"]["sim_scenes"]["default"] = 5
    d["datasets"]["nuscenes"]["sim_samples_per_scene"] = 2
    d["datasets"]["nuscenes"]["version"] = "v1.0-sim"
    d["datasets"]["nuscenes"]["dataroot"] = str(root)
    return root, _write_params(tmp_path / "params.yaml", d), tmp_path / "cache" / "nuscenes"


def test_truncated_sweep_stops_ingest(tmp_path, nus_root):
    from compact_perception.data.nuscenes import LIDAR_CHANNEL
    from pipeline.ingest_nuscenes import main

    root, params, out = _ingest(tmp_path, nus_root)
    victim = sorted((root / "samples" / LIDAR_CHANNEL).iterdir())[1]
    _truncate(victim, drop=6)  # not a whole number of 20-byte points
    msg = _exit_message(main, ["--params", str(params), "--out", str(out)])
    assert str(victim) in msg and "multiple of 20" in msg, msg
    assert not (tmp_path / "cache").exists() or not any((tmp_path / "cache").iterdir())


def test_sweep_cut_at_a_point_boundary_stops_ingest(tmp_path, nus_root):
    """Whole points missing: the sweep still reshapes, the label count no longer matches."""
    from compact_perception.data.nuscenes import LIDAR_CHANNEL
    from pipeline.ingest_nuscenes import main

    root, params, out = _ingest(tmp_path, nus_root)
    victim = sorted((root / "samples" / LIDAR_CHANNEL).iterdir())[0]
    _truncate(victim, drop=40)
    msg = _exit_message(main, ["--params", str(params), "--out", str(out)])
    assert "lidarseg label file" in msg and victim.name in msg and "expected" in msg, msg
    assert not (tmp_path / "cache").exists() or not any((tmp_path / "cache").iterdir())


def test_truncated_lidarseg_labels_stop_ingest(tmp_path, nus_root):
    from pipeline.ingest_nuscenes import main

    root, params, out = _ingest(tmp_path, nus_root)
    victim = sorted((root / "lidarseg" / "v1.0-sim").iterdir())[2]
    _truncate(victim, drop=1)
    msg = _exit_message(main, ["--params", str(params), "--out", str(out)])
    assert str(victim) in msg and "labels, expected" in msg, msg
    assert not (tmp_path / "cache").exists() or not any((tmp_path / "cache").iterdir())


def test_missing_dataroot_stops_ingest(tmp_path, nus_root):
    from pipeline.ingest_nuscenes import main

    root, params, out = _ingest(tmp_path, nus_root)
    shutil.rmtree(root)
    msg = _exit_message(main, ["--params", str(params), "--out", str(out)])
    assert msg.startswith("error: datasets.nuscenes.dataroot: nuScenes dataroot not found: ") and str(root) in msg
    assert not (tmp_path / "cache").exists()


# ----------------------------------------------------------------------------- a full disk while writing data
def _tiny_sim_params(tmp_path: Path) -> Path:
    d = repo_params_dict()
    d["world"]["resolution"]["default"] = 32
    d["world"]["lidar"]["horizontal_samples"] = 64
    d["world"]["frames_per_episode"] = 1
    d["world"]["workers"] = 1
    d["datasets"]["A"]["frames"]["default"] = 5
    d["datasets"]["A"]["split_ratio"]["default"] = {"train": 3, "val": 1, "test": 1}
    d["preprocess"]["workers"] = 1
    return _write_params(tmp_path / "params.yaml", d)


def _disk_full(*_a, **_k):
    import errno

    raise OSError(errno.ENOSPC, "No space left on device", "data/raw/A/frames/town01_ep0000_000.npz")


def test_disk_full_stops_generate_with_one_line(tmp_path, monkeypatch):
    """Generation that cannot write a frame: one line naming the file and the reason, and no
    dataset folder left behind (it is built in a temporary folder)."""
    from compact_perception.data.world import generate as gen
    from pipeline.generate import main

    params = _tiny_sim_params(tmp_path)
    monkeypatch.setattr(gen.io, "write_npz", _disk_full)
    monkeypatch.chdir(tmp_path)
    msg = _exit_message(main, ["--dataset", "A", "--params", str(params), "--out", "raw", "--figure-dir", "figs"])
    assert msg == "error: data/raw/A/frames/town01_ep0000_000.npz: could not write (No space left on device)"
    assert not (tmp_path / "raw").exists() or not any((tmp_path / "raw").iterdir())


def test_disk_full_stops_preprocess_with_one_line(tmp_path, monkeypatch):
    from compact_perception.core import cache as cache_mod
    from pipeline.generate import main as generate
    from pipeline.preprocess import main

    params = _tiny_sim_params(tmp_path)
    monkeypatch.chdir(tmp_path)
    assert generate(["--dataset", "A", "--params", str(params), "--out", "raw", "--figure-dir", "figs"]) == 0

    def full(*_a, **_k):
        import errno

        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(cache_mod.np, "save", full)
    monkeypatch.setattr(cache_mod.cio, "write_json", full)
    msg = _exit_message(main, ["--dataset", "A", "--params", str(params), "--raw-root", "raw",
                               "--cache-root", "cache", "--figures", "figs"])
    assert msg == "error: cache/A: could not write (No space left on device)"
    assert not (tmp_path / "cache" / "A").exists()


def test_missing_meta_stops_evaluate_naming_the_cache(tmp_path, monkeypatch):
    from pipeline.evaluate import main

    root = _eval_tree(tmp_path)
    (root / "data" / "cache" / "A" / "meta.json").unlink()
    before = _files(root)
    monkeypatch.chdir(root)
    msg = _exit_message(main, ["--dataset", "A", "--params", "params.yaml"])
    assert "data/cache/A" in msg and "meta.json" in msg
    assert _files(root) == before
