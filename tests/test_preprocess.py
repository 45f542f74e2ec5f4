"""Preprocessing (section IV-C, eq. (1)-(5)), the cache and the loader (the authors' dataset: test_authors.py)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from compact_perception.core.cache import CacheError, read_cache, write_cache
from compact_perception.core.classes import BEV_NAMES, CARLA_NAMES, CARLA_PALETTE, palette_to_index
from compact_perception.core.params import parse_params
from compact_perception.data.loader import make_loader, to_device
from compact_perception.data.dvs import dvs_colour_to_image, events_to_image
from compact_perception.data.lidar import height_channel, ls_ground_truth, topview_15l, topview_1l
from compact_perception.data.preprocess import RecordError, preprocess_dataset, preprocess_record, preprocess_sim
from compact_perception.data.record import RecordSpec
from compact_perception.data.geometry import VIEWS

from fixtures_raw import make_raw_dataset, make_record
from repo_params import section

S = 128


def pts(*rows: tuple[float, float, float, float]) -> np.ndarray:
    return np.array(rows, dtype=np.float32).reshape(-1, 4)


def occupied(img: np.ndarray) -> list[tuple[int, ...]]:
    return [tuple(int(v) for v in ix) for ix in np.argwhere(img != 0)]


# ----------------------------------------------------------------------------- eq. (2)-(3) grid
def test_cell_index_at_the_borders() -> None:
    assert occupied(topview_1l(pts((-32, -32, 0, 1)), 32, S, fill=False)) == [(0, 0)]
    assert occupied(topview_1l(pts((32, 32, 0, 1)), 32, S, fill=False)) == [(S - 1, S - 1)]
    assert occupied(topview_1l(pts((0, 0, 0, 1)), 32, S, fill=False)) == [(64, 64)]  # ego cell
    # x = 32.01 rounds to 127 but is outside the range: dropped
    assert occupied(topview_1l(pts((32.01, 0, 0, 1)), 32, S, fill=False)) == []
    assert occupied(topview_1l(pts((0, -32.01, 0, 1)), 32, S, fill=False)) == []


def test_rounding_at_half_cells() -> None:
    # S = 129, R = 32: exactly 2 cells per metre, so these land on exact half-cells
    img = topview_1l(pts((-31.75, 0, 0, 1)), 32, 129, fill=False)  # 0.5 -> 0 (half to even)
    assert occupied(img) == [(0, 64)]
    img = topview_1l(pts((-31.25, 0, 0, 1)), 32, 129, fill=False)  # 1.5 -> 2
    assert occupied(img) == [(2, 64)]
    # S = 128: just below / above the half-cell boundary between cells 0 and 1
    half = 64 / 127
    assert occupied(topview_1l(pts((-32 + 0.49 * half, 0, 0, 1)), 32, S, fill=False))[0][0] == 0
    assert occupied(topview_1l(pts((-32 + 0.51 * half, 0, 0, 1)), 32, S, fill=False))[0][0] == 1


def test_out_of_range_dropped_never_wrapped() -> None:
    far = pts((40, 0, 0, 1), (-40, 5, 0, 1), (0, 33, 0, 1), (0, -100, 0, 1))
    assert not topview_1l(far, 32, S).any()
    assert not topview_15l(far, 32, S).any()
    assert (ls_ground_truth(far, np.ones(4, np.uint8), 32, S) == 255).all()


# ----------------------------------------------------------------------------- eq. (5) heights
def test_height_channel() -> None:
    assert height_channel(np.array([-2.0, 11.0, 4.5, 0.0, -2.01, 11.01])).tolist() == [0, 13, 6, 2, -1, -1]
    img = topview_15l(pts((0, 0, -2, 0.3), (10, 0, 11, 0.6), (0, 10, -2.5, 0.9), (0, -10, 12, 0.8)), fill=False)
    assert img.shape == (15, S, S)
    i10 = int(np.rint(42 / 64 * 127))  # x = 10 m -> rint(83.34) = 83
    j10, jm10 = i10, int(np.rint(22 / 64 * 127))
    assert img[0, 64, 64] == pytest.approx(0.3)
    assert img[13, i10, 64] == pytest.approx(0.6)
    # z outside [-2, 11]: in no height layer, but still in the flattened 1L channel
    assert not img[:14, 64, j10].any() and img[14, 64, j10] == pytest.approx(0.9)
    assert not img[:14, 64, jm10].any() and img[14, 64, jm10] == pytest.approx(0.8)
    assert np.array_equal(img[14], topview_1l(pts((0, 0, -2, 0.3), (10, 0, 11, 0.6), (0, 10, -2.5, 0.9), (0, -10, 12, 0.8)), fill=False))


def test_highest_point_wins() -> None:
    p = pts((0, 0, 0.3, 0.7), (0, 0, 0.0, 0.2), (0, 0, 1.0, 0.9), (0, 0, 0.1, 0.4))
    assert topview_1l(p, fill=False)[64, 64] == pytest.approx(0.9)
    img = topview_15l(p, fill=False)
    assert img[2, 64, 64] == pytest.approx(0.7)  # z = 0.3 beats 0.0 and 0.1 in channel rint(2.3) = 2
    assert img[3, 64, 64] == pytest.approx(0.9)  # z = 1.0 -> rint(3) = 3
    assert img[14, 64, 64] == pytest.approx(0.9)
    assert ls_ground_truth(p, np.array([1, 2, 3, 4], np.uint8))[64, 64] == 3


def test_neighbour_filling() -> None:
    img = topview_1l(pts((0, 0, 0, 0.5)), fill=True)
    assert occupied(img) == [(i, j) for i in (63, 64, 65) for j in (63, 64, 65)]
    assert np.allclose(img[63:66, 63:66], 0.5)
    # two points two cells apart compete for the cell between them: the higher point wins
    c = 64 / 127  # one cell in metres; y = 0.1 m -> rint(63.7) = 64 (y = 0 sits on a half-cell)
    a, b = pts((0, 0.1, 1.0, 0.3)), pts((0, 0.1 + 2 * c, 2.0, 0.7))
    img = topview_1l(np.concatenate([a, b]), fill=True)
    assert img[64, 65] == pytest.approx(0.7) and img[64, 64] == pytest.approx(0.3) and img[64, 66] == pytest.approx(0.7)
    # a real point's cell is never overwritten by a (higher) neighbour
    img = topview_1l(np.concatenate([pts((0, 0.1, 0.0, 0.3)), pts((0, 0.1 + c, 5.0, 0.7))]), fill=True)
    assert img[64, 64] == pytest.approx(0.3) and img[64, 65] == pytest.approx(0.7) and img[64, 63] == pytest.approx(0.3)
    # at the grid border nothing wraps
    img = topview_15l(pts((-32, -32, 0, 1)), fill=True)
    assert occupied(img[14]) == [(0, 0), (0, 1), (1, 0), (1, 1)]


def test_ls_ground_truth_255_where_no_point() -> None:
    ls = ls_ground_truth(pts((0, 0, 0, 1), (10, 10, 0, 1)), np.array([7, 10], np.uint8))
    assert ls.dtype == np.uint8 and ls.shape == (S, S)
    k = int(np.rint(42 / 64 * 127))
    assert ls[64, 64] == 7 and ls[k, k] == 10
    assert (ls == 255).sum() == S * S - 2  # no neighbour filling for LS


# ----------------------------------------------------------------------------- eq. (1) DVS
def test_dvs_polarity_channels() -> None:
    ev = np.array([[0, 3, 5, 1], [1, 7, 2, -1], [2, 3, 5, 1], [3, 3, 5, -1]], dtype=np.int64)
    img = events_to_image(ev, 8)
    assert img.dtype == np.uint8 and img.shape == (2, 8, 8)
    assert img[0, 5, 3] == 1 and img[1, 2, 7] == 1 and img[1, 5, 3] == 1
    assert img.sum() == 3
    assert not events_to_image(np.zeros((0, 4), np.int64), 8).any()
    with pytest.raises(ValueError, match="outside"):
        events_to_image(np.array([[0, 8, 0, 1]]), 8)
    bgr = np.zeros((4, 4, 3), np.uint8)
    bgr[1, 2] = (255, 0, 0)  # blue in BGR = positive
    bgr[3, 0] = (0, 0, 255)  # red = negative
    out = dvs_colour_to_image(bgr)
    assert out[0, 1, 2] == 1 and out[1, 3, 0] == 1 and out.sum() == 2


# ----------------------------------------------------------------------------- record -> frame
def test_preprocess_record_keys_and_class_maps() -> None:
    rec = make_record(16, seed=3)
    idx = np.arange(16 * 16).reshape(16, 16) % 23
    rec["sem_l"] = CARLA_PALETTE[idx]
    spec = RecordSpec(VIEWS, 16)
    f = preprocess_record(rec, spec, section("preprocess"), frame_id="x")
    expect = {"rgb": (np.uint8, (4, 3, 16, 16)), "dvs": (np.uint8, (4, 2, 16, 16)), "lidar": (np.float16, (15, 16, 16)),
              "de": (np.float16, (4, 1, 16, 16)), "ss": (np.uint8, (4, 16, 16)), "ls": (np.uint8, (16, 16)),
              "bevp": (np.uint8, (9, 16, 16))}
    for k, (dt, shape) in expect.items():
        assert f[k].dtype == dt and f[k].shape == shape, k
    assert np.array_equal(f["ss"][1], idx)
    assert np.array_equal(f["rgb"][0], rec["rgb_f"].transpose(2, 0, 1))
    assert np.allclose(f["de"][2, 0], rec["depth_ri"] / 65535, atol=1e-3) and f["de"].max() <= 1
    assert palette_to_index(CARLA_PALETTE[None, [4, 10]], CARLA_PALETTE).tolist() == [[4, 10]]


# ----------------------------------------------------------------------------- cache + loader
def _frames(n: int, size: int = 8, seed: int = 0, dvs: bool = True) -> list[dict]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        f = {"frame_id": f"f{i}", "rgb": rng.integers(0, 256, (4, 3, size, size), dtype=np.uint8),
             "lidar": rng.random((15, size, size)).astype(np.float16), "de": rng.random((4, 1, size, size)).astype(np.float16),
             "ss": rng.integers(0, 23, (4, size, size)).astype(np.uint8), "ls": rng.choice([0, 5, 255], (size, size)).astype(np.uint8),
             "bevp": rng.integers(0, 2, (9, size, size)).astype(np.uint8)}
        if dvs:
            f["dvs"] = rng.integers(0, 2, (4, 2, size, size)).astype(np.uint8)
        out.append(f)
    return out


META = {"dataset": "T", "source": "test", "seg_classes": list(CARLA_NAMES), "bev_classes": list(BEV_NAMES),
        "has_dvs": True, "resolution": 8, "views": list(VIEWS)}


def test_cache_round_trip_exact(tmp_path: Path) -> None:
    splits = {"train": _frames(5), "val": _frames(2, seed=1), "test": _frames(1, seed=2)}
    write_cache(tmp_path / "c", {k: iter(v) for k, v in splits.items()}, META)
    cache = read_cache(tmp_path / "c")
    assert cache.meta["counts"] == {"train": 5, "val": 2, "test": 1}
    for name, frames in splits.items():
        sp = cache[name]
        assert sp.frame_ids == [f["frame_id"] for f in frames]
        for k in frames[0]:
            if k != "frame_id":
                assert isinstance(sp.arrays[k], np.memmap)
                assert np.array_equal(sp.arrays[k], np.stack([f[k] for f in frames])), k
    # generic over keys: no dvs, 32 classes
    write_cache(tmp_path / "n", {"train": _frames(2, dvs=False)}, {**META, "has_dvs": False, "seg_classes": ["c"] * 32})
    assert "dvs" not in read_cache(tmp_path / "n")["train"].arrays


def test_cache_errors_leave_nothing(tmp_path: Path) -> None:
    bad = _frames(3)
    bad[2]["ls"] = bad[2]["ls"][:4]
    with pytest.raises(CacheError, match="frame f2"):
        write_cache(tmp_path / "c", {"train": bad}, META)
    with pytest.raises(CacheError, match="'val' is empty"):
        write_cache(tmp_path / "c", {"train": _frames(1), "val": []}, META)
    assert not any(tmp_path.iterdir())


def test_loader_determinism_and_to_device(tmp_path: Path) -> None:
    write_cache(tmp_path / "c", {"train": _frames(10)}, META)

    def order(seed: int) -> list[int]:
        dl = make_loader(tmp_path / "c", "train", 15, batch_size=3, shuffle=True, seed=seed, num_workers=0)
        return [int(i) for b in dl for i in b["index"]]

    assert order(7) == order(7) and sorted(order(7)) == list(range(10)) and order(7) != order(8)
    dl = make_loader(tmp_path / "c", "train", 1, batch_size=4, shuffle=False, num_workers=0, drop_last=True)
    batch = next(iter(dl))
    assert batch["rgb"].dtype == torch.uint8 and batch["lidar"].dtype == torch.float16 and batch["lidar"].shape == (4, 1, 8, 8)
    out = to_device(batch, "cpu", 23)
    shapes = {k: tuple(v.shape) for k, v in out.items()}
    assert shapes == {"rgb": (4, 4, 3, 8, 8), "dvs": (4, 4, 2, 8, 8), "lidar": (4, 1, 8, 8), "de": (4, 4, 1, 8, 8),
                      "ss": (4, 4, 23, 8, 8), "ls": (4, 23, 8, 8), "bevp": (4, 9, 8, 8), "index": (4,)}
    assert all(v.dtype == torch.float32 for k, v in out.items() if k != "index")
    assert out["rgb"].max() <= 1.0
    ss = batch["ss"].long()
    assert torch.equal(out["ss"].argmax(2), ss) and torch.equal(out["ss"].sum(2), torch.ones_like(out["ss"][:, :, 0]))
    ls = batch["ls"].long()
    assert torch.equal(out["ls"].sum(1) == 0, ls == 255)
    assert torch.equal(out["ls"].argmax(1)[ls != 255], ls[ls != 255])
    lid15 = make_loader(tmp_path / "c", "train", 15, batch_size=4).dataset[0]["lidar"]
    assert torch.equal(batch["lidar"][0, 0], lid15[14])


# ----------------------------------------------------------------------------- raw dataset errors
@pytest.fixture()
def raw(tmp_path: Path) -> Path:
    return make_raw_dataset(tmp_path / "raw" / "A", size=16, n_frames=5)[0]


def _run(raw: Path, out: Path) -> Path:
    return preprocess_sim(raw, out, "A", section("preprocess", workers=1))


def test_preprocess_sim_end_to_end(raw: Path, tmp_path: Path) -> None:
    cache = read_cache(_run(raw, tmp_path / "cache" / "A"))
    assert cache.meta["counts"] == {"train": 3, "val": 1, "test": 1} and cache.has_dvs and cache.num_seg_classes == 23
    assert cache["train"].arrays["lidar"].shape == (3, 15, 16, 16)


@pytest.mark.parametrize("damage", ["truncated", "missing_key", "wrong_shape", "missing_file"])
def test_bad_record_names_frame_and_file(raw: Path, tmp_path: Path, damage: str) -> None:
    path = raw / "frames" / "A_00003.npz"
    if damage == "truncated":
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    elif damage == "missing_file":
        path.unlink()
    else:
        rec = make_record(16, seed=3)
        if damage == "missing_key":
            del rec["lidar_tag"]
        else:
            rec["sem_f"] = rec["sem_f"][:8]
        from compact_perception.core.io import write_npz

        write_npz(path, rec)
    out = tmp_path / "cache" / "A"
    with pytest.raises(RecordError, match=r"frame A_00003: .*A_00003\.npz"):
        _run(raw, out)
    assert not (tmp_path / "cache").exists() or not any((tmp_path / "cache").iterdir())


def test_empty_split_and_incomplete_dataset(raw: Path, tmp_path: Path) -> None:
    m = json.loads((raw / "manifest.json").read_text())
    m["splits"]["val"] = []
    (raw / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(RecordError, match=r"manifest\.json: split 'val' is empty"):
        _run(raw, tmp_path / "cache" / "A")
    (raw / "manifest.json").unlink()
    with pytest.raises(RecordError, match="dataset incomplete"):
        _run(raw, tmp_path / "cache" / "A")
    assert not (tmp_path / "cache").exists()


def test_preprocess_dataset_with_figure(raw: Path, tmp_path: Path, params_dict: dict) -> None:
    params_dict["preprocess"]["workers"] = 2
    params = parse_params(params_dict)
    fig = tmp_path / "fig.png"
    preprocess_dataset(params, "A", raw_root=raw.parent, cache_root=tmp_path / "cache", figure_path=fig)
    assert fig.stat().st_size > 1000 and read_cache(tmp_path / "cache" / "A").meta["counts"]["test"] == 1

