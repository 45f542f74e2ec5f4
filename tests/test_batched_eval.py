"""Evaluation at ``evaluate.batch_size``: every test frame is scored on its own outputs by the code of
a batch of one, so a network whose outputs do not depend on the batch scores every frame exactly as
at batch 1; a convolutional network's outputs move in their last bits with the batch (measured here:
that is why batch 1 stays the default, the committed scores' batch)."""
from __future__ import annotations


import numpy as np
import pandas as pd
import pytest
import torch

from compact_perception.core.cache import read_split
from compact_perception.core.params import parse_params
from compact_perception.data.loader import make_loader
from compact_perception.evaluation.evaluate import _score_frames
from compact_perception.evaluation.floor import fit_trivial
from compact_perception.learning.models import build_model

from synthetic import make_cache


def _scores(model, cache, batch_size: int, save: int = 3):
    loader = make_loader(cache, "test", 15, batch_size)
    ids = read_split(cache, "test").frame_ids
    return _score_frames(model, loader, ids, 23, torch.device("cpu"), save, "test", 80.0)


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return make_cache(tmp_path_factory.mktemp("eval") / "cache", size=16, counts=(2, 1, 7))


def test_a_batch_independent_predictor_scores_every_frame_exactly_as_at_batch_1(cache):
    """The floor's fixed predictor gives every frame the same output in any batch: batch 3 over 7
    frames (a short last batch) gives the per-frame scores, the class counts and the saved
    predictions and inputs of batch 1, bit for bit."""
    model = fit_trivial("floor_pixel", cache)
    one, three = _scores(model, cache, 1), _scores(model, cache, 3)
    pd.testing.assert_frame_equal(one[0], three[0], check_exact=True)
    assert len(one[0]) == 7 and list(one[0]["frame_id"]) == read_split(cache, "test").frame_ids
    for t in one[1].counts:
        assert all(np.array_equal(a, b) for a, b in zip(one[1].counts[t], three[1].counts[t]))
    for a, b in ((one[2], three[2]), (one[3], three[3])):
        assert set(a) == set(b) and all(len(a[k]) == 3 and all(np.array_equal(x, y) for x, y in zip(a[k], b[k]))
                                        for k in a)


def test_a_network_s_frames_move_only_in_their_last_bits_with_the_batch(cache):
    """compact_15l at batch 4 against batch 1: the class maps' IoUs agree, MAE within 1e-6, the
    metric-depth errors within 1e-3 of their value (the batch changes a convolution's summation
    order, not what is predicted)."""
    torch.manual_seed(0)
    model = build_model("compact_15l", "A").eval()
    one, four = _scores(model, cache, 1)[0], _scores(model, cache, 4)[0]
    assert list(one["frame_id"]) == list(four["frame_id"])
    for col in one.columns.drop("frame_id"):
        a, b = one[col].to_numpy(float), four[col].to_numpy(float)
        if col.startswith("iou"):
            np.testing.assert_array_equal(a, b, err_msg=col)
        elif col in ("mae_de", "tm"):
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-6, err_msg=col)
        else:
            np.testing.assert_allclose(a, b, rtol=1e-3, atol=0, err_msg=col)


def test_the_default_is_batch_1(params_dict):
    assert parse_params(params_dict).evaluate.batch_size == 1
