"""A Markdown report with the paper's figures from training runs and evaluations.

    python scripts/report.py runs=[runs/sweep] evals=[outputs/eval-sweep] out=reports/sweep
    python scripts/report.py runs=[runs] evals=[outputs/eval,outputs/human/episodes.csv] survival=train

Arguments (``key=value``, lists as ``[a,b]``):
    runs      run directories of scripts/train.py, or folders holding them (searched recursively)
    evals     evaluate.py output directories or episode CSV files (incl. human play records of scripts/play.py);
              a checkpoint evaluated there is tied to its run through the run directory it lies in
    out       output directory (default outputs/report)
    survival  eval (default): a stage's survival is its last evaluation (eval.csv); train: the mean of its last
              `window` training episodes (also the fallback for stages without evaluations)
    window    training episodes averaged for `survival=train` (default 20)
    bins      env-step bins of the training curves (default 20)
    title     the report's title
    acting    which evaluations of the checkpoints to report when one was evaluated in several ways: mode, sample,
              mode+epsilon=0.05 ... (evaluate.py's acting column; reference agents are always kept)

Writes ``out/report.md`` (tables: mean ± standard error across seeds; the runs, and those missing or unfinished),
the figures ``fig_training_curves.png`` (training survival against env steps, one panel per training set-up),
``fig4a_survival_per_level.png``, ``fig4a_curriculum_vs_direct.png``, ``fig4b_success_per_testbed.png``,
``fig4b_generalisation.png``, ``fig25_ablation_curves.png``, ``fig26_ablation_success.png`` (those the inputs have
data for) and the tables' numbers as ``out/data/*.csv``.  See docs/reports.md.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path

from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing

from baselines.report import ReportError, build_report  # noqa: E402


@dataclass
class ReportConfig:
    runs: list[str] = field(default_factory=list)
    evals: list[str] = field(default_factory=list)
    out: str = "outputs/report"
    survival: str = "eval"
    window: int = 20
    bins: int = 20
    title: str = "evaaa report"
    acting: str | None = None


def parse(argv: list[str]) -> ReportConfig:
    """``key=value`` arguments over the defaults; a single value where a list is expected becomes a list."""
    bad = [a for a in argv if "=" not in a]
    allowed = ", ".join(ReportConfig.__dataclass_fields__)
    if bad:
        raise SystemExit(f"report.py: arguments are key=value, got {' '.join(bad)}\n  allowed keys: {allowed}")
    try:
        given = OmegaConf.from_dotlist(argv)
        for key in ("runs", "evals"):
            if key in given and not OmegaConf.is_list(given[key]):
                given[key] = [given[key]]
        return OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(ReportConfig), given))
    except OmegaConfBaseException as err:
        raise SystemExit(f"report.py: {err.msg if hasattr(err, 'msg') else err}\n  allowed keys: {allowed}") from None


def main(argv: list[str] | None = None) -> int:
    cfg = parse(sys.argv[1:] if argv is None else argv)
    try:
        report = build_report(cfg.runs, cfg.evals, cfg.out, survival=cfg.survival, window=cfg.window,
                              bins=cfg.bins, title=cfg.title, acting=cfg.acting)
    except ReportError as err:
        raise SystemExit(f"report.py: {err}") from None
    for problem in report.problems:
        print(f"note: {problem}")
    print("wrote " + ", ".join(str(p) for p in [report.markdown, *report.figures]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
