"""A report's tables in Markdown: the cell of a statistic (``IQM [low, high]; mean ± se (n=…)``, ``rate [low,
high] (n=…)``), a table of cells, and ``scripts/evaluate.py``'s summary of an evaluation (:func:`summarize`,
:func:`markdown_table`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from .aggregate import CAPPED_SHARE, estimate, mean_se
from .load import LEVEL_ORDER, display_names


def sample_size(n: int, episodes: int, unit: str = "seeds", means_only: bool = False) -> str:
    """``2 seeds × 20 ep.`` (or ``2 seeds, 37 ep.`` when the seeds have unequal numbers of episodes; ``2 seeds ×
    mean of 8 ep.`` where each seed gave one evaluation's mean); reference agents: ``20 ep.``, or ``3 participants,
    30 ep.``."""
    if unit == "episodes":
        return f"{episodes} ep."
    word = unit if n != 1 else unit.rstrip("s")
    if means_only:
        return (
            f"{n} {word} × mean of {episodes // n} ep."
            if n and episodes % n == 0
            else f"{n} {word}, means of {episodes} ep."
        )
    return f"{n} {word} × {episodes // n} ep." if n and episodes % n == 0 else f"{n} {word}, {episodes} ep."


def _points(row: Mapping[str, Any], k: float, pct: str) -> str:
    points = row.get("points") or ()
    if isinstance(points, str):  # read back from a CSV
        points = [float(p) for p in points.split(";") if p]
    return ", ".join(f"{k * p:.1f}{pct}" for p in points)


def capped(row: Mapping[str, Any]) -> bool:
    """Whether a survival cell's episodes reach the step cap more often than :data:`.aggregate.CAPPED_SHARE` (a
    quarter): its IQM, and its interval's upper end, are then lower bounds."""
    share = row.get("at_cap", float("nan")) if hasattr(row, "get") else float("nan")
    try:
        return bool(float(share) > CAPPED_SHARE)
    except (TypeError, ValueError):
        return False


def censored_note(row: Mapping[str, Any]) -> str:
    """What a capped survival cell adds: the share of episodes at the cap and the intake (food and water eaten per
    1,000 decisions), e.g. ``93 % at the step cap; intake 7.5 / 1,000 decisions``; "" for a cell that is not."""
    if not capped(row):
        return ""
    intake = row.get("intake", float("nan"))
    said = f"{100 * float(row['at_cap']):.0f} % at the step cap"
    try:
        if not np.isnan(float(intake)):
            said += f"; intake {float(intake):.1f} / 1,000 decisions"
    except (TypeError, ValueError):
        pass
    return said


def cell(row: Mapping[str, Any], percent: bool = False) -> str:
    """A table cell from a row of :data:`STAT_COLUMNS`: survival ``IQM [low, high]; mean ± se (n=…)``, success
    ``rate% [low, high] (n=…)`` (one decimal); under three seeds no interval: ``IQM; seeds a, b (n=…)``.  A survival
    cell with more than a quarter of its episodes at the step cap is a lower bound: ``≥ 5000.0 [...] ...; 93 % at
    the step cap; intake 7.5 / 1,000 decisions (n=…)``."""
    if not row["n"] or np.isnan(row["value"]):
        return "–"
    k, pct = (100.0, "%") if percent else (1.0, "")
    text = ("≥ " if capped(row) else "") + f"{k * row['value']:.1f}{pct}"
    if not np.isnan(row["low"]):
        text += f" [{k * row['low']:.1f}, {k * row['high']:.1f}]"
    if row["statistic"] == "iqm" and not np.isnan(row["se"]):
        text += f"; {row['mean']:.1f} ± {row['se']:.1f}"
    points = _points(row, k, pct)
    if points:
        text += f"; {'seeds' if row.get('unit', 'seeds') == 'seeds' else row.get('unit')} {points}"
    note = censored_note(row)
    if note:
        text += f"; {note}"
    size = sample_size(int(row["n"]), int(row["episodes"]), row.get("unit", "seeds"), bool(row.get("means_only")))
    return f"{text} (n={size})"


def _named(stats: pd.DataFrame, column: str, col: str | None) -> str:
    """What ``stats`` says in ``column`` (acting, worlds), with the algorithms (the first part of the ``col``
    labels) it applies to where it differs."""
    if column not in stats:
        return "not recorded"
    part = stats[stats[column].fillna("").astype(str) != ""]
    ways = list(dict.fromkeys(part[column].astype(str)))
    if not ways:
        return "not recorded"
    if len(ways) == 1 or col is None or col not in part:
        return " / ".join(f"`{w}`" if column == "acting" else w for w in ways)
    algo = part[col].astype(str).str.split(" · ").str[0].str.split(" [", regex=False).str[0]
    return "; ".join(
        (f"`{w}`" if column == "acting" else w) + f" ({', '.join(dict.fromkeys(algo[part[column] == w]))})"
        for w in ways
    )


def caption(title: str, stats: pd.DataFrame, col: str | None = "label", compared: str = "") -> str:
    """A table's title line: what it shows, how the agents acted and on which worlds (per column where they differ;
    reference agents follow their own rule and are not listed), and a warning where agents acted differently;
    ``compared``: the acting the report's claims compare (Markdown; ``Inputs.compared``), named where agents
    acted."""
    agents = stats[stats["unit"] != "episodes"] if "unit" in stats else stats
    agents = agents[agents["unit"] != "participants"] if "unit" in agents else agents
    acting = _named(agents if len(agents) else stats, "acting", col)
    worlds = _named(stats, "worlds", col)
    text = f"**{title}.** Acting: {acting}. Worlds: {worlds}."
    modes = {m for m in agents.get("acting", pd.Series(dtype=str)).fillna("").astype(str) if m}
    if compared and modes:
        text += f" The claims compare {compared}" + (
            "; cells of any other acting are shown, labelled, and compared with nothing." if len(modes) > 1 else "."
        )
    elif len(modes) > 1:
        text += " Not one acting mode: cells of different modes are not compared."
    if "means_only" in stats and stats["means_only"].fillna(False).astype(bool).any():
        text += " Means only: some seeds gave only an evaluation's mean (eval.csv of the older format)."
    return text


def pivot_table(
    stats: pd.DataFrame,
    row: str,
    col: str,
    *,
    percent: bool = False,
    row_title: str = "level",
    rows: Sequence[str] | None = None,
    cols: Sequence[str] | None = None,
    title: str = "Table",
    compared: str = "",
) -> str:
    """A Markdown table of ``stats`` (:data:`STAT_COLUMNS`) with one row per ``row`` value and one column per
    ``col`` value (cells: :func:`cell`), under its :func:`caption` (``compared``: the acting the claims compare)."""
    rows = list(rows if rows is not None else dict.fromkeys(stats[row]))
    cols = list(cols if cols is not None else dict.fromkeys(stats[col]))
    lines = [
        caption(title, stats, col, compared),
        "",
        f"| {row_title} | " + " | ".join(cols) + " |",
        "|---|" + "---|" * len(cols),
    ]
    for r in rows:
        cells = []
        for c in cols:
            hit = stats[(stats[row] == r) & (stats[col] == c)]
            cells.append(cell(hit.iloc[0], percent) if len(hit) else "–")
        lines.append(f"| {r} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------------ evaluate.py
#: What evaluate.py's summary table shows, for the text above it.
SUMMARY_NOTE = (
    "Testbeds: success rate `rate [low, high]`, the share of successful episodes with its 95 % Wilson "
    "score interval. Training levels: survival (decisions) `IQM [low, high]; mean ± se`, the "
    "interquartile mean of the episodes with its 95 % percentile bootstrap interval (2000 resamples; "
    "one policy's episodes are its units; human play: participants redrawn, then their episodes), then "
    "the mean ± standard error over episodes. n: episodes (and participants where there are several; "
    "under three participants, their values and no interval)."
)


def summarize(rows: pd.DataFrame) -> pd.DataFrame:
    """evaluate.py's summary: one row per (level, policy and how it acted; ``policy`` holds
    :func:`.load.display_names`) with ``episodes``; the success rate with its Wilson interval
    (``success_rate``, ``success_low``, ``success_high``; NaN where the level has no success rule); survival as
    ``survival_iqm`` with its bootstrap interval (``survival_low``, ``survival_high``) and ``survival_mean`` ±
    ``survival_se`` over episodes; ``units`` and ``unit`` (the strata: participants of human play when several, else
    the evaluation seeds); mean ``collisions``."""
    rows = rows.assign(policy=display_names(rows))
    out = []
    for (level, policy), part in rows.groupby(["level", "policy"], sort=False):
        unit = (
            "participants"
            if "participant" in part
            and part["participant"].astype(str).str.len().gt(0).all()
            and part["participant"].nunique() > 1
            else "seeds"
        )
        key = "participant" if unit == "participants" else ("seed" if "seed" in part else None)
        strata = [g for _, g in part.groupby(key, sort=False)] if key else [part]
        steps = [tuple(g["steps"].astype(float)) for g in strata]
        # one network's (or policy's) episodes are independent draws: episodes are the units, except for human
        # play, where participants are
        by = unit if unit == "participants" else "episodes"
        surv = estimate(steps, unit=by)
        mean, se, _ = mean_se(part["steps"].astype(float))
        judged = part["success"].notna()
        success = (
            estimate(
                [tuple(g.loc[judged.loc[g.index], "success"].astype(float)) for g in strata], success=True, unit=by
            )
            if judged.any()
            else {"value": np.nan, "low": np.nan, "high": np.nan}
        )
        out.append(
            {
                "level": level,
                "policy": policy,
                "episodes": len(part),
                "units": len(strata),
                "unit": unit,
                "success_rate": success["value"],
                "success_low": success["low"],
                "success_high": success["high"],
                "survival_iqm": surv["value"],
                "survival_low": surv["low"],
                "survival_high": surv["high"],
                "survival_mean": mean,
                "survival_se": se,
                "collisions": float(part["collisions"].mean()),
            }
        )
    table = pd.DataFrame(out)
    return (
        table.sort_values(
            by="level", key=lambda c: c.map(lambda n: LEVEL_ORDER.get(n, len(LEVEL_ORDER))), kind="stable"
        )
        if len(table)
        else table
    )


def markdown_table(summary: pd.DataFrame) -> str:
    """evaluate.py's table: success rate (testbeds) or survival (training levels) per level, one column per policy
    (cells as :data:`SUMMARY_NOTE` says)."""
    policies = list(dict.fromkeys(summary["policy"]))
    lines = ["| level | " + " | ".join(policies) + " |", "|---|" + "---|" * len(policies)]
    for level, part in summary.groupby("level", sort=False):
        cells = []
        for policy in policies:
            hit = part[part["policy"] == policy]
            if hit.empty:
                cells.append("–")
                continue
            r = hit.iloc[0]
            n = (
                f"{r['episodes']} ep."
                if r["units"] < 2
                else sample_size(int(r["units"]), int(r["episodes"]), r["unit"])
            )
            judged = not np.isnan(r["success_rate"])
            cells.append(
                cell(
                    {
                        "value": r["success_rate"] if judged else r["survival_iqm"],
                        "low": r["success_low"] if judged else r["survival_low"],
                        "high": r["success_high"] if judged else r["survival_high"],
                        "statistic": "rate" if judged else "iqm",
                        "mean": r["survival_mean"],
                        "se": r["survival_se"],
                        "n": r["episodes"],
                        "episodes": r["episodes"],
                    },
                    percent=judged,
                ).rsplit(" (n=", 1)[0]
                + f" (n={n})"
            )
        lines.append(f"| {level} | " + " | ".join(cells) + " |")
    return "\n".join(lines)
