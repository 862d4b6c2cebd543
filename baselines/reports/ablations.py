"""The sections of the modality ablations: training curves (Fig. 25) and testbed success (Fig. 26) per
modality set."""

from __future__ import annotations

import pandas as pd

from .aggregate import across_seeds, per_run
from .document import Document, Inputs, source_words
from .figures import plot_bars, plot_lines
from .load import labels, level_sorted
from .tables import pivot_table


def ablation_curves(doc: Document, inp: Inputs) -> None:
    """Fig. 25: training curves per modality set, one panel per algorithm (and training set-up), and each
    modality's survival at the end of the run."""
    curve_rows, by_dir = inp.run_curves, inp.by_dir
    ab_lab = labels(inp.usable, ("algo", "reward", "extras", "training"))
    table = figure = None
    if len(curve_rows):
        # one bin grid per group: a group's runs share a budget (steps per stage is part of the group)
        by = curve_rows.assign(
            group=lambda d: d["run"].map(ab_lab), label=lambda d: d["run"].map(lambda x: by_dir[x].modality)
        )
        stats = across_seeds(by, ["group", "label", "bin", "steps"], "survival")
        doc.tables["ablation_curves"] = stats
        figure = plot_lines(
            _ablations(stats),
            doc.out / "fig25_ablation_curves.png",
            x="steps",
            panel="group",
            band=True,
            ylabel="survival (decisions)",
            xlabel="env steps",
            title="Training curves per modality",
            colour_by="modality",
        )
        final = inp.final
        last = inp.labelled(
            final[final["last"]].assign(group=lambda d: d["run"].map(ab_lab)),
            {d: by_dir[d].modality for d in by_dir},
            within=("group",),
        )
        fstats = across_seeds(last, ["group", "label"], "survival")
        doc.tables["ablation_final_survival"] = fstats
        table = (
            pivot_table(
                fstats,
                "label",
                "group",
                row_title="modality",
                rows=sorted(dict.fromkeys(fstats["label"]), key=_modality_key),
                title="Survival at the end of each run, per modality set (decisions)",
                compared=inp.compared,
            )
            if len(fstats)
            else ""
        )
        table += (
            f"\n\nCurves: survival of training episodes in {inp.bins} bins of env steps, IQM with its 95 % "
            "bootstrap interval (band). Table: survival at the end of each run (" + source_words(inp) + ")."
        )
    doc.section(
        "Modality ablations: training curves (Fig. 25)",
        "One panel per algorithm (and training set-up) trained with several modality sets, one line per "
        "modality set; the table has every run.",
        figure,
        table,
        "No finished training episode in the runs given.",
    )


def ablation_success(doc: Document, inp: Inputs) -> None:
    """Fig. 26: testbed success per modality set, one panel per algorithm (and training set-up)."""
    table = figure = None
    if len(inp.best):
        ab_ck = labels(inp.checkpoint_runs, ("algo", "reward", "extras", "training"))
        stats = across_seeds(
            inp.labelled(
                per_run(inp.best, "success").assign(group=lambda d: d["run"].map(ab_ck)),
                {d: inp.runs[d].modality for d in ab_ck},
                within=("group",),
            ),
            ["group", "label", "level"],
            "success",
            success=True,
        )
        order = {g: i for i, g in enumerate(dict.fromkeys(stats["group"]))}
        stats = stats.sort_values("label", key=lambda s: s.map(_modality_key), kind="stable").sort_values(
            "group", key=lambda s: s.map(order), kind="stable"
        )
        doc.tables["ablation_success"] = stats
        figure = plot_bars(
            _ablations(stats),
            doc.out / "fig26_ablation_success.png",
            panel="group",
            scale=100,
            top=105,
            ylabel="success rate (%)",
            title="Testbed success per modality",
            colour_by="modality",
            compared=inp.compared,
        )
        stats = (
            stats.assign(column=stats["group"] + " · " + stats["label"])
            if stats["group"].nunique() > 1
            else stats.assign(column=stats["label"])
        )
        table = pivot_table(
            stats,
            "level",
            "column",
            rows=level_sorted(stats["level"]),
            percent=True,
            row_title="testbed",
            title="Testbed success per modality set",
            compared=inp.compared,
        )
    doc.section(
        "Modality ablations: testbed success (Fig. 26)",
        "Each run's furthest-trained evaluated checkpoint, evaluated with the observation keys it was trained "
        "on; the figure has a panel per algorithm (and training set-up) trained with several modality sets, "
        "the table every run.",
        figure,
        table,
        "No testbed evaluation of a run's checkpoint given.",
    )


def _ablations(stats: pd.DataFrame) -> pd.DataFrame:
    """The groups (algorithm and training set-up) trained with several modality sets, where there are any: an
    ablation figure's panels (the table keeps every group; a panel per run trained with every sense only would bury
    them)."""
    # several modality sets, not several acting modes of one ("all [mode]", "all [sample]")
    modality = stats["label"].astype(str).str.split(" [", regex=False).str[0]
    several = modality.groupby(stats["group"], sort=False).transform("nunique") > 1
    return stats[several] if several.any() else stats


def _modality_key(name: str) -> tuple[int, str]:
    return (0 if name == "all" else 1, name)
