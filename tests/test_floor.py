"""The trivial-predictor floor (SPEC 8) against hand computations on a tiny cache.

The cache is written by hand: three train frames whose values at a few pixels are chosen so
that the per-pixel mode, the "no label" rule, the tie rule, the BEV majority and the mean depth
each have one answer computed here, not by the code under test.
"""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch

from compact_perception.core.cache import write_cache
from compact_perception.core.classes import BEV_NAMES, CARLA_NAMES
from compact_perception.core.params import parse_params
from compact_perception.evaluation.evaluate import evaluate_floors
from compact_perception.core.floor_rule import FLOOR_PREDICTORS
from compact_perception.evaluation.floor import TRIVIAL, FixedPredictor, fit_trivial, floor_of, margins
from compact_perception.data.geometry import VIEWS

S, V, C, CB = 16, len(VIEWS), len(CARLA_NAMES), len(BEV_NAMES)


def _frame(ss00: int, ss01: int, ss02: int, ls00: int, bev00: int, de00: float, ls_rest: int = 255) -> dict:
    """Everything class 7 (road) / depth 0.5 / no BEV, but for the pixels the test sets."""
    ss = np.full((V, S, S), 7, np.uint8)
    ss[0, 0, 0], ss[0, 0, 1], ss[0, 0, 2] = ss00, ss01, ss02
    ls = np.full((S, S), ls_rest, np.uint8)
    ls[0, 0] = ls00
    bev = np.zeros((CB, S, S), np.uint8)
    bev[0, 0, 0] = bev00
    de = np.full((V, 1, S, S), 0.5, np.float16)
    de[0, 0, 0, 0] = de00
    return {"rgb": np.zeros((V, 3, S, S), np.uint8), "dvs": np.zeros((V, 2, S, S), np.uint8),
            "lidar": np.zeros((15, S, S), np.float16), "de": de, "ss": ss, "ls": ls, "bevp": bev}


TRAIN = [  # per pixel: ss(0,0,0) mode 1; ss(0,0,1) "no label" twice -> nothing; ss(0,0,2) a 3-way tie
    _frame(1, 255, 3, 4, 1, 0.25),
    _frame(1, 255, 4, 4, 1, 0.5),
    _frame(2, 9, 255, 255, 0, 0.75),
]


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    out = tmp_path_factory.mktemp("floor") / "A"
    test = [_frame(1, 0, 3, 4, 1, 0.5), _frame(2, 0, 3, 4, 0, 0.25)]
    meta = {"dataset": "A", "source": "sim", "seg_classes": list(CARLA_NAMES), "bev_classes": list(BEV_NAMES),
            "has_dvs": True, "resolution": S, "views": list(VIEWS)}
    write_cache(out, {"train": TRAIN, "val": test[:1], "test": test}, meta)
    return out


def test_pixel_floor_by_hand(cache):
    pred = {k: v.numpy() for k, v in fit_trivial("floor_pixel", cache).state_dict().items()}
    ss = pred["pred_ss"]                                             # (V,C,S,S)
    assert ss[0, :, 0, 0].argmax() == 1 and ss[0, :, 0, 0].sum() == 1      # mode of 1, 1, 2
    assert (ss[0, :, 0, 1] < 0.5).all() and ss[0, 9, 0, 1] == 0.25   # "no label" twice of three: nothing
                                                                     # by eq. (5); class 9 for an arg-max
    assert ss[0, 3, 0, 2] == 1 and ss[0, :, 0, 2].sum() == 1         # 3, 4, none: the lowest class wins
    assert (ss[:, 7, 1:, :] == 1).all()                              # road everywhere else
    ls = pred["pred_ls"]                                             # (C,S,S)
    assert ls[4, 0, 0] == 1 and ls[:, 0, 0].sum() == 1               # 4, 4, none
    assert (ls[:, 1:, :] < 0.5).all()                                # no point anywhere else: nothing
    bev = pred["pred_bevp"]                                          # (CB,S,S)
    assert bev[0, 0, 0] == 1 and bev.sum() == 1                      # set in 2 of 3 frames
    de = pred["pred_de"]                                             # (V,1,S,S)
    assert de[0, 0, 0, 0] == pytest.approx(0.5) and de[1, 0, 3, 3] == pytest.approx(0.5)


def test_global_floor_by_hand(cache):
    pred = {k: v.numpy() for k, v in fit_trivial("floor_global", cache).state_dict().items()}
    assert (pred["pred_ss"][:, 7] == 1).all() and pred["pred_ss"].sum() == V * S * S   # road
    assert (pred["pred_ls"] < 0.5).all() and pred["pred_ls"][4].max() == 0.25   # "no label" is most
                                                                     # frequent; 4 the most frequent class
    assert pred["pred_bevp"].sum() == 0                              # no mask set in more than half
    n = 3 * V * S * S                                                # the overall mean depth
    mean = (3 * 0.5 * (n - 3) / 3 + 0.25 + 0.5 + 0.75) / n
    assert pred["pred_de"] == pytest.approx(np.full((V, 1, S, S), mean))


def test_a_tie_in_the_bev_majority_is_not_set(tmp_path):
    frames = [_frame(1, 1, 1, 1, 1, 0.5), _frame(1, 1, 1, 1, 0, 0.5)]     # set in exactly half
    meta = {"dataset": "A", "source": "sim", "seg_classes": list(CARLA_NAMES), "bev_classes": list(BEV_NAMES),
            "has_dvs": True, "resolution": S, "views": list(VIEWS)}
    write_cache(tmp_path / "A", {"train": frames, "val": frames[:1], "test": frames[:1]}, meta)
    assert fit_trivial("floor_pixel", tmp_path / "A").pred_bevp[0, 0, 0] == 0


def test_fixed_predictor_expands_to_the_batch():
    p = FixedPredictor({"de": np.zeros((V, 1, 2, 2), np.float32), "ls": np.ones((C, 2, 2), np.float32)})
    out = p({"rgb": torch.zeros(3, V, 3, 2, 2)})
    assert p.tasks == ("de", "ls") and out["de"].shape == (3, V, 1, 2, 2) and out["ls"].shape == (3, C, 2, 2)


def test_floor_scores_use_the_metric_code(cache, tmp_path, params_dict):
    shutil.copytree(cache, tmp_path / "data" / "cache" / "A")  # where the evaluate stage reads it (core.layout)
    params_dict["evaluate"].update(save_predictions=0, depth_max_m=80)
    params_dict["train"]["num_threads"] = 1
    floor = evaluate_floors(parse_params(params_dict), "A", tmp_path)
    res = json.loads((tmp_path / "results" / "A" / "floor_pixel" / "metrics.json").read_text())
    # MAE by hand: depth 0.5 everywhere, but test frame 2's pixel (0,0,0) of view f is 0.25 -> |0.5-0.25|
    n_px = V * S * S
    assert res["mae_de"]["mean"] == pytest.approx((0.0 + 0.25 / n_px) / 2)
    # LS: predicted class 4 at (0,0); ground truth 4 there, nothing elsewhere: IoU 1 on both frames
    assert res["iou_ls"]["mean"] == pytest.approx(1.0)
    # BEVP: predicted mask 0 at (0,0); frame 1 has it (IoU 1), frame 2 not (0 / 1 = 0)
    assert res["iou_bevp"]["mean"] == pytest.approx(0.5)
    assert floor["tm"] == pytest.approx(res["tm"]["mean"])               # the per-pixel prior is the better one
    assert (tmp_path / "data" / "eval" / "A" / "floor_global" / "per_frame.csv").is_file()


def test_floor_of_takes_the_better_predictor_per_metric():
    floors = {"p": {"mae_de": 0.2, "iou_ss": 0.4, "iou_ls": 0.1, "iou_bevp": 0.3, "tm": 2.2},
              "g": {"mae_de": 0.3, "iou_ss": 0.5, "iou_ls": 0.0, "iou_bevp": 0.3, "tm": 2.5}}
    assert floor_of(floors) == {"mae_de": 0.2, "iou_ss": 0.5, "iou_ls": 0.1, "iou_bevp": 0.3, "tm": 2.2}


def test_every_trivial_predictor_is_fitted_under_its_core_id_and_label():
    """The report reads the predictors' ids and labels from core (no torch); evaluation fits one
    predictor per id there, in the same order (the report's rows), under the same label."""
    assert tuple(TRIVIAL.keys()) == tuple(FLOOR_PREDICTORS.keys()) == ("floor_pixel", "floor_global")
    assert [TRIVIAL[t].label for t in TRIVIAL.keys()] == ["Floor (per-pixel prior)", "Floor (global prior)"]


def test_margins_are_positive_when_better():
    floor = {"mae_de": 0.2, "iou_ss": 0.4, "tm": 2.2}
    m = margins({"mae_de": 0.15, "iou_ss": 0.35, "tm": 2.0, "iou_ls": 0.9}, floor)
    assert m == pytest.approx({"mae_de": 0.05, "iou_ss": -0.05, "tm": 0.2})


@pytest.mark.parametrize("frame_id, cluster", [
    ("town02_ep0035_004", "town02_ep0035"),       # an episode of the embedded world
    ("scene-0061_012", "scene-0061"),             # a nuScenes scene (ingest: <scene name>_<k:03d>)
    ("0042.png", "block0004"),                    # the authors' release: blocks of 10 numbers
    ("0049.png", "block0004"),
    ("0050.png", "block0005"),
    ("test_000007", "test_000007"),               # an unnamed frame: its own cluster
])
def test_frame_cluster(frame_id, cluster):
    from compact_perception.core.cache import frame_cluster

    assert frame_cluster(frame_id) == cluster
