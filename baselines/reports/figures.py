"""A report's figures: grouped bars and lines of statistics with their intervals, and what happened in each episode
(outcomes), saved as PNG.  Labels name what differs among the runs shown; titles say which statistic and interval
are drawn.  ``scripts/evaluate.py`` draws its figures with the same functions.
"""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from .load import display_names, level_sorted

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
        labels = {p: "/".join(q[head : len(q) - tail]) for p, q in zip(paths, parts)}
        if len(set(labels.values())) == len(labels) and all(labels.values()):
            short = labels
            note = "checkpoints: " + "/".join([*parts[0][:head], "<label>", *parts[0][len(parts[0]) - tail :]])
    out = {}
    for name in names:
        base, acting = split(name)
        out[name] = short.get(base, base) + acting
    return out, note


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


#: a figure's widest size: readable at page width (issue 42); panels wrap into rows to stay within it
MAX_WIDTH_PX = 1600
DPI = 120
MAX_WIDTH_IN = (MAX_WIDTH_PX - 40) / DPI  # less what bbox_inches="tight" may add around the axes

#: One colour per algorithm, per reference agent and per modality set, the same in every figure (tab10/Dark2
#: colours; references in greys and black, so that agents stand out against them)
ALGO_COLOURS = {
    "ppo": "#1f77b4",
    "dqn": "#ff7f0e",
    "ppo_lstm": "#2ca02c",
    "dreamer": "#9467bd",
    "dreamer_xs": "#8c564b",
}
REFERENCE_COLOURS = {"oracle": "#000000", "random": "#7f7f7f", "still": "#bcbcbc", "human": "#e377c2"}
MODALITY_COLOURS = {
    "all": "#1b9e77",
    "no_vision": "#d95f02",
    "no_interoception": "#7570b3",
    "no_olfaction": "#e7298a",
    "no_thermoception": "#66a61e",
    "no_collision": "#e6ab02",
}
HATCHES = ("", "//", "..", "xx", "\\\\", "oo", "++", "--")
#: the one convention for acting modes in every figure: bars of networks acting `sample` solid, `mode` hatched ``//``
#: (lines: solid and dashed); other variants of one colour take the remaining hatches
ACTING_HATCHES = {"sample": "", "mode": "//"}
#: a legend entry's longest (characters): longer labels lose the settings every entry shares, then are cut
MAX_LEGEND = 60
#: the legend names of the figures drawn, by file (for the tests and the report's checks)
LEGENDS: dict[str, list[str]] = {}
OTHER_COLOURS = ("#17becf", "#d62728", "#aec7e8", "#98df8a", "#c5b0d5", "#c49c94")


def styles(labels: Sequence[str], colour_by: str = "algo") -> dict[str, tuple[str, str]]:
    """(colour, hatch) of each label: the colour of its algorithm (the label's first part, ``ppo · curriculum``)
    or, with ``colour_by="modality"``, of its modality set (the label itself); reference agents keep theirs.
    Labels sharing a colour get different hatches, in the order given."""
    table = MODALITY_COLOURS if colour_by == "modality" else ALGO_COLOURS
    out, used, spare = {}, {}, iter(OTHER_COLOURS * 10)
    others = [h for h in HATCHES if h not in ACTING_HATCHES.values()]
    for label in labels:
        base, _, bracket = str(label).partition(" [")
        acting = bracket.rstrip("]").split("+")[0]
        key = base.split(" · ")[0].strip()
        colour = REFERENCE_COLOURS.get(base) or table.get(key) or table.get(base)
        if colour is None:
            colour = used.setdefault(("other", key), next(spare))
        variant = (colour, base)  # the acting mode sets the hatch; other variants of one colour take the rest
        if variant not in used:
            used[variant] = used.get(colour, 0)
            used[colour] = used.get(colour, 0) + 1
        k = used[variant]
        hatch = ACTING_HATCHES.get(acting, "")
        if k:  # a second series of one colour (direct beside curriculum): dotted, over the acting mode's hatch
            hatch += others[(k - 1) % len(others)]
        out[label] = (colour, hatch)
    return out


def legend_names(names: Sequence[str], limit: int = MAX_LEGEND) -> dict[str, str]:
    """Legend entries of at most ``limit`` characters: where some name is longer, the `` · ``-parts every
    multi-part name shares (but its first, the algorithm) are dropped, and a name still too long is cut with "…"
    (the tables name every setting)."""
    if all(len(n) <= limit for n in names):
        return {n: n for n in names}
    split = {n: n.partition(" [") for n in names}
    parts = {n: b.split(" · ") for n, (b, _, _) in split.items() if " · " in b}
    common = set.intersection(*(set(p[1:]) for p in parts.values())) if parts else set()
    out = {}
    for n, (base, bracket, rest) in split.items():
        if n in parts:
            kept = [parts[n][0], *[p for p in parts[n][1:] if p not in common]]
            base = " · ".join(kept)
        name = base + (bracket + rest if bracket else "")
        out[n] = name if len(name) <= limit else name[: limit - 1] + "…"
    if len(set(out.values())) < len(out):  # dropping made two entries one: cut the full names instead
        out = {n: n if len(n) <= limit else n[: limit - 1] + "…" for n in names}
    return out


def _finish(fig, axes, path: Path, title: str, legend_rows: int = 0) -> Path:
    """One legend under the panels (entries of at most :data:`MAX_LEGEND` characters, :func:`legend_names`), the
    title above the first panel's own title (room kept for each of its lines), and the file, cropped to what was
    drawn."""
    handles, names = {}, []
    for ax in axes:
        for h, n in zip(*ax.get_legend_handles_labels()):
            if n not in handles:
                handles[n] = h
                names.append(n)
        ax.spines[["top", "right"]].set_visible(False)
    width = fig.get_size_inches()[0]
    shown = legend_names(names)
    LEGENDS[Path(path).name] = [shown[n] for n in names]
    if names:
        longest = max(len(shown[n]) for n in names)
        ncols = max(1, min(len(names), int(width / (0.065 * longest + 0.6))))
        fig.legend(
            [handles[n] for n in names],
            [shown[n] for n in names],
            loc="lower center",
            ncols=ncols,
            frameon=False,
            fontsize=8,
        )
        rows = -(-len(names) // ncols)
    else:
        rows = 0
    fig.suptitle(title, fontsize=10)
    height = fig.get_size_inches()[1]
    bottom = min(0.45, (0.22 * rows + 0.1) / height) if rows else 0.0
    lines = title.count("\n") + 1
    top = max(0.5, 1.0 - (0.05 * lines) / height)  # tight_layout places the suptitle; a little more for panel titles
    fig.tight_layout(rect=(0, bottom, 1, top))
    fig.savefig(path, dpi=DPI, bbox_inches="tight")
    _plt().close(fig)
    return Path(path)


def whiskers(stats: pd.DataFrame, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Bar heights (``value``) and their whiskers as matplotlib's (2, N) ``yerr``: the distance down to ``low`` and
    up to ``high`` (none where there is no interval)."""
    value = scale * stats["value"].to_numpy(dtype=float)
    low = np.nan_to_num(value - scale * stats["low"].to_numpy(dtype=float))
    high = np.nan_to_num(scale * stats["high"].to_numpy(dtype=float) - value)
    return value, np.clip(np.vstack([low, high]), 0, None)


def interval_note(stats: pd.DataFrame, drawn: str = "whiskers") -> str:
    """What the figure's bars or lines and their ``drawn`` (whiskers, band) show, for its caption."""
    kinds = set(stats["statistic"])
    parts = []
    if "iqm" in kinds:
        parts.append(f"interquartile mean, {drawn} 95 % bootstrap interval over seeds and episodes")
    if "rate" in kinds:
        parts.append(f"share of episodes, {drawn} 95 % seed-clustered Wilson interval")
    if "n" in stats and "unit" in stats and ((stats["unit"] == "seeds") & (stats["n"] < 3)).any():
        parts.append("under 3 seeds: dots are the seeds, no interval")
    return "; ".join(parts)


def how_measured(stats: pd.DataFrame, compared: str = "") -> str:
    """A figure title's line naming how the agents acted and on which worlds (and a line with ``compared``, the
    acting the report's claims compare, where agents acted)."""
    if "acting" not in stats and "worlds" not in stats:  # evaluate.py's summary: its own title says
        return ""

    def named(column: str) -> str:
        if column not in stats:
            return "not recorded"
        agents = stats[stats["acting"].fillna("").astype(str) != ""] if column == "acting" else stats
        ways = [w for w in dict.fromkeys(agents[column].fillna("").astype(str)) if w]
        return " / ".join(ways) or "not recorded"

    acting = named("acting")
    claims = f"\nthe claims compare {compared.replace('`', '')}" if compared and acting != "not recorded" else ""
    return f"acting: {acting} · worlds: {named('worlds')}{claims}"


def _chunks(items: Sequence, size: int) -> list[list]:
    """``items`` in rows of at most ``size``, as even as they go (8 levels by 6: two rows of 4, not 6 and 2)."""
    rows = -(-len(items) // max(1, size)) if len(items) else 1
    even = -(-len(items) // rows) if len(items) else 1
    return [list(items[i : i + even]) for i in range(0, len(items), even)] or [[]]


def plot_bars(
    stats: pd.DataFrame,
    path: Path,
    *,
    ylabel: str,
    title: str,
    panel: str | None = None,
    scale: float = 1.0,
    levels: Sequence[str] | None = None,
    top: float | None = None,
    note: str = "",
    panel_height: float = 3.0,
    colour_by: str = "algo",
    compared: str = "",
    references: pd.DataFrame | None = None,
) -> Path:
    """Grouped bars — one group per ``level``, one bar per ``label`` (``value``, its interval as whiskers, the
    seeds' ``points`` as dots where there is no interval) — in one panel per ``panel`` value (or a single panel),
    levels wrapped into further rows so that the figure stays within :data:`MAX_WIDTH_PX`; the y axis starts at 0
    and ends at ``top`` if given.  ``stats`` has the columns of :data:`.aggregate.STAT_COLUMNS`; ``note``: a last
    line of the title (e.g. what shortened labels stand for); ``compared``: the acting the report's claims compare
    (:func:`how_measured`); colours: :func:`styles`; ``references``: rows (label, level, value) of reference agents,
    drawn as a marker across each level's group of bars."""
    plt = _plt()
    panels = list(dict.fromkeys(stats[panel])) if panel else [None]
    style = styles(list(dict.fromkeys(stats["label"])), colour_by)
    rows = []  # (panel name, levels of this row, labels)
    for name in panels:
        part = stats if name is None else stats[stats[panel] == name]
        order = [lv for lv in (levels or level_sorted(part["level"])) if lv in set(part["level"])]
        names = list(dict.fromkeys(part["label"]))
        per_row = int((MAX_WIDTH_IN - 1.2) / (0.2 * len(names) + 0.35))
        rows += [(name, chunk, names) for chunk in _chunks(order, per_row)]
    widest = max(len(r[1]) * (0.2 * len(r[2]) + 0.35) + 1.2 for r in rows)
    width = min(MAX_WIDTH_IN, max(5.0, widest))
    slots = max(len(r[1]) for r in rows)  # every row as wide as the widest, so that bars keep one width
    fig, axes = plt.subplots(len(rows), 1, figsize=(width, panel_height * len(rows) + 0.6), squeeze=False)
    for ax, (name, order, names) in zip(axes[:, 0], rows):
        part = stats if name is None else stats[stats[panel] == name]
        bar = 0.8 / max(len(names), 1)
        for i, label in enumerate(names):
            one = part[part["label"] == label].set_index("level").reindex(order)
            heights, yerr = whiskers(one, scale)
            xs = np.arange(len(order)) + (i - (len(names) - 1) / 2) * bar
            colour, hatch = style[label]
            ax.bar(
                xs,
                heights,
                bar,
                yerr=yerr,
                capsize=2,
                label=label,
                color=colour,
                hatch=hatch,
                edgecolor="white" if hatch else None,
                linewidth=0,
            )
            if "points" in one:
                for x, pts in zip(xs, one["points"]):
                    if isinstance(pts, tuple) and pts:
                        ax.plot([x] * len(pts), [scale * p for p in pts], "o", ms=2.5, color="0.15", zorder=3)
        if references is not None and len(references):
            marks = {"random": "--", "still": ":", "oracle": "-", "human": "-."}
            for ref, rows_ in references.groupby("label", sort=False):
                at = rows_.set_index("level")["value"].reindex(order)
                for i, v in enumerate(at):
                    if not np.isnan(v):
                        ax.hlines(
                            scale * v,
                            i - 0.45,
                            i + 0.45,
                            colors=REFERENCE_COLOURS.get(str(ref), "0.35") if ref != "still" else "0.45",
                            linestyles=marks.get(str(ref), "--"),
                            linewidth=1.6,
                            label=f"{'stand-still' if ref == 'still' else ref} (reference)"
                            if i == 0 or np.isnan(at.iloc[:i]).all()
                            else None,
                            zorder=4,
                        )
        ax.set_xticks(
            range(len(order)),
            order,
            rotation=30 if len(order) > 2 else 0,
            ha="right" if len(order) > 2 else "center",
            fontsize=8,
        )
        ax.set_xlim(-0.5, slots - 0.5)
        ax.set_ylabel(ylabel, fontsize=8)
        ax.set_ylim(0, top)
        if name is not None:
            ax.set_title(str(name), fontsize=9)
    lines = [title, f"({interval_note(stats)})", how_measured(stats, compared), note]
    return _finish(fig, axes[:, 0], path, "\n".join(line for line in lines if line))


def plot_lines(
    stats: pd.DataFrame,
    path: Path,
    *,
    x: str,
    panel: str | None,
    ylabel: str,
    xlabel: str,
    title: str,
    band: bool,
    scale: float = 1.0,
    order: Sequence[str] | None = None,
    hlines: pd.DataFrame | None = None,
    top: float | None = None,
    colour_by: str = "algo",
    compared: str = "",
    xlabels: dict[str, str] | None = None,
) -> Path:
    """Lines of ``value`` per ``label`` (one panel per ``panel`` value, two panels a row), with its interval as a
    band or whiskers; ``order``: categorical x values in this order (labels drawn side by side, slightly apart, so
    that equal values stay visible); ``hlines``: (label, value) rows drawn as dashed lines; the y axis starts at 0,
    ends at ``top``; ``compared``: the acting the report's claims compare (:func:`how_measured`); colours:
    :func:`styles`; ``xlabels``: a panel's own x label, where panels differ in what x is."""
    plt = _plt()
    panels = list(dict.fromkeys(stats[panel])) if panel else [None]
    cols = min(len(panels), 2)
    nrows = -(-len(panels) // cols)
    style = styles(list(dict.fromkeys(stats["label"])), colour_by)
    dashes = ("-", "--", ":", "-.")
    fig, axes = plt.subplots(nrows, cols, figsize=(min(MAX_WIDTH_IN, 6.0 * cols), 3.4 * nrows + 0.8), squeeze=False)
    for ax in axes.flat[len(panels) :]:
        ax.set_visible(False)
    for ax, name in zip(axes.flat, panels):
        part = stats if name is None else stats[stats[panel] == name]
        n_labels = part["label"].nunique()
        for k, (label, line) in enumerate(part.groupby("label", sort=False)):
            if order is not None:
                line = line.assign(_x=line[x].map({v: i for i, v in enumerate(order)})).sort_values("_x")
                xs = line["_x"].to_numpy(dtype=float) + 0.04 * (k - (n_labels - 1) / 2)
            else:
                line = line.sort_values(x)
                xs = line[x].to_numpy(dtype=float)
            m, yerr = whiskers(line, scale)
            colour, hatch = style[label]
            dash = "--" if hatch.startswith("//") else dashes[[h[:1] for h in HATCHES].index(hatch[:1]) % len(dashes)]
            if band:
                ax.plot(xs, m, marker="." if len(xs) < 30 else None, label=label, color=colour, linestyle=dash)
                ax.fill_between(xs, m - yerr[0], m + yerr[1], alpha=0.25, color=colour, linewidth=0)
            else:
                ax.errorbar(xs, m, yerr=yerr, marker="o", capsize=3, label=label, color=colour, linestyle=dash)
        for style_, (_, ref) in zip(
            ("--", ":", "-.", (0, (5, 1))), (hlines if hlines is not None else pd.DataFrame()).iterrows()
        ):
            base = str(ref["label"]).split(" (")[0]
            ax.axhline(
                scale * ref["value"],
                linestyle=style_,
                linewidth=1,
                color=REFERENCE_COLOURS.get(base, "0.35"),
                label=ref["label"],
            )
        if order is not None:
            ax.set_xticks(range(len(order)), order, fontsize=8)
            ax.set_xlim(-0.3, len(order) - 0.7)
        else:  # env steps: 250k, 1.5M rather than six-digit labels that run into each other
            from matplotlib.ticker import EngFormatter

            ax.xaxis.set_major_formatter(EngFormatter(sep=""))
        ax.set_xlabel((xlabels or {}).get(name, xlabel), fontsize=8)
        ax.set_ylabel(ylabel, fontsize=8)
        ax.set_ylim(0, top)
        if name is not None:
            ax.set_title(str(name), fontsize=9)
    note = interval_note(stats, "band" if band else "whiskers")
    lines = [title, f"({note})", how_measured(stats, compared)]
    return _finish(fig, list(axes.flat[: len(panels)]), path, "\n".join(line for line in lines if line))


def plot_summary(summary: pd.DataFrame, path: str | Path, *, success: bool, title: str) -> Path:
    """``scripts/evaluate.py``'s figure of its summary (:func:`.tables.summarize`): per level one bar per policy,
    the success rate with its Wilson interval (``success``) or the IQM survival with its bootstrap interval;
    checkpoint paths shortened to the parts in which they differ (the title's last line says how)."""
    names, note = short_labels(list(dict.fromkeys(summary["policy"])))
    kind = "success" if success else "survival"
    stats = pd.DataFrame(
        {
            "label": summary["policy"].map(names),
            "level": summary["level"],
            "value": summary["success_rate" if success else "survival_iqm"],
            "low": summary[f"{kind}_low"],
            "high": summary[f"{kind}_high"],
            "statistic": "rate" if success else "iqm",
        }
    )
    return plot_bars(
        stats,
        Path(path),
        levels=list(dict.fromkeys(summary["level"])),
        scale=100 if success else 1.0,
        top=105 if success else None,
        ylabel="success rate (%)" if success else "survival (decisions)",
        title=title,
        note=note,
        panel_height=4.2,
    )


def plot_outcomes(rows: pd.DataFrame, path: str | Path, *, title: str = "What happened in each episode") -> Path:
    """Per level and policy, the share of episodes by outcome (success, wrong resource, cause of death,
    timeout), with the mean number of collisions written above each bar."""
    rows = rows.assign(policy=display_names(rows))
    names, note = short_labels(list(dict.fromkeys(rows["policy"])))
    rows = rows.assign(policy=rows["policy"].map(names))
    plt = _plt()
    rows = rows.assign(outcome=rows.apply(outcome, axis=1))
    levels = list(dict.fromkeys(rows["level"]))
    policies = list(dict.fromkeys(rows["policy"]))
    per_panel = max(1.6, 0.65 * len(policies))
    cols = max(1, min(len(levels), 5, int((MAX_WIDTH_IN - 1.0) // per_panel)))
    nrows = -(-len(levels) // cols)
    fig, axes = plt.subplots(
        nrows, cols, figsize=(min(MAX_WIDTH_IN, 1.0 + cols * per_panel), 3.2 * nrows + 0.9), sharey=True, squeeze=False
    )
    for ax in axes.flat[len(levels) :]:
        ax.set_visible(False)
    for ax, level in zip(axes.flat, levels):
        part = rows[rows["level"] == level]
        bottom = np.zeros(len(policies))
        for name, colour in zip(OUTCOMES, OUTCOME_COLOURS):
            share = np.array(
                [
                    (part[part["policy"] == p]["outcome"] == name).mean() if (part["policy"] == p).any() else 0.0
                    for p in policies
                ]
            )
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
