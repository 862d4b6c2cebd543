"""A report's numbers: each run's survival per stage and training curve, each run's evaluation scores, and the
statistics of a table cell over seeds (or over episodes and participants for reference agents).

A survival cell is the interquartile mean (IQM) of the episodes with its 95 % percentile bootstrap interval
(episodes redrawn within each seed: seeds are the strata), beside the mean over seeds of each seed's value ± the
standard error across seeds (no error with one seed); where a seed has only one number (the mean of its last
evaluation in ``eval.csv``) the IQM and its bootstrap are over the seeds' numbers.  A success rate is the share of
successful episodes of all seeds pooled, with its Wilson score interval.  The estimators are in :mod:`.stats`.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
import pandas as pd

from .load import RunRecord
from .stats import binomial_interval, interval


def standard_error(values: pd.Series) -> float:
    """Standard error of the mean of ``values`` (ddof 1); NaN for fewer than two."""
    n = values.count()
    return float(values.std(ddof=1) / np.sqrt(n)) if n > 1 else float("nan")


def mean_se(values: Iterable[float]) -> tuple[float, float, int]:
    """Mean, standard error of the mean (ddof 1; NaN for one value) and count of the non-NaN values."""
    s = pd.Series(list(values), dtype=float).dropna()
    return (float(s.mean()) if len(s) else float("nan")), standard_error(s), int(len(s))


def final_survival(runs: Sequence[RunRecord], source: str = "eval", window: int = 20) -> pd.DataFrame:
    """One row per finished stage of every run: the survival the stage ended with.

    ``source="eval"``: the stage's last evaluation (``eval.csv``: episodes at the stage's end, deterministic or,
    with ``eval.sample``, sampled), or, in a stage without evaluations, the mean survival of its last ``window``
    training episodes; ``"train"``: always the training episodes.  The ``source`` column says which.
    """
    rows = []
    for r in runs:
        if not r.usable:
            continue
        for index, level, _ in r.stages:
            if index not in r.complete:
                continue
            value, used, scores, episodes = float("nan"), "none", (), 0
            ev = r.evals[r.evals["stage"] == index] if r.evals is not None else None
            if source == "eval" and ev is not None and len(ev):
                last = ev.sort_values("env_steps", kind="stable").iloc[-1]
                value, used = float(last["survival_mean"]), "eval"
                # eval.csv keeps each evaluation's mean, not its episodes: the seed contributes that one number
                scores = (value,)
                episodes = int(last["episodes"]) if "episodes" in last and pd.notna(last["episodes"]) else 1
            else:
                eps = r.episodes[r.episodes["stage"] == index]
                if len(eps):
                    scores = tuple(float(v) for v in eps["steps"].iloc[-window:])
                    value, used, episodes = float(np.mean(scores)), "train", len(scores)
            rows.append(
                {
                    "run": r.dir,
                    "stage": index,
                    "level": level,
                    "survival": value,
                    "source": used,
                    "last": index == r.stages[-1][0],
                    "scores": scores,
                    "episodes": episodes,
                }
            )
    return pd.DataFrame(rows, columns=["run", "stage", "level", "survival", "source", "last", "scores", "episodes"])


def curves(runs: Sequence[RunRecord], bins: int = 20) -> pd.DataFrame:
    """Training curves: survival of the training episodes against env steps (summed over stages), per run in
    ``bins`` equal bins of its group's longest budget (bin i holds episodes ending in (i·w, (i+1)·w]; the first
    also holds step 0); columns run, bin, steps (bin centre), survival (mean of the run's episodes in the bin),
    scores (those episodes' survival) and episodes (how many)."""
    rows = []
    for r in runs:
        if not r.usable or r.episodes is None or not len(r.episodes) or not r.total:
            continue
        x = np.array([r.offset(int(s)) + int(e) for s, e in zip(r.episodes["stage"], r.episodes["env_steps"])])
        width = r.total / bins
        b = np.clip(np.ceil(x / width).astype(int) - 1, 0, bins - 1)
        survival = r.episodes["steps"].to_numpy(dtype=float)
        for i in np.unique(b):
            scores = tuple(survival[b == i].tolist())
            rows.append(
                {
                    "run": r.dir,
                    "bin": int(i),
                    "steps": (i + 0.5) * width,
                    "survival": float(np.mean(scores)),
                    "scores": scores,
                    "episodes": len(scores),
                }
            )
    return pd.DataFrame(rows, columns=["run", "bin", "steps", "survival", "scores", "episodes"])


#: Columns of the statistics frames (:func:`across_seeds`), after the grouping columns.  ``statistic`` says what
#: ``value`` and its interval ``low``..``high`` are: ``iqm`` (survival: interquartile mean, 95 % percentile
#: bootstrap interval) or ``rate`` (success: pooled share of episodes, 95 % Wilson interval); ``mean`` ± ``se``: the
#: mean over units (seeds, or episodes or participants for reference agents) and the standard error across them;
#: ``n``: units, ``episodes``: episodes behind the numbers.
STAT_COLUMNS = ("value", "low", "high", "statistic", "mean", "se", "n", "episodes", "unit")


def estimate(
    samples: Sequence[Sequence[float]], success: bool = False, seed: int = 0, episodes: int | None = None
) -> dict[str, Any]:
    """The statistics of one table cell from ``samples``: one sequence of episode scores per unit (seed,
    participant; a success is 1.0, a failure 0.0).  Units that gave one number each (a seed's evaluation mean) are
    bootstrapped as one stratum: there is nothing to redraw within a unit.  ``episodes``: the episodes behind the
    scores, where a score is itself a mean (default: one per score)."""
    samples = [np.asarray(s, dtype=float).ravel() for s in samples]
    samples = [s for s in samples if s.size]
    scored = int(sum(s.size for s in samples))
    episodes = scored if episodes is None else int(episodes)
    m, se, n = mean_se(s.mean() for s in samples)
    if success:
        est = binomial_interval(int(round(sum(s.sum() for s in samples))), scored)
        return {
            "value": est.value,
            "low": est.low,
            "high": est.high,
            "statistic": "rate",
            "mean": m,
            "se": se,
            "n": n,
            "episodes": episodes,
        }
    strata = [np.concatenate(samples)] if samples and all(s.size == 1 for s in samples) else samples
    est = interval(strata, "iqm", seed=seed)
    return {
        "value": est.value,
        "low": est.low,
        "high": est.high,
        "statistic": "iqm",
        "mean": m,
        "se": se,
        "n": n,
        "episodes": episodes,
    }


def across_seeds(
    values: pd.DataFrame, by: Sequence[str], value: str, *, success: bool = False, unit: str = "seeds"
) -> pd.DataFrame:
    """Per group of ``by``: the statistics of :data:`STAT_COLUMNS` over the group's rows (one row per seed, its
    episodes' scores in a ``scores`` column, or ``value`` alone where there is none)."""
    out = []
    for key, part in values.groupby(list(by), sort=False, dropna=False):
        if "scores" in part:
            samples = [s if len(s) else () for s in part["scores"]]
        else:
            samples = [(v,) for v in part[value].astype(float).dropna()]
        est = estimate(samples, success, episodes=int(part["episodes"].sum()) if "episodes" in part else None)
        out.append({**dict(zip(by, key if isinstance(key, tuple) else (key,))), **est, "unit": unit})
    return pd.DataFrame(out, columns=[*by, *STAT_COLUMNS])


def per_run(ckpts: pd.DataFrame, value: str, by: Sequence[str] = ("run", "level")) -> pd.DataFrame:
    """Each run's mean of ``value`` (success as 0/1, or steps) per ``by``: one value per seed, with its episodes'
    values in ``scores``."""
    grouped = ckpts.assign(_v=ckpts[value].astype(float)).groupby(list(by), sort=False)["_v"]
    return grouped.agg(**{value: "mean", "scores": lambda v: tuple(v.dropna())}).reset_index()


def reference_stats(refs: pd.DataFrame, value: str) -> pd.DataFrame:
    """Per (policy, level) the statistics (:data:`STAT_COLUMNS`) of ``value`` (``success`` or ``steps``) for
    reference agents: over episodes, or with participants as units for human rows of several participants."""
    out = []
    for (policy, level), part in refs.groupby(["policy", "level"], sort=False):
        vals, unit, samples = part[value].astype(float), "episodes", None
        if (
            "participant" in part
            and part["participant"].astype(str).str.len().gt(0).all()
            and part["participant"].nunique() > 1
        ):
            unit = "participants"
            samples = [tuple(v.dropna()) for _, v in part.assign(_v=vals).groupby("participant")["_v"]]
        est = estimate(samples if samples is not None else [tuple(vals.dropna())], success=value == "success")
        if unit == "episodes":  # mean ± se over episodes, not over the one stratum
            est |= dict(zip(("mean", "se", "n"), mean_se(vals)))
        out.append({"label": policy, "level": level, **est, "unit": unit})
    return pd.DataFrame(out, columns=["label", "level", *STAT_COLUMNS])
