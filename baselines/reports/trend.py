"""The gain of a success rate across ordered training levels, with its interval and its power: the statistic of
claim (d)'s "no monotonic gain with training difficulty" (:func:`..paper.claims.testbeds_below_ceiling`).

**The gain** of an agent's mean testbed success over levels ``x_1 < … < x_L`` (their positions in the curriculum)
is the rise of the least-squares line through the levels' rates from the first level to the last:
``slope · (x_L − x_1)``, a weighted sum ``Σ w_l p_l`` of the levels' rates with ``w_l = (x_l − x̄) (x_L − x_1) /
Σ (x − x̄)²``.  It uses every level (a difference of the first and last level alone would use two of eight), and a
rise and fall of equal size gives 0: no gain.

**Its interval** (:func:`gain`): the two-stage bootstrap of :mod:`.stats`, the seeds redrawn *once per replicate
for every level* where the levels hold the same seeds (a curriculum's checkpoints of one seed are one training
run, so its levels are not independent; ``units`` names each level's seeds), then each drawn seed's episodes
redrawn from that seed's episodes on that level; the levels' seeds are redrawn apart where they are not the same
runs.  Tables written by hand, without episodes, give a normal interval from the cells' own intervals
(:func:`gain_from_intervals`; the levels taken as independent).

**Its power** (:func:`power`), normal approximation from the gain's standard error ``se`` (the replicates' standard
deviation): the chance that its 95 % interval lies at or under ``+margin`` when there is no gain,
``Φ(margin / se − z_0.975)``, and the smallest gain whose interval lies above ``+margin`` with probability
``power``, ``margin + (z_0.975 + z_power) · se``.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats as sps

from .stats import MIN_SEEDS, TooFewSeeds, pooled_replicates

__all__ = ["Gain", "gain", "gain_from_intervals", "power", "weights"]


@dataclass(frozen=True)
class Gain:
    """A gain with its interval; ``se``: its standard error; ``how``: how the interval was made."""

    value: float
    low: float
    high: float
    se: float
    how: str


def weights(positions: Sequence[float]) -> np.ndarray:
    """The weights ``w`` that make ``w @ rates`` the least-squares line's rise from the first position to the last."""
    x = np.asarray(positions, dtype=float)
    if x.size < 2 or not np.all(np.diff(x) > 0):
        raise ValueError(f"positions must be at least 2 and increasing, got {list(positions)}")
    d = x - x.mean()
    return d / float((d**2).sum()) * float(x[-1] - x[0])


def _strata(samples: Sequence[Sequence[float]]) -> list[np.ndarray]:
    return [a for a in (np.asarray(s, dtype=float).ravel() for s in samples) if a.size]


def gain(
    samples: Sequence[Sequence[Sequence[float]]],
    positions: Sequence[float],
    units: Sequence[Sequence[Hashable]] | None = None,
    *,
    confidence: float = 0.95,
    resamples: int = 2000,
    seed: int = 0,
) -> Gain:
    """The gain (module docstring) of the levels' pooled rates: ``samples[l]`` holds level ``l``'s episodes, one
    sequence of 0/1 outcomes per seed; ``positions[l]`` its place in the curriculum; ``units[l]`` the seeds' names
    in the same order (the levels that hold the same ones are redrawn together).  Raises :class:`..stats.TooFewSeeds`
    where a level has fewer than :data:`..stats.MIN_SEEDS` seeds."""
    if len(samples) != len(positions) or (units is not None and len(units) != len(samples)):
        raise ValueError("gain: samples, positions and units need one entry per level")
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    w = weights(positions)
    levels = [_strata(s) for s in samples]
    if min(len(s) for s in levels) < MIN_SEEDS:
        raise TooFewSeeds(f"a gain's interval needs at least {MIN_SEEDS} seeds a level, got {[len(s) for s in levels]}")
    value = float(w @ np.array([np.concatenate(s).mean() for s in levels]))
    rng = np.random.default_rng(seed)
    names = [list(u) for u in units] if units is not None else None
    paired = (
        names is not None
        and all(len(u) == len(s) and len(set(u)) == len(u) for u, s in zip(names, levels))
        and all(set(u) == set(names[0]) for u in names)
    )
    if paired:
        k = len(names[0])
        chosen = rng.integers(0, k, size=(resamples, k))  # the same seeds on every level of a replicate
        means = []
        for u, s in zip(names, levels):
            at = {n: i for i, n in enumerate(u)}
            means.append(pooled_replicates([s[at[n]] for n in names[0]], chosen, rng, "mean"))
    else:
        means = [pooled_replicates(s, rng.integers(0, len(s), size=(resamples, len(s))), rng, "mean") for s in levels]
    reps = w @ np.vstack(means)
    alpha = 100 * (1 - confidence) / 2
    low, high = np.percentile(reps, [alpha, 100 - alpha])
    how = "seeds redrawn together across levels" if paired else "each level's seeds redrawn apart"
    return Gain(value, float(low), float(high), float(reps.std(ddof=1)), how)


def gain_from_intervals(
    values: Sequence[float],
    lows: Sequence[float],
    highs: Sequence[float],
    positions: Sequence[float],
    *,
    confidence: float = 0.95,
) -> Gain:
    """The gain of cells given as ``value [low, high]`` (95 % intervals) without episodes: each level's standard
    error read off its interval, ``(high − low) / (2 z_0.975)``, the levels taken as independent, and a normal
    interval at ``confidence``."""
    w = weights(positions)
    v, lo, hi = (np.asarray(a, dtype=float) for a in (values, lows, highs))
    if np.isnan(lo).any() or np.isnan(hi).any():
        return Gain(float(w @ v), math.nan, math.nan, math.nan, "no interval")
    se = float(np.sqrt(((w * (hi - lo) / (2 * sps.norm.ppf(0.975))) ** 2).sum()))
    z = float(sps.norm.ppf(0.5 + confidence / 2))
    value = float(w @ v)
    return Gain(value, value - z * se, value + z * se, se, "the cells' intervals, levels independent")


def power(se: float, margin: float, *, confidence: float = 0.95, power: float = 0.8) -> tuple[float, float]:
    """For a gain of standard error ``se``: the probability that its interval lies at or under ``+margin`` when
    the true gain is 0, and the smallest true gain whose interval lies above ``+margin`` with probability
    ``power`` (normal approximation; module docstring)."""
    z = float(sps.norm.ppf(0.5 + confidence / 2))
    if not se > 0:
        return math.nan, math.nan
    return float(sps.norm.cdf(margin / se - z)), float(margin + (z + sps.norm.ppf(power)) * se)
