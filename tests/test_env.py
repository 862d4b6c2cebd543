"""The environment end to end: specs, the contract's keys, mechanics in the MuJoCo world, seeding, batching."""

from __future__ import annotations

import re
from functools import partial

import numpy as np
import pytest
import torch
from helpers import decode_mp4
from torchrl.envs import SerialEnv, TransformedEnv
from torchrl.envs.transforms import StepCounter
from torchrl.envs.utils import check_env_specs

import evaaa
from evaaa.physiology import END_TYPES
from evaaa.sim import EAT, FORWARD, LEFT, NONE, RIGHT, Simulator

#: An empty, fixed-start version of 1-1 for controlled experiments.
BARE = {
    "agent.start": "fixed",
    "agent.start_position": [0.0, 0.0],
    "agent.start_heading": 0.0,
    "resources.food.count": 1,
    "resources.water.count": 1,
}


def bare_sim(modalities=None, **overrides) -> Simulator:
    sim = Simulator(evaaa.load_level("1-1", {**BARE, **overrides}), 1, modalities, seed=0)
    sim.reset()
    # park both items far from the agent
    sim.place_item(0, 0, (-30.0, -30.0))
    sim.place_item(0, 1, (-30.0, 30.0))
    return sim


def end_name(info) -> str:
    return END_TYPES[int(np.asarray(info["end_type"]).reshape(-1)[0])]


# ------------------------------------------------------------------------------------------------ specs
@pytest.mark.parametrize(
    "level,num_envs,dropped",
    [(name, n, None) for name in evaaa.LEVELS + evaaa.TESTBEDS for n in (1, 4)]
    + [(name, n, m) for name in ("1-1", "1-2") for n in (1, 4) for m in evaaa.MODALITIES],
)
def test_check_env_specs(level, num_envs, dropped):
    modalities = None if dropped is None else [m for m in evaaa.MODALITIES if m != dropped]
    info = dropped is None  # the diagnostics' specs are checked with every sense on; without, no "info" key
    env = evaaa.make_env(level, num_envs=num_envs, seed=0, modalities=modalities, info=info)
    check_env_specs(env, seed=0)
    keys = set(env.observation_spec.keys())
    if dropped is not None:
        assert dropped not in keys
    assert set(modalities or evaaa.MODALITIES) | ({"info"} if info else set()) == keys
    env.close()


def test_contract_shapes_and_dtypes():
    env = evaaa.make_env("1-1", num_envs=2, seed=0, info=True)
    td = env.reset()
    assert td["pixels"].shape == (2, 64, 64, 3) and td["pixels"].dtype == torch.uint8
    for key, dim in [("interoception", 4), ("olfaction", 10), ("thermoception", 8), ("collision", 10)]:
        assert td[key].shape == (2, dim) and td[key].dtype == torch.float32
    assert env.action_spec.n == 5
    out = env.rand_step(td)
    assert out["next", "reward"].shape == (2, 1)
    assert set(out["next", "info"].keys()) >= {
        "position",
        "yaw",
        "satiation",
        "hydration",
        "temperature",
        "damage",
        "food_eaten",
        "water_eaten",
        "collision",
        "damage_taken",
        "step_count",
        "end_type",
    }
    env.close()


def test_info_is_emitted_only_as_asked():
    """No "info" by default (it would cost every step); a list emits just those fields, with the values of the full
    set; an unknown field or a wrong type is refused naming the allowed fields."""
    plain = evaaa.make_env("1-1", num_envs=2, seed=0, modalities=["interoception"])
    assert "info" not in plain.observation_spec.keys() and "info" not in plain.rollout(3).keys(True)
    some = evaaa.make_env("1-1", num_envs=2, seed=0, modalities=["interoception"], info=["end_type", "yaw"])
    full = evaaa.make_env("1-1", num_envs=2, seed=0, modalities=["interoception"], info=True)
    assert list(some.observation_spec["info"].keys()) == ["yaw", "end_type"] and "info=['yaw', 'end_type']" in repr(
        some
    )
    torch.manual_seed(0)
    a = some.rollout(20, break_when_any_done=False)
    torch.manual_seed(0)
    b = full.rollout(20, break_when_any_done=False)
    assert set(a["next", "info"].keys()) == {"yaw", "end_type"}
    assert torch.equal(a["next", "info", "yaw"], b["next", "info", "yaw"])
    assert torch.equal(a["next", "interoception"], b["next", "interoception"])
    for bad, match in [
        (["end_type", "hunger"], r"info names unknown fields \['hunger'\]; allowed: position, yaw"),
        (3, r"info must be True, False or a list of fields of position, yaw"),
    ]:
        with pytest.raises(ValueError, match=match):
            evaaa.make_env("1-1", info=bad)
    for env in (plain, some, full):
        env.close()


def test_resolution_is_configurable():
    env = evaaa.make_env("1-1", seed=0, **{"sensors.vision.width": 32, "sensors.vision.height": 48})
    assert env.reset()["pixels"].shape == (1, 48, 32, 3)
    env.close()


# ------------------------------------------------------------------------------------------------ physiology in the world
def test_ev_rates_over_100_noop_steps():
    sim = bare_sim(["interoception"], **{"thermal.hotspots.count": 0, "thermal.base_temperature": 0.0})
    for _ in range(100):
        obs, *_ = sim.step(np.array([NONE]))
    satiation, hydration, temperature, damage = obs["interoception"][0]
    assert satiation == pytest.approx(-1.35, rel=0.01)
    assert hydration == pytest.approx(-0.9, rel=0.01)
    assert temperature == pytest.approx(0.0, abs=1e-9)  # a field at body temperature neither warms nor cools
    assert damage == 0.0


def test_cold_field_cools_the_body():
    sim = bare_sim(["interoception"], **{"thermal.hotspots.count": 0, "thermal.base_temperature": -20.0})
    for _ in range(100):
        obs, *_ = sim.step(np.array([NONE]))
    expected = -20.0 * (1 - (1 - 8 * 0.0004) ** 100)
    assert obs["interoception"][0, 2] == pytest.approx(expected, rel=1e-6)


@pytest.mark.parametrize("slot,kind,column", [(0, "food", 0), (1, "water", 1)])
def test_eating_an_item_in_the_zone_adds_its_value_and_respawns_it(slot, kind, column):
    sim = bare_sim(["interoception"])
    sim.place_item(0, slot, (0.0, 0.9))  # inside the eating sphere, 0.873 ahead
    before = sim.ev[0].copy()
    _, _, terminated, _, info = sim.step(np.array([EAT]))
    after = sim.ev[0]
    decay = {0: -0.0135, 1: -0.009}[column]
    assert after[column] - before[column] == pytest.approx(3.0 + decay)
    assert info[f"{kind}_eaten"][0, 0] == 1
    assert np.linalg.norm(sim.res_xy[0, slot] - (0.0, 0.9)) > 1e-6  # moved elsewhere (random respawn)
    assert sim.res_present[0, slot]
    lo, hi = sim.pool.low[slot], sim.pool.high[slot]
    assert np.all(sim.res_xy[0, slot] >= lo) and np.all(sim.res_xy[0, slot] <= hi)
    assert not terminated[0]


def test_eating_needs_the_eat_action_and_the_zone():
    sim = bare_sim(["interoception"])
    sim.place_item(0, 0, (0.0, 0.9))
    _, _, _, _, info = sim.step(np.array([NONE]))
    assert info["food_eaten"][0, 0] == 0  # no eat intent
    sim.place_item(0, 0, (0.0, 2.5))
    _, _, _, _, info = sim.step(np.array([EAT]))
    assert info["food_eaten"][0, 0] == 0  # out of reach


def test_the_simulator_offers_every_query_of_the_world_protocol():
    from evaaa.sensors import World

    sim = bare_sim(["interoception"])
    assert isinstance(sim, World)
    members = [m for m in vars(World) if not m.startswith("_")]
    assert {"pos", "heading_rad", "can_eat", "item_distances2", "obs_xy"} <= set(members)
    assert all(hasattr(sim, m) for m in members)


def test_the_worlds_can_eat_query_is_the_test_eating_applies():
    """Planners (the oracle) ask ``Simulator.can_eat``; an Eat decision consumes exactly where it says yes."""
    sim = bare_sim(["interoception"])
    answers = []
    for x, y in [(0.0, 0.9), (0.0, 1.8), (0.0, 1.95), (0.0, 2.1), (0.8, 1.5), (1.2, 1.2), (0.0, -0.9), (0.3, 1.0)]:
        sim.place_item(0, 0, (x, y))
        said = bool(sim.can_eat(0, 0, sim.pos[0], sim.heading_rad[0]))
        _, _, _, _, info = sim.step(np.array([EAT]))
        assert bool(info["food_eaten"][0, 0]) == said, (x, y)
        answers.append(said)
    assert any(answers) and not all(answers)


class WorldOnly:
    """A simulator seen only through what :class:`evaaa.sensors.World` lists: anything else is refused."""

    def __init__(self, sim: Simulator):
        from evaaa.sensors import World

        self._sim = sim
        self._members = {m for m in vars(World) if not m.startswith("_")}

    def __getattr__(self, name):
        if name not in self._members:
            raise AttributeError(f"{name!r} is not part of the World protocol")
        return getattr(self._sim, name)


def test_the_sensors_read_the_world_only_through_the_protocol():
    from evaaa.sensors import SENSORS

    sim = Simulator(evaaa.load_level("4-2"), 2, seed=4, threads=1)  # obstacles, items, predators, day and night
    sim.reset()
    rng = np.random.default_rng(0)
    for _ in range(5):
        obs, *_ = sim.step(rng.integers(0, 5, size=2))
    seen = WorldOnly(sim)
    for key, reading in obs.items():
        assert np.array_equal(SENSORS[key](seen).read(np.arange(2)), reading), key
    with pytest.raises(AttributeError, match="not part of the World protocol"):
        _ = seen.datas
    sim.close()


@pytest.mark.parametrize("name", ["two-resource-food", "predator-day-night"])
def test_the_oracle_reads_the_world_only_through_the_protocol(name):
    from evaaa.agents import OracleAgent

    sims = [Simulator(evaaa.load_level(name), 2, ["interoception"], seed=11, threads=1) for _ in range(2)]
    for sim in sims:
        sim.reset()
    direct, seen, eaten = OracleAgent(), OracleAgent(), 0
    for _ in range(100):
        actions = direct.act(sims[0])
        assert np.array_equal(seen.act(WorldOnly(sims[1])), actions)
        for sim in sims:
            _, _, terminated, truncated, info = sim.step(actions)
            if (terminated | truncated).any():
                sim.reset(terminated | truncated)
        eaten += int(info["food_eaten"].sum())
    assert eaten > 0  # the oracle got to its food (and so planned, and asked can_eat)
    for sim in sims:
        sim.close()


def test_the_worlds_queries_agree_with_its_state():
    sim = Simulator(
        evaaa.load_level("4-2", {"daynight.random_start": False, "daynight.start_angle": 200.0}),
        2,
        ["interoception"],
        seed=3,
        threads=1,
    )
    sim.reset()
    for w in range(2):
        # the floor under the thermal sensors is what they read
        points = sim.sampler.sensor_points(sim.pos[w : w + 1], sim.heading_rad[w : w + 1])[0]
        assert np.array_equal(sim.ground_temperature(w, points), sim.thermal_readings[w])
        # what blocks the body: the placed obstacles and the present solid items, as floor rectangles
        centres, half, heading = sim.obstacle_slices(w)
        blocking = sim.obs_present[w].sum() + (sim.res_present[w] & sim.res_solid).sum()
        assert centres.shape == half.shape == (blocking, 2) and heading.shape == (blocking,)
        assert (half > 0).all()
    assert sim.is_night().all()  # 200 degrees: after sunset
    sim.close()
    sim = Simulator(evaaa.load_level("1-1"), 2, ["interoception"], seed=3, threads=1)
    sim.reset()
    assert not sim.is_night().any()  # no day/night cycle: never night
    sim.close()


def test_a_snapshot_holds_exactly_the_world_state_and_refuses_arrays_it_does_not_know():
    from dataclasses import fields

    from evaaa.state import WorldState

    sim = Simulator(evaaa.load_level("1-1"), 2, ["interoception"], seed=3, threads=1)
    sim.reset()
    sim.step(np.array([FORWARD, EAT]))
    snap = sim.snapshot()
    assert list(snap["arrays"]) == [f.name for f in fields(WorldState)]
    older = {**snap, "arrays": {k: v for k, v in snap["arrays"].items() if k != "triggered"}}
    sim.step(np.array([FORWARD, FORWARD]))
    sim.restore(older)  # a snapshot from before a field existed restores the rest
    assert np.array_equal(sim.pos, snap["arrays"]["pos"])
    foreign = {**snap, "arrays": {**snap["arrays"], "mystery": np.zeros(2)}}
    with pytest.raises(ValueError, match=r"\['mystery'\] are not part of a world's state"):
        sim.restore(foreign)
    sim.close()


@pytest.mark.parametrize(
    "column,value,end",
    [
        (0, -14.999, "FoodOutOfRange"),
        (0, 14.5, "FoodOutOfRange"),
        (1, -14.995, "WaterOutOfRange"),
        (2, -14.99, "TemperatureOutOfRange"),
        (3, 99.999, "DamageTooHigh"),
    ],
)
def test_an_ev_pushed_past_its_bound_terminates_with_its_end_type(column, value, end):
    sim = bare_sim(["interoception"], **{"thermal.hotspots.count": 0})
    sim.ev[0, column] = value
    if column == 0 and value > 0:  # overeating: eat a cube worth 3
        sim.place_item(0, 0, (0.0, 0.9))
        action = EAT
    elif column == 3:  # damage grows only by collisions; push it from 99.999 by hitting a wall
        sim.set_agent_pose(0, (0.0, 46.0), 0.0)
        action = FORWARD
    else:
        action = NONE
    for _ in range(3):
        _, reward, terminated, truncated, info = sim.step(np.array([action]))
        if terminated[0]:
            break
    assert terminated[0] and not truncated[0]
    assert end_name(info) == end
    assert reward[0] < -99  # the terminal penalty


def test_truncation_at_max_steps_is_not_termination():
    env = evaaa.make_env("1-1", seed=0, info=["end_type"], **{"episode.max_steps": 5})
    td = env.reset()
    for step in range(1, 6):
        td["action"] = torch.tensor([NONE])
        td = env.step(td)
        nxt = td["next"]
        assert nxt["truncated"].item() == (step == 5)
        assert not nxt["terminated"].item()
        assert nxt["done"].item() == (step == 5)
        td = td["next"].clone()
    assert END_TYPES[nxt["info", "end_type"].item()] == "MaxStepReached"
    assert nxt["reward"].item() > -1.0  # no terminal penalty on truncation by default
    env.close()


def test_reward_equals_its_terms():
    env = evaaa.make_env("1-1", seed=3, info=True)
    data = env.rollout(60)
    info = data["next", "info"]
    expected = -0.01 * (
        info["satiation"] ** 2 + info["hydration"] ** 2 + info["temperature"] ** 2 + (0.15 * info["damage"]) ** 2
    )
    torch.testing.assert_close(data["next", "reward"], expected)
    env.close()


# ------------------------------------------------------------------------------------------------ collisions
def test_a_full_speed_wall_hit_adds_damage():
    sim = bare_sim(["collision"])
    sim.set_agent_pose(0, (0.0, 44.0), 0.0)  # 6 m from the north wall, facing it
    damages, events = [], []
    for _ in range(4):
        _, _, _, _, info = sim.step(np.array([FORWARD]))
        damages.append(info["damage_taken"][0, 0])
        events.append(info["collision"][0, 0])
    assert damages[0] == 0.0 and damages[1] == 0.0  # still in the open
    assert 1.0 < max(damages) < 15.0  # a few damage points, as in the original
    assert any(events)
    assert sim.pos[0, 1] < 50.0 - 0.5 + 0.25  # the wall stopped the body (soft contacts yield a little)
    # the hit does not bounce the agent back: standing still next to the wall costs nothing more
    y = sim.pos[0, 1]
    for _ in range(5):
        _, _, _, _, info = sim.step(np.array([NONE]))
        assert info["damage_taken"][0, 0] < 1e-3
    assert abs(sim.pos[0, 1] - y) < 0.2  # only the soft contact relaxing, no rebound


def test_walking_in_the_open_costs_no_damage():
    sim = bare_sim(["collision"])
    total = 0.0
    for action in [FORWARD, FORWARD, LEFT, FORWARD, RIGHT, RIGHT, FORWARD, FORWARD, EAT, FORWARD]:
        _, _, _, _, info = sim.step(np.array([action]))
        total += info["damage_taken"][0, 0]
        assert not info["collision"][0, 0]
    assert total == 0.0
    assert np.linalg.norm(sim.pos[0]) > 10.0


def test_one_forward_decision_travels_about_1_9_m():
    sim = bare_sim(["interoception"])
    sim.step(np.array([FORWARD]))
    assert sim.pos[0, 1] == pytest.approx(1.9, abs=0.1)
    assert abs(sim.pos[0, 0]) < 1e-6


def test_turns_are_24_degrees():
    sim = bare_sim(["interoception"])
    _, _, _, _, info = sim.step(np.array([RIGHT]))
    assert info["yaw"][0, 0] == pytest.approx(24.0)
    _, _, _, _, info = sim.step(np.array([LEFT]))
    _, _, _, _, info = sim.step(np.array([LEFT]))
    assert info["yaw"][0, 0] == pytest.approx(336.0)


# ------------------------------------------------------------------------------------------------ senses
def _centre_colour(sim) -> np.ndarray:
    frame = sim.render_eye(np.arange(1))[0].astype(int)
    h, w = frame.shape[:2]
    return frame[h // 2 - 4 : h // 2 + 4, w // 2 - 4 : w // 2 + 4].reshape(-1, 3).mean(axis=0)


def test_a_food_cube_ahead_makes_the_centre_red_and_water_blue():
    sim = bare_sim(["pixels"])
    sim.place_item(0, 0, (0.0, 2.0))
    r, g, b = _centre_colour(sim)
    assert r > 2 * g and r > 2 * b
    sim.place_item(0, 0, (-30.0, -30.0))
    sim.place_item(0, 1, (0.0, 2.0))
    r, g, b = _centre_colour(sim)
    assert b > 2 * r and b > 2 * g


def test_pixels_change_when_the_agent_turns():
    env = evaaa.make_env("1-1", seed=0, modalities=["pixels"])
    td = env.reset()
    first = td["pixels"].clone()
    td["action"] = torch.tensor([RIGHT])
    after = env.step(td)["next", "pixels"]
    assert (first.float() - after.float()).abs().mean() > 1.0
    env.close()


def test_olfaction_smells_food_and_water_apart_and_closer_is_stronger():
    sim = bare_sim(["olfaction"])
    sim.place_item(0, 0, (0.0, 10.0))
    far = sim.last_obs["olfaction"][0].copy()
    sim.place_item(0, 0, (0.0, 3.0))
    near = sim.last_obs["olfaction"][0].copy()
    assert np.all(near[:5] > far[:5]) and np.allclose(near[:5], near[0])
    assert near[5] < near[0]  # the water cube is far away
    sim.place_item(0, 1, (3.0, 0.0))
    both = sim.last_obs["olfaction"][0]
    assert both[5] > near[5]


def test_thermal_sensors_turn_with_the_agent():
    sim = bare_sim(["thermoception"], **{"thermal.hotspots.count": 0, "thermal.sigma": 0.0})
    sim.fields[0, :, :] = 0.0
    sim.fields[0, 50, 51] = 40.0  # the cell just north of the agent at (0, 0)... (cells are 1 m; (0,0) is cell 50,50)
    sim.set_agent_pose(0, (0.5, 0.5), 0.0)
    f, b = sim.last_obs["thermoception"][0][:2]
    assert (f, b) == (40.0, 0.0)
    sim.set_agent_pose(0, (0.5, 2.5), 180.0)
    f, b = sim.last_obs["thermoception"][0][:2]
    assert (f, b) == (40.0, 0.0)


def test_collision_rays_see_a_wall_ahead_only_when_close():
    sim = bare_sim(["collision"])
    sim.set_agent_pose(0, (0.0, 49.0), 0.0)  # wall 1 m ahead of the centre
    sectors = sim.last_obs["collision"][0]
    assert sectors[0] == 1.0 and sectors[9] == 1.0  # the two sectors either side of straight ahead
    assert sectors[4] == 0.0 and sectors[5] == 0.0  # nothing behind
    sim.set_agent_pose(0, (0.0, 0.0), 0.0)
    assert not sim.last_obs["collision"][0].any()


def test_observations_are_not_constant():
    env = evaaa.make_env("1-1", seed=1)
    data = env.rollout(50)
    for key in ["pixels", "interoception", "olfaction", "thermoception"]:
        values = data["next", key].float()
        assert values.std(dim=1).sum() > 0, key
    env.close()


# ------------------------------------------------------------------------------------------------ seeding and batching
def _trajectory(seed, steps=200):
    env = evaaa.make_env("1-1", num_envs=2, seed=seed)
    gen = torch.Generator().manual_seed(123)
    actions = torch.randint(0, 5, (steps, 2), generator=gen)
    td = env.reset()
    out = []
    for t in range(steps):
        td["action"] = actions[t]
        step, td = env.step_and_maybe_reset(td)
        out.append(step["next"].exclude("info").clone())
    env.close()
    return torch.stack(out)


def test_same_seed_same_trajectory_different_seed_different():
    a, b, c = _trajectory(7), _trajectory(7), _trajectory(8)
    assert (a == b).all()
    assert torch.equal(a["pixels"], b["pixels"])
    assert not torch.equal(a["pixels"], c["pixels"])
    assert not torch.equal(a["interoception"], c["interoception"])


def test_layouts_are_redrawn_each_episode_without_recompiling():
    env = evaaa.make_env("1-1", seed=0)
    model = env.sim.model
    env.reset()
    first = env.sim.res_xy[0].copy()
    env.reset()
    assert not np.allclose(first, env.sim.res_xy[0])
    assert env.sim.model is model
    env.close()


def test_partial_reset_only_touches_masked_worlds():
    env = evaaa.make_env("1-1", num_envs=3, seed=0, info=["step_count"])
    td = env.reset()
    for _ in range(5):
        td["action"] = torch.full((3,), FORWARD)
        td = env.step(td)["next"].clone()
    before = td["info", "step_count"].clone()
    pix = td["pixels"].clone()
    td["_reset"] = torch.tensor([[False], [True], [False]])
    out = env.reset(td)
    assert out["info", "step_count"].flatten().tolist() == [before[0].item(), 0, before[2].item()]
    assert torch.equal(out["pixels"][0], pix[0]) and torch.equal(out["pixels"][2], pix[2])
    env.close()


def test_worlds_in_a_batch_are_independent():
    env = evaaa.make_env("1-1", num_envs=2, seed=0, info=["position"])
    td = env.reset()
    assert not torch.equal(td["pixels"][0], td["pixels"][1])
    td["action"] = torch.tensor([FORWARD, NONE])
    nxt = env.step(td)["next"]
    moved = (nxt["info", "position"] - td["info", "position"]).norm(dim=-1)
    assert moved[0] > 1.5 and moved[1] < 1e-6
    env.close()


def test_serial_transformed_and_collector():
    from torchrl.collectors import Collector

    serial = SerialEnv(2, lambda: evaaa.make_env("1-2", seed=0))
    data = serial.rollout(5)
    assert data["next", "pixels"].shape == (2, 1, 5, 64, 64, 3)
    serial.close()
    env = TransformedEnv(evaaa.make_env("1-1", seed=0), StepCounter())
    check_env_specs(env, seed=0)
    collector = Collector(env, policy=None, frames_per_batch=16, total_frames=32)
    batches = [b for b in collector]
    collector.shutdown()
    assert len(batches) == 2 and batches[0]["next", "pixels"].shape[-3:] == (64, 64, 3)


def test_parallel_env():
    from torchrl.envs import ParallelEnv

    env = ParallelEnv(2, partial(evaaa.make_env, "1-1", seed=0), mp_start_method="spawn")
    check_env_specs(env, seed=0)
    data = env.rollout(10)
    assert data["next", "interoception"].shape == (2, 1, 10, 4)
    env.close()


# ------------------------------------------------------------------------------------------------ bad input
def test_bad_input_gives_clear_errors():
    with pytest.raises(evaaa.LevelError, match="available: 1-1"):
        evaaa.make_env("9-9")
    with pytest.raises(evaaa.LevelError, match="allowed: .*move_speed"):
        evaaa.make_env("1-1", **{"agent.speed": 3})
    with pytest.raises(ValueError, match="unknown modality 'smell'"):
        evaaa.make_env("1-1", modalities=["smell"])
    with pytest.raises(ValueError, match="num_envs must be a positive integer"):
        evaaa.make_env("1-1", num_envs=0)
    env = evaaa.make_env("1-1", seed=0, modalities=["interoception"])
    td = env.reset()
    td["action"] = torch.tensor([7])
    with pytest.raises(ValueError, match="0..4"):
        env.step(td)
    td["action"] = torch.tensor([1.5])
    with pytest.raises(ValueError, match="integer"):
        env.step(td)
    env.close()


def test_snapshot_restore_continues_exactly():
    env = evaaa.make_env("1-1", num_envs=2, seed=5)
    actions = torch.randint(0, 5, (60, 2), generator=torch.Generator().manual_seed(0))
    td = env.reset()
    for t in range(20):
        td["action"] = actions[t]
        _, td = env.step_and_maybe_reset(td)
    snap = env.snapshot()
    saved_td = td.clone()

    def run(td):
        out = []
        for t in range(20, 60):
            td["action"] = actions[t]
            step, td = env.step_and_maybe_reset(td)
            out.append(step["next"].clone())
        return torch.stack(out)

    first = run(td)
    env.restore(snap)
    second = run(saved_td)
    assert (first == second).all()
    other = evaaa.make_env("1-2", num_envs=2, seed=5)
    with pytest.raises(ValueError, match="another level"):
        other.restore(snap)
    env.close()
    other.close()


def test_a_snapshot_with_predators_is_plain_data_and_continues_exactly_in_another_env():
    from evaaa_baselines.checkpoint import from_plain, to_plain

    def make():
        return evaaa.make_env("4-2", num_envs=2, seed=3, modalities=["interoception", "collision"])

    actions = torch.randint(0, 5, (160, 2), generator=torch.Generator().manual_seed(1))

    def run(env, td, steps):
        out = []
        for t in steps:
            td["action"] = actions[t]
            step, td = env.step_and_maybe_reset(td)
            out.append(step["next"].clone())
        return torch.stack(out), td

    env = make()
    _, td = run(env, env.reset(), range(80))
    start = env.sim.predators.xy.copy()
    # what a checkpoint holds: plain data only (the predators' navigation grids and patrol areas as arrays)
    stored = from_plain(to_plain(env.snapshot()))
    saved_td = td.clone()
    first, _ = run(env, td, range(80, 160))
    assert not np.allclose(env.sim.predators.xy, start)  # the predators moved on their routes
    other = make()
    other.reset()
    other.restore(stored)
    second, _ = run(other, saved_td, range(80, 160))
    assert (first == second).all()
    env.close()
    other.close()


def test_closing_one_env_leaves_the_others_pictures_intact():
    keep = evaaa.make_env("1-1", seed=0, modalities=["pixels"])
    before = keep.reset()["pixels"].clone()
    other = evaaa.make_env("1-2", seed=1, modalities=["pixels"])
    other.reset()
    assert not other.is_closed
    other.close()
    assert other.is_closed
    keep.set_seed(0)
    assert torch.equal(keep.reset()["pixels"], before)
    keep.close()


@pytest.mark.parametrize("level", ["1-1", "4-2"])
def test_threads_give_the_same_trajectories(level):
    def trajectory(threads: int):
        env = evaaa.EvaaaEnv(level, num_envs=3, seed=3, threads=threads)
        assert env.sim.threads == threads and env.sim._renderer.threaded is (threads > 1)
        td = env.rollout(40, policy=lambda td: td.set("action", torch.full((3,), FORWARD)), break_when_any_done=False)
        env.close()
        return td["next"]

    direct = trajectory(1)
    assert direct["pixels"].float().std() > 0
    for threads in (2, 3):  # 3 worlds in shares of 1 and 2, and one each
        shared = trajectory(threads)
        assert (shared == direct).all(), f"threads={threads}"


@pytest.mark.parametrize("level", ["1-1", "4-2"])
def test_one_world_with_a_helper_gives_the_same_trajectory(level):
    # one world, threads=2: the frame is drawn on the calling thread while a helper does the EVs and other senses
    def trajectory(threads: int):
        env = evaaa.EvaaaEnv(level, num_envs=1, seed=5, threads=threads, info=True)
        assert env.sim.threads == threads and not env.sim._renderer.threaded
        generator = torch.Generator().manual_seed(0)
        td = env.rollout(
            150,
            policy=lambda td: td.set("action", torch.randint(0, 5, (1,), generator=generator)),
            break_when_any_done=False,
        )
        used_helper = env.sim.workers.started
        env.close()
        return td, used_helper

    direct, used = trajectory(1)
    assert not used
    helped, used = trajectory(2)
    assert used
    assert list(helped["next"].keys()) == list(direct["next"].keys())  # pixels first, as without the helper
    assert (helped == direct).all()
    assert direct["next", "info", "satiation"].std() > 0  # the EVs moved


def test_before_draw_runs_once_the_scene_is_ready():
    from evaaa.render import BatchRenderer

    sim = Simulator(evaaa.load_level("1-1"), 2, seed=2, threads=1)
    sim.reset()
    calls = []
    sim._renderer._scene.ngeom = 0  # forget the scene of the reset's frames
    hooked = sim.render_eye(np.arange(2), before_draw=lambda: calls.append(sim._renderer._scene.ngeom))
    assert len(calls) == 1 and calls[0] > 0  # once, with the first frame's scene already built
    assert np.array_equal(hooked, sim.render_eye(np.arange(2)))
    threaded = BatchRenderer(sim.model, 16, 16, threaded=True)
    with pytest.raises(ValueError, match="before_draw is for renderers that draw on the calling thread"):
        threaded.render(sim.datas[:1], sim.index.eye_camera, before_draw=lambda: None)
    threaded.close()
    sim.close()


def test_a_renderer_freed_in_the_middle_of_a_frame_leaves_the_frame_intact():
    # the garbage collector frees an unclosed renderer in whichever thread it runs, perhaps between the calls that
    # draw another renderer's frame: that frame must still be drawn in its own context
    from evaaa.render import BatchRenderer
    from evaaa.scene import GROUP_AGENT

    sim = Simulator(evaaa.load_level("1-1"), 1, seed=0, threads=1)
    sim.reset()
    plain = sim.render_eye(np.arange(1))
    other = BatchRenderer(sim.model, 32, 32)

    def free_other(row, scene, context):  # called after the scene is built, before it is drawn
        other.close()

    interrupted = BatchRenderer(sim.model, 64, 64, hidden_groups=(GROUP_AGENT,), adjust=free_other)
    frame = interrupted.render(sim.datas, sim.index.eye_camera)
    assert other._gl is None  # it was freed, mid-frame
    assert np.array_equal(frame, plain)
    interrupted.close()
    sim.close()


def test_threads_light_each_world_by_its_own_hour():
    # the render threads draw shares of the batch: each world must still get its own sun, sky and fog
    def frames(threads: int) -> np.ndarray:
        sim = Simulator(evaaa.load_level("4-2"), 3, seed=1, threads=threads)
        sim.reset()
        sim.sun_angle[:] = (10.0, 100.0, 250.0)  # morning, noon, night
        out = sim.render_eye(np.arange(3))
        sim.close()
        return out

    direct = frames(1)
    assert direct[2].mean() < direct[1].mean()  # the night world is darker
    assert np.array_equal(frames(2), direct)


def test_night_fog_density_reaches_the_pixels():
    # MuJoCo passes a context's fog range to OpenGL only when the context is made: each foggy frame passes it again
    def night_frame(density: float, first: int | None = None) -> np.ndarray:
        sim = Simulator(evaaa.load_level("4-2", {"daynight.night_fog_density": density}), 2, seed=1, threads=1)
        sim.reset()
        sim.sun_angle[:] = 250.0  # the depth of night
        if first is not None:  # the context drew another world first
            sim.render_eye(np.array([first]))
        frame = sim.render_eye(np.array([1]))[0].astype(float)
        sim.close()
        return frame

    thin, thick = night_frame(0.02), night_frame(2.0)
    fog = np.array([0.02, 0.02, 0.05]) * 255
    assert np.abs(thick - fog).mean() < 0.5 * np.abs(thin - fog).mean()  # thick fog: the picture is the fog
    assert np.array_equal(night_frame(0.02, first=0), thin)


@pytest.mark.parametrize("serial", ["1", "0"])
def test_render_threads_take_turns_to_draw_when_told(monkeypatch, serial):
    """With EVAAA_SERIAL_DRAW=1 two render threads of one process never draw at once (Mesa's llvmpipe crashed
    doing so, rarely); by default they do (the check sees both at once then, so it can fail).  Frames are the
    same either way."""
    import threading
    import time

    from evaaa import render

    monkeypatch.setenv("EVAAA_SERIAL_DRAW", serial)
    inside, most, guard = [0], [0], threading.Lock()
    draw = render.mujoco.mjr_render

    def watched(*args):
        with guard:
            inside[0] += 1
            most[0] = max(most[0], inside[0])
        time.sleep(0.002)  # a wide window, the GIL released, for the other thread to come in
        draw(*args)
        with guard:
            inside[0] -= 1

    monkeypatch.setattr(render.mujoco, "mjr_render", watched)
    frames = {}
    for threads in (2, 1):
        env = evaaa.make_env("1-1", num_envs=4, seed=0, modalities=["pixels"], threads=threads)
        assert isinstance(env.sim._renderer, render.SplitRenderer) == (threads == 2)
        torch.manual_seed(0)
        frames[threads] = env.rollout(10, break_when_any_done=False)["next", "pixels"]
        env.close()
        if threads == 2:
            assert most[0] == (1 if serial == "1" else 2)
    assert torch.equal(frames[2], frames[1])


def test_threads_setting(monkeypatch):
    from evaaa import render, sim

    monkeypatch.delenv("EVAAA_THREADS", raising=False)
    monkeypatch.setattr(sim, "usable_cores", lambda: 2)
    assert sim.default_threads() == 2
    env = evaaa.make_env("1-1", num_envs=2, modalities=["pixels"])
    assert env.sim.threads == 2 and isinstance(env.sim._renderer, render.SplitRenderer)
    env.close()
    env = evaaa.make_env("1-1", num_envs=1)  # one world: a helper beside the frame, one GL context
    assert env.sim.threads == 2 and isinstance(env.sim._renderer, render.BatchRenderer)
    env.close()
    env = evaaa.make_env("1-1", num_envs=1, modalities=["olfaction", "collision"])  # no frame to work beside
    assert env.sim.threads == 1
    env.close()
    monkeypatch.setattr(sim, "usable_cores", lambda: 1)
    assert sim.default_threads() == 1
    monkeypatch.setenv("EVAAA_THREADS", "3")
    assert sim.default_threads() == 3
    env = evaaa.make_env("1-1", num_envs=2, modalities=["pixels"])
    assert env.sim.threads == 2  # never more shares than worlds
    env.close()
    env = evaaa.make_env("1-1", num_envs=1, modalities=["pixels"])
    assert env.sim.threads == 2  # one world uses one helper at most
    env.close()
    for bad in ("some", "0"):
        monkeypatch.setenv("EVAAA_THREADS", bad)
        with pytest.raises(ValueError, match="EVAAA_THREADS must be an integer >= 1"):
            sim.default_threads()
    monkeypatch.delenv("EVAAA_THREADS")
    with pytest.raises(ValueError, match="threads must be an integer >= 1"):
        evaaa.make_env("1-1", num_envs=2, threads=0)


# ------------------------------------------------------------------------------------------------ level edge cases
def test_a_level_without_resources_runs_with_a_random_start():
    env = evaaa.make_env(
        "1-2",
        seed=0,
        modalities=["interoception", "olfaction", "collision"],
        **{"resources.food.count": 0, "resources.water.count": 0, "agent.start": "random"},
    )
    td = env.rollout(20, break_when_any_done=False)
    assert td["next", "interoception"].isfinite().all()
    assert (td["next", "olfaction"] == 0).all()  # nothing to smell
    env.close()


def test_a_steep_collision_damage_rule_saturates_at_its_cap_without_overflow():
    from evaaa.physiology import contact_damage

    assert contact_damage(1e4, 0.0002, 5.0, 60.0, 80.0) == 80.0  # exp(49700) would overflow
    assert contact_damage(60.0, 0.0002, 5.0, 60.0, 80.0) == pytest.approx(0.0002)
    assert contact_damage(1e4, 0.0, 5.0, 60.0, 80.0) == 0.0
    assert contact_damage(-1e4, 0.0002, 5.0, 60.0, 80.0) == 0.0
    # the default rule is unchanged where it does not saturate
    assert contact_damage(100.0, 0.0002, 0.07, 60.0, 80.0) == pytest.approx(0.0002 * np.exp(0.07 * 40.0))
    # pressing into a wall for a while with a steep rule: every substep's damage stays at most the cap
    sim = bare_sim(["collision"], **{"agent.collision_damage.rate": 5.0, "physiology.bounds.damage": [0, 1e5]})
    sim.set_agent_pose(0, (0.0, 46.0), 0.0)
    for _ in range(30):
        _, reward, _, _, info = sim.step(np.array([FORWARD]))
        assert np.isfinite(reward).all()
        assert 0.0 <= info["damage_taken"][0, 0] <= 80.0 * 5
    assert np.isfinite(sim.ev).all()


@pytest.mark.parametrize(
    "overrides, field",
    [
        ({"agent.mass": 1e-20}, "agent.mass"),
        ({"obstacles.bushes.scale": [[1e-12, 1e-12], [1, 1], [1, 1]]}, "obstacles.bushes"),
    ],
)
def test_a_scene_mujoco_refuses_is_a_level_error_naming_the_field(overrides, field):
    with pytest.raises(evaaa.LevelError, match=rf"invalid level '2-1':\n  {re.escape(field)}.*MuJoCo cannot build it"):
        evaaa.make_env("2-1", modalities=["interoception"], **overrides)


# ------------------------------------------------------------------------------------------------ API hygiene
def test_a_missing_or_one_hot_action_gets_a_clear_error():
    env = evaaa.make_env("1-1", num_envs=2, seed=0, modalities=["interoception"], info=["step_count"])
    td = env.reset()
    with pytest.raises(ValueError, match=r"no 'action' entry: set td\['action'\] to an integer tensor of shape \(2,\)"):
        env.step(td.clone())
    td["action"] = torch.nn.functional.one_hot(torch.tensor([1, 3]), 5)
    with pytest.raises(ValueError, match=r"shape \(2, 5\), like a one-hot encoding.*action\.argmax\(-1\)"):
        env.step(td)
    td["action"] = torch.tensor([[1, 3], [0, 0]])
    with pytest.raises(ValueError, match=r"got shape \(2, 2\)"):
        env.step(td)
    td["action"] = torch.tensor([1, 3])
    assert env.step(td)["next", "info", "step_count"].tolist() == [[1], [1]]
    env.close()


def test_stepping_a_closed_env_is_an_error_and_rebuilds_nothing():
    env = evaaa.make_env("1-1", seed=0, modalities=["pixels"])
    td = env.reset()
    td["action"] = torch.tensor([1])
    env.close()
    with pytest.raises(RuntimeError, match=r"EvaaaEnv \(1-1\) was closed; make a new one"):
        env.step(td)
    with pytest.raises(RuntimeError, match="was closed"):
        env.reset()
    assert env.sim._renderer is None


def test_repr_says_what_the_env_is():
    env = evaaa.make_env("2-1", num_envs=3, seed=4, modalities=["olfaction", "pixels"], threads=1)
    assert repr(env) == (
        "EvaaaEnv(level='2-1', num_envs=3, modalities=['pixels', 'olfaction'], info=False, device=cpu, "
        "seed=4, worlds=train, threads=1)"
    )
    env.close()


def test_the_collision_spec_is_bounded_zero_to_one():
    env = evaaa.make_env("1-1", seed=0, modalities=["collision"])
    spec = env.observation_spec["collision"]
    assert (spec.space.low == 0).all() and (spec.space.high == 1).all()
    env.close()


def test_mujoco_warnings_go_to_logging_not_to_a_file(tmp_path, monkeypatch, caplog):
    import mujoco

    monkeypatch.chdir(tmp_path)
    model = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body><freejoint/><geom size="1"/></body></worldbody></mujoco>'
    )
    data = mujoco.MjData(model)
    data.qpos[0] = np.nan
    with caplog.at_level("WARNING", logger="mujoco"):
        mujoco.mj_step(model, data)
    assert any("MuJoCo: Nan, Inf or huge value in QPOS" in r.getMessage() for r in caplog.records)
    assert list(tmp_path.iterdir()) == []  # no MUJOCO_LOG.TXT


def test_a_torchrl_video_recorder_writes_a_playable_mp4(tmp_path):
    from torchrl.envs import TransformedEnv
    from torchrl.record import VideoRecorder

    from evaaa.video import VideoLogger

    logger = VideoLogger(tmp_path / "videos", fps=10)
    env = TransformedEnv(
        evaaa.make_env("1-1", seed=0, modalities=["pixels"]), VideoRecorder(logger, tag="eye", in_keys=["pixels"])
    )
    td = env.rollout(12, break_when_any_done=False)
    env.transform.dump()
    env.close()
    assert logger.written == [tmp_path / "videos" / "eye_0.mp4"]
    frames = decode_mp4(logger.written[0])
    assert len(frames) == 13  # the reset frame and one per step
    last = td["next", "pixels"][0, -1].numpy()  # world 0, last step
    assert frames[-1].shape == last.shape and np.abs(frames[-1].astype(int) - last).mean() < 20
