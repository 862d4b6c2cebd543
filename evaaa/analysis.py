"""From episode records to pictures: reading episode files, outcomes, figure labels, bar and outcome figures.

Works on the rows of :mod:`evaaa.records` (a pandas DataFrame read from ``episodes.csv`` files), so agents,
reference agents and human players are drawn the same way.  The numbers with their intervals (interquartile mean,
bootstrap and Wilson intervals) are computed with the reports, in ``evaaa_baselines.report`` (``summarize``,
``markdown_table``) over ``evaaa_baselines.stats``: the environment package does not import the baselines.
"""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd


#: Outcome of an episode, in the order they are stacked in the outcome plots.
OUTCOMES: tuple[str, ...] = (
    "success",
    "ate food (wrong)",
    "drank water (wrong)",
    "starved",
    "dehydrated",
    "too hot or cold",
    "too damaged",
    "reached max steps",
)
OUTCOME_COLOURS = ("#2ca02c", "#d62728", "#1f77b4", "#8c564b", "#17becf", "#ff7f0e", "#7f7f7f", "#bcbd22")


def read_episodes(paths: Sequence[str | Path]) -> pd.DataFrame:
    """Episode rows of several CSV files in one frame (``success`` as booleans, NaN where a level has none)."""
    frames = [pd.read_csv(p, dtype={"participant": str, "seed": str}, keep_default_na=False) for p in paths]
    if not frames:
        raise ValueError("no episode files given")
    rows = pd.concat(frames, ignore_index=True)
    # files written before the acting column existed: how their checkpoints acted is not known
    rows["acting"] = rows["acting"].fillna("") if "acting" in rows else ""
    rows["success"] = rows["success"].map({"True": True, "False": False, True: True, False: False, "": np.nan})
    return rows


def outcome(row) -> str:
    """The outcome category of one episode row."""
    if row["success"] is True or row["success"] == 1.0:
        return "success"
    end = row["end_type"]
    if end == "ResourceConsumed":
        return "ate food (wrong)" if row["food_eaten"] > 0 else "drank water (wrong)"
    return {
        "FoodOutOfRange": "starved",
        "WaterOutOfRange": "dehydrated",
        "TemperatureOutOfRange": "too hot or cold",
        "DamageTooHigh": "too damaged",
    }.get(end, "reached max steps")


def standard_error(values: pd.Series) -> float:
    n = values.count()
    return float(values.std(ddof=1) / np.sqrt(n)) if n > 1 else float("nan")


def display_names(rows: pd.DataFrame) -> pd.Series:
    """The policy column as tables and figures show it: a checkpoint's path with how it acted, e.g.
    ``run/model-0-1-1.pt [sample]``, so that one checkpoint evaluated in two ways gives two entries."""
    if "acting" not in rows:
        return rows["policy"]
    acting = rows["acting"].fillna("").astype(str)
    return rows["policy"].where(acting == "", rows["policy"] + " [" + acting + "]")


def short_labels(names: Sequence[str]) -> tuple[dict[str, str], str]:
    """Figure labels for policy names: a checkpoint path shortened to the path components in which the checkpoints
    shown differ (``runs/1-1/ppo/all-squared/seed0/model-0-1-1.pt`` and ``runs/1-1/dqn/...`` become ``ppo`` and
    ``dqn``), how it acted (`` [sample]``) kept; other names (oracle, random, human) unchanged.  Also returns a note
    that says what the labels stand for (``checkpoints: runs/1-1/<label>/all-squared/seed0/model-0-1-1.pt``), or
    ``""`` when nothing was shortened.  Full paths made legends wider than the plot and pushed labels off the image."""
    def split(name: str) -> tuple[str, str]:
        base, bracket, rest = name.partition(" [")
        return base, bracket + rest

    paths = list(dict.fromkeys(b for b, _ in map(split, names) if "/" in b or b.endswith(".pt")))
    short: dict[str, str] = {}
    note = ""
    if len(paths) == 1:
        parts = Path(paths[0]).parts
        if len(parts) > 2:
            short[paths[0]] = "/".join(parts[-2:])
            note = f"{short[paths[0]]}: {paths[0]}"
    elif paths:
        parts = [Path(p).parts for p in paths]
        shortest = min(map(len, parts))
        head = 0
        while head < shortest - 1 and len({p[head] for p in parts}) == 1:
            head += 1
        tail = 0
        while tail < shortest - head - 1 and len({p[len(p) - 1 - tail] for p in parts}) == 1:
            tail += 1
        labels = {p: "/".join(q[head:len(q) - tail]) for p, q in zip(paths, parts)}
        if len(set(labels.values())) == len(labels) and all(labels.values()):
            short = labels
            note = "checkpoints: " + "/".join([*parts[0][:head], "<label>", *parts[0][len(parts[0]) - tail:]])
    out = {}
    for name in names:
        base, acting = split(name)
        out[name] = short.get(base, base) + acting
    return out, note


def plot_bars(summary: pd.DataFrame, value: str, low: str, high: str, path: str | Path, *, ylabel: str, title: str,
              scale: float = 1.0) -> Path:
    """Grouped bar chart: one group per level, one bar per policy, the bars' heights from column ``value`` and the
    whiskers from ``low`` to ``high`` (an interval; no whisker where they are NaN).  ``title`` should say which
    statistic and interval are shown."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    levels = list(dict.fromkeys(summary["level"]))
    names, note = short_labels(list(dict.fromkeys(summary["policy"])))
    summary = summary.assign(policy=summary["policy"].map(names))
    policies = list(dict.fromkeys(summary["policy"]))
    width = 0.8 / max(len(policies), 1)
    fig, ax = plt.subplots(figsize=(max(6.0, 1.1 * len(levels) + 2), 4.2))
    x = np.arange(len(levels))
    for i, policy in enumerate(policies):
        part = summary[summary["policy"] == policy].set_index("level").reindex(levels)
        heights = scale * part[value].to_numpy(dtype=float)
        yerr = np.vstack([heights - scale * part[low].to_numpy(dtype=float),
                          scale * part[high].to_numpy(dtype=float) - heights])
        ax.bar(x + (i - (len(policies) - 1) / 2) * width, heights, width,
               yerr=np.clip(np.nan_to_num(yerr), 0, None), capsize=3, label=policy)
    ax.set_xticks(x, levels, rotation=30, ha="right")
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    # the legend goes beside the axes, not over the bars
    ax.legend(frameon=False, fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.spines[["top", "right"]].set_visible(False)
    if note:
        fig.text(0.01, 0.01, note, fontsize=7, color="0.35")
    fig.tight_layout(rect=(0, 0.04 if note else 0, 0.78 if max(map(len, policies)) > 12 else 0.88, 1))
    path = Path(path)
    fig.savefig(path, dpi=120, bbox_inches="tight")  # whatever the labels, nothing is cut off
    plt.close(fig)
    return path


def plot_outcomes(rows: pd.DataFrame, path: str | Path, *, title: str = "What happened in each episode") -> Path:
    """Per level and policy, the share of episodes by outcome (success, wrong resource, cause of death,
    timeout), with the mean number of collisions written above each bar."""
    rows = rows.assign(policy=display_names(rows))
    names, note = short_labels(list(dict.fromkeys(rows["policy"])))
    rows = rows.assign(policy=rows["policy"].map(names))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = rows.assign(outcome=rows.apply(outcome, axis=1))
    levels = list(dict.fromkeys(rows["level"]))
    policies = list(dict.fromkeys(rows["policy"]))
    cols = min(len(levels), 5)
    nrows = -(-len(levels) // cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(1.0 + cols * max(1.6, 0.65 * len(policies)), 3.2 * nrows + 0.9),
                             sharey=True, squeeze=False)
    for ax in axes.flat[len(levels):]:
        ax.set_visible(False)
    for ax, level in zip(axes.flat, levels):
        part = rows[rows["level"] == level]
        bottom = np.zeros(len(policies))
        for name, colour in zip(OUTCOMES, OUTCOME_COLOURS):
            share = np.array([(part[part["policy"] == p]["outcome"] == name).mean() if (part["policy"] == p).any()
                              else 0.0 for p in policies])
            ax.bar(range(len(policies)), share, bottom=bottom, color=colour, label=name)
            bottom += share
        for i, p in enumerate(policies):
            hits = part[part["policy"] == p]["collisions"]
            if len(hits):
                ax.text(i, 1.02, f"{hits.mean():.1f}", ha="center", fontsize=7)
        ax.set_xticks(range(len(policies)), policies, rotation=45, ha="right", fontsize=8)
        ax.set_title("\n".join(textwrap.wrap(level, 18)), fontsize=8)
        ax.set_ylim(0, 1.12)
        ax.spines[["top", "right"]].set_visible(False)
    for ax in axes[:, 0]:
        ax.set_ylabel("share of episodes", fontsize=8)
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncols=4, frameon=False, fontsize=8)
    fig.suptitle(f"{title} (numbers: mean collisions per episode)" + (f"\n{note}" if note else ""), fontsize=10)
    fig.tight_layout(rect=(0, 0.9 / (3.2 * nrows + 0.9), 1, 0.93 if note else 0.96))
    path = Path(path)
    fig.savefig(path, dpi=120, bbox_inches="tight")  # rotated labels and the legend stay inside the image
    plt.close(fig)
    return path
