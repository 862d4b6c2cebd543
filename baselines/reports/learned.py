"""What each agent learned beside the references: :func:`learned_table` (food, water, collisions, ends and
survival per level), the report's opening paragraph on it (:func:`learned_paragraph`) and its section
(:func:`what_it_learned`)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

import evaaa

from .aggregate import across_seeds
from .load import MODEL_FILE, level_sorted
from .stats import MIN_SEEDS
from .tables import capped, caption, censored_note

if TYPE_CHECKING:
    from .document import Document, Inputs


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


def _describe(label: str, level: str, part: pd.DataFrame, unit: str, key: str | None) -> dict:
    """One row of :func:`learned_table`: ``part``'s episodes of one agent (seeds: its runs, grouped by ``key``) or
    reference agent (``key`` None) on ``level``."""
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
    for (policy, level), part in refs.groupby(["policy", "level"], sort=False):
        rows.append(_describe(policy, level, part, "episodes", None))
    if len(own):
        own = inp.labelled(own, inp.checkpoint_labels)
        for (label, level), part in own.groupby(["label", "level"], sort=False):
            rows.append(_describe(label, level, part, "seeds", "run"))
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
