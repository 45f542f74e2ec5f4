"""Losses (section III-B eq. 1-3, baseline losses) and metrics (eq. 4-7) against hand values."""
from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import torch

from compact_perception.learning.losses import (
    bce_dice_loss,
    cross_entropy_onehot,
    huber_loss,
    kl_normal,
    lovasz_softmax,
    squared_loss,
)
from compact_perception.learning.metrics import (
    class_confusion,
    class_iou,
    argmax_one_hot,
    compute_metrics,
    compute_metrics_per_sample,
    decode_log_depth,
    depth_errors_per_sample,
    depth_valid_mask,
    iou,
    iou_per_sample,
    mae,
    mae_per_sample,
    mean_iou,
    metric_variance,
    multilabel_confusion,
    scores_from_means,
    total_metric,
    total_metric_partial,
)
from compact_perception.report.paper import TASK_COLUMNS, load_paper_numbers

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


def test_softmax_tasks_are_scored_by_their_argmax_map() -> None:
    """One view, 3 classes, 2 pixels. Softmax pixel 0 = [0.40, 0.35, 0.25] (arg-max class 0),
    pixel 1 = [0.30, 0.45, 0.25] (arg-max 1); ground truth: class 0, class 2. Arg-max one-hot:
    intersection {p0 c0} = 1, union {p0 c0, p1 c1, p1 c2} = 3 -> IoU 1/3. Eq. (5) on the
    probabilities themselves: nothing above 0.5 -> intersection 0, union 2 -> IoU 0."""
    probs = torch.tensor([[0.40, 0.30], [0.35, 0.45], [0.25, 0.25]], dtype=D).reshape(1, 1, 3, 1, 2)
    gt = torch.tensor([[1.0, 0.0], [0.0, 0.0], [0.0, 1.0]], dtype=D).reshape(1, 1, 3, 1, 2)
    assert argmax_one_hot(probs).reshape(3, 2).tolist() == [[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]]
    assert compute_metrics({"ss": probs}, {"ss": gt}, argmax_tasks=("ss",))["iou_ss"] == pytest.approx(1 / 3)
    assert compute_metrics({"ss": probs}, {"ss": gt}, argmax_tasks=())["iou_ss"] == 0.0
    per = compute_metrics_per_sample({"ss": probs}, {"ss": gt}, argmax_tasks=("ss",))
    assert per["iou_ss"].tolist() == pytest.approx([1 / 3])


def test_both_scoring_rules_by_hand_on_a_sigmoid_ls_head() -> None:
    """The two rules of every class map (issue 24 item 5) on one LS map, 3 classes, 3 cells.
    Sigmoid outputs: cell 0 = [0.7, 0.6, 0.1] (two classes fire), cell 1 = [0.2, 0.3, 0.4] (none
    fires), cell 2 = [0.1, 0.2, 0.9]. Ground truth: cell 0 class 1, cell 1 class 2, cell 2 no
    label (no LiDAR point: the all-zero vector).
    Eq. (5) on the raw outputs at the labelled cells: cell 2 left out, predicted {c0 k0, c0 k1},
    truth {c0 k1, c1 k2}: intersection 1, union 3 -> 1/3 (over the whole grid cell 2's k2 would
    join the union: 1/4).
    Arg-max rule: cell 0 -> class 0, cell 1 -> class 2, cell 2 left out (no label): predicted
    {c0 k0, c1 k2}, truth {c0 k1, c1 k2}: intersection 1, union 3 -> 1/3."""
    from compact_perception.learning.metrics import iou_argmax_per_sample

    out = torch.tensor([[0.7, 0.2, 0.1], [0.6, 0.3, 0.2], [0.1, 0.4, 0.9]], dtype=D).reshape(1, 3, 1, 3)
    gt = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], dtype=D).reshape(1, 3, 1, 3)
    assert compute_metrics({"ls": out}, {"ls": gt}, argmax_tasks=())["iou_ls"] == pytest.approx(1 / 3)
    assert iou(out, gt).item() == pytest.approx(0.25)  # eq. (5) itself, whole grid
    assert iou_argmax_per_sample(out, gt).tolist() == pytest.approx([1 / 3])


def test_unlabelled_cells_count_for_no_model_but_bevp_is_scored_whole() -> None:
    """A softmax LS head (PolarNet's) on a 2x2 grid, 2 classes; only cells 0 and 1 hold a LiDAR
    point (truth class 0 and class 1), cells 2 and 3 none (all-zero vectors). Softmax class-0
    probabilities [0.9, 0.2, 0.8, 0.7] (class 1: 1 - p). Labelled cells only: predicted
    {c0 k0, c1 k1}, truth the same -> IoU 1. Over the whole grid the two empty cells would add
    {c2 k0, c3 k0} to the union: 2/4 = 0.5. The same values as a BEVP map (binary masks, an
    all-zero vector a labelled "none") keep the whole grid: predicted {c0 k0, c1 k1, c2 k0,
    c3 k0} against {c0 k0, c1 k1} -> 2/4."""
    p0 = torch.tensor([0.9, 0.2, 0.8, 0.7], dtype=D)
    probs = torch.stack([p0, 1 - p0]).reshape(1, 2, 2, 2)
    gt = torch.tensor([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]], dtype=D).reshape(1, 2, 2, 2)
    assert compute_metrics({"ls": probs}, {"ls": gt}, argmax_tasks=())["iou_ls"] == pytest.approx(1.0)
    assert compute_metrics({"ls": probs}, {"ls": gt}, argmax_tasks=("ls",))["iou_ls"] == pytest.approx(1.0)
    assert compute_metrics_per_sample({"ls": probs}, {"ls": gt}, argmax_tasks=())["iou_ls"].tolist() == [1.0]
    assert iou(probs, gt).item() == pytest.approx(0.5)
    assert compute_metrics({"bevp": probs}, {"bevp": gt}, argmax_tasks=())["iou_bevp"] == pytest.approx(0.5)


def test_argmax_rule_averages_views_and_keeps_every_labelled_pixel() -> None:
    """SS, two views of 2 pixels, 2 classes, every pixel labelled. View 0: outputs argmax
    [0, 1], truth [0, 1] -> IoU 1. View 1: argmax [0, 0], truth [1, 1] -> intersection 0,
    union 4 -> 0. Mean over views 0.5."""
    from compact_perception.learning.metrics import iou_argmax_per_sample

    out = torch.tensor([[[0.9, 0.2], [0.1, 0.8]], [[0.6, 0.7], [0.4, 0.3]]], dtype=D).reshape(1, 2, 2, 1, 2)
    gt = torch.tensor([[[1.0, 0.0], [0.0, 1.0]], [[0.0, 0.0], [1.0, 1.0]]], dtype=D).reshape(1, 2, 2, 1, 2)
    assert iou_argmax_per_sample(out, gt).tolist() == pytest.approx([0.5])


def test_compute_metrics_keys_and_combine() -> None:
    g = torch.Generator().manual_seed(4)
    out = {"de": torch.rand(2, 4, 1, 4, 4, generator=g, dtype=D), "ss": torch.rand(2, 4, 3, 4, 4, generator=g, dtype=D),
           "ls": torch.rand(2, 3, 4, 4, generator=g, dtype=D), "bevp": torch.rand(2, 2, 4, 4, generator=g, dtype=D)}
    tgt = {k: (torch.rand(v.shape, generator=g, dtype=D) > 0.5).to(D) for k, v in out.items()}
    m = compute_metrics(out, tgt, argmax_tasks=())
    assert set(m) == {"mae_de", "iou_ss", "iou_ls", "iou_bevp", "tm", "mv"}
    assert m["tm"] == pytest.approx(total_metric(m["mae_de"], m["iou_ss"], m["iou_ls"], m["iou_bevp"]))
    assert set(compute_metrics({"ls": out["ls"]}, tgt, argmax_tasks=())) == {"iou_ls"}
    ps = compute_metrics_per_sample(out, tgt, argmax_tasks=())
    assert ps["tm"].shape == (2,) and "mv" not in ps          # MV is not a per-frame quantity
    # the combination row's TM and MV: what the report computes from its four means (scores_from_means)
    c = scores_from_means({"mae_de": 0.1, "iou_ss": 0.8, "iou_ls": 0.6, "iou_bevp": 0.9})
    assert c["tm"] == pytest.approx(0.8) and c["mv"] == pytest.approx(0.015)



# ----------------------------------------------------------------------------- MV as the paper defines it
def test_mv_of_the_means_set_a_15l_mgn() -> None:
    """Eq. (7) on the four test-set mean terms: A 15L+MGN 0.084, 0.373, 0.530, 0.406 -> 0.0267."""
    s = scores_from_means({"mae_de": 0.084, "iou_ss": 0.627, "iou_ls": 0.470, "iou_bevp": 0.594})
    assert s["mv"] == pytest.approx(float(np.var([0.084, 0.373, 0.530, 0.406])), abs=1e-15)
    assert s["mv"] == pytest.approx(0.0267, abs=5e-5) and round(s["mv"], 3) == 0.027
    assert s["tm"] == pytest.approx(1.393, abs=1e-12)
    assert scores_from_means({"mae_de": 0.1, "iou_ss": 0.5}) == {}
    # the mean of per-frame MVs is a different number (why the project no longer reports it)
    frames = np.array([[0.0, 1.0, 1.0, 1.0], [0.2, 0.2, 0.2, 0.2]])   # mae, iou_ss, iou_ls, iou_bevp
    per_frame = metric_variance(*frames.T)
    of_means = scores_from_means(dict(zip(TASK_COLUMNS, frames.mean(axis=0))))["mv"]
    assert of_means == pytest.approx(np.var([0.1, 0.4, 0.4, 0.4])) and float(per_frame.mean()) != pytest.approx(of_means)


#: Rows whose printed MV does not follow from their printed Table II columns (the paper's own
#: inconsistency): nuScenes 15L+MGN* prints 0.017, its columns give 0.0180 (0.01784..0.01808
#: for any means that round to the printed ones).
MV_NOT_REPRODUCED = {("nuscenes", "compact_15l_mgn")}


def _paper_terms(rows, rid: str) -> list[float]:
    if rid == "combination":
        src = {"mae_de": "gradnorm_segnet", "iou_ss": "gradnorm_segnet", "iou_ls": "polarnet", "iou_bevp": "chen_bev"}
        return [rows[src[c]].value(c) for c in TASK_COLUMNS]
    return [rows[rid].value(c) for c in TASK_COLUMNS]


@pytest.mark.parametrize("ds", ["A", "B", "C", "nuscenes"])
@pytest.mark.parametrize("rid", ["compact_1l", "compact_15l", "compact_15l_mgn", "combination"])
def test_paper_mv_reproduces_from_table2_columns(ds: str, rid: str) -> None:
    """Every compact row (and the combination) of Table II: MV of the four printed means,
    rounded to the printed precision, equals the printed MV (except the listed row)."""
    rows = load_paper_numbers().table2[ds]
    s = scores_from_means(dict(zip(TASK_COLUMNS, _paper_terms(rows, rid))))
    printed = rows[rid].mv
    if (ds, rid) in MV_NOT_REPRODUCED:
        assert round(s["mv"], 3) != printed and abs(s["mv"] - printed) < 1.5e-3
        # no set of means that round to the printed ones gives it either
        terms = np.array([_paper_terms(rows, rid)[0]] + [1 - v for v in _paper_terms(rows, rid)[1:]])
        corners = np.array(list(itertools.product((-5e-4, 5e-4), repeat=4)))
        assert (np.var(terms + corners, axis=1) >= printed + 5e-4).all()
    else:
        assert round(s["mv"], 3) == printed
    # TM: the printed means are rounded, so TM may differ by up to 4 x 0.0005
    assert s["tm"] == pytest.approx(rows[rid].tm, abs=2e-3 + 1e-12)


def test_total_metric_partial() -> None:
    assert total_metric_partial({"mae_de": 0.1, "iou_ss": 0.8}) == pytest.approx(0.3)
    assert total_metric_partial({"iou_ls": 0.6}) == pytest.approx(0.4)
    full = {"mae_de": 0.1, "iou_ss": 0.8, "iou_ls": 0.6, "iou_bevp": 0.9}
    assert total_metric_partial(full) == pytest.approx(total_metric(0.1, 0.8, 0.6, 0.9))


# ----------------------------------------------------------------------------- metrics beyond the paper
def _onehot(idx: list, n: int) -> torch.Tensor:
    """(H,W) class indices (-1 = no label) -> (1,n,H,W) one-hot, all-zero where -1."""
    a = torch.tensor(idx)
    out = torch.zeros((1, n) + tuple(a.shape), dtype=D)
    for c in range(n):
        out[0, c] = (a == c).to(D)
    return out


def test_class_confusion_by_hand() -> None:
    # ground truth   pred (arg-max)
    # 0 0 1          0 1 1
    # 2 - 1          2 0 0       (- = no label: left out)
    gt = _onehot([[0, 0, 1], [2, -1, 1]], 4)
    pred = _onehot([[0, 1, 1], [2, 0, 0]], 4) * 0.8 + 0.05
    tp, fp, fn = class_confusion(pred, gt)
    assert tp.tolist() == [1, 1, 1, 0] and fp.tolist() == [1, 1, 0, 0] and fn.tolist() == [1, 1, 0, 0]
    ious = class_iou(tp, fp, fn)
    assert ious[:3].tolist() == pytest.approx([1 / 3, 1 / 3, 1.0]) and np.isnan(ious[3])   # class 3 absent
    assert mean_iou(ious) == pytest.approx((1 / 3 + 1 / 3 + 1.0) / 3)                     # absent class left out
    # 5-D (views) layout gives the same counts; counts add over frames
    tp5, _, _ = class_confusion(pred.unsqueeze(1), gt.unsqueeze(1))
    assert tp5.tolist() == tp.tolist()
    two = class_confusion(torch.cat([pred, pred]), torch.cat([gt, gt]))
    assert two[0].tolist() == [2, 2, 2, 0]
    assert np.isnan(mean_iou([np.nan, np.nan]))


def test_multilabel_confusion_by_hand() -> None:
    pred = t([[[[0.9, 0.6], [0.2, 0.5]], [[0.1, 0.1], [0.1, 0.1]], [[0.7, 0.0], [0.0, 0.0]]]])   # (1,3,2,2)
    gt = t([[[[1.0, 0.0], [1.0, 1.0]], [[0.0, 0.0], [0.0, 0.0]], [[0.0, 0.0], [0.0, 0.0]]]])
    tp, fp, fn = multilabel_confusion(pred, gt)
    # class 0: pred {00, 01} (0.5 is not > 0.5), gt {00, 10, 11}: TP 1, FP 1, FN 2
    assert tp.tolist() == [1, 0, 0] and fp.tolist() == [1, 0, 1] and fn.tolist() == [2, 0, 0]
    ious = class_iou(tp, fp, fn)
    assert ious[0] == pytest.approx(0.25) and np.isnan(ious[1]) and ious[2] == 0.0
    assert mean_iou(ious) == pytest.approx(0.125)


def test_the_encoders_and_the_metric_decoder_agree() -> None:
    """The world's depth camera (uint16) and the nuScenes projection (float) encode what the
    depth metrics decode: one CARLA log encoding (core/depth.py)."""
    from compact_perception.data.nuscenes.projection import carla_log_depth
    from compact_perception.data.world import camera

    d = np.array([5.0, 20.0, 80.0, 500.0])
    x = torch.from_numpy(carla_log_depth(d).astype(np.float64))
    assert decode_log_depth(x).numpy() == pytest.approx(d, rel=1e-6)
    x16 = torch.from_numpy(camera.encode_depth(d).astype(np.float64) / 65535.0)   # 1/65535 steps of x
    assert decode_log_depth(x16).numpy() == pytest.approx(d, rel=1e-4)
    assert camera.decode_depth(camera.encode_depth(d)) == pytest.approx(d, rel=1e-4)
    assert float(decode_log_depth(t(1.0))) == pytest.approx(1000.0)
    assert float(decode_log_depth(t(0.0))) == pytest.approx(1000.0 * math.exp(-5.70378))
    assert float(decode_log_depth(t(1.3))) == pytest.approx(1000.0)                 # clamped to the range


def _enc(d_m: float) -> float:
    return 1.0 + math.log(d_m / 1000.0) / 5.70378


def test_depth_errors_by_hand() -> None:
    # one frame, 4 pixels: gt 10 m, 20 m, none (0), sky (1); pred 12 m, 20 m, 7 m, 3 m
    gt = t([[[[_enc(10.0), _enc(20.0), 0.0, 1.0]]]])          # (1,1,1,4)
    pred = t([[[[_enc(12.0), _enc(20.0), _enc(7.0), _enc(3.5)]]]])
    assert depth_valid_mask(gt).tolist() == [[[[True, True, False, False]]]]
    e = depth_errors_per_sample(pred, gt)
    assert float(e["abs_rel"][0]) == pytest.approx((2 / 10 + 0.0) / 2)
    assert float(e["rmse_m"][0]) == pytest.approx(math.sqrt((4.0 + 0.0) / 2))
    assert float(e["delta_1.25"][0]) == pytest.approx(1.0)     # 12/10 = 1.2 < 1.25
    assert float(e["n_valid"][0]) == 2
    # a 13 m prediction: ratio 1.3 fails delta; a frame with no valid pixel gives NaN
    pred2 = t([[[[_enc(13.0), _enc(20.0), 0.5, 0.5]]]])
    gt2 = torch.cat([gt, t([[[[0.0, 0.0, 1.0, 1.0]]]])])
    e2 = depth_errors_per_sample(torch.cat([pred2, pred2]), gt2)
    assert float(e2["delta_1.25"][0]) == pytest.approx(0.5) and math.isnan(float(e2["abs_rel"][1]))


def test_depth_errors_field_convention_by_hand() -> None:
    """Eigen et al.'s convention at an 80 m cap: ground truth beyond 80 m left out, the prediction
    clamped to [3.33 m, 80 m] (one above the encoding's range, x = 1.4, and one at 400 m), and the
    seven standard errors computed by hand on the three pixels that remain."""
    near = 1000.0 * math.exp(-5.70378)
    # gt: 10 m, 40 m, 60 m, 120 m (beyond the cap), sky; pred: 8.5 m, 400 m (-> 80), x = 1.4 (-> 80), 30 m, 5 m
    gt = t([[[[_enc(10.0), _enc(40.0), _enc(60.0), _enc(120.0), 1.0]]]])
    pred = t([[[[_enc(8.5), _enc(400.0), 1.4, _enc(30.0), _enc(5.0)]]]])
    assert depth_valid_mask(gt, 80.0).tolist() == [[[[True, True, True, False, False]]]]
    e = depth_errors_per_sample(pred, gt, 80.0)
    d, g = [8.5, 80.0, 80.0], [10.0, 40.0, 60.0]                   # max(d/d*, d*/d): 1.176, 2.0, 1.333
    assert float(e["n_valid"][0]) == 3
    assert float(e["abs_rel"][0]) == pytest.approx((1.5 / 10 + 40 / 40 + 20 / 60) / 3, rel=1e-6)
    assert float(e["sq_rel"][0]) == pytest.approx((2.25 / 10 + 1600 / 40 + 400 / 60) / 3, rel=1e-6)
    assert float(e["rmse_m"][0]) == pytest.approx(math.sqrt((2.25 + 1600 + 400) / 3), rel=1e-6)
    assert float(e["rmse_log"][0]) == pytest.approx(
        math.sqrt(sum((math.log(a) - math.log(b)) ** 2 for a, b in zip(d, g)) / 3), rel=1e-6)
    assert float(e["delta_1.25"][0]) == pytest.approx(1 / 3)         # only 1.176 < 1.25
    assert float(e["delta_1.25^2"][0]) == pytest.approx(2 / 3)       # 1.176 and 1.333 < 1.5625; 2.0 is not
    assert float(e["delta_1.25^3"][0]) == pytest.approx(2 / 3)       # 2.0 > 1.953
    # without the cap, the same prediction above the range decodes to 1000 m and dominates
    raw = depth_errors_per_sample(pred, gt)
    assert float(raw["rmse_m"][0]) > 400 > float(e["rmse_m"][0])
    # a prediction below the encoding's nearest depth is clamped to it (3.33 m)
    low = depth_errors_per_sample(t([[[[-0.5]]]]), t([[[[_enc(10.0)]]]]), 80.0)
    assert float(low["abs_rel"][0]) == pytest.approx((10.0 - near) / 10.0, rel=1e-6)
    with pytest.raises(ValueError, match="max_m"):
        depth_errors_per_sample(pred, gt, 2.0)


# ----------------------------------------------------------------------------- evaluation summary
def test_summarise_mv_of_the_means_and_tm() -> None:
    import pandas as pd

    from compact_perception.evaluation.evaluate import frame_scores, summarise

    rows = [frame_scores({"mae_de": 0.0, "iou_ss": 1.0, "iou_ls": 1.0, "iou_bevp": 1.0, "loss_de": 9.0}),
            frame_scores({"mae_de": 0.2, "iou_ss": 0.2, "iou_ls": 0.2, "iou_bevp": 0.2})]
    assert set(rows[0]) == {"mae_de", "iou_ss", "iou_ls", "iou_bevp", "tm"}          # no per-frame MV
    s = summarise(pd.DataFrame(rows))
    assert s["mv"]["value"] == pytest.approx(np.var([0.1, 0.4, 0.4, 0.4]))          # MV of the four means
    assert "eq. 7" in s["mv"]["definition"] and set(s["mv"]) == {"value", "definition"}
    assert s["tm"]["mean"] == pytest.approx(np.mean([r["tm"] for r in rows]))        # TM of means = mean TM
    assert s["tm"]["var"] == pytest.approx(np.var([r["tm"] for r in rows]))
    assert s["iou_ss"] == {"mean": pytest.approx(0.6), "var": pytest.approx(0.16)}
    assert set(summarise(pd.DataFrame([{"iou_ls": 0.5}]))) == {"iou_ls"}               # a baseline: no TM / MV


def test_class_counts_accumulate_over_frames() -> None:
    from compact_perception.evaluation.evaluate import ClassCounts

    gt = _onehot([[0, 0, 1], [2, -1, 1]], 4)
    pred = _onehot([[0, 1, 1], [2, 0, 0]], 4)
    cc = ClassCounts()
    cc.add({"ls": pred, "de": pred}, {"ls": gt})
    cc.add({"ls": pred}, {"ls": gt})
    cc.add({"bevp": pred}, {"bevp": gt})
    out = cc.summary({"ls": ["a", "b", "c", "d"], "bevp": []})
    assert out["ls"]["classes"] == {"a": pytest.approx(1 / 3), "b": pytest.approx(1 / 3), "c": 1.0, "d": None}
    assert out["ls"]["miou"] == pytest.approx(5 / 9) and out["ls"]["n_classes_in_miou"] == 3
    assert set(out["bevp"]["classes"]) == {"0", "1", "2", "3"} and "definition" in out


def test_evaluate_run_writes_paper_mv_and_field_metrics(tmp_path, params_dict) -> None:
    """The real evaluation on a tiny synthetic cache with an untrained model."""
    import json

    import pandas as pd

    from compact_perception.core.params import parse_params
    from compact_perception.evaluation.evaluate import evaluate_run
    from compact_perception.learning.models import build_model
    from run_fixture import run_in
    from synthetic import make_cache

    cache = make_cache(tmp_path / "cache" / "A", size=32, counts=(1, 1, 3))
    torch.manual_seed(0)
    model = build_model("compact_15l", "A")
    run = tmp_path / "run"
    run.mkdir()
    torch.save({"model": model.state_dict(), "epoch": 0}, run / "best.pt")
    out = tmp_path / "metrics.json"
    params_dict["evaluate"].update(save_predictions=1, depth_max_m=80)
    params_dict["train"].update(device="cpu", num_threads=1)
    params = parse_params(params_dict)
    evaluate_run(params, run_in(params, "compact_15l", cache, run, metrics_path=out, eval_dir=tmp_path / "eval"))
    m = json.loads(out.read_text())
    pf = pd.read_csv(tmp_path / "eval" / "per_frame.csv")
    means = {c: float(pf[c].mean()) for c in TASK_COLUMNS}
    assert m["mv"]["value"] == pytest.approx(scores_from_means(means)["mv"], abs=1e-5)
    assert m["tm"]["mean"] == pytest.approx(float(pf["tm"].mean()), abs=1e-5)
    assert "mv" not in pf.columns and {"abs_rel", "rmse_m", "delta_1.25", "n_valid"} <= set(pf.columns)
    assert set(m["class_iou"]) == {"ss", "ls", "bevp", "definition"}
    assert len(m["class_iou"]["ss"]["classes"]) == 23 and "road" in m["class_iou"]["ss"]["classes"]
    miou = m["class_iou"]["ls"]["miou"]
    assert miou is None or 0.0 <= miou <= 1.0
    assert m["depth"]["rmse_m"]["mean"] > 0 and 0.0 <= m["depth"]["delta_1.25"]["mean"] <= 1.0
