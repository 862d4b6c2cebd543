"""The report itself: its inputs read once (:class:`Inputs`), then one function per section, each adding its
Markdown, figure and tables to the :class:`Document` (the paper's Figs. 4a, 4b, 25 and 26, what each agent learned
beside the references, training curves, the runs and what is missing), and :func:`build_report`, which runs them in
order and writes the files.  Every table names how the agents acted and on which worlds (its caption, and the
``acting`` and ``worlds`` columns of its CSV); an agent evaluated in several ways gets one labelled column per way.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import pandas as pd

import evaaa

from ..paper import claims as rules
from ..paper.choice import choice_text
from .aggregate import STAT_COLUMNS, across_seeds, curves, evaluation_points, final_survival, per_run, reference_stats
from .figures import plot_bars, plot_lines
from .load import (
    GREEDY_STAND_IN,
    MODEL_FILE,
    Evaluations,
    ReportError,
    RunRecord,
    attach,
    can_sample,
    check_acting,
    describe_extras,
    final_checkpoints,
    find_run_dirs,
    labels,
    level_sorted,
    load_evaluations,
    load_run,
    select_acting,
    stand_in,
)
from .matched import curve_points, learned_gate, reaching, threshold
from .stats import MIN_SEEDS
from .tables import capped, caption, cell, censored_note, markdown_table, pivot_table, summarize


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
    # the acting mode the claims compare (report option ``compare``); None: the mode every run has, else each run's
    # most frequent (:func:`_one_mode`)
    compare: str | None = None
    # report option ``learned``: an agent enters the claims' comparisons only if its all-senses network survives the
    # first level at least this many times the better of random and stand-still (:mod:`.matched`); None: every agent
    learned_factor: float | None = None
    # the verdict rules' settings (margins; a protocol's ``report.verdicts``); "fails" uses ``learned_factor`` where set
    verdict_rules: rules.Rules = field(default_factory=lambda: rules.Rules())
    # where ``compare`` was chosen from validation rows (a protocol's compared_mode.json, report option
    # ``compare_from``): that file's data, which the report states with its numbers; None: a fixed choice
    choice: dict | None = None

    @cached_property
    def verdicts(self) -> list[rules.Verdict]:
        """Claims (a)–(e) judged on these inputs (:func:`claim_verdicts`): the summary at the top and the claims
        section at the end share them."""
        return claim_verdicts(self)

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
        return final_survival(self.usable, self.survival, self.window, self.evals.checkpoints)

    @cached_property
    def run_curves(self) -> pd.DataFrame:
        """Each run's binned training curve (:func:`.aggregate.curves`)."""
        return curves(self.usable, self.bins)

    @cached_property
    def curriculum_algos(self) -> set[tuple]:
        """The settings (:func:`setting`) of the curriculum runs."""
        return {setting(r) for r in self.usable if r.curriculum}

    @cached_property
    def source_note(self) -> str:
        """Where the final-survival values come from, for the sections that show them."""
        # stages, not rows: a stage evaluated in two acting modes is one stage
        counts = (
            self.final.drop_duplicates(["run", "stage"])["source"].value_counts()
            if len(self.final)
            else pd.Series(dtype=int)
        )
        said = {
            "evaluate.py": "the stage's network evaluated by evaluate.py on its level (one row per episode)",
            "eval.csv": "the stage's last in-training evaluation (`eval.csv`, one row per episode)",
            "eval.csv (means only)": "the stage's last in-training evaluation, of which `eval.csv` (an older "
            "format) kept only the mean: means only",
            "training episodes": f"the stage's last {self.window} training episodes (exploring policy)",
        }
        parts = [f"{said.get(k, k)} ({v} stage{'s' if v != 1 else ''})" for k, v in counts.items() if k != "none"]
        return "Survival: " + ("; ".join(parts) if parts else "none") + "."

    @cached_property
    def checkpoint_runs(self) -> list[RunRecord]:
        """The runs whose checkpoints were evaluated, in the order of the evaluations."""
        ck = self.evals.checkpoints
        return [self.runs[d] for d in dict.fromkeys(ck["run"])] if len(ck) else []

    @cached_property
    def checkpoint_labels(self) -> dict[Path, str]:
        return labels(self.checkpoint_runs, ("algo", "modality", "reward", "extras", "training"))

    def labelled(
        self, frame: pd.DataFrame, labels: dict[Path, str], column: str = "label", within: Sequence[str] = ()
    ) -> pd.DataFrame:
        """``frame`` (rows with ``run`` and ``acting``) with ``column`` = the run's label, and the acting mode in
        brackets wherever one label (within one value of each of ``within``: a figure's panel) holds rows of several
        modes (both shown, labelled, never pooled)."""
        if not len(frame):
            return frame.assign(**{column: pd.Series(dtype=str)})
        out = frame.assign(**{column: frame["run"].map(labels)})
        ways = out.groupby([*within, column])["acting"].transform("nunique")
        return out.assign(**{column: out[column].where(ways < 2, out[column] + " [" + out["acting"] + "]")})

    @cached_property
    def greedy_algos(self) -> list[str]:
        """The algorithms without an action distribution (DQN) when the claims compare sampled actions: their
        checkpoints take part with their greedy action (:func:`.load.stand_in`)."""
        if self.compare is None or stand_in(self.compare) is None:
            return []
        return sorted({r.algo for r in self.runs.values() if r.algo and not can_sample(r.algo)})

    @cached_property
    def compared(self) -> str:
        """The acting the claims compare, in words for the captions (Markdown); "" without ``compare``."""
        if self.compare is None:
            return ""
        greedy = self.greedy_algos
        said = {"mode": "the most likely action", "sample": "sampled actions"}[self.compare.split("+")[0]]
        return f"`{self.compare}` ({said}" + (
            f"; {', '.join(greedy)}: `{stand_in(self.compare)}`, greedy: it has no action distribution)"
            if greedy
            else ")"
        )

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
    def learned(self) -> pd.DataFrame:
        """The "what it learned" table (:func:`learned_table`)."""
        return learned_table(self)

    @cached_property
    def reference_training(self) -> pd.DataFrame:
        """Reference agents' survival on training levels."""
        refs = self.evals.references
        return reference_stats(refs[refs["level"].isin(evaaa.LEVELS)], "steps")

    @cached_property
    def matched(self) -> list[RunRecord]:
        """The compute-matched runs with every sense (bounded by CPU minutes: :attr:`.load.RunRecord.cpu_budget`)."""
        return [r for r in self.usable if r.cpu_budget is not None and r.modality == "all" and not r.curriculum]

    @cached_property
    def gate(self) -> pd.DataFrame:
        """Which algorithms learned the first level (:func:`.matched.learned_gate`), in the compared acting mode:
        a row per algorithm for its runs with a step budget and one for its compute-matched runs (column
        ``compute_bound``); empty without the report option ``learned``."""
        if self.learned_factor is None:
            return pd.DataFrame(columns=["algo", "compute_bound", "learned", "reading"])
        final = _one_mode(self.final, self)
        args = (self.usable, final, self.reference_training, evaaa.LEVELS[0], self.learned_factor)
        return pd.concat([learned_gate(*args), learned_gate(*args, compute_bound=True)], ignore_index=True)

    def gate_of(self, compute_bound: bool) -> pd.DataFrame:
        gate = self.gate
        return gate[gate["compute_bound"] == compute_bound] if len(gate) else gate

    def enters(self, run: RunRecord) -> bool:
        """Whether ``run``'s agent takes part in the claims' comparisons: always without ``learned``, else only if
        its algorithm learned at the budget of its kind (compute-matched or a step budget)."""
        if self.learned_factor is None:
            return True
        gate = self.gate_of(run.cpu_budget is not None)
        return bool(gate.loc[gate["algo"] == run.algo, "learned"].any())

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
    compare: str | None = None,
    learned: float | None = None,
    margin: float = 0.1,
    gain_margin: float = 0.1,
    choice: dict | None = None,
) -> Inputs:
    """Check the arguments, read the runs and evaluations and tie the evaluated checkpoints to their runs."""
    if survival not in ("eval", "train"):
        raise ReportError(f"survival must be eval or train, not {survival!r}")
    if window < 1 or bins < 1:
        raise ReportError("window and bins must be positive")
    if learned is not None and not learned > 0:
        raise ReportError(f"learned must be a positive factor (e.g. 2), not {learned!r}")
    if not 0 <= margin < 1:
        raise ReportError(f"margin must lie in [0, 1), not {margin!r}")
    if not 0 < gain_margin < 1:
        raise ReportError(f"gain_margin must lie in (0, 1), not {gain_margin!r}")
    check_acting("compare", compare)
    if not run_paths and not eval_paths:
        raise ReportError(
            "nothing to report: give runs=[...] (run directories) and/or evals=[...] (evaluate.py outputs)"
        )
    runs = {d: load_run(d) for d in find_run_dirs(run_paths)}
    # attach may add the runs of evaluated checkpoints
    read_notes: list[str] = []
    evals = attach(load_evaluations(eval_paths, read_notes), runs)
    evals.checkpoints = select_acting(evals.checkpoints, acting, runs)
    if compare is not None and len(evals.checkpoints):
        _check_compared(evals.checkpoints, runs, compare)
    verdict_rules = rules.Rules(
        margin=margin,
        fails_factor=learned if learned is not None else rules.Rules().fails_factor,
        gain_margin=gain_margin,
    )
    inputs = Inputs(runs, evals, read_notes, survival, window, bins, compare, learned, verdict_rules, choice)
    describe_extras(inputs.usable)
    return inputs


def _check_compared(ckpts: pd.DataFrame, runs: dict[Path, RunRecord], compare: str) -> None:
    """A :class:`ReportError` when no checkpoint was evaluated acting ``compare`` (nor, for one without an action
    distribution, acting its stand-in)."""
    greedy = ckpts["run"].map(lambda d: d in runs and not can_sample(runs[d].algo))
    acting = ckpts["acting"].astype(str)
    if not ((acting == compare) | (greedy & (acting == (stand_in(compare) or compare)))).any():
        raise ReportError(
            f"compare: no checkpoint was evaluated acting {compare!r}; the evaluations hold "
            f"{', '.join(repr(m) for m in dict.fromkeys(acting))}"
        )


# ------------------------------------------------------------------------------------------------ sections
STATISTICS_NOTE = (
    "**Statistics.** Seeds (training runs) are the unit. Survival cells: `IQM [low, high]; mean ± se (n=…)` — the "
    "interquartile mean (mean of the middle 50 %) of the seeds' episodes pooled, with its 95 % percentile interval "
    "from a two-stage bootstrap (2000 replicates: the seeds redrawn with replacement, then each drawn seed's episodes "
    "redrawn from its own; rliable's stratified bootstrap with the episodes within seeds added), then the mean over "
    "seeds of each seed's mean ± the standard error across seeds. Success cells: `rate [low, high] (n=…)` — the "
    "share of successful episodes of all seeds pooled, with a 95 % Wilson interval on the effective number of "
    "episodes (seed-clustered: episodes of one seed are not independent). "
    f"**Under {MIN_SEEDS} seeds a cell has no interval**: it shows its point and each seed's value (`; seeds a, b`), "
    "and no claim is decided on it. n: seeds × episodes per seed (`2 seeds, 37 ep.` when seeds have unequal "
    "episodes; `× mean of 8 ep.` where a seed gave only an evaluation's mean). Reference agents (oracle, random, "
    "stand-still) are one fixed policy each: their episodes are the units; human play: participants. Figures: bars "
    "and lines show the IQM or rate, whiskers and bands its 95 % interval, dots the seeds where there is none. Runs "
    "that differ only in their seed are pooled; labels name what else differs. Every table's title names how the "
    "agents acted (`mode`: the greedy or most likely action; `sample`: drawn from the policy's distribution; "
    "`+epsilon=e`: a uniformly random action with chance e) and on which worlds (`test`: held out; `validation`: "
    "the periodic evaluations and tuning; anything else is not held out)."
)


def introduction(doc: Document, inp: Inputs, title: str) -> None:
    """Title, what the agents learned (a paragraph and a line per agent), what was read, how to read the cells,
    how the checkpoints acted and on which worlds."""
    evals = inp.evals
    n_policies = evals.checkpoints["policy"].nunique() + evals.references["policy"].nunique()
    doc.md += [f"# {title}", ""]
    learned = learned_paragraph(inp)
    if learned:
        doc.md += [learned, ""]
    ck = evals.checkpoints
    ways = (
        ", ".join(f"`{w}`" if w else "not recorded" for w in dict.fromkeys(ck["acting"].astype(str))) if len(ck) else ""
    )
    worlds = ", ".join(dict.fromkeys(ck["worlds"].astype(str))) if len(ck) else ""
    doc.md += [
        f"**The paper's claims at a glance.** Acting: {inp.compared or ways or 'none evaluated'}. Worlds: "
        f"{worlds or 'none evaluated'}. Each claim's rule and numbers: [The paper's claims](#the-papers-claims).",
        "",
        *rules.glance(inp.verdicts),
        "",
    ]
    doc.md += [
        f"{len(inp.run_list)} run directories; {n_policies} evaluated policies "
        f"({len(evals.checkpoints) + len(evals.references)} evaluation episodes).",
        "",
        STATISTICS_NOTE,
        "",
    ]
    if len(ck):
        doc.md += [f"Checkpoints acted: {ways}; worlds: {worlds}.", ""]
        if inp.compared:
            chosen = f" The compared mode was {choice_text(inp.choice)}." if inp.choice is not None else ""
            doc.md += [
                f"**Compared acting.** The claims compare the checkpoints acting {inp.compared}; the tables and "
                f"figures also show any other acting mode, labelled, which decides no claim.{chosen}",
                "",
            ]
        if (ck["worlds"].astype(str).str.contains("not held out")).any():
            doc.md += [
                "**Not held out.** Evaluations written before evaluate.py recorded its worlds were made on "
                "`make_env(seed=s)`'s worlds, the worlds a seed-s training run starts on; every number "
                "measured there is labelled so and is not a held-out result.",
                "",
            ]


def _run_caption(inp: Inputs) -> str:
    ways: dict[str, list[str]] = {}
    for r in inp.usable:
        if r.evals is not None:
            for way in dict.fromkeys(r.evals["acting"].astype(str)):
                ways.setdefault(way, [])
                if r.algo not in ways[way]:
                    ways[way].append(r.algo)
    acting = "; ".join(f"`{w}` ({', '.join(a)})" for w, a in ways.items()) or "no in-training evaluations"
    worlds = (
        " / ".join(dict.fromkeys(w for r in inp.usable if r.evals is not None for w in r.evals["worlds"].astype(str)))
        or "none"
    )
    return (
        f"**Runs.** Acting: training episodes explore; in-training evaluations {acting}. Worlds: training "
        f"worlds (training episodes); {worlds} (in-training evaluations)."
    )


def runs_and_problems(doc: Document, inp: Inputs) -> list[str]:
    """The table of runs and the list of what is missing, partial or doubtful; returns that list."""
    rel = inp.rel
    doc.md += [
        "## Runs",
        "",
        _run_caption(inp),
        "",
        "| run | algo | modality | reward | training | seed | env steps | status |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in inp.run_list:
        status = "finished" if r.problem is None else r.problem.split(":")[0]
        # a compute-bound run: the env steps its CPU minutes bought
        steps = f"{r.steps:,} / {r.total:,}" if r.cpu_budget is None else f"{r.steps:,} in {r.budget}"
        doc.md.append(
            f"| {rel(r.dir)} | {r.algo} | {r.modality} | {r.reward} | {r.training} | "
            f"{'' if r.seed is None else r.seed} | {steps} | {status} |"
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


def setting(r: RunRecord) -> tuple:
    """What a run trained, its budget aside: algorithm, modality, reward and other settings (``extras`` less
    ``budget=``)."""
    return (r.algo, r.modality, r.reward, tuple(e for e in r.extras if not e.startswith("budget=")))


def series_label(r: RunRecord) -> str:
    """A short label of a run with every sense for the figures of survival per level: its algorithm, curriculum or
    direct, and the CPU budget of a compute-matched run (``ppo · curriculum``, ``dqn · direct · 110 CPU-min``); the
    other settings go to the table of series."""
    label = f"{r.algo} · {'curriculum' if r.curriculum else 'direct'}"
    return label + (f" · {r.budget}" if r.cpu_budget is not None else "")


def survival_per_level(doc: Document, inp: Inputs) -> None:
    """Fig. 4a as the paper draws it: the survival each training level ended with, levels on the x axis, one series
    per agent × curriculum or direct (and acting mode, hatched for `mode`), the references (random, stand-still,
    the oracle) as markers across each level; runs with every sense only (the modality ablations are Figs. 25 and
    26). Compute-matched runs are in the table and in Fig. 20, not in the figure."""
    final = inp.final
    runs = [r for r in inp.usable if r.modality == "all"]
    table = figure = None
    if len(final) and runs:
        lab = {r.dir: series_label(r) for r in runs}
        f = inp.labelled(final[final["run"].isin(list(lab))], lab)
        stats = across_seeds(f, ["label", "level"], "survival")
        doc.tables["survival_per_level"] = stats
        levels = level_sorted(stats["level"])
        matched = {series_label(r) for r in runs if r.cpu_budget is not None}
        drawn = stats[~stats["label"].map(lambda x: x.split(" [")[0] in matched)]
        refs = inp.reference_training
        refs = refs[refs["level"].isin(levels)] if len(refs) else refs
        figure = plot_bars(
            drawn if len(drawn) else stats,
            doc.out / "fig4a_survival_per_level.png",
            levels=levels,
            ylabel="survival (decisions)",
            title="Survival per training level",
            compared=inp.compared,
            references=refs[["label", "level", "value"]] if len(refs) else None,
        )
        cols = sorted(dict.fromkeys(stats["label"]), key=lambda x: (x.split(" [")[0] in matched, x))
        table = pivot_table(
            stats,
            "level",
            "label",
            rows=levels,
            cols=cols,
            title="Survival per training level (decisions)",
            compared=inp.compared,
        )
        settings = {}
        for r in runs:
            key = series_label(r)
            entry = settings.setdefault(key, {"reward": set(), "budget": {}, "seeds": set()})
            entry["reward"].add(r.reward)
            entry["seeds"].add(r.seed)
            entry["budget"].setdefault(r.training, set()).add(r.budget)
        table += (
            "\n\n**Series.** Acting: as labelled in the table above. Worlds: as above. Every setting the labels "
            "leave out (all runs with every sense):\n\n"
        )
        table += "| series | reward | budget per training | seeds | in the figure |\n|---|---|---|---|---|\n"
        table += "\n".join(
            f"| {k} | {', '.join(sorted(v['reward']))} | "
            + "; ".join(f"{t}: {', '.join(sorted(b))}" for t, b in v["budget"].items())
            + f" | {len(v['seeds'])} | {'no (Fig. 20)' if k in matched else 'yes'} |"
            for k, v in settings.items()
        )
    doc.section(
        "Survival per training level (Fig. 4a, left)",
        inp.source_note
        + " Every series with every sense (the modality ablations: Figs. 25 and 26); references as markers across "
        "each level (dashed: random, dotted: stand-still); bars of networks acting `mode` hatched, `sample` solid, "
        "in every figure. Compute-matched runs are in the table and in Fig. 20.",
        figure,
        table,
        "No finished stage in the runs given.",
    )


def _seen(inp: Inputs, final: pd.DataFrame) -> pd.Series:
    """Env steps each row's network had seen when its stage ended: a curriculum stage k has seen its own and the
    stages' before it ((k+1) × the budget for equal budgets), a direct run its budget."""
    return final.apply(
        lambda row: (
            inp.by_dir[row["run"]].offset(int(row["stage"])) + inp.by_dir[row["run"]].stages[int(row["stage"])][2]
        ),
        axis=1,
    )


def _direct_views(inp: Inputs, rows: pd.DataFrame, key: str) -> pd.DataFrame:
    """``rows`` (final survival of curriculum and direct runs, ``key`` naming what they share) with ``seen`` and
    ``view``: ``curriculum`` for a curriculum stage; for a direct run, what its env steps match in the curriculum of
    the same ``key`` on its level — ``equal`` (the stage's own env steps), ``matched`` (all the curriculum had seen
    by the end of that stage), ``both`` (the first stage, where they are one) or ``other`` (neither)."""
    rows = rows.assign(
        seen=_seen(inp, rows) if len(rows) else pd.Series(dtype=int),
        own=rows.apply(lambda r: inp.by_dir[r["run"]].stages[int(r["stage"])][2], axis=1)
        if len(rows)
        else pd.Series(dtype=int),
        curriculum=rows["run"].map(lambda d: inp.by_dir[d].curriculum),
    )
    cur = rows[rows["curriculum"]].groupby([key, "level"]).agg(stage_own=("own", "max"), stage_total=("seen", "max"))
    rows = rows.join(cur, on=[key, "level"])

    def view(r: pd.Series) -> str:
        if r["curriculum"]:
            return "curriculum"
        equal, matched = r["seen"] == r["stage_own"], r["seen"] == r["stage_total"]
        return "both" if equal and matched else "equal" if equal else "matched" if matched else "other"

    return rows.assign(view=rows.apply(view, axis=1) if len(rows) else pd.Series(dtype=str))


def curriculum_vs_direct(doc: Document, inp: Inputs) -> None:
    """Fig. 4a, right: per level, curriculum runs' stage of that level beside runs trained on that level alone —
    at equal env steps per stage (the paper's view: the curriculum stage has seen more in total), and at matched
    total env steps (a direct run with as many env steps as the curriculum had seen by the end of that stage). The
    figure draws the view that covers more levels."""
    usable, final = inp.usable, inp.final

    # a direct run's budget in env steps is what this comparison varies (equal per stage, or the stage's total): not
    # a group; compute-bound runs (CPU minutes, not env steps) take no part
    key = setting
    usable = [r for r in usable if r.cpu_budget is None]
    both = {key(r) for r in usable if r.curriculum} & {key(r) for r in usable if not r.curriculum}
    cmp_runs = [r for r in usable if key(r) in both]
    tables: list[str] = []
    figure = None
    if cmp_runs and len(final):
        keys = {r.dir: key(r) for r in cmp_runs}
        varies = [i for i in range(1, 4) if len({k[i] for k in keys.values()}) > 1]
        base = {d: " · ".join([k[0], *(", ".join(k[i]) if i == 3 else k[i] for i in varies)]) for d, k in keys.items()}
        lab = {d: f"{v} · {'curriculum' if inp.by_dir[d].curriculum else 'direct'}" for d, v in base.items()}
        f = inp.labelled(final[final["run"].isin(list(lab))], lab)
        f = _direct_views(inp, f.assign(setting=f["run"].map(base)), "setting")
        direct = f[~f["curriculum"]]
        views = {}
        for name, kinds in (("equal", {"equal", "both"}), ("matched", {"matched", "both"})):
            d = direct[direct["view"].isin(kinds)]
            rows = pd.concat([f[f["curriculum"] & f["level"].isin(set(d["level"]))], d])
            # a view of its own only where some curriculum stage has seen more than its own env steps
            views[name] = (rows, bool((d["stage_own"] != d["stage_total"]).any())) if len(d) else (rows, False)
        shown = [v for v in ("equal", "matched") if views[v][1]] or (["equal"] if len(views["equal"][0]) else [])
        titles = {
            "equal": "Curriculum vs direct at equal env steps per stage (survival, decisions)",
            "matched": "Curriculum vs direct at matched total env steps (survival, decisions)",
        }
        drawn = max(shown, key=lambda v: (views[v][0]["level"].nunique(), v == "matched"), default=None)
        for name in shown:
            rows = views[name][0]
            stats = across_seeds(rows, ["label", "level"], "survival").sort_values(
                "label", key=lambda s: s.str.contains("direct"), kind="stable"
            )
            seen = rows.groupby(["label", "level"])["seen"].agg(lambda s: "/".join(f"{v:,}" for v in sorted(set(s))))
            stats["env_steps"] = [seen.get((lb, lv), "") for lb, lv in zip(stats["label"], stats["level"])]
            doc.tables["curriculum_vs_direct" + ("_matched" if name == "matched" else "")] = stats
            levels = level_sorted(stats["level"])
            if name == drawn:
                figure = plot_bars(
                    stats,
                    doc.out / "fig4a_curriculum_vs_direct.png",
                    levels=levels,
                    ylabel="survival (decisions)",
                    title="With and without curriculum, "
                    + (
                        "equal env steps per stage (curriculum stage k has seen k+1 stages' env steps)"
                        if name == "equal"
                        else "matched total env steps (a direct run on level k has k+1 stages' env steps)"
                    ),
                    compared=inp.compared,
                )
            steps_by_level = {
                lv: "; ".join(
                    dict.fromkeys(
                        f"{lb.rsplit(' · ', 1)[-1]} {st}"
                        for lb, st in zip(
                            stats.loc[stats["level"] == lv, "label"], stats.loc[stats["level"] == lv, "env_steps"]
                        )
                    )
                )
                for lv in levels
            }
            tables.append(
                pivot_table(stats, "level", "label", rows=levels, title=titles[name], compared=inp.compared)
                + "\n\nEnv steps seen per cell: "
                + "; ".join(f"{lv}: {steps_by_level[lv]}" for lv in levels)
                + "."
            )
        cur = f[f["curriculum"] & f["level"].isin(set(direct["level"]))]
        unmatched = cur[~cur["level"].isin(set(direct.loc[direct["view"].isin({"matched", "both"}), "level"]))]
        if len(unmatched):
            needs = unmatched.groupby("level")["seen"].max()
            tables.append(
                "**At matched total env steps:** no direct run here has as many env steps as the curriculum stage on "
                + ", ".join(f"{lv} ({needs[lv]:,})" for lv in level_sorted(needs.index))
                + "."
            )
        other = direct[direct["view"] == "other"]
        if len(other):
            budgets = other.groupby("level")["seen"].agg(lambda s: "/".join(f"{v:,}" for v in sorted(set(s))))
            tables.append(
                "Direct runs of neither budget, in no view: "
                + ", ".join(f"{lv} ({budgets[lv]} env steps)" for lv in level_sorted(budgets.index))
                + "."
            )
    doc.section(
        "With and without curriculum (Fig. 4a, right)",
        inp.source_note + " Curriculum: the stage of that level after the levels before it (it has seen "
        "their env steps too); direct: a run trained on that level alone.",
        figure,
        "\n\n".join(tables) if figure else None,
        "No algorithm has both curriculum runs (`level=curriculum`) and direct runs (`level=<level>`) here.",
    )


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
            inp.labelled(_mean_testbed_success(tests), inp.checkpoint_labels),
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


def _mean_testbed_success(tests: pd.DataFrame) -> pd.DataFrame:
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


def evaluation_survival(doc: Document, inp: Inputs) -> None:
    """Survival in evaluations on training levels, when there are any (a table, no figure)."""
    ck = inp.evals.checkpoints
    train_ck = final_checkpoints(ck[ck["level"].isin(evaaa.LEVELS)])
    ref_train = inp.reference_training
    if not (len(train_ck) or len(ref_train)):
        return
    stats = (
        across_seeds(inp.labelled(per_run(train_ck, "steps"), inp.checkpoint_labels), ["label", "level"], "steps")
        if len(train_ck)
        else ref_train.iloc[:0]
    )
    stats = pd.concat([stats.assign(unit="seeds"), ref_train], ignore_index=True)
    doc.tables["evaluation_survival"] = stats
    doc.md += [
        "## Evaluation on training levels",
        "",
        "Survival (decisions) in evaluate.py's episodes (cells as "
        "described under Statistics); checkpoints as above; references: stand-still (`still`: always the "
        "action none), random and the oracle, where evaluated.",
        "",
        pivot_table(
            stats,
            "level",
            "label",
            rows=level_sorted(stats["level"]),
            title="Survival in evaluations on training levels (decisions)",
            compared=inp.compared,
        ),
        "",
    ]


# ------------------------------------------------------------------------------------------------ what it learned
#: end types as the "what it learned" table names them
ENDS = {
    "FoodOutOfRange": "starved",
    "WaterOutOfRange": "dehydrated",
    "TemperatureOutOfRange": "too hot/cold",
    "DamageTooHigh": "damaged",
    "MaxStepReached": "time limit",
    "ResourceConsumed": "ate (testbed end)",
}
LEARNED_REFERENCES = ("random", "still")


def learned_table(inp: Inputs) -> pd.DataFrame:
    """Per training level, each agent's networks (every stage's network on its own level: the run's episodes of
    ``model-<stage>-<level>.pt`` on ``<level>``) and each reference agent: food and water eaten, collisions per
    episode, how episodes ended, survival (IQM) and, for agents, survival against the better of random and
    stand-still on that level.  ``learned`` says, point by point (no verdict), what the numbers show."""
    ck = inp.evals.checkpoints
    own = ck[(ck["level"] == ck["ckpt_level"]) & ck["level"].isin(evaaa.LEVELS)] if len(ck) else ck
    if len(own):
        own = own[own["policy"].map(lambda p: bool(MODEL_FILE.match(Path(p).name)))]
    refs = inp.evals.references
    refs = refs[refs["level"].isin(evaaa.LEVELS) & refs["policy"].isin(["oracle", *LEARNED_REFERENCES])]
    rows = []

    def describe(label: str, level: str, part: pd.DataFrame, unit: str, key: str | None) -> dict:
        groups = [g for _, g in part.groupby(key, sort=False)] if key else [part]
        per = lambda col: [float(g[col].astype(float).mean()) for g in groups]  # noqa: E731
        ends = part["end_type"].map(lambda e: ENDS.get(e, e)).value_counts(normalize=True)
        eaten = lambda g: tuple(g["food_eaten"].astype(float) + g["water_eaten"].astype(float))  # noqa: E731
        surv = across_seeds(  # with the level and what was eaten: the share at the step cap and the intake
            pd.DataFrame(
                {
                    "scores": [tuple(g["steps"].astype(float)) for g in groups],
                    "eaten": [eaten(g) for g in groups],
                    "episodes": [len(g) for g in groups],
                    "level": level,
                    "g": 0,
                }
            ),
            ["g"],
            "steps",
            unit=unit,
        ).iloc[0]
        return {
            "level": level,
            "label": label,
            "n": len(groups) if unit == "seeds" else len(part),
            "unit": unit,
            "episodes": len(part),
            "acting": "/".join(dict.fromkeys(part["acting"].astype(str))),
            "worlds": " / ".join(dict.fromkeys(part["worlds"].astype(str))),
            "food": float(part["food_eaten"].astype(float).mean()),
            "food_seeds": tuple(per("food_eaten")),
            "water": float(part["water_eaten"].astype(float).mean()),
            "water_seeds": tuple(per("water_eaten")),
            "collisions": float(part["collisions"].astype(float).mean()),
            "ends": ", ".join(f"{k} {100 * v:.0f} %" for k, v in ends.items()),
            "survival": float(surv["value"]),
            "survival_low": float(surv["low"]),
            "survival_high": float(surv["high"]),
            "at_cap": float(surv["at_cap"]),
            "intake": float(surv["intake"]),
        }

    for (policy, level), part in refs.groupby(["policy", "level"], sort=False):
        rows.append(describe(policy, level, part, "episodes", None))
    if len(own):
        own = inp.labelled(own, inp.checkpoint_labels)
        for (label, level), part in own.groupby(["label", "level"], sort=False):
            rows.append(describe(label, level, part, "seeds", "run"))
    table = pd.DataFrame(rows)
    if not len(table):
        return table
    ref = table[table["label"].isin(LEARNED_REFERENCES)]
    compared = {
        lv: " and ".join("stand-still" if p == "still" else p for p in LEARNED_REFERENCES if p in set(part["label"]))
        for lv, part in ref.groupby("level")
    }
    better = ref.sort_values("survival").groupby("level").tail(1).set_index("level")
    most_eaten = ref.assign(eaten=ref["food"] + ref["water"]).groupby("level")["eaten"].max()
    learned, vs, eats_more, lives_longer = [], [], [], []
    for row in table.itertuples():
        if row.label in (*LEARNED_REFERENCES, "oracle") or row.level not in better.index:
            learned.append("")
            vs.append("")
            eats_more.append(False)
            lives_longer.append(False)
            continue
        b = better.loc[row.level]
        ratio = row.survival / b["survival"] if b["survival"] else float("nan")
        vs.append(f"{'≥ ' if capped(row._asdict()) else ''}{ratio:.2f}× {b['label']}")  # a capped IQM: a lower bound
        eats = row.food + row.water > most_eaten.get(row.level, np.inf)
        lives = ratio > 1
        eats_more.append(bool(eats))
        lives_longer.append(bool(lives))
        than = compared[row.level]
        learned.append(
            f"eats more than {than}" + (" and survives longer" if lives else "")
            if eats
            else f"survives longer than {than}, eats no more"
            if lives
            else f"neither eats more nor survives longer than {than}"
        )
    return table.assign(vs_reference=vs, learned=learned, eats_more=eats_more, lives_longer=lives_longer)


def _cubes(per_episode: float) -> str:
    """Cubes eaten per episode: one decimal, or two significant digits under one (1 cube in 30 episodes: 0.033)."""
    return f"{per_episode:.1f}" if per_episode >= 1 else f"{per_episode:.2g}"


def learned_paragraph(inp: Inputs) -> str:
    """The report's first block: what the agents learned, from :func:`learned_table` (agents trained with every
    sense, grouped by algorithm and curriculum or direct) — a paragraph, then one line per agent."""
    table = inp.learned
    if not len(table):
        return ""
    agents = table[~table["label"].isin((*LEARNED_REFERENCES, "oracle"))]
    refs = table[table["label"].isin(LEARNED_REFERENCES)]
    if not len(agents):
        return ""
    missing = [r for r in LEARNED_REFERENCES if r not in set(refs["label"])]
    acting = ", ".join(f"`{a}`" for a in dict.fromkeys(agents["acting"]))
    worlds = ", ".join(dict.fromkeys(agents["worlds"]))
    budgets = [
        f"{b} a stage" if r.cpu_budget is None else f"{b} a compute-matched run"
        for b, r in {r.budget: r for r in sorted(inp.usable, key=lambda r: r.cpu_budget or 0)}.items()
    ]

    def said(w: str) -> str:  # "test" -> "test worlds"; the older labels say "worlds" already
        return w if "worlds" in w else f"{w} worlds"

    worlds = ", ".join(said(w) for w in dict.fromkeys(agents["worlds"]))
    ref_worlds = {
        ("stand-still" if r == "still" else r): ", ".join(said(w) for w in dict.fromkeys(part["worlds"]))
        for r, part in refs.groupby("label", sort=False)
    }
    differ = any(w != worlds for w in ref_worlds.values())
    out = [
        f"**What the agents learned** ({', '.join(budgets)}; every stage's "
        f"network on its own level, acting {acting}, on {worlds}"
        + ("; " + "; ".join(f"{r} on {w}" for r, w in ref_worlds.items()) if differ else "")
        + ")."
    ]
    groups: dict[str, pd.DataFrame] = {}
    for label, part in agents.groupby("label", sort=False):
        base = label.split(" [")[0]  # one sentence per acting mode: "[sample]" and "[mode]" are two agents here
        key = base.split(" · trained on ")[0] + (" · direct" if " · trained on " in base else "") + label[len(base) :]
        groups[key] = pd.concat([groups.get(key, part.iloc[:0]), part])
    sentences = []
    for key, part in groups.items():
        if any(m in key for m in ("no_vision", "no_interoception", "no_olfaction", "no_thermoception", "no_collision")):
            continue
        eats = part[part["eats_more"]]
        than = " and ".join("stand-still" if r == "still" else r for r in LEARNED_REFERENCES if r in set(refs["label"]))
        lives = part[part["lives_longer"]]
        sentences.append(
            f"{key} ate more food and water per episode than {than} on {len(eats)} of {len(part)} levels"
            + (
                f" ({', '.join(f'{r.level}: {_cubes(r.food + r.water)}' for r in eats.itertuples())})"
                if len(eats)
                else ""
            )
            + f" and survived longer than {'the better of ' if ' and ' in than else ''}{than} on "
            f"{len(lives)} of {len(part)}"
        )
    if len(refs):
        still = refs[refs["label"] == "still"]
        if len(still):
            out.append(
                "Stand-still survives "
                + ", ".join(f"{r.survival:.0f} decisions on {r.level}" for r in still.itertuples())
                + " without eating."
            )
    if missing:
        out.append(
            f"No {' or '.join(missing)} reference was evaluated on these levels: the comparison uses "
            f"{' and '.join(r for r in LEARNED_REFERENCES if r not in missing) or 'nothing'}."
        )
    out.append('Counts are of points, not verdicts; see "What each agent learned" for the numbers.')
    # one line per agent: a list that follows its paragraph without a blank line (one block of the report)
    return " ".join(out) + "".join(f"\n- {s}" for s in sentences)


def what_it_learned(doc: Document, inp: Inputs) -> None:
    """Per level, each agent beside the references: what it ate, how it collided, how its episodes ended and how
    long it survived against the better of random and stand-still, so that surviving by not moving is never read
    as learning."""
    table = inp.learned
    doc.md += ["## What each agent learned", ""]
    if not len(table):
        doc.md += ["No evaluation of a stage's network on its own level given.", ""]
        return
    doc.tables["what_it_learned"] = table.assign(
        food_seeds=table["food_seeds"].map(lambda t: ";".join(f"{v:.3g}" for v in t)),
        water_seeds=table["water_seeds"].map(lambda t: ";".join(f"{v:.3g}" for v in t)),
    )
    ordered = table.assign(
        _l=table["level"].map(lambda lv: level_sorted(evaaa.LEVELS).index(lv)),
        _r=~table["label"].isin((*LEARNED_REFERENCES, "oracle")),
    ).sort_values(["_l", "_r"], kind="stable")

    def seeds(values: tuple, unit: str) -> str:
        return f" ({', '.join(f'{v:.2f}' for v in values)})" if unit == "seeds" and 1 < len(values) < MIN_SEEDS else ""

    doc.md += [
        caption(
            "What each agent learned on its own level",
            ordered.assign(unit=ordered["unit"], means_only=False),
            col="label",
            compared=inp.compared,
        ),
        "",
        "| level | agent | n | food / ep. | water / ep. | collisions / ep. | ends | survival (IQM) | "
        "vs better of random, stand-still | reading |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in ordered.itertuples():
        n = (
            f"{r.n} seeds × {r.episodes // r.n} ep."
            if r.unit == "seeds" and r.episodes % r.n == 0
            else (f"{r.n} seeds, {r.episodes} ep." if r.unit == "seeds" else f"{r.episodes} ep.")
        )
        interval_ = "" if np.isnan(r.survival_low) else f" [{r.survival_low:.0f}, {r.survival_high:.0f}]"
        said = censored_note(r._asdict())  # a capped IQM is a lower bound: the share at the cap and the intake
        interval_ += f"; {said}" if said else ""
        doc.md.append(
            f"| {r.level} | {r.label} | {n} | {r.food:.2f}{seeds(r.food_seeds, r.unit)} | "
            f"{r.water:.2f}{seeds(r.water_seeds, r.unit)} | {r.collisions:.1f} | {r.ends} | "
            f"{'≥ ' if capped(r._asdict()) else ''}{r.survival:.0f}{interval_} | {r.vs_reference} | {r.learned} |"
        )
    doc.md += [
        "",
        "Food and water: items eaten per episode (per seed in brackets under three seeds); ends: share of "
        "episodes by how they ended; reading: the points compared (no interval, no verdict) — an agent that "
        "survives longer without eating more than stand-still has learned at most to move less.",
        "",
    ]


def matched_level(inp: Inputs) -> tuple[str, str] | None:
    """The level and budget of the compute-matched comparison (the first, where runs were matched on several)."""
    if not inp.matched:
        return None
    r = inp.matched[0]
    return r.training, r.budget


def matched_survival(inp: Inputs) -> pd.DataFrame:
    """The compute-matched runs' final networks on their level, per algorithm, in the compared acting mode
    (columns algo, level and :data:`STAT_COLUMNS`)."""
    where = matched_level(inp)
    final = _one_mode(inp.final, inp)
    if where is None or not len(final):
        return pd.DataFrame(columns=["algo", "level", *STAT_COLUMNS])
    dirs = {r.dir: r.algo for r in inp.matched if r.training == where[0] and r.budget == where[1]}
    rows = final[final["run"].isin(list(dirs)) & (final["level"] == where[0])]
    return across_seeds(rows.assign(algo=rows["run"].map(dirs)), ["algo", "level"], "survival")


def matched_reaching(inp: Inputs) -> pd.DataFrame:
    """When each compute-matched run's in-training evaluations first reached the learning threshold
    (:func:`.matched.reaching`); empty without a threshold (the report option ``learned`` and references)."""
    where = matched_level(inp)
    bar = threshold(inp.reference_training, where[0], inp.learned_factor) if where and inp.learned_factor else None
    runs = [r for r in inp.matched if where and r.training == where[0] and r.budget == where[1]]
    points = evaluation_points(runs)
    if bar is None or not len(points):
        return pd.DataFrame(columns=["run", "algo", "seed", "reached", "steps", "cpu_minutes"])
    return reaching(points, inp.by_dir, bar[0])


def equal_compute(doc: Document, inp: Inputs) -> None:
    """Fig. 20 at equal compute: every algorithm trained on one level for the same CPU minutes; learning curves on
    validation worlds against env steps and against CPU minutes, and each algorithm's final networks on test worlds
    beside the references, whether it learned, and when its evaluations reached the learning threshold."""
    where = matched_level(inp)
    if where is None:
        return
    level, budget = where
    runs = [r for r in inp.matched if r.training == level and r.budget == budget]
    lab = {r.dir: f"{r.algo} · {r.reward}" for r in runs}
    points = evaluation_points(runs)
    doc.md += [f"## At equal compute on {level} (Fig. 20)", ""]
    rewards = ", ".join(f"{a}: `{w}`" for a, w in dict.fromkeys((r.algo, r.reward) for r in runs))
    doc.md += [
        f"Every algorithm trained on {level} with every sense for {budget} of one core (`max_cpu_minutes`, "
        "`threads=1`; an evaluation's CPU time counts in it), whatever env steps that bought; each on the reward "
        f"it learns on ({rewards}). The measure compared is survival, not return.",
        "",
    ]
    if len(points):
        stats = across_seeds(curve_points(points, lab), ["view", "label", "x"], "survival")
        doc.tables["equal_compute_curves"] = stats
        refs = inp.reference_training
        hl = refs[(refs["level"] == level) & refs["label"].isin(["random", "still"])] if len(refs) else None
        if hl is not None and len(hl):
            hl = hl.assign(label=hl["label"] + " (test worlds)")[["label", "value"]]
            bar = threshold(refs, level, inp.learned_factor) if inp.learned_factor else None
            if bar is not None:
                hl = pd.concat(
                    [hl, pd.DataFrame([{"label": f"learned: {inp.learned_factor:g}× {bar[1]}", "value": bar[0]}])]
                )
        figure = plot_lines(
            stats,
            doc.out / "fig20_equal_compute.png",
            x="x",
            panel="view",
            band=True,
            ylabel="survival (decisions)",
            xlabel="env steps",
            xlabels={"against env steps": "env steps", "against CPU minutes": "CPU minutes"},
            title=f"Learning curves at equal compute on {level} ({budget}; in-training evaluations)",
            hlines=hl if hl is not None and len(hl) else None,
        )
        doc.figures.append(figure)
        doc.md += [
            "Curves: the in-training evaluations (validation worlds), each seed's k-th evaluation pooled with the "
            "other seeds' k-th at their mean env steps (left) or CPU minutes (right), IQM of their episodes with "
            "its 95 % bootstrap interval (band); lines: the references on test worlds"
            + (" and the learning threshold" if inp.learned_factor else "")
            + ".",
            "",
            f"![At equal compute on {level} (Fig. 20)]({figure.name})",
            "",
        ]
    surv = matched_survival(inp)
    if not len(surv):
        doc.md += ["No compute-matched run has finished and been evaluated yet: its curves only.", ""]
        return
    reach = matched_reaching(inp)
    gate = inp.gate_of(True).set_index("algo") if inp.learned_factor is not None else None
    steps: dict[str, list[int]] = {}
    for r in sorted(runs, key=lambda r: r.seed or 0):  # per algorithm, each seed's env steps in seed order
        steps.setdefault(r.algo, []).append(r.steps)
    header = "| agent | seeds | env steps reached | survival on test worlds (IQM) | intake / 1,000 decisions |"
    rule_ = "|---|---|---|---|---|"
    if gate is not None:
        header += " vs better of random, stand-still | learned? | env steps to the threshold | CPU min to it |"
        rule_ += "---|---|---|---|"
    doc.md += [
        caption(
            f"Final networks at equal compute on {level} ({budget})",
            surv.assign(label=surv["algo"]),
            col="label",
            compared=inp.compared,
        ),
        "",
        header,
        rule_,
    ]
    for row in surv.itertuples():
        line = (
            f"| {row.algo} | {row.n} | {', '.join(f'{v:,}' for v in steps.get(row.algo, []))} | {cell(row._asdict())} | "
            f"{'' if np.isnan(row.intake) else f'{row.intake:.1f}'} |"
        )
        if gate is not None:
            g = gate.loc[row.algo] if row.algo in gate.index else None
            mine = reach[reach["algo"] == row.algo] if len(reach) else reach

            def when(column: str, mine=mine) -> str:
                return ", ".join(f"{v:,.0f}" if ok else "never" for v, ok in zip(mine[column], mine["reached"]))

            line += (
                f" {'≥ ' if capped(g) else ''}{g['ratio']:.2f}× "
                f"{'stand-still' if g['reference'] == 'still' else g['reference']} | "
                f"{'yes' if g['learned'] else 'did not learn at this budget'} | {when('steps')} | "
                f"{when('cpu_minutes')} |"
                if g is not None
                else " | | | |"
            )
        doc.md.append(line)
    doc.tables["equal_compute_final"] = surv
    if len(reach):
        doc.tables["equal_compute_threshold"] = reach.assign(run=reach["run"].map(inp.rel))
    refs = inp.reference_training
    refs = refs[(refs["level"] == level) & refs["label"].isin(["random", "still"])] if len(refs) else refs
    ref_intake = "; ".join(
        f"{'stand-still' if r.label == 'still' else r.label} {r.intake:.1f}"
        for r in refs.itertuples()
        if not np.isnan(r.intake)
    )
    doc.md += [
        "",
        "Survival: "
        + _source_words(inp)
        + "; a cell with more than a quarter of its episodes at the step cap is a lower bound (`≥`, share at the "
        "cap); intake: food and water eaten per 1,000 decisions, every episode of the seeds pooled"
        + (f" (references on {level}: {ref_intake})" if ref_intake else "")
        + "; env steps reached: per seed; "
        + (
            f"learned: the 95 % interval above {inp.learned_factor:g}× the better of random and stand-still on "
            f"{level}; "
            "threshold: the first in-training evaluation (validation worlds, IQM of its episodes) at or above "
            "that, per seed (never: not within the budget)."
            if gate is not None
            else "no learning threshold (the report option `learned` is unset)."
        ),
        "",
    ]


def _source_words(inp: Inputs) -> str:
    """How the final survival of a stage was measured, in words (the source note without its label)."""
    return inp.source_note[len("Survival: ") :].rstrip(".")


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
        every_sense = {lab[r.dir] for r in inp.usable if r.modality == "all"}
        drawn = stats[stats["label"].isin(every_sense)]  # the modality ablations: Fig. 25
        figure = plot_lines(
            drawn if len(drawn) else stats,
            doc.out / "fig_training_curves.png",
            x="steps",
            panel="group",
            band=True,
            ylabel="survival (decisions)",
            xlabel="env steps",
            title="Training curves",
            hlines=hl,
        )
        # each run's own last bin, the seeds pooled (compute-matched runs end at different env steps: the pooled
        # curve's last bin holds one seed)
        last = by.sort_values("bin").groupby("run", sort=False).tail(1)
        # on its last stage's level: a cell with more than a quarter of its episodes at that level's cap says so
        last = last.assign(level=last["run"].map(lambda d: by_dir[d].stages[-1][1] if by_dir[d].stages else ""))
        ends = across_seeds(last, ["group", "label"], "survival")
        table = pivot_table(
            ends.rename(columns={"group": "level"}),
            "level",
            "label",
            row_title="training",
            title="Training survival in each run's last bin of env steps (decisions)",
        )
        table += (
            f"\n\nCurves: survival of the training episodes (exploring policy) in {inp.bins} bins of env "
            "steps, IQM of the bin's episodes with its 95 % bootstrap interval (band); table: each run's last bin, the "
            "seeds pooled. "
            "Dashed/dotted: reference agents' IQM survival in evaluate.py's episodes on that level, when given."
        )
    doc.section(
        "Training curves",
        "One panel per training set-up, one line per algorithm and settings, runs with every sense (the modality "
        "ablations: Fig. 25); the table has every run.",
        figure,
        table,
        "No finished training episode in the runs given.",
    )


def evaluation_curves(doc: Document, inp: Inputs) -> None:
    """The in-training evaluations (``eval.csv``: validation worlds in runs that record them) against env steps:
    one panel per training set-up, one line per algorithm and settings; each point over the seeds' episodes of that
    evaluation, or over their means where ``eval.csv`` kept only means (said so)."""
    points = evaluation_points(inp.usable)
    table = figure = None
    if len(points):
        lab = labels(inp.usable, ("algo", "modality", "reward", "extras"))
        by = inp.labelled(points, lab).assign(
            group=lambda d: d["run"].map(lambda x: f"trained on {inp.by_dir[x].training}")
        )
        stats = across_seeds(by, ["group", "label", "steps"], "survival")
        doc.tables["evaluation_curves"] = stats
        every_sense = {lab[r.dir] for r in inp.usable if r.modality == "all"}
        drawn = stats[stats["label"].str.split(" [", regex=False).str[0].isin(every_sense)]  # ablations: Fig. 25
        figure = plot_lines(
            drawn if len(drawn) else stats,
            doc.out / "fig_evaluation_curves.png",
            x="steps",
            panel="group",
            band=True,
            ylabel="survival (decisions)",
            xlabel="env steps",
            title="In-training evaluations" + (" (means only)" if stats["means_only"].any() else ""),
        )
        # each run's own last evaluation, the seeds pooled (compute-matched runs end at different env steps)
        last = by.sort_values("steps").groupby(["run", "acting"], sort=False).tail(1)
        # on its stage's level: a cell with more than a quarter of its episodes at that level's cap says so
        stage_level = {d: {i: lv for i, lv, _ in inp.by_dir[d].stages} for d in set(last["run"])}
        last = last.assign(level=[stage_level[d].get(int(i), "") for d, i in zip(last["run"], last["stage"])])
        ends = across_seeds(last, ["group", "label"], "survival")
        table = pivot_table(
            ends.rename(columns={"group": "level"}),
            "level",
            "label",
            row_title="training",
            title="Each run's last in-training evaluation (survival, decisions)",
        )
    doc.section(
        "In-training evaluations",
        "Survival in the periodic evaluations during training against env steps (summed over a "
        "curriculum's stages): the worlds of model selection and tuning, never a published number. Where "
        "`eval.csv` kept one mean per evaluation (its older format) the points are over those means: means "
        "only.",
        figure,
        table,
        "No in-training evaluation in the runs given.",
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
            "bootstrap interval (band). Table: survival at the end of each run (" + _source_words(inp) + ")."
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


def _pooled_success(episodes: pd.DataFrame, by: Sequence[str]) -> pd.DataFrame:
    """Per ``by`` (``run`` among them): the successes of all its testbed episodes pooled, as one seed's scores."""
    grouped = episodes.assign(_v=episodes["success"].astype(float)).groupby(list(by), sort=False)["_v"]
    return grouped.agg(success="mean", scores=lambda v: tuple(v.dropna())).reset_index()


def _one_mode(rows: pd.DataFrame, inp: Inputs | None = None) -> pd.DataFrame:
    """``rows`` of one acting mode for the claims, the same for every agent where it can be.  With the report's
    ``compare``: each run's rows acting so — for a run whose algorithm has no action distribution (DQN) in a
    ``sample`` comparison, its greedy rows, their ``acting`` relabelled ``sample… (greedy: no action
    distribution)`` so that :mod:`.claims` compares them with the others' sampled rows and says so.  Without it
    (or for runs with neither): where networks were evaluated in several ways, the way every run has (the
    deterministic ``mode…`` first, the one every algorithm has; DQN has no other), else each run's most frequent
    (such agents are then not compared: :mod:`.claims`).  The other ways stay in the tables, labelled."""
    if inp is not None and inp.compare is not None and len(rows) and "acting" in rows:
        acting = rows["acting"].astype(str)
        greedy = rows["run"].map(lambda d: d in inp.runs and not can_sample(inp.runs[d].algo))
        sub = stand_in(inp.compare)
        own = acting == inp.compare
        standing_in = greedy & (acting == sub) if sub else pd.Series(False, index=rows.index)
        chosen = own | standing_in
        has = chosen.groupby(rows["run"]).transform("any")
        out = rows[chosen].assign(
            acting=acting[chosen].where(~standing_in[chosen], inp.compare + GREEDY_STAND_IN),
        )
        return pd.concat([out, _shared_mode(rows[~has])]) if (~has).any() else out
    return _shared_mode(rows)


def _shared_mode(rows: pd.DataFrame) -> pd.DataFrame:
    """``rows`` of the acting mode every run has (``mode…`` first), else of each run's most frequent."""
    if not len(rows) or "acting" not in rows or rows["acting"].nunique() < 2:
        return rows
    per_run = rows.groupby("run")["acting"].agg(lambda a: set(a))
    shared = sorted(set.intersection(*per_run), key=lambda a: (not a.startswith("mode"), a))
    if shared:
        return rows[rows["acting"] == shared[0]]
    counts = (
        rows.groupby(["run", "acting"])
        .size()
        .reset_index(name="k")
        .sort_values(["k", "acting"], ascending=[True, False], kind="stable")
    )
    chosen = dict(zip(counts["run"], counts["acting"]))
    return rows[rows["acting"] == rows["run"].map(chosen)]


def claim_verdicts(inp: Inputs) -> list[rules.Verdict]:
    """The verdicts of claims (a)–(e) (:mod:`.claims`) from the report's inputs: survival per level from the final
    survival of every finished stage of runs with every sense (curriculum runs where an algorithm has them, else its
    direct runs), testbed success of each run's furthest-trained checkpoint, generalisation of curriculum runs'
    stage models, and the ablations: runs of one algorithm and training set-up with several modality sets."""
    order = list(evaaa.LEVELS)
    runs = inp.by_dir
    empty = pd.DataFrame(columns=["algo", "setup", "level", *STAT_COLUMNS])
    final = _one_mode(inp.final, inp)
    # runs with every sense of every agent (the gate decides nothing: it explains undecided parts), less the
    # compute-matched ones (their budget is CPU minutes: they answer (c) alone)
    full = (
        final[final["run"].map(lambda d: runs[d].modality == "all" and runs[d].cpu_budget is None)]
        if len(final)
        else final
    )
    if len(full):
        full = _direct_views(
            inp,
            full.assign(
                algo=full["run"].map(lambda d: runs[d].algo),
                setup=full["run"].map(lambda d: "curriculum" if runs[d].curriculum else "direct"),
            ),
            "algo",
        )
        # (b) at matched total env steps where direct runs of a curriculum stage's total exist, else at equal env
        # steps per stage (Fig. 4a right's two views)
        matched = full["view"].isin({"matched", "both"})
        has_match = set(zip(full.loc[matched, "algo"], full.loc[matched, "level"]))
        pair = pd.Series(list(zip(full["algo"], full["level"])), index=full.index)
        keep = (
            (full["view"] == "curriculum")
            | matched
            | ((full["view"] == "equal") & ~pair.isin(has_match))
            | full["stage_own"].isna()  # no curriculum of that algorithm on that level: nothing to pair it with
        )
        by_setup = across_seeds(full, ["algo", "setup", "level"], "survival")
        cmp = across_seeds(full[keep], ["algo", "setup", "level"], "survival")
    else:
        by_setup = cmp = empty
    with_cur = set(by_setup.loc[by_setup["setup"] == "curriculum", "algo"])
    survival = by_setup[(by_setup["setup"] == "curriculum") | ~by_setup["algo"].isin(with_cur)]

    def agent(d: Path) -> str:
        r = inp.runs[d]
        return f"{r.algo} · {r.training}"

    best = _one_mode(inp.best, inp)
    best = (
        best[best["run"].map(lambda d: inp.runs[d].modality == "all" and inp.runs[d].cpu_budget is None)]
        if len(best)
        else best
    )
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

    tests = _one_mode(inp.testbed_episodes, inp)
    tests = (
        tests[
            tests["run"].map(lambda d: inp.runs[d].curriculum and inp.runs[d].modality == "all")
            & tests["policy"].map(lambda p: bool(MODEL_FILE.match(Path(p).name)))
        ]
        if len(tests)
        else tests
    )
    per_stage = (
        _mean_testbed_success(tests).assign(agent=lambda d: d["run"].map(lambda x: inp.runs[x].algo))
        if len(tests)
        else None
    )
    gen = (
        across_seeds(per_stage, ["agent", "ckpt_level"], "success", success=True).rename(
            columns={"ckpt_level": "level"}
        )
        if per_stage is not None
        else pd.DataFrame(columns=["agent", "level", *STAT_COLUMNS])
    )
    if per_stage is not None:  # each cell's seeds by run, in its samples' order: (d) redraws a curriculum's together
        gen["units"] = list(
            per_stage.groupby(["agent", "ckpt_level"], sort=False)["run"].agg(lambda r: tuple(map(str, r)))
        )
    vr = inp.verdict_rules
    factor = inp.learned_factor if inp.learned_factor is not None else vr.fails_factor
    refs_train = inp.reference_training
    bars = {
        lv: bar[0]
        for lv in order
        if (bar := threshold(refs_train, lv, factor) if len(refs_train) else None) is not None
    }
    where = matched_level(inp)
    if where is not None:  # (c) where the paper states it for one level, at equal compute
        msurv = matched_survival(inp)
        gate = inp.gate_of(True) if inp.learned_factor is not None else pd.DataFrame(columns=["algo", "learned"])
        ordering = rules.matched_ordering(
            msurv, bars.get(where[0], float("nan")), gate, matched_reaching(inp), *where, rules=vr
        )
    else:
        ordering = rules.algorithm_ordering(survival, bars, order, vr)
    verdicts = [
        rules.survival_falls(survival, order, rules=vr),
        rules.curriculum_beats_direct(cmp, order, rules=vr),
        ordering,
        rules.testbeds_below_ceiling(success, ref_tests, gen, order, vr),
    ]
    # ablations: runs of one algorithm and training set-up (a level, or the curriculum) with several modality sets
    groups: dict[tuple, list[RunRecord]] = {}
    for r in inp.usable:  # one budget per group: a compute-matched run is no ablation's all-senses run
        groups.setdefault((r.algo, r.training, r.budget), []).append(r)
    groups = {k: v for k, v in groups.items() if len({r.modality for r in v}) > 1}
    if not groups:
        verdicts.append(
            rules.missing(
                rules.ablations(pd.DataFrame(), pd.DataFrame()).claim,
                "no runs of one algorithm and level with several modality sets",
            )
        )
    for (algo, level, _), members in groups.items():
        dirs = {r.dir: r.modality for r in members}
        last = final[final["run"].isin(list(dirs)) & final["last"]] if len(final) else final
        surv = (
            across_seeds(last.assign(modality=last["run"].map(dirs)), ["modality"], "survival")
            if len(last)
            else pd.DataFrame(columns=["modality", *STAT_COLUMNS])
        )
        ab_best = _one_mode(inp.best, inp)
        ab_best = ab_best[ab_best["run"].isin(list(dirs))] if len(ab_best) else ab_best
        succ = (
            across_seeds(
                _pooled_success(ab_best, ["run"]).assign(modality=lambda d, dirs=dirs: d["run"].map(dirs)),
                ["modality"],
                "success",
                success=True,
            )
            if len(ab_best)
            else pd.DataFrame(columns=["modality", *STAT_COLUMNS])
        )
        # the bar of the level the final networks were evaluated on (a curriculum's last stage)
        on = str(last["level"].iloc[0]) if len(last) and last["level"].nunique() == 1 else level
        v = rules.ablations(surv, succ, bars.get(on, float("nan")), vr)
        v.claim += f" ({algo}, trained on {level})"
        verdicts.append(v)
    return verdicts


def claims(doc: Document, inp: Inputs) -> None:
    """The paper's claims (a)–(e), one by one: reproduced, contradicted or not resolvable at this scale, with the
    rule and the numbers (:mod:`.claims`)."""
    acting = list(dict.fromkeys(inp.evals.checkpoints["acting"].astype(str))) if len(inp.evals.checkpoints) else []
    how = (
        f", acting {inp.compared}"
        if inp.compared
        else (f", acting {', '.join(f'`{a}`' for a in acting)}" if acting else "")
    )
    doc.md += [
        "## The paper's claims",
        "",
        "Each claim of the EVAAA paper judged against the numbers above by fixed rules that decide both ways "
        '(docs/reports.md, "The verdict rules"; margins from the protocol: '
        f"`margin={inp.verdict_rules.margin:g}`, `gain_margin={inp.verdict_rules.gain_margin:g}`). "
        f"**A beats B** (survival; testbed success the same on rates): the ratio of their IQMs with its 95 % bootstrap interval — above "
        f"{1 + inp.verdict_rules.margin:g} reproduces, at or under {1 + inp.verdict_rules.margin:g} contradicts (equal "
        "within the margin, or worse), straddling it is not resolvable. **Censoring**: a cell with more than a "
        "quarter of its episodes at the step cap is a lower bound (`≥`); a ratio over a capped cell cannot "
        "reproduce, one of a capped cell cannot contradict. **Fails**, one definition for every claim: did not "
        "learn by the gate — the survival interval not above "
        f"{inp.verdict_rules.fails_factor:g}× the better of random and stand-still on that level. **The gate "
        "decides nothing**: every agent is compared; a part the data leave undecided says which of its agents "
        'did not learn. (d)\'s "no monotonic gain": the gain of mean testbed success along the least-squares '
        "line from the first training level to the last, its 95 % interval from a two-stage bootstrap that redraws "
        "a curriculum's seeds together across its levels — at or under "
        f"+{inp.verdict_rules.gain_margin:g} (no gain beyond the margin) reproduces, above it contradicts — or a "
        "drop between consecutive training levels (one-sided two-proportion tests on the effective episodes, "
        "Holm-corrected over the steps), which reproduces too; the power of both at these seeds and episodes is "
        f"stated ({100 * inp.verdict_rules.power:.0f} %). A part whose agent cells have fewer than {MIN_SEEDS} "
        "seeds has no interval and is not decided (`not resolvable: 2 seeds`); agents that acted differently are "
        "not compared"
        + (
            f" — the claims compare the checkpoints acting {inp.compared}, and the other acting modes' numbers "
            "in the tables decide nothing"
            if inp.compared
            else ""
        )
        + ". (b) compares at matched total env steps where direct runs of a "
        "curriculum stage's total exist, else at equal env steps per stage (the curriculum stage has seen "
        "more). A claim of several parts is reproduced when every part is, contradicted when any part is (it "
        "states each of them), otherwise not resolvable. Survival per level: "
        + _source_words(inp)
        + " (runs with every sense; curriculum runs where an "
        "algorithm has them). Testbed success: each run's furthest-trained evaluated checkpoint" + how + ".",
        "",
    ]
    if inp.learned_factor is not None:
        gate = inp.gate
        level = evaaa.LEVELS[0]
        known = set(gate["algo"])
        unknown = sorted({r.algo for r in inp.usable} - known)
        doc.md += [
            f"**Which agents learned.** An agent learned {level} when the 95 % interval of its network with every "
            f"sense (IQM of its seeds' episodes) lies above {inp.learned_factor:g}× the better of random and "
            "stand-still there, judged at the budget it is compared at: its compute-matched runs for the comparison "
            f"at equal compute; for the others its direct runs on {level} with a step budget, else its "
            'curriculum\'s first stage. One whose interval does not "did not learn at this budget" — the one '
            'meaning of "fails" in the claims. The gate decides no part: it explains parts the data leave '
            "undecided.",
            "",
            *[f"- {r}" for r in gate["reading"]],
            *[f"- {a}: no evaluation of its network with every sense on {level}" for a in unknown],
            "",
        ]
    doc.md += rules.markdown(inp.verdicts)
    doc.md.append("")


#: The sections after the runs, in the order the report shows them.
def own_levels(doc: Document, inp: Inputs) -> None:
    """Evaluations on levels of your own (``evaluate.py levels=[path/to/my.yaml]``, ``train.py level=file``), when
    there are any: evaluate.py's table, a row per level and a column per policy.  The paper's sections above compare
    the packaged levels only."""
    frames = [f for f in (inp.evals.references, inp.evals.checkpoints) if len(f)]
    rows = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=["level"])
    rows = rows[~rows["level"].isin((*evaaa.LEVELS, *evaaa.TESTBEDS))]
    if not len(rows):
        return
    table = summarize(rows)
    doc.tables["own_levels"] = table
    doc.md += [
        "## Levels of your own",
        "",
        "Levels outside the package, as evaluate.py's summary shows them: the success rate where the level has a "
        "success rule, else survival (decisions); episodes are the units (cells as described under Statistics).",
        "",
        markdown_table(table),
        "",
    ]


SECTIONS = (
    survival_per_level,
    curriculum_vs_direct,
    success_per_testbed,
    generalisation,
    evaluation_survival,
    what_it_learned,
    equal_compute,
    training_curves,
    evaluation_curves,
    ablation_curves,
    ablation_success,
    own_levels,
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
    compare: str | None = None,
    learned: float | None = None,
    margin: float = 0.1,
    gain_margin: float = 0.1,
    choice: dict | None = None,
) -> Report:
    """Read runs and evaluations, write ``out/report.md``, its PNG figures and ``out/data/*.csv`` (the tables'
    numbers); returns what was written.  ``acting``: which of the checkpoints' evaluation modes to report
    (:func:`.load.select_acting`); ``compare``: the one the claims compare, every mode staying in the tables
    (:func:`_one_mode`); ``learned``: the factor over the better of random and stand-still an agent's network
    with every sense must clear on the first level to have learned it (:mod:`.matched`; the bar of "fails");
    ``margin``, ``gain_margin``: the verdict rules' margins (:class:`..paper.claims.Rules`); ``choice``: where ``compare``
    was chosen from validation rows, the choice's data (:mod:`..paper.choice`), stated in the report."""
    inp = read_inputs(
        run_paths,
        eval_paths,
        survival=survival,
        window=window,
        bins=bins,
        acting=acting,
        compare=compare,
        learned=learned,
        margin=margin,
        gain_margin=gain_margin,
        choice=choice,
    )
    doc = Document(Path(out))
    (doc.out / "data").mkdir(parents=True, exist_ok=True)
    introduction(doc, inp, title)
    problems = runs_and_problems(doc, inp)
    for section in SECTIONS:
        section(doc, inp)
    for name, frame in doc.tables.items():
        # each seed's episodes (``samples``) feed the claims' ratio intervals; the CSV keeps the cells' numbers
        frame.drop(columns=["samples"], errors="ignore").to_csv(doc.out / "data" / f"{name}.csv", index=False)
    if len(inp.run_curves):
        rows = inp.run_curves.assign(run=inp.run_curves["run"].map(inp.rel))
        rows.to_csv(doc.out / "data" / "curves_per_run.csv", index=False)
    path = doc.out / "report.md"
    path.write_text("\n".join(doc.md).rstrip() + "\n")
    return Report(path, doc.figures, doc.tables, problems)
