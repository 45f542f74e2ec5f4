"""The intervals, power, decidability and verdict rule of the claims scorecard (compact_perception.stats;
issue 24). tests/test_stats_regression.py pins their numbers."""
from __future__ import annotations

import math
import time

import numpy as np
import pytest

from compact_perception.learning.metrics import metric_variance
from compact_perception.stats import (
    CONTRADICTED,
    COVERAGE_SIMS,
    INCONCLUSIVE,
    METHOD,
    METHODS,
    NOT_DECIDABLE,
    REPRODUCED,
    SCENARIOS,
    STATISTICS,
    VERDICTS,
    Comparison,
    Design,
    Group,
    comparison_verdict,
    coverage,
    coverage_line,
    decidable,
    interval,
    make_comparison,
    mde,
    normal_ppf,
    satterthwaite_df,
    seed_interval,
    simulate,
    stat_mean,
    stat_mv,
    stat_tm,
    t_cdf,
    t_ppf,
    undecidable_reasons,
    verdict,
)


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
    r = interval(make_comparison([{0: m, 1: m + 0.01, 2: m - 0.01}, {0: b, 1: b + 0.01, 2: b - 0.01}],
                                 np.arange(50) // 5), stat_mv, lambda v: v[..., 1] - v[..., 0])
    assert r.estimate == pytest.approx(float(np.mean([stat_mv(x.mean(0)) for x in (b, b + 0.01, b - 0.01)])
                                             - np.mean([stat_mv(x.mean(0)) for x in (m, m + 0.01, m - 0.01)])))
    assert r.ci_low <= r.estimate <= r.ci_high


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
    r = interval(_hand_comparison(), stat_mean, _b_minus_a)
    assert r.mde == pytest.approx((t_ppf(0.975, r.df) + t_ppf(0.8, r.df)) * r.se)


def test_satterthwaite_df() -> None:
    assert satterthwaite_df([(1.0, 2.0), (1.0, 9.0)]) == pytest.approx(4.0 / (0.5 + 1 / 9))
    assert satterthwaite_df([(3.0, 4.0)]) == pytest.approx(4.0)
    assert satterthwaite_df([(0.0, 2.0)]) == math.inf
    assert satterthwaite_df([(1.0, 2.0), (1.0, 2.0)], total=0.1) == 1.0          # floored at 1


# ----------------------------------------------------------------------------- the interval, by hand
def _b_minus_a(v: np.ndarray) -> np.ndarray:
    return v[..., 1] - v[..., 0]


#: The seeds x clusters table of B - A's cluster means in :func:`_hand_comparison`.
HAND_D = np.array([[1.0, 3.0], [2.0, 4.0], [3.0, 8.0]])


def _hand_comparison() -> Comparison:
    """A = 0 everywhere; B's cluster means per seed are HAND_D (2 frames per cluster)."""
    a = {s: np.zeros(4) for s in range(3)}
    b = {s: np.array([d[0] - 1, d[0] + 1, d[1] - 0.5, d[1] + 0.5]) for s, d in enumerate(HAND_D)}
    return make_comparison([a, b], ["e1", "e1", "e2", "e2"])


def test_crossed_interval_by_hand() -> None:
    """Rows (2, 3, 5.5): V_seed = var/S = 3.25/3; columns (2, 5), pi = 1/2: V_cluster = K/(K-1)
    sum pi^2 (u - 3.5)^2 = 2.25; residuals +-0.5, +-0.5, -+1: V_inter = 0.75 K / ((S-1)(K-1)S) =
    0.25; V = 3.0833; df = V^2 / (V_seed^2/2 + V_cluster^2/1 + V_inter^2/2) = 1.6736."""
    comp = _hand_comparison()
    assert comp.paired and comp.n_clusters == 2 and comp.n_frames == 4 and comp.n_seeds == (3, 3)
    r = interval(comp, stat_mean, _b_minus_a, method="crossed-t")
    v = 3.25 / 3 + 2.25 - 0.25
    df = v * v / ((3.25 / 3) ** 2 / 2 + 2.25 ** 2 / 1 + 0.25 ** 2 / 2)
    assert r.estimate == pytest.approx(3.5) and r.se == pytest.approx(math.sqrt(v), rel=1e-7)
    assert r.df == pytest.approx(df, rel=1e-7)
    assert r.ci_high - r.estimate == pytest.approx(t_ppf(0.975, df) * math.sqrt(v), rel=1e-7)
    assert r.estimate - r.ci_low == pytest.approx(r.ci_high - r.estimate)
    cons = interval(comp, stat_mean, _b_minus_a, method="crossed-t-conservative")
    assert cons.se ** 2 == pytest.approx(3.25 / 3 + 2.25, rel=1e-7)
    assert cons.df == pytest.approx((3.25 / 3 + 2.25) ** 2 / ((3.25 / 3) ** 2 / 2 + 2.25 ** 2), rel=1e-7)
    seed_t = interval(comp, stat_mean, _b_minus_a, method="seed-t")
    assert seed_t.se ** 2 == pytest.approx(3.25 / 3, rel=1e-7) and seed_t.df == pytest.approx(2.0)


def test_estimate_of_a_non_linear_statistic_by_hand() -> None:
    """MV (eq. 7) of each run's column means, averaged over seeds, then B - A."""
    rng = np.random.default_rng(11)
    runs = {g: {s: np.column_stack([rng.uniform(0.1, 0.3, 20), rng.uniform(0.3, 0.8, (20, 3))]) for s in range(3)}
            for g in ("a", "b")}
    comp = make_comparison([runs["a"], runs["b"]], np.repeat(np.arange(4), 5))
    by_hand = {g: np.mean([float(metric_variance(*r.mean(axis=0))) for r in runs[g].values()]) for g in runs}
    r = interval(comp, stat_mv, _b_minus_a)
    assert r.estimate == pytest.approx(by_hand["b"] - by_hand["a"], rel=1e-9)
    assert r.ci_low < r.estimate < r.ci_high and r.n_clusters == 4 and r.n_frames == 20


def test_seed_pairing_cancels_a_shared_seed_effect() -> None:
    """Each seed shifts both models alike (common random numbers): paired, the shift cancels;
    with the seeds taken as unrelated it stays in the interval."""
    rng = np.random.default_rng(12)
    base = rng.normal(0.5, 0.1, 100)
    a, b = {}, {}
    for s, shift in enumerate((0.05, -0.04, 0.0)):
        a[s] = base + shift + rng.normal(0, 0.005, 100)
        b[s] = base + shift + 0.01 + rng.normal(0, 0.005, 100)
    clusters = np.repeat(np.arange(10), 10)
    paired = interval(make_comparison([a, b], clusters), stat_mean, _b_minus_a)
    unpaired = interval(make_comparison([a, {s + 100: v for s, v in b.items()}], clusters), stat_mean, _b_minus_a)
    assert paired.paired and not unpaired.paired
    assert paired.estimate == pytest.approx(unpaired.estimate)
    assert paired.ci_low > 0 and paired.se < unpaired.se / 5 and unpaired.ci_low < 0


def test_cluster_resampling_widens_with_a_model_x_episode_effect() -> None:
    """B is better or worse by episode: the frames of one episode are not 10 observations."""
    rng = np.random.default_rng(13)
    clusters = np.repeat(np.arange(10), 10)
    episode = rng.normal(0, 0.03, 10)[clusters]
    base = rng.normal(0.5, 0.1, 100)
    a = {s: base + rng.normal(0, 0.01, 100) for s in range(3)}
    b = {s: base + 0.01 + episode + rng.normal(0, 0.01, 100) for s in range(3)}
    by_episode = interval(make_comparison([a, b], clusters), stat_mean, _b_minus_a)
    by_frame = interval(make_comparison([a, b], np.arange(100)), stat_mean, _b_minus_a)
    assert by_episode.estimate == pytest.approx(by_frame.estimate)
    assert by_episode.se > 2 * by_frame.se and by_frame.n_clusters == 100


def test_frame_level_intervals_undercover_episode_level_ones_do_not() -> None:
    """The issue's 60% in simulation: the same simulated data with each frame its own cluster."""
    design = Design()
    scenarios = [s for s in SCENARIOS if s.name.startswith("model x episode/")]
    hits = {"episode": 0, "frame": 0}
    n = 120
    for i in range(n):
        sc = scenarios[i % len(scenarios)]
        comp, truth = simulate(sc, design, np.random.default_rng([5, i]))
        for key, c in (("episode", comp), ("frame", make_comparison(comp.groups, np.arange(comp.n_frames)))):
            r = interval(c, STATISTICS[sc.statistic], lambda v: v[..., 1] - v[..., 0])
            hits[key] += r.ci_low <= truth <= r.ci_high
    assert hits["frame"] / n < 0.85 and hits["episode"] / n >= 0.9


# ----------------------------------------------------------------------------- coverage
@pytest.mark.parametrize("design", [
    Design(),                                                                     # A/B/C: 10 episodes of 10
    Design(cluster_sizes=(5, 7, 9, 10, 11, 13, 15, 6, 8, 12, 14, 10, 9, 11, 10)),  # nuScenes-like scenes
    Design(paired=False),                                                         # seeds not shared
], ids=["episodes", "scenes", "unpaired"])
def test_coverage_at_nominal_95(design: Design) -> None:
    """400 simulations (every scenario: seed, cluster, model x cluster, run x cluster and frame
    effects; mean, TM, MV; true difference 0 and 0.03) at 3 seeds: coverage >= 93%."""
    t0 = time.perf_counter()
    res = coverage(design)
    took = time.perf_counter() - t0
    assert res.n_sim == COVERAGE_SIMS == 400 and res.method == METHOD and res.n_seeds == 3
    assert res.coverage >= 0.93, res.per_scenario
    assert sum(n for *_, n in res.per_scenario) == 400 and len(res.per_scenario) == len(SCENARIOS)
    assert took < 10.0                                # the report runs it once per design


def test_coverage_is_deterministic_and_has_its_report_line() -> None:
    small = [s for s in SCENARIOS if s.statistic == "mean"]
    r1 = coverage(Design(), scenarios=small, n_sim=24)
    r2 = coverage(Design(), scenarios=small, n_sim=24)
    assert r1 == r2
    line = coverage_line(r1)
    assert line == (f"intervals: {METHOD}; coverage {100 * r1.coverage:.1f}% at nominal 95% in 24 simulations "
                    "at 3 seeds, 10 clusters")
    assert coverage(Design(), scenarios=small, n_sim=24, seed=1) != r1
    with pytest.raises(ValueError, match="n_sim"):
        coverage(Design(), n_sim=0)


def test_design_of_a_comparison() -> None:
    comp = make_comparison([{0: np.zeros(6), 1: np.ones(6), 2: np.ones(6)}, Group({0: np.ones(6)}, fixed=True)],
                           [1, 1, 2, 2, 2, 3])
    d = Design.of(comp)
    assert d == Design(3, (2, 3, 1), False)


# ----------------------------------------------------------------------------- no verdict from a single run
def test_fewer_than_three_seeds_is_not_decidable() -> None:
    clusters = np.repeat(np.arange(5), 4)
    rng = np.random.default_rng(14)
    three = {s: rng.normal(0.5, 0.1, 20) for s in range(3)}
    one = {0: rng.normal(0.8, 0.1, 20)}
    r = interval(make_comparison([three, one], clusters), stat_mean, _b_minus_a)
    assert r.n_seeds == (3, 1) and not r.paired and not r.decidable
    assert math.isnan(r.ci_low) and math.isnan(r.se) and math.isnan(r.mde)
    assert comparison_verdict(r) == NOT_DECIDABLE == "not decidable"
    assert undecidable_reasons(r, ["A", "B"]) == ["1 seed: B"]
    two = interval(make_comparison([three, {0: one[0], 1: one[0] + 0.1}], clusters), stat_mean, _b_minus_a)
    assert math.isfinite(two.ci_low) and comparison_verdict(two) == NOT_DECIDABLE   # an interval, yet no verdict
    assert undecidable_reasons(two, ["A", "B"]) == ["2 seeds: B"]
    ok = interval(make_comparison([three, {s: v + 1.0 for s, v in three.items()}], clusters), stat_mean, _b_minus_a)
    assert ok.decidable and comparison_verdict(ok) == REPRODUCED and undecidable_reasons(ok, ["A", "B"]) == []


def test_decidable_needs_three_seeds_per_trained_model() -> None:
    assert decidable((3, 3)) and not decidable((3, 2)) and not decidable((1, 3)) and not decidable(())
    assert decidable((1, 3), (True, False))          # a deterministic floor: one fixed run
    assert set(VERDICTS) == {REPRODUCED, CONTRADICTED, INCONCLUSIVE, NOT_DECIDABLE} and NOT_DECIDABLE == "not decidable"


def test_a_deterministic_floor_is_one_fixed_run() -> None:
    """The trivial floor has no training randomness: compared with 3 seeds it is decidable, and
    only the model's seeds and the clusters enter the interval."""
    rng = np.random.default_rng(15)
    clusters = np.repeat(np.arange(10), 10)
    floor = Group({0: rng.normal(0.2, 0.05, 100)}, fixed=True, name="floor")
    model = {s: floor.runs[0] + 0.1 + rng.normal(0, 0.02, 100) + 0.01 * s for s in range(3)}
    r = interval(make_comparison([model, floor], clusters), stat_mean, lambda v: v[..., 0] - v[..., 1])
    assert r.fixed == (False, True) and r.decidable and not r.paired and r.ci_low > 0
    assert r.estimate == pytest.approx(0.11, abs=0.01)
    assert undecidable_reasons(r, ["model", "floor"]) == [] and comparison_verdict(r) == REPRODUCED
    with pytest.raises(ValueError, match="fixed"):
        make_comparison([model, Group({0: model[0], 1: model[1]}, fixed=True)], clusters)


def test_seed_interval() -> None:
    r = seed_interval([0.2, 0.1, 0.3, 0.25])
    sd = float(np.std([0.2, 0.1, 0.3, 0.25], ddof=1))
    assert r.estimate == pytest.approx(0.2125) and r.df == 3 and r.se == pytest.approx(sd / 2)
    assert r.ci_high - r.estimate == pytest.approx(3.182 * sd / 2, rel=1e-3)
    one = seed_interval([0.3])
    assert math.isnan(one.ci_low) and not one.decidable and comparison_verdict(one) == NOT_DECIDABLE


# ----------------------------------------------------------------------------- methods, inputs, speed
def test_every_method_gives_an_interval_around_the_estimate() -> None:
    comp, _ = simulate(SCENARIOS[0], Design(), np.random.default_rng(16))
    for method in METHODS:
        r = interval(comp, stat_mean, _b_minus_a, method=method, n_boot=300)
        assert r.method == method and r.ci_low < r.ci_high
    with pytest.raises(ValueError, match="method"):
        interval(comp, stat_mean, _b_minus_a, method="hierarchical-bootstrap")     # the former method, removed
    with pytest.raises(ValueError, match="method"):
        interval(comp, stat_mean, _b_minus_a, method="magic")


def test_comparison_bad_inputs() -> None:
    ok = np.zeros((6, 2))
    with pytest.raises(ValueError, match="group 1 seed 0: shape"):
        make_comparison([{0: ok}, {0: ok[:5]}], range(6))
    with pytest.raises(ValueError, match="group 0 seed 3: scores must be finite"):
        make_comparison([{3: np.full((6, 2), np.nan)}], range(6))
    with pytest.raises(ValueError, match="clusters: expected one label per frame"):
        make_comparison([{0: ok}], range(5))
    with pytest.raises(ValueError, match="group 1 has no runs"):
        make_comparison([{0: ok}, {}], range(6))
    with pytest.raises(ValueError, match="no groups"):
        make_comparison([], range(6))


def test_one_interval_is_fast() -> None:
    """The report computes ~100 intervals: 4 models x 3 seeds x 100 frames x 4 columns, MV."""
    rng = np.random.default_rng(17)
    groups = [{s: rng.uniform(0, 1, (100, 4)) for s in range(3)} for _ in range(4)]
    comp = make_comparison(groups, np.repeat(np.arange(10), 10))
    t0 = time.perf_counter()
    for _ in range(10):
        interval(comp, stat_mv, lambda v: v[..., 0] - v[..., 1:].max(axis=-1))
    assert (time.perf_counter() - t0) / 10 < 0.25


# ----------------------------------------------------------------------------- seeds to decide
def test_seeds_to_decide_two_model_design_by_hand() -> None:
    """Two paired models, 3 seeds, 4 episodes of 5 frames; every frame of a run scores the run's
    value, so the episodes add nothing and the interval is the seeds' paired t. The seeds'
    contrasts 0.10, 0.14, 0.06 have sample variance 0.0016; at S seeds the SE is sqrt(0.0016 / S)
    on S - 1 df and the MDE (t_{0.975,S-1} + t_{0.8,S-1}) SE, computed here with scipy. The
    paper's effect 0.05 needs 8 seeds (7 give 0.0507); 0.2 needs the minimum, 3."""
    from scipy import stats as sps

    from compact_perception.stats import (MIN_SEEDS, interval, make_comparison, mde, seed_interval, seeds_to_decide,
                                          stat_mean)

    clusters = [c for c in range(4) for _ in range(5)]
    a = {k: np.full((20, 1), v) for k, v in enumerate([0.40, 0.38, 0.44])}
    b = {k: np.full((20, 1), a[k][0, 0] + d) for k, d in enumerate([0.10, 0.14, 0.06])}
    res = interval(make_comparison([a, b], clusters), stat_mean, lambda v: v[..., 1] - v[..., 0])
    assert res.estimate == pytest.approx(0.10) and res.se == pytest.approx(math.sqrt(0.0016 / 3))
    assert res.mde == pytest.approx(mde(math.sqrt(0.0016 / 3), 2.0))

    def by_hand(effect: float) -> int:
        for s in range(MIN_SEEDS, 101):
            if (sps.t.ppf(0.975, s - 1) + sps.t.ppf(0.8, s - 1)) * math.sqrt(0.0016 / s) <= effect:
                return s
        raise AssertionError("not reached")

    assert by_hand(0.05) == 8
    assert seeds_to_decide(res, 0.05) == 8 and seeds_to_decide(res, -0.05) == 8      # the sign does not matter
    assert seeds_to_decide(res, 0.2) == by_hand(0.2) == MIN_SEEDS
    assert seeds_to_decide(res, 1e-4) is None                                          # beyond 100 seeds
    assert seeds_to_decide(res, None) is None and seeds_to_decide(seed_interval([0.1, 0.2]), 0.1) is None
    one = interval(make_comparison([{0: a[0]}, {0: b[0]}], clusters), stat_mean, lambda v: v[..., 1] - v[..., 0])
    assert seeds_to_decide(one, 0.05) is None                                          # one seed: no seed variance


def test_seeds_to_decide_keeps_the_episodes_part() -> None:
    """With an episode effect the models do not share, more seeds shrink only the seed part: an
    effect below the episodes' own MDE is never reached (None), a larger one is."""
    from compact_perception.stats import interval, make_comparison, seeds_to_decide, stat_mean

    rng = np.random.default_rng(0)
    clusters = [c for c in range(6) for _ in range(5)]
    ep = np.repeat(rng.normal(0, 0.05, 6), 5)[:, None]                 # model b's own episode effect
    a = {k: np.full((30, 1), 0.4 + 0.01 * k) for k in range(3)}
    b = {k: a[k] + 0.1 + ep + 0.002 * (k - 1) for k in range(3)}
    res = interval(make_comparison([a, b], clusters), stat_mean, lambda v: v[..., 1] - v[..., 0])
    floor_mde = res.mde
    assert seeds_to_decide(res, floor_mde / 3) is None
    n = seeds_to_decide(res, floor_mde * 1.01)
    assert n is not None and n >= 3
