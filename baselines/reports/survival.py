"""The sections of survival on the training levels: survival per level (Fig. 4a, left), with and without
curriculum (Fig. 4a, right) and the evaluations on training levels; :func:`direct_views`, which pairs a direct
run with the curriculum stage its env steps match."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

import evaaa

from .aggregate import across_seeds, per_run
from .document import Document, Inputs
from .figures import plot_bars
from .load import RunRecord, final_checkpoints, level_sorted
from .tables import pivot_table


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


def direct_views(inp: Inputs, rows: pd.DataFrame, key: str) -> pd.DataFrame:
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


#: the titles of :func:`curriculum_vs_direct`'s two views
_VIEW_TITLES = {
    "equal": "Curriculum vs direct at equal env steps per stage (survival, decisions)",
    "matched": "Curriculum vs direct at matched total env steps (survival, decisions)",
}


def _view_table(
    doc: Document, inp: Inputs, name: str, rows: pd.DataFrame, drawn: str | None
) -> tuple[str, Path | None]:
    """One view of :func:`curriculum_vs_direct` (``equal`` or ``matched``, its curriculum and direct ``rows``): its
    table (Markdown, and its numbers in ``doc.tables``) and, where it is the view ``drawn``, its figure."""
    stats = across_seeds(rows, ["label", "level"], "survival").sort_values(
        "label", key=lambda s: s.str.contains("direct"), kind="stable"
    )
    seen = rows.groupby(["label", "level"])["seen"].agg(lambda s: "/".join(f"{v:,}" for v in sorted(set(s))))
    stats["env_steps"] = [seen.get((lb, lv), "") for lb, lv in zip(stats["label"], stats["level"])]
    doc.tables["curriculum_vs_direct" + ("_matched" if name == "matched" else "")] = stats
    levels = level_sorted(stats["level"])
    figure = None
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
    table = (
        pivot_table(stats, "level", "label", rows=levels, title=_VIEW_TITLES[name], compared=inp.compared)
        + "\n\nEnv steps seen per cell: "
        + "; ".join(f"{lv}: {steps_by_level[lv]}" for lv in levels)
        + "."
    )
    return table, figure


def _unmatched_notes(f: pd.DataFrame, direct: pd.DataFrame) -> list[str]:
    """What :func:`curriculum_vs_direct`'s views leave out: the levels no direct run matches at total env steps,
    and the direct runs of neither budget."""
    notes: list[str] = []
    cur = f[f["curriculum"] & f["level"].isin(set(direct["level"]))]
    unmatched = cur[~cur["level"].isin(set(direct.loc[direct["view"].isin({"matched", "both"}), "level"]))]
    if len(unmatched):
        needs = unmatched.groupby("level")["seen"].max()
        notes.append(
            "**At matched total env steps:** no direct run here has as many env steps as the curriculum stage on "
            + ", ".join(f"{lv} ({needs[lv]:,})" for lv in level_sorted(needs.index))
            + "."
        )
    other = direct[direct["view"] == "other"]
    if len(other):
        budgets = other.groupby("level")["seen"].agg(lambda s: "/".join(f"{v:,}" for v in sorted(set(s))))
        notes.append(
            "Direct runs of neither budget, in no view: "
            + ", ".join(f"{lv} ({budgets[lv]} env steps)" for lv in level_sorted(budgets.index))
            + "."
        )
    return notes


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
        f = direct_views(inp, f.assign(setting=f["run"].map(base)), "setting")
        direct = f[~f["curriculum"]]
        views = {}
        for name, kinds in (("equal", {"equal", "both"}), ("matched", {"matched", "both"})):
            d = direct[direct["view"].isin(kinds)]
            rows = pd.concat([f[f["curriculum"] & f["level"].isin(set(d["level"]))], d])
            # a view of its own only where some curriculum stage has seen more than its own env steps
            views[name] = (rows, bool((d["stage_own"] != d["stage_total"]).any())) if len(d) else (rows, False)
        shown = [v for v in ("equal", "matched") if views[v][1]] or (["equal"] if len(views["equal"][0]) else [])
        drawn = max(shown, key=lambda v: (views[v][0]["level"].nunique(), v == "matched"), default=None)
        for name in shown:
            table, drawn_figure = _view_table(doc, inp, name, views[name][0], drawn)
            tables.append(table)
            figure = drawn_figure or figure
        tables += _unmatched_notes(f, direct)
    doc.section(
        "With and without curriculum (Fig. 4a, right)",
        inp.source_note + " Curriculum: the stage of that level after the levels before it (it has seen "
        "their env steps too); direct: a run trained on that level alone.",
        figure,
        "\n\n".join(tables) if figure else None,
        "No algorithm has both curriculum runs (`level=curriculum`) and direct runs (`level=<level>`) here.",
    )


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
