"""A report's numbers: each run's survival per stage (from per-episode evaluations where there are any) and training
curve, and the statistics of a table cell over seeds (or over episodes and participants for reference agents).

A cell's unit is the seed (a training run): a survival cell is the interquartile mean (IQM) of the seeds' episodes
pooled with its 95 % interval from the two-stage bootstrap of :mod:`.stats` (seeds redrawn, then episodes within
each), beside the mean over seeds of each seed's mean ± the standard error across seeds; a success cell is the share
of successful episodes pooled with its seed-clustered Wilson interval.  With fewer than three seeds a cell has no
interval and no standard error: it carries its points (each seed's mean) instead.  A reference agent is one fixed
policy, so its episodes are its units.  Where a seed has only an evaluation's mean (``eval.csv`` files written
before evaluations kept one row per episode), the cell is over those means and says so (``means_only``).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from .load import BEST_MODEL_FILE, MODEL_FILE, RunRecord
from .stats import MIN_SEEDS, binomial_interval, clustered_rate, interval, iqm


def standard_error(values: pd.Series) -> float:
    """Standard error of the mean of ``values`` (ddof 1); NaN for fewer than two."""
    n = values.count()
    return float(values.std(ddof=1) / np.sqrt(n)) if n > 1 else float("nan")


def mean_se(values: Iterable[float]) -> tuple[float, float, int]:
    """Mean, standard error of the mean (ddof 1; NaN for one value) and count of the non-NaN values."""
    s = pd.Series(list(values), dtype=float).dropna()
    return (float(s.mean()) if len(s) else float("nan")), standard_error(s), int(len(s))


#: columns of :func:`final_survival`
FINAL_COLUMNS = [
    "run",
    "stage",
    "level",
    "survival",
    "source",
    "last",
    "scores",
    "episodes",
    "acting",
    "worlds",
    "means_only",
    "eaten",
]

#: a survival cell whose episodes reach the step cap more often than this: its IQM is censored, a lower bound
CAPPED_SHARE = 0.25


@cache
def level_cap(level: str) -> float:
    """The step cap (``episode.max_steps``) of ``level``; NaN for a name that is no level."""
    from evaaa.level_files import load_level

    try:
        return float(load_level(level).episode.max_steps)
    except Exception:  # noqa: BLE001 - a group that is not a level (a testbed mean, a label)
        return float("nan")


def _checkpoint_rank(policy: str) -> int:
    """Which evaluated network stands for a stage: its final model, else its best, else the latest state."""
    name = Path(policy).name
    return 0 if MODEL_FILE.match(name) else 1 if BEST_MODEL_FILE.match(name) else 2


def final_survival(
    runs: Sequence[RunRecord], source: str = "eval", window: int = 20, checkpoints: pd.DataFrame | None = None
) -> pd.DataFrame:
    """One row per finished stage of every run (and per acting mode): the survival the stage ended with, with its
    episodes' scores.

    ``source="eval"``: the stage's network evaluated by evaluate.py on the stage's level (``checkpoints``: the
    checkpoint episodes of :func:`.load.attach`; the final model preferred), else the stage's last in-training
    evaluation (``eval.csv``: its episodes, or only its mean in files written before evaluations kept episodes),
    else the mean survival of its last ``window`` training episodes; ``"train"``: always the training episodes.
    The ``source`` column says which; ``acting`` and ``worlds`` say how the network acted and on which worlds."""
    rows = []
    ck = checkpoints if checkpoints is not None and len(checkpoints) else None
    for r in runs:
        if not r.usable:
            continue
        mine = ck[ck["run"] == r.dir] if ck is not None else None
        for index, level, _ in r.stages:
            if index not in r.complete:
                continue
            base = {"run": r.dir, "stage": index, "level": level, "last": index == r.stages[-1][0]}
            found = []
            if source == "eval" and mine is not None:
                hits = mine[(mine["ckpt_stage"] == index) & (mine["level"] == level)]
                if len(hits):
                    best = min(hits["policy"].unique(), key=_checkpoint_rank)
                    for acting, part in hits[hits["policy"] == best].groupby("acting", sort=False):
                        scores = tuple(part["steps"].astype(float))
                        eaten = (
                            tuple(part["food_eaten"].astype(float) + part["water_eaten"].astype(float))
                            if {"food_eaten", "water_eaten"} <= set(part)
                            else ()
                        )
                        found.append(
                            base
                            | {
                                "survival": float(np.mean(scores)),
                                "source": "evaluate.py",
                                "scores": scores,
                                "episodes": len(scores),
                                "acting": acting,
                                "worlds": " / ".join(dict.fromkeys(part["worlds"])),
                                "means_only": False,
                                "eaten": eaten,
                            }
                        )
            ev = r.evals[r.evals["stage"] == index] if r.evals is not None else None
            if source == "eval" and not found and ev is not None and len(ev):
                last = ev[ev["env_steps"] == ev["env_steps"].max()]
                if r.eval_means_only:
                    value = float(last["survival_mean"].iloc[-1])
                    n = (
                        int(last["episodes"].iloc[-1])
                        if "episodes" in last and pd.notna(last["episodes"].iloc[-1])
                        else 1
                    )
                    found.append(
                        base
                        | {
                            "survival": value,
                            "source": "eval.csv (means only)",
                            "scores": (value,),
                            "episodes": n,
                            "acting": r.eval_acting,
                            "worlds": r.eval_worlds,
                            "means_only": True,
                        }
                    )
                else:
                    for acting, part in last.groupby("acting", sort=False):
                        scores = tuple(part["steps"].astype(float))
                        found.append(
                            base
                            | {
                                "survival": float(np.mean(scores)),
                                "source": "eval.csv",
                                "scores": scores,
                                "episodes": len(scores),
                                "acting": acting,
                                "worlds": " / ".join(dict.fromkeys(part["worlds"].astype(str))),
                                "means_only": False,
                            }
                        )
            if not found and r.episodes is not None:
                eps = r.episodes[r.episodes["stage"] == index]
                if len(eps):
                    scores = tuple(float(v) for v in eps["steps"].iloc[-window:])
                    found.append(
                        base
                        | {
                            "survival": float(np.mean(scores)),
                            "source": "training episodes",
                            "scores": scores,
                            "episodes": len(scores),
                            "acting": "exploring (training)",
                            "worlds": "training worlds",
                            "means_only": False,
                        }
                    )
            if not found:
                found.append(
                    base
                    | {
                        "survival": float("nan"),
                        "source": "none",
                        "scores": (),
                        "episodes": 0,
                        "acting": "",
                        "worlds": "",
                        "means_only": False,
                    }
                )
            rows += found
    return pd.DataFrame(rows, columns=FINAL_COLUMNS)


def curves(runs: Sequence[RunRecord], bins: int = 20) -> pd.DataFrame:
    """Training curves: survival of the training episodes against env steps (summed over stages), per run in
    ``bins`` equal bins of its group's longest budget (bin i holds episodes ending in (i·w, (i+1)·w]; the first
    also holds step 0; compute-bound runs: of the furthest env steps their group's runs reached); columns run, bin, steps (bin centre), survival (mean of the run's episodes in the bin),
    scores (those episodes' survival) and episodes (how many)."""
    rows = []
    # compute-bound runs: the grid spans the env steps the group's runs reached (their step budget is none), one grid
    # for the seeds of a group so that their bins pool
    reached: dict[tuple, int] = {}
    for r in runs:
        if r.usable and r.cpu_budget is not None:
            key = (r.algo, r.modality, r.reward, r.extras, r.training)
            reached[key] = max(reached.get(key, 0), r.steps)
    for r in runs:
        if not r.usable or r.episodes is None or not len(r.episodes) or not r.total:
            continue
        x = np.array([r.offset(int(s)) + int(e) for s, e in zip(r.episodes["stage"], r.episodes["env_steps"])])
        span = r.total if r.cpu_budget is None else reached[(r.algo, r.modality, r.reward, r.extras, r.training)]
        width = max(span, 1) / bins
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
                    "acting": "exploring (training)",
                    "worlds": "training worlds",
                }
            )
    return pd.DataFrame(rows, columns=["run", "bin", "steps", "survival", "scores", "episodes", "acting", "worlds"])


def evaluation_points(runs: Sequence[RunRecord]) -> pd.DataFrame:
    """Every in-training evaluation of every run (``eval.csv``): its env steps summed over stages, the survival of
    its episodes in ``scores`` (one row per episode), or of ``eval.csv`` files of the older format its mean alone
    (``means_only``), with its acting mode and worlds; ``cpu_minutes``: the CPU time its stage had taken (NaN in
    files written before ``eval.csv`` kept it)."""
    rows = []
    for r in runs:
        if not r.usable or r.evals is None or not len(r.evals):
            continue
        for (stage, steps, acting), part in r.evals.groupby(["stage", "env_steps", "acting"], sort=True):
            x = r.offset(int(stage)) + int(steps)
            if r.eval_means_only:
                scores = tuple(float(v) for v in part["survival_mean"])
                n = int(part["episodes"].sum()) if "episodes" in part else len(scores)
            else:
                scores, n = tuple(part["steps"].astype(float)), len(part)
            cpu = pd.to_numeric(part["cpu_seconds"], errors="coerce").max() if "cpu_seconds" in part else np.nan
            rows.append(
                {
                    "run": r.dir,
                    "stage": int(stage),
                    "steps": x,
                    "cpu_minutes": float(cpu) / 60.0,
                    "survival": float(np.mean(scores)),
                    "scores": scores,
                    "episodes": n,
                    "means_only": r.eval_means_only,
                    "acting": acting,
                    "worlds": " / ".join(dict.fromkeys(part["worlds"].astype(str))),
                    "source": "eval.csv",
                }
            )
    return pd.DataFrame(
        rows,
        columns=[
            "run",
            "stage",
            "steps",
            "cpu_minutes",
            "survival",
            "scores",
            "episodes",
            "means_only",
            "acting",
            "worlds",
            "source",
        ],
    )


#: Columns of the statistics frames (:func:`across_seeds`), after the grouping columns.  ``statistic`` says what
#: ``value`` and its interval ``low``..``high`` are: ``iqm`` (survival: interquartile mean, 95 % two-stage bootstrap
#: interval) or ``rate`` (success: pooled share of episodes, 95 % seed-clustered Wilson interval); ``mean`` ± ``se``:
#: the mean over units (seeds, or episodes or participants for reference agents) and the standard error across them
#: (none under three seeds); ``n``: units, ``episodes``: episodes behind the numbers; ``points``: each seed's value
#: (where there are fewer than three seeds, the cell's only spread); ``means_only``: the seeds gave evaluation means,
#: not episodes; ``acting``, ``worlds``, ``source``: how the networks acted, on which worlds, from which files.
#: columns :func:`across_seeds` adds after :data:`STAT_COLUMNS`: ``at_cap``, the share of a survival cell's episodes
#: at its level's step cap (NaN for success and where no cap is known); ``intake``, food and water eaten per 1,000
#: decisions (all the cell's episodes pooled; NaN where the episodes did not record it); ``samples``, each seed's
#: episode scores (for the claims' ratio intervals; not written to the CSV files)
EXTRA_COLUMNS = ("at_cap", "intake", "samples")
STAT_COLUMNS = (
    "value",
    "low",
    "high",
    "statistic",
    "mean",
    "se",
    "n",
    "episodes",
    "unit",
    "points",
    "means_only",
    "acting",
    "worlds",
    "source",
)


def estimate(
    samples: Sequence[Sequence[float]],
    success: bool = False,
    seed: int = 0,
    episodes: int | None = None,
    unit: str = "seeds",
    means_only: bool = False,
) -> dict[str, Any]:
    """The statistics of one table cell from ``samples``: one sequence of episode scores per unit (seed,
    participant; a success is 1.0, a failure 0.0); ``unit="episodes"``: one sequence whose every episode is a unit
    (a reference agent).  Under three units: no interval, the units' values as ``points``.  ``episodes``: the
    episodes behind the scores, where a score is itself a mean (``means_only``)."""
    samples = [np.asarray(s, dtype=float).ravel() for s in samples]
    samples = [s for s in samples if s.size]
    if unit == "episodes":
        samples = [np.concatenate(samples)] if samples else []
        units = [s[i : i + 1] for s in samples for i in range(s.size)]
    else:
        units = samples
    scored = int(sum(s.size for s in samples))
    episodes = scored if episodes is None else int(episodes)
    nan = float("nan")
    out = {
        "value": nan,
        "low": nan,
        "high": nan,
        "statistic": "rate" if success else "iqm",
        "mean": nan,
        "se": nan,
        "n": len(units),
        "episodes": episodes,
        "points": (),
        "means_only": means_only,
    }
    if not units:
        return out
    pooled = np.concatenate(samples)
    m, se, _ = mean_se(s.mean() for s in units)
    out["value"] = float(pooled.mean()) if success else float(iqm(pooled))
    out["mean"] = m
    if len(units) < MIN_SEEDS:
        out["points"] = tuple(float(s.mean()) for s in units)
        return out
    out["se"] = se
    if success:
        est = (
            binomial_interval(int(round(pooled.sum())), int(pooled.size))
            if unit == "episodes"
            else clustered_rate(units)
        )
    else:
        est = interval(units, "iqm", seed=seed)
    out["low"], out["high"] = est.low, est.high
    return out


def _joined(values: pd.Series) -> str:
    return " / ".join(str(v) for v in dict.fromkeys(values.fillna("").astype(str)) if v)


def censoring(part: pd.DataFrame, samples: Sequence[Sequence[float]], cap: float | None) -> tuple[float, float]:
    """(share of the episodes at the step cap, food and water eaten per 1,000 decisions) of a survival cell: the
    cap is ``cap``, else that of the rows' one ``level``; NaN where neither is known or nothing was eaten counted."""
    pooled = np.concatenate([np.asarray(s, dtype=float).ravel() for s in samples]) if samples else np.array([])
    if cap is None and "level" in part and part["level"].nunique() == 1:
        cap = level_cap(str(part["level"].iloc[0]))
    share = float((pooled >= cap).mean()) if cap is not None and not np.isnan(cap) and pooled.size else float("nan")
    intake = float("nan")
    if "eaten" in part:
        eaten = [e for e in part["eaten"] if isinstance(e, tuple) and len(e)]
        if eaten and len(eaten) == len(part) and pooled.sum() > 0:
            intake = 1000.0 * float(sum(sum(e) for e in eaten)) / float(pooled.sum())
    return share, intake


def across_seeds(
    values: pd.DataFrame,
    by: Sequence[str],
    value: str,
    *,
    success: bool = False,
    unit: str = "seeds",
    cap: float | None = None,
) -> pd.DataFrame:
    """Per group of ``by``: the statistics of :data:`STAT_COLUMNS` over the group's rows (one row per seed, its
    episodes' scores in a ``scores`` column, or ``value`` alone where there is none); ``acting``, ``worlds`` and
    ``source`` name what the rows say (joined where they differ); then :data:`EXTRA_COLUMNS` (survival: the share
    at the step cap, ``cap`` or the level's, and the intake)."""
    out = []
    for key, part in values.groupby(list(by), sort=False, dropna=False):
        if "scores" in part:
            samples = [s if len(s) else () for s in part["scores"]]
        else:
            samples = [(v,) for v in part[value].astype(float).dropna()]
        means_only = bool(part["means_only"].any()) if "means_only" in part else False
        est = estimate(
            samples,
            success,
            episodes=int(part["episodes"].sum()) if "episodes" in part else None,
            unit=unit,
            means_only=means_only,
        )
        named = {c: _joined(part[c]) if c in part else "" for c in ("acting", "worlds", "source")}
        share, intake = (
            censoring(part, samples, cap) if not success and not means_only else (float("nan"), float("nan"))
        )
        extra = {"at_cap": share, "intake": intake, "samples": tuple(tuple(map(float, s)) for s in samples)}
        out.append({**dict(zip(by, key if isinstance(key, tuple) else (key,))), **est, "unit": unit, **named, **extra})
    return pd.DataFrame(out, columns=[*by, *STAT_COLUMNS, *EXTRA_COLUMNS])


def per_run(ckpts: pd.DataFrame, value: str, by: Sequence[str] = ("run", "level")) -> pd.DataFrame:
    """Each run's mean of ``value`` (success as 0/1, or steps) per ``by`` (and acting mode): one value per seed,
    with its episodes' values in ``scores`` and the episodes' acting mode and worlds."""
    keys = list(dict.fromkeys([*by, "acting"]))
    grouped = ckpts.assign(_v=ckpts[value].astype(float)).groupby(keys, sort=False)
    out = grouped["_v"].agg(**{value: "mean", "scores": lambda v: tuple(v.dropna())})
    out["worlds"] = grouped["worlds"].agg(_joined)
    if value == "steps" and {"food_eaten", "water_eaten"} <= set(ckpts):
        eaten = ckpts["food_eaten"].astype(float) + ckpts["water_eaten"].astype(float)
        out["eaten"] = ckpts.assign(_e=eaten).groupby(keys, sort=False)["_e"].agg(tuple)
    out["source"] = "evaluate.py"
    return out.reset_index().assign(episodes=lambda d: d["scores"].map(len))


def reference_stats(refs: pd.DataFrame, value: str) -> pd.DataFrame:
    """Per (policy, level) the statistics (:data:`STAT_COLUMNS`) of ``value`` (``success`` or ``steps``) for
    reference agents: episodes as the units, or participants for human rows of several participants."""
    out = []
    for (policy, level), part in refs.groupby(["policy", "level"], sort=False):
        vals = part[value].astype(float)
        if (
            "participant" in part
            and part["participant"].astype(str).str.len().gt(0).all()
            and part["participant"].nunique() > 1
        ):
            unit = "participants"
            samples = [tuple(v.dropna()) for _, v in part.assign(_v=vals).groupby("participant")["_v"]]
        else:
            unit, samples = "episodes", [tuple(vals.dropna())]
        est = estimate(samples, success=value == "success", unit=unit)
        share = intake = float("nan")
        if value == "steps":
            cap = level_cap(str(level))
            share = float((vals >= cap).mean()) if not np.isnan(cap) and len(vals) else float("nan")
            if {"food_eaten", "water_eaten"} <= set(part) and vals.sum() > 0:
                eaten = part["food_eaten"].astype(float) + part["water_eaten"].astype(float)
                intake = 1000.0 * float(eaten.sum()) / float(vals.sum())
        out.append(
            {
                "label": policy,
                "level": level,
                **est,
                "unit": unit,
                "acting": "",
                "worlds": _joined(part["worlds"]) if "worlds" in part else "",
                "source": "evaluate.py",
                "at_cap": share,
                "intake": intake,
                "samples": tuple((float(v),) for v in vals.dropna()) if unit == "episodes" else tuple(samples),
            }
        )
    return pd.DataFrame(out, columns=["label", "level", *STAT_COLUMNS, *EXTRA_COLUMNS])
