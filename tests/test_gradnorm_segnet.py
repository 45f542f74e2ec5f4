"""GradNorm SegNet's SS prediction as the pipeline scores it (issue 12 item 3, docs/gradnorm_segnet.md).

The baseline's SS head ends in a softmax over the C = 23 classes; the IoU_SS of eq. (5) counts a
class as predicted where its probability exceeds 0.5. A network whose arg-max class map is
exactly right but whose top probability is below 0.5 (every pixel of the default-scale runs:
top probability 0.077 on average after 3 epochs) then scores IoU_SS = 0. These tests rig the SS
head of a one-view GradNormSegNet to output a known class map, through the same scoring calls
that ``evaluate.evaluate_run`` (``frame_scores(compute_metrics(...))``) and the training loop's
validation (``training.epoch.evaluate_split``) make.
"""
from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from compact_perception.evaluation.evaluate import frame_scores
from compact_perception.learning.metrics import class_confusion, class_iou, compute_metrics
from compact_perception.learning.models.segnet import GradNormSegNet
from compact_perception.learning.training.epoch import evaluate_split

N_CLS, S = 23, 32  # classes of the simulated sets, default resolution


class FixedLogits(nn.Module):
    """Replaces a view's SS head: logits ``margin`` on a fixed class map, 0 elsewhere."""

    def __init__(self, class_map: Tensor, margin: float) -> None:
        super().__init__()
        self.register_buffer("logits", margin * F.one_hot(class_map, N_CLS).movedim(-1, 0).float())

    def forward(self, x: Tensor) -> Tensor:
        return self.logits.expand(x.shape[0], -1, -1, -1)


def _class_map() -> Tensor:
    """(S,S) class indices using every class, not symmetric in rows and columns."""
    r, c = torch.meshgrid(torch.arange(S), torch.arange(S), indexing="ij")
    return (3 * r + 7 * c) % N_CLS


def _rigged(margin: float) -> tuple[GradNormSegNet, dict[str, Tensor]]:
    """One-view GradNormSegNet whose SS arg-max is the ground truth; top probability
    e^m / (e^m + C - 1): 0.25 for m = 2, 0.999 for m = 10."""
    torch.manual_seed(0)
    model = GradNormSegNet(N_CLS, n_views=1).eval()
    cm = _class_map()
    model.views[0].head_ss = FixedLogits(cm, margin)
    raw = {"rgb": torch.zeros(1, 1, 3, S, S, dtype=torch.uint8), "de": torch.zeros(1, 1, 1, S, S),
           "ss": cm.to(torch.uint8)[None, None]}
    return model, raw


def _batch(raw: dict[str, Tensor]) -> dict[str, Tensor]:
    return {"rgb": raw["rgb"].float() / 255, "de": raw["de"],
            "ss": F.one_hot(raw["ss"].long(), N_CLS).movedim(-1, 2).float()}


@pytest.mark.parametrize("margin", [2.0, 10.0])
def test_layout_argmax_class_map_is_the_ground_truth(margin: float) -> None:
    """Channel order, view order and class axis agree with the targets: the per-class IoU
    (arg-max over the class axis, evaluate.ClassCounts) of the rigged head is 1 for every class."""
    model, raw = _rigged(margin)
    batch = _batch(raw)
    with torch.no_grad():
        out = model(batch)
    assert out["ss"].shape == batch["ss"].shape
    ious = class_iou(*(c.numpy() for c in class_confusion(out["ss"], batch["ss"])))
    assert ious.min() == 1.0


def test_confident_correct_prediction_scores_iou_one() -> None:
    """Top probability 0.999: eq. (5) as scored today gives IoU_SS 1 (the scoring path works
    for a confident softmax)."""
    model, raw = _rigged(10.0)
    batch = _batch(raw)
    with torch.no_grad():
        assert frame_scores(compute_metrics(model(batch), batch, argmax_tasks=model.argmax_tasks))["iou_ss"] \
            == pytest.approx(1.0)


def test_unconfident_correct_prediction_scores_iou_one() -> None:
    """Top probability 0.25 but the right class everywhere: the network's predicted class map
    is the ground truth, so IoU_SS must be 1 in the test evaluation and in the validation that
    selects the checkpoint. Before the fix both gave 0: the cause of the baseline's IoU_SS ~ 0
    (eq. 5's p > 0.5 on the softmax instead of its arg-max map)."""
    model, raw = _rigged(2.0)
    batch = _batch(raw)
    with torch.no_grad():
        out = model(batch)
    assert out["ss"].amax(dim=2).max() < 0.5
    assert model.argmax_tasks == ("ss",)
    assert frame_scores(compute_metrics(out, batch, argmax_tasks=model.argmax_tasks))["iou_ss"] == pytest.approx(1.0)
    assert frame_scores(compute_metrics(out, batch, argmax_tasks=()))["iou_ss"] == 0.0  # the old scoring
    val = evaluate_split(model, [raw], torch.device("cpu"), {"num_seg_classes": N_CLS}, torch.float32)
    assert val["iou_ss"] == pytest.approx(1.0)
