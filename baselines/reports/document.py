"""The report being written and what it is about: :class:`Document` (its Markdown, figures and tables),
:class:`Inputs` (the runs and evaluations read once, with the numbers several sections share) and
:func:`read_inputs`; :class:`Report` (what was written); the sections every report opens and closes with that need
no claim (the runs and what is missing, levels of your own); and the acting mode one comparison uses
(:func:`one_mode`).  Every table names how the agents acted and on which worlds (its caption, and the ``acting``
and ``worlds`` columns of its CSV); an agent evaluated in several ways gets one labelled column per way.
The paper's claims and the assembled report are in :mod:`..paper.verdicts` and :mod:`..paper.report`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import pandas as pd

import evaaa

from .aggregate import curves, final_survival, reference_stats
from .learned import learned_table
from .load import (
    GREEDY_STAND_IN,
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
    load_evaluations,
    load_run,
    select_acting,
    stand_in,
)
from .matched import learned_gate
from .stats import MIN_SEEDS
from .tables import markdown_table, summarize


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
    # most frequent (:func:`one_mode`)
    compare: str | None = None
    # report option ``learned``: an agent enters the claims' comparisons only if its all-senses network survives the
    # first level at least this many times the better of random and stand-still (:mod:`.matched`); None: every agent
    learned_factor: float | None = None

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
        final = one_mode(self.final, self)
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


def check_options(survival: str, window: int, bins: int, learned: float | None) -> None:
    """A :class:`ReportError` for a report option out of its range (the options :func:`read_inputs` reads by)."""
    if survival not in ("eval", "train"):
        raise ReportError(f"survival must be eval or train, not {survival!r}")
    if window < 1 or bins < 1:
        raise ReportError("window and bins must be positive")
    if learned is not None and not learned > 0:
        raise ReportError(f"learned must be a positive factor (e.g. 2), not {learned!r}")


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
) -> Inputs:
    """Check the arguments, read the runs and evaluations and tie the evaluated checkpoints to their runs."""
    check_options(survival, window, bins, learned)
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
    inputs = Inputs(runs, evals, read_notes, survival, window, bins, compare, learned)
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


def one_mode(rows: pd.DataFrame, inp: Inputs | None = None) -> pd.DataFrame:
    """``rows`` of one acting mode for the claims, the same for every agent where it can be.  With the report's
    ``compare``: each run's rows acting so — for a run whose algorithm has no action distribution (DQN) in a
    ``sample`` comparison, its greedy rows, their ``acting`` relabelled ``sample… (greedy: no action
    distribution)`` so that :mod:`..paper.claims` compares them with the others' sampled rows and says so.  Without it
    (or for runs with neither): where networks were evaluated in several ways, the way every run has (the
    deterministic ``mode…`` first, the one every algorithm has; DQN has no other), else each run's most frequent
    (such agents are then not compared: :mod:`..paper.claims`).  The other ways stay in the tables, labelled."""
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


def source_words(inp: Inputs) -> str:
    """How the final survival of a stage was measured, in words (the source note without its label)."""
    return inp.source_note[len("Survival: ") :].rstrip(".")


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
