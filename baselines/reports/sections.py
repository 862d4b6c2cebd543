"""The report itself: its inputs read once (:class:`Inputs`), then one function per section, each adding its
Markdown, figure and tables to the :class:`Document` (the paper's Figs. 4a, 4b, 25 and 26, training curves, the
runs and what is missing), and :func:`build_report`, which runs them in order and writes the files.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import pandas as pd

import evaaa

from . import claims as rules
from .aggregate import STAT_COLUMNS, across_seeds, curves, final_survival, per_run, reference_stats
from .figures import plot_bars, plot_lines
from .load import (
    MODEL_FILE,
    Evaluations,
    ReportError,
    RunRecord,
    attach,
    describe_extras,
    final_checkpoints,
    find_run_dirs,
    labels,
    level_sorted,
    load_evaluations,
    load_run,
    select_acting,
)
from .tables import pivot_table


@dataclass
class Report:
    """What :func:`build_report` wrote: the Markdown file, the figures, the tables' numbers, the problems listed."""

    markdown: Path
    figures: list[Path]
    tables: dict[str, pd.DataFrame]
    problems: list[str]


@dataclass
class Document:
    """The report being written: Markdown lines, the figures drawn and the tables (``data/<name>.csv``)."""

    out: Path
    md: list[str] = field(default_factory=list)
    figures: list[Path] = field(default_factory=list)
    tables: dict[str, pd.DataFrame] = field(default_factory=dict)

    def section(self, heading: str, note: str, figure: Path | None, table: str | None, empty: str) -> None:
        """A section with a figure and its table, or the sentence ``empty`` when the inputs have no data for it."""
        self.md.extend([f"## {heading}", ""])
        if figure is None:
            self.md.extend([empty, ""])
            return
        self.figures.append(figure)
        self.md.extend([note, "", f"![{heading}]({figure.name})", "", table or "", ""])


@dataclass
class Inputs:
    """The runs and evaluations a report is about, with the numbers several sections share."""

    runs: dict[Path, RunRecord]  # every run, those added because a checkpoint of theirs was evaluated included
    evals: Evaluations
    read_notes: list[str]  # rows skipped while reading the evaluation files
    survival: str
    window: int
    bins: int

    @cached_property
    def run_list(self) -> list[RunRecord]:
        return sorted(self.runs.values(), key=lambda r: str(r.dir))

    @cached_property
    def usable(self) -> list[RunRecord]:
        return [r for r in self.run_list if r.usable]

    @cached_property
    def by_dir(self) -> dict[Path, RunRecord]:
        return {r.dir: r for r in self.usable}

    @cached_property
    def final(self) -> pd.DataFrame:
        """The survival every finished stage ended with (:func:`.aggregate.final_survival`)."""
        return final_survival(self.usable, self.survival, self.window)

    @cached_property
    def run_curves(self) -> pd.DataFrame:
        """Each run's binned training curve (:func:`.aggregate.curves`)."""
        return curves(self.usable, self.bins)

    @cached_property
    def curriculum_algos(self) -> set[tuple]:
        """(algorithm, modality, reward, other settings) of the curriculum runs."""
        return {(r.algo, r.modality, r.reward, r.extras) for r in self.usable if r.curriculum}

    @cached_property
    def source_note(self) -> str:
        """Where the final-survival values come from, for the sections that show them."""
        fallback = int((self.final["source"] == "train").sum()) if self.survival == "eval" else 0
        modes = {bool((r.config.get("eval") or {}).get("sample", False)) for r in self.usable}
        how = {frozenset({False}): "deterministic episodes", frozenset({True}): "episodes sampled from the policy"}.get(
            frozenset(modes), "deterministic episodes, or sampled ones where a run set `eval.sample`"
        )
        note = (
            f"Survival: the last evaluation of each finished stage (`eval.csv`, {how})"
            if self.survival == "eval"
            else f"Survival: the mean of each finished stage's last {self.window} training episodes"
        )
        if fallback:
            note += f"; {fallback} value(s) from the last {self.window} training episodes (stages without evaluation)"
        return note + "."

    @cached_property
    def checkpoint_runs(self) -> list[RunRecord]:
        """The runs whose checkpoints were evaluated, in the order of the evaluations."""
        ck = self.evals.checkpoints
        return [self.runs[d] for d in dict.fromkeys(ck["run"])] if len(ck) else []

    @cached_property
    def checkpoint_labels(self) -> dict[Path, str]:
        return labels(self.checkpoint_runs, ("algo", "modality", "reward", "extras", "training"))

    @cached_property
    def testbed_episodes(self) -> pd.DataFrame:
        """The evaluated checkpoints' episodes on testbeds."""
        ck = self.evals.checkpoints
        return ck[ck["level"].isin(evaaa.TESTBEDS)]

    @cached_property
    def best(self) -> pd.DataFrame:
        """Per run, the testbed episodes of its furthest-trained evaluated checkpoint."""
        return final_checkpoints(self.testbed_episodes)

    @cached_property
    def reference_training(self) -> pd.DataFrame:
        """Reference agents' survival on training levels."""
        refs = self.evals.references
        return reference_stats(refs[refs["level"].isin(evaaa.LEVELS)], "steps")

    def rel(self, p: Path) -> str:
        """``p`` relative to the current directory where it lies under it (the report names runs that way)."""
        try:
            return str(p.relative_to(Path.cwd()))
        except ValueError:
            return str(p)


def read_inputs(
    run_paths: Sequence[str | Path],
    eval_paths: Sequence[str | Path],
    *,
    survival: str = "eval",
    window: int = 20,
    bins: int = 20,
    acting: str | None = None,
) -> Inputs:
    """Check the arguments, read the runs and evaluations and tie the evaluated checkpoints to their runs."""
    if survival not in ("eval", "train"):
        raise ReportError(f"survival must be eval or train, not {survival!r}")
    if window < 1 or bins < 1:
        raise ReportError("window and bins must be positive")
    if not run_paths and not eval_paths:
        raise ReportError(
            "nothing to report: give runs=[...] (run directories) and/or evals=[...] (evaluate.py outputs)"
        )
    runs = {d: load_run(d) for d in find_run_dirs(run_paths)}
    # attach may add the runs of evaluated checkpoints
    read_notes: list[str] = []
    evals = attach(select_acting(load_evaluations(eval_paths, read_notes), acting), runs)
    inputs = Inputs(runs, evals, read_notes, survival, window, bins)
    describe_extras(inputs.usable)
    return inputs


# ------------------------------------------------------------------------------------------------ sections
def introduction(doc: Document, inp: Inputs, title: str) -> None:
    """Title, what was read, how to read the cells, how the checkpoints acted."""
    evals = inp.evals
    n_policies = evals.checkpoints["policy"].nunique() + evals.references["policy"].nunique()
    doc.md += [
        f"# {title}",
        "",
        f"{len(inp.run_list)} run directories; {n_policies} evaluated policies "
        f"({len(evals.checkpoints) + len(evals.references)} evaluation episodes).",
        "",
        "**Statistics.** Survival cells: `IQM [low, high]; mean ± se (n=…)` — the interquartile mean (mean of "
        "the middle 50 %) of the episodes with its 95 % percentile bootstrap interval (2000 resamples; "
        "episodes redrawn within each seed, seeds as strata; where a seed gives one number, its last "
        "evaluation's mean, the seeds' numbers are redrawn), then the mean over seeds of each seed's value ± "
        "the standard error across seeds (none with one seed). Success cells: `rate [low, high] (n=…)` — the "
        "share of successful episodes of all seeds pooled, with its 95 % Wilson score interval (not "
        "degenerate at 0 % or 100 %). n: seeds × episodes per seed (`2 seeds, 37 ep.` when seeds have "
        "unequal episodes). Reference agents (oracle, random): over episodes; human: participants as the "
        "units when there are several. Figures: bars and lines show the IQM or rate, whiskers and bands its "
        "95 % interval. Runs that differ only in their seed are pooled; labels name what else differs.",
        "",
    ]
    ways = list(dict.fromkeys(evals.checkpoints["acting"].astype(str))) if len(evals.checkpoints) else []
    if ways:
        doc.md += [
            "Checkpoints acted: "
            + ", ".join(f"`{w}`" if w else "not recorded" for w in ways)
            + " (evaluate.py: `mode` the most likely action, `sample` drawn from the policy, `+epsilon=e` a "
            "random action with chance e).",
            "",
        ]


def runs_and_problems(doc: Document, inp: Inputs) -> list[str]:
    """The table of runs and the list of what is missing, partial or doubtful; returns that list."""
    rel = inp.rel
    doc.md += [
        "## Runs",
        "",
        "| run | algo | modality | reward | training | seed | env steps | status |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in inp.run_list:
        status = "finished" if r.problem is None else r.problem.split(":")[0]
        doc.md.append(
            f"| {rel(r.dir)} | {r.algo} | {r.modality} | {r.reward} | {r.training} | "
            f"{'' if r.seed is None else r.seed} | {r.steps:,} / {r.total:,} | {status} |"
        )
    if inp.evals.absent:
        evaluated = inp.evals.checkpoints["policy"].nunique()
        doc.md += [
            "",
            f"{len(inp.evals.absent)} of the {evaluated} evaluated checkpoints are not on disk here, their "
            "runs are (a committed record keeps no model files): their recorded episodes are used.",
        ]
    problems = [f"{rel(r.dir)}: {r.problem}" for r in inp.run_list if r.problem] + inp.evals.orphans
    problems += [note for r in inp.run_list for note in r.notes] + inp.read_notes
    groups: dict[tuple, list[RunRecord]] = {}
    for r in inp.usable:
        groups.setdefault((r.algo, r.modality, r.reward, r.extras, r.training, r.seed), []).append(r)
    problems += [
        f"{', '.join(rel(r.dir) for r in same)}: same settings and seed; all are counted as seeds"
        for same in groups.values()
        if len(same) > 1
    ]
    doc.md += ["", "## Missing and partial runs", ""]
    doc.md += (
        [f"- {p}" for p in problems]
        if problems
        else ["None: every run finished and every evaluated checkpoint belongs to a run given here."]
    )
    doc.md.append("")
    return problems


def survival_per_level(doc: Document, inp: Inputs) -> None:
    """Fig. 4a, left: the survival each training level ended with, per algorithm (curriculum runs where an
    algorithm has them, else its direct runs)."""
    final = inp.final
    left_runs = [
        r for r in inp.usable if r.curriculum or (r.algo, r.modality, r.reward, r.extras) not in inp.curriculum_algos
    ]
    table = figure = None
    if len(final):
        lab = labels(left_runs)
        f = final[final["run"].isin(list(lab))].assign(label=lambda d: d["run"].map(lab))
        stats = across_seeds(f, ["label", "level"], "survival")
        doc.tables["survival_per_level"] = stats
        levels = level_sorted(stats["level"])
        figure = plot_bars(
            stats,
            doc.out / "fig4a_survival_per_level.png",
            levels=levels,
            ylabel="survival (decisions)",
            title="Survival per training level",
        )
        table = pivot_table(stats, "level", "label", rows=levels)
    doc.section(
        "Survival per training level (Fig. 4a, left)",
        inp.source_note + " Curriculum runs where an algorithm has them, else its direct runs.",
        figure,
        table,
        "No finished stage in the runs given.",
    )


def curriculum_vs_direct(doc: Document, inp: Inputs) -> None:
    """Fig. 4a, right: per level, curriculum runs' stage of that level beside runs trained on that level alone."""
    usable, final = inp.usable, inp.final
    both = {
        k
        for k in inp.curriculum_algos
        if any(not r.curriculum and (r.algo, r.modality, r.reward, r.extras) == k for r in usable)
    }
    cmp_runs = [r for r in usable if (r.algo, r.modality, r.reward, r.extras) in both]
    table = figure = None
    if cmp_runs and len(final):
        lab = {
            d: f"{v} · {'curriculum' if inp.by_dir[d].curriculum else 'direct'}"
            for d, v in labels(cmp_runs, ("algo", "modality", "reward", "extras")).items()
        }
        f = final[final["run"].isin(list(lab))].assign(label=lambda d: d["run"].map(lab))
        f = f[f["level"].isin(set(f[f["label"].str.endswith("direct")]["level"]))]  # levels with direct runs
        stats = across_seeds(f, ["label", "level"], "survival").sort_values(
            "label", key=lambda s: s.str.endswith("direct"), kind="stable"
        )
        doc.tables["curriculum_vs_direct"] = stats
        levels = level_sorted(stats["level"])
        if len(stats):
            figure = plot_bars(
                stats,
                doc.out / "fig4a_curriculum_vs_direct.png",
                levels=levels,
                ylabel="survival (decisions)",
                title="With and without curriculum",
            )
            table = pivot_table(stats, "level", "label", rows=levels)
    doc.section(
        "With and without curriculum (Fig. 4a, right)",
        inp.source_note + " Curriculum: the stage of that level after the levels before it; direct: a run "
        "trained on that level alone.",
        figure,
        table,
        "No algorithm has both curriculum runs (`level=curriculum`) and direct runs (`level=<level>`) here.",
    )


def success_per_testbed(doc: Document, inp: Inputs) -> None:
    """Fig. 4b, left: success per testbed of each run's furthest-trained evaluated checkpoint, with the reference
    agents beside."""
    refs = inp.evals.references
    ref_tests = reference_stats(refs[refs["level"].isin(evaaa.TESTBEDS)], "success")
    table = figure = None
    note = (
        "Each run's furthest-trained evaluated checkpoint; its episodes pooled over seeds (Wilson interval); n: "
        "seeds × episodes for trained agents, episodes (or human participants) for the others."
    )
    if len(inp.best) or len(ref_tests):
        stats = (
            across_seeds(
                per_run(inp.best, "success").assign(label=lambda d: d["run"].map(inp.checkpoint_labels)),
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
        # references; every other run (direct, ablations) stays in the table, where dozens of bars are still legible
        agents = set(stats.loc[stats["unit"] == "seeds", "label"])
        paper = _curriculum_labels(inp)
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
        )
        table = pivot_table(stats, "level", "label", rows=testbeds, percent=True, row_title="testbed")
    doc.section(
        "Success per testbed (Fig. 4b, left)", note, figure, table, "No testbed evaluation given (`evals=[...]`)."
    )


def _curriculum_labels(inp: Inputs) -> set[str]:
    """The labels of the evaluated runs trained through a curriculum with every sense: the agents the paper's
    Fig. 4b draws."""
    return {inp.checkpoint_labels[r.dir] for r in inp.checkpoint_runs if r.curriculum and r.modality == "all"}


def generalisation(doc: Document, inp: Inputs) -> None:
    """Fig. 4b, right: per evaluated checkpoint, its success averaged over the testbeds, at the level it was trained
    up to; reference agents as horizontal lines."""
    tests, refs = inp.testbed_episodes, inp.evals.references
    table = figure = None
    if len(tests):
        per_ckpt = per_run(tests, "success", ("run", "policy", "ckpt_stage", "ckpt_level", "level"))
        mean_tb = (
            per_ckpt.groupby(["run", "policy", "ckpt_stage", "ckpt_level"], sort=False)
            .agg(
                success=("success", "mean"),
                testbeds=("success", "size"),
                scores=("scores", lambda s: tuple(x for one in s for x in one)),
            )
            .reset_index()
        )
        mean_tb = mean_tb.sort_values(
            "policy", key=lambda p: p.map(lambda s: not MODEL_FILE.match(Path(s).name)), kind="stable"
        ).drop_duplicates(["run", "ckpt_stage"])
        stats = across_seeds(
            mean_tb.assign(label=lambda d: d["run"].map(inp.checkpoint_labels)),
            ["label", "ckpt_level"],
            "success",
            success=True,
        ).rename(columns={"ckpt_level": "level"})
        doc.tables["generalisation"] = stats
        order = level_sorted(stats["level"])
        ref_tb = refs[refs["level"].isin(evaaa.TESTBEDS)]
        ref_mean = reference_stats(ref_tb.assign(level="testbeds"), "success") if len(ref_tb) else None
        paper = _curriculum_labels(inp)
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
        )
        tb_names = ", ".join(level_sorted(tests["level"]))
        table = pivot_table(stats, "level", "label", rows=order, percent=True, row_title="trained up to")
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


def evaluation_survival(doc: Document, inp: Inputs) -> None:
    """Survival in evaluations on training levels, when there are any (a table, no figure)."""
    ck = inp.evals.checkpoints
    train_ck = final_checkpoints(ck[ck["level"].isin(evaaa.LEVELS)])
    ref_train = inp.reference_training
    if not (len(train_ck) or len(ref_train)):
        return
    stats = (
        across_seeds(
            per_run(train_ck, "steps").assign(label=lambda d: d["run"].map(inp.checkpoint_labels)),
            ["label", "level"],
            "steps",
        )
        if len(train_ck)
        else ref_train.iloc[:0]
    )
    stats = pd.concat([stats.assign(unit="seeds"), ref_train], ignore_index=True)
    doc.tables["evaluation_survival"] = stats
    doc.md += [
        "## Evaluation on training levels",
        "",
        "Survival (decisions) in evaluate.py's episodes (cells as described under Statistics); checkpoints as above.",
        "",
        pivot_table(stats, "level", "label", rows=level_sorted(stats["level"])),
        "",
    ]


def training_curves(doc: Document, inp: Inputs) -> None:
    """Training survival against env steps: one panel per training set-up, one line per algorithm and settings,
    reference agents' evaluations on the level as dashed lines."""
    all_curves, by_dir, ref_train = inp.run_curves, inp.by_dir, inp.reference_training
    table = figure = None
    if len(all_curves):
        lab = labels(inp.usable, ("algo", "modality", "reward", "extras"))
        by = all_curves.assign(
            group=lambda d: d["run"].map(lambda x: f"trained on {by_dir[x].training}"),
            label=lambda d: d["run"].map(lab),
        )
        stats = across_seeds(by, ["group", "label", "bin", "steps"], "survival")
        doc.tables["training_curves"] = stats
        trained_on = {by_dir[d].training for d in by["run"]}
        hl = None
        if len(trained_on) == 1 and len(ref_train):
            hl = ref_train[ref_train["level"] == next(iter(trained_on))]
            hl = hl.assign(label=hl["label"] + " (evaluation)") if len(hl) else None
        figure = plot_lines(
            stats,
            doc.out / "fig_training_curves.png",
            x="steps",
            panel="group",
            band=True,
            ylabel="survival (decisions)",
            xlabel="env steps",
            title="Training curves",
            hlines=hl,
        )
        ends = stats.sort_values("bin").groupby(["group", "label"], sort=False).tail(1)
        table = pivot_table(ends.rename(columns={"group": "level"}), "level", "label", row_title="training")
        table += (
            f"\n\nCurves: survival of the training episodes (exploring policy) in {inp.bins} bins of env "
            "steps, IQM of the bin's episodes with its 95 % bootstrap interval (band); table: the last bin. "
            "Dashed/dotted: reference agents' IQM survival in evaluate.py's episodes on that level, when given."
        )
    doc.section(
        "Training curves",
        "One panel per training set-up, one line per algorithm and settings.",
        figure,
        table,
        "No finished training episode in the runs given.",
    )


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
        )
        final = inp.final
        last = final[final["last"]].assign(
            group=lambda d: d["run"].map(ab_lab), label=lambda d: d["run"].map(lambda x: by_dir[x].modality)
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
            )
            if len(fstats)
            else ""
        )
        table += (
            f"\n\nCurves: survival of training episodes in {inp.bins} bins of env steps, IQM with its 95 % "
            "bootstrap interval (band). Table: survival at the end of each run ("
            + ("last evaluation" if inp.survival == "eval" else f"last {inp.window} training episodes")
            + ")."
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
            per_run(inp.best, "success").assign(
                group=lambda d: d["run"].map(ab_ck), label=lambda d: d["run"].map(lambda x: inp.runs[x].modality)
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
        )
        stats = (
            stats.assign(column=stats["group"] + " · " + stats["label"])
            if stats["group"].nunique() > 1
            else stats.assign(column=stats["label"])
        )
        table = pivot_table(
            stats, "level", "column", rows=level_sorted(stats["level"]), percent=True, row_title="testbed"
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
    several = stats.groupby("group", sort=False)["label"].transform("nunique") > 1
    return stats[several] if several.any() else stats


def _modality_key(name: str) -> tuple[int, str]:
    return (0 if name == "all" else 1, name)


def _pooled_success(episodes: pd.DataFrame, by: Sequence[str]) -> pd.DataFrame:
    """Per ``by`` (``run`` among them): the successes of all its testbed episodes pooled, as one seed's scores."""
    grouped = episodes.assign(_v=episodes["success"].astype(float)).groupby(list(by), sort=False)["_v"]
    return grouped.agg(success="mean", scores=lambda v: tuple(v.dropna())).reset_index()


def claim_verdicts(inp: Inputs) -> list[rules.Verdict]:
    """The verdicts of claims (a)–(e) (:mod:`.claims`) from the report's inputs: survival per level from the final
    survival of every finished stage of runs with every sense (curriculum runs where an algorithm has them, else its
    direct runs), testbed success of each run's furthest-trained checkpoint, generalisation of curriculum runs'
    stage models, and the ablations: runs of one algorithm and training set-up with several modality sets."""
    order = list(evaaa.LEVELS)
    runs = inp.by_dir
    empty = pd.DataFrame(columns=["algo", "setup", "level", *STAT_COLUMNS])
    final = inp.final
    full = final[final["run"].map(lambda d: runs[d].modality == "all")] if len(final) else final
    if len(full):
        full = full.assign(
            algo=full["run"].map(lambda d: runs[d].algo),
            setup=full["run"].map(lambda d: "curriculum" if runs[d].curriculum else "direct"),
        )
        by_setup = across_seeds(full, ["algo", "setup", "level"], "survival")
    else:
        by_setup = empty
    with_cur = set(by_setup.loc[by_setup["setup"] == "curriculum", "algo"])
    survival = by_setup[(by_setup["setup"] == "curriculum") | ~by_setup["algo"].isin(with_cur)]
    random = inp.reference_training
    random = random[random["label"] == "random"] if len(random) else random

    def agent(d: Path) -> str:
        r = inp.runs[d]
        return f"{r.algo} · {r.training}"

    best = inp.best
    best = best[best["run"].map(lambda d: inp.runs[d].modality == "all")] if len(best) else best
    if len(best):
        best = best[best["run"].map(lambda d: inp.runs[d].curriculum or inp.runs[d].algo not in with_cur)]
    success = (
        across_seeds(
            per_run(best, "success").assign(agent=lambda d: d["run"].map(agent)),
            ["agent", "level"],
            "success",
            success=True,
        )
        if len(best)
        else pd.DataFrame(columns=["agent", "level", *STAT_COLUMNS])
    )
    refs = inp.evals.references
    ref_tests = (
        reference_stats(refs[refs["level"].isin(evaaa.TESTBEDS)], "success").rename(columns={"label": "agent"})
        if len(refs)
        else pd.DataFrame(columns=["agent", "level", *STAT_COLUMNS])
    )

    tests = inp.testbed_episodes
    tests = (
        tests[
            tests["run"].map(lambda d: inp.runs[d].curriculum and inp.runs[d].modality == "all")
            & tests["policy"].map(lambda p: bool(MODEL_FILE.match(Path(p).name)))
        ]
        if len(tests)
        else tests
    )
    gen = (
        across_seeds(
            _pooled_success(tests, ["run", "ckpt_level"]).assign(
                agent=lambda d: d["run"].map(lambda x: inp.runs[x].algo)
            ),
            ["agent", "ckpt_level"],
            "success",
            success=True,
        ).rename(columns={"ckpt_level": "level"})
        if len(tests)
        else pd.DataFrame(columns=["agent", "level", *STAT_COLUMNS])
    )

    verdicts = [
        rules.survival_falls(survival, order),
        rules.curriculum_beats_direct(by_setup, order),
        rules.algorithm_ordering(survival, random, order),
        rules.testbeds_below_ceiling(success, ref_tests, gen, order),
    ]
    # ablations: runs of one algorithm and training set-up (a level, or the curriculum) with several modality sets
    groups: dict[tuple, list[RunRecord]] = {}
    for r in inp.usable:
        groups.setdefault((r.algo, r.training), []).append(r)
    groups = {k: v for k, v in groups.items() if len({r.modality for r in v}) > 1}
    if not groups:
        verdicts.append(
            rules.missing(
                rules.ablations(pd.DataFrame(), pd.DataFrame()).claim,
                "no runs of one algorithm and level with several modality sets",
            )
        )
    for (algo, level), members in groups.items():
        dirs = {r.dir: r.modality for r in members}
        last = final[final["run"].isin(list(dirs)) & final["last"]] if len(final) else final
        surv = (
            across_seeds(last.assign(modality=last["run"].map(dirs)), ["modality"], "survival")
            if len(last)
            else pd.DataFrame(columns=["modality", *STAT_COLUMNS])
        )
        ab_best = inp.best[inp.best["run"].isin(list(dirs))] if len(inp.best) else inp.best
        succ = (
            across_seeds(
                _pooled_success(ab_best, ["run"]).assign(modality=lambda d: d["run"].map(dirs)),
                ["modality"],
                "success",
                success=True,
            )
            if len(ab_best)
            else pd.DataFrame(columns=["modality", *STAT_COLUMNS])
        )
        v = rules.ablations(surv, succ)
        v.claim += f" ({algo}, trained on {level})"
        verdicts.append(v)
    return verdicts


def claims(doc: Document, inp: Inputs) -> None:
    """The paper's claims (a)–(e), one by one: reproduced, contradicted or not resolvable at this scale, with the
    rule and the numbers (:mod:`.claims`)."""
    acting = list(dict.fromkeys(inp.evals.checkpoints["acting"].astype(str))) if len(inp.evals.checkpoints) else []
    doc.md += [
        "## The paper's claims",
        "",
        "Each claim of the EVAAA paper judged against the numbers above by a fixed rule: two cells differ only "
        "where their 95 % intervals do not overlap, and overlapping intervals never decide a claim (not "
        "resolvable at this scale). A claim of several parts is reproduced when every part is, contradicted "
        "when some part is and none is reproduced. Survival per level: "
        + inp.source_note[len("Survival: ") :].rstrip(".")
        + " (runs with every sense; curriculum runs where an "
        "algorithm has them). Testbed success: each run's furthest-trained evaluated checkpoint"
        + (f", acting {', '.join(f'`{a}`' for a in acting)}" if acting else "")
        + ".",
        "",
    ]
    doc.md += rules.markdown(claim_verdicts(inp))
    doc.md.append("")


#: The sections after the runs, in the order the report shows them.
SECTIONS = (
    survival_per_level,
    curriculum_vs_direct,
    success_per_testbed,
    generalisation,
    evaluation_survival,
    training_curves,
    ablation_curves,
    ablation_success,
    claims,
)


# ------------------------------------------------------------------------------------------------ the report
def build_report(
    run_paths: Sequence[str | Path],
    eval_paths: Sequence[str | Path],
    out: str | Path,
    *,
    survival: str = "eval",
    window: int = 20,
    bins: int = 20,
    title: str = "evaaa report",
    acting: str | None = None,
) -> Report:
    """Read runs and evaluations, write ``out/report.md``, its PNG figures and ``out/data/*.csv`` (the tables'
    numbers); returns what was written.  ``acting``: which of the checkpoints' evaluation modes to report
    (:func:`.load.select_acting`)."""
    inp = read_inputs(run_paths, eval_paths, survival=survival, window=window, bins=bins, acting=acting)
    doc = Document(Path(out))
    (doc.out / "data").mkdir(parents=True, exist_ok=True)
    introduction(doc, inp, title)
    problems = runs_and_problems(doc, inp)
    for section in SECTIONS:
        section(doc, inp)
    for name, frame in doc.tables.items():
        frame.to_csv(doc.out / "data" / f"{name}.csv", index=False)
    if len(inp.run_curves):
        rows = inp.run_curves.assign(run=inp.run_curves["run"].map(inp.rel))
        rows.to_csv(doc.out / "data" / "curves_per_run.csv", index=False)
    path = doc.out / "report.md"
    path.write_text("\n".join(doc.md).rstrip() + "\n")
    return Report(path, doc.figures, doc.tables, problems)
