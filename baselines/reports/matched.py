"""Which agents learned, and the compute-matched comparison (the paper's Fig. 20 at equal compute).

* :func:`learned_gate` — an agent learned the first level when the 95 % interval of its network with every sense
  (IQM over its seeds' episodes, on the worlds the final networks were evaluated on) lies above ``factor`` × the
  better of random and stand-still there; one whose interval does not "did not learn at this budget" — the one
  definition of "fails" of the claims (:func:`..paper.claims.fails`).  The gate decides no claim's part: it says
  which agents learned, and explains parts the data leave undecided.  An agent is judged at the budget it is compared at:
  its compute-matched runs for the compute-matched comparison, and for the others its direct runs on that level
  with a step budget, else its curriculum's first stage.
* :func:`reaching` — when each compute-matched run's in-training evaluations (validation worlds) first reached that
  threshold, in env steps and in CPU minutes: how fast it learned.
* :func:`curve_points` — the compute-matched runs' learning curves, against env steps and against CPU minutes.

Compute-matched runs are those bounded by CPU time (:attr:`.load.RunRecord.cpu_budget`): every algorithm given the
same CPU minutes, whatever env steps they buy.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pandas as pd

from .aggregate import across_seeds, level_cap
from .load import RunRecord
from .stats import iqm
from .tables import capped

#: the references an agent must beat to have learned: the better of the two
GATE_REFERENCES = ("random", "still")


def threshold(reference_training: pd.DataFrame, level: str, factor: float) -> tuple[float, str] | None:
    """``factor`` × the better survival (IQM) of random and stand-still on ``level``, and which it was; None where
    neither was evaluated there."""
    refs = reference_training
    refs = refs[(refs["level"] == level) & refs["label"].isin(GATE_REFERENCES)] if len(refs) else refs
    if not len(refs):
        return None
    best = refs.sort_values("value").iloc[-1]
    return factor * float(best["value"]), str(best["label"])


def gate_runs(runs: Sequence[RunRecord], level: str, compute_bound: bool) -> dict[str, list[RunRecord]]:
    """Per algorithm, the runs with every sense that speak for whether it learned ``level``: its compute-matched
    runs on that level (``compute_bound``), or else its direct runs there with a step budget, where it has none its
    curricula (whose first stage is that level)."""
    out: dict[str, list[RunRecord]] = {}
    picks = (
        [lambda r: r.cpu_budget is not None and not r.curriculum and r.training == level]
        if compute_bound
        else [
            lambda r: r.cpu_budget is None and not r.curriculum and r.training == level,
            lambda r: r.curriculum and bool(r.stages) and r.stages[0][1] == level,
        ]
    )
    for algo in dict.fromkeys(r.algo for r in runs):
        mine = [r for r in runs if r.algo == algo and r.usable and r.modality == "all"]
        for pick in picks:
            chosen = [r for r in mine if pick(r)]
            if chosen:
                out[algo] = chosen
                break
    return out


def learned_gate(
    runs: Sequence[RunRecord],
    final: pd.DataFrame,
    reference_training: pd.DataFrame,
    level: str,
    factor: float,
    compute_bound: bool = False,
) -> pd.DataFrame:
    """Per algorithm: its all-senses network's survival on ``level`` (``final``: rows of
    :func:`.aggregate.final_survival` in the acting mode compared), the threshold, and whether it learned — of its
    runs with a step budget, or (``compute_bound``) of its compute-matched runs: an agent is judged at the budget it
    is compared at.

    Columns: algo, compute_bound, runs (how many), budget (what they were given), value, low, high, n, acting, worlds,
    threshold, reference (which reference set it), ratio (survival / the better reference), learned (bool), reading
    (a line for the report)."""
    columns = [
        "algo",
        "compute_bound",
        "runs",
        "budget",
        "value",
        "low",
        "high",
        "n",
        "acting",
        "worlds",
        "threshold",
        "reference",
        "ratio",
        "at_cap",
        "learned",
        "reading",
    ]
    bar = threshold(reference_training, level, factor)
    rows = []
    for algo, chosen in gate_runs(runs, level, compute_bound).items():
        dirs = {r.dir for r in chosen}
        mine = final[final["run"].isin(dirs) & (final["level"] == level)] if len(final) else final
        budget = " / ".join(dict.fromkeys(r.budget for r in chosen))
        if not len(mine) or bar is None:
            continue
        est = across_seeds(mine.assign(g=0), ["g"], "survival", cap=level_cap(level)).iloc[0]
        value, low = float(est["value"]), float(est["low"])
        limit, ref = bar
        learned = not math.isnan(low) and low > limit  # its interval above the bar (claims.fails: the same rule)
        ratio = value * factor / limit if limit else float("nan")
        bound = "≥ " if capped(est) else ""
        rows.append(
            {
                "algo": algo,
                "compute_bound": compute_bound,
                "runs": len(chosen),
                "budget": budget,
                "value": value,
                "low": float(est["low"]),
                "high": float(est["high"]),
                "n": int(est["n"]),
                "acting": est["acting"],
                "worlds": est["worlds"],
                "threshold": limit,
                "reference": ref,
                "ratio": ratio,
                "at_cap": float(est["at_cap"]),
                "learned": learned,
                # a capped cell's IQM is a lower bound, and so its ratio to the references
                "reading": (
                    f"{algo} ({budget}): {bound}{value:,.0f} "
                    f"[{low:,.0f}, {float(est['high']):,.0f}] decisions on {level}, {bound}{ratio:.2f}× "
                    f"{'stand-still' if ref == 'still' else ref} — "
                    + (
                        f"learned (interval above {factor:g}× = {limit:,.0f})"
                        if learned
                        else f"did not learn at this budget (interval not above {factor:g}× = {limit:,.0f})"
                    )
                ),
            }
        )
    return pd.DataFrame(rows, columns=columns)


def reaching(points: pd.DataFrame, runs: dict, limit: float) -> pd.DataFrame:
    """Per compute-matched run: the env steps and CPU minutes of its first in-training evaluation whose survival
    (IQM of that evaluation's episodes) reached ``limit``, or, where none did, NaN with ``reached`` False and the
    run's last evaluation's env steps and CPU minutes (how far it looked).  ``points``: rows of
    :func:`.aggregate.evaluation_points`; ``runs``: run directory → :class:`.load.RunRecord`."""
    rows = []
    for run, part in points.groupby("run", sort=False):
        part = part.sort_values("steps")
        scores = part["scores"].map(lambda s: float(iqm(np.asarray(s, dtype=float))) if len(s) else float("nan"))
        hit = part[scores.to_numpy() >= limit]
        r = runs[run]
        first = hit.iloc[0] if len(hit) else None
        rows.append(
            {
                "run": run,
                "algo": r.algo,
                "seed": r.seed,
                "reached": first is not None,
                "steps": float(first["steps"]) if first is not None else float("nan"),
                "cpu_minutes": float(first["cpu_minutes"]) if first is not None else float("nan"),
                "looked_steps": float(part["steps"].max()),
                "looked_cpu_minutes": float(part["cpu_minutes"].max()),
            }
        )
    return pd.DataFrame(
        rows,
        columns=["run", "algo", "seed", "reached", "steps", "cpu_minutes", "looked_steps", "looked_cpu_minutes"],
    )


def curve_points(points: pd.DataFrame, labels: dict) -> pd.DataFrame:
    """The compute-matched runs' learning curves in two views (column ``view``): against env steps and against CPU
    minutes.  A run's k-th evaluation is pooled with the other seeds' k-th (their schedules are the same: every
    ``eval.every`` env steps, and a last one where the CPU minutes ran out), at the seeds' mean env steps or CPU
    minutes.  One row per run and point with the episodes' ``scores``, for :func:`.aggregate.across_seeds` over
    ``view``, ``label``, ``x``; no CPU view for runs whose ``eval.csv`` has no ``cpu_seconds``."""
    out = []
    for run, part in points.groupby("run", sort=False):
        part = part.sort_values("steps").reset_index(drop=True)
        views = [("against env steps", "steps")]
        if part["cpu_minutes"].notna().all():
            views.append(("against CPU minutes", "cpu_minutes"))
        for view, column in views:
            for k, row in part.iterrows():
                out.append(
                    {
                        "view": view,
                        "label": labels[run],
                        "run": run,
                        "k": int(k),
                        "x": float(row[column]),
                        "scores": tuple(row["scores"]),
                        "episodes": len(row["scores"]),
                        "means_only": bool(row["means_only"]),
                        "acting": str(row["acting"]),
                        "worlds": str(row["worlds"]),
                        "source": "eval.csv",
                    }
                )
    frame = pd.DataFrame(
        out,
        columns=["view", "label", "run", "k", "x", "scores", "episodes", "means_only", "acting", "worlds", "source"],
    )
    if len(frame):
        frame["x"] = frame.groupby(["view", "label", "k"])["x"].transform("mean")
    return frame
