"""Interval estimates for reports, with seeds as the unit: interquartile mean and mean with a two-stage stratified
bootstrap over seeds and episodes within seeds, success rates with seed-clustered Wilson intervals, and the
multiple-comparison correction the claims use.

The field's reference is rliable (Agarwal et al., 2021, "Deep RL at the edge of the statistical precipice"):
interquartile mean (IQM, the mean of the middle 50 % of scores, ``scipy.stats.trim_mean(x, 0.25)``) with percentile
intervals from a stratified bootstrap.  rliable 1.2 does not import beside pandas 3 (its dependency ``arch`` < 8
fails at import), so the same estimator is computed here with numpy.

**The resampling scheme** (:func:`replicates`).  A cell holds ``k`` seeds (training runs; for reference agents,
which are not trained, each episode is its own unit), seed ``i`` with its ``m_i`` episode scores.  One bootstrap
replicate

1. draws ``k`` seeds uniformly with replacement from the ``k`` seeds (the between-seed variation: a new set of
   training runs), then
2. for every seed drawn, draws ``m_i`` episodes uniformly with replacement from that seed's own episodes (the
   within-seed variation: new evaluation episodes of the same network; episodes are never mixed across seeds), and
3. computes the statistic (IQM or mean) over all episodes of the replicate pooled.

``resamples`` replicates (2,000) from ``numpy.random.default_rng(seed)`` give the percentile interval (2.5th and
97.5th percentiles, ``numpy.percentile``'s linear interpolation).  rliable stratifies by task (levels) and redraws
runs within each; a report's cell is one task, so its strata are the seeds and step 2 adds the episodes within
them.  With fewer than :data:`MIN_SEEDS` seeds the seed-to-seed variation cannot be estimated (two draws bracket
the median only half of the time), so :func:`interval` refuses; a report's cell then shows its points (each seed's
value) and no interval, and no claim is decided on it.

**Success rates** (:func:`clustered_rate`): the share of successful episodes of all seeds pooled, with a Wilson
score interval (it stays inside [0, 1] and is not degenerate at 0 % or 100 %) computed on the effective number of
episodes ``n / deff``: ``deff`` (Kish's design effect, at least 1) is the ratio of the seed-clustered variance of
the pooled rate (the ratio estimator's sandwich variance, ``k/(k-1) · Σ (s_i − p·m_i)² / n²``) to the binomial
variance ``p(1−p)/n``.  Episodes of one seed share a network and are not independent: eight of nine successes from
one seed widen the interval, equal rates in every seed leave Wilson's as it is.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats as sps

__all__ = [
    "Estimate",
    "MIN_SEEDS",
    "TooFewSeeds",
    "iqm",
    "interval",
    "replicates",
    "binomial_interval",
    "clustered_rate",
    "holm",
    "design_effect",
    "ratio_interval",
    "drop_pvalue",
    "detectable_drop",
    "STATISTICS",
]

#: the fewest seeds (units) an interval is computed from
MIN_SEEDS = 3
Z95 = float(sps.norm.ppf(0.975))


class TooFewSeeds(ValueError):
    """An interval was asked of fewer than :data:`MIN_SEEDS` seeds."""


def iqm(values: np.ndarray, axis: int | None = None) -> np.ndarray | float:
    """Interquartile mean: the mean of the values between the 25th and 75th percentiles (25 % cut at each end)."""
    return sps.trim_mean(values, 0.25, axis=axis)


def _mean(values: np.ndarray, axis: int | None = None) -> np.ndarray | float:
    return np.mean(values, axis=axis)


#: the statistics :func:`interval` accepts, by name
STATISTICS = {"iqm": iqm, "mean": _mean}


def _ragged(statistic: str, values: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """``statistic`` of each row of ``values`` over its first ``counts[row]`` entries (rows of unequal length, as
    replicates of seeds with unequal episodes are): the rows are sorted and cut as ``trim_mean`` cuts."""
    width = values.shape[1]
    live = np.arange(width)[None, :] < counts[:, None]
    ordered = np.sort(np.where(live, values, np.inf), axis=1)
    cut = (0.25 * counts).astype(int) if statistic == "iqm" else np.zeros_like(counts)
    keep = (np.arange(width)[None, :] >= cut[:, None]) & (np.arange(width)[None, :] < (counts - cut)[:, None])
    return np.where(keep, ordered, 0.0).sum(axis=1) / keep.sum(axis=1)


def replicates(
    samples: Sequence[Sequence[float]], statistic: str = "iqm", *, resamples: int = 2000, seed: int = 0
) -> np.ndarray:
    """``resamples`` bootstrap replicates of ``statistic`` by the two-stage scheme of the module docstring: seeds
    redrawn with replacement, then each drawn seed's episodes redrawn from that seed alone."""
    if statistic not in STATISTICS:
        raise ValueError(f"statistic must be one of {sorted(STATISTICS)}, got {statistic!r}")
    strata = [np.asarray(s, dtype=float).ravel() for s in samples]
    strata = [s for s in strata if s.size]
    rng = np.random.default_rng(seed)
    chosen = rng.integers(0, len(strata), size=(resamples, len(strata)))  # step 1: seeds
    return pooled_replicates(strata, chosen, rng, statistic)


def pooled_replicates(
    strata: Sequence[np.ndarray], chosen: np.ndarray, rng: np.random.Generator, statistic: str = "iqm"
) -> np.ndarray:
    """Step 2 of the two-stage scheme for seeds already drawn: per replicate (a row of ``chosen``, indices into
    ``strata``), each drawn seed's episodes redrawn from that seed alone and pooled, then ``statistic`` of them."""
    sizes = np.array([s.size for s in strata])
    padded = np.full((len(strata), sizes.max()), np.nan)
    for i, s in enumerate(strata):
        padded[i, : s.size] = s
    resamples = chosen.shape[0]
    m = sizes[chosen]  # (resamples, k) episodes of each drawn seed
    draws = np.floor(rng.random((*chosen.shape, sizes.max())) * m[:, :, None]).astype(int)  # step 2: episodes
    values = padded[chosen[:, :, None], draws]
    live = np.arange(sizes.max())[None, None, :] < m[:, :, None]
    # pool each replicate's episodes into one row, those beyond a seed's own count left out
    flat = np.where(live, values, np.nan).reshape(resamples, -1)
    order = np.argsort(~live.reshape(resamples, -1), axis=1, kind="stable")
    flat = np.take_along_axis(flat, order, axis=1)
    return _ragged(statistic, flat, m.sum(axis=1))


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
    """``statistic`` (``"iqm"`` or ``"mean"``) of all values of ``samples`` pooled (one sequence of episode scores
    per seed), with its percentile interval from the two-stage bootstrap (module docstring).  Seeded, so a report
    is reproducible.  ``n``: the seeds.  Raises :class:`TooFewSeeds` for fewer than :data:`MIN_SEEDS` seeds."""
    if statistic not in STATISTICS:
        raise ValueError(f"statistic must be one of {sorted(STATISTICS)}, got {statistic!r}")
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    strata = [np.asarray(s, dtype=float).ravel() for s in samples]
    strata = [s for s in strata if s.size]
    if len(strata) < MIN_SEEDS:
        raise TooFewSeeds(
            f"an interval needs at least {MIN_SEEDS} seeds, got {len(strata)}: show the seeds' values instead"
        )
    pooled = np.concatenate(strata)
    if not np.isfinite(pooled).all():
        raise ValueError("interval: scores must be finite")
    value = float(STATISTICS[statistic](pooled))
    reps = replicates(strata, statistic, resamples=resamples, seed=seed)
    alpha = 100 * (1 - confidence) / 2
    low, high = np.percentile(reps, [alpha, 100 - alpha])
    return Estimate(value, float(low), float(high), len(strata))


def _wilson(p: float, n: float, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval of a share ``p`` of ``n`` (possibly fractional: an effective size) trials."""
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z / denom * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return max(0.0, centre - half), min(1.0, centre + half)


def binomial_interval(successes: int, trials: int, *, confidence: float = 0.95) -> Estimate:
    """Success rate ``successes / trials`` of independent trials (a reference agent's episodes) with its Wilson
    score interval."""
    if trials < 0 or not 0 <= successes <= max(trials, 0):
        raise ValueError(f"binomial_interval: need 0 <= successes <= trials, got {successes} of {trials}")
    if trials == 0:
        return Estimate(math.nan, math.nan, math.nan, 0)
    ci = sps.binomtest(int(successes), int(trials)).proportion_ci(confidence_level=confidence, method="wilson")
    return Estimate(successes / trials, float(ci.low), float(ci.high), int(trials))


def clustered_rate(samples: Sequence[Sequence[float]], *, confidence: float = 0.95) -> Estimate:
    """Success rate of all episodes of ``samples`` (one sequence of 0/1 outcomes per seed) pooled, with a Wilson
    interval on the effective number of episodes (design effect of the seeds; module docstring).  ``n``: the
    seeds.  Raises :class:`TooFewSeeds` for fewer than :data:`MIN_SEEDS` seeds."""
    strata = [np.asarray(s, dtype=float).ravel() for s in samples]
    strata = [s for s in strata if s.size]
    if len(strata) < MIN_SEEDS:
        raise TooFewSeeds(
            f"an interval needs at least {MIN_SEEDS} seeds, got {len(strata)}: show the seeds' values instead"
        )
    n = float(sum(x.size for x in strata))
    p = float(sum(x.sum() for x in strata) / n)
    low, high = _wilson(p, n / design_effect(strata), float(sps.norm.ppf(0.5 + confidence / 2)))
    return Estimate(p, low, high, len(strata))


def design_effect(samples: Sequence[Sequence[float]]) -> float:
    """Kish's design effect (at least 1) of the pooled success rate of ``samples`` (one sequence of 0/1 outcomes per
    seed): the seed-clustered (sandwich) variance of the pooled rate over the binomial ``p(1−p)/n``; 1 where every
    outcome is the same, or for one seed.  ``n / design_effect`` is the effective number of episodes."""
    strata = [np.asarray(x, dtype=float).ravel() for x in samples]
    strata = [x for x in strata if x.size]
    s = np.array([x.sum() for x in strata])
    m = np.array([x.size for x in strata], dtype=float)
    n, k = m.sum(), len(strata)
    if k < 2 or not n:
        return 1.0
    p = float(s.sum() / n)
    if not 0 < p < 1:
        return 1.0
    clustered = k / (k - 1) * float(((s - p * m) ** 2).sum()) / n**2
    return max(1.0, clustered / (p * (1 - p) / n))


def ratio_interval(
    a: Sequence[Sequence[float]],
    b: Sequence[Sequence[float]],
    statistic: str = "iqm",
    *,
    confidence: float = 0.95,
    resamples: int = 2000,
    seed: int = 0,
) -> Estimate:
    """``statistic`` (IQM for survival, mean for success as 0/1) of ``a`` over that of ``b`` (each: one sequence of
    episode scores per seed) with the percentile interval of the ratio of independent two-stage bootstrap replicates
    of each (:func:`replicates`; ``b`` drawn from another stream; a replicate of ``b`` at 0 gives an infinite
    ratio).  ``n``: the fewer seeds.  Raises :class:`TooFewSeeds` under :data:`MIN_SEEDS` seeds on either side."""
    sa = [np.asarray(s, dtype=float).ravel() for s in a]
    sb = [np.asarray(s, dtype=float).ravel() for s in b]
    sa, sb = [s for s in sa if s.size], [s for s in sb if s.size]
    if min(len(sa), len(sb)) < MIN_SEEDS:
        raise TooFewSeeds(f"a ratio's interval needs at least {MIN_SEEDS} seeds a side, got {len(sa)} and {len(sb)}")
    stat = STATISTICS[statistic]
    with np.errstate(divide="ignore", invalid="ignore"):
        value = float(np.divide(stat(np.concatenate(sa)), stat(np.concatenate(sb))))
        ra = replicates(sa, statistic, resamples=resamples, seed=seed)
        rb = replicates(sb, statistic, resamples=resamples, seed=seed + 1)
        ratios = np.where(rb > 0, ra / np.where(rb > 0, rb, 1.0), np.where(ra > 0, np.inf, 1.0))
    alpha = 100 * (1 - confidence) / 2
    low, high = np.percentile(ratios, [alpha, 100 - alpha])
    return Estimate(value, float(low), float(high), min(len(sa), len(sb)))


def drop_pvalue(p1: float, n1: float, p2: float, n2: float) -> float:
    """One-sided p-value that a success rate fell from ``p1`` (of ``n1`` effective episodes) to ``p2`` (of ``n2``):
    the two-proportion z-test with the pooled rate (``scipy.stats.norm.sf`` of z); 1 where both rates are 0 or 1."""
    pooled = (p1 * n1 + p2 * n2) / (n1 + n2)
    var = pooled * (1 - pooled) * (1 / n1 + 1 / n2)
    if var <= 0:
        return 1.0
    return float(sps.norm.sf((p1 - p2) / math.sqrt(var)))


def detectable_drop(rate: float, n: float, alpha: float, power: float = 0.8) -> float:
    """The smallest fall of a success rate from ``rate`` that the one-sided test of :func:`drop_pvalue` at level
    ``alpha`` finds with probability ``power``, both levels of ``n`` effective episodes (normal approximation:
    ``(z_{1−alpha} + z_power) · sqrt(2 rate (1 − rate) / n)``)."""
    rate = min(max(rate, 1e-3), 1 - 1e-3)
    return float((sps.norm.isf(alpha) + sps.norm.ppf(power)) * math.sqrt(2 * rate * (1 - rate) / n))


def holm(pvalues: Sequence[float], alpha: float = 0.05) -> np.ndarray:
    """Holm's step-down procedure: which of ``pvalues`` are rejected at family-wise error ``alpha`` (the i-th
    smallest p is compared with alpha / (m − i); the first that fails stops the rejections)."""
    p = np.asarray(pvalues, dtype=float)
    order = np.argsort(p, kind="stable")
    reject = np.zeros(p.size, dtype=bool)
    for rank, i in enumerate(order):
        if not p[i] <= alpha / (p.size - rank):
            break
        reject[i] = True
    return reject
