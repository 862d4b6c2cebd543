"""The paper's claims (a)–(e) of issue 20 judged against a report's numbers: each claim's rule, applied to tables of
estimates with 95 % intervals (``value``, ``low``, ``high``; ``samples``, each seed's episodes, where the report has
them), gives a :class:`Verdict` — reproduced, contradicted, or not resolvable at this scale — with the numbers
behind it.  The rules decide both ways (issue 62); their margins are settings (:class:`Rules`, a protocol's
``report.verdicts``):

* **A beats B** (survival; testbed success the same on rates): the ratio of their IQMs with its 95 % interval (independent two-stage bootstraps of
  each, :func:`..reports.stats.ratio_interval`; hand-made tables without episodes: the bounds
  ``[low_A / high_B, high_A / low_B]``).  Reproduced when the interval lies above ``1 + margin``; contradicted
  when it lies at or under ``1 + margin`` — A is no more than the margin better: equal within the margin, or
  worse (the ratio inside [0.9, 1.1] contradicts "curriculum beats direct"); otherwise not resolvable.
* **Censoring**: a cell with more than a quarter of its episodes at the step cap has an IQM that is a lower bound.
  A ratio whose numerator is capped is a lower bound (it can reproduce "A beats B", never contradict it); one whose
  denominator is capped an upper bound (it can contradict, never reproduce).
* **Fails** — one definition for every claim: an agent fails a level when it did not learn it by the gate: its
  survival interval not above ``fails_factor`` (the report's ``learned``, else 2) × the better of random and
  stand-still on that level (IQM).  Contradicted ("it learned") when the interval lies above that bar.
* **The gate does not hide what the data decide**: an agent that did not learn is still compared; a part left
  undecided says which of its agents did not learn.
* **(d) no monotonic gain**: the gain of mean testbed success along the least-squares line from the first training
  level to the last (:mod:`..reports.trend`), its 95 % interval from a two-stage bootstrap that redraws a
  curriculum's seeds together across its levels: at or under ``+gain_margin`` (no gain beyond the margin: flat
  within it, or falling) reproduces, above it contradicts; a drop between consecutive levels (one-sided
  two-proportion tests on the effective episodes, Holm-corrected over the steps) reproduces too (the gain is not
  monotonic).  The report states the power of both at the protocol's seeds and episodes.
* **A claim of parts** is reproduced when every part is, contradicted when any part is (a claim that states
  several things is false when one of them is), otherwise not resolvable.

A part whose agent cells have fewer than three seeds has no intervals and is not decided: its verdict is "not
resolvable: 2 seeds", with the numbers (each seed's value).  Two agents that acted differently (greedy against
sampled actions) are not compared — except where a report compares sampled actions and an agent without an action
distribution (DQN) takes part with its greedy action, labelled so (:data:`..reports.load.GREEDY_STAND_IN`).  A part
without data (DreamerV3, human records) is said to be missing and counts as not resolvable.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import stats as sps

from ..reports import trend
from ..reports.load import GREEDY_STAND_IN, same_acting
from ..reports.stats import MIN_SEEDS, TooFewSeeds, design_effect, detectable_drop, drop_pvalue, holm, ratio_interval
from ..reports.tables import capped

REPRODUCED, CONTRADICTED, UNRESOLVED = "reproduced", "contradicted", "not resolvable at this scale"


@dataclass(frozen=True)
class Rules:
    """The settings of the verdict rules (a protocol's ``report.verdicts``, scripts/report.py's arguments of the same
    names), fixed before a protocol's runs."""

    #: survival: "A beats B" needs the ratio's interval above 1 + margin; at or under 1 + margin contradicts it
    margin: float = 0.1
    #: fails: survival interval not above this × the better of random and stand-still (the report's learned gate)
    fails_factor: float = 2.0
    #: (d) "no monotonic gain": the gain of mean testbed success (a share, 0.1 = 10 points) from the first training
    #: level to the last whose 95 % interval lies at or under +gain_margin reproduces; above it contradicts
    gain_margin: float = 0.1
    #: the family-wise error of (d)'s drop tests and the power the report states for them
    alpha: float = 0.05
    power: float = 0.8


DEFAULT_RULES = Rules()


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
    return f"{x:,.0f}" if abs(x) >= 100 else f"{x:.3g}"  # survival in whole decisions, rates to 3 digits


def _fmt(row) -> str:
    v, lo, hi = float(row["value"]), float(row["low"]), float(row["high"])
    if math.isnan(v):
        return "n/a"
    bound = "≥ " if capped(row) else ""
    if math.isnan(lo):
        points = row.get("points", ()) if hasattr(row, "get") else ()
        if isinstance(points, tuple) and len(points) > 1:
            return f"{bound}{_num(v)} (seeds {', '.join(_num(p) for p in points)})"
        return bound + _num(v)
    text = f"{bound}{_num(v)} [{_num(lo)}, {_num(hi)}]"
    if bound:
        text += f" ({100 * float(row['at_cap']):.0f} % at the step cap)"
    return text


def above(a, b) -> bool:
    """``a``'s interval lies entirely above ``b``'s (no overlap)."""
    return not (math.isnan(a["low"]) or math.isnan(b["high"])) and a["low"] > b["high"]


def _samples(row) -> list | None:
    s = row.get("samples") if hasattr(row, "get") else None
    return list(s) if isinstance(s, tuple) and len(s) >= MIN_SEEDS else None


def ratio(a, b) -> tuple[float, float, float, str]:
    """``a``'s value over ``b``'s (survival: IQM; success: rate) with its 95 % interval, and how the interval was
    made: from each cell's episodes (``samples``) by independent bootstraps, else the bounds of the cells'
    intervals ``[low_a / high_b, high_a / low_b]`` (infinite where ``low_b`` is 0)."""
    sa, sb = _samples(a), _samples(b)
    statistic = "mean" if (a.get("statistic") if hasattr(a, "get") else None) == "rate" else "iqm"
    if sa is not None and sb is not None:
        try:
            est = ratio_interval(sa, sb, statistic)
            return est.value, est.low, est.high, "bootstrap"
        except TooFewSeeds:
            pass
    v = float(a["value"]) / float(b["value"]) if float(b["value"]) else math.inf
    if any(math.isnan(float(x)) for x in (a["low"], a["high"], b["low"], b["high"])) or float(b["high"]) <= 0:
        return v, math.nan, math.nan, "none"
    hi = float(a["high"]) / float(b["low"]) if float(b["low"]) > 0 else math.inf
    return v, float(a["low"]) / float(b["high"]), hi, "bounds"


#: outcomes of a comparison of two cells
ABOVE, NOT_ABOVE = "above", "not above"


def beats(a, b, margin: float, names: tuple[str, str]) -> tuple[str | None, str]:
    """Whether ``a`` survives longer (or succeeds more often) than ``b`` by more than ``margin`` (:data:`ABOVE`: the ratio's 95 % interval
    above 1 + margin), not (:data:`NOT_ABOVE`: at or under 1 + margin: equal within the margin, or worse), or
    undecided (None), with a line of evidence.  Censoring: a capped ``a`` cannot give NOT_ABOVE, a capped ``b``
    cannot give ABOVE."""
    r, lo, hi, how = ratio(a, b)
    na, nb = names
    line = f"{na} / {nb} = {r:.2f}" + ("" if math.isnan(lo) else f" [{lo:.2f}, {hi:.2f}]")
    if math.isnan(lo):
        return None, line + " (no interval)"
    if how == "bounds":
        line += " (bounds of the cells' intervals)"
    if lo > 1 + margin:
        if capped(b):
            return None, line + f"; {nb} at the step cap: its IQM is a lower bound, so the ratio an upper one"
        return ABOVE, line + f" > {1 + margin:g}"
    if hi <= 1 + margin:
        if capped(a):
            return None, line + f"; {na} at the step cap: its IQM is a lower bound, so the ratio a lower one"
        return NOT_ABOVE, line + f" ≤ {1 + margin:g}" + (" (equal within the margin)" if lo >= 1 - margin else "")
    return None, line + f" straddles {1 + margin:g}"


def fails(row, bar: float) -> tuple[str | None, str]:
    """The one definition of "fails": the agent did not learn by the gate — its survival interval not above
    ``bar`` (``fails_factor`` × the better of random and stand-still).  Returns ("fails" | "learned" | None,
    evidence); None without an interval, or where a capped cell's interval does not clear the bar."""
    if math.isnan(float(row["low"])) or math.isnan(bar):
        return None, f"{_fmt(row)} vs the bar {_num(bar)}: no interval"
    if float(row["low"]) > bar:
        return "learned", f"{_fmt(row)}: interval above the bar {_num(bar)} (learned)"
    if capped(row):
        return None, f"{_fmt(row)}: capped, its interval a lower bound under the bar {_num(bar)}"
    return "fails", f"{_fmt(row)}: interval not above the bar {_num(bar)} (did not learn)"


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
    """A claim made of ``parts``: reproduced when every part is, contradicted when any part is (the claim states
    each of them), otherwise not resolvable."""
    verdicts = [p.verdict for p in parts]
    if verdicts and all(v == REPRODUCED for v in verdicts):
        verdict = REPRODUCED
    elif CONTRADICTED in verdicts:
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


#: what a part left undecided says of an agent that did not learn
NOT_LEARNED = "not resolvable: did not learn at this budget"


def _explain(verdict: Verdict, who: Sequence[str], gate: pd.DataFrame | None) -> Verdict:
    """An undecided ``verdict`` says which of ``who`` did not learn by the gate (a decided one stays as it is: the
    gate hides nothing the data decide)."""
    if gate is None or not len(gate) or not unresolved(verdict.verdict) or verdict.verdict != UNRESOLVED:
        return verdict
    rows = gate.set_index("algo")
    short = [a for a in who if a in rows.index and not bool(rows.loc[a, "learned"])]
    if short:
        verdict.verdict = NOT_LEARNED
        verdict.evidence += [str(rows.loc[a, "reading"]) for a in short]
    return verdict


# ------------------------------------------------------------------------------------------------ (a)
def falls_beyond(a, b, margin: float, names: tuple[str, str]) -> tuple[str, str]:
    """Whether survival falls from ``b`` to ``a`` by more than ``margin``: the ratio ``a`` / ``b`` (:func:`ratio`),
    its 95 % interval under 1 − margin reproduces (a fall beyond the margin), at or above 1 − margin contradicts
    (no fall beyond it); otherwise not resolvable.  Censoring: a capped ``a`` makes the ratio a lower bound (it can
    contradict, not reproduce), a capped ``b`` an upper bound (it can reproduce, not contradict)."""
    r, lo, hi, how = ratio(a, b)
    line = f"{names[0]} / {names[1]} = {r:.2f}" + ("" if math.isnan(lo) else f" [{lo:.2f}, {hi:.2f}]")
    line += " (bounds of the cells' intervals)" if how == "bounds" else ""
    if math.isnan(lo):
        return UNRESOLVED, line + " (no interval)"
    if hi < 1 - margin and not capped(a):
        return REPRODUCED, line + f" < {1 - margin:g}"
    if lo >= 1 - margin and not capped(b):
        return CONTRADICTED, line + f" ≥ {1 - margin:g}"
    return UNRESOLVED, line + f" straddles {1 - margin:g}"


def survival_falls(
    survival: pd.DataFrame, order: Sequence[str], hard_from: str = HARD_FROM, rules: Rules = DEFAULT_RULES
) -> Verdict:
    """(a) Survival falls with level difficulty, sharply from 3-2 on.  ``survival``: columns algo, level, value,
    low, high (survival per training level; ``samples``, ``at_cap``).  Two parts per algorithm, each by
    :func:`falls_beyond` (a fall beyond the margin reproduces, none beyond it contradicts): *falls* — the hardest
    level's survival over the easiest's (the last and first of ``order`` it has; Spearman's rho of the levels'
    IQMs against their order, exact p, beside it as the shape); *drops at ``hard_from``* — ``hard_from``'s survival
    over the level's before it."""
    claim = f"(a) survival falls with level difficulty, sharply from {hard_from} on"
    low = f"{1 - rules.margin:g}"
    if not len(survival):
        return missing(claim, "no survival per training level")
    cut = list(order).index(hard_from)
    before = order[cut - 1]
    rule_drop = (
        f"{hard_from} / {before} survival ratio, 95 % interval: under {low} (a drop beyond the margin) reproduces, "
        f"at or above {low} contradicts"
    )
    parts = []
    for algo, part in survival.groupby("algo", sort=False):
        part = _sorted(part.dropna(subset=["value"]), order)
        levels = "; ".join(f"{r.level}: {_fmt(r._asdict())}" for r in part.itertuples())
        if len(part) < 3:
            parts.append(
                _gate(Verdict(f"{algo}: falls with level", UNRESOLVED, "no rule: fewer than 3 levels", [levels]), part)
            )
        else:
            first, last = part.iloc[0], part.iloc[-1]
            rule_falls = (
                f"survival ratio of the hardest level to the easiest ({last['level']} / {first['level']}), 95 % "
                f"interval: under {low} (a fall beyond the margin) reproduces, at or above {low} contradicts"
            )
            verdict, line = falls_beyond(last, first, rules.margin, (str(last["level"]), str(first["level"])))
            rank = part["level"].map({n: i for i, n in enumerate(order)})
            rho, p = spearman(rank, part["value"]) if part["value"].nunique() > 1 else (0.0, 1.0)
            shape = f"the shape: Spearman's rho {rho:.2f} (exact p = {p:.3g}, {len(part)} levels)"
            parts.append(
                _gate(Verdict(f"{algo}: falls with level", verdict, rule_falls, [levels, line, shape]), first, last)
            )
        cells = part.set_index("level")
        if hard_from in cells.index and before in cells.index:
            a, b = cells.loc[hard_from], cells.loc[before]
            verdict, line = falls_beyond(a, b, rules.margin, (hard_from, before))
            evidence = [f"{hard_from}: {_fmt(a)}; {before}: {_fmt(b)}", line]
            parts.append(_gate(Verdict(f"{algo}: drops at {hard_from}", verdict, rule_drop, evidence), a, b))
        else:
            parts.append(missing(f"{algo}: drops at {hard_from}", f"no survival on {before} and {hard_from}"))
    return combine(claim, parts, "each part by its rule")


# ------------------------------------------------------------------------------------------------ (b)
def curriculum_beats_direct(
    cmp: pd.DataFrame, order: Sequence[str], skip: Sequence[str] = ("1-1",), rules: Rules = DEFAULT_RULES
) -> Verdict:
    """(b) Curriculum beats direct training.  ``cmp``: columns algo, setup (curriculum or direct), level, value,
    low, high (and ``samples``).  Per algorithm, over the levels both have (``skip``: the first level, where both
    are the same training), each level's ratio curriculum / direct (:func:`beats`): reproduced when the curriculum
    beats direct by more than the margin on at least half of them and is not above on none; contradicted when it
    is not above (equal within the margin, or below) on at least half and above on none; otherwise not
    resolvable."""
    claim = "(b) curriculum beats direct training"
    rule = (
        f"per algorithm, levels after the first: curriculum / direct survival ratio, 95 % interval above "
        f"{1 + rules.margin:g} (beats) or at or under it (equal within the margin, or worse); reproduced when it "
        "beats on at least half of the levels and fails to on none, contradicted the other way round"
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
        up, down, lines = [], [], []
        for lv in levels:
            outcome, line = beats(cur.loc[lv], dire.loc[lv], rules.margin, ("curriculum", "direct"))
            lines.append(f"{lv}: curriculum {_fmt(cur.loc[lv])} vs direct {_fmt(dire.loc[lv])}; {line}")
            (up if outcome == ABOVE else down if outcome == NOT_ABOVE else []).append(lv)
        evidence = [
            *lines,
            f"curriculum beats direct on {len(up)} of {len(levels)} levels ({', '.join(up) or 'none'}), does not "
            f"on {len(down)} ({', '.join(down) or 'none'})",
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
def _ordered(
    a: str, b: str, survival: pd.DataFrame, order: Sequence[str], rules: Rules = DEFAULT_RULES, gate=None
) -> Verdict:
    """``a`` survives longer than ``b``: per level the ratio a / b (:func:`beats`); reproduced when a beats b on at
    least half of the levels both have and fails to on none (and the reverse for contradicted)."""
    rule = (
        f"per level, survival ratio {a} / {b}: 95 % interval above {1 + rules.margin:g} (longer) or at or under it "
        "(not longer); reproduced when longer on at least half of the levels and not longer on none, contradicted "
        "the other way round"
    )
    sa, sb = (survival[survival["algo"] == x].set_index("level") for x in (a, b))
    if not len(sa) or not len(sb):
        return missing(f"{a} > {b}", f"no survival of {a if not len(sa) else b}")
    levels = [lv for lv in order if lv in sa.index and lv in sb.index]
    up, down, lines = [], [], []
    for lv in levels:
        outcome, line = beats(sa.loc[lv], sb.loc[lv], rules.margin, (a, b))
        lines.append(f"{lv}: {a} {_fmt(sa.loc[lv])} vs {b} {_fmt(sb.loc[lv])}; {line}")
        (up if outcome == ABOVE else down if outcome == NOT_ABOVE else []).append(lv)
    evidence = [
        *lines,
        f"{a} longer on {len(up)} of {len(levels)} levels ({', '.join(up) or 'none'}), not longer on "
        f"{len(down)} ({', '.join(down) or 'none'})",
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
    out = _gate(Verdict(f"{a} > {b} in survival", verdict, rule, evidence), sa.loc[levels], sb.loc[levels])
    return _explain(out, [a, b], gate)


def _fails(algo: str, levels: Sequence[str], survival: pd.DataFrame, bars: Mapping[str, float]) -> Verdict:
    """``algo`` fails on ``levels``: :func:`fails` on each; reproduced when it fails on every level, contradicted
    when it learned on most of them."""
    name = f"{algo} fails"
    rule = (
        "fails on a level: did not learn it by the gate — its survival's 95 % interval not above the bar (the "
        "learned factor × the better of random and stand-still there); reproduced when it fails on every level, "
        "contradicted when its interval is above the bar on most of them"
    )
    s = survival[survival["algo"] == algo].set_index("level")
    if not len(s):
        return missing(name, f"no survival of {algo}")
    checked = [lv for lv in levels if lv in s.index and lv in bars]
    if not checked:
        return missing(name, "no reference survival (random, stand-still) on those levels")
    outcomes = {lv: fails(s.loc[lv], bars[lv]) for lv in checked}
    failed = [lv for lv, (o, _) in outcomes.items() if o == "fails"]
    learned = [lv for lv, (o, _) in outcomes.items() if o == "learned"]
    evidence = [f"{lv}: {line}" for lv, (_, line) in outcomes.items()]
    evidence.append(f"fails on {len(failed)} of {len(checked)} ({', '.join(failed) or 'none'})")
    verdict = (
        REPRODUCED if len(failed) == len(checked) else CONTRADICTED if 2 * len(learned) > len(checked) else UNRESOLVED
    )
    return _gate(Verdict(name, verdict, rule, evidence), s.loc[checked])


def algorithm_ordering(
    survival: pd.DataFrame, bars: Mapping[str, float], order: Sequence[str], rules: Rules = DEFAULT_RULES
) -> Verdict:
    """(c) DreamerV3 > DQN > PPO in survival; DQN fails beyond 1-2; PPO+LSTM fails.  ``survival``: columns algo,
    level, value, low, high; ``bars``: per level the bar of "fails" (:func:`fails`).  DQN's speed on 1-1 (learning
    curves) is not judged by a rule here."""
    claim = "(c) DreamerV3 > DQN > PPO in survival; DQN fails beyond 1-2; PPO+LSTM fails"
    algos = set(survival["algo"]) if len(survival) else set()
    dreamer = next((a for a in ("dreamer", "dreamer_xs") if a in algos), None)
    late = [lv for lv in order if list(order).index(lv) > 1]
    dqn_late = _fails("dqn", late, survival, bars)
    dqn_early = _fails("dqn", list(order[:2]), survival, bars)
    if dqn_late.verdict == REPRODUCED and dqn_early.verdict != CONTRADICTED:  # fails beyond 1-2 but not before
        dqn_late.verdict = UNRESOLVED if dqn_early.verdict == UNRESOLVED else CONTRADICTED
        dqn_late.evidence.append(f"on {' and '.join(order[:2])}: {dqn_early.evidence[-1]}")
    dqn_late.claim = f"dqn fails beyond {order[1]}"
    parts = [
        _ordered(dreamer, "dqn", survival, order, rules)
        if dreamer
        else missing("DreamerV3 > DQN", "no DreamerV3 runs"),
        _ordered("dqn", "ppo", survival, order, rules),
        dqn_late,
        _fails("ppo_lstm", list(order), survival, bars),
    ]
    return combine(claim, parts, "each part by its rule")


def _learned(gate: pd.DataFrame) -> list[str]:
    return list(gate.loc[gate["learned"], "algo"]) if len(gate) else []


def survives_longest(
    algo: str, survival: pd.DataFrame, gate: pd.DataFrame, level: str, rules: Rules = DEFAULT_RULES
) -> Verdict:
    """``algo`` survives longest on ``level`` at equal compute: longer (:func:`beats`) than every other agent
    (reproduced); not longer than some other (contradicted).  Every agent is compared, learned or not."""
    claim = f"{algo} survives longest on {level}"
    rule = (
        f"survival ratio {algo} / each other agent, 95 % interval: above {1 + rules.margin:g} for every other "
        f"agent reproduces, at or under {1 + rules.margin:g} for some other contradicts"
    )
    s = survival[survival["level"] == level].set_index("algo") if len(survival) else survival
    if algo not in s.index:
        return missing(claim, f"no compute-matched run of {algo}")
    others = [a for a in s.index if a != algo]
    if not others:
        return missing(claim, "no other agent on the level")
    up, down, lines = [], [], [f"{a}: {_fmt(s.loc[a])}" for a in [algo, *others]]
    for a in others:
        outcome, line = beats(s.loc[algo], s.loc[a], rules.margin, (algo, a))
        lines.append(line)
        (up if outcome == ABOVE else down if outcome == NOT_ABOVE else []).append(a)
    evidence = [
        "; ".join(lines[: len(others) + 1]),
        *lines[len(others) + 1 :],
        f"longer than {len(up)} of {len(others)} ({', '.join(up) or 'none'}), not longer than {len(down)} "
        f"({', '.join(down) or 'none'})",
    ]
    verdict = CONTRADICTED if down else REPRODUCED if len(up) == len(others) else UNRESOLVED
    out = _gate(Verdict(claim, verdict, rule, evidence), s.loc[[algo, *others]].reset_index())
    return _explain(out, [algo, *others], gate)


def learns_fastest(algo: str, reach: pd.DataFrame, gate: pd.DataFrame, level: str) -> Verdict:
    """``algo`` learns ``level`` fastest: the env steps at which each seed's in-training evaluations (validation
    worlds) first reached the learning threshold; reproduced when every seed of ``algo`` got there before any seed
    of every other agent, contradicted when every seed of another got there before any of its own (a seed that
    never got there counts as later than any that did; two agents none of whose seeds got there are not ordered).
    Every agent is compared, learned or not."""
    claim = f"{algo} learns {level} fastest"
    rule = (
        "env steps at which a seed's in-training evaluation (validation worlds, IQM) first reached the bar: "
        "every seed of it before every seed of each other agent (reproduced), or every seed of another before "
        "every seed of it (contradicted); a seed that never did is later than any that did"
    )
    if not len(reach) or algo not in set(reach["algo"]):
        return missing(claim, f"no compute-matched run of {algo}")
    others = [a for a in dict.fromkeys(reach["algo"]) if a != algo]
    if not others:
        return missing(claim, "no other agent on the level")
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
    return _explain(Verdict(claim, verdict, rule, evidence), [algo, *others], gate)


def matched_ordering(
    survival: pd.DataFrame,
    bar: float,
    gate: pd.DataFrame,
    reach: pd.DataFrame,
    level: str,
    budget: str,
    rules: Rules = DEFAULT_RULES,
) -> Verdict:
    """(c) where the paper states it for ``level``, at equal compute (``budget``, e.g. 110 CPU-min): DreamerV3
    survives longest, DQN above PPO, DQN learns the level fastest, PPO+LSTM fails.  ``survival``: the compute-
    matched runs' final networks per algo (columns algo, level, value, low, high, n, unit, acting, samples,
    at_cap); ``bar``: the bar of "fails" on ``level`` (:func:`fails`); ``gate``:
    :func:`..reports.matched.learned_gate` (it explains undecided parts, it decides none); ``reach``:
    :func:`..reports.matched.reaching`."""
    claim = f"(c) at equal compute on {level} ({budget}): DreamerV3 survives longest, DQN > PPO, DQN learns fastest, PPO+LSTM fails"
    algos = set(survival["algo"]) if len(survival) else set()
    dreamer = next((a for a in ("dreamer", "dreamer_xs") if a in algos), "dreamer_xs")
    on_level = survival[survival["level"] == level] if len(survival) else survival
    parts = [
        survives_longest(dreamer, survival, gate, level, rules),
        _ordered("dqn", "ppo", on_level, [level], rules, gate),
        learns_fastest("dqn", reach, gate, level),
        _fails("ppo_lstm", [level], survival, {level: bar}),
    ]
    return combine(claim, parts, "each part by its rule; the gate decides nothing, it explains undecided parts")


# ------------------------------------------------------------------------------------------------ (d)
def _effective(row) -> float:
    """The effective number of episodes of a success cell: its episodes over the seeds' design effect (from its
    ``samples`` where it has them)."""
    samples = row.get("samples") if hasattr(row, "get") else None
    n = float(row["episodes"]) if "episodes" in row and not pd.isna(row["episodes"]) else math.nan
    if isinstance(samples, tuple) and len(samples) > 1:
        return n / design_effect(samples)
    return n


def drops(gen: pd.DataFrame, order: Sequence[str], rules: Rules = DEFAULT_RULES) -> tuple[list, list[str], float]:
    """The resolved drops of one agent's mean testbed success between consecutive training levels: for each step
    a one-sided two-proportion test (:func:`..reports.stats.drop_pvalue`) on the effective episodes
    (:func:`_effective`), Holm-corrected over the steps (family-wise error ``alpha``).  ``gen``: columns level,
    value, episodes (and ``samples``).  Returns the rejected steps, a line per step, and the smallest drop the
    first Holm step finds with ``power`` at the agent's mean rate and effective episodes."""
    part = _sorted(gen, order).reset_index(drop=True)
    steps, pvalues, lines = [], [], []
    for i in range(len(part) - 1):
        a, b = part.iloc[i], part.iloc[i + 1]
        n1, n2 = _effective(a), _effective(b)
        if math.isnan(n1) or math.isnan(n2) or seeds_short(a, b) is not None:
            continue
        steps.append((a["level"], b["level"]))
        pvalues.append(drop_pvalue(float(a["value"]), n1, float(b["value"]), n2))
    rejected = holm(pvalues, rules.alpha) if pvalues else np.zeros(0, dtype=bool)
    for (a, b), p, r in zip(steps, pvalues, rejected):
        lines.append(f"{a}→{b}: p = {p:.3g}{' (rejected)' if r else ''}")
    n_eff = float(np.nanmean([_effective(r) for _, r in part.iterrows()])) if len(part) else math.nan
    mdd = (
        detectable_drop(float(part["value"].mean()), n_eff, rules.alpha / max(len(steps), 1), rules.power)
        if steps and not math.isnan(n_eff)
        else math.nan
    )
    return [s for s, r in zip(steps, rejected) if r], lines, mdd


def testbeds_below_ceiling(
    success: pd.DataFrame,
    references: pd.DataFrame,
    generalisation: pd.DataFrame,
    order: Sequence[str],
    rules: Rules = DEFAULT_RULES,
) -> Verdict:
    """(d) On the testbeds humans are near the ceiling, agents far below, and more training difficulty does not give
    monotonic gains.  ``success``: agents' testbed success (agent, level, value, low, high, n, unit);
    ``references``: the same for oracle, random and human (column agent); ``generalisation``: per agent the mean
    testbed success by the level trained up to (agent, level, value, low, high, n, unit, episodes; ``samples``,
    ``units``: each seed's name, so that a curriculum's seeds are redrawn together across its levels).  "No
    monotonic gain": :func:`no_monotonic_gain`."""
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
            parts.append(_gate(no_monotonic_gain(agent, part, order, rules), part))
    return combine(claim, parts, "each part by its rule")


def level_gain(part: pd.DataFrame, order: Sequence[str]) -> trend.Gain:
    """The gain of ``part``'s rates (one agent's levels, in ``order``) along the least-squares line from its first
    level to its last (:func:`..reports.trend.gain`): from each level's episodes (``samples``; a curriculum's seeds
    paired across levels by ``units`` where the table has them), else from the cells' intervals."""
    positions = part["level"].map({n: i for i, n in enumerate(order)}).tolist()
    samples = [_samples(r) for _, r in part.iterrows()]
    if all(s is not None for s in samples):
        named = "units" in part and part["units"].map(lambda u: isinstance(u, tuple)).all()
        units = list(part["units"]) if named else None
        try:
            return trend.gain(samples, positions, units)
        except TooFewSeeds:
            pass
    return trend.gain_from_intervals(part["value"], part["low"], part["high"], positions)


def no_monotonic_gain(agent: str, part: pd.DataFrame, order: Sequence[str], rules: Rules = DEFAULT_RULES) -> Verdict:
    """(d)'s "no monotonic gain with training difficulty" for one agent's mean testbed success by training level
    (``part``: level, value, low, high, episodes; ``samples``, ``units``), by the gain along the least-squares line
    (:func:`level_gain`): its 95 % interval at or under ``+gain_margin`` reproduces (no gain beyond the margin),
    above it contradicts; a resolved drop between consecutive levels (:func:`drops`) reproduces too."""
    m = rules.gain_margin
    found, tested, mdd = drops(part, order, rules)
    g = level_gain(part, order)
    p_flat, smallest = trend.power(g.se, m, power=rules.power)
    first, last = part["level"].iloc[0], part["level"].iloc[-1]
    interval = "no interval" if math.isnan(g.low) else f"[{g.low:+.3f}, {g.high:+.3f}]"
    evidence = [
        "; ".join(f"{r.level}: {_fmt(r._asdict())}" for r in part.itertuples()),
        f"gain along the least-squares line from {first} to {last}: {g.value:+.3f} {interval} ({g.how}); margin +{m:g}",
        f"drops between consecutive levels (one-sided two-proportion tests on the effective episodes, Holm over the "
        f"{len(tested)} steps): {'; '.join(tested) or 'none tested'}; resolved: "
        f"{', '.join(f'{a}→{b}' for a, b in found) or 'none'}",
        (
            f"power at these seeds and episodes (the gain's standard error {g.se:.3f}): with no gain its interval lies "
            f"at or under +{m:g} with probability {100 * p_flat:.0f} % (reproduces); a gain of {smallest:.3f} or more "
            f"lies above it with {100 * rules.power:.0f} % (contradicts)"
            if not math.isnan(p_flat)
            else "power: the gain has no standard error here (no interval)"
        )
        + (
            f"; a drop of {mdd:.3f} between two consecutive levels is resolved with {100 * rules.power:.0f} % "
            f"(one-sided, alpha {rules.alpha:g} / {len(tested)})"
            if not math.isnan(mdd)
            else ""
        ),
    ]
    if found or (not math.isnan(g.high) and g.high <= m):
        verdict = REPRODUCED
    elif not math.isnan(g.low) and g.low > m:
        verdict = CONTRADICTED
    else:
        verdict = UNRESOLVED
    rule = (
        f"the gain of mean testbed success along the least-squares line from the first training level to the last, "
        f"95 % interval at or under +{m:g} (no gain beyond the margin) reproduces, above +{m:g} contradicts; a "
        "resolved drop between consecutive levels (one-sided two-proportion tests on the effective episodes, "
        "Holm-corrected over the steps) reproduces too"
    )
    return Verdict(f"{agent}: no monotonic gain with training level", verdict, rule, evidence)


# ------------------------------------------------------------------------------------------------ (e)
def ablations(
    survival: pd.DataFrame, success: pd.DataFrame, bar: float = math.nan, rules: Rules = DEFAULT_RULES
) -> Verdict:
    """(e) No-EV (no_interoception) and no-vision ablations fail; olfaction matters least, thermoception and
    collision more.  ``survival`` / ``success``: per modality (column modality) the final survival and the success
    pooled over the testbeds (value, low, high; ``samples``), of one algorithm and training set-up; ``bar``: the
    bar of "fails" on its level (:func:`fails`).  Survival: "fails" by the one definition; "olfaction matters
    least" by ratios (:func:`beats`).  Testbed success: every comparison by the ratio of rates (:func:`beats`): a
    rate near 0 gives a ratio interval too wide to decide, so a floor of failures decides nothing."""
    claim = "(e) no-EV and no-vision fail; olfaction matters least, thermoception and collision more"
    parts = []
    need = ("no_olfaction", "no_thermoception", "no_collision")
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
            if name == "survival":
                outcome, line = fails(t.loc[mod], bar)
                base_outcome, base_line = fails(base, bar)
                if base_outcome == "fails":
                    base_line += ": with every sense it did not learn either, so the failing is not shown to come from the missing sense"
                v = REPRODUCED if outcome == "fails" else CONTRADICTED if outcome == "learned" else UNRESOLVED
                parts.append(
                    _gate(
                        Verdict(
                            f"{mod} fails (survival)",
                            v,
                            "fails: did not learn by the gate — its survival's 95 % interval not above the bar "
                            "(the learned factor × the better of random and stand-still); contradicted when above",
                            [f"{mod} {line}", f"all {base_line}"],
                        ),
                        t.loc[mod],
                    )
                )
                continue
            outcome, line = beats(base, t.loc[mod], rules.margin, ("all", mod))
            v = REPRODUCED if outcome == ABOVE else CONTRADICTED if outcome == NOT_ABOVE else UNRESOLVED
            parts.append(
                _gate(
                    Verdict(
                        f"{mod} below all (testbed success)",
                        v,
                        f"success ratio all / {mod}, 95 % interval: above {1 + rules.margin:g} reproduces, at or "
                        f"under {1 + rules.margin:g} contradicts",
                        [f"{mod} {_fmt(t.loc[mod])} vs all {_fmt(base)}; {line}"],
                    ),
                    t.loc[mod],
                    base,
                )
            )
        if not all(m in t.index for m in need):
            parts.append(
                missing(f"olfaction matters least ({name})", "no_olfaction, no_thermoception and no_collision runs")
            )
            continue
        olf = t.loc["no_olfaction"]
        others = {m: t.loc[m] for m in need[1:]}
        outcomes, lines = [], []
        for m, o in others.items():
            outcome, line = beats(olf, o, rules.margin, ("no_olfaction", m))
            outcomes.append(outcome)
            lines.append(line)
        v = (
            REPRODUCED
            if all(o == ABOVE for o in outcomes)
            else CONTRADICTED
            if any(o == NOT_ABOVE for o in outcomes)
            else UNRESOLVED
        )
        rule = (
            f"no_olfaction above no_thermoception and no_collision: {'survival' if name == 'survival' else 'success'} "
            f"ratio's 95 % interval above {1 + rules.margin:g} for both (reproduced), at or under it for either "
            "(contradicted)"
        )
        parts.append(
            _gate(
                Verdict(
                    f"olfaction matters least ({name})",
                    v,
                    rule,
                    [f"no_olfaction {_fmt(olf)}; " + "; ".join(f"{m} {_fmt(o)}" for m, o in others.items()), *lines],
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
