"""Choose the acting mode a protocol's claims compare from its runs' validation rows, before any test evaluation.

    python scripts/choose_acting.py runs=[runs/a,runs/b] out=record/compared_mode.json evals=record/evals

The mode (``sample`` or ``mode``) whose in-training validation evaluations (``eval.csv`` rows with
``worlds=validation``, both modes recorded through ``eval.both_modes=true``) survive longer, pooled over every
network's last validation evaluation, is written to ``out`` with the numbers it rests on; ``out`` is written once
and never over.  It refuses where ``evals`` already holds a checkpoint's evaluation: the choice must not follow one.
A protocol with ``evaluation.compare: validation`` runs it as its cell ``choose/acting`` (scripts/reproduce.py),
after every training and before every checkpoint's evaluation.  See docs/reports.md.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

from evaaa_baselines import cli
from evaaa_baselines.cli import option
from evaaa_baselines.paper.choice import ChoiceError, checkpoint_evaluations, choice_text, choose, write_choice


@dataclass
class ChooseConfig:
    runs: list[str] = option([], "the run directories whose eval.csv rows the choice pools")
    out: str = option("compared_mode.json", "the file the choice is written to (never over an existing one)")
    first: str = option(
        "sample", "the mode chosen where both survive as long (the protocol's first)", choices=["sample", "mode"]
    )
    epsilon: float = option(
        0.0,
        "the epsilon of the protocol's test evaluations: the compared acting is named as they record it "
        "(sample+epsilon=0.05)",
        check=(lambda v: 0 <= v <= 1, "a number in [0, 1]"),
    )
    evals: str | None = option(
        None, "a folder of test evaluations that must not yet hold a checkpoint's (reference agents' may be there)"
    )


def main(argv: list[str] | None = None) -> int:
    cfg = cli.parse(
        ChooseConfig,
        argv,
        prog="choose_acting.py",
        description=__doc__.split("\n\n")[0],
        examples=["runs=[runs/a,runs/b] out=record/compared_mode.json evals=record/evals"],
    )
    if not cfg.runs:
        cli.fail("choose_acting.py", "runs: give the run directories, runs=[a,b]")
    made = checkpoint_evaluations(cfg.evals) if cfg.evals else []
    if made:
        cli.fail(
            "choose_acting.py",
            f"evals: {made[0]} holds a checkpoint's evaluation: the compared mode is chosen before any "
            f"({len(made)} found); nothing was written",
        )
    try:
        data = choose(cfg.runs, cfg.first, cfg.epsilon)
        path = write_choice(cfg.out, data)
    except ChoiceError as err:
        cli.fail("choose_acting.py", str(err))
    print(f"wrote {path}: {choice_text(data, path.name)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
