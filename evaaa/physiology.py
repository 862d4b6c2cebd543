"""Essential variables (EVs): their dynamics, the episode end rules and the reward functions.

Pure, batched numpy over worlds: every function takes arrays whose first axis is the world, and nothing here
touches MuJoCo, so the dynamics can be checked analytically.  EVs are ordered as :data:`EV_NAMES`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

EV_NAMES: tuple[str, ...] = ("satiation", "hydration", "temperature", "damage")
SATIATION, HYDRATION, TEMPERATURE, DAMAGE = range(4)

#: How an episode ended; index 0 means it has not ended.  Stored as an integer in ``info["end_type"]``.
END_TYPES: tuple[str, ...] = (
    "None",
    "ResourceConsumed",
    "FoodOutOfRange",
    "WaterOutOfRange",
    "TemperatureOutOfRange",
    "DamageTooHigh",
    "MaxStepReached",
)
END_NONE, END_RESOURCE, END_FOOD, END_WATER, END_TEMPERATURE, END_DAMAGE, END_MAX_STEPS = range(7)
#: The original's name of each end type (its DataRecorder's ``EpisodeEndType``), for comparing logs.
ORIGINAL_END_TYPES: dict[str, str] = {
    "None": "Unknown",
    "ResourceConsumed": "ResourceConsumed",
    "FoodOutOfRange": "FoodLevelOutOfRange",
    "WaterOutOfRange": "WaterLevelOutOfRange",
    "TemperatureOutOfRange": "ThermoLevelOutOfRange",
    "DamageTooHigh": "HealthLevelTooLow",
    "MaxStepReached": "MaxStepReached",
}
#: End types that mean the animal died (an EV left its viable range).
DEATHS = (END_FOOD, END_WATER, END_TEMPERATURE, END_DAMAGE)
_IS_DEATH = np.isin(np.arange(len(END_TYPES)), DEATHS)

#: The original's hand-shaped reward (its Python wrapper with the homeostatic reward switched off): the sum of
#: the 10 odour values over ODOUR_DIVISOR, minus the sum of the 8 thermal readings' magnitudes over
#: HEAT_DIVISOR, plus CONSUMPTION_BONUS when something was eaten or drunk, minus COLLISION_COST on a collision.
SHAPED_ODOUR_DIVISOR = 10.0
SHAPED_HEAT_DIVISOR = 1000.0
SHAPED_CONSUMPTION_BONUS = 100.0
SHAPED_COLLISION_COST = 1.0


def contact_damage(impulse: float, constant: float, rate: float, offset: float, cap: float) -> float:
    """Damage of one contact impulse ``I`` (N s): ``min(constant * exp(rate * (I - offset)), cap)``.

    Past the exponent at which the cap is reached the cap is returned without evaluating the exponential, so a steep
    ``rate`` or a hard hit cannot overflow ``math.exp``.
    """
    if constant <= 0.0 or cap <= 0.0:
        return 0.0
    exponent = rate * (impulse - offset)
    if exponent >= math.log(cap / constant):
        return cap
    return constant * math.exp(exponent)


@dataclass(frozen=True)
class PhysiologyParams:
    """A level's physiology and reward settings as arrays, ready for the batched functions below (a level's own:
    :meth:`evaaa.level.Level.physiology_params`)."""

    start: np.ndarray  # (4,)
    low: np.ndarray  # (4,)
    high: np.ndarray  # (4,)
    setpoint: np.ndarray  # (4,)
    decay: np.ndarray  # (4,) per decision; temperature's entry is 0 (it follows the thermal field)
    thermal_coupling: float
    food_value: float
    water_value: float
    reward: str
    weights: np.ndarray  # (4,)
    terminal_penalty: float
    penalize_truncation: bool
    terminal_mode: str = "add"
    penalize_consumption: bool = False
    action_cost: float = 0.0
    clip: float | None = None


def step_evs(
    ev: np.ndarray,
    params: PhysiologyParams,
    *,
    food_eaten: np.ndarray,
    water_eaten: np.ndarray,
    thermal_sum: np.ndarray,
    damage_taken: np.ndarray,
) -> np.ndarray:
    """One decision of EV dynamics.

    ``ev`` is (N, 4); ``food_eaten``/``water_eaten`` are (N,) booleans (an item of that kind was consumed this
    decision; several items count once), ``thermal_sum`` is sum_i (T_i - temperature) over the thermal sensors
    and ``damage_taken`` the collision damage of this decision.  Damage never falls below its lower bound (the
    agent cannot be healthier than unhurt); nothing else is clamped, so overeating past the upper bound kills.
    """
    new = ev + params.decay
    new[:, SATIATION] += params.food_value * food_eaten
    new[:, HYDRATION] += params.water_value * water_eaten
    new[:, TEMPERATURE] += params.thermal_coupling * thermal_sum
    new[:, DAMAGE] = np.maximum(new[:, DAMAGE] + damage_taken, params.low[DAMAGE])
    return new


def end_types(
    ev: np.ndarray,
    params: PhysiologyParams,
    *,
    resource_consumed: np.ndarray,
    single_trial: bool,
    steps: np.ndarray,
    max_steps: int,
) -> np.ndarray:
    """The end type of each world after a decision (``END_NONE`` while it goes on).

    Precedence: a single-trial consumption, then satiation, hydration, temperature and damage leaving their
    ranges, then reaching ``max_steps`` (a truncation, reported only if nothing else ended the episode).
    """
    out = np.zeros(len(ev), dtype=np.int64)
    outside = (ev < params.low) | (ev > params.high)
    outside[:, DAMAGE] = ev[:, DAMAGE] > params.high[DAMAGE]
    # assign from lowest to highest precedence so that the highest wins
    out[steps >= max_steps] = END_MAX_STEPS
    for column, end in (
        (DAMAGE, END_DAMAGE),
        (TEMPERATURE, END_TEMPERATURE),
        (HYDRATION, END_WATER),
        (SATIATION, END_FOOD),
    ):
        out[outside[:, column]] = end
    if single_trial:
        out[resource_consumed] = END_RESOURCE
    return out


def drive(ev: np.ndarray, params: PhysiologyParams) -> np.ndarray:
    """Weighted squared deviation from the set points, sum_i w_i (EV_i - s_i)^2, per world."""
    return ((ev - params.setpoint) ** 2 * params.weights).sum(axis=-1)


# A reward function maps (EV before, EV after, params, what it reads) to the step's reward before the action cost,
# the terminal penalty and clipping.  Its name is a level's ``reward.name``: the level schema, the ``reward=<name>``
# training options and :func:`reward` all read this one registry, and :func:`register_reward` adds to it.
@dataclass(frozen=True)
class RewardFunction:
    """A reward function and what it reads beyond the EVs.

    ``reads`` names what the simulator passes to ``fn`` as keyword arguments of those names, each an (N, ...) array:
    a sensor's observation key (``olfaction``, ``thermoception``, ... : its reading, whether the agent observes that
    sense or not) or an event of the decision (:data:`REWARD_EVENTS`).  A reward that reads nothing gets only the EVs.
    """

    fn: Callable[..., np.ndarray]
    reads: tuple[str, ...] = ()


#: the events of a decision a reward function may read, (N,) booleans, with their meaning
REWARD_EVENTS: dict[str, str] = {
    "consumed": "anything was eaten or drunk this decision",
    "collided": "the body collided this decision",
}

#: every reward function by its name (``reward.name`` of a level)
REWARD_FUNCTIONS: dict[str, RewardFunction] = {}


def register_reward(name: str, *, reads: tuple[str, ...] | list[str] = ()) -> Callable:
    """Decorator: make ``fn(ev_before, ev_after, params, **reads)`` the reward function ``reward.name = name``.

    ``reads`` names the sensor keys and decision events (:data:`REWARD_EVENTS`) it reads; the simulator checks
    them against its sensors when it is built.  A name already taken is refused.
    """
    if not isinstance(name, str) or not name.isidentifier():
        raise ValueError(f"a reward function's name must be an identifier, got {name!r}")
    reads = tuple(reads)
    if not all(isinstance(r, str) and r for r in reads):
        raise ValueError(f"reward {name!r}: reads must be names of sensor keys or events, got {reads!r}")

    def add(fn: Callable[..., np.ndarray]) -> Callable[..., np.ndarray]:
        known = REWARD_FUNCTIONS.get(name)
        if known is not None and known.fn is not fn:
            raise ValueError(f"reward name {name!r} is already taken by {known.fn.__module__}.{known.fn.__qualname__}")
        REWARD_FUNCTIONS[name] = RewardFunction(fn, reads)
        return fn

    return add


@register_reward("squared")
def _squared(ev_before, ev_after, params) -> np.ndarray:
    return -drive(ev_after, params)


@register_reward("drive_reduction")
def _drive_reduction(ev_before, ev_after, params) -> np.ndarray:
    return drive(ev_before, params) - drive(ev_after, params)


@register_reward("neg_distance")
def _neg_distance(ev_before, ev_after, params) -> np.ndarray:
    sigma = np.maximum(np.abs(params.high - params.setpoint), np.abs(params.low - params.setpoint))
    sigma = np.where(sigma > 0, sigma, 1.0)
    return -np.sqrt((((ev_after - params.setpoint) / sigma) ** 2).sum(axis=-1))


@register_reward("sparse")
def _sparse(ev_before, ev_after, params) -> np.ndarray:
    return np.zeros(len(ev_after))


@register_reward("shaped", reads=("olfaction", "thermoception", "consumed", "collided"))
def _shaped(ev_before, ev_after, params, *, olfaction, thermoception, consumed, collided) -> np.ndarray:
    return (
        np.asarray(olfaction, dtype=np.float64).sum(axis=-1) / SHAPED_ODOUR_DIVISOR
        - np.abs(np.asarray(thermoception, dtype=np.float64)).sum(axis=-1) / SHAPED_HEAT_DIVISOR
        + SHAPED_CONSUMPTION_BONUS * np.asarray(consumed, dtype=bool)
        - SHAPED_COLLISION_COST * np.asarray(collided, dtype=bool)
    )


#: the packaged reward functions' names (:data:`REWARD_FUNCTIONS` also holds any registered since)
REWARDS: tuple[str, ...] = tuple(REWARD_FUNCTIONS)


def reward_reads(name: str) -> tuple[str, ...]:
    """What the reward function ``name`` reads beyond the EVs (a clear error for an unknown name)."""
    if name not in REWARD_FUNCTIONS:
        raise ValueError(f"reward.name must be one of {', '.join(REWARD_FUNCTIONS)}, got {name!r}")
    return REWARD_FUNCTIONS[name].reads


def reward(
    ev_before: np.ndarray,
    ev_after: np.ndarray,
    end: np.ndarray,
    params: PhysiologyParams,
    *,
    costly: np.ndarray | None = None,
    **reads: np.ndarray,
) -> np.ndarray:
    """Reward of a decision from the internal state (and from what the reward function reads, given as ``reads``).

    * ``squared`` (default): ``-drive(EV_after)`` — what the original baselines trained on.
    * ``drive_reduction``: ``drive(EV_before) - drive(EV_after)`` — reward for moving toward the set points.
    * ``neg_distance``: ``-|| (EV_after - s) / sigma ||_2`` with sigma_i the largest distance from the set point
      to a bound of EV i.
    * ``sparse``: 0.
    * ``shaped``: the original's hand-shaped reward, ``sum(odour) / 10 - sum(|thermal|) / 1000 + 100 consumed
      - 1 collided``; it reads ``olfaction`` (the 10 odour values), ``thermoception`` (the 8 thermal readings, as
      the level's thermoception reports them), ``consumed`` and ``collided``, all (N, ...) arrays.

    ``action_cost`` is then subtracted where ``costly`` (a Forward or Eat decision).  The terminal penalty applies
    where an EV left its range, on truncation if ``penalize_truncation`` and on a single-trial consumption if
    ``penalize_consumption``; ``terminal_mode`` says whether it is added to the step's reward or replaces it.
    Last, the reward is clipped to ``[-clip, clip]`` when ``clip`` is set.
    """
    wanted = reward_reads(params.reward)  # the level schema rules an unknown name out; guards direct construction
    missing = [k for k in wanted if reads.get(k) is None]
    if missing:
        raise ValueError(f"reward {params.reward!r} reads {', '.join(wanted)}; not given: {', '.join(missing)}")
    r = REWARD_FUNCTIONS[params.reward].fn(ev_before, ev_after, params, **{k: reads[k] for k in wanted})
    if params.action_cost and costly is not None:
        r = r - params.action_cost * np.asarray(costly, dtype=bool)
    penalised = _IS_DEATH[end]
    if params.penalize_truncation:
        penalised = penalised | (end == END_MAX_STEPS)
    if params.penalize_consumption:
        penalised = penalised | (end == END_RESOURCE)
    if params.terminal_mode == "replace":
        r = np.where(penalised, params.terminal_penalty, r)
    else:
        r = r + params.terminal_penalty * penalised
    if params.clip is not None:
        r = np.clip(r, -params.clip, params.clip)
    return r.astype(np.float32)
