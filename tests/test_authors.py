"""The authors' released CARLA dataset, read as released (compact_perception.data.authors).

The fixture (tests/authors_fixture.py) is written in the release's own layout; the real
stages run in-process (pipeline.generate.main, pipeline.preprocess.main) with a params file
that sets ``source: authors``.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

import authors_fixture as fx
from compact_perception.data.authors import ingest_authors, plan_authors
from compact_perception.core.cache import read_cache
from compact_perception.core.params import ParamsError, parse_params
from compact_perception.core.errors import RecordError
from pipeline import generate as generate_stage
from pipeline import preprocess as preprocess_stage
from repo_params import docs_params_block

DEFAULT_SPLITS = {"A": ("Tr1", "Va2", "Te2"), "B": ("Tr2", "Va1", "Te1"), "C": ("Tr12345", "Va12345", "Te12345")}


def authors_source(ds: str, root: str | Path) -> dict:
    """``datasets.<ds>.source`` of the authors' release as docs/data-formats.md shows it, at ``root``."""
    return {**docs_params_block("data-formats.md", "id: authors")["datasets"][ds]["source"], "root": str(root)}


@pytest.fixture(scope="module")
def release(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The pristine release (never modified: tests damage a hard-linked copy)."""
    return fx.build_release(tmp_path_factory.mktemp("release"))


@pytest.fixture()
def copy(release: Path, tmp_path: Path) -> Path:
    """A private copy of the release to damage."""
    return fx.link_copy(release, tmp_path / "dl" / "dataset")


def write_params(params_dict: dict, tmp_path: Path, root: Path, ds: str = "A", resolution: int = 128) -> Path:
    """A params file in tmp_path with ``datasets.<ds>.source`` the authors' release at ``root``."""
    params_dict["datasets"][ds]["source"] = authors_source(ds, root)
    params_dict["world"]["resolution"][params_dict["scale"]] = resolution
    params_dict["preprocess"]["workers"] = 2
    pf = tmp_path / "params.yaml"
    pf.write_text(yaml.safe_dump(params_dict))
    return pf


def run_preprocess(pf: Path, tmp_path: Path, ds: str = "A") -> Path:
    rc = preprocess_stage.main(["--dataset", ds, "--params", str(pf), "--raw-root", str(tmp_path / "raw"),
                                "--cache-root", str(tmp_path / "cache"), "--figures", str(tmp_path / "fig")])
    assert rc == 0
    return tmp_path / "cache" / ds


def stage_error(stage: str, pf: Path, tmp_path: Path, ds: str = "A") -> str:
    """Run a stage expecting exit status 1; returns its one-line message; nothing was written."""
    if stage == "preprocess":
        args = ["--raw-root", str(tmp_path / "raw"), "--cache-root", str(tmp_path / "cache"), "--figures", str(tmp_path / "fig")]
        main = preprocess_stage.main
    else:
        args = ["--out", str(tmp_path / "raw"), "--figure-dir", str(tmp_path / "fig")]
        main = generate_stage.main
    with pytest.raises(SystemExit) as exc:
        main(["--dataset", ds, "--params", str(pf), *args])
    msg = exc.value.code
    assert isinstance(msg, str) and msg.startswith("error: ") and "\n" not in msg, msg
    for out in ("raw", "cache", "fig"):
        assert not (tmp_path / out).exists(), f"{out} was written"
    return msg


# ----------------------------------------------------------------------------- params
def test_the_docs_name_the_papers_split_folders(params_dict: dict) -> None:
    """docs/data-formats.md's sources load as written, each with the paper's split folders."""
    for ds in DEFAULT_SPLITS:
        params_dict["datasets"][ds]["source"] = authors_source(ds, "/data/dataset")
    p = parse_params(params_dict)
    for ds, (tr, va, te) in DEFAULT_SPLITS.items():
        src = getattr(p.datasets, ds).source
        assert (src.id, src.root, src.splits.train, src.splits.val, src.splits.test) == \
            ("authors", "/data/dataset", tr, va, te)


def test_authors_splits_is_required_and_checked(params_dict: dict) -> None:
    bad = json.loads(json.dumps(params_dict))
    bad["datasets"]["B"]["source"] = {"id": "authors", "root": "/data/dataset"}
    with pytest.raises(ParamsError, match=r"datasets\.B\.source\.splits: Field required"):
        parse_params(bad)
    params_dict["datasets"]["A"]["source"] = authors_source("A", "/data/dataset")
    params_dict["datasets"]["A"]["source"]["splits"]["val"] = "../Va2"
    with pytest.raises(ParamsError, match=r"datasets\.A\.source\.splits\.val"):
        parse_params(params_dict)


def test_no_import_cycle(root: Path) -> None:
    code = ("import sys, compact_perception.data.authors; "
            "assert 'compact_perception.data.preprocess' not in sys.modules, 'authors imports preprocess'; "
            "from compact_perception.data.preprocess import RecordError; "
            "from compact_perception.core.errors import RecordError as E; assert RecordError is E")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=root, timeout=60)
    assert r.returncode == 0, r.stderr


# ----------------------------------------------------------------------------- the three sets
@pytest.mark.parametrize("ds", ["A", "B", "C"])
def test_default_splits_of_each_set(ds: str, release: Path, params_dict: dict) -> None:
    params_dict["datasets"][ds]["source"] = authors_source(ds, release)
    plan = plan_authors(release, parse_params(params_dict).dataset(ds).source.splits, ds)
    tr, va, te = DEFAULT_SPLITS[ds]
    assert plan.splits["train"].ids == tuple(fx.split_list(tr)) and plan.splits["train"].frame_dir == release / "TrSet"
    assert plan.splits["val"].ids == tuple(fx.split_list(va)) and plan.splits["val"].frame_dir == release / "VaSet"
    assert plan.splits["test"].ids == tuple(sorted(fx.split_list(te))) and plan.splits["test"].frame_dir == release / "TeSet"
    assert [plan.splits[s].key for s in ("train", "val", "test")] == ["train_idx", "val_idx", "test_idx"]
    # the test town never enters training (sets A and B)
    if ds != "C":
        test_town = int(te[2:])
        assert all(fx.frame_ids("TrSet")[f] != test_town for f in plan.splits["train"].ids)


@pytest.mark.parametrize("ds", ["A", "C"])
def test_stages_ingest_the_release_as_read_by_the_authors(ds: str, release: Path, params_dict: dict, tmp_path: Path) -> None:
    pf = write_params(params_dict, tmp_path, release, ds)
    assert generate_stage.main(["--dataset", ds, "--params", str(pf), "--out", str(tmp_path / "raw"),
                                "--figure-dir", str(tmp_path / "fig")]) == 0
    manifest = json.loads((tmp_path / "raw" / ds / "manifest.json").read_text())
    tr, va, te = DEFAULT_SPLITS[ds]
    assert manifest["splits"] == {"train": fx.split_list(tr), "val": fx.split_list(va), "test": sorted(fx.split_list(te))}
    assert (tmp_path / "fig" / f"world_{ds}.png").read_bytes()[:4] == b"\x89PNG"

    cache = read_cache(run_preprocess(pf, tmp_path, ds))
    assert cache.meta["source"] == "authors" and cache.meta["resolution"] == 128 and cache.meta["resize"] is None
    assert cache["train"].frame_ids == fx.split_list(tr) and cache["test"].frame_ids == sorted(fx.split_list(te))
    assert cache.meta["seg_classes"] == fx.SEG_CLASSES and cache.meta["bev_classes"] == fx.BIRD_CLASSES
    for split, frame_folder in (("val", "VaSet"), ("test", "TeSet")):
        a = cache[split].arrays
        for n, fid in enumerate(cache[split].frame_ids):
            c = fx.frame_content(frame_folder, fid)
            assert np.array_equal(a["rgb"][n], c["bgr"][..., ::-1].transpose(0, 3, 1, 2))  # stored RGB
            dvs = a["dvs"][n]
            assert np.array_equal(dvs[:, 0], (c["dvs_bgr"][..., 0] > 0).astype(np.uint8))  # blue = positive
            assert np.array_equal(dvs[:, 1], (c["dvs_bgr"][..., 2] > 0).astype(np.uint8))  # red = negative
            assert np.allclose(a["de"][n][:, 0], c["depth"] / 255.0, atol=1e-3)
            assert np.array_equal(a["ss"][n], c["ss"]) and np.array_equal(a["ls"][n], c["ls"])
            assert np.array_equal(a["bevp"][n], c["bev"].astype(np.uint8))
            assert np.allclose(a["lidar"][n][:14], c["lid15"][:14], atol=1e-3)
            assert np.allclose(a["lidar"][n][14], c["lid1"] / 255.0, atol=1e-3)
    assert (tmp_path / "fig" / f"lidar_preprocessing_{ds}.png").is_file()


def test_channel_14_is_the_1l_png(copy: Path, tmp_path: Path) -> None:
    """The 1L model reads cache channel 14: it holds lid_depth_top/<id> / 255, not the npy's channel 14."""
    png = copy / "TeSet" / "lid_depth_top" / "0000.png"
    fx.replace(png, lambda p: cv2.imwrite(str(p), np.full((128, 128), 51, np.uint8)))
    cache = read_cache(ingest_authors(copy, {"train": "Tr1", "val": "Va2", "test": "Te12345"}, tmp_path / "c", "A"))
    n = cache["test"].frame_ids.index("0000.png")
    assert np.allclose(cache["test"].arrays["lidar"][n][14], 0.2, atol=1e-3)
    assert np.allclose(cache["test"].arrays["lidar"][n][:14], fx.frame_content("TeSet", "0000.png")["lid15"][:14], atol=1e-3)


def test_resized_to_world_resolution(release: Path, params_dict: dict, tmp_path: Path) -> None:
    """At 64 px: area for images, depth and LiDAR; nearest for classes and masks; DVS = any event."""
    pf = write_params(params_dict, tmp_path, release, "B", resolution=64)
    cache = read_cache(run_preprocess(pf, tmp_path, "B"))
    assert cache.meta["resolution"] == 64 and cache.meta["source_resolution"] == 128 and cache.meta["resize"]
    a, fid = cache["test"].arrays, cache["test"].frame_ids[0]
    c = fx.frame_content("TeSet", fid)

    def block_mean(x: np.ndarray) -> np.ndarray:
        return x.reshape(x.shape[:-2] + (64, 2, 64, 2)).astype(np.float64).mean(axis=(-3, -1))

    assert a["rgb"].shape[1:] == (4, 3, 64, 64) and a["ss"].shape[1:] == (4, 64, 64) and a["lidar"].shape[1:] == (15, 64, 64)
    rgb = c["bgr"][..., ::-1].transpose(0, 3, 1, 2)
    assert np.abs(a["rgb"][0].astype(np.int64) - np.round(block_mean(rgb))).max() <= 1
    assert np.allclose(a["de"][0][:, 0], block_mean(c["depth"] / 255.0), atol=2e-3)
    assert np.allclose(a["lidar"][0][:14], block_mean(c["lid15"][:14]), atol=2e-3)
    assert np.allclose(a["lidar"][0][14], block_mean(c["lid1"] / 255.0), atol=2e-3)
    pos = c["dvs_bgr"][..., 0] > 0
    assert np.array_equal(a["dvs"][0][:, 0], pos.reshape(4, 64, 2, 64, 2).any(axis=(2, 4)).astype(np.uint8))
    # nearest: every output label is the label of one of the 2x2 source pixels it covers
    for got, src in ((a["ss"][0], c["ss"]), (a["ls"][0], c["ls"]), (a["bevp"][0], c["bev"].astype(np.uint8))):
        blocks = src.reshape(src.shape[:-2] + (64, 2, 64, 2))
        assert (blocks == got[..., :, None, :, None]).any(axis=(-3, -1)).all()
    assert set(np.unique(a["ss"][0])) <= set(np.unique(c["ss"])) and a["bevp"].max() <= 1


# ----------------------------------------------------------------------------- split lists
def test_null_list_falls_back_as_in_train_py(copy: Path, tmp_path: Path) -> None:
    fx.set_info(copy, "Tr1", train_idx=None, val_idx=["0002.png", "0000.png"])  # train: train -> val -> test
    fx.set_info(copy, "Va2", val_idx=None, test_idx=None, train_idx=["0001.png"])  # val: val -> test -> train
    plan = plan_authors(copy, {"train": "Tr1", "val": "Va2", "test": "Te2"}, "A")
    assert plan.splits["train"].key == "val_idx" and plan.splits["train"].ids == ("0002.png", "0000.png")
    assert plan.splits["val"].key == "train_idx" and plan.splits["val"].ids == ("0001.png",)


def test_null_test_list_is_an_error(copy: Path, params_dict: dict, tmp_path: Path) -> None:
    """predict.py reads test_idx only: no fall-back for the test split."""
    info = fx.set_info(copy, "Te2", test_idx=None, val_idx=["0001.png"])
    msg = stage_error("preprocess", write_params(params_dict, tmp_path, copy), tmp_path)
    assert msg.startswith(f"error: {info}: test_idx is null")


def test_empty_list_is_an_error(copy: Path, params_dict: dict, tmp_path: Path) -> None:
    info = fx.set_info(copy, "Tr1", train_idx=[])
    pf = write_params(params_dict, tmp_path, copy)
    for stage in ("preprocess", "generate"):
        msg = stage_error(stage, pf, tmp_path)
        assert msg.startswith(f"error: {info}: train_idx is an empty list")


def test_split_folder_without_yml(copy: Path, params_dict: dict, tmp_path: Path) -> None:
    (copy / "Va1" / "data_info.yml").unlink()
    pf = write_params(params_dict, tmp_path, copy, "B")
    for stage in ("preprocess", "generate"):
        msg = stage_error(stage, pf, tmp_path, "B")
        assert msg.startswith(f"error: {copy / 'Va1' / 'data_info.yml'}: file not found") and "source.splits.val" in msg


def test_missing_frame_file(copy: Path, params_dict: dict, tmp_path: Path) -> None:
    gone = copy / "TrSet" / "segmentation_ri" / "0001_128.npy"
    gone.unlink()
    pf = write_params(params_dict, tmp_path, copy)
    for stage in ("preprocess", "generate"):
        msg = stage_error(stage, pf, tmp_path)
        assert msg.startswith(f"error: {gone}: file not found") and str(copy / "Tr1" / "data_info.yml") in msg


@pytest.mark.parametrize("shape", [(9, 64, 64), (128, 128, 9)])
def test_wrong_array_shape(shape: tuple[int, ...], copy: Path, params_dict: dict, tmp_path: Path) -> None:
    bad = copy / "VaSet" / "bird_view" / "0001_128.npy"
    fx.replace(bad, lambda p: np.save(p, np.zeros(shape)))
    msg = stage_error("preprocess", write_params(params_dict, tmp_path, copy), tmp_path)
    assert msg == f"error: {bad}: array of shape {shape}, expected (9, 128, 128) (channels first, 128 px)"


def test_list_entries_must_be_file_names(copy: Path, params_dict: dict, tmp_path: Path) -> None:
    info = fx.set_info(copy, "Va2", val_idx=[0])
    msg = stage_error("preprocess", write_params(params_dict, tmp_path, copy), tmp_path)
    assert msg.startswith(f"error: {info}: val_idx[0] is 0; expected a frame file name")


def test_listed_frame_absent_and_bad_png(copy: Path, tmp_path: Path) -> None:
    fx.set_info(copy, "Te2", test_idx=["0001.png", "0099.png"])
    with pytest.raises(RecordError, match=r"TeSet/rgb_f/0099\.png: file not found"):
        ingest_authors(copy, {"train": "Tr1", "val": "Va2", "test": "Te2"}, tmp_path / "c", "A")
    fx.set_info(copy, "Te2")
    depth = copy / "TeSet" / "depth_l" / "0001.png"
    fx.replace(depth, lambda p: cv2.imwrite(str(p), np.zeros((128, 128, 3), np.uint8)))
    with pytest.raises(RecordError, match=r"depth_l/0001\.png: PNG mode RGB; expected a single-channel"):
        ingest_authors(copy, {"train": "Tr1", "val": "Va2", "test": "Te2"}, tmp_path / "c", "A", workers=2)
    assert not (tmp_path / "c").exists()


def test_splits_sharing_frames_are_an_error(release: Path) -> None:
    """Val = Tr1 (its train_idx, by the fall-back) overlaps train = Tr12345 in the same frame folder."""
    with pytest.raises(RecordError, match=r"Tr1/data_info\.yml: train_idx shares 2 frame\(s\) of .*TrSet"):
        plan_authors(release, {"train": "Tr12345", "val": "Tr1", "test": "Te2"}, "A")


def test_missing_authors_root(params_dict: dict, tmp_path: Path) -> None:
    pf = write_params(params_dict, tmp_path, tmp_path / "nowhere" / "dataset", "C")
    for stage in ("generate", "preprocess"):
        msg = stage_error(stage, pf, tmp_path, "C")
        assert msg.startswith("error: datasets.C.source.root: ") and "is not a directory" in msg
