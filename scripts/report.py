"""A Markdown report with the paper's figures from training runs and evaluations.

    python scripts/report.py runs=[runs/sweep] evals=[outputs/eval-sweep] out=reports/sweep
    python scripts/report.py runs=[runs] evals=[outputs/eval,outputs/human/episodes.csv] survival=train

Arguments are ``key=value`` (lists as ``[a,b]``), the keys of :class:`ReportConfig`; ``--help`` lists them with
their types, defaults and meanings.

Writes ``out/report.md`` (seeds as the unit; tables: survival as interquartile mean with its 95 % bootstrap interval
over seeds and episodes beside mean ± standard error across seeds, success rates with 95 % seed-clustered Wilson
intervals, no interval under three seeds but each seed's value, n as seeds × episodes, every table naming how the
agents acted and on which worlds; what each agent learned beside random and stand-still; the paper's claims; the
runs, and those missing or unfinished),
the figures ``fig_training_curves.png`` (training survival against env steps, one panel per training set-up),
``fig4a_survival_per_level.png``, ``fig4a_curriculum_vs_direct.png``, ``fig4b_success_per_testbed.png``,
``fig4b_generalisation.png``, ``fig25_ablation_curves.png``, ``fig26_ablation_success.png`` (those the inputs have
data for) and the tables' numbers as ``out/data/*.csv``.  See docs/reports.md.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

from evaaa_baselines import cli  # noqa: E402
from evaaa_baselines.cli import option  # noqa: E402


@dataclass
class ReportConfig:
    runs: list[str] = option([], "run directories of scripts/train.py, or folders holding them (searched recursively)")
    evals: list[str] = option(
        [],
        "evaluate.py output directories (or folders of them, searched recursively) or "
        "episode CSV files (incl. human play records of scripts/play.py); a checkpoint "
        "evaluated there is tied to its run through the run directory it lies in",
    )
    out: str = option("outputs/report", "output directory")
    survival: str = option(
        "eval",
        "eval: a stage's survival is its last evaluation (eval.csv); train: the mean of "
        "its last `window` training episodes (also the fallback for stages without "
        "evaluations)",
        choices=["eval", "train"],
    )
    window: int = option(
        20, "training episodes averaged for survival=train", check=(lambda v: v >= 1, "a positive integer")
    )
    bins: int = option(20, "env-step bins of the training curves", check=(lambda v: v >= 1, "a positive integer"))
    title: str = option("evaaa report", "the report's title")
    acting: str | None = option(
        None,
        "which evaluations of the checkpoints to report when one was evaluated in "
        "several ways: mode, sample, mode+epsilon=0.05 ... (evaluate.py's acting "
        "column; reference agents are always kept)",
    )
    compare: str | None = option(
        None,
        "the acting mode the claims compare when checkpoints were evaluated in several ways "
        "(mode, sample, ...; every mode stays in the tables, labelled): each run's rows of that "
        "mode, and where a run's algorithm has no action distribution (DQN) and sample is "
        "compared, its greedy rows, labelled so; unset: the mode every run has (mode first)",
    )
    compare_from: str | None = option(
        None,
        "a protocol's compared_mode.json (written by choose_acting.py from validation rows before any test "
        "evaluation): the claims compare the mode it chose, and the report states the choice with its numbers; "
        "instead of compare",
    )
    learned: float | None = option(
        None,
        "an agent enters the claims' comparisons only if its network with every sense survives the first "
        "level at least this many times the better of random and stand-still (e.g. 2); one that does not is "
        "reported as 'did not learn at this budget'; unset: every agent is compared",
        check=(lambda v: v is None or v > 0, "a positive factor"),
    )
    margin: float = option(
        0.1,
        "the verdict rules' margin: 'A beats B' (survival IQMs, testbed success rates) is reproduced when the 95 % "
        "interval of the ratio A / B lies above 1 + margin and contradicted when it lies at or under it "
        "(docs/reports.md)",
        check=(lambda v: 0 <= v < 1, "a number in [0, 1)"),
    )
    gain_margin: float = option(
        0.1,
        "claim (d)'s margin, in testbed success (0.1: 10 points): 'no monotonic gain' is reproduced when the 95 % "
        "interval of the gain along the least-squares line from the first training level to the last lies at or "
        "under +gain_margin and contradicted when it lies above (docs/reports.md)",
        check=(lambda v: 0 < v < 1, "a number in (0, 1)"),
    )


def parse(argv: list[str] | None = None) -> ReportConfig:
    """The config from ``key=value`` arguments; ``--help`` lists the keys."""
    return cli.parse(
        ReportConfig,
        argv,
        prog="report.py",
        description=__doc__.split("\n\n")[0],
        examples=[
            "runs=[runs/sweep] evals=[outputs/eval-sweep] out=reports/sweep",
            "runs=[runs] evals=[outputs/eval,outputs/human/episodes.csv] survival=train",
        ],
    )


def main(argv: list[str] | None = None) -> int:
    cfg = parse(argv)
    # after the arguments: --help and a refusal need neither scipy nor pandas (--help within 3 s of CPU)
    from evaaa_baselines.paper.choice import ChoiceError, read_choice
    from evaaa_baselines.paper.report import build_report
    from evaaa_baselines.reports import ReportError

    compare, choice = cfg.compare, None
    if cfg.compare_from is not None:
        if cfg.compare is not None:
            cli.fail("report.py", "compare_from: give compare or compare_from, not both")
        try:
            choice = read_choice(cfg.compare_from)
        except ChoiceError as err:
            cli.fail("report.py", str(err))
        compare = choice["compare"]
    try:
        report = build_report(
            cfg.runs,
            cfg.evals,
            cfg.out,
            survival=cfg.survival,
            window=cfg.window,
            bins=cfg.bins,
            title=cfg.title,
            acting=cfg.acting,
            compare=compare,
            learned=cfg.learned,
            margin=cfg.margin,
            gain_margin=cfg.gain_margin,
            choice=choice,
        )
    except ReportError as err:  # an input that does not hold what the key asks for: named in the message
        cli.fail("report.py", str(err))
    for problem in report.problems:
        print(f"note: {problem}")
    print("wrote " + ", ".join(str(p) for p in [report.markdown, *report.figures]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
