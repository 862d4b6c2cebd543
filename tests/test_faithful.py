"""Where evaaa follows the original EVAAA and where a level option restores it: level contents, vertical
placement, reward semantics, success rules, predator harm, olfaction, night fog, end-type names and the per-step
behaviour log."""

from __future__ import annotations

import csv
import dataclasses
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers import load_script

import evaaa
from evaaa import daynight
from evaaa.level import LevelError
from evaaa.physiology import (
    END_DAMAGE,
    END_FOOD,
    END_MAX_STEPS,
    END_NONE,
    END_RESOURCE,
    END_TEMPERATURE,
    END_TYPES,
    END_WATER,
    ORIGINAL_END_TYPES,
    PhysiologyParams,
    reward,
)
from evaaa.records import EPISODE_FIELDS, STEP_FIELDS, EpisodeTracker, StepLog, append_rows, new_log_path, read_rows
from evaaa.sensors import SENSORS
from evaaa.sim import EAT, FORWARD, LEFT, NONE, RIGHT, Simulator
from evaaa.worldgen import ObstaclePool, place_obstacles


def _food_pixels(frame: np.ndarray) -> int:
    """Pixels of the food cube's red (0.85, 0.08, 0.08), lit or shaded."""
    red = (frame[..., 0] > 150) & (frame[..., 1] < 60) & (frame[..., 2] < 60)
    return int(red.sum())


# ------------------------------------------------------------------------------------------------ level contents
@pytest.mark.parametrize("name", [n for n in evaaa.LEVELS + evaaa.TESTBEDS if evaaa.load_level(n).obstacles])
def test_every_level_holds_every_obstacle_its_file_lists_over_20_seeds(name):
    level = evaaa.load_level(name)
    pool = ObstaclePool.from_level(level)
    listed = {group: spec.count for group, spec in level.obstacles.items()}
    for seed in range(20):
        _, present = place_obstacles(pool, np.random.default_rng(seed))
        held = {group: int(present[pool.group == g].sum()) for g, group in enumerate(pool.names)}
        assert held == listed, f"seed {seed}"


def test_a_level_too_crowded_to_build_fails_naming_the_group():
    level = evaaa.load_level("2-1", {"obstacles.rocks.count": 400, "obstacles.rocks.padding": 6.0})
    pool = ObstaclePool.from_level(level)
    with pytest.raises(LevelError, match=r"obstacles\.rocks: obstacle \d+ of 400"):
        place_obstacles(pool, np.random.default_rng(0))


def test_placement_keeps_the_padding_around_each_new_centre_clear_of_earlier_obstacles():
    pool = ObstaclePool.from_level(evaaa.load_level("2-2"))
    xy, present = place_obstacles(pool, np.random.default_rng(3))
    order = np.flatnonzero(present)
    for i, o in enumerate(order):
        if pool.static[o]:
            continue
        earlier = order[:i]
        gap = np.abs(xy[earlier] - xy[o]) - pool.half[earlier]
        assert (gap.max(axis=1) >= pool.padding[o]).all()


# ------------------------------------------------------------------------------------------------ vertical placement
def test_collision_avoidance_first_frame_shows_the_food_over_the_low_blocks():
    sim = Simulator(evaaa.load_level("collision-avoidance"), 1, ["pixels"], seed=0, threads=1)
    frame = sim.reset()["pixels"][0]
    assert _food_pixels(frame) > 10
    tall = {f"obstacles.b{i:02d}.lift": 0.0 for i in range(1, 12)}  # the blocks resting on the floor, 2.3 m tall
    sim_tall = Simulator(evaaa.load_level("collision-avoidance", tall), 1, ["pixels"], seed=0, threads=1)
    assert _food_pixels(sim_tall.reset()["pixels"][0]) == 0
    sim.close()
    sim_tall.close()


def _tops(sim: Simulator) -> np.ndarray:
    """Height above the floor of the top of each obstacle slot."""
    return sim.obstacles.centre_z() + sim.obstacles.extents[:, 2] / 2


@pytest.mark.parametrize(
    "name, top",
    [
        ("collision-avoidance", 0.55),
        ("goal-manipulation-food-to-water", 0.5),
        ("two-resource-food", 4.0),
        ("risk-taking", 4.0),
        ("y-maze", 4.0),
        ("multi-goal-planning", 4.0),
    ],
)
def test_testbed_blocks_stand_as_high_as_the_originals(name, top):
    sim = Simulator(evaaa.load_level(name), 1, ["collision"], seed=0, threads=1)
    sim.reset()
    blocks = sim.obstacles.kind == "block"
    assert np.allclose(_tops(sim)[blocks], top)
    # the compiled scene agrees: each block's geom reaches that height
    model = sim.model
    for o in np.flatnonzero(blocks):
        body = model.body(f"obs{o}")
        geom = model.geom(body.geomadr[0])
        z = body.pos[2] if model.body_mocapid[body.id] < 0 else sim.datas[0].mocap_pos[model.body_mocapid[body.id], 2]
        assert z + geom.size[2] == pytest.approx(top)
    sim.close()


def test_testbed_walls_stand_4_5_m_and_a_low_block_still_stops_the_rays_and_the_body():
    level = evaaa.load_level("goal-manipulation-food-to-water")
    assert level.arena.wall_height == 4.5
    sim = Simulator(level, 1, ["collision"], seed=0, threads=1)
    sim.reset()
    # face the 0.5 m strip (x -15 ... 5 at y = -7) from 1 m north of it: the rays at the body centre's height see it
    sim.set_agent_pose(0, (-5.0, -5.6), 180.0)
    assert sim.last_obs["collision"][0, 0] == 1.0
    for _ in range(5):
        sim.step(np.array([1]))
    # the strip's north face is at y = -6.5 and the body's half-width 0.5: it stops there (soft contacts give ~0.1)
    assert sim.pos[0, 1] > -6.2
    sim.close()


# ------------------------------------------------------------------------------------------------ reward options
CONF = Path(__file__).resolve().parents[1] / "conf" / "reward"


def reward_option(option: str) -> dict:
    """The level reward fields a reward option (conf/reward/<option>.yaml) sets."""
    data = yaml.safe_load((CONF / f"{option}.yaml").read_text())
    return data.get("overrides", {"name": data["name"]})


def params_for(option: str, level: str = "two-resource-food") -> PhysiologyParams:
    return evaaa.load_level(level, {"reward": reward_option(option)}).physiology_params()


def squared_by_hand(f, w, t, d):
    return -0.01 * (f**2 + w**2 + t**2 + (0.15 * d) ** 2)


# (EVs after the step, end type, action) -> the original's reward by hand for: the original wrapper (what its PPO,
# PPO+LSTM and DreamerV3 trained on), its DQN, and evaaa's default
STEPS = [
    ((-3.0, 4.0, -10.0, 20.0), END_NONE, FORWARD),
    ((-3.0, 4.0, -10.0, 20.0), END_NONE, LEFT),
    ((-3.0, 4.0, -10.0, 20.0), END_NONE, EAT),
    ((-15.5, 0.0, 0.0, 0.0), END_FOOD, FORWARD),
    ((1.0, 2.0, 3.0, 4.0), END_MAX_STEPS, NONE),
    ((1.0, 2.0, 3.0, 4.0), END_RESOURCE, EAT),
    ((0.0, 0.0, 0.0, 100.5), END_DAMAGE, RIGHT),
]


def original_wrapper_by_hand(ev, end, action):
    return -100.0 if end != END_NONE else squared_by_hand(*ev)


def original_dqn_by_hand(ev, end, action):
    r = -10.0 if end != END_NONE else squared_by_hand(*ev) - (0.001 if action in (FORWARD, EAT) else 0.0)
    return min(max(r, -10.0), 10.0)


def evaaa_default_by_hand(ev, end, action):
    return squared_by_hand(*ev) - (100.0 if end in (END_FOOD, END_WATER, END_TEMPERATURE, END_DAMAGE) else 0.0)


@pytest.mark.parametrize(
    "option, by_hand",
    [("original", original_wrapper_by_hand), ("dqn", original_dqn_by_hand), ("squared", evaaa_default_by_hand)],
)
def test_each_reward_option_follows_its_formula_on_hand_computed_steps(option, by_hand):
    p = params_for(option)
    after = np.array([ev for ev, _, _ in STEPS])
    end = np.array([e for _, e, _ in STEPS])
    actions = np.array([a for _, _, a in STEPS])
    r = reward(np.zeros_like(after), after, end, p, costly=(actions == FORWARD) | (actions == EAT))
    expected = [by_hand(ev, e, a) for ev, e, a in STEPS]
    np.testing.assert_allclose(r, expected, rtol=1e-6, atol=1e-6)


def test_the_default_reward_is_unchanged():
    level = evaaa.load_level("1-1")
    r = level.reward
    assert (
        r.name,
        r.terminal_penalty,
        r.terminal_mode,
        r.penalize_truncation,
        r.penalize_consumption,
        r.action_cost,
        r.clip,
    ) == ("squared", -100.0, "add", False, False, 0.0, None)


def test_the_hand_shaped_reward_by_hand():
    p = params_for("shaped")
    odour = np.array([[0.2] * 5 + [0.1] * 5, [0.0] * 10, [1.0] * 10])
    thermal = np.array([[-20.0] * 8, [5.0, -5.0] * 4, [0.0] * 8])
    consumed = np.array([True, False, True])
    collided = np.array([True, False, False])
    end = np.array([END_NONE, END_NONE, END_RESOURCE])
    ev = np.zeros((3, 4))
    r = reward(ev, ev, end, p, olfaction=odour, thermoception=thermal, consumed=consumed, collided=collided)
    expected = [1.5 / 10 - 160 / 1000 + 100 - 1, 0 - 40 / 1000, -100.0]
    np.testing.assert_allclose(r, expected, rtol=1e-6, atol=1e-5)
    with pytest.raises(ValueError, match="shaped"):
        reward(ev, ev, end, p)


def test_clip_bounds_the_reward():
    p = dataclasses.replace(params_for("dqn"), clip=1.0)
    ev = np.array([[15.0, 15.0, 0.0, 0.0]])  # squared drive -4.5
    assert reward(ev, ev, np.array([END_NONE]), p)[0] == pytest.approx(-1.0)


@pytest.mark.parametrize("option, consumed, at_limit", [("original", -100.0, -100.0), ("dqn", -10.0, -10.0)])
def test_the_original_penalty_replaces_the_reward_at_every_end_in_the_env(option, consumed, at_limit):
    # a single-trial consumption: the episode ends ResourceConsumed
    sim = Simulator(
        evaaa.load_level("two-resource-food", {"reward": reward_option(option)}),
        1,
        ["interoception"],
        seed=0,
        threads=1,
    )
    sim.reset()
    slot = int(np.flatnonzero(sim.res_is_food)[0])
    sim.set_agent_pose(0, sim.res_xy[0, slot] - (0.0, 0.9), 0.0)
    _, r, terminated, _, info = sim.step(np.array([EAT]))
    assert terminated[0] and END_TYPES[int(info["end_type"][0, 0])] == "ResourceConsumed"
    assert r[0] == pytest.approx(consumed)
    # the step limit: the last step's reward is the penalty, the ones before are the squared drive
    sim = Simulator(
        evaaa.load_level("two-resource-food", {"reward": reward_option(option), "episode.max_steps": 3}),
        1,
        ["interoception"],
        seed=0,
        threads=1,
    )
    sim.reset()
    rewards = [sim.step(np.array([NONE]))[1][0] for _ in range(3)]
    assert rewards[2] == pytest.approx(at_limit)
    assert -1.0 < rewards[0] < 0.0 and -1.0 < rewards[1] < 0.0
    sim.close()


def test_the_shaped_reward_in_the_env_reads_the_senses_even_when_they_are_not_observed():
    sim = Simulator(
        evaaa.load_level("two-resource-food", {"reward": reward_option("shaped")}),
        1,
        ["interoception"],
        seed=0,
        threads=1,
    )
    sim.reset()
    _, r, *_ = sim.step(np.array([NONE]))
    odour = SENSORS["olfaction"](sim).read(np.array([0]))
    thermal = SENSORS["thermoception"](sim).read(np.array([0]))
    assert odour.sum() > 0
    assert r[0] == pytest.approx(odour.sum() / 10 - np.abs(thermal).sum() / 1000, rel=1e-5)
    sim.close()


# ------------------------------------------------------------------------------------------------ success rules
def _drink_in_risk_taking(**overrides) -> tuple[bool, str]:
    sim = Simulator(evaaa.load_level("risk-taking", overrides), 1, ["interoception"], seed=0, threads=1)
    sim.reset()
    slot = int(np.flatnonzero(sim.res_is_water)[0])
    sim.set_agent_pose(0, sim.res_xy[0, slot] - (0.0, 0.9), 0.0)
    _, _, _, _, info = sim.step(np.array([EAT]))
    sim.close()
    return bool(info["success"][0, 0]), END_TYPES[int(info["end_type"][0, 0])]


def test_risk_taking_success_is_the_food_by_default_and_any_consumption_under_the_papers_rule():
    assert evaaa.load_level("risk-taking").episode.success.rule == "consume"
    assert _drink_in_risk_taking() == (False, "ResourceConsumed")
    assert _drink_in_risk_taking(**{"episode.success": {"rule": "consume_any", "resource": None}}) == (
        True,
        "ResourceConsumed",
    )


def test_a_consume_rule_without_a_resource_is_refused_but_consume_any_needs_none():
    with pytest.raises(LevelError, match="episode.success"):
        evaaa.load_level("risk-taking", {"episode.success": {"rule": "consume", "resource": None}})
    level = evaaa.load_level("risk-taking", {"episode.success.rule": "consume_any"})
    assert level.episode.success.rule == "consume_any"


# ------------------------------------------------------------------------------------------------ predator harm
def _attacked_damage(attack: str) -> tuple[float, bool]:
    """Damage after 40 decisions of standing still, starting at 30, with one predator 10 m away that sees it."""
    overrides = {
        "obstacles.bushes.count": 0,
        "obstacles.rocks.count": 0,
        "obstacles.bonfires.count": 0,
        "predators.p2.count": 0,
        "predators.p3.count": 0,
        "predators.p1.x": [0.0, 0.0],
        "predators.p1.y": [-6.0, -6.0],
        "predators.p1.heading": 0.0,
        "predators.p1.attack": attack,
        "agent.start": "fixed",
        "agent.start_position": [0.0, 4.0],
        "agent.start_heading": 0.0,
    }
    sim = Simulator(evaaa.load_level("4-1", overrides), 1, ["interoception"], seed=0, threads=1)
    sim.reset()
    sim.ev[0, 3] = 30.0
    attacked = False
    for _ in range(40):
        _, _, _, _, info = sim.step(np.array([NONE]))
        attacked |= bool(info["attacked"][0, 0])
    damage = float(sim.ev[0, 3])
    sim.close()
    return damage, attacked


def test_predator_attacks_harm_by_default_and_heal_under_the_originals_rule():
    assert evaaa.load_level("4-1").predators["p1"].attack == "harm"
    harmed, attacked = _attacked_damage("harm")
    assert attacked and harmed > 30.0 + 5.0
    healed, attacked = _attacked_damage("original")
    # the original's sign: each attack takes its 5 points off the damage (passive healing alone is 0.01 a decision)
    assert attacked and healed < 30.0 - 5.0


# ------------------------------------------------------------------------------------------------ smaller items
def test_every_end_type_has_the_originals_name():
    assert set(ORIGINAL_END_TYPES) == set(END_TYPES)
    assert ORIGINAL_END_TYPES["DamageTooHigh"] == "HealthLevelTooLow"
    assert ORIGINAL_END_TYPES["FoodOutOfRange"] == "FoodLevelOutOfRange"
    assert ORIGINAL_END_TYPES["TemperatureOutOfRange"] == "ThermoLevelOutOfRange"


def test_olfaction_clamp_is_a_field():
    near = {
        "agent.start": "fixed",
        "agent.start_position": [0.0, 0.0],
        "resources.food.count": 1,
        "resources.food.x": [0.0, 0.0],
        "resources.food.y": [0.1, 0.1],
        "resources.water.count": 0,
    }
    readings = []
    for clamp in (0.5, 0.05):
        sim = Simulator(
            evaaa.load_level("1-1", {**near, "sensors.olfaction.min_distance": clamp}),
            1,
            ["olfaction"],
            seed=0,
            threads=1,
        )
        readings.append(float(sim.reset()["olfaction"][0, 0]))
        sim.close()
    # the cube's centre is 0.1 m ahead and 0.2 m below the nose: 1/d = 1/0.5 clamped, 1/0.224 not
    assert readings[0] == pytest.approx(0.1 / 0.5, rel=1e-5)
    assert readings[1] == pytest.approx(0.1 / np.hypot(0.1, 0.2), rel=1e-5)


def test_night_fog_follows_evaaas_schedule_or_the_originals_table():
    hours = np.arange(24)
    original = daynight.original_darkness(hours)
    # the original: half the night's fog at 21:00 growing quadratically over six hours, full at 03:00, none by day
    assert original[21] == pytest.approx(0.5)
    assert original[0] == pytest.approx(0.5 + 0.5 * 0.25)
    assert original[2] == pytest.approx(0.5 + 0.5 * (5 / 6) ** 2)
    assert original[3] == 1.0 and (original[7:18] == 0).all()
    assert original[19] == pytest.approx((1 / 3) ** 1.5) and original[5] == pytest.approx((2 / 3) ** 1.5)
    smooth = daynight.darkness(hours)
    assert (smooth[21:] == 1.0).all() and (smooth[:4] == 1.0).all()
    # the level option reaches the renderer: at 23:00 the original's fog is thinner, so it ends farther away
    ends = {}
    for schedule in ("smooth", "original"):
        level = evaaa.load_level(
            "4-2", {"daynight.fog_schedule": schedule, "daynight.random_start": False, "daynight.start_angle": 255.0}
        )  # 23:00
        sim = Simulator(level, 1, ["interoception"], seed=0, threads=1)
        sim.reset()
        sim.daynight.plan(sim.sun_angle[:1])
        ends[schedule] = sim.daynight.light_plan[0][3]
        sim.close()
    assert ends["original"] == pytest.approx(ends["smooth"] / original[23], rel=1e-6)


def test_the_thermal_panel_marks_apples_and_the_pond(tmp_path):
    from matplotlib.figure import Figure

    from evaaa.pictures import plot_thermal

    sim = Simulator(evaaa.load_level("2-2"), 1, ["interoception"], seed=0, threads=1)
    sim.reset()
    ax = Figure().subplots()
    plot_thermal(ax, sim, colorbar=False)
    labels = {t.get_text() for t in ax.get_legend().get_texts()}
    assert {"food (9)", "water (1)"} <= labels  # 9 apples and the pond
    sim.close()


def test_wall_hits_prints_a_range_per_angle(capsys):
    assert load_script("wall_hits").main([]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 5
    low, high = (float(v) for v in lines[1].split()[1:4:2])
    assert 0.5 < low < high < 15.0  # a head-on hit costs a few damage points per decision


# ------------------------------------------------------------------------------------------------ behaviour logs
def _log_rows(path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_the_step_log_writes_one_row_per_decision_with_the_listed_columns(tmp_path):
    sim = Simulator(
        evaaa.load_level("two-resource-food", {"episode.max_steps": 4}), 2, ["interoception"], seed=0, threads=1
    )
    sim.reset()
    path = new_log_path(tmp_path)
    with StepLog(path, policy="scripted") as log:
        log.start("two-resource-food", sim.last_info, seed=0)
        start = sim.pos.copy()
        actions = [
            np.array([FORWARD, LEFT]),
            np.array([FORWARD, NONE]),
            np.array([EAT, RIGHT]),
            np.array([NONE, FORWARD]),
        ]
        for a in actions:
            _, r, term, trunc, info = sim.step(a)
            log.update(a, r, info, term | trunc)
    rows = _log_rows(path)
    assert tuple(rows[0]) == STEP_FIELDS
    for column in ("x", "y", "yaw", "action", "reward", "distance", "collision", "event", "consumed", "end_type"):
        assert column in STEP_FIELDS
    assert len(rows) == 2 * len(actions)  # one row per world and decision
    world0 = [r for r in rows if r["world"] == "0"]
    assert [r["action"] for r in world0] == ["forward", "forward", "eat", "none"]
    assert [int(r["step"]) for r in world0] == [1, 2, 3, 4]
    # a Forward decision moves the body about 1.9 m, and the distance column says so
    first = world0[0]
    moved = np.hypot(float(first["x"]) - start[0, 0], float(first["y"]) - start[0, 1])
    assert float(first["distance"]) == pytest.approx(moved, rel=1e-5) and 1.5 < moved < 2.1
    assert [r for r in rows if r["world"] == "1"][0]["distance"] == "0.0"  # a turn does not move the body
    last = world0[-1]
    assert last["done"] == "True" and last["end_type"] == "MaxStepReached"
    assert last["original_end_type"] == "MaxStepReached" and last["success"] == "False"
    assert all(r["end_type"] == "" for r in world0[:-1])
    # a new log never overwrites an old one
    with pytest.raises(FileExistsError):
        StepLog(path)
    assert new_log_path(tmp_path) != path


def test_evaluate_writes_a_step_log_only_when_asked(tmp_path):
    evaluate = load_script("evaluate")
    out = tmp_path / "eval"
    assert evaluate.main(["policy=oracle", "levels=two-resource-water", "episodes=2", "num_envs=2", f"out={out}"]) == 0
    assert not list(out.glob("steps-*.csv"))
    out = tmp_path / "eval-logged"  # an out= holding an evaluation is refused
    assert (
        evaluate.main(
            ["policy=oracle", "levels=two-resource-water", "episodes=2", "num_envs=2", f"out={out}", "step_log=true"]
        )
        == 0
    )
    logs = list(out.glob("steps-*.csv"))
    assert len(logs) == 1
    rows = _log_rows(logs[0])
    episodes = [r for r in csv.DictReader(open(out / "episodes.csv"))][-2:]
    # every decision of the two counted episodes is in the log (a world may start one more episode afterwards)
    ends = [r for r in rows if r["done"] == "True"]
    assert len(ends) >= 2 and {r["end_type"] for r in ends} == {"ResourceConsumed"}
    assert sorted(int(r["step"]) for r in ends)[:2] == sorted(int(e["steps"]) for e in episodes)
    assert all(r["policy"] == "oracle" and r["level"] == "two-resource-water" for r in rows)
    # the episode rows carry the original's reward statistics and action shares
    for e in episodes:
        shares = [float(e[f"{a}_pct"]) for a in evaaa.ACTION_NAMES]
        assert sum(shares) == pytest.approx(100.0)
        assert float(e["min_reward"]) <= float(e["mean_reward"]) <= float(e["max_reward"])
        assert float(e["mean_reward"]) * int(e["steps"]) == pytest.approx(float(e["return"]), rel=1e-5)


def test_play_writes_a_step_log_when_asked(tmp_path):
    from evaaa.play import PlaySession, PlaySettings

    session = PlaySession(
        PlaySettings(level="two-resource-food", out=tmp_path, step_log=True, overrides={"episode.max_steps": 3})
    )
    try:
        for action in (FORWARD, LEFT, FORWARD):
            session.step(action)
    finally:
        session.close()
    rows = _log_rows(next(tmp_path.glob("steps-*.csv")))
    assert [r["action"] for r in rows] == ["forward", "left", "forward"]
    assert rows[-1]["end_type"] == "MaxStepReached" and rows[0]["participant"] == "anonymous"


def test_an_episode_file_from_before_the_new_columns_is_widened_not_refused(tmp_path):
    path = tmp_path / "episodes.csv"
    tracker = EpisodeTracker(1, "two-resource-water", "random")
    done = {
        "food_eaten": [[0]],
        "water_eaten": [[1]],
        "collision": [[False]],
        "damage_taken": [[0.0]],
        "step_count": [[2]],
        "end_type": [[END_RESOURCE]],
        "success": [[True]],
        "satiation": [[7.0]],
        "hydration": [[-4.0]],
        "temperature": [[0.0]],
        "damage": [[0.0]],
    }
    row = tracker.update([0.5], done, [True], actions=[EAT])[0]
    old = {k: row[k] for k in EPISODE_FIELDS}
    append_rows(path, [old])  # a file as earlier versions wrote it
    append_rows(path, [row])
    rows = read_rows(path)
    assert len(rows) == 2
    assert {k: rows[0][k] for k in EPISODE_FIELDS} == {k: str(v) for k, v in old.items()}
    assert rows[0]["mean_reward"] == "" and float(rows[1]["mean_reward"]) == pytest.approx(0.5)
    assert float(rows[1]["eat_pct"]) == pytest.approx(100.0)
    with pytest.raises(ValueError):
        append_rows(path, [dict(row, unknown=1)])


def test_a_snapshot_from_before_the_new_level_fields_still_restores():
    sim = Simulator(evaaa.load_level("4-1"), 1, ["interoception"], seed=0, threads=1)
    sim.reset()
    sim.step(np.array([FORWARD]))
    snap = sim.snapshot()
    old = snap["level"]
    for group in old["obstacles"].values():
        del group["lift"]
    for group in old["predators"].values():
        del group["attack"]
    for key in ("terminal_mode", "penalize_consumption", "action_cost", "clip"):
        del old["reward"][key]
    del old["daynight"]["fog_schedule"]
    after = sim.step(np.array([LEFT]))[4]["position"].copy()
    sim.restore(snap)
    assert np.array_equal(sim.step(np.array([LEFT]))[4]["position"], after)
    old["agent"]["move_speed"] = 5.0  # another level is still refused
    with pytest.raises(ValueError, match="another level"):
        sim.restore(snap)
    sim.close()
