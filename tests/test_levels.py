"""The training levels 2-1 ... 4-2: obstacles, heat, pond and apples, tree regions, predators, day and night."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

import evaaa
from evaaa import daynight
from evaaa.physiology import END_TYPES
from evaaa.predator import ATTACKING, CHASING, RESTING, NavGrid
from evaaa.sim import EAT, FORWARD, NONE, Simulator

NO_SCRUB = {"obstacles.bushes.count": 0, "obstacles.rocks.count": 0, "obstacles.bonfires.count": 0}
FIXED = {"agent.start": "fixed", "agent.start_position": [0.0, 0.0], "agent.start_heading": 0.0}


def make_sim(level: str, modalities=("interoception",), n: int = 1, seed: int = 0, **overrides) -> Simulator:
    sim = Simulator(evaaa.load_level(level, overrides), n, list(modalities), seed=seed)
    sim.reset()
    return sim


@pytest.mark.parametrize("level", evaaa.LEVELS)
def test_random_rollout_of_500_steps_is_finite(level):
    env = evaaa.make_env(level, num_envs=2, seed=0)
    data = env.rollout(500, break_when_any_done=False)
    for key in ["interoception", "olfaction", "thermoception", "collision", "reward"]:
        values = data["next", key]
        assert torch.isfinite(values).all(), key
    assert data["next", "pixels"].float().std() > 0
    env.close()


# ------------------------------------------------------------------------------------------------ heat and obstacles
def one_bonfire(at=(0.0, 10.0)) -> dict:
    return {
        **NO_SCRUB,
        "obstacles.bonfires.count": 1,
        "obstacles.bonfires.x": [at[0], at[0]],
        "obstacles.bonfires.y": [at[1], at[1]],
        **FIXED,
    }


def test_a_bonfire_warms_the_body_nearby_and_the_cold_cools_it_far_away():
    near = make_sim("2-1", **{**one_bonfire(), "agent.start_position": [0.0, 6.0]})
    far = make_sim("2-1", **{**one_bonfire(), "agent.start_position": [0.0, -40.0]})
    assert near.fields[0].max() > 1000  # a bonfire at 10000 C, smoothed
    for _ in range(30):
        near.step(np.array([NONE]))
        far.step(np.array([NONE]))
    assert near.ev[0, 2] > 1.0
    assert far.ev[0, 2] < -0.5


def test_static_obstacles_stay_and_random_ones_move_between_episodes():
    sim = make_sim("3-1", n=2)
    pool = sim.obstacles
    first_xy, first_present = sim.obs_xy.copy(), sim.obs_present.copy()
    sim.reset()
    static = pool.static
    assert static.sum() == 18  # 3 trees and 15 rock walls
    assert np.array_equal(sim.obs_xy[:, static], first_xy[:, static])
    assert sim.obs_present[:, static].all() and first_present[:, static].all()
    moved = np.linalg.norm(sim.obs_xy[:, ~static] - first_xy[:, ~static], axis=-1)
    assert (moved > 1.0).mean() > 0.9
    # the two worlds of the batch draw their own layouts
    assert not np.allclose(sim.obs_xy[0, ~static], sim.obs_xy[1, ~static])


def test_random_obstacles_keep_their_padding():
    sim = make_sim("2-2")
    placed = sim.obs_present[0] & ~sim.obstacles.static
    xy, half = sim.obs_xy[0, placed], sim.obstacles.half[placed]
    gaps = np.abs(xy[:, None] - xy[None])
    overlap = np.all(gaps < half[:, None] + half[None], axis=-1) & ~np.eye(len(xy), dtype=bool)
    assert not overlap.any()


def test_driving_into_a_rock_adds_damage():
    rock = {
        **NO_SCRUB,
        "obstacles.rocks.count": 1,
        "obstacles.rocks.x": [0.0, 0.0],
        "obstacles.rocks.y": [8.0, 8.0],
        **FIXED,
    }
    sim = make_sim("2-1", modalities=("collision",), **rock)
    total, events = 0.0, 0
    for _ in range(5):
        _, _, _, _, info = sim.step(np.array([FORWARD]))
        total += info["damage_taken"][0, 0]
        events += int(info["collision"][0, 0])
    assert total > 1.0 and events >= 1
    assert sim.pos[0, 1] < 8.0 - 1.5  # stopped at the rock's flank
    assert sim.last_obs["collision"][0, 0] == 1.0  # and the rays see it ahead


# ------------------------------------------------------------------------------------------------ resources
def test_the_pond_never_depletes():
    sim = make_sim("2-2", modalities=("olfaction",), **NO_SCRUB)
    pond = int(np.flatnonzero(sim.pool.kind == "pond")[0])
    centre = sim.res_xy[0, pond].copy()
    # stand south of the pond's centre and walk north into it: the body stops at its edge
    sim.set_agent_pose(0, centre - (0.0, 12.0), 0.0)
    for _ in range(8):
        sim.step(np.array([FORWARD]))
    assert sim.pos[0, 1] < centre[1]  # a pond is solid
    sim.ev[0, 1] = -14.0
    for _ in range(8):
        before = sim.ev[0, 1]
        _, _, _, _, info = sim.step(np.array([EAT]))
        assert info["water_eaten"][0, 0] == 1
        assert sim.ev[0, 1] == pytest.approx(before + 3.0 - 0.009)
    assert sim.res_present[0, pond] and np.array_equal(sim.res_xy[0, pond], centre)
    # it smells far stronger than cubes: the water channels dominate
    smell = sim.last_obs["olfaction"][0]
    assert smell[5] > 1.0 and smell[5] > 10 * smell[0]


def eat_item(sim: Simulator, slot: int) -> dict:
    item = sim.res_xy[0, slot].copy()
    sim.set_agent_pose(0, item - (0.0, 0.9), 0.0)
    return sim.step(np.array([EAT]))[4]


def test_grouped_apples_move_to_a_tree_drawn_anew_once_eaten():
    drawn = set()
    for seed in range(6):
        sim = make_sim("3-2", seed=seed)
        grouped = sim.pool.respawn == "grouped"
        group = sim.active_group[0]
        slots = np.flatnonzero(grouped & (sim.pool.group == group))
        assert set(np.flatnonzero(sim.res_present[0] & grouped)) == set(slots)  # only one tree bears fruit
        old = sim.res_xy[0, slots].copy()
        # apples under one tree may lie close enough for one bite to take several (their EV effect counts once)
        eaten = 0
        while eaten < len(slots):
            left = slots[sim.res_present[0, slots]]
            info = eat_item(sim, left[0])
            eaten += int(info["food_eaten"][0, 0])
            assert info["food_eaten"][0, 0] >= 1
            if eaten < len(slots):  # an eaten apple is gone until the whole tree is bare
                assert sim.res_present[0, slots].sum() == len(slots) - eaten
        new_group = sim.active_group[0]
        new_slots = np.flatnonzero(sim.res_present[0] & grouped)
        assert set(new_slots) == set(np.flatnonzero(grouped & (sim.pool.group == new_group)))
        assert len(new_slots) == 3
        if new_group == group:
            assert not np.allclose(sim.res_xy[0, new_slots], old)
        drawn.add((int(group), int(new_group)))
    assert any(a != b for a, b in drawn)  # another tree is drawn at least sometimes


def test_apples_in_2_2_regrow_under_their_own_tree():
    sim = make_sim("2-2")
    apples = np.flatnonzero(sim.pool.kind == "apple")
    slot = int(apples[0])
    eat_item(sim, slot)
    lo, hi = sim.pool.low[slot], sim.pool.high[slot]
    assert sim.res_present[0, slot]
    assert np.all(sim.res_xy[0, slot] >= lo) and np.all(sim.res_xy[0, slot] <= hi)


# ------------------------------------------------------------------------------------------------ predators
def lone_predator(**extra) -> dict:
    return {
        **NO_SCRUB,
        "predators.p2.count": 0,
        "predators.p3.count": 0,
        "predators.p1.x": [0.0, 0.0],
        "predators.p1.y": [-6.0, -6.0],
        "predators.p1.heading": 0.0,
        **FIXED,
        "agent.start_position": [0.0, 4.0],
        **extra,
    }


def test_a_predator_that_sees_the_agent_chases_it_and_contact_adds_damage():
    sim = make_sim("4-1", **lone_predator())
    preds = sim.predators
    start = preds.xy[0, 0].copy()
    states, damage, attacked = [], 0.0, False
    for _ in range(40):
        _, _, _, _, info = sim.step(np.array([NONE]))
        states.append(int(preds.state[0, 0]))
        damage += info["damage_taken"][0, 0]
        attacked |= bool(info["attacked"][0, 0])
    assert CHASING in states and ATTACKING in states
    assert attacked and damage >= 5.0
    assert np.linalg.norm(preds.xy[0, 0] - start) > 5.0
    # it stops at the agent's side instead of walking through it
    assert np.linalg.norm(preds.xy[0, 0] - sim.pos[0]) > 1.0


def test_a_predator_behind_the_agent_only_chases_what_it_sees():
    # the predator faces south, away from the agent: it does not see it
    sim = make_sim(
        "4-1",
        **lone_predator(
            **{
                "predators.p1.heading": 180.0,
                "predators.p1.search_interval": 1000,
                "predators.p1.max_searching_steps": 1000,
            }
        ),
    )
    for _ in range(20):
        sim.step(np.array([NONE]))
        assert sim.predators.state[0, 0] not in (CHASING, ATTACKING)


def test_predators_walk_around_obstacles():
    blocked = np.zeros((20, 20), dtype=bool)
    blocked[10, 2:18] = True  # a wall across the middle
    grid = NavGrid((20.0, 20.0), blocked)
    start, goal = np.array([-5.0, 0.0]), np.array([5.0, 0.0])
    route = grid.route(start, goal)
    assert len(route) > 2 and np.allclose(route[-1], goal)
    points = np.concatenate([start[None], route])
    for a, b in zip(points[:-1], points[1:]):
        assert grid.clear_line(a, b)
    assert not grid.clear_line(start, goal)


def test_at_night_predators_rest_and_the_field_cools():
    night = {"daynight.random_start": False, "daynight.start_angle": 200.0}  # 19:20
    sim = make_sim("4-2", **lone_predator(**night))
    for _ in range(30):
        sim.step(np.array([NONE]))
        assert sim.predators.state[0, 0] == RESTING
    assert sim.ev[0, 3] == 0.0  # no attack
    # over the evening the whole field's offset falls
    offsets = []
    for _ in range(120):
        sim.step(np.array([NONE]))
        offsets.append(sim.field_offset[0])
    assert offsets[-1] < offsets[0] - 1.0
    assert np.all(np.diff(offsets) <= 1e-9)


def test_day_night_clock():
    assert daynight.hour(np.array([0.0, 90.0, 180.0, 270.0])).tolist() == [6, 12, 18, 0]
    assert daynight.is_night(np.array([90.0, 171.0, 300.0, 355.0])).tolist() == [False, True, True, False]
    offsets = daynight.temperature_offset(np.array([12, 4, 20, 0]), 15.0, -10.0)
    assert np.allclose(offsets, [15.0, -10.0, 2.5, -3.75])
    assert daynight.darkness(np.array([12]))[0] == 0.0 and daynight.darkness(np.array([1]))[0] == 1.0


def test_night_is_darker_than_day_in_the_pixels():
    frames = {}
    for name, angle in [("noon", 90.0), ("midnight", 270.0)]:
        sim = make_sim(
            "4-2",
            modalities=("pixels",),
            **lone_predator(**{"daynight.random_start": False, "daynight.start_angle": angle}),
        )
        frames[name] = sim.last_obs["pixels"][0].astype(float).mean()
    assert frames["midnight"] < 0.6 * frames["noon"]


def test_episode_ends_by_damage_when_predators_keep_attacking():
    sim = make_sim("4-1", **lone_predator())
    sim.ev[0, 3] = 95.0
    for _ in range(60):
        _, _, terminated, _, info = sim.step(np.array([NONE]))
        if terminated[0]:
            break
    assert terminated[0] and END_TYPES[int(info["end_type"][0, 0])] == "DamageTooHigh"


@pytest.mark.parametrize("level,overrides", [("1-1", {"resources.food.count": 300}), ("3-1", {}), ("4-1", {})])
def test_collision_rays_agree_with_mujoco_ray_casting(level, overrides):
    import mujoco

    from evaaa.scene import GROUP_RESOURCE, GROUP_SOLID

    # three worlds: the sensor casts the rays of every world in one batch, each world must read only its own things
    n = 3
    sim = make_sim(level, modalities=("collision",), n=n, seed=3, **overrides)
    sensor = sim.sensors[0]
    rng = np.random.default_rng(0)
    vec, geom, dist = np.zeros((100, 3)), np.zeros(100, np.int32), np.zeros(100)
    groups = np.zeros(6, np.uint8)
    groups[[GROUP_SOLID, GROUP_RESOURCE]] = 1
    seen = 0
    for _ in range(300):
        _, _, terminated, truncated, _ = sim.step(rng.choice([1, 1, 1, 2, 3], n))
        if (terminated | truncated).any():
            sim.reset(terminated | truncated)
        for w in range(n):
            data = sim.datas[w]
            angles = sim.heading_rad[w] + sensor.offsets
            vec[:, 0], vec[:, 1] = np.sin(angles), np.cos(angles)
            mujoco.mj_multiRay(
                sim.model,
                data,
                data.xpos[sim.index.agent_body],
                vec.reshape(-1),
                groups,
                1,
                sim.index.agent_body,
                geom,
                dist,
                None,
                100,
                1.5,
            )
            expected = ((dist >= 0) & (dist <= 1.5)).reshape(10, 10).any(axis=1)
            assert np.array_equal(sim.last_obs["collision"][w] > 0, expected), w
            seen += expected.any()
    assert seen > 90  # the walks did meet things


# ------------------------------------------------------------------------------------------------ python -m evaaa.levels
@pytest.mark.parametrize("name", [evaaa.LEVELS[-1], evaaa.TESTBEDS[0]])
def test_the_printed_level_is_the_resolved_level_and_loads_back_as_itself(name, tmp_path, capsys):
    from evaaa.levels.__main__ import main

    assert main([name, "episode.max_steps=1234"]) == 0
    text = capsys.readouterr().out
    printed = yaml.safe_load(text)
    level = evaaa.load_level(name, {"episode.max_steps": 1234})
    assert printed == level.model_dump(mode="json") and printed["episode"]["max_steps"] == 1234
    # extends applied: the file itself names only what it changes, the print holds every field
    own = yaml.safe_load((Path(evaaa.__file__).parent / "levels" / f"{name}.yaml").read_text())
    assert "extends" not in printed and set(printed) - set(own)
    (tmp_path / "resolved.yaml").write_text(text)  # a standalone level file: the same level again
    assert evaaa.load_level(tmp_path / "resolved.yaml") == level


def test_the_level_printer_lists_levels_and_refuses_bad_input(capsys):
    from evaaa.levels.__main__ import main

    assert main([]) == 0
    listed = capsys.readouterr().out
    assert all(name in listed for name in evaaa.LEVELS + evaaa.TESTBEDS)
    assert main(["1-1", "reward.name=dense"]) == 2
    assert "reward.name: must be one of 'squared'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["1-1", "not-an-override"])
    assert "an override is dotted.path=value, got 'not-an-override'" in capsys.readouterr().err
