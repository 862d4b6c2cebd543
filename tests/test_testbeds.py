"""The testbeds: layouts, success criteria (a scripted success and a scripted failure each), the oracle,
and the evaluation tool."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from helpers import load_script

import evaaa
from evaaa.agents import OracleAgent
from evaaa.physiology import END_TYPES
from evaaa.records import read_rows
from evaaa.sim import EAT, FORWARD, NONE, Simulator


def make_sim(name: str, **overrides) -> Simulator:
    sim = Simulator(evaaa.load_level(name, overrides), 1, ["interoception"], seed=0)
    sim.reset()
    return sim


def kind_slot(sim: Simulator, kind: str) -> int:
    feeds = sim.res_is_food if kind == "food" else sim.res_is_water
    return int(np.flatnonzero(feeds & sim.res_present[0])[0])


def eat(sim: Simulator, kind: str):
    """Stand in front of an item of ``kind`` and eat it; return the step's outputs."""
    slot = kind_slot(sim, kind)
    sim.set_agent_pose(0, sim.res_xy[0, slot] - (0.0, 0.9), 0.0)
    return sim.step(np.array([EAT]))


def outcome(step) -> tuple[bool, bool, str]:
    _, _, terminated, truncated, info = step
    return bool(info["success"][0, 0]), bool(terminated[0] or truncated[0]), END_TYPES[int(info["end_type"][0, 0])]


def test_the_testbed_list_is_every_packaged_testbed_file():
    files = sorted(p.stem for p in (Path(evaaa.__file__).parent / "levels").glob("*.yaml") if p.stem[0] != "_")
    assert evaaa.TESTBEDS and not set(evaaa.TESTBEDS) & set(evaaa.LEVELS)
    assert sorted(evaaa.LEVELS + evaaa.TESTBEDS) == files  # every file is listed, under the kind it declares
    assert [n for n in files if evaaa.load_level(n).kind == "testbed"] == sorted(evaaa.TESTBEDS)
    for name in evaaa.TESTBEDS:
        level = evaaa.load_level(name)
        assert level.kind == "testbed" and level.thermal.relative and level.arena.floor == "gray"
        assert level.agent.start == "fixed" and level.thermal.hotspots.count == 0
        assert level.episode.success.rule != "none"


@pytest.mark.parametrize(
    "name,right,wrong", [("two-resource-food", "food", "water"), ("two-resource-water", "water", "food")]
)
def test_two_resource_choice(name, right, wrong):
    assert outcome(eat(make_sim(name), right)) == (True, True, "ResourceConsumed")
    assert outcome(eat(make_sim(name), wrong)) == (False, True, "ResourceConsumed")


def test_two_resource_temperature_needs_warmth_not_food():
    sim = make_sim("two-resource-temp", **{"episode.max_steps": 20})
    assert outcome(eat(sim, "food")) == (False, True, "ResourceConsumed")  # eating ends the trial uselessly
    sim = make_sim("two-resource-temp", **{"episode.max_steps": 20})
    fire = np.flatnonzero(sim.obstacles.temperature > 0)[0]
    sim.set_agent_pose(0, sim.obs_xy[0, fire] - (0.0, 5.0), 0.0)  # warm ground near the fire
    for _ in range(20):
        step = sim.step(np.array([NONE]))
    assert outcome(step) == (True, True, "MaxStepReached")
    assert sim.ev[0, 2] > -12.0
    sim = make_sim("two-resource-temp")  # staying in the cold kills within ~150 decisions
    for _ in range(300):
        step = sim.step(np.array([NONE]))
        if outcome(step)[1]:
            break
    assert outcome(step) == (False, True, "TemperatureOutOfRange")


@pytest.mark.parametrize("name", ["collision-avoidance", "risk-taking", "predator-day-night"])
def test_reach_the_food(name):
    assert outcome(eat(make_sim(name), "food"))[:2] == (True, True)
    sim = make_sim(name, **{"episode.max_steps": 5})
    for _ in range(5):
        step = sim.step(np.array([NONE]))
    assert outcome(step) == (False, True, "MaxStepReached")


def test_risk_taking_fires_overheat_the_body():
    sim = make_sim("risk-taking")
    fire = np.flatnonzero(sim.obstacles.temperature > 0)[0]
    sim.set_agent_pose(0, sim.obs_xy[0, fire] - (0.0, 1.5), 0.0)
    step = sim.step(np.array([NONE]))
    for _ in range(10):
        if outcome(step)[1]:
            break
        step = sim.step(np.array([NONE]))
    assert outcome(step) == (False, True, "TemperatureOutOfRange")


@pytest.mark.parametrize(
    "name,first,then",
    [("goal-manipulation-food-to-water", "food", "water"), ("goal-manipulation-water-to-food", "water", "food")],
)
def test_goal_manipulation(name, first, then):
    # walking across the trigger swaps the needs; then eating the newly needed resource succeeds
    sim = make_sim(name)
    trigger_x = sim.level.events["switch"].x
    start = sim.ev[0, :2].copy()
    sim.set_agent_pose(0, (trigger_x + (1.5 if trigger_x < 0 else -1.5), 0.0), 270.0 if trigger_x < 0 else 90.0)
    _, _, _, _, info = sim.step(np.array([FORWARD]))
    assert info["trigger_crossed"][0, 0]
    assert np.allclose(sim.ev[0, :2], -start, atol=0.05)  # +7 / -7 swapped
    assert outcome(eat(sim, then)) == (True, True, "ResourceConsumed")
    # the trigger fires once only
    sim = make_sim(name)
    for _ in range(2):
        sim.set_agent_pose(0, (trigger_x + (1.5 if trigger_x < 0 else -1.5), 0.0), 270.0 if trigger_x < 0 else 90.0)
        _, _, _, _, info = sim.step(np.array([FORWARD]))
    assert not info["trigger_crossed"][0, 0] and sim.trigger_count[0, 0] == 1
    # without crossing, even the resource that becomes needed is a failure; so is the first one
    assert outcome(eat(make_sim(name), then))[0] is False
    assert outcome(eat(make_sim(name), first))[0] is False


@pytest.mark.parametrize("name", ["y-maze", "multi-goal-planning"])
def test_survival_tasks(name):
    sim = make_sim(name, **{"episode.max_steps": 30})
    sim.ev[0, :3] = 0.0  # a well-kept body lasts the episode
    for _ in range(30):
        step = sim.step(np.array([NONE]))
    assert outcome(step) == (True, True, "MaxStepReached")
    sim = make_sim(name)  # doing nothing starves (or freezes) the body long before 350 decisions
    for _ in range(350):
        step = sim.step(np.array([NONE]))
        if outcome(step)[1]:
            break
    success, ended, end = outcome(step)
    assert ended and not success and end != "MaxStepReached"


def test_y_maze_and_multi_goal_floors_have_no_visible_walls_but_keep_the_agent_in():
    for name in ("y-maze", "multi-goal-planning"):
        sim = make_sim(name)
        half = np.array(sim.level.arena.size) / 2
        sim.set_agent_pose(0, (0.0, half[1] - 2.0), 0.0)
        for _ in range(4):
            sim.step(np.array([FORWARD]))
        assert sim.pos[0, 1] < half[1]


@pytest.mark.parametrize("name", evaaa.TESTBEDS)
def test_the_oracle_solves_every_testbed(name):
    sim = Simulator(evaaa.load_level(name), 2, ["interoception"], seed=11)
    sim.reset()
    oracle, results = OracleAgent(), []
    while len(results) < 4:
        _, _, terminated, truncated, info = sim.step(oracle.act(sim))
        done = terminated | truncated
        results += [bool(info["success"][w, 0]) for w in np.flatnonzero(done)]
        if done.any():
            sim.reset(done)
    assert all(results)


# ------------------------------------------------------------------------------------------------ evaluate.py
def load_evaluate():
    return load_script("evaluate")


def test_evaluate_writes_records_table_and_figures(tmp_path):
    out = tmp_path / "eval"
    code = load_evaluate().main(
        [
            "policy=[oracle,random]",
            "levels=[two-resource-water,1-2]",
            "episodes=3",
            "num_envs=2",
            f"out={out}",
            "episodes=3",
        ]
    )
    assert code == 0
    rows = read_rows(out / "episodes.csv")
    assert len(rows) == 12
    oracle_water = [r for r in rows if r["policy"] == "oracle" and r["level"] == "two-resource-water"]
    assert [r["success"] for r in oracle_water] == ["True"] * 3
    assert all(r["success"] == "" for r in rows if r["level"] == "1-2")  # training levels are not judged
    table = (out / "summary.md").read_text()
    # oracle: 3 of 3, with its Wilson interval rather than "± 0"; training levels: survival IQM [interval]; mean ± se
    assert "| two-resource-water | 100.0% [43.9, 100.0] (n=3 ep.) |" in table
    assert re.search(r"\| 1-2 \| [\d.]+ \[[\d.]+, [\d.]+\]; [\d.]+ ± [\d.]+ \(n=3 ep\.\) \|", table)
    for name in ("success.png", "survival.png", "outcomes.png"):
        assert (out / name).stat().st_size > 1000


def test_evaluate_plays_test_worlds_and_stand_still_never_moves(tmp_path):
    out = tmp_path / "eval"
    assert load_evaluate().main(["policy=[still]", "levels=[1-1]", "episodes=2", "num_envs=2", f"out={out}"]) == 0
    rows = read_rows(out / "episodes.csv")
    assert [r["worlds"] for r in rows] == ["test", "test"] and all(r["policy"] == "still" for r in rows)
    assert all(float(r["none_pct"]) == 100.0 and r["food_eaten"] == "0" and r["collisions"] == "0" for r in rows)
    # it dies of hunger or thirst, not of damage: it never moved
    assert {r["end_type"] for r in rows} <= {"FoodOutOfRange", "WaterOutOfRange"}
    assert "test worlds of seed 0" in (out / "summary.md").read_text()


@pytest.mark.parametrize(
    "args,message",
    [
        (["worlds=train"], "worlds=train: 'train' is not allowed; allowed: test, validation"),
        (
            ["levels=[no-such-testbed]"],
            "levels=[no-such-testbed]: 'no-such-testbed' is not allowed (did you mean testbeds?); allowed: 1-1",
        ),
        (
            ["policy=missing/checkpoint.pt"],
            "policy=missing/checkpoint.pt: expected oracle, random, still, zoo:NAME, an existing checkpoint file or "
            "py:MODULE:NAME",
        ),
        (["episodes=0"], "episodes=0: expected a positive integer"),
        (["episodes=abc"], "episodes=abc: expected an integer"),
        (["colour=red"], "unknown key 'colour'; keys: policy, references, levels, episodes"),
    ],
)
def test_evaluate_rejects_bad_input(args, message, tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        load_evaluate().main([*args, f"out={tmp_path / 'eval'}"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.count("\n") == 1 and message in err, err
    assert not (tmp_path / "eval").exists()
