"""The full report: :func:`build_report` reads the inputs (:func:`.verdicts.read_inputs`), writes the
introduction (what the agents learned, the claims at a glance, how to read the cells), the runs, every section of
:mod:`..reports` in the order of :data:`SECTIONS` and the claims, then the files (``report.md``, its PNG figures,
``data/*.csv``).  It sits in the paper layer because it shows the claims; the drawing layer (:mod:`..reports`)
imports nothing from here."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from ..reports.ablations import ablation_curves, ablation_success
from ..reports.curves import evaluation_curves, training_curves
from ..reports.document import STATISTICS_NOTE, Document, Report, own_levels, runs_and_problems
from ..reports.equal_compute import equal_compute
from ..reports.learned import learned_paragraph, what_it_learned
from ..reports.survival import curriculum_vs_direct, evaluation_survival, survival_per_level
from ..reports.testbeds import generalisation, success_per_testbed
from . import claims as rules
from .choice import choice_text
from .verdicts import ClaimInputs, claims, read_inputs


def introduction(doc: Document, inp: ClaimInputs, title: str) -> None:
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


#: The sections after the runs, in the order the report shows them.
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
    (:func:`..reports.load.select_acting`); ``compare``: the one the claims compare, every mode staying in the
    tables (:func:`..reports.document.one_mode`); ``learned``: the factor over the better of random and
    stand-still an agent's network with every sense must clear on the first level to have learned it
    (:mod:`..reports.matched`; the bar of "fails"); ``margin``, ``gain_margin``: the verdict rules' margins
    (:class:`.claims.Rules`); ``choice``: where ``compare`` was chosen from validation rows, the choice's data
    (:mod:`.choice`), stated in the report."""
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
