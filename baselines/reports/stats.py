"""Interval estimates for reports: interquartile mean and mean with stratified bootstrap intervals, and binomial
intervals for success rates.

The field's reference for these estimators is rliable (Agarwal et al., 2021: "Deep RL at the edge of the statistical
precipice"): interquartile mean (IQM, the mean of the middle 50 % of scores) with percentile intervals from a
bootstrap stratified by run.  rliable 1.2 does not import beside pandas 3 (its dependency ``arch`` < 8 fails at
import; ``arch`` 8 refuses rliable's ``random_state=None``), so the same estimators are computed here with scipy:
``scipy.stats.trim_mean(x, 0.25)`` is the IQM, and ``scipy.stats.bootstrap`` over one sample per seed resamples
each seed's episodes independently, which is rliable's stratified bootstrap with the seeds as strata.  Success rates
get Wilson score intervals (``scipy.stats.binomtest``), which stay inside [0, 1] and are not degenerate at 0 % or
100 % the way "mean ± standard error" is.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats as sps

__all__ = ["Estimate", "iqm", "interval", "binomial_interval", "STATISTICS"]


def iqm(values: np.ndarray, axis: int | None = None) -> np.ndarray | float:
    """Interquartile mean: the mean of the values between the 25th and 75th percentiles (25 % cut at each end)."""
    return sps.trim_mean(values, 0.25, axis=axis)


def _mean(values: np.ndarray, axis: int | None = None) -> np.ndarray | float:
    return np.mean(values, axis=axis)


#: the statistics :func:`interval` accepts, by name
STATISTICS = {"iqm": iqm, "mean": _mean}


@dataclass(frozen=True)
class Estimate:
    """A point estimate with a confidence interval (``low``/``high`` are NaN where no interval can be given)."""

    value: float
    low: float
    high: float
    n: int

    def __str__(self) -> str:
        if math.isnan(self.value):
            return "n/a"
        if math.isnan(self.low):
            return f"{self.value:.4g} (n={self.n})"
        return f"{self.value:.4g} [{self.low:.4g}, {self.high:.4g}]"


def interval(
    samples: Sequence[Sequence[float]],
    statistic: str = "iqm",
    *,
    confidence: float = 0.95,
    resamples: int = 2000,
    seed: int = 0,
) -> Estimate:
    """``statistic`` (``"iqm"`` or ``"mean"``) of all values of ``samples`` pooled, with a percentile bootstrap
    interval stratified by sample: ``samples`` holds one sequence per seed (its episodes' scores), and every
    bootstrap replicate redraws each seed's episodes from that seed alone.  Seeded, so a report is reproducible."""
    if statistic not in STATISTICS:
        raise ValueError(f"statistic must be one of {sorted(STATISTICS)}, got {statistic!r}")
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    strata = [np.asarray(s, dtype=float).ravel() for s in samples]
    strata = [s for s in strata if s.size]
    pooled = np.concatenate(strata) if strata else np.empty(0)
    if pooled.size == 0:
        return Estimate(math.nan, math.nan, math.nan, 0)
    if not np.isfinite(pooled).all():
        raise ValueError("interval: scores must be finite")
    fn = STATISTICS[statistic]
    value = float(fn(pooled))
    if pooled.size < 2 or np.ptp(pooled) == 0:  # nothing to resample: every replicate is the point itself
        return Estimate(
            value, value if pooled.size > 1 else math.nan, value if pooled.size > 1 else math.nan, int(pooled.size)
        )

    # a seed with one episode has nothing to redraw: its score is in every replicate as it is (scipy's bootstrap
    # refuses samples of one value)
    varied = [s for s in strata if s.size > 1]
    fixed = np.concatenate([s for s in strata if s.size == 1] or [np.empty(0)])
    if all(np.ptp(s) == 0 for s in varied):  # every replicate is the point itself
        return Estimate(value, value, value, int(pooled.size))

    def pooled_statistic(*parts: np.ndarray, axis: int = -1) -> np.ndarray:
        if fixed.size:
            parts = (*parts, np.broadcast_to(fixed, (*parts[0].shape[:-1], fixed.size)))
        return fn(np.concatenate(parts, axis=axis), axis=axis)

    result = sps.bootstrap(
        tuple(varied),
        pooled_statistic,
        n_resamples=resamples,
        confidence_level=confidence,
        method="percentile",
        paired=False,
        vectorized=True,
        rng=np.random.default_rng(seed),
    )
    ci = result.confidence_interval
    return Estimate(value, float(ci.low), float(ci.high), int(pooled.size))


def binomial_interval(successes: int, trials: int, *, confidence: float = 0.95) -> Estimate:
    """Success rate ``successes / trials`` with its Wilson score interval."""
    if trials < 0 or not 0 <= successes <= max(trials, 0):
        raise ValueError(f"binomial_interval: need 0 <= successes <= trials, got {successes} of {trials}")
    if trials == 0:
        return Estimate(math.nan, math.nan, math.nan, 0)
    ci = sps.binomtest(int(successes), int(trials)).proportion_ci(confidence_level=confidence, method="wilson")
    return Estimate(successes / trials, float(ci.low), float(ci.high), int(trials))
