"""The paper's claims (a)–(e) of issue 20 judged against a report's numbers: each claim's rule, applied to tables of
estimates with 95 % intervals (``value``, ``low``, ``high``), gives a :class:`Verdict` — reproduced, contradicted, or
not resolvable at this scale — with the numbers behind it.

The rules are deliberately conservative: two cells differ only where their intervals (two-stage bootstrap over
seeds and episodes, seed-clustered Wilson for success; :mod:`.stats`) do not overlap; overlapping intervals never
decide a claim.  A part whose agent cells have fewer than three seeds has no intervals and is not decided: its
verdict is "not resolvable: 2 seeds", with the numbers (each seed's value).  Two agents that acted differently
(greedy against sampled actions) are not compared — except where a report compares sampled actions and an agent
without an action distribution (DQN) takes part with its greedy action, labelled so
(:data:`..reports.load.GREEDY_STAND_IN`).  The (d) "drop" rule looks at every pair of training levels of an agent,
so its one-sided paired tests over seeds are corrected for the number of pairs (Holm).  A claim made of parts is
reproduced when every part with data is, contradicted when some part is and none is reproduced, and otherwise not
resolvable (the parts' verdicts are listed).  A part without data (DreamerV3, human records) is said to be missing
and counts as not resolvable.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import stats as sps

from ..reports.load import GREEDY_STAND_IN, same_acting
from ..reports.stats import MIN_SEEDS, holm

REPRODUCED, CONTRADICTED, UNRESOLVED = "reproduced", "contradicted", "not resolvable at this scale"


def few_seeds(n: int) -> str:
    """The verdict of a part whose cells have ``n`` < 3 seeds."""
    return f"not resolvable: {n} seed{'s' if n != 1 else ''}"


def unresolved(verdict: str) -> bool:
    return verdict.startswith("not resolvable")


def seeds_short(*cells) -> int | None:
    """The fewest seeds among agent cells (rows or frames with ``n`` and ``unit``; reference agents, whose units
    are episodes, do not count) where that is under :data:`MIN_SEEDS`, else None."""
    counts = []
    for c in cells:
        frame = c.to_frame().T if isinstance(c, pd.Series) else c
        if frame is None or not len(frame) or "n" not in frame:
            continue
        agents = frame[frame["unit"] == "seeds"] if "unit" in frame else frame
        counts += [int(n) for n in agents["n"].dropna()]
    short = [n for n in counts if n < MIN_SEEDS]
    return min(short) if short else None


#: levels the paper calls hard: survival drops sharply from 3-2 on
HARD_FROM = "3-2"


@dataclass
class Verdict:
    """One claim or part of a claim: what it says, the verdict, the rule applied and the numbers behind it."""

    claim: str
    verdict: str
    rule: str
    evidence: list[str] = field(default_factory=list)
    parts: list[Verdict] = field(default_factory=list)


def _num(x: float) -> str:
    return f"{x:.0f}" if abs(x) >= 100 else f"{x:.3g}"  # survival in whole decisions, rates to 3 digits


def _fmt(row) -> str:
    v, lo, hi = float(row["value"]), float(row["low"]), float(row["high"])
    if math.isnan(v):
        return "n/a"
    if math.isnan(lo):
        points = row.get("points", ()) if hasattr(row, "get") else ()
        if isinstance(points, tuple) and len(points) > 1:
            return f"{_num(v)} (seeds {', '.join(_num(p) for p in points)})"
        return _num(v)
    return f"{_num(v)} [{_num(lo)}, {_num(hi)}]"


def above(a, b) -> bool:
    """``a``'s interval lies entirely above ``b``'s (no overlap)."""
    return not (math.isnan(a["low"]) or math.isnan(b["high"])) and a["low"] > b["high"]


def spearman(x, y) -> tuple[float, float]:
    """Spearman's rho of ``y`` against ``x`` and its two-sided p-value from the exact permutation distribution (all
    n! orders of ``y``, at most 8 levels here): scipy's ``spearmanr`` p-value comes from a t approximation that
    gives p = 0 to any perfect order, even of 3 or 4 levels, where the exact p is 1/3 or 1/12."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    r0 = sps.rankdata(x)
    r0 = r0 - r0.mean()

    def rho(v, axis=-1):
        rv = sps.rankdata(v, axis=axis)
        rv = rv - rv.mean(axis=axis, keepdims=True)
        return (rv * r0).sum(axis=axis) / np.sqrt((rv**2).sum(axis=axis) * (r0**2).sum())

    res = sps.permutation_test(
        (y,),
        rho,
        permutation_type="pairings",
        vectorized=True,
        n_resamples=math.factorial(len(y)),
        alternative="two-sided",
    )
    return float(res.statistic), float(res.pvalue)


def combine(claim: str, parts: Sequence[Verdict], rule: str) -> Verdict:
    """A claim made of ``parts``: reproduced when every part is, contradicted when some part is and none is
    reproduced, otherwise not resolvable."""
    verdicts = [p.verdict for p in parts]
    if verdicts and all(v == REPRODUCED for v in verdicts):
        verdict = REPRODUCED
    elif CONTRADICTED in verdicts and REPRODUCED not in verdicts:
        verdict = CONTRADICTED
    else:
        # every part with data short of seeds in the same way: the claim says so
        with_data = {v for v, p in zip(verdicts, parts) if p.rule != "no data"}
        verdict = (
            with_data.pop()
            if len(with_data) == 1 and next(iter(with_data)).startswith("not resolvable: ")
            else UNRESOLVED
        )
    return Verdict(claim, verdict, rule, parts=list(parts))


def _gate(verdict: Verdict, *cells) -> Verdict:
    """``verdict`` unless its agent cells have fewer than three seeds: then not resolvable, with the numbers."""
    n = seeds_short(*cells)
    if n is not None:
        verdict.verdict = few_seeds(n)
        verdict.evidence.append(f"fewer than {MIN_SEEDS} seeds ({n}): no interval, no verdict")
    return verdict


def missing(claim: str, what: str) -> Verdict:
    return Verdict(claim, UNRESOLVED, "no data", [f"no data: {what}"])


def _sorted(frame: pd.DataFrame, order: Sequence[str]) -> pd.DataFrame:
    rank = {n: i for i, n in enumerate(order)}
    return frame[frame["level"].isin(rank)].sort_values("level", key=lambda s: s.map(rank))


# ------------------------------------------------------------------------------------------------ (a)
def survival_falls(survival: pd.DataFrame, order: Sequence[str], hard_from: str = HARD_FROM) -> Verdict:
    """(a) Survival falls with level difficulty, sharply from 3-2 on.  ``survival``: columns algo, level, value,
    low, high (survival per training level).  Per algorithm: Spearman's rho of survival against level order (scipy,
    two-sided p) and whether every level from ``hard_from`` on lies below every level before it (intervals apart).
    Reproduced: rho < 0 with p < 0.05 and the hard levels apart below; contradicted: rho > 0 with p < 0.05, or the
    hard levels apart above; otherwise not resolvable."""
    claim = f"(a) survival falls with level difficulty, sharply from {hard_from} on"
    rule = (
        f"per algorithm: Spearman's rho of survival IQM against level order (p < 0.05), and every level from "
        f"{hard_from} on below every earlier level (95 % intervals apart)"
    )
    if not len(survival):
        return missing(claim, "no survival per training level")
    cut = list(order).index(hard_from)
    parts = []
    for algo, part in survival.groupby("algo", sort=False):
        part = _sorted(part.dropna(subset=["value"]), order)
        rank = part["level"].map({n: i for i, n in enumerate(order)})
        evidence = ["; ".join(f"{r.level}: {_fmt(r._asdict())}" for r in part.itertuples())]
        if len(part) < 3 or part["value"].nunique() < 2:
            parts.append(
                _gate(Verdict(f"{algo}", UNRESOLVED, rule, evidence + ["fewer than 3 levels, or all equal"]), part)
            )
            continue
        rho, p = spearman(rank, part["value"])
        early, late = part[rank < cut], part[rank >= cut]
        apart_below = len(early) and len(late) and late["high"].max() < early["low"].min()
        apart_above = len(early) and len(late) and late["low"].min() > early["high"].max()
        evidence.append(
            f"Spearman's rho {rho:.2f} (p = {p:.3g}, {len(part)} levels); levels from {hard_from} on "
            + (
                "apart below the earlier ones"
                if apart_below
                else "apart above the earlier ones"
                if apart_above
                else "not apart from the earlier ones (intervals overlap)"
            )
        )
        if rho < 0 and p < 0.05 and apart_below:
            verdict = REPRODUCED
        elif (rho > 0 and p < 0.05) or apart_above:
            verdict = CONTRADICTED
        else:
            verdict = UNRESOLVED
        parts.append(_gate(Verdict(f"{algo}", verdict, rule, evidence), part))
    return combine(claim, parts, rule)


# ------------------------------------------------------------------------------------------------ (b)
def curriculum_beats_direct(cmp: pd.DataFrame, order: Sequence[str], skip: Sequence[str] = ("1-1",)) -> Verdict:
    """(b) Curriculum beats direct training.  ``cmp``: columns algo, setup (curriculum or direct), level, value,
    low, high.  Per algorithm, over the levels both have (``skip``: the first level, where both are the same
    training): reproduced when curriculum's interval lies above direct's on at least half of them and below on none;
    contradicted when direct's lies above on at least half and curriculum's above on none; otherwise not
    resolvable."""
    claim = "(b) curriculum beats direct training"
    rule = (
        "per algorithm, levels after the first: curriculum's 95 % interval above direct's (no overlap) on at least "
        "half of the levels and below on none"
    )
    if not len(cmp) or set(cmp["setup"]) != {"curriculum", "direct"}:
        return missing(claim, "no algorithm with both curriculum and direct runs")
    parts = []
    for algo, part in cmp.groupby("algo", sort=False):
        cur = part[part["setup"] == "curriculum"].set_index("level")
        dire = part[part["setup"] == "direct"].set_index("level")
        levels = [lv for lv in order if lv in cur.index and lv in dire.index and lv not in skip]
        if not levels:
            parts.append(missing(algo, "no level with both curriculum and direct runs"))
            continue
        up = [lv for lv in levels if above(cur.loc[lv], dire.loc[lv])]
        down = [lv for lv in levels if above(dire.loc[lv], cur.loc[lv])]
        evidence = [
            "; ".join(f"{lv}: curriculum {_fmt(cur.loc[lv])} vs direct {_fmt(dire.loc[lv])}" for lv in levels),
            f"curriculum above on {len(up)} of {len(levels)} levels ({', '.join(up) or 'none'}), below on "
            f"{len(down)} ({', '.join(down) or 'none'})",
        ]
        if 2 * len(up) >= len(levels) and not down:
            verdict = REPRODUCED
        elif 2 * len(down) >= len(levels) and not up:
            verdict = CONTRADICTED
        else:
            verdict = UNRESOLVED
        parts.append(_gate(Verdict(algo, verdict, rule, evidence), cur.loc[levels], dire.loc[levels]))
    return combine(claim, parts, rule)


# ------------------------------------------------------------------------------------------------ (c)
def _ordered(a: str, b: str, survival: pd.DataFrame, order: Sequence[str]) -> Verdict:
    """``a`` survives longer than ``b``: per level, intervals apart; reproduced when a is above on at least half of
    the levels both have and below on none (and the reverse for contradicted)."""
    rule = "per level, 95 % intervals apart: above on at least half of the levels both have and below on none"
    sa, sb = (survival[survival["algo"] == x].set_index("level") for x in (a, b))
    if not len(sa) or not len(sb):
        return missing(f"{a} > {b}", f"no survival of {a if not len(sa) else b}")
    levels = [lv for lv in order if lv in sa.index and lv in sb.index]
    up = [lv for lv in levels if above(sa.loc[lv], sb.loc[lv])]
    down = [lv for lv in levels if above(sb.loc[lv], sa.loc[lv])]
    evidence = [
        f"{a} above {b} on {len(up)} of {len(levels)} levels ({', '.join(up) or 'none'}), below on "
        f"{len(down)} ({', '.join(down) or 'none'})"
    ]
    verdict = (
        REPRODUCED
        if levels and 2 * len(up) >= len(levels) and not down
        else CONTRADICTED
        if levels and 2 * len(down) >= len(levels) and not up
        else UNRESOLVED
    )
    modes = [" / ".join(dict.fromkeys(x.loc[levels, "acting"].astype(str))) if "acting" in x else "" for x in (sa, sb)]
    if all(modes) and not same_acting(*modes):  # greedy against sampled actions says nothing about the algorithms
        verdict = UNRESOLVED
        evidence.append(f"acting modes differ ({a}: `{modes[0]}`, {b}: `{modes[1]}`): not compared")
    elif any(GREEDY_STAND_IN in m for m in modes):  # DQN in a `sample` comparison: its greedy action
        evidence.append(
            f"acting: {a} `{modes[0]}`, {b} `{modes[1]}` (an agent without an action distribution takes its greedy "
            "action where the others sample)"
        )
    return _gate(Verdict(f"{a} > {b} in survival", verdict, rule, evidence), sa.loc[levels], sb.loc[levels])


def _fails(
    algo: str, levels: Sequence[str], survival: pd.DataFrame, random: pd.DataFrame, learns_on: Sequence[str] = ()
) -> Verdict:
    """``algo`` fails on ``levels`` (its survival interval not above random's there) — and, where ``learns_on`` is
    given, does not fail on at least one of those."""
    name = f"{algo} fails" + (f" beyond {learns_on[-1]}" if learns_on else "")
    rule = (
        "fails on a level: its 95 % interval not above the random agent's; reproduced when it fails on every "
        "level"
        + (f" beyond {learns_on[-1]} and is above random on {' or '.join(learns_on)}" if learns_on else "")
        + "; contradicted when it is above random on most of those levels"
    )
    s = survival[survival["algo"] == algo].set_index("level")
    r = random.set_index("level")
    if not len(s):
        return missing(name, f"no survival of {algo}")
    checked = [lv for lv in levels if lv in s.index and lv in r.index]
    if not checked:
        return missing(name, "no random-agent survival on those levels (references on the training levels)")
    beats = [lv for lv in checked if above(s.loc[lv], r.loc[lv])]
    # a level without an interval (one seed's single number) shows neither failing nor learning there
    unknown = [lv for lv in checked if math.isnan(s.loc[lv]["low"]) or math.isnan(r.loc[lv]["high"])]
    evidence = [
        "; ".join(f"{lv}: {_fmt(s.loc[lv])} vs random {_fmt(r.loc[lv])}" for lv in checked),
        f"above random on {len(beats)} of {len(checked)} ({', '.join(beats) or 'none'})",
    ]
    if unknown:
        evidence.append(f"no interval on {', '.join(unknown)}: failing there is not shown")
    early_ok = True
    if learns_on:
        early = [lv for lv in learns_on if lv in s.index and lv in r.index]
        early_ok = any(above(s.loc[lv], r.loc[lv]) for lv in early)
        evidence.append(f"above random on {' or '.join(learns_on)}: {'yes' if early_ok else 'no'}")
    verdict = (
        REPRODUCED
        if not beats and not unknown and early_ok
        else CONTRADICTED
        if 2 * len(beats) > len(checked)
        else UNRESOLVED
    )
    return _gate(Verdict(name, verdict, rule, evidence), s.loc[checked])


def algorithm_ordering(survival: pd.DataFrame, random: pd.DataFrame, order: Sequence[str]) -> Verdict:
    """(c) DreamerV3 > DQN > PPO in survival; DQN fails beyond 1-2; PPO+LSTM fails.  ``survival``: columns algo,
    level, value, low, high; ``random``: the random agent's survival per level (level, value, low, high).  DQN's
    speed on 1-1 (learning curves) is not judged by a rule here."""
    claim = "(c) DreamerV3 > DQN > PPO in survival; DQN fails beyond 1-2; PPO+LSTM fails"
    algos = set(survival["algo"]) if len(survival) else set()
    dreamer = next((a for a in ("dreamer", "dreamer_xs") if a in algos), None)
    parts = [
        _ordered(dreamer, "dqn", survival, order) if dreamer else missing("DreamerV3 > DQN", "no DreamerV3 runs"),
        _ordered("dqn", "ppo", survival, order),
        _fails("dqn", [lv for lv in order if list(order).index(lv) > 1], survival, random, learns_on=order[:2]),
        _fails("ppo_lstm", list(order), survival, random),
    ]
    return combine(claim, parts, "each part by its rule")


#: what a part says of an agent that did not learn: it is compared with nothing
NOT_LEARNED = "not resolvable: did not learn at this budget"


def _not_learned(claim: str, who: Sequence[str], gate: pd.DataFrame) -> Verdict:
    readings = gate.set_index("algo")["reading"] if len(gate) else pd.Series(dtype=str)
    return Verdict(
        claim,
        NOT_LEARNED,
        "an agent enters a comparison only if its network with every sense learned the level",
        [str(readings.get(a, f"{a}: no evaluation of its network on the level")) for a in who],
    )


def _learned(gate: pd.DataFrame) -> list[str]:
    return list(gate.loc[gate["learned"], "algo"]) if len(gate) else []


def survives_longest(algo: str, survival: pd.DataFrame, gate: pd.DataFrame, level: str) -> Verdict:
    """``algo`` survives longest on ``level`` at equal compute: its interval above every other agent that learned
    (reproduced), some other's above its own (contradicted)."""
    claim = f"{algo} survives longest on {level}"
    rule = "its 95 % interval above every other agent's that learned; contradicted where one's lies above its own"
    s = survival[survival["level"] == level].set_index("algo") if len(survival) else survival
    if algo not in s.index:
        return missing(claim, f"no compute-matched run of {algo}")
    if algo not in _learned(gate):
        return _not_learned(claim, [algo], gate)
    others = [a for a in _learned(gate) if a != algo and a in s.index]
    if not others:
        return missing(claim, "no other agent learned the level")
    up = [a for a in others if above(s.loc[algo], s.loc[a])]
    down = [a for a in others if above(s.loc[a], s.loc[algo])]
    evidence = [
        "; ".join(f"{a}: {_fmt(s.loc[a])}" for a in [algo, *others]),
        f"above {len(up)} of {len(others)} ({', '.join(up) or 'none'}), below {len(down)} ({', '.join(down) or 'none'})",
    ]
    verdict = CONTRADICTED if down else REPRODUCED if len(up) == len(others) else UNRESOLVED
    return _gate(Verdict(claim, verdict, rule, evidence), s.loc[[algo, *others]].reset_index())


def learns_fastest(algo: str, reach: pd.DataFrame, gate: pd.DataFrame, level: str) -> Verdict:
    """``algo`` learns ``level`` fastest: the env steps at which each seed's in-training evaluations (validation
    worlds) first reached the learning threshold; reproduced when every seed of ``algo`` got there before any seed
    of every other agent that learned, contradicted when every seed of another got there before any of its own
    (a seed that never got there counts as later than any that did)."""
    claim = f"{algo} learns {level} fastest"
    rule = (
        "env steps at which a seed's in-training evaluation (validation worlds, IQM) first reached the threshold: "
        "every seed of it before every seed of each other agent that learned (reproduced), or every seed of "
        "another before every seed of it (contradicted)"
    )
    if not len(reach) or algo not in set(reach["algo"]):
        return missing(claim, f"no compute-matched run of {algo}")
    if algo not in _learned(gate):
        return _not_learned(claim, [algo], gate)
    others = [a for a in _learned(gate) if a != algo and a in set(reach["algo"])]
    if not others:
        return missing(claim, "no other agent learned the level")
    steps = {
        a: sorted(float(r.steps) if r.reached else math.inf for r in reach[reach["algo"] == a].itertuples(index=False))
        for a in [algo, *others]
    }

    def said(values: list[float]) -> str:
        return ", ".join(f"{v:,.0f}" if math.isfinite(v) else "never" for v in values)

    evidence = ["; ".join(f"{a}: {said(v)}" for a, v in steps.items())]
    first = [a for a in others if steps[algo][-1] < steps[a][0]]
    later = [a for a in others if steps[a][-1] < steps[algo][0]]
    evidence.append(
        f"every seed before every seed of {len(first)} of {len(others)} ({', '.join(first) or 'none'}); "
        f"after every seed of {len(later)} ({', '.join(later) or 'none'})"
    )
    verdict = CONTRADICTED if later else REPRODUCED if len(first) == len(others) else UNRESOLVED
    fewest = min(len(v) for v in steps.values())
    if fewest < MIN_SEEDS:
        verdict = few_seeds(fewest)
        evidence.append(f"fewer than {MIN_SEEDS} seeds ({fewest}): no verdict")
    return Verdict(claim, verdict, rule, evidence)


def matched_ordering(
    survival: pd.DataFrame, random: pd.DataFrame, gate: pd.DataFrame, reach: pd.DataFrame, level: str, budget: str
) -> Verdict:
    """(c) where the paper states it for ``level``, at equal compute (``budget``, e.g. 110 CPU-min): DreamerV3
    survives longest, DQN above PPO, DQN learns the level fastest, PPO+LSTM fails.  ``survival``: the compute-
    matched runs' final networks per algo (columns algo, level, value, low, high, n, unit, acting); ``random``: the
    random agent's survival per level; ``gate``: :func:`..reports.matched.learned_gate`; ``reach``:
    :func:`..reports.matched.reaching`.  Only agents that learned the level are compared; "fails" needs no gate."""
    claim = f"(c) at equal compute on {level} ({budget}): DreamerV3 survives longest, DQN > PPO, DQN learns fastest, PPO+LSTM fails"
    algos = set(survival["algo"]) if len(survival) else set()
    dreamer = next((a for a in ("dreamer", "dreamer_xs") if a in algos), "dreamer_xs")
    learned = _learned(gate)
    short = [a for a in ("dqn", "ppo") if a in algos and a not in learned]
    parts = [
        survives_longest(dreamer, survival, gate, level),
        _not_learned("dqn > ppo in survival", short, gate)
        if short
        else _ordered("dqn", "ppo", survival[survival["level"] == level] if len(survival) else survival, [level]),
        learns_fastest("dqn", reach, gate, level),
        _fails("ppo_lstm", [level], survival, random),
    ]
    return combine(claim, parts, "each part by its rule; agents that did not learn are compared with nothing")


# ------------------------------------------------------------------------------------------------ (d)
def drops(per_seed: pd.DataFrame, order: Sequence[str], alpha: float = 0.05) -> tuple[list, list[str]]:
    """The resolved drops of one agent's testbed success between training levels: for every pair of levels i before
    j, a one-sided paired t-test over seeds (``scipy.stats.ttest_1samp`` of each seed's success at i minus at j,
    alternative "greater"), Holm-corrected over all pairs (family-wise error ``alpha``).  ``per_seed``: columns
    level, seed, value (each seed's mean testbed success).  Returns the rejected pairs and a line per pair tested."""
    levels = [lv for lv in order if lv in set(per_seed["level"])]
    wide = per_seed.pivot_table(index="seed", columns="level", values="value", aggfunc="mean")
    pairs, pvalues, lines = [], [], []
    for i, a in enumerate(levels):
        for b in levels[i + 1 :]:
            d = (wide[a] - wide[b]).dropna().to_numpy()
            if len(d) < MIN_SEEDS:
                continue
            if np.allclose(d, d[0]):  # every seed the same difference: no spread to test against
                p = 0.0 if d[0] > 0 else 1.0
            else:
                p = float(sps.ttest_1samp(d, 0.0, alternative="greater").pvalue)
            pairs.append((a, b))
            pvalues.append(p)
    rejected = holm(pvalues, alpha)
    for (a, b), p, r in zip(pairs, pvalues, rejected):
        lines.append(f"{a}→{b}: p = {p:.3g}{' (rejected)' if r else ''}")
    return [pair for pair, r in zip(pairs, rejected) if r], lines


def testbeds_below_ceiling(
    success: pd.DataFrame,
    references: pd.DataFrame,
    generalisation: pd.DataFrame,
    order: Sequence[str],
    per_seed: pd.DataFrame | None = None,
) -> Verdict:
    """(d) On the testbeds humans are near the ceiling, agents far below, and more training difficulty does not give
    monotonic gains.  ``success``: agents' testbed success (agent, level, value, low, high, n, unit);
    ``references``: the same for oracle, random and human (column agent); ``generalisation``: per agent the mean
    testbed success by the level trained up to (agent, level, value, low, high, n, unit); ``per_seed``: the same
    per seed (agent, level, seed, value), for the paired tests of :func:`drops`."""
    claim = "(d) testbeds: humans ≈ ceiling, agents far below; no monotonic gain with training difficulty"
    refs = {a: p.set_index("level") for a, p in references.groupby("agent")} if len(references) else {}
    parts = []
    oracle = refs.get("oracle")
    if "human" in refs and oracle is not None:
        human = refs["human"]
        tb = [lv for lv in human.index if lv in oracle.index]
        below = [lv for lv in tb if above(oracle.loc[lv], human.loc[lv])]
        parts.append(
            Verdict(
                "humans ≈ ceiling (the oracle)",
                REPRODUCED if tb and not below else CONTRADICTED if tb and 2 * len(below) > len(tb) else UNRESOLVED,
                "humans' 95 % interval not below the oracle's on any testbed",
                [f"humans below the oracle on {len(below)} of {len(tb)} testbeds"],
            )
        )
    else:
        parts.append(missing("humans ≈ ceiling", "no human play records (scripts/play.py) among the evaluations"))
    if oracle is None or not len(success):
        parts.append(missing("agents far below the ceiling", "no oracle or no agent evaluated on the testbeds"))
    else:
        for agent, part in success.groupby("agent", sort=False):
            p = part.set_index("level")
            tb = [lv for lv in p.index if lv in oracle.index]
            below = [lv for lv in tb if above(oracle.loc[lv], p.loc[lv])]
            near = [lv for lv in tb if p.loc[lv]["value"] >= oracle.loc[lv]["low"]]
            verdict = (
                REPRODUCED
                if tb and 2 * len(below) >= len(tb)
                else CONTRADICTED
                if tb and 2 * len(near) > len(tb)
                else UNRESOLVED
            )
            parts.append(
                _gate(
                    Verdict(
                        f"{agent} far below the oracle",
                        verdict,
                        "below: its 95 % interval under the oracle's; reproduced when below on at "
                        "least half of the testbeds, contradicted when its rate reaches the oracle's "
                        "lower bound on most",
                        [f"below on {len(below)} of {len(tb)} testbeds; at the oracle's level on {len(near)}"],
                    ),
                    part,
                )
            )
    if not len(generalisation):
        parts.append(missing("no monotonic gain", "no checkpoint of several training levels evaluated on testbeds"))
    else:
        for agent, part in generalisation.groupby("agent", sort=False):
            part = _sorted(part, order).reset_index(drop=True)
            if len(part) < 3:
                parts.append(missing(f"{agent}: no monotonic gain", "fewer than 3 training levels"))
                continue
            mine = per_seed[per_seed["agent"] == agent] if per_seed is not None and len(per_seed) else None
            found, tested = drops(mine, order) if mine is not None and len(mine) else ([], [])
            rises = all(part.loc[i + 1, "value"] >= part.loc[i, "value"] for i in range(len(part) - 1)) and above(
                part.iloc[-1], part.iloc[0]
            )
            evidence = [
                "; ".join(f"{r.level}: {_fmt(r._asdict())}" for r in part.itertuples()),
                f"resolved drops (one-sided paired t-tests over seeds, Holm-corrected over the {len(tested)} "
                f"pairs of levels): {', '.join(f'{a}→{b}' for a, b in found) or 'none'}",
            ]
            verdict = REPRODUCED if found else CONTRADICTED if rises else UNRESOLVED
            parts.append(
                _gate(
                    Verdict(
                        f"{agent}: no monotonic gain with training level",
                        verdict,
                        "reproduced by a resolved drop (a later level below an earlier one, Holm-"
                        "corrected over every pair of levels); contradicted by a rise at every step "
                        "whose last level's interval lies above the first's",
                        evidence,
                    ),
                    part,
                )
            )
    return combine(claim, parts, "each part by its rule")


# ------------------------------------------------------------------------------------------------ (e)
def ablations(survival: pd.DataFrame, success: pd.DataFrame) -> Verdict:
    """(e) No-EV (no_interoception) and no-vision ablations fail; olfaction matters least, thermoception and
    collision more.  ``survival`` / ``success``: per modality (column modality) the final survival and the success
    pooled over the testbeds (value, low, high), of one algorithm and training set-up."""
    claim = "(e) no-EV and no-vision fail; olfaction matters least, thermoception and collision more"
    parts = []
    for name, table in (("survival", survival), ("testbed success", success)):
        t = table.set_index("modality") if len(table) else table
        if not len(t) or "all" not in t.index:
            parts.append(missing(f"ablations ({name})", "no ablation runs beside modality=all"))
            continue
        base = t.loc["all"]
        for mod in ("no_interoception", "no_vision"):
            if mod not in t.index:
                parts.append(missing(f"{mod} fails ({name})", f"no {mod} run"))
                continue
            v = REPRODUCED if above(base, t.loc[mod]) else CONTRADICTED if above(t.loc[mod], base) else UNRESOLVED
            parts.append(
                _gate(
                    Verdict(
                        f"{mod} fails ({name})",
                        v,
                        "its 95 % interval below all's (contradicted: above)",
                        [f"{mod} {_fmt(t.loc[mod])} vs all {_fmt(base)}"],
                    ),
                    t.loc[mod],
                    base,
                )
            )
        need = ("no_olfaction", "no_thermoception", "no_collision")
        if not all(m in t.index for m in need):
            parts.append(
                missing(f"olfaction matters least ({name})", "no_olfaction, no_thermoception and no_collision runs")
            )
            continue
        olf = t.loc["no_olfaction"]
        others = {m: t.loc[m] for m in need[1:]}
        v = (
            REPRODUCED
            if all(above(olf, o) for o in others.values())
            else CONTRADICTED
            if any(above(o, olf) for o in others.values())
            else UNRESOLVED
        )
        parts.append(
            _gate(
                Verdict(
                    f"olfaction matters least ({name})",
                    v,
                    "no_olfaction's 95 % interval above no_thermoception's and no_collision's "
                    "(contradicted: below either)",
                    [f"no_olfaction {_fmt(olf)}; " + "; ".join(f"{m} {_fmt(o)}" for m, o in others.items())],
                ),
                olf,
                *others.values(),
            )
        )
    return combine(claim, parts, "each part by its rule")


def glance(verdicts: Sequence[Verdict]) -> list[str]:
    """The claims as one Markdown table: a row per claim with its verdict and each part's (no rules, no numbers)."""

    def cell(text: str) -> str:
        return text.replace("|", "\\|")

    lines = ["| claim | verdict | its parts |", "|---|---|---|"]
    for v in verdicts:
        parts = "; ".join(f"{p.claim}: *{p.verdict}*" for p in v.parts) or "–"
        lines.append(f"| {cell(v.claim)} | **{v.verdict}** | {cell(parts)} |")
    return lines


def markdown(verdicts: Sequence[Verdict]) -> list[str]:
    """The claims as Markdown: a line per claim with its verdict, then its parts with rules and numbers."""
    lines = []
    for v in verdicts:
        lines.append(f"- **{v.claim}: {v.verdict}.**" + (f" Rule: {v.rule}." if not v.parts else ""))
        lines += [f"  - {e}" for e in v.evidence]
        for p in v.parts:
            lines.append(f"  - {p.claim}: *{p.verdict}* (rule: {p.rule})")
            lines += [f"    - {e}" for e in p.evidence]
    return lines
