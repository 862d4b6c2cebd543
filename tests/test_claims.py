"""The rules that judge the paper's claims (a)–(e) (evaaa_baselines.paper.claims), on aggregated tables written
here by hand: every rule reaches each of its verdicts — reproduced, contradicted, not resolvable at this scale —
from the numbers that should give it, and says which numbers it used.  Tables without episodes (``samples``) give
a ratio's interval from the bounds of the cells' intervals, ``[low_a / high_b, high_a / low_b]``, so that each case
is computed by hand in its comment."""

from __future__ import annotations

import pandas as pd
import pytest

from evaaa_baselines.paper import claims as c

LEVELS = ["1-1", "1-2", "2-1", "2-2", "3-1", "3-2", "4-1", "4-2"]


def cell(value: float, half: float = 10.0, **keys) -> dict:
    return {**keys, "value": value, "low": value - half, "high": value + half}


def frame(rows) -> pd.DataFrame:
    return pd.DataFrame(rows)


def per_level(algo: str, values, half: float = 10.0, levels=LEVELS, **keys) -> list[dict]:
    return [cell(v, half, algo=algo, level=lv, **keys) for lv, v in zip(levels, values)]


# ------------------------------------------------------------------------------------------------ (a)
def test_a_survival_falling_and_a_drop_at_3_2_is_reproduced():
    v = c.survival_falls(frame(per_level("ppo", [900, 850, 800, 780, 700, 200, 150, 100])), LEVELS)
    assert v.verdict == c.REPRODUCED
    falls, drop = v.parts
    # 4-2 / 1-1 = 100 / 900 = 0.11, bounds [90 / 910, 110 / 890] = [0.099, 0.124]: under 1 − 0.1
    assert "4-2 / 1-1 = 0.11 [0.10, 0.12]" in falls.evidence[1] and falls.verdict == c.REPRODUCED
    assert "Spearman's rho -1.00" in falls.evidence[2] and "3-2: 200 [190, 210]" in falls.evidence[0]
    # 3-2 / 3-1 = 200 / 700 = 0.29, bounds [190 / 710, 210 / 690] = [0.27, 0.30]: under 1 − 0.1
    assert "3-2 / 3-1 = 0.29 [0.27, 0.30]" in drop.evidence[1] and drop.verdict == c.REPRODUCED


def test_a_survival_rising_is_contradicted():
    v = c.survival_falls(frame(per_level("dqn", [100, 150, 200, 250, 300, 800, 850, 900])), LEVELS)
    assert v.verdict == c.CONTRADICTED


def test_a_falling_but_the_drop_at_3_2_not_resolved_is_not_resolvable():
    # 4-2 / 1-1 = 550 / 900, bounds [540 / 910, 560 / 890] = [0.59, 0.63]: a fall; 3-2 / 3-1 = 650 / 700 with bounds
    # [450 / 900, 850 / 500] = [0.5, 1.7]: straddles 0.9
    halves = [10, 10, 10, 10, 200, 200, 10, 10]
    rows = [
        cell(v, h, algo="ppo", level=lv) for lv, v, h in zip(LEVELS, [900, 850, 800, 750, 700, 650, 600, 550], halves)
    ]
    v = c.survival_falls(frame(rows), LEVELS)
    assert [p.verdict for p in v.parts] == [c.REPRODUCED, c.UNRESOLVED] and v.verdict == c.UNRESOLVED
    assert "[0.59, 0.63]" in v.parts[0].evidence[1] and "[0.50, 1.70]" in v.parts[1].evidence[1]
    assert c.survival_falls(frame([]), LEVELS).verdict == c.UNRESOLVED


def test_a_flat_survival_is_a_decided_contradiction_by_equivalence():
    # 4-2 / 1-1 = 700 / 700, bounds [690 / 710, 710 / 690] = [0.972, 1.029]: at or above 1 − 0.1, no fall beyond the
    # margin — contradicted, though Spearman's rho of equal values says nothing
    v = c.survival_falls(frame(per_level("ppo", [700] * 8)), LEVELS)
    assert (
        v.parts[0].verdict == c.CONTRADICTED
        and "4-2 / 1-1 = 1.00 [0.97, 1.03] (bounds of the cells' intervals) ≥ 0.9" in v.parts[0].evidence[1]
    )
    # a margin of 0.02 leaves the same interval straddling 0.98: not resolvable
    tight = c.survival_falls(frame(per_level("ppo", [700] * 8)), LEVELS, rules=c.Rules(margin=0.02))
    assert tight.parts[0].verdict == c.UNRESOLVED


def test_a_no_drop_at_3_2_within_the_margin_is_contradicted():
    # 3-2 / 3-1 = 690 / 700, bounds [680 / 710, 700 / 690] = [0.958, 1.014]: at or above 1 − 0.1, no sharp drop
    v = c.survival_falls(frame(per_level("ppo", [900, 850, 800, 750, 700, 690, 680, 670])), LEVELS)
    assert v.parts[1].verdict == c.CONTRADICTED and "[0.96, 1.01]" in v.parts[1].evidence[1]
    assert v.verdict == c.CONTRADICTED  # one part contradicted: the claim states it


def test_a_claim_of_parts_is_reproduced_only_when_every_part_is():
    mixed = frame(
        per_level("ppo", [900, 850, 800, 780, 700, 200, 150, 100])
        + per_level("dqn", [100, 150, 200, 250, 300, 800, 850, 900])
    )
    assert c.survival_falls(mixed, LEVELS).verdict == c.CONTRADICTED  # dqn's rise contradicts what ppo reproduces
    parts = [c.Verdict("x", c.CONTRADICTED, ""), c.Verdict("y", c.UNRESOLVED, "")]
    assert c.combine("z", parts, "").verdict == c.CONTRADICTED
    parts = [c.Verdict("x", c.REPRODUCED, ""), c.Verdict("y", c.UNRESOLVED, "")]
    assert c.combine("z", parts, "").verdict == c.UNRESOLVED


# ------------------------------------------------------------------------------------------------ (b)
def cmp_rows(algo, cur, direct, half=10.0):
    return per_level(algo, cur, half, setup="curriculum") + per_level(algo, direct, half, setup="direct")


def test_b_curriculum_above_direct_on_most_levels_is_reproduced():
    # 500 / 100 with bounds [490 / 110, 510 / 90] = [4.45, 5.67]: above 1.1 on the 7 levels after 1-1
    v = c.curriculum_beats_direct(frame(cmp_rows("ppo", [500] * 8, [500] + [100] * 7)), LEVELS)
    assert v.verdict == c.REPRODUCED
    assert "curriculum beats direct on 7 of 7 levels" in v.parts[0].evidence[-1]  # 1-1: the same training, skipped


def test_b_a_decided_contradiction_by_equivalence():
    # curriculum 1000 [980, 1020] against direct 1000 [980, 1020] on every level: the ratio's bounds
    # [980 / 1020, 1020 / 980] = [0.961, 1.041] lie inside [0.9, 1.1] — equal within the margin, and so not
    # beating it: contradicted, though neither interval lies above the other
    rows = frame(cmp_rows("ppo", [1000] * 8, [1000] * 8, half=20))
    v = c.curriculum_beats_direct(rows, LEVELS)
    assert v.verdict == c.CONTRADICTED and v.parts[0].verdict == c.CONTRADICTED
    assert "curriculum / direct = 1.00 [0.96, 1.04]" in v.parts[0].evidence[0]
    assert "equal within the margin" in v.parts[0].evidence[0]
    assert not c.above(rows.iloc[1], rows.iloc[9]) and not c.above(rows.iloc[9], rows.iloc[1])
    # a margin of 0.02 from the protocol: 1.041 is over 1.02, so the same numbers no longer decide
    tight = c.curriculum_beats_direct(rows, LEVELS, rules=c.Rules(margin=0.02))
    assert tight.verdict == c.UNRESOLVED


def test_b_direct_above_curriculum_is_contradicted_and_overlap_is_not_resolvable():
    assert c.curriculum_beats_direct(frame(cmp_rows("dqn", [100] * 8, [500] * 8)), LEVELS).verdict == c.CONTRADICTED
    # 130 [110, 150] / 110 [100, 120]: bounds [110 / 120, 150 / 100] = [0.92, 1.5] straddle 1.1
    rows = frame(per_level("dqn", [130] * 8, 20, setup="curriculum") + per_level("dqn", [110] * 8, setup="direct"))
    assert c.curriculum_beats_direct(rows, LEVELS).verdict == c.UNRESOLVED
    only_cur = frame(per_level("ppo", [1] * 8, setup="curriculum"))
    v = c.curriculum_beats_direct(only_cur, LEVELS)
    assert v.verdict == c.UNRESOLVED and "no algorithm with both" in v.evidence[0]


# ------------------------------------------------------------------------------------------------ (c)
def survival_c(dreamer=None, dqn=(800, 700, 100, 100, 100, 100, 100, 100), ppo=(300,) * 8, lstm=(100,) * 8):
    rows = per_level("dqn", dqn) + per_level("ppo", ppo) + per_level("ppo_lstm", lstm)
    if dreamer is not None:
        rows += per_level("dreamer_xs", dreamer)
    return frame(rows)


#: the bar of "fails" on every level: 2 × the better of random and stand-still (100)
BARS = dict.fromkeys(LEVELS, 200.0)


def test_c_every_part_holding_is_reproduced_and_dreamer_missing_is_said():
    v = c.algorithm_ordering(survival_c(dreamer=(2000,) * 8, ppo=(50,) * 8), BARS, LEVELS)
    assert v.verdict == c.REPRODUCED, [(p.claim, p.verdict, p.evidence) for p in v.parts]
    v = c.algorithm_ordering(survival_c(ppo=(50,) * 8), BARS, LEVELS)
    assert v.verdict == c.UNRESOLVED
    assert v.parts[0].evidence == ["no data: no DreamerV3 runs"]
    assert [p.verdict for p in v.parts[1:]] == [c.REPRODUCED] * 3


def test_c_ppo_above_dqn_and_lstm_learning_are_contradicted():
    v = c.algorithm_ordering(survival_c(dqn=(100,) * 8, ppo=(900,) * 8, lstm=(900,) * 8), BARS, LEVELS)
    assert v.verdict == c.CONTRADICTED
    verdicts = {p.claim: p.verdict for p in v.parts}
    assert verdicts["dqn > ppo in survival"] == c.CONTRADICTED
    assert verdicts["ppo_lstm fails"] == c.CONTRADICTED  # 890 > 200 on every level: it learned
    # DQN under the bar on 1-1 and 1-2 too: it fails everywhere, so "fails *beyond* 1-2" is contradicted
    assert verdicts["dqn fails beyond 1-2"] == c.CONTRADICTED


# ------------------------------------------------------------------------------------------------ (d)
TESTBEDS = ["two-resource-food", "y-maze", "risk-taking"]


def refs(human=True):
    rows = [cell(1.0, 0.1, agent="oracle", level=t) for t in TESTBEDS]
    rows += [cell(0.05, 0.05, agent="random", level=t) for t in TESTBEDS]
    if human:
        rows += [cell(0.95, 0.1, agent="human", level=t) for t in TESTBEDS]
    return frame(rows)


def gen(values, episodes=100, half=0.05):
    return frame([cell(v, half, agent="ppo", level=lv, episodes=episodes) for lv, v in zip(LEVELS, values)])


def test_d_agents_below_humans_at_ceiling_and_a_drop_is_reproduced():
    success = frame([cell(0.1, 0.1, agent="ppo · curriculum", level=t) for t in TESTBEDS])
    values = [0.1, 0.3, 0.3, 0.1, 0.1, 0.1, 0.1, 0.1]
    v = c.testbeds_below_ceiling(success, refs(), gen(values), LEVELS)
    assert v.verdict == c.REPRODUCED, [(p.claim, p.verdict) for p in v.parts]
    # 2-1 → 2-2: 0.3 → 0.1 of 100 effective episodes each: pooled 0.2, z = 0.2 / sqrt(0.2 · 0.8 · 2 / 100) = 3.54,
    # one-sided p = 0.000203 < 0.05 / 7 (Holm's first step over the 7 steps)
    assert "2-1→2-2: p = 0.000203 (rejected)" in v.parts[-1].evidence[2]
    assert "Holm over the 7 steps" in v.parts[-1].evidence[2]


def test_d_the_drop_rule_has_power_at_three_seeds_and_says_it():
    # the smallest drop found with 80 % power at a rate of 0.1 and 300 effective episodes a level (3 seeds × 100):
    # (z_{1 − 0.05/7} + z_{0.8}) · sqrt(2 · 0.1 · 0.9 / 300) = (2.448 + 0.842) · 0.02449 = 0.0806
    assert c.detectable_drop(0.1, 300, 0.05 / 7) == pytest.approx(0.0806, abs=5e-4)
    # the old rule, paired t-tests over 3 seeds Holm-corrected over 28 pairs, rejected nothing short of t > 16;
    # here a drop of 0.1 → 0.0 between consecutive levels of 300 episodes is found
    v = c.testbeds_below_ceiling(frame([]), refs(), gen([0.1] * 7 + [0.0], episodes=300), LEVELS)
    assert v.parts[-1].verdict == c.REPRODUCED
    # at the mean rate 0.0875: (2.448 + 0.842) · sqrt(2 · 0.0875 · 0.9125 / 300) = 0.076
    assert "a drop of 0.076 between two consecutive levels is resolved with 80 %" in v.parts[-1].evidence[3]


def test_d_without_human_records_is_not_resolvable_and_says_so():
    success = frame([cell(0.1, 0.1, agent="ppo · curriculum", level=t) for t in TESTBEDS])
    v = c.testbeds_below_ceiling(success, refs(human=False), gen([0.1, 0.12, 0.14, 0.16] * 2), LEVELS)
    assert v.verdict == c.UNRESOLVED
    assert "no human play records" in v.parts[0].evidence[0]


def test_d_agents_at_the_oracle_and_a_monotonic_rise_are_contradicted():
    success = frame([cell(0.98, 0.05, agent="ppo · curriculum", level=t) for t in TESTBEDS])
    rising = gen([0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8])  # rho 1, exact p = 2 / 8!; 0.8 [0.75, 0.85] above 0.1's
    v = c.testbeds_below_ceiling(success, refs(human=False), rising, LEVELS)
    assert [p.verdict for p in v.parts[1:]] == [c.CONTRADICTED, c.CONTRADICTED]
    assert v.verdict == c.CONTRADICTED
    # the gain along the least-squares line over levels 0..7 is Σ (x − 3.5) / 6 · p: a rise of 0.1 a level gives
    # 0.7; each level's standard error 0.05 / 1.96 = 0.0255, the gain's sqrt(Σ w²) = sqrt(7 / 6) times it, 0.0276:
    # 0.7 ± 1.96 · 0.0276 = [0.646, 0.754], above +0.1
    assert "+0.700 [+0.646, +0.754]" in v.parts[-1].evidence[1]


def test_d_a_flat_success_is_a_decided_no_gain_by_equivalence_and_its_power_is_stated():
    success = frame([cell(0.1, 0.1, agent="ppo · curriculum", level=t) for t in TESTBEDS])
    # flat at 0.1, each level ± 0.05: the gain 0 ± 1.96 · 0.0276 = [−0.054, +0.054], at or under +0.1: no gain beyond
    # the margin, with no drop resolved
    flat = c.testbeds_below_ceiling(success, refs(human=False), gen([0.1] * 8), LEVELS).parts[-1]
    assert flat.verdict == c.REPRODUCED and "0.000 [-0.054, +0.054]" in flat.evidence[1]
    assert "resolved: none" in flat.evidence[2]
    # power: Φ(0.1 / 0.0276 − 1.96) = Φ(1.67) = 95 % to reproduce with no gain; 0.1 + (1.96 + 0.842) · 0.0276 = 0.177
    assert "probability 95 %" in flat.evidence[3] and "a gain of 0.177 or more" in flat.evidence[3]
    # a margin of 0.05 under the interval's top: not resolvable — the margin is the protocol's, not the data's
    tight = c.testbeds_below_ceiling(success, refs(human=False), gen([0.1] * 8), LEVELS, c.Rules(gain_margin=0.05))
    assert tight.parts[-1].verdict == c.UNRESOLVED


# ------------------------------------------------------------------------------------------------ (e)
def ablation(values, half=10.0):
    return frame([cell(v, half, modality=m) for m, v in values.items()])


def test_e_reproduced_contradicted_and_not_resolvable():
    good = {
        "all": 900,
        "no_vision": 100,
        "no_interoception": 100,
        "no_olfaction": 800,
        "no_thermoception": 400,
        "no_collision": 500,
    }
    # fails: 100 [90, 110] not above the bar 200; olfaction: 800 / 400 bounds [790 / 410, 810 / 390] above 1.1;
    # success: all / no_vision = 0.9 / 0.1 bounds [0.89 / 0.11, 0.91 / 0.09] above 1.1
    v = c.ablations(ablation(good), ablation({k: x / 1000 for k, x in good.items()}, 0.01), 200.0)
    assert v.verdict == c.REPRODUCED, [(p.claim, p.verdict) for p in v.parts]
    bad = dict(good, no_vision=1500, no_olfaction=100)
    v = c.ablations(ablation(bad), frame([]), 200.0)
    verdicts = {p.claim: p.verdict for p in v.parts}
    assert verdicts["no_vision fails (survival)"] == c.CONTRADICTED  # 1490 > 200: it learned
    assert verdicts["olfaction matters least (survival)"] == c.CONTRADICTED
    assert verdicts["ablations (testbed success)"] == c.UNRESOLVED
    assert v.verdict == c.CONTRADICTED
    wide = {p.claim: p.verdict for p in c.ablations(ablation(good, half=1000), frame([]), 200.0).parts}
    assert wide["olfaction matters least (survival)"] == c.UNRESOLVED
    # "fails" puts the burden on learning: an interval that does not clear the bar is "did not learn"
    assert wide["no_vision fails (survival)"] == c.REPRODUCED


def test_e_success_at_the_floor_decides_nothing():
    # every rate about 0.04: no_olfaction / no_collision bounds [0.02 / 0.08, 0.08 / 0.02] = [0.25, 4]: a floor
    # of failures is no evidence that two senses matter equally
    rates = dict.fromkeys(["all", "no_vision", "no_interoception", "no_olfaction", "no_thermoception"], 0.05)
    v = c.ablations(frame([]), ablation(dict(rates, no_collision=0.05), 0.03))
    assert all(p.verdict == c.UNRESOLVED for p in v.parts if "success" in p.claim)


def test_markdown_names_every_verdict_rule_and_number():
    v = c.survival_falls(frame(per_level("ppo", [900, 850, 800, 780, 700, 200, 150, 100])), LEVELS)
    text = "\n".join(c.markdown([v]))
    assert text.startswith("- **(a) survival falls with level difficulty, sharply from 3-2 on: reproduced.**")
    assert "Spearman's rho" in text and "4-2: 100 [90, 110]" in text


@pytest.mark.parametrize(
    "a, b, expected",
    [
        ({"low": 5, "high": 6}, {"low": 1, "high": 4}, True),
        ({"low": 4, "high": 6}, {"low": 1, "high": 4}, False),
        ({"low": float("nan"), "high": 6}, {"low": 1, "high": 4}, False),
    ],
)
def test_above_needs_intervals_apart(a, b, expected):
    assert c.above(a, b) is expected


def test_spearman_p_is_exact_for_few_levels_so_a_perfect_order_of_four_is_not_significant():
    rho, p = c.spearman([0, 1, 2, 3], [400, 300, 200, 100])
    assert rho == pytest.approx(-1.0) and p == pytest.approx(2 / 24)  # two of the 24 orders are this extreme
    assert c.spearman(range(8), range(8, 0, -1))[1] == pytest.approx(2 / 40320)
    v = c.survival_falls(frame(per_level("dqn", [900, 800, 300, 200], levels=LEVELS[:4])), LEVELS)
    assert v.verdict == c.UNRESOLVED and "p = 0.0833" in v.parts[0].evidence[2]  # the shape beside the ratio


def test_no_part_is_decided_on_fewer_than_three_seeds():
    # a rising survival would contradict (a) on its points alone (Spearman's rho 1, p < 0.001); with two seeds per
    # cell there are no intervals and no verdict: "not resolvable: 2 seeds", with each seed's value
    nan = float("nan")
    rising = frame(
        [
            {
                "algo": "ppo",
                "level": lv,
                "value": 100.0 * (i + 1),
                "low": nan,
                "high": nan,
                "n": 2,
                "unit": "seeds",
                "points": (100.0 * (i + 1) - 5, 100.0 * (i + 1) + 5),
            }
            for i, lv in enumerate(LEVELS)
        ]
    )
    v = c.survival_falls(rising, LEVELS)
    assert v.verdict == "not resolvable: 2 seeds" and v.parts[0].verdict == "not resolvable: 2 seeds"
    assert "1-1: 100 (seeds 95, 105)" in v.parts[0].evidence[0]
    three = rising.assign(n=3, low=rising["value"] - 10, high=rising["value"] + 10)
    assert c.survival_falls(three, LEVELS).verdict == c.CONTRADICTED
    # the same for "fails", against a bar
    short = frame(
        [
            {"algo": "ppo_lstm", "level": lv, "value": 900.0, "low": 890.0, "high": 910.0, "n": 2, "unit": "seeds"}
            for lv in LEVELS[:3]
        ]
    )
    assert c._fails("ppo_lstm", LEVELS[:3], short, BARS).verdict == "not resolvable: 2 seeds"


def test_agents_that_acted_differently_are_not_compared():
    fast = frame(
        [cell(900.0, algo="dqn", level=lv, acting="mode+epsilon=0.05") for lv in LEVELS[:4]]
        + [cell(100.0, algo="ppo", level=lv, acting="sample+epsilon=0.05") for lv in LEVELS[:4]]
    )
    v = c._ordered("dqn", "ppo", fast, LEVELS)
    assert v.verdict == c.UNRESOLVED and "acting modes differ" in v.evidence[-1]
    same = fast.assign(acting="mode")
    assert c._ordered("dqn", "ppo", same, LEVELS).verdict == c.REPRODUCED


def test_fails_is_not_reproduced_on_levels_without_an_interval():
    nan = float("nan")
    one_seed = frame([{"algo": "ppo_lstm", "level": lv, "value": 900.0, "low": nan, "high": nan} for lv in LEVELS[:3]])
    v = c._fails("ppo_lstm", LEVELS[:3], one_seed, BARS)
    assert v.verdict == c.UNRESOLVED
    assert "no interval" in v.evidence[0] and "fails on 0 of 3" in v.evidence[-1]


def test_a_greedy_agent_without_a_distribution_is_compared_in_a_sample_comparison_and_said_so():
    # the report compares `sample` and DQN, which has no action distribution, takes part with its greedy action:
    # labelled so, compared, and the evidence says how each acted
    stand_in = "sample" + c.GREEDY_STAND_IN
    rows = [cell(900.0, algo="dqn", level=lv, acting=stand_in) for lv in LEVELS[:4]]
    rows += [cell(100.0, algo="ppo", level=lv, acting="sample") for lv in LEVELS[:4]]
    v = c._ordered("dqn", "ppo", frame(rows), LEVELS)
    assert v.verdict == c.REPRODUCED
    assert f"dqn `{stand_in}`, ppo `sample`" in v.evidence[-1] and "takes its greedy action" in v.evidence[-1]
    # a stand-in for `sample` is still not `mode`, and epsilon must match
    for other in ("mode", "sample+epsilon=0.05"):
        mixed = frame([r | {"acting": other} if r["algo"] == "ppo" else r for r in rows])
        assert c._ordered("dqn", "ppo", mixed, LEVELS).verdict == c.UNRESOLVED


# ------------------------------------------------------------------------------------------------ issue 62
def test_one_definition_of_fails_for_every_claim():
    """PPO+LSTM at 1,885 [1,283, 2,539] and no_vision at 2,007 [1,632, 2,528] on 1-1, where stand-still survives
    1,112 and random 823: both intervals lie above random's, neither above the bar 2 × 1,112 = 2,224 — both fail,
    in (c) and in (e) alike, by the rule the learned gate uses (its interval above the bar)."""
    bar = 2 * 1112.0
    lstm = cell(1885, algo="ppo_lstm", level="1-1") | {"low": 1283.0, "high": 2539.0}
    vision = {"modality": "no_vision", "value": 2007.0, "low": 1632.0, "high": 2528.0}
    assert c.fails(lstm, bar)[0] == "fails" and c.fails(vision, bar)[0] == "fails"
    assert lstm["low"] > 823  # the old (c) rule, "not above random", would have said it does not fail
    matched = c.matched_ordering(frame([lstm]), bar, frame([]), frame([]), "1-1", "110 CPU-min")
    assert {p.claim: p.verdict for p in matched.parts}["ppo_lstm fails"] == c.REPRODUCED
    ab = frame([{"modality": "all", "value": 2820.0, "low": 2131.0, "high": 3994.0}, vision])
    parts = {p.claim: p for p in c.ablations(ab, frame([]), bar).parts}
    assert parts["no_vision fails (survival)"].verdict == c.REPRODUCED
    assert "with every sense it did not learn either" in parts["no_vision fails (survival)"].evidence[1]
    # above the bar: learned, and "fails" contradicted in both claims
    assert c.fails({"value": 3000.0, "low": 2300.0, "high": 3500.0}, bar)[0] == "learned"


def test_a_gate_does_not_hide_a_part_the_data_decide():
    """At equal compute every DQN seed ≤ 1,563 and every PPO seed ≥ 4,564: DQN 1,221 [1,112, 1,454] against PPO
    ≥ 5,000 [5,000, 5,000] (93 % of its episodes at the step cap) decides "DQN > PPO" — contradicted, bounds
    [1,112 / 5,000, 1,454 / 5,000] = [0.22, 0.29] — although the gate says DQN did not learn; an undecided part
    names the agents that did not learn."""
    survival = frame(
        [
            {"algo": "dqn", "level": "1-1", "value": 1221.0, "low": 1112.0, "high": 1454.0, "acting": "mode"},
            {"algo": "ppo", "level": "1-1", "value": 5000.0, "low": 5000.0, "high": 5000.0, "acting": "mode"},
            {"algo": "dreamer_xs", "level": "1-1", "value": 1383.0, "low": 1265.0, "high": 1528.0, "acting": "mode"},
        ]
    ).assign(at_cap=[0.0, 0.93, 0.0])
    gate = frame(
        [
            {"algo": "dqn", "learned": False, "reading": "dqn: did not learn at this budget"},
            {"algo": "ppo", "learned": True, "reading": "ppo: learned"},
            {"algo": "dreamer_xs", "learned": False, "reading": "dreamer_xs: did not learn at this budget"},
        ]
    )
    v = c.matched_ordering(survival, 2224.0, gate, frame([]), "1-1", "110 CPU-min")
    parts = {p.claim: p for p in v.parts}
    assert parts["dqn > ppo in survival"].verdict == c.CONTRADICTED
    assert "dqn / ppo = 0.24 [0.22, 0.29]" in parts["dqn > ppo in survival"].evidence[0]
    assert parts["dreamer_xs survives longest on 1-1"].verdict == c.CONTRADICTED  # not longer than ppo
    # DreamerV3-XS against DQN alone: bounds [1,265 / 1,454, 1,528 / 1,112] = [0.87, 1.37] straddle 1.1, and
    # both did not learn: the part says so
    two = c.survives_longest("dreamer_xs", survival[survival["algo"] != "ppo"], gate, "1-1")
    assert two.verdict == c.NOT_LEARNED and "dqn: did not learn at this budget" in two.evidence
    # censoring: PPO at the cap is a lower bound, so "PPO longer than DQN" holds, "DQN not longer" too, but an
    # equivalence of two capped cells decides nothing
    assert c.beats(survival.iloc[1], survival.iloc[0], 0.1, ("ppo", "dqn"))[0] == c.ABOVE
    capped = survival.iloc[1]
    assert c.beats(capped, capped, 0.1, ("ppo", "ppo"))[0] is None


def test_a_capped_survival_cell_is_labelled_a_lower_bound_with_intake():
    from evaaa_baselines.reports.aggregate import across_seeds
    from evaaa_baselines.reports.tables import cell as table_cell

    # three seeds on 1-1 (cap 5,000): 5 of 6 episodes at the cap; eaten 52 in 26,000 decisions: 2.0 per 1,000
    rows = frame(
        [
            {"level": "1-1", "scores": (5000.0, 5000.0), "eaten": (10.0, 10.0), "episodes": 2},
            {"level": "1-1", "scores": (5000.0, 1000.0), "eaten": (10.0, 2.0), "episodes": 2},
            {"level": "1-1", "scores": (5000.0, 5000.0), "eaten": (10.0, 10.0), "episodes": 2},
        ]
    )
    stats = across_seeds(rows, ["level"], "survival")
    row = stats.iloc[0]
    assert row["at_cap"] == pytest.approx(5 / 6) and row["intake"] == pytest.approx(2.0)
    text = table_cell(row)
    assert text.startswith("≥ 5000.0 [") and "83 % at the step cap; intake 2.0 / 1,000 decisions" in text
    # a quarter at the cap exactly is not more than a quarter: no bound, no note
    quarter = across_seeds(
        frame([{"level": "1-1", "scores": (5000.0, 100.0, 200.0, 300.0), "episodes": 4}] * 3), ["level"], "survival"
    ).iloc[0]
    assert quarter["at_cap"] == pytest.approx(0.25) and not table_cell(quarter).startswith("≥")


def test_one_hatching_for_acting_modes_and_legends_of_at_most_60_characters():
    from evaaa_baselines.reports.figures import legend_names, styles

    for order in (["ppo [mode]", "ppo [sample]"], ["ppo [sample]", "ppo [mode]"]):
        style = styles(order)
        assert style["ppo [sample]"][1] == "" and style["ppo [mode]"][1] == "//"
    long = [
        "ppo · no_interoception · original · 150,000 env steps · trained on 1-1 [sample]",
        "ppo · no_vision · original · 150,000 env steps · trained on 1-1 [sample]",
    ]
    shown = legend_names(long)
    assert all(len(v) <= 60 for v in shown.values()) and len(set(shown.values())) == 2
    assert shown[long[1]] == "ppo · no_vision [sample]"
