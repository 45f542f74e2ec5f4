"""The bootstrap and the verdict rule of the claims scorecard (compact_perception.stats)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from compact_perception.metrics import metric_variance
from compact_perception.stats import (
    CONTRADICTED,
    INCONCLUSIVE,
    NOT_DECIDABLE,
    REPRODUCED,
    VERDICTS,
    bootstrap_contrast,
    decidable,
    mde,
    normal_ppf,
    paired_bootstrap,
    satterthwaite_df,
    seed_bootstrap,
    stat_mean,
    stat_mv,
    stat_tm,
    t_cdf,
    t_ppf,
    verdict,
)


def _frames(n: int, shift: float, seed: int, noise: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Two models on the same n frames: a shared per-frame difficulty, model b = a + shift + noise."""
    rng = np.random.default_rng(seed)
    difficulty = rng.normal(0.5, 0.2, n)
    a = difficulty + rng.normal(0, noise, n)
    b = difficulty + shift + rng.normal(0, noise, n)
    return a[:, None], b[:, None]


def test_known_large_difference_is_covered_and_excludes_zero() -> None:
    a, b = _frames(300, 0.1, seed=1)
    r = paired_bootstrap([a], [b], stat_mean, lower_is_better=True, n_boot=1000)
    # "a beats b, lower is better": measured = mean(b) - mean(a), ~ +0.1
    assert r.estimate == pytest.approx(float(b.mean() - a.mean()))
    assert r.ci_low < 0.1 < r.ci_high and r.ci_low > 0
    assert verdict(r.ci_low, r.ci_high) == REPRODUCED
    # the same data read the other way: contradicted
    r2 = paired_bootstrap([b], [a], stat_mean, lower_is_better=True, n_boot=1000)
    assert r2.estimate == pytest.approx(-r.estimate) and verdict(r2.ci_low, r2.ci_high) == CONTRADICTED
    # higher-is-better flips the sign
    r3 = paired_bootstrap([a], [b], stat_mean, lower_is_better=False, n_boot=1000)
    assert r3.estimate == pytest.approx(-r.estimate)
    assert r.n_frames == 300 and r.n_seeds == (1, 1) and r.n_boot == 1000


def test_no_difference_interval_includes_zero() -> None:
    a, b = _frames(200, 0.0, seed=2)
    r = paired_bootstrap([a], [b], stat_mean, lower_is_better=True, n_boot=1000)
    assert r.ci_low < 0 < r.ci_high and verdict(r.ci_low, r.ci_high) == INCONCLUSIVE


def test_pairing_narrows_the_interval() -> None:
    """Frame difficulty varies a lot but cancels in the paired difference."""
    a, b = _frames(200, 0.02, seed=3, noise=0.01)
    r = paired_bootstrap([a], [b], stat_mean, lower_is_better=True, n_boot=1000)
    assert r.ci_high - r.ci_low < 0.01 and r.ci_low > 0      # unpaired, the spread would be ~0.04


def test_deterministic() -> None:
    a, b = _frames(100, 0.01, seed=4)
    r1 = paired_bootstrap([a], [b], stat_mean, lower_is_better=True, n_boot=500)
    r2 = paired_bootstrap([a], [b], stat_mean, lower_is_better=True, n_boot=500)
    assert r1 == r2
    r3 = paired_bootstrap([a], [b], stat_mean, lower_is_better=True, n_boot=500, seed=7)
    assert r3.estimate == r1.estimate and (r3.ci_low, r3.ci_high) != (r1.ci_low, r1.ci_high)


def test_tm_and_mv_statistics_of_the_means() -> None:
    rng = np.random.default_rng(5)
    m = np.column_stack([rng.uniform(0, 0.2, 50), rng.uniform(0.4, 0.9, (50, 3))])
    means = m.mean(axis=0)
    assert float(stat_tm(means)) == pytest.approx(means[0] + 3 - means[1:].sum())
    assert float(stat_mv(means)) == pytest.approx(float(metric_variance(*means)))
    assert stat_tm(np.stack([means, means])).shape == (2,)
    # MV interval: model b has the same terms spread further apart -> larger MV
    b = m.copy()
    b[:, 2] -= 0.2                         # lower IoU_LS -> its term 1 - IoU_LS grows
    r = paired_bootstrap([m], [b], stat_mv, lower_is_better=True, n_boot=500)
    assert r.estimate == pytest.approx(float(stat_mv(b.mean(0)) - stat_mv(m.mean(0))))
    assert r.ci_low <= r.estimate <= r.ci_high


def test_seeds_are_resampled() -> None:
    """Three seeds per model: the interval reflects the spread between seeds."""
    rng = np.random.default_rng(6)
    n = 100
    base = rng.normal(0.5, 0.1, n)
    a_runs = [(base + off)[:, None] for off in (0.0, 0.01, -0.01)]
    b_tight = [(base + 0.05 + off)[:, None] for off in (0.0, 0.01, -0.01)]
    b_loose = [(base + 0.05 + off)[:, None] for off in (0.0, 0.2, -0.2)]
    tight = paired_bootstrap(a_runs, b_tight, stat_mean, lower_is_better=True, n_boot=800)
    loose = paired_bootstrap(a_runs, b_loose, stat_mean, lower_is_better=True, n_boot=800)
    assert tight.estimate == pytest.approx(0.05) and loose.estimate == pytest.approx(0.05)
    assert tight.ci_low > 0 and loose.ci_low < 0 < loose.ci_high
    assert tight.n_seeds == (3, 3)


def test_contrast_against_the_best_of_several() -> None:
    a, b = _frames(200, -0.05, seed=8)            # b lower than a
    c = b - 0.05                                   # c lower still
    r = bootstrap_contrast([[a], [b], [c]], stat_mean, lambda v: v[..., 0] - v[..., 1:].max(axis=-1), n_boot=500)
    assert r.estimate == pytest.approx(float(a.mean() - b.mean())) and r.ci_low > 0


def test_bad_inputs() -> None:
    a, b = _frames(10, 0.0, seed=9)
    with pytest.raises(ValueError, match="same frames"):
        paired_bootstrap([a], [b[:5]], stat_mean, lower_is_better=True)
    with pytest.raises(ValueError, match="finite"):
        paired_bootstrap([a], [np.full_like(b, np.nan)], stat_mean, lower_is_better=True)
    with pytest.raises(ValueError, match="no runs"):
        paired_bootstrap([a], [], stat_mean, lower_is_better=True)


def test_seed_bootstrap_needs_three_seeds() -> None:
    r = seed_bootstrap([0.2, 0.1])
    assert r.estimate == pytest.approx(0.15) and math.isnan(r.ci_low) and verdict(r.ci_low, r.ci_high) == INCONCLUSIVE
    r3 = seed_bootstrap([0.2, 0.1, 0.3, 0.25], n_boot=500)
    assert 0.1 <= r3.ci_low <= r3.estimate <= r3.ci_high <= 0.3 and verdict(r3.ci_low, r3.ci_high) == REPRODUCED
    assert verdict(*(lambda r: (r.ci_low, r.ci_high))(seed_bootstrap([0.2, -0.1, 0.3]))) == INCONCLUSIVE


# ----------------------------------------------------------------------------- the verdict rule at its edges
@pytest.mark.parametrize(("lo", "hi", "expected"), [
    (0.01, 0.2, REPRODUCED),
    (0.0, 0.2, INCONCLUSIVE),          # touching 0: not wholly on the claimed side
    (-0.2, 0.0, INCONCLUSIVE),         # touching 0 from below: not wholly on the other side
    (-0.2, -1e-9, CONTRADICTED),
    (-0.1, 0.1, INCONCLUSIVE),
    (0.0, 0.0, INCONCLUSIVE),
    (math.nan, 0.1, INCONCLUSIVE),
])
def test_verdict_ordering_claims(lo: float, hi: float, expected: str) -> None:
    assert verdict(lo, hi) == expected


@pytest.mark.parametrize(("lo", "hi", "expected"), [
    (-0.001, 0.001, REPRODUCED),        # exactly at the margin: within
    (-0.0005, 0.0002, REPRODUCED),
    (-0.001, 0.0010001, INCONCLUSIVE),  # just past it on one side
    (0.0010001, 0.01, CONTRADICTED),    # wholly above the margin
    (-0.01, -0.0010001, CONTRADICTED),
    (0.001, 0.01, INCONCLUSIVE),        # touching the margin from outside
])
def test_verdict_equality_claims(lo: float, hi: float, expected: str) -> None:
    assert verdict(lo, hi, margin=0.001) == expected


def test_verdict_rejects_bad_bounds() -> None:
    with pytest.raises(ValueError):
        verdict(0.2, 0.1)
    with pytest.raises(ValueError):
        verdict(-0.1, 0.1, margin=-1.0)


# ============================================================================= issue 24: verdicts that hold
# ----------------------------------------------------------------------------- Student's t and the MDE
@pytest.mark.parametrize(("p", "df", "printed"), [
    (0.975, 1, 12.706), (0.975, 2, 4.303), (0.975, 3, 3.182), (0.975, 10, 2.228), (0.975, 30, 2.042),
    (0.8, 2, 1.061), (0.8, 10, 0.879), (0.8, 30, 0.854), (0.995, 5, 4.032), (0.9, 4, 1.533),
])
def test_t_quantile_matches_printed_tables(p: float, df: float, printed: float) -> None:
    assert t_ppf(p, df) == pytest.approx(printed, abs=6e-4)
    assert t_ppf(1 - p, df) == pytest.approx(-t_ppf(p, df))
    assert t_cdf(t_ppf(p, df), df) == pytest.approx(p, abs=1e-12)


def test_t_quantile_limits_and_errors() -> None:
    assert normal_ppf(0.975) == pytest.approx(1.959964, abs=1e-6)
    assert normal_ppf(0.8) == pytest.approx(0.841621, abs=1e-6)
    assert t_ppf(0.975, math.inf) == normal_ppf(0.975) and t_ppf(0.975, 1e6) == pytest.approx(1.959966, abs=1e-5)
    assert t_ppf(0.975, 2.5) < t_ppf(0.975, 2) and t_ppf(0.5, 3) == 0.0    # non-integer df (Satterthwaite)
    assert t_cdf(0.0, 4) == 0.5 and t_cdf(1.0, 1) == pytest.approx(0.75)      # Cauchy: 1/2 + atan(1)/pi
    for bad in ((0.0, 2), (1.0, 2), (0.5, 0)):
        with pytest.raises(ValueError):
            t_ppf(*bad)


@pytest.mark.parametrize("p", [0.6, 0.8, 0.9, 0.975, 0.995, 0.9999])
def test_t_quantile_against_closed_forms(p: float) -> None:
    """df = 1 (Cauchy): tan(pi (p - 1/2)); df = 2: (2p - 1) / sqrt(2 p (1 - p))."""
    assert t_ppf(p, 1) == pytest.approx(math.tan(math.pi * (p - 0.5)), rel=1e-10)
    assert t_ppf(p, 2) == pytest.approx((2 * p - 1) / math.sqrt(2 * p * (1 - p)), rel=1e-10)


def test_mde_against_the_closed_form() -> None:
    """MDE = (t_{1-alpha/2, df} + t_{power, df}) * SE, with table values by hand."""
    assert mde(0.01, 2) == pytest.approx((4.303 + 1.061) * 0.01, abs=2e-5)       # 0.05364
    assert mde(0.01, 10) == pytest.approx((2.228 + 0.879) * 0.01, abs=2e-5)      # 0.03107
    assert mde(0.002, math.inf) == pytest.approx((1.95996 + 0.84162) * 0.002, abs=1e-7)
    assert mde(0.01, 2, alpha=0.1, power=0.9) == pytest.approx((2.920 + 1.886) * 0.01, abs=2e-5)
    assert math.isnan(mde(math.nan, 2)) and math.isnan(mde(0.01, math.nan))


def test_satterthwaite_df() -> None:
    assert satterthwaite_df([(1.0, 2.0), (1.0, 9.0)]) == pytest.approx(4.0 / (0.5 + 1 / 9))
    assert satterthwaite_df([(3.0, 4.0)]) == pytest.approx(4.0)
    assert satterthwaite_df([(0.0, 2.0)]) == math.inf
    assert satterthwaite_df([(1.0, 2.0), (1.0, 2.0)], total=0.1) == 1.0          # floored at 1


def test_decidable_needs_three_seeds_per_trained_model() -> None:
    assert decidable((3, 3)) and not decidable((3, 2)) and not decidable((1, 3)) and not decidable(())
    assert decidable((1, 3), (True, False))          # a deterministic floor: one fixed run
    assert set(VERDICTS) == {REPRODUCED, CONTRADICTED, INCONCLUSIVE, NOT_DECIDABLE} and NOT_DECIDABLE == "not decidable"
