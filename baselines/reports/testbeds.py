"""The sections of testbed success: success per testbed (Fig. 4b, left) and generalisation by training level
(Fig. 4b, right); :func:`mean_testbed_success`, a checkpoint's success over the testbeds."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

import evaaa

from .aggregate import across_seeds, per_run, reference_stats
from .document import Document, Inputs
from .figures import plot_bars, plot_lines
from .load import MODEL_FILE, level_sorted
from .tables import pivot_table


def success_per_testbed(doc: Document, inp: Inputs) -> None:
    """Fig. 4b, left: success per testbed of each run's furthest-trained evaluated checkpoint, with the reference
    agents beside."""
    refs = inp.evals.references
    ref_tests = reference_stats(refs[refs["level"].isin(evaaa.TESTBEDS)], "success")
    table = figure = None
    note = (
        "Each run's furthest-trained evaluated checkpoint; its episodes pooled over seeds (seed-clustered Wilson "
        "interval); n: seeds × episodes for trained agents, episodes (or human participants) for the others."
    )
    if len(inp.best) or len(ref_tests):
        stats = (
            across_seeds(
                inp.labelled(per_run(inp.best, "success"), inp.checkpoint_labels),
                ["label", "level"],
                "success",
                success=True,
            )
            if len(inp.best)
            else ref_tests.iloc[:0]
        )
        stats = pd.concat([stats.assign(unit="seeds"), ref_tests], ignore_index=True)
        doc.tables["success_per_testbed"] = stats
        testbeds = level_sorted(stats["level"])
        # the figure, as the paper's: the agents trained through the curriculum with every sense, beside the
        # references; every other run (direct, ablations) stays in the table
        agents = set(stats.loc[stats["unit"] == "seeds", "label"])
        paper = _curriculum_labels(inp, stats["label"])
        shown = stats[~stats["label"].isin(agents - paper)] if paper and agents - paper else stats
        if len(shown) < len(stats):
            note += (
                f" The figure shows the {len(agents & paper)} curriculum-trained agents with every sense beside "
                "the references; the table has every run."
            )
        figure = plot_bars(
            shown,
            doc.out / "fig4b_success_per_testbed.png",
            levels=testbeds,
            scale=100,
            top=105,
            ylabel="success rate (%)",
            title="Success per testbed",
            compared=inp.compared,
        )
        table = pivot_table(
            stats,
            "level",
            "label",
            rows=testbeds,
            percent=True,
            row_title="testbed",
            title="Success per testbed",
            compared=inp.compared,
        )
    doc.section(
        "Success per testbed (Fig. 4b, left)", note, figure, table, "No testbed evaluation given (`evals=[...]`)."
    )


def _curriculum_labels(inp: Inputs, shown: pd.Series | None = None) -> set[str]:
    """The labels of the evaluated runs trained through a curriculum with every sense: the agents the paper's
    Fig. 4b draws (with their acting modes where ``shown`` labels them so)."""
    base = {inp.checkpoint_labels[r.dir] for r in inp.checkpoint_runs if r.curriculum and r.modality == "all"}
    if shown is None:
        return base
    return {s for s in shown if s.split(" [")[0] in base}


def generalisation(doc: Document, inp: Inputs) -> None:
    """Fig. 4b, right: per evaluated checkpoint, its success averaged over the testbeds, at the level it was trained
    up to; reference agents as horizontal lines."""
    tests, refs = inp.testbed_episodes, inp.evals.references
    table = figure = None
    if len(tests):
        stats = across_seeds(
            inp.labelled(mean_testbed_success(tests), inp.checkpoint_labels),
            ["label", "ckpt_level"],
            "success",
            success=True,
        ).rename(columns={"ckpt_level": "level"})
        doc.tables["generalisation"] = stats
        order = level_sorted(stats["level"])
        ref_tb = refs[refs["level"].isin(evaaa.TESTBEDS)]
        ref_mean = reference_stats(ref_tb.assign(level="testbeds"), "success") if len(ref_tb) else None
        paper = _curriculum_labels(inp, stats["label"])
        shown = stats[stats["label"].isin(paper)] if paper and set(stats["label"]) - paper else stats
        figure = plot_lines(
            shown,
            doc.out / "fig4b_generalisation.png",
            x="level",
            panel=None,
            order=order,
            ylabel="mean testbed success (%)",
            xlabel="trained up to level",
            scale=100,
            top=105,
            band=False,
            title="Generalisation by training level",
            hlines=ref_mean,
            compared=inp.compared,
        )
        tb_names = ", ".join(level_sorted(tests["level"]))
        table = pivot_table(
            stats,
            "level",
            "label",
            rows=order,
            percent=True,
            row_title="trained up to",
            title="Mean testbed success by training level",
            compared=inp.compared,
        )
        table += f"\n\nTestbeds averaged: {tb_names} (each checkpoint over the testbeds it was evaluated on)."
    doc.section(
        "Generalisation by training level (Fig. 4b, right)",
        "Success averaged over the testbeds, for checkpoints trained up to each level "
        "(`model-<stage>-<level>.pt` of curriculum runs; a direct run's checkpoint at its level); dashed: "
        "reference agents. Where there are curriculum runs with every sense, the figure draws those (the "
        "paper's view) and the table every run.",
        figure,
        table,
        "No testbed evaluation of a run's checkpoint given.",
    )


def mean_testbed_success(tests: pd.DataFrame) -> pd.DataFrame:
    """Per run, stage network and acting mode: the successes of all its testbed episodes, as one seed's scores
    (the final model of a stage preferred to its best model and to ``checkpoint.pt``)."""
    per_ckpt = per_run(tests, "success", ("run", "policy", "ckpt_stage", "ckpt_level", "level"))
    mean_tb = (
        per_ckpt.groupby(["run", "policy", "ckpt_stage", "ckpt_level", "acting"], sort=False)
        .agg(
            success=("success", "mean"),
            scores=("scores", lambda s: tuple(x for one in s for x in one)),
            worlds=("worlds", lambda w: " / ".join(dict.fromkeys(w))),
            source=("source", "first"),
        )
        .reset_index()
    )
    mean_tb["episodes"] = mean_tb["scores"].map(len)
    return mean_tb.sort_values(
        "policy", key=lambda p: p.map(lambda s: not MODEL_FILE.match(Path(s).name)), kind="stable"
    ).drop_duplicates(["run", "ckpt_stage", "acting"])
