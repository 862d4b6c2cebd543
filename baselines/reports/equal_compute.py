"""The section at equal compute (Fig. 20): every algorithm trained on one level for the same CPU minutes, its
curves and final networks; :func:`matched_survival` and :func:`matched_reaching`, the numbers the claims take
from it."""

from __future__ import annotations

import numpy as np
import pandas as pd

from .aggregate import STAT_COLUMNS, across_seeds, evaluation_points
from .document import Document, Inputs, one_mode, source_words
from .figures import plot_lines
from .matched import curve_points, reaching, threshold
from .tables import capped, caption, cell


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
    final = one_mode(inp.final, inp)
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


def _curves(doc: Document, inp: Inputs, level: str, budget: str, points: pd.DataFrame, lab: dict) -> None:
    """Fig. 20's learning curves (the compute-matched runs' in-training evaluations ``points``, labelled ``lab``)
    against env steps and CPU minutes, with the references and the learning threshold as lines."""
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


def _final_row(row, steps: dict[str, list[int]], gate: pd.DataFrame | None, reach: pd.DataFrame) -> str:
    """A row of the final networks' table at equal compute: an algorithm's survival and intake, and with a gate
    whether it learned and when its evaluations reached the threshold."""
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
    return line


def _final_note(inp: Inputs, level: str, gated: bool) -> str:
    """The note under the final networks' table: how survival and intake were measured, and the learning
    threshold where there is one (``gated``)."""
    refs = inp.reference_training
    refs = refs[(refs["level"] == level) & refs["label"].isin(["random", "still"])] if len(refs) else refs
    ref_intake = "; ".join(
        f"{'stand-still' if r.label == 'still' else r.label} {r.intake:.1f}"
        for r in refs.itertuples()
        if not np.isnan(r.intake)
    )
    return (
        "Survival: "
        + source_words(inp)
        + "; a cell with more than a quarter of its episodes at the step cap is a lower bound (`≥`, share at the "
        "cap); intake: food and water eaten per 1,000 decisions, every episode of the seeds pooled"
        + (f" (references on {level}: {ref_intake})" if ref_intake else "")
        + "; env steps reached: per seed; "
        + (
            f"learned: the 95 % interval above {inp.learned_factor:g}× the better of random and stand-still on "
            f"{level}; "
            "threshold: the first in-training evaluation (validation worlds, IQM of its episodes) at or above "
            "that, per seed (never: not within the budget)."
            if gated
            else "no learning threshold (the report option `learned` is unset)."
        )
    )


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
        _curves(doc, inp, level, budget, points, lab)
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
    doc.md += [_final_row(row, steps, gate, reach) for row in surv.itertuples()]
    doc.tables["equal_compute_final"] = surv
    if len(reach):
        doc.tables["equal_compute_threshold"] = reach.assign(run=reach["run"].map(inp.rel))
    doc.md += ["", _final_note(inp, level, gate is not None), ""]
