"""Interval estimates used by the reports (baselines/reports/stats.py)."""

import math

import numpy as np
import pytest

from evaaa_baselines.reports.stats import binomial_interval, interval, iqm


def test_iqm_is_the_mean_of_the_middle_half():
    assert iqm(np.arange(1, 9, dtype=float)) == pytest.approx(4.5)  # mean of 3, 4, 5, 6
    assert iqm(np.array([0.0, 10, 10, 1000])) == pytest.approx(10.0)  # the outlier does not move it


def test_bootstrap_is_stratified_by_seed():
    # each seed's episodes are redrawn from that seed alone: a seed of constant scores contributes no spread, so
    # the mean of [0]*10 + [100]*10 is 50 in every replicate (pooled resampling would spread it)
    est = interval([[0.0] * 10, [100.0] * 10], "mean")
    assert (est.value, est.low, est.high) == (50.0, 50.0, 50.0)


def test_interval_covers_the_estimate_and_narrows_with_more_episodes():
    rng = np.random.default_rng(0)
    few = interval([rng.normal(100, 20, 10), rng.normal(100, 20, 10)])
    many = interval([rng.normal(100, 20, 400), rng.normal(100, 20, 400)])
    for est in (few, many):
        assert est.low <= est.value <= est.high
    assert many.high - many.low < 0.5 * (few.high - few.low)
    assert many.low < 100 < many.high
    assert interval([[1.0, 2, 3]], seed=1) == interval([[1.0, 2, 3]], seed=1)  # seeded: reproducible


def test_interval_edge_cases_and_errors():
    assert math.isnan(interval([]).value) and interval([]).n == 0
    single = interval([[7.0]])
    assert single.value == 7.0 and math.isnan(single.low) and str(single) == "7 (n=1)"
    with pytest.raises(ValueError, match="statistic"):
        interval([[1.0, 2.0]], "median")
    with pytest.raises(ValueError, match="finite"):
        interval([[1.0, float("nan")]])


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


def test_a_seed_with_one_episode_stays_fixed_in_every_replicate():
    # a seed's single episode cannot be redrawn: the replicates pool 10 with two draws from {20, 40}, so their mean
    # (the IQM of three values cuts nothing) is 50/3, 70/3 or 30 and the interval lies within those
    est = interval([[10.0], [20.0, 40.0]], "iqm")
    assert est.value == pytest.approx(70 / 3) and est.n == 3
    assert 50 / 3 - 1e-9 <= est.low < est.high <= 30 + 1e-9
    only_singletons = interval([[10.0], [20.0]], "mean")  # nothing to redraw in any seed
    assert (only_singletons.value, only_singletons.low, only_singletons.high) == (15.0, 15.0, 15.0)
