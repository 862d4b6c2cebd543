"""Reports from finished (or running) training runs and evaluations: the paper's figures and their tables, and
``scripts/evaluate.py``'s summary of an evaluation.

The package reads top to bottom:

* :mod:`.load` — the inputs: run directories of ``scripts/train.py`` and episode files of ``scripts/evaluate.py``
  and ``scripts/play.py``, an evaluated checkpoint tied to its run through the directory it lies in;
* :mod:`.stats` — the estimators, seeds as the unit (interquartile mean with a two-stage bootstrap over seeds and
  episodes within seeds, refused under three seeds; seed-clustered Wilson intervals; Holm's correction);
* :mod:`.aggregate` — a report's numbers: survival per stage from per-episode evaluations, training curves, a table
  cell's statistics over seeds (its points where there are fewer than three);
* :mod:`.tables` and :mod:`.figures` — Markdown tables and PNG figures of those numbers;
* :mod:`.document` — the report being written and the inputs it is about, read once (:func:`read_inputs`), with
  the runs and what is missing;
* the sections, one room each: :mod:`.survival` (Fig. 4a), :mod:`.testbeds` (Fig. 4b), :mod:`.learned` (what each
  agent learned), :mod:`.equal_compute` (Fig. 20), :mod:`.curves` (training and in-training evaluation curves),
  :mod:`.ablations` (Figs. 25 and 26).

This layer draws; it imports nothing from :mod:`..paper`.  The paper's claims judged on these numbers
(:mod:`..paper.verdicts`) and the full report, sections and claims together (:func:`..paper.report.build_report`,
what ``scripts/report.py`` calls), are in the paper layer.

Runs that differ only in their seed (and in bookkeeping: logger, evaluation and checkpoint cadence, threads, run
directory) are pooled; anything else that differs (modality, reward, a hyperparameter, steps per stage, curriculum
or not) makes a separate group, and labels name what differs.  Nothing is dropped silently: runs without episodes,
unfinished runs and evaluations whose run directory is gone are listed in the report.  Every table names how the
agents acted and on which worlds.  See docs/reports.md.
"""

from .aggregate import STAT_COLUMNS, across_seeds, curves, estimate, final_survival, mean_se, per_run, reference_stats
from .document import Report
from .figures import OUTCOMES, outcome, plot_bars, plot_lines, plot_outcomes, plot_summary, short_labels
from .load import (
    REFERENCES,
    Evaluations,
    ReportError,
    RunRecord,
    attach,
    describe_extras,
    display_names,
    final_checkpoints,
    find_run_dirs,
    labels,
    load_evaluations,
    load_run,
    read_episodes,
    select_acting,
)
from .tables import SUMMARY_NOTE, cell, markdown_table, pivot_table, sample_size, summarize

__all__ = [
    "OUTCOMES",
    "REFERENCES",
    "STAT_COLUMNS",
    "SUMMARY_NOTE",
    "Evaluations",
    "Report",
    "ReportError",
    "RunRecord",
    "across_seeds",
    "attach",
    "cell",
    "curves",
    "describe_extras",
    "display_names",
    "estimate",
    "final_checkpoints",
    "final_survival",
    "find_run_dirs",
    "labels",
    "load_evaluations",
    "load_run",
    "markdown_table",
    "mean_se",
    "outcome",
    "per_run",
    "pivot_table",
    "plot_bars",
    "plot_lines",
    "plot_outcomes",
    "plot_summary",
    "read_episodes",
    "reference_stats",
    "sample_size",
    "select_acting",
    "short_labels",
    "summarize",
]
