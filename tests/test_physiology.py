"""Analytic checks of evaaa.physiology (EV dynamics, end types, rewards) against SPEC.md sections 2 and 3.

Nothing here touches MuJoCo: every quantity is computed by hand from the level's numbers.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from evaaa.level_files import load_level
from evaaa.physiology import (
    DAMAGE,
    DEATHS,
    END_DAMAGE,
    END_FOOD,
    END_MAX_STEPS,
    END_NONE,
    END_RESOURCE,
    END_TEMPERATURE,
    END_TYPES,
    END_WATER,
    HYDRATION,
    REWARDS,
    SATIATION,
    TEMPERATURE,
    PhysiologyParams,
    end_types,
    reward,
    step_evs,
)

N_SENSORS = 8


@pytest.fixture(scope="module")
def params() -> PhysiologyParams:
    return load_level("1-1").physiology_params()


def _step(ev, p, *, food=False, water=False, thermal_sum=0.0, damage=0.0):
    """One decision for a batch; scalar inputs are broadcast over the worlds."""
    ev = np.asarray(ev, dtype=np.float64)
    n = len(ev)
    return step_evs(
        ev,
        p,
        food_eaten=np.broadcast_to(np.asarray(food, dtype=bool), (n,)).copy(),
        water_eaten=np.broadcast_to(np.asarray(water, dtype=bool), (n,)).copy(),
        thermal_sum=np.broadcast_to(np.asarray(thermal_sum, dtype=np.float64), (n,)).copy(),
        damage_taken=np.broadcast_to(np.asarray(damage, dtype=np.float64), (n,)).copy(),
    )


def _uniform_field_sum(ev: np.ndarray, field_temperature: float) -> np.ndarray:
    """sum_i (T_i - t) over 8 sensors that all read ``field_temperature``."""
    sensors = np.full((len(ev), N_SENSORS), field_temperature)
    return (sensors - ev[:, TEMPERATURE : TEMPERATURE + 1]).sum(axis=1)


def _ends(ev, p, *, consumed=False, single_trial=False, steps=0, max_steps=5000):
    ev = np.atleast_2d(np.asarray(ev, dtype=np.float64))
    n = len(ev)
    return end_types(
        ev,
        p,
        resource_consumed=np.broadcast_to(np.asarray(consumed, dtype=bool), (n,)).copy(),
        single_trial=single_trial,
        steps=np.broadcast_to(np.asarray(steps, dtype=np.int64), (n,)).copy(),
        max_steps=max_steps,
    )


# ------------------------------------------------------------------------------------------------ level numbers
def test_params_follow_the_original(params):
    np.testing.assert_allclose(params.start, [0, 0, 0, 0])
    np.testing.assert_allclose(params.low, [-15, -15, -15, 0])
    np.testing.assert_allclose(params.high, [15, 15, 15, 100])
    np.testing.assert_allclose(params.setpoint, [0, 0, 0, 0])
    np.testing.assert_allclose(params.decay, [-0.0135, -0.009, 0.0, -0.01])
    assert params.thermal_coupling == pytest.approx(0.0004)
    assert params.reward == "squared"
    assert params.terminal_penalty == -100.0
    assert params.penalize_truncation is False


# ------------------------------------------------------------------------------------------------ dynamics
def test_no_op_decisions_decay_satiation_and_hydration(params):
    ev = params.start[None].copy()
    for _ in range(100):
        ev = _step(ev, params, thermal_sum=_uniform_field_sum(ev, ev[0, TEMPERATURE]))
    delta = ev[0] - params.start
    assert delta[SATIATION] == pytest.approx(-1.35, rel=0.01)
    assert delta[HYDRATION] == pytest.approx(-0.9, rel=0.01)
    assert delta[TEMPERATURE] == pytest.approx(0.0, abs=1e-12)  # sensors at body temperature: no drift
    assert delta[DAMAGE] == 0.0  # already at 0, cannot heal further


def test_damage_heals_by_0_01_per_decision(params):
    ev = np.array([[0.0, 0.0, 0.0, 50.0]])
    for _ in range(100):
        ev = _step(ev, params)
    assert ev[0, DAMAGE] == pytest.approx(49.0, rel=1e-9)


def test_damage_never_falls_below_zero(params):
    ev = np.array([[0.0, 0.0, 0.0, 0.5]])
    trace = []
    for _ in range(100):
        ev = _step(ev, params)
        trace.append(ev[0, DAMAGE])
    assert min(trace) >= 0.0
    assert trace[-1] == 0.0
    assert trace[10] == pytest.approx(0.5 - 11 * 0.01)  # still healing normally before the floor


def test_collision_damage_adds(params):
    ev = np.array([[0.0, 0.0, 0.0, 10.0]])
    out = _step(ev, params, damage=3.6)
    assert out[0, DAMAGE] == pytest.approx(10.0 - 0.01 + 3.6, rel=1e-12)


@pytest.mark.parametrize("field, t0", [(-20.0, 0.0), (20.0, -5.0), (3.0, 3.0)])
def test_temperature_relaxes_exponentially_in_a_uniform_field(params, field, t0):
    ev = np.array([[0.0, 0.0, t0, 0.0]])
    k = 100
    for _ in range(k):
        ev = _step(ev, params, thermal_sum=_uniform_field_sum(ev, field))
    closed_form = field + (t0 - field) * (1 - N_SENSORS * 0.0004) ** k
    assert ev[0, TEMPERATURE] == pytest.approx(closed_form, rel=1e-9, abs=1e-12)


def test_temperature_reaches_minus_15_after_about_433_decisions(params):
    # SPEC §2.1: from 0 in a -20 field, -15 is reached after ~433 decisions
    ev = np.array([[0.0, 0.0, 0.0, 0.0]])
    k = 0
    while ev[0, TEMPERATURE] >= -15.0:
        ev = _step(ev, params, thermal_sum=_uniform_field_sum(ev, -20.0))
        k += 1
        assert k < 1000
    assert 425 <= k <= 440


def test_thermal_coupling_is_a_parameter(params):
    p = dataclasses.replace(params, thermal_coupling=0.001)
    out = _step(np.zeros((1, 4)), p, thermal_sum=-160.0)
    assert out[0, TEMPERATURE] == pytest.approx(-0.16, rel=1e-12)


@pytest.mark.parametrize("food_value, water_value", [(3.0, 3.0), (5.0, 7.5), (-2.0, 0.0)])
def test_eating_adds_the_resource_value_once(params, food_value, water_value):
    p = dataclasses.replace(params, food_value=food_value, water_value=water_value)
    ev = np.array([[1.0, -2.0, 0.0, 0.0]] * 4)
    food = np.array([False, True, False, True])
    water = np.array([False, False, True, True])
    out = _step(ev, p, food=food, water=water)
    base = ev + p.decay
    np.testing.assert_allclose(out[:, SATIATION], base[:, SATIATION] + food_value * food, rtol=0, atol=1e-12)
    np.testing.assert_allclose(out[:, HYDRATION], base[:, HYDRATION] + water_value * water, rtol=0, atol=1e-12)
    np.testing.assert_allclose(out[:, TEMPERATURE], base[:, TEMPERATURE], rtol=0, atol=0)


def test_step_does_not_modify_its_input(params):
    ev = np.array([[1.0, 2.0, 3.0, 4.0]])
    keep = ev.copy()
    _step(ev, params, food=True, water=True, thermal_sum=8.0, damage=1.0)
    np.testing.assert_array_equal(ev, keep)


def test_overeating_is_not_clamped(params):
    out = _step(np.array([[14.0, 14.0, 0.0, 0.0]]), params, food=True, water=True)
    assert out[0, SATIATION] > params.high[SATIATION]
    assert out[0, HYDRATION] > params.high[HYDRATION]


def test_batched_worlds_are_independent(params):
    ev = np.array([[0.0, 0.0, 0.0, 0.0], [-3.0, 4.0, -10.0, 20.0], [14.0, -14.5, 12.0, 0.005]])
    food = np.array([False, True, False])
    water = np.array([True, False, False])
    thermal = np.array([0.0, -80.0, 64.0])
    damage = np.array([0.0, 0.0, 2.5])
    batch = step_evs(ev, params, food_eaten=food, water_eaten=water, thermal_sum=thermal, damage_taken=damage)
    for i in range(3):
        single = step_evs(
            ev[i : i + 1],
            params,
            food_eaten=food[i : i + 1],
            water_eaten=water[i : i + 1],
            thermal_sum=thermal[i : i + 1],
            damage_taken=damage[i : i + 1],
        )
        np.testing.assert_array_equal(batch[i : i + 1], single)

    after = np.array([[0.0, 0.0, 0.0, 0.0], [16.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 101.0]])
    consumed = np.array([True, False, False])
    steps = np.array([10, 5000, 3])
    ends = end_types(after, params, resource_consumed=consumed, single_trial=True, steps=steps, max_steps=5000)
    np.testing.assert_array_equal(ends, [END_RESOURCE, END_FOOD, END_DAMAGE])
    rewards = reward(ev, after, ends, params)
    for i in range(3):
        single_end = end_types(
            after[i : i + 1],
            params,
            resource_consumed=consumed[i : i + 1],
            single_trial=True,
            steps=steps[i : i + 1],
            max_steps=5000,
        )
        assert single_end[0] == ends[i]
        assert reward(ev[i : i + 1], after[i : i + 1], single_end, params)[0] == rewards[i]


# ------------------------------------------------------------------------------------------------ end types
@pytest.mark.parametrize(
    "column, value, expected",
    [
        (SATIATION, 15.01, END_FOOD),
        (SATIATION, -15.01, END_FOOD),
        (HYDRATION, 15.01, END_WATER),
        (HYDRATION, -15.01, END_WATER),
        (TEMPERATURE, 15.01, END_TEMPERATURE),
        (TEMPERATURE, -15.01, END_TEMPERATURE),
        (DAMAGE, 100.01, END_DAMAGE),
        (DAMAGE, -1.0, END_NONE),  # below 0 is healthier than unhurt, not a death
        # the viable band is closed: the bounds themselves are alive
        (SATIATION, 15.0, END_NONE),
        (SATIATION, -15.0, END_NONE),
        (HYDRATION, -15.0, END_NONE),
        (TEMPERATURE, 15.0, END_NONE),
        (DAMAGE, 100.0, END_NONE),
    ],
)
def test_each_bound_gives_its_end_type(params, column, value, expected):
    ev = np.zeros((1, 4))
    ev[0, column] = value
    assert _ends(ev, params)[0] == expected


# each row fixes one more cause, so the next one in precedence order shows
_ALL_OUT = [20.0, -20.0, 20.0, 200.0]


@pytest.mark.parametrize(
    "ev, single_trial, expected",
    [
        (_ALL_OUT, True, END_RESOURCE),
        (_ALL_OUT, False, END_FOOD),
        ([0.0, -20.0, 20.0, 200.0], False, END_WATER),
        ([0.0, 0.0, 20.0, 200.0], False, END_TEMPERATURE),
        ([0.0, 0.0, 0.0, 200.0], False, END_DAMAGE),
        ([0.0, 0.0, 0.0, 0.0], False, END_MAX_STEPS),
    ],
)
def test_end_type_precedence(params, ev, single_trial, expected):
    assert _ends(ev, params, consumed=True, single_trial=single_trial, steps=5000, max_steps=5000)[0] == expected


def test_consumption_ends_only_single_trial_episodes(params):
    ev = np.zeros((2, 4))
    consumed = np.array([True, False])
    np.testing.assert_array_equal(_ends(ev, params, consumed=consumed, single_trial=True), [END_RESOURCE, END_NONE])
    np.testing.assert_array_equal(_ends(ev, params, consumed=consumed, single_trial=False), [END_NONE, END_NONE])


def test_max_steps_only_at_or_after_the_limit(params):
    ev = np.zeros((4, 4))
    ends = _ends(ev, params, steps=np.array([0, 99, 100, 101]), max_steps=100)
    np.testing.assert_array_equal(ends, [END_NONE, END_NONE, END_MAX_STEPS, END_MAX_STEPS])
    assert ends.dtype.kind == "i"


def test_max_steps_yields_to_a_death(params):
    ev = np.array([[0.0, 0.0, -16.0, 0.0]])
    assert _ends(ev, params, steps=100, max_steps=100)[0] == END_TEMPERATURE


# ------------------------------------------------------------------------------------------------ rewards
_BEFORE = np.array([[0.0, 0.0, 0.0, 0.0], [-3.0, 4.0, -10.0, 20.0], [14.0, -14.5, 12.0, 60.0]])
_AFTER = np.array([[-0.0135, -0.009, 0.5, 0.0], [0.0, 1.0, -9.0, 80.0], [-2.0, 7.0, 14.0, 100.0]])


def _squared_by_hand(ev):
    f, w, t, d = ev.T
    return -0.01 * (f**2 + w**2 + t**2 + (0.15 * d) ** 2)


def _neg_distance_by_hand(ev):
    sigma = np.array([15.0, 15.0, 15.0, 100.0])
    return -np.sqrt((((ev - 0.0) / sigma) ** 2).sum(axis=1))


@pytest.mark.parametrize(
    "name, by_hand",
    [
        ("squared", lambda before, after: _squared_by_hand(after)),
        # drive = -squared, so drive(before) - drive(after) = squared(after) - squared(before)
        ("drive_reduction", lambda before, after: _squared_by_hand(after) - _squared_by_hand(before)),
        ("neg_distance", lambda before, after: _neg_distance_by_hand(after)),
        ("sparse", lambda before, after: np.zeros(len(after))),
    ],
)
def test_reward_functions(params, name, by_hand):
    p = dataclasses.replace(params, reward=name)
    end = np.full(len(_AFTER), END_NONE)
    r = reward(_BEFORE, _AFTER, end, p)
    assert r.dtype == np.float32
    assert r.shape == (len(_AFTER),)
    np.testing.assert_allclose(r, by_hand(_BEFORE, _AFTER), rtol=1e-6, atol=1e-6)


def test_reward_of_a_known_state(params):
    # f=1, w=2, t=3, d=20: -0.01 * (1 + 4 + 9 + 9) = -0.23
    ev = np.array([[1.0, 2.0, 3.0, 20.0]])
    assert reward(ev, ev, np.array([END_NONE]), params)[0] == pytest.approx(-0.23, rel=1e-6)
    p = dataclasses.replace(params, reward="neg_distance")
    expected = -math.sqrt((1 / 15) ** 2 + (2 / 15) ** 2 + (3 / 15) ** 2 + (20 / 100) ** 2)
    assert reward(ev, ev, np.array([END_NONE]), p)[0] == pytest.approx(expected, rel=1e-6)


def test_drive_reduction_rewards_moving_toward_the_set_point(params):
    p = dataclasses.replace(params, reward="drive_reduction")
    before = np.array([[-10.0, 0.0, 0.0, 0.0]])
    after = np.array([[-7.0, 0.0, 0.0, 0.0]])
    end = np.array([END_NONE])
    assert reward(before, after, end, p)[0] == pytest.approx(0.01 * (100 - 49), rel=1e-6)
    assert reward(after, before, end, p)[0] == pytest.approx(-0.01 * (100 - 49), rel=1e-6)


@pytest.mark.parametrize("name", [r for r in REWARDS if r != "shaped"])  # shaped: tests/test_faithful.py
@pytest.mark.parametrize("penalize_truncation", [False, True])
def test_terminal_penalty_only_on_deaths(params, name, penalize_truncation):
    p = dataclasses.replace(params, reward=name, penalize_truncation=penalize_truncation)
    n = len(END_TYPES)
    ev = np.tile([[1.0, -2.0, 3.0, 10.0]], (n, 1))
    ends = np.arange(n)
    base = reward(ev, ev, np.full(n, END_NONE), p)
    r = reward(ev, ev, ends, p)
    assert r.dtype == np.float32
    for end in range(n):
        penalised = end in DEATHS or (penalize_truncation and end == END_MAX_STEPS)
        expected = base[end] + (-100.0 if penalised else 0.0)
        assert r[end] == pytest.approx(expected, abs=1e-4), END_TYPES[end]
    assert r[END_RESOURCE] == base[END_RESOURCE]
    assert r[END_NONE] == base[END_NONE]


def test_terminal_penalty_is_a_parameter(params):
    p = dataclasses.replace(params, reward="sparse", terminal_penalty=-7.0)
    r = reward(np.zeros((2, 4)), np.zeros((2, 4)), np.array([END_FOOD, END_NONE]), p)
    np.testing.assert_array_equal(r, np.array([-7.0, 0.0], dtype=np.float32))


def test_unknown_reward_name_raises(params):
    p = dataclasses.replace(params, reward="bogus")
    with pytest.raises(ValueError, match="squared, drive_reduction, neg_distance, sparse"):
        reward(np.zeros((1, 4)), np.zeros((1, 4)), np.array([END_NONE]), p)
