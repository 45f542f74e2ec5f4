"""Statistics for the claims scorecard and Table II's bold marks (CLAIMS.md, SPEC 8; issue 24).

A comparison is a *contrast* of per-model statistics of the test scores, oriented so that a
positive value means the claim holds (e.g. ``TM(1L) - TM(15L)`` for "15L has a lower TM").
Every statistic is a function of a run's per-column test-set means (a mean score, TM of the
means (eq. 6, linear), MV of the means (eq. 7, the population variance of the four terms: not
linear)); a model's value is the mean over its training seeds of the statistic of that run's
column means, and the estimate is the contrast of the models' values.

The modules, each importing only those above it:

- ``distributions`` t and normal quantiles and distribution function (scipy.stats), Satterthwaite's df
- ``comparison``    the data of one comparison (:class:`Group`, :class:`Comparison`,
                    :func:`make_comparison`) and the statistics (mean, TM, MV)
- ``variance``      the linearised contrast and its seeds x clusters variance parts
- ``power``         the minimal detectable effect (:func:`mde`), the decidability rule (:func:`decidable`)
- ``intervals``     :func:`interval` (:data:`METHOD` = ``seed-cluster-t``), :func:`seed_interval`,
                    :class:`IntervalResult`
- ``verdicts``      the verdict rule (:func:`verdict`, :func:`comparison_verdict`), :func:`seeds_to_decide`
- ``coverage``      the coverage check by simulation (:func:`coverage`, :func:`coverage_line`)

This package re-exports every public name, so ``from compact_perception.stats import interval``
is the way in; ``report/`` (claims, Table II, the gate) uses :func:`interval`.

Measured (:func:`coverage`: two models, 3 seeds, nominal 95%, 1800 simulations per composition
of :data:`COMPOSITIONS`, each over mean, TM and MV and a true difference of 0 and 0.03; coverage,
then in brackets the mean width relative to ``seed-cluster-t`` on the same simulated data).
A/B/C design, 10 paired episodes of 10 frames. The last column is history: the hierarchical
percentile bootstrap (seeds resampled per model, frames one by one) was the method before
``seed-cluster-t``; it had no caller left and has been removed from the code, so this column can
no longer be re-measured here:

=================  ==============  ===========  ============  ===========  ===========  ============
composition        seed-cluster-t  crossed-t    crossed-t-    seed-t       pigeonhole-  hierarchical-
                                                conservative               bootstrap    bootstrap
=================  ==============  ===========  ============  ===========  ===========  ============
balanced           96.8% (1.00)    94.9% (.85)  95.1% (.81)   94.4% (.95)  88.8% (.48)  88.6% (.51)
seed               95.6% (1.00)    95.0% (.99)  94.6% (.99)   95.4% (1.0)  73.3% (.37)  89.9% (.53)
model x episode    96.9% (1.00)    95.4% (.92)  95.6% (.93)   58.8% (.38)  90.6% (.76)  44.1% (.25)
run x episode      96.5% (1.00)    97.6% (.92)  98.7% (.85)   95.0% (.96)  99.1% (.69)  86.4% (.42)
frame noise        97.2% (1.00)    97.9% (.92)  99.0% (.85)   95.2% (.96)  99.0% (.70)  98.4% (.61)
unshared seeds     96.7% (1.00)    94.2% (.88)  93.8% (.84)   94.9% (.97)  84.1% (.43)  80.7% (.39)
=================  ==============  ===========  ============  ===========  ===========  ============

Other designs, lowest composition (``seed-cluster-t`` / ``crossed-t`` / ``seed-t``): 15
nuScenes-like scenes of 5-15 frames 95.6 / 92.6 / 61.1%; 40 episodes of 10 (paper scale)
95.5 / 93.1 / 78.4%; 10 episodes with unpaired seeds 96.6 / 95.3 / 63.5%.

Why ``seed-cluster-t``. The bootstraps undercover (3 seeds give a percentile interval with
normal-like quantiles and no df correction; the former hierarchical one also ignored the episodes:
44% with a model x episode effect, the issue's 60.5%); ``seed-t`` fails whenever models differ by
episode. The pooled ``crossed-t`` and its conservative form are 1-19% narrower but fall to
92.1-93.2% when the seed part carries most of the variance and the clusters are many (15, 40):
``V_seed`` has 2 df, and when it comes out small by chance the pooled Satterthwaite df jumps to
the cluster part's and t shrinks with it (Welch's problem with tiny samples; in the limit of
infinitely many clusters a separate calculation gives 92.1-93.0% at a seed share of 70-95%).
Keeping the seed part on its own 2 df holds >= 95.5% in every composition and design measured,
for 1-18% more width than ``crossed-t`` in the A/B/C design (1% when the seeds dominate).
Subtracting ``V_inter`` from the cluster part (it is in ``V_seed`` already) saves 8-12% of the
width where run x episode or frame noise dominate (kept in both parts, those compositions covered
98.7-99.7%). A delete-one jackknife over seeds and clusters gives the same two variances for a
linear statistic, so it is not a separate method. One interval (4 models x 3 seeds x 100 frames
x 4 columns, MV) takes about 7 ms; the report's check, :func:`coverage` with 400 simulations,
3-7 s on a shared 2-core CPU.

Use (the scorecard; ``a[k]``/``b[k]``: (frames, columns) per-frame scores of seed k, ``episode``:
one label per frame)::

    comp = make_comparison([{0: a[0], 1: a[1], 2: a[2]}, {0: b[0], 1: b[1], 2: b[2]}], episode)
    res = interval(comp, stat_tm, lambda v: v[..., 1] - v[..., 0])   # "A has a lower TM than B"
    comparison_verdict(res, margin=None), res.mde, undecidable_reasons(res, ["A", "B"])
    coverage_line(coverage(Design.of(comp)))                          # the report's one line
"""
from __future__ import annotations

from .comparison import (STATISTICS, Comparison, Contrast, Group, Statistic, make_comparison, score_stat, stat_mean,
                         stat_mv, stat_tm)
from .coverage import (COMPOSITIONS, COVERAGE_SEED, COVERAGE_SIMS, LEVELS, SCENARIOS, CoverageResult, Design, Scenario,
                       coverage, coverage_line, simulate)
from .distributions import normal_ppf, satterthwaite_df, t_cdf, t_ppf
from .intervals import BOOTSTRAP_SEED, CONFIDENCE, METHOD, METHODS, N_BOOT, IntervalResult, interval, seed_interval
from .power import ALPHA, MIN_SEEDS, POWER, decidable, mde
from .verdicts import (CONTRADICTED, INCONCLUSIVE, MAX_SEEDS_TO_DECIDE, NOT_DECIDABLE, REPRODUCED, VERDICTS,
                       comparison_verdict, seeds_to_decide, undecidable_reasons, verdict)

__all__ = [
    "BOOTSTRAP_SEED", "N_BOOT", "CONFIDENCE", "ALPHA", "POWER", "MIN_SEEDS", "METHOD", "METHODS",
    "REPRODUCED", "CONTRADICTED", "INCONCLUSIVE", "NOT_DECIDABLE", "VERDICTS",
    "COVERAGE_SEED", "COVERAGE_SIMS", "STATISTICS", "LEVELS", "COMPOSITIONS", "SCENARIOS",
    "Group", "Comparison", "make_comparison", "IntervalResult", "interval", "seed_interval",
    "t_cdf", "t_ppf", "normal_ppf", "satterthwaite_df", "mde", "seeds_to_decide", "MAX_SEEDS_TO_DECIDE", "decidable",
    "comparison_verdict", "undecidable_reasons", "Scenario", "Design", "simulate", "CoverageResult", "coverage",
    "coverage_line", "stat_mean", "score_stat", "stat_tm", "stat_mv", "verdict", "Statistic", "Contrast",
]
