"""Losses (section III-B eq. 1-3, baseline losses) and metrics (eq. 4-7) against hand values."""
from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import torch

from compact_perception.losses import (
    bce_dice_loss,
    cross_entropy_onehot,
    huber_loss,
    kl_normal,
    lovasz_softmax,
    squared_loss,
)
from compact_perception.metrics import (
    combine_tasks,
    compute_metrics,
    compute_metrics_per_sample,
    iou,
    iou_per_sample,
    mae,
    mae_per_sample,
    metric_variance,
    total_metric,
)

D = torch.float64


def t(x) -> torch.Tensor:
    return torch.tensor(x, dtype=D)


# ----------------------------------------------------------------------------- losses
def test_huber_both_branches() -> None:
    pred = t([[0.2, 1.0], [-0.3, 0.0]])
    target = t([[0.0, 0.0], [0.0, 0.5]])
    # |d| = 0.2 (quadratic), 1.0 (linear), 0.3 (quadratic), 0.5 (linear: not < delta)
    z = [0.5 * 0.04, 0.5 * (1.0 - 0.25), 0.5 * 0.09, 0.5 * (0.5 - 0.25)]
    assert float(huber_loss(pred, target)) == pytest.approx(sum(z) / 4, abs=1e-12)


def test_huber_equals_mean_of_view_means() -> None:
    g = torch.Generator().manual_seed(0)
    pred = torch.rand(2, 4, 1, 3, 3, generator=g, dtype=D) * 2
    target = torch.rand(2, 4, 1, 3, 3, generator=g, dtype=D)
    per_view = torch.stack([huber_loss(pred[:, v], target[:, v]) for v in range(4)]).mean()
    assert float(huber_loss(pred, target)) == pytest.approx(float(per_view), abs=1e-12)


def test_bce_dice_2x2_by_hand() -> None:
    p = t([[[[0.9, 0.2], [0.6, 0.1]]]])  # (1,1,2,2), V = 1
    y = t([[[[1.0, 0.0], [1.0, 0.0]]]])
    bce = -(math.log(0.9) + math.log(0.8) + math.log(0.6) + math.log(0.9)) / 4  # positive BCE
    dice = 2 * (0.9 + 0.6) / ((0.9 + 0.2 + 0.6 + 0.1) + 2.0)
    assert float(bce_dice_loss(p, y)) == pytest.approx(bce + 1 - dice, abs=1e-6)


def test_bce_dice_views_averaged() -> None:
    g = torch.Generator().manual_seed(1)
    p = torch.rand(2, 3, 2, 4, 4, generator=g, dtype=D)
    y = (torch.rand(2, 3, 2, 4, 4, generator=g, dtype=D) > 0.5).to(D)
    per_view = torch.stack([bce_dice_loss(p[:, v], y[:, v]) for v in range(3)]).mean()
    assert float(bce_dice_loss(p, y)) == pytest.approx(float(per_view), abs=1e-12)
    # perfect (clamped) prediction -> ~0; extreme probabilities stay finite
    assert float(bce_dice_loss(y, y)) == pytest.approx(0.0, abs=1e-5)


def test_cross_entropy_ignores_unlabelled() -> None:
    logits = t([[[[2.0, 5.0]], [[0.0, -1.0]]]])  # (1,2,1,2)
    target = t([[[[1.0, 0.0]], [[0.0, 0.0]]]])  # pixel 1 has no label
    assert float(cross_entropy_onehot(logits, target)) == pytest.approx(math.log(1 + math.exp(-2)), abs=1e-12)
    # 5D: class axis 2
    l5, t5 = logits.unsqueeze(1), target.unsqueeze(1)
    assert float(cross_entropy_onehot(l5, t5)) == pytest.approx(math.log(1 + math.exp(-2)), abs=1e-12)
    assert float(cross_entropy_onehot(logits, torch.zeros_like(target))) == 0.0


def _jaccard_set_loss(fg: np.ndarray, mispredicted: set[int]) -> float:
    """Delta_J(M) = |M| / |gt U M| (Berman et al., eq. 4 rewritten for the set M of errors)."""
    gt = {i for i in range(len(fg)) if fg[i] > 0}
    union = gt | mispredicted
    return len(mispredicted) / len(union) if union else 0.0


def _lovasz_brute(probs: np.ndarray, onehot: np.ndarray) -> float:
    """Lovasz extension as the max over all orderings (Delta_J is submodular, so the greedy
    order by decreasing error attains the maximum of the base-polytope linear program)."""
    n, c = probs.shape
    vals = []
    for k in range(c):
        fg = onehot[:, k]
        if fg.sum() == 0:
            continue
        m = np.abs(fg - probs[:, k])
        best = -np.inf
        for perm in itertools.permutations(range(n)):
            s, prev, acc = set(), 0.0, 0.0
            for i in perm:
                s.add(i)
                cur = _jaccard_set_loss(fg, s)
                acc += m[i] * (cur - prev)
                prev = cur
            best = max(best, acc)
        vals.append(best)
    return float(np.mean(vals))


def test_lovasz_softmax() -> None:
    g = torch.Generator().manual_seed(3)
    logits = torch.randn(1, 3, 1, 6, generator=g, dtype=D)
    probs = logits.softmax(dim=1)
    labels = torch.tensor([0, 2, 2, 0, 1, 0])
    onehot = torch.nn.functional.one_hot(labels, 3).to(D).T.reshape(1, 3, 1, 6)
    onehot[..., 5] = 0.0  # pixel 5 unlabelled: ignored
    ref = _lovasz_brute(probs[0, :, 0, :5].T.numpy(), onehot[0, :, 0, :5].T.numpy())
    assert float(lovasz_softmax(probs, onehot)) == pytest.approx(ref, abs=1e-12)
    # perfect prediction -> 0; 5D layout same value
    assert float(lovasz_softmax(onehot, onehot)) == pytest.approx(0.0, abs=1e-12)
    assert float(lovasz_softmax(probs.unsqueeze(1), onehot.unsqueeze(1))) == pytest.approx(ref, abs=1e-12)
    assert probs.requires_grad is False


def test_squared_and_kl() -> None:
    assert float(squared_loss(t([1.0, 3.0]), t([0.0, 1.0]))) == pytest.approx(2.5)
    assert float(kl_normal(torch.zeros(2, 5, dtype=D), torch.zeros(2, 5, dtype=D))) == 0.0
    # mu = 1, logvar = 0: 0.5 per dim, 3 dims
    assert float(kl_normal(torch.ones(4, 3, dtype=D), torch.zeros(4, 3, dtype=D))) == pytest.approx(1.5)


# ----------------------------------------------------------------------------- metrics
def test_mae() -> None:
    pred = t([[[[[0.5, 0.0]]], [[[1.0, 1.0]]]]])  # (1,2,1,1,2)
    gt = t([[[[[0.0, 0.0]]], [[[0.0, 1.0]]]]])
    assert float(mae(pred, gt)) == pytest.approx(0.375)
    assert mae_per_sample(pred.repeat(2, 1, 1, 1, 1), gt.repeat(2, 1, 1, 1, 1)).shape == (2,)


def test_iou_threshold_and_empty_union() -> None:
    pred = t([[[[0.9, 0.5], [0.7, 0.1]]]])  # 0.5 is NOT > 0.5
    gt = t([[[[1.0, 1.0], [0.0, 0.0]]]])
    assert float(iou(pred, gt)) == pytest.approx(1 / 3)
    empty = torch.zeros(1, 1, 2, 2, dtype=D)
    assert float(iou(empty + 0.3, empty)) == 1.0  # empty union -> 1.0
    # two views: [1/3, empty -> 1] averaged
    p5 = torch.stack([pred, empty], dim=1)
    g5 = torch.stack([gt, empty], dim=1)
    assert float(iou(p5, g5)) == pytest.approx((1 / 3 + 1) / 2)
    # per sample: sample 0 as above, sample 1 perfect
    pb, gb = torch.cat([pred, gt]), torch.cat([gt, gt])
    assert iou_per_sample(pb, gb).tolist() == pytest.approx([1 / 3, 1.0])
    # batch-level IoU pools the batch: inter 1 + 2, union 3 + 2
    assert float(iou(pb, gb)) == pytest.approx(3 / 5)


def test_tm_mv_by_hand() -> None:
    # terms 0.1, 0.2, 0.4, 0.1 -> TM 0.8, mean 0.2, MV (0.01 + 0 + 0.04 + 0.01)/4
    assert total_metric(0.1, 0.8, 0.6, 0.9) == pytest.approx(0.8)
    assert metric_variance(0.1, 0.8, 0.6, 0.9) == pytest.approx(0.015)
    arr = metric_variance(np.array([0.1, 0.0]), np.array([0.8, 1.0]), np.array([0.6, 1.0]), np.array([0.9, 1.0]))
    assert arr.tolist() == pytest.approx([0.015, 0.0])


def test_compute_metrics_keys_and_combine() -> None:
    g = torch.Generator().manual_seed(4)
    out = {"de": torch.rand(2, 4, 1, 4, 4, generator=g, dtype=D), "ss": torch.rand(2, 4, 3, 4, 4, generator=g, dtype=D),
           "ls": torch.rand(2, 3, 4, 4, generator=g, dtype=D), "bevp": torch.rand(2, 2, 4, 4, generator=g, dtype=D)}
    tgt = {k: (torch.rand(v.shape, generator=g, dtype=D) > 0.5).to(D) for k, v in out.items()}
    m = compute_metrics(out, tgt)
    assert set(m) == {"mae_de", "iou_ss", "iou_ls", "iou_bevp", "tm", "mv"}
    assert m["tm"] == pytest.approx(total_metric(m["mae_de"], m["iou_ss"], m["iou_ls"], m["iou_bevp"]))
    assert set(compute_metrics({"ls": out["ls"]}, tgt)) == {"iou_ls"}
    ps = compute_metrics_per_sample(out, tgt)
    assert ps["tm"].shape == (2,)
    c = combine_tasks({"mae_de": 0.1, "iou_ss": 0.8}, {"iou_ls": 0.6}, {"iou_bevp": 0.9})
    assert c["tm"] == pytest.approx(0.8) and c["mv"] == pytest.approx(0.015)
    c2 = combine_tasks({"mae_de": [0.1, 0.0], "iou_ss": [0.8, 1.0]}, {"iou_ls": [0.6, 1.0]}, {"iou_bevp": [0.9, 1.0]})
    assert c2["tm"] == pytest.approx([0.8, 0.0])
    with pytest.raises(ValueError):
        combine_tasks({"mae_de": [0.1], "iou_ss": [0.8]}, {"iou_ls": 0.6}, {"iou_bevp": 0.9})
