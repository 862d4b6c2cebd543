"""Interval estimates used by the reports (baselines/reports/stats.py): the two-stage bootstrap over seeds and
episodes within seeds checked against hand-computed and enumerated cases, the refusal under three seeds, the
seed-clustered success interval and Holm's correction."""

import itertools
import math

import numpy as np
import pytest
from scipy import stats as sps

from evaaa_baselines.reports.stats import (
    MIN_SEEDS,
    TooFewSeeds,
    binomial_interval,
    clustered_rate,
    holm,
    interval,
    iqm,
    replicates,
)


def test_iqm_is_the_mean_of_the_middle_half():
    assert iqm(np.arange(1, 9, dtype=float)) == pytest.approx(4.5)  # mean of 3, 4, 5, 6
    assert iqm(np.array([0.0, 10, 10, 1000])) == pytest.approx(10.0)  # the outlier does not move it


def test_an_interval_of_fewer_than_three_seeds_is_refused():
    assert MIN_SEEDS == 3
    for samples in ([[1.0, 2.0, 3.0]], [[1.0, 2.0], [3.0, 4.0]], [[1.0] * 50, [2.0] * 50, []]):
        with pytest.raises(TooFewSeeds, match="at least 3 seeds"):
            interval(samples)
        with pytest.raises(TooFewSeeds):
            clustered_rate([[1.0, 0.0]] * len([s for s in samples if s]))
    assert interval([[1.0], [2.0], [3.0]]).n == 3


def test_seeds_are_redrawn_by_hand():
    # three seeds of constant episodes: only the seed draw varies.  The replicate mean is the mean of three draws
    # from {0, 10, 20}; P(all 0) = P(all 20) = 1/27 > 2.5 %, so the 95 % interval is [0, 20] (a bootstrap of the
    # episodes within each seed alone, the old scheme, gave [10, 10])
    est = interval([[0.0, 0.0], [10.0, 10.0], [20.0, 20.0]], "mean", resamples=4000)
    assert (est.value, est.low, est.high, est.n) == (10.0, 0.0, 20.0, 3)


def test_episodes_are_redrawn_within_each_seed_by_hand():
    # three identical seeds of episodes {0, 10}: the seed draw changes nothing, the replicate mean is 10·B/6 with
    # B ~ Binomial(6, 1/2): P(B = 0) = 1/64 < 2.5 % < P(B <= 1) = 7/64, so the interval is [10/6, 50/6]
    est = interval([[0.0, 10.0]] * 3, "mean", resamples=4000)
    assert est.value == 5.0 and (est.low, est.high) == pytest.approx((10 / 6, 50 / 6))


def test_the_bootstrap_distribution_matches_its_enumeration():
    # every equally likely replicate of three seeds of unequal episodes, enumerated: 27 seed draws, then every
    # draw of each drawn seed's episodes from its own; the IQM of each computed with scipy
    seeds = [[0.0, 3.0], [1.0], [5.0, 6.0, 20.0]]
    exact, weights = [], []
    for drawn in itertools.product(range(3), repeat=3):
        per_seed = [list(itertools.product(seeds[s], repeat=len(seeds[s]))) for s in drawn]
        for episodes in itertools.product(*per_seed):
            exact.append(sps.trim_mean(np.concatenate(episodes), 0.25))
            weights.append(1.0 / math.prod(len(p) for p in per_seed))
    exact, weights = np.array(exact), np.array(weights) / 27
    assert weights.sum() == pytest.approx(1.0)
    reps = replicates(seeds, "iqm", resamples=40_000, seed=3)
    assert reps.mean() == pytest.approx(float((exact * weights).sum()), abs=0.05)
    for x in np.unique(exact):  # the distribution functions agree everywhere (Monte Carlo error ~0.0025)
        assert (reps <= x + 1e-9).mean() == pytest.approx(weights[exact <= x + 1e-9].sum(), abs=0.01)


def test_interval_covers_the_estimate_narrows_with_more_episodes_and_is_seeded():
    rng = np.random.default_rng(0)
    few = interval([rng.normal(100, 20, 10) for _ in range(4)])
    many = interval([rng.normal(100, 20, 400) for _ in range(4)])
    for est in (few, many):
        assert est.low <= est.value <= est.high
    assert many.high - many.low < 0.5 * (few.high - few.low)
    assert many.low < 100 < many.high
    assert interval([[1.0, 2, 3]] * 3, seed=1) == interval([[1.0, 2, 3]] * 3, seed=1)


def test_interval_errors():
    with pytest.raises(ValueError, match="statistic"):
        interval([[1.0, 2.0]] * 3, "median")
    with pytest.raises(ValueError, match="finite"):
        interval([[1.0, float("nan")]] * 3)


def test_binomial_interval_is_wilson_and_not_degenerate_at_the_ends():
    k, n, z = 7, 20, 1.959963984540054
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z / (1 + z * z / n) * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    est = binomial_interval(k, n)
    assert est.value == pytest.approx(0.35)
    assert (est.low, est.high) == pytest.approx((centre - half, centre + half), abs=1e-9)
    zero, full = binomial_interval(0, 20), binomial_interval(20, 20)
    assert zero.low == 0 and 0.1 < zero.high < 0.2  # not "0 % ± 0"
    assert full.high == 1 and 0.8 < full.low < 0.9
    with pytest.raises(ValueError, match="successes"):
        binomial_interval(5, 3)


def test_success_intervals_are_clustered_by_seed():
    # equal rates in every seed: no design effect, Wilson's interval of the pooled episodes
    even = clustered_rate([[1.0] * 3 + [0.0] * 7] * 3)
    pooled = binomial_interval(9, 30)
    assert (even.value, even.low, even.high) == pytest.approx((pooled.value, pooled.low, pooled.high))
    # eight of nine successes from one seed: the same 9 of 30, a much wider interval
    lumped = clustered_rate([[1.0] * 8 + [0.0] * 2, [1.0] + [0.0] * 9, [0.0] * 10])
    assert lumped.value == pytest.approx(0.3) and lumped.n == 3
    assert lumped.low < pooled.low and lumped.high > pooled.high
    # by hand: sandwich variance 3/2 · (5² + 2² + 3²) / 30² = 0.0633 against 0.3 · 0.7 / 30 = 0.007: deff 9.05
    deff = 1.5 * (25 + 4 + 9) / 900 / (0.21 / 30)
    n_eff, z = 30 / deff, 1.959963984540054
    centre = (0.3 + z * z / (2 * n_eff)) / (1 + z * z / n_eff)
    half = z / (1 + z * z / n_eff) * math.sqrt(0.21 / n_eff + z * z / (4 * n_eff**2))
    assert (lumped.low, lumped.high) == pytest.approx((centre - half, centre + half))
    nothing = clustered_rate([[0.0] * 10] * 3)
    assert nothing.value == 0 and nothing.low == 0 and 0.05 < nothing.high < 0.15  # not "0 % ± 0"


def test_holm_rejects_step_down():
    # sorted p: 0.01 <= 0.05/4 rejected; 0.03 > 0.05/3 stops: nothing after it is rejected, though 0.04 < 0.05
    assert holm([0.01, 0.04, 0.03, 0.2]).tolist() == [True, False, False, False]
    assert holm([0.001, 0.02, 0.01]).tolist() == [True, True, True]  # 0.001 <= 0.05/3, 0.01 <= 0.025, 0.02 <= 0.05
    assert holm([]).tolist() == []
