"""The gain of a rate across ordered training levels (baselines/reports/trend.py), claim (d)'s statistic: the
least-squares line's rise computed by hand, the paired bootstrap narrower than the unpaired one where a seed's
levels move together, the interval from cells' intervals and the power, each against numbers worked out here."""

import numpy as np
import pytest

from evaaa_baselines.reports import trend
from evaaa_baselines.reports.stats import TooFewSeeds


def test_the_gain_is_the_least_squares_line_rise_from_the_first_level_to_the_last():
    # positions 0, 1, 3 (a level left out): x̄ = 4/3, d = (−4/3, −1/3, 5/3), Σ d² = 42/9; rates 0.1, 0.3, 0.2:
    # slope = Σ d p / Σ d² = (−0.1333 − 0.1 + 0.3333) / 4.667 = 0.02143, rise over 3 positions = 0.0643
    w = trend.weights([0, 1, 3])
    assert w @ np.array([0.1, 0.3, 0.2]) == pytest.approx(0.0643, abs=1e-4)
    assert w @ np.ones(3) == pytest.approx(0.0)  # a flat rate gains nothing
    with pytest.raises(ValueError, match="increasing"):
        trend.weights([0, 2, 1])


def _levels(rates_per_seed, episodes=100):
    """Each seed's episodes on each level: ``rates_per_seed[s][l]`` of ``episodes`` successes, exactly."""
    levels = len(rates_per_seed[0])
    return [
        [tuple([1.0] * round(r[lv] * episodes) + [0.0] * (episodes - round(r[lv] * episodes))) for r in rates_per_seed]
        for lv in range(levels)
    ]


def test_seeds_paired_across_levels_give_a_narrower_interval_where_a_seed_is_good_on_every_level():
    # three seeds whose rates differ by a seed effect (0.1, 0.3, 0.5) and rise by 0.05 a level on each: the gain
    # over four levels is 0.15 whatever the seed; redrawn together the seeds' effect cancels in the line's rise,
    # redrawn apart it does not
    rates = [[b + 0.05 * lv for lv in range(4)] for b in (0.1, 0.3, 0.5)]
    samples = _levels(rates)
    units = [("s0", "s1", "s2")] * 4
    paired = trend.gain(samples, [0, 1, 2, 3], units)
    apart = trend.gain(samples, [0, 1, 2, 3])
    assert paired.value == pytest.approx(0.15) and apart.value == pytest.approx(0.15)
    assert paired.low <= 0.15 <= paired.high
    assert paired.se < apart.se / 2 and paired.how.startswith("seeds redrawn together")
    # the same seeds listed in another order on one level are still paired by name
    shuffled = [s if lv != 2 else s[::-1] for lv, s in enumerate(samples)]
    names = [u if lv != 2 else u[::-1] for lv, u in enumerate(units)]
    again = trend.gain(shuffled, [0, 1, 2, 3], names)
    assert again.se == pytest.approx(paired.se, rel=0.2) and again.how == paired.how
    with pytest.raises(TooFewSeeds):
        trend.gain([s[:2] for s in samples], [0, 1, 2, 3])


def test_the_gain_from_cells_intervals_and_its_power_by_hand():
    # three levels at 0, 1, 2: w = (−1, 0, 1); each ± 0.0392 (se 0.02): the gain's se sqrt(2) · 0.02 = 0.0283
    g = trend.gain_from_intervals([0.2, 0.25, 0.3], [0.1608] * 3, [0.2392] * 3, [0, 1, 2])
    assert g.value == pytest.approx(0.1) and g.se == pytest.approx(0.0283, abs=1e-4)
    assert (g.low, g.high) == pytest.approx((0.1 - 1.96 * 0.0283, 0.1 + 1.96 * 0.0283), abs=1e-3)
    # with no gain, P(interval ≤ +0.1) = Φ(0.1 / 0.0283 − 1.96) = Φ(1.575) = 0.942; the gain found above +0.1 with
    # 80 %: 0.1 + (1.96 + 0.8416) · 0.0283 = 0.179
    p_flat, smallest = trend.power(g.se, 0.1)
    assert p_flat == pytest.approx(0.942, abs=2e-3) and smallest == pytest.approx(0.179, abs=1e-3)
