"""The sections of curves against env steps: training curves and the in-training evaluations."""

from __future__ import annotations

from .aggregate import across_seeds, evaluation_points
from .document import Document, Inputs
from .figures import plot_lines
from .load import labels
from .tables import pivot_table


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
