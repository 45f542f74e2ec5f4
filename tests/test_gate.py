"""The learnedness gate (compact_perception.report.gate): a row is above the trivial-predictor floor
on a metric when the 95% interval of its margin lies above 0 with at least 3 seeds. Its edges (an
interval touching 0, 3 against 2 seeds, a model equal to the floor), the floor per metric, and the
margin's interval and MDE against closed forms."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from compact_perception.evaluation.floor import floor_of
from compact_perception.report.collect import load_row_frames
from compact_perception.report.gate import (ABOVE, BELOW, NO_DATA, NO_FLOOR, UNSHOWN, Gate, Margin,
                                            dataset_gate, failing_text, status_of)
from compact_perception.stats import IntervalResult
from report_fixture import FLOOR_BASES, MODELS, SEEDS, SHIFTS, bases_with, build_tree, seed_map


def _res(estimate: float, lo: float, hi: float, n_seeds: int = 3) -> IntervalResult:
    """A margin's interval by hand: the model (``n_seeds``) against the fixed floor."""
    return IntervalResult(estimate, lo, hi, 0.01, 2.0, "seed-cluster-t", (n_seeds, 1), (False, True), 6, 60, False)


def test_status_at_its_edges() -> None:
    assert status_of(_res(0.05, 1e-12, 0.1)) == ABOVE
    assert status_of(_res(0.05, 0.0, 0.1)) == UNSHOWN               # an interval touching 0 is not above it
    assert status_of(_res(0.05, -0.01, 0.1)) == UNSHOWN
    assert status_of(_res(0.0, -0.01, 0.01)) == BELOW               # a model equal to the floor
    assert status_of(_res(-0.02, -0.03, -0.01)) == BELOW
    assert status_of(_res(0.05, 0.01, 0.1, n_seeds=3)) == ABOVE     # exactly 3 seeds: decidable
    assert status_of(_res(0.05, 0.01, 0.1, n_seeds=2)) == UNSHOWN   # 2 seeds: not, whatever the interval
    assert status_of(_res(0.05, math.nan, math.nan, n_seeds=1)) == UNSHOWN


def _gate(root: Path, ds: str = "A", seeds=None) -> Gate:
    frames = load_row_frames(root, ds, MODELS, seeds or seed_map())
    return dataset_gate(root, ds, frames)


def test_the_floor_is_the_better_predictor_per_metric(tmp_path: Path) -> None:
    """report_fixture: the per-pixel prior is the better on DE, SS, LS and TM (2.50 vs 2.60), the
    global prior on BEVP (0.35 vs 0.30)."""
    build_tree(tmp_path, ("A",), n_frames=40, curves=False)
    floor = _gate(tmp_path).floor
    assert floor is not None
    value = floor.value()
    assert value == pytest.approx({"mae_de": 0.30, "iou_ss": 0.30, "iou_ls": 0.20, "iou_bevp": 0.35, "tm": 2.50})
    assert value == floor_of(floor.means())
    assert [floor.source(m) for m in ("mae_de", "iou_ss", "iou_ls", "iou_bevp", "tm")] == \
        ["floor_pixel"] * 3 + ["floor_global", "floor_pixel"]


def test_margin_interval_and_mde_closed_form(tmp_path: Path) -> None:
    """Without frame noise a run's frames differ from the floor's by a constant (base - floor + the
    seed's shift): no cluster variance, and the interval is the t interval over the three seeds'
    margins: se = sd(shifts) / sqrt(3), df = 2, t_{p,2} = (2p - 1) / sqrt(2p(1 - p));
    MDE = (t_{0.975,2} + t_{0.8,2}) se."""
    build_tree(tmp_path, ("A",), n_frames=40, curves=False, noise=0.0)
    m = _gate(tmp_path).margin("compact_15l", "iou_ls")
    shifts = np.array([SHIFTS[k] for k in SEEDS])
    se = shifts.std(ddof=1) / math.sqrt(3)

    def t2(p: float) -> float:
        return (2 * p - 1) / math.sqrt(2 * p * (1 - p))

    assert m.status == ABOVE and m.floor_id == "floor_pixel" and m.n_seeds == 3
    assert m.estimate == pytest.approx(0.50 - 0.20 + shifts.mean(), abs=1e-9)
    assert m.result is not None and m.result.se == pytest.approx(se, rel=1e-6)
    assert (m.ci_low, m.ci_high) == pytest.approx((m.estimate - t2(0.975) * se, m.estimate + t2(0.975) * se), rel=1e-6)
    assert m.result.mde == pytest.approx((t2(0.975) + t2(0.8)) * se, rel=1e-6)
    # MAE_DE: lower is better, the margin is floor - model
    assert _gate(tmp_path).margin("compact_15l", "mae_de").estimate == pytest.approx(0.30 - 0.09 + shifts.mean())
    assert m.text() == f"{m.estimate:+.3f} [{m.ci_low:+.3f}, {m.ci_high:+.3f}]"


def test_three_seeds_pass_two_do_not(tmp_path: Path) -> None:
    build_tree(tmp_path, ("A",), n_frames=40, curves=False)
    assert _gate(tmp_path).margin("compact_1l", "iou_ls").status == ABOVE
    two = _gate(tmp_path, seeds=seed_map((0, 1), (0, 1))).margin("compact_1l", "iou_ls")
    assert two.status == UNSHOWN and two.n_seeds == 2 and two.estimate > 0.15 and two.ci_low > 0


def test_a_model_just_below_or_near_the_floor(tmp_path: Path) -> None:
    """1L's IoU_LS is 0.002 below the floor's over its seeds (below: not better); 15L's IoU_SS
    0.01 above it, inside the seeds' spread (not shown above); every other task of theirs is far above."""
    mean_shift = float(np.mean([SHIFTS[k] for k in SEEDS]))
    build_tree(tmp_path, ("A",), n_frames=40, curves=False,
               bases=bases_with(compact_1l={"iou_ls": FLOOR_BASES["floor_pixel"]["iou_ls"] - mean_shift - 0.002},
                                compact_15l={"iou_ss": FLOOR_BASES["floor_pixel"]["iou_ss"] - mean_shift + 0.01}))
    gate = _gate(tmp_path)
    at = gate.margin("compact_1l", "iou_ls")
    assert at.status == BELOW and at.estimate == pytest.approx(-0.002, abs=1e-9)
    near = gate.margin("compact_15l", "iou_ss")
    assert near.status == UNSHOWN and near.ci_low < 0 < near.estimate
    assert [m.metric for m in gate.failing("compact_1l", ("mae_de", "iou_ss", "iou_ls", "iou_bevp"))] == ["iou_ls"]
    assert not gate.passes("compact_1l") and gate.passes("compact_15l_mgn")
    assert gate.margin("compact_1l", "tm").status == ABOVE              # TM itself is far above the floor's
    text = failing_text([("compact_15l", gate.failing("compact_15l", ("iou_ss", "iou_ls"))),
                         ("compact_1l", gate.failing("compact_1l", ("iou_ss", "iou_ls"))), ("chen_bev", [])])
    assert text == "15L SS, 1L LS"


def test_no_floor_and_no_data(tmp_path: Path) -> None:
    build_tree(tmp_path, ("A",), n_frames=40, curves=False, floors=None)
    gate = _gate(tmp_path)
    assert not gate.has_floor and gate.margin("compact_1l", "iou_ls").status == NO_FLOOR
    assert Gate(None).margin_of([], "iou_ls") == Margin("iou_ls", NO_FLOOR)
    build_tree(tmp_path / "b", ("A",), n_frames=40, curves=False)
    gate = _gate(tmp_path / "b")
    assert gate.margin("no_such_row", "iou_ls").status == NO_DATA
    assert gate.margin("polarnet", "iou_ss").status == NO_DATA         # PolarNet has no SS head
