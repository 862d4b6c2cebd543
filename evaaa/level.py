"""Level specifications: the typed schema of a level file, and loading with clear errors.

A level is data (``evaaa/levels/<name>.yaml``); this module owns what a level may say and how a file, the
files it extends and the user's overrides are merged and validated.  Every level starts from
``levels/_defaults.yaml`` (the values common to all levels), may ``extends:`` another level, and may be changed
by dotted-path overrides (``{"agent.move_speed": 10}``).  Any mistake raises :class:`LevelError` naming the
field and what it accepts.
"""

from __future__ import annotations

import functools
import math
import os
import re
import reprlib
import stat
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import yaml
from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    Strict,
    ValidationError,
    field_validator,
    model_validator,
)

from .entities import OBSTACLE_KINDS, RESOURCE_KINDS
from .physiology import EV_NAMES, REWARD_FUNCTIONS, PhysiologyParams

__all__ = [
    "Level",
    "LevelError",
    "LEVELS",
    "TESTBEDS",
    "load_level",
    "level_names",
    "register_level",
]


class LevelError(ValueError):
    """A level name, level file or override is invalid.  The message names the field and what is allowed."""


def _ordered(pair: tuple[float, float]) -> tuple[float, float]:
    if pair[0] > pair[1]:
        raise ValueError(f"expected [low, high] with low <= high, got [{pair[0]}, {pair[1]}]")
    return pair


def _not_a_set(value: Any) -> Any:
    if isinstance(value, (set, frozenset)):  # a set has no order: [low, high] would be whichever came first
        raise ValueError(f"expected a list, got a set {excerpt(value)}")
    return value


#: numbers, flags and text are strict (``_Spec``'s config): ``true`` is no mass and ``'3'`` no count.  A sequence
#: of fixed length is written as a YAML list, so it is read as a list or a tuple (strictly, only a tuple), never as
#: a set; its items stay strict.
Lax, NoSet = Strict(False), BeforeValidator(_not_a_set)
#: A closed interval ``[low, high]``.
Interval = Annotated[tuple[float, float], Lax, NoSet, AfterValidator(_ordered)]
Positive = Annotated[float, Field(gt=0)]
NonNegative = Annotated[float, Field(ge=0)]


#: Largest magnitude of any number in a level.  Lengths, temperatures, rates and weights all stay far below it, and
#: so do their squares and products in float32 observations and rewards (float32 overflows near 3.4e38).
MAX_MAGNITUDE = 1e6
#: Largest integer in a level (counts, step limits): beyond it a loop or an array would outgrow the machine.
MAX_INTEGER = 10**9
#: Longest side of an arena (m): predators plan on a grid of 1 m cells over the floor.
MAX_ARENA_SIDE = 1000.0
#: Smallest side of an arena (m): the agent's body is 1 m wide.
MIN_ARENA_SIDE = 2.0
#: Bodies the agent collides with (obstacles and ponds), in all: MuJoCo's collision detection ran out of its
#: default memory at 2,000 of them (1,500 worked); this keeps a margin.
MAX_SOLID_BODIES = 1200
#: Resource items in all (measured: 2,000 items step in ~3 ms a decision on one core).
MAX_ITEMS = 2000
#: Landmark points of a patrol pattern (each predator plans routes between them).
MAX_LANDMARKS = 10_000
#: A chasing predator whose straight line to the agent is blocked plans a new route at most this often (decisions).
REPLAN_EVERY = 5
#: Route planning allowed per decision, in grid cells visited: a plan can be a shortest-path search over the whole
#: grid of 1 m cells (scipy's Dijkstra, 400-600 ns a cell on the 2-core box), made by each searching predator every
#: search_interval decisions and by each chasing one every REPLAN_EVERY.  1e6 is about 0.5 s a decision at the worst;
#: 4-1 needs 6.4e3; the audit's 1,000 m arena with 50 predators searching every decision needed 6e7 (20-38 s a step).
MAX_PLANNING_WORK = 1e6
#: Work of one smoothing of the thermal field (cells times kernel width, both passes) allowed at every episode
#: reset: the default 100 x 100 grid at sigma 10 costs 6.1e5; 1000 x 1000 cells at sigma 3 (3.8e7) took 15 ms of
#: CPU on the 2-core box.  Painting the hotspots is held to the same number of cells.
MAX_SMOOTHING_WORK = 5e7


def _check_bounded(value: Any) -> None:
    """Raise if a number in ``value`` (a number, or a tuple or list of them) lies beyond the allowed magnitude."""
    if isinstance(value, bool):
        return
    if isinstance(value, float) and abs(value) > MAX_MAGNITUDE:
        raise ValueError(f"must lie within [-{MAX_MAGNITUDE:g}, {MAX_MAGNITUDE:g}]")
    if isinstance(value, int) and abs(value) > MAX_INTEGER:
        raise ValueError(f"must lie within [-{MAX_INTEGER:.0e}, {MAX_INTEGER:.0e}]")
    if isinstance(value, (tuple, list)):
        for item in value:
            _check_bounded(item)


class _Spec(BaseModel):
    # every float of a level is finite: NaN or infinity anywhere would reach the observations or the reward
    # strict: YAML's true, '3' and !!binary are not numbers (lax pydantic would read them as 1.0 and 3.0)
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, strict=True)

    @field_validator("*", mode="after")
    @classmethod
    def _bounded(cls, value: Any) -> Any:
        _check_bounded(value)
        return value


# --------------------------------------------------------------------------------------------------- arena / agent
class Arena(_Spec):
    """The floor (centred on the origin; walking surface at z = 0) and its walls."""

    size: Annotated[
        tuple[
            Annotated[float, Field(ge=MIN_ARENA_SIDE, le=MAX_ARENA_SIDE)],
            Annotated[float, Field(ge=MIN_ARENA_SIDE, le=MAX_ARENA_SIDE)],
        ],
        Lax,
        NoSet,
    ]
    walls: bool
    wall_height: Positive
    floor: Literal["ground", "gray"]


class CollisionDamage(_Spec):
    """Damage per physics substep from a contact impulse ``I`` (N s): ``min(constant * exp(rate * (I - offset)), cap)``."""

    constant: NonNegative
    rate: NonNegative
    offset: float
    cap: NonNegative
    #: a substep whose damage exceeds this counts as a collision event
    event_threshold: NonNegative


class Agent(_Spec):
    mass: Positive
    #: speed set by a Forward decision (units/s); drag and floor friction act during the 5 substeps
    move_speed: Positive
    turn_degrees: Annotated[float, Field(gt=0, lt=180)]
    linear_drag: NonNegative
    floor_friction: NonNegative
    eat_radius: Positive
    #: distance of the eating sphere's centre ahead of the body centre
    eat_offset: NonNegative
    auto_eat: bool
    start: Literal["random", "fixed"]
    #: sampling box of a random start (clipped to the floor); rejected where the body plus padding overlaps an entity
    spawn_x: Interval
    spawn_y: Interval
    spawn_padding: NonNegative
    start_position: Annotated[tuple[float, float], Lax, NoSet]
    #: compass heading in degrees: 0 faces +y, 90 faces +x (clockwise seen from above)
    start_heading: float
    collision_damage: CollisionDamage


# --------------------------------------------------------------------------------------------------- physiology
class EVs(_Spec):
    satiation: float
    hydration: float
    temperature: float
    damage: float


class EVBounds(_Spec):
    satiation: Interval
    hydration: Interval
    temperature: Interval
    damage: Interval


class Decay(_Spec):
    """Change per decision without any other input (negative: the EV falls)."""

    satiation: float
    hydration: float
    damage: float


class Physiology(_Spec):
    start: EVs
    bounds: EVBounds
    setpoint: EVs
    decay: Decay
    #: temperature change per decision = coupling * sum over the 8 thermal sensors of (T_sensor - temperature)
    thermal_coupling: NonNegative
    food_value: float
    water_value: float

    @model_validator(mode="after")
    def _start_inside_bounds(self) -> Physiology:
        for ev in EVs.model_fields:
            lo, hi = getattr(self.bounds, ev)
            value = getattr(self.start, ev)
            if not lo <= value <= hi:
                raise ValueError(f"start.{ev} = {value} lies outside bounds.{ev} = [{lo}, {hi}]")
        return self


# --------------------------------------------------------------------------------------------------- resources
Extents = Annotated[
    tuple[Positive, Positive, Positive], Lax, NoSet, Field(description="width (x), depth (y), height (z)")
]


class ResourceGroup(_Spec):
    """A group of identical consumable items placed uniformly in a box."""

    #: food and apple feed, water and pond water; a pond is a solid slab the body cannot enter
    kind: Literal[tuple(RESOURCE_KINDS)]  # type: ignore[valid-type]
    count: Annotated[int, Field(ge=0, le=1000)]
    #: random: a consumed item reappears uniformly in its group's box; static: never depletes; grouped: one
    #: grouped group holds items at a time, and when its items are all eaten a group is drawn anew
    respawn: Literal["random", "static", "grouped"]
    x: Interval
    y: Interval
    #: edge of a cube, or the item's extents in metres (width, depth, height) before turning it by ``heading``
    size: Positive | Extents
    #: compass heading of the item's depth axis, degrees (fixed)
    heading: float = 0.0

    @property
    def extents(self) -> tuple[float, float, float]:
        return (self.size,) * 3 if isinstance(self.size, float) else tuple(self.size)


# --------------------------------------------------------------------------------------------------- obstacles
class ObstacleGroup(_Spec):
    """Obstacles of one kind.  A group of one obstacle at a fixed spot is static (placed once, never moved);
    the others are re-drawn every episode by rejection sampling with ``padding``."""

    kind: Literal[tuple(OBSTACLE_KINDS)]  # type: ignore[valid-type]
    count: Annotated[int, Field(ge=0, le=1000)]
    x: Interval
    y: Interval
    #: compass heading of the obstacle's depth axis, degrees (fixed, not random)
    heading: float = 0.0
    #: per-axis scale ranges (width, depth, height) applied to the kind's base extents (see evaaa.entities)
    scale: Annotated[tuple[Interval, Interval, Interval], Lax, NoSet] = ((1.0, 1.0), (1.0, 1.0), (1.0, 1.0))
    padding: NonNegative = 2.0
    #: cells under the obstacle are set to this temperature before smoothing (0: no heat)
    temperature: float = 0.0
    #: metres the obstacle is raised from resting on the floor; negative sinks it, so that only its top part
    #: stands above the floor (the original's collision-avoidance blocks show 0.55 m, just above the 0.5 m eye)
    lift: float = 0.0

    @field_validator("scale", mode="after")
    @classmethod
    def _positive_scale(cls, scale: tuple) -> tuple:
        if min(min(pair) for pair in scale) <= 0:
            raise ValueError("every scale must be > 0 (a body needs a size)")
        return scale

    @property
    def static(self) -> bool:
        return self.count == 1 and self.x[0] == self.x[1] and self.y[0] == self.y[1]


# --------------------------------------------------------------------------------------------------- predators
class PredatorGroup(_Spec):
    count: Annotated[int, Field(ge=0, le=50)]
    x: Interval
    y: Interval
    heading: float = 0.0
    walk_speed: Positive = 6.0
    #: degrees per second
    turn_speed: Positive = 180.0
    view_angle: Annotated[float, Field(gt=0, le=360)] = 120.0
    view_distance: Positive = 20.0
    #: damage added per decision while attacking, capped at max_damage
    damage: NonNegative = 5.0
    max_damage: NonNegative = 20.0
    max_resting_steps: Annotated[int, Field(ge=1)] = 50
    max_searching_steps: Annotated[int, Field(ge=1)] = 150
    #: a searching predator picks a new landmark every this many decisions
    search_interval: Annotated[int, Field(ge=1)] = 60
    #: what an attack does each decision: ``harm`` adds ``damage`` to the damage EV (evaaa); ``original`` does what
    #: the original's code did, subtracting it (healing, floored at 0), so that contact harms only through
    #: collisions (evaaa's predators never push the agent, so they then do no harm at all)
    attack: Literal["harm", "original"] = "harm"


class Landmarks(_Spec):
    """Patrol points: the floor split into a grid of cells; a cell holding n > 0 gets n x n points.
    Rows run from the north (+y) edge southward.  The patrol area is the convex hull of the points."""

    pattern: Annotated[list[Annotated[list[Annotated[int, Field(ge=0, le=10)]], Lax, NoSet]], Lax, NoSet]
    radius: Positive = 1.5
    padding: NonNegative = 2.0

    @model_validator(mode="after")
    def _rectangular(self) -> Landmarks:
        if not self.pattern or len({len(row) for row in self.pattern}) != 1 or not self.pattern[0]:
            raise ValueError("pattern must be a non-empty rectangle of rows of equal length")
        if sum(map(sum, self.pattern)) == 0:
            raise ValueError("pattern places no landmark")
        points = sum(n * n for row in self.pattern for n in row)
        if points > MAX_LANDMARKS:
            raise ValueError(f"pattern places {points} landmark points; at most {MAX_LANDMARKS}")
        return self


# --------------------------------------------------------------------------------------------------- events
class EVAssignment(_Spec):
    satiation: float | None = None
    hydration: float | None = None
    temperature: float | None = None
    damage: float | None = None


class EventTrigger(_Spec):
    """An invisible box on the floor; when the agent's body enters it (at most ``max_count`` times an episode)
    the EVs named in ``set`` are assigned those values (clamped to their ranges)."""

    x: float
    y: float
    #: width (x) and depth (y) of the box before it is turned by ``heading``
    size: Annotated[tuple[Positive, Positive], Lax, NoSet]
    heading: float = 0.0
    max_count: Annotated[int, Field(ge=1)] = 1
    set: EVAssignment


# --------------------------------------------------------------------------------------------------- day and night
class DayNight(_Spec):
    enabled: bool
    #: draw the starting sun angle uniformly each episode (else start at start_angle; 90 is noon)
    random_start: bool
    start_angle: float
    degrees_per_step: NonNegative
    #: temperature offsets added to the whole field at noon and at 04:00; hours between are interpolated
    day_temperature: float
    night_temperature: float
    night_fog_density: NonNegative
    day_far: Positive
    night_far: Positive
    #: how fog and far plane follow the hour: ``smooth`` (evaaa: full night fog from 21:00 to 03:00) or
    #: ``original`` (the original's table: half the night fog at 21:00 rising to 5/6 of the way by 02:00, full at
    #: 03:00; see evaaa.daynight.original_darkness)
    fog_schedule: Literal["smooth", "original"] = "smooth"


# --------------------------------------------------------------------------------------------------- thermal field
class Hotspots(_Spec):
    count: Annotated[int, Field(ge=0, le=1000)]
    #: side of the square of cells set to ``temperature`` (odd; an even size is rounded up as in the original)
    size: Annotated[int, Field(ge=1, le=1000)]
    temperature: float


class Thermal(_Spec):
    grid: Annotated[tuple[Annotated[int, Field(ge=1, le=1000)], Annotated[int, Field(ge=1, le=1000)]], Lax, NoSet]
    base_temperature: float
    hotspots: Hotspots
    #: Gaussian smoothing in cells (0: none)
    sigma: Annotated[float, Field(ge=0, le=100)]
    #: thermoception reads T_sensor - body temperature instead of T_sensor
    relative: bool

    @model_validator(mode="after")
    def _smoothing_affordable(self) -> Thermal:
        # the field is rebuilt and smoothed at every reset: two passes of a 2*ceil(3 sigma)+1 kernel over the grid
        gx, gy = self.grid
        work = 2 * gx * gy * (2 * math.ceil(3 * self.sigma) + 1)
        if self.sigma > 0 and work > MAX_SMOOTHING_WORK:
            raise ValueError(
                f"sigma = {self.sigma:g} cells over a grid of {gx} x {gy} cells is too much work for "
                f"every reset ({work:.2g} > {MAX_SMOOTHING_WORK:.0e} cell operations): lower sigma or "
                "the grid"
            )
        spots = self.hotspots
        painted = spots.count * min(spots.size, gx) * min(spots.size, gy)
        if painted > MAX_SMOOTHING_WORK:
            raise ValueError(
                f"hotspots.count = {spots.count} squares of hotspots.size = {spots.size} cells paint "
                f"{painted:.2g} cells at every reset; at most {MAX_SMOOTHING_WORK:.0e}"
            )
        return self


# --------------------------------------------------------------------------------------------------- sensors
class Vision(_Spec):
    width: Annotated[int, Field(ge=8, le=1024)]
    height: Annotated[int, Field(ge=8, le=1024)]
    fovy: Annotated[float, Field(gt=0, lt=180)]
    near: Positive
    far: Positive

    @model_validator(mode="after")
    def _near_before_far(self) -> Vision:
        if self.near >= self.far:
            raise ValueError(f"near ({self.near:g}) must be less than far ({self.far:g}): nothing would be drawn")
        return self


class Olfaction(_Spec):
    radius: Positive
    #: distances are clamped below at this value so that an item at the nose reads large but finite
    min_distance: Positive


class CollisionSensor(_Spec):
    rays: Annotated[int, Field(ge=1, le=1000)]
    sectors: Annotated[int, Field(ge=1, le=100)]
    range: Positive

    @model_validator(mode="after")
    def _rays_fill_sectors(self) -> CollisionSensor:
        if self.rays % self.sectors:
            raise ValueError(f"rays ({self.rays}) must be a multiple of sectors ({self.sectors})")
        return self


class Sensors(_Spec):
    vision: Vision
    olfaction: Olfaction
    collision: CollisionSensor


# --------------------------------------------------------------------------------------------------- episode / reward
class Success(_Spec):
    """How a testbed judges an episode (reported in ``info["success"]`` on its last step).

    * ``none``: no criterion (training levels).
    * ``consume``: the episode ended by consuming ``resource`` (single-trial tasks).
    * ``consume_any``: the episode ended by consuming anything (the paper's rule for risk taking).
    * ``consume_after_trigger``: as ``consume``, after an event trigger was crossed (goal manipulation).
    * ``survive``: alive when the episode reaches ``max_steps``.
    """

    rule: Literal["none", "consume", "consume_any", "consume_after_trigger", "survive"] = "none"
    resource: Literal["food", "water"] | None = None

    @model_validator(mode="after")
    def _resource_when_consuming(self) -> Success:
        if self.rule in ("consume", "consume_after_trigger") and self.resource is None:
            raise ValueError(f"rule '{self.rule}' needs resource: food or water")
        return self


class Episode(_Spec):
    #: decisions before truncation
    max_steps: Annotated[int, Field(ge=1)]
    #: the episode ends (terminated, ResourceConsumed) once any resource is consumed
    single_trial: bool
    success: Success = Success()


class Reward(_Spec):
    #: a reward function of evaaa.physiology.REWARD_FUNCTIONS (the packaged ones, and any registered since)
    name: str
    #: added on the step an EV leaves its range
    terminal_penalty: float
    #: also add the terminal penalty when the episode is truncated at max_steps (the original did)
    penalize_truncation: bool
    #: per-EV weights w_i of the squared deviation sum_i w_i (EV_i - setpoint_i)^2 (squared, drive_reduction)
    weights: EVs
    #: how the terminal penalty meets the step's reward: ``add`` it, or ``replace`` the step's reward with it (the
    #: original's Python wrapper and its DQN did)
    terminal_mode: Literal["add", "replace"] = "add"
    #: also apply the terminal penalty when a single-trial episode ends by consuming a resource (the original did)
    penalize_consumption: bool = False
    #: subtracted on every Forward or Eat decision (the original DQN: 0.001)
    action_cost: NonNegative = 0.0
    #: the final reward is clipped to [-clip, clip] (the original DQN: 10); null: no clipping
    clip: Positive | None = None

    @field_validator("name", mode="after")
    @classmethod
    def _known(cls, name: str) -> str:
        if name not in REWARD_FUNCTIONS:
            raise ValueError(f"must be one of {', '.join(repr(n) for n in REWARD_FUNCTIONS)}")
        return name


# --------------------------------------------------------------------------------------------------- level
#: What a level's name may be: it names the MuJoCo model, the level's pictures (``<name>_eye.png``) and, for a level
#: from the user's file, its run folder, so it holds no quote, markup, path separator, space or leading dot.
LEVEL_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")
LEVEL_NAME_RULE = "1 to 64 letters, digits, '-', '_' or '.', starting with a letter or digit"


def check_level_name(name: str) -> str:
    """``name`` if it is a :data:`LEVEL_NAME`; else ValueError saying what is allowed."""
    if not LEVEL_NAME.fullmatch(name):
        raise ValueError(f"must be {LEVEL_NAME_RULE} (a level file's name is its file's stem unless it says name:)")
    return name


class Level(_Spec):
    name: Annotated[str, AfterValidator(check_level_name)]
    kind: Literal["training", "testbed"]
    description: str
    arena: Arena
    agent: Agent
    physiology: Physiology
    resources: dict[str, ResourceGroup]
    obstacles: dict[str, ObstacleGroup]
    predators: dict[str, PredatorGroup]
    landmarks: Landmarks | None = None
    daynight: DayNight
    events: dict[str, EventTrigger] = {}
    thermal: Thermal
    sensors: Sensors
    episode: Episode
    reward: Reward

    def physiology_params(self) -> PhysiologyParams:
        """The level's physiology and reward settings as the arrays :mod:`evaaa.physiology` computes with."""
        p, r = self.physiology, self.reward

        def vec(evs: EVs) -> np.ndarray:
            return np.array([getattr(evs, n) for n in EV_NAMES], dtype=np.float64)

        bounds = np.array([getattr(p.bounds, n) for n in EV_NAMES], dtype=np.float64)
        return PhysiologyParams(
            start=vec(p.start),
            low=bounds[:, 0],
            high=bounds[:, 1],
            setpoint=vec(p.setpoint),
            decay=np.array([p.decay.satiation, p.decay.hydration, 0.0, p.decay.damage]),
            thermal_coupling=p.thermal_coupling,
            food_value=p.food_value,
            water_value=p.water_value,
            reward=r.name,
            weights=vec(r.weights),
            terminal_penalty=r.terminal_penalty,
            penalize_truncation=r.penalize_truncation,
            terminal_mode=r.terminal_mode,
            penalize_consumption=r.penalize_consumption,
            action_cost=r.action_cost,
            clip=r.clip,
        )

    @model_validator(mode="after")
    def _inside_arena(self) -> Level:
        hx, hy = self.arena.size[0] / 2, self.arena.size[1] / 2
        for section in ("resources", "obstacles", "predators"):
            for name, group in getattr(self, section).items():
                for axis, (lo, hi), half in (("x", group.x, hx), ("y", group.y, hy)):
                    if lo < -half or hi > half:
                        raise ValueError(
                            f"{section}.{name}.{axis} = [{lo}, {hi}] leaves the floor [{-half}, {half}] "
                            f"(arena.size {list(self.arena.size)})"
                        )
        return self

    @model_validator(mode="after")
    def _entities_fit(self) -> Level:
        solid = sum(g.count for g in self.obstacles.values()) + sum(
            g.count for g in self.resources.values() if getattr(RESOURCE_KINDS.get(g.kind), "solid", False)
        )
        if solid > MAX_SOLID_BODIES:
            raise ValueError(
                f"the obstacles' count and the solid resources' (ponds) count add up to {solid} bodies "
                f"the agent collides with; at most {MAX_SOLID_BODIES} in all"
            )
        items = sum(g.count for g in self.resources.values())
        if items > MAX_ITEMS:
            raise ValueError(f"the resources' count adds up to {items} items; at most {MAX_ITEMS} in all")
        return self

    @model_validator(mode="after")
    def _predators_need_landmarks(self) -> Level:
        if any(g.count for g in self.predators.values()) and self.landmarks is None:
            raise ValueError("predators patrol the convex hull of the landmarks: set landmarks.pattern")
        return self

    @model_validator(mode="after")
    def _planning_bounded(self) -> Level:
        # what predator.NavGrid plans on (1 m cells) and how often predator.Predators plans: see MAX_PLANNING_WORK
        cells = math.ceil(self.arena.size[0]) * math.ceil(self.arena.size[1])
        plans = sum(g.count * (1 / g.search_interval + 1 / REPLAN_EVERY) for g in self.predators.values())
        if cells * plans > MAX_PLANNING_WORK:
            named = [f"{n}: count {g.count}, search_interval {g.search_interval}" for n, g in self.predators.items()]
            groups = "; ".join(named[:3]) + (f"; and {len(named) - 3} more" if len(named) > 3 else "")
            raise ValueError(
                f"predators plan routes over {cells * plans:.2g} grid cells a decision (arena.size "
                f"{self.arena.size[0]:g} x {self.arena.size[1]:g} = {cells} cells of 1 m, times the predators' "
                f"count x (1 / search_interval + 1 / {REPLAN_EVERY}), predators {groups}); at most "
                f"{MAX_PLANNING_WORK:.0e}: a smaller arena, fewer predators or a longer search_interval"
            )
        return self

    @model_validator(mode="after")
    def _agent_starts_on_the_floor(self) -> Level:
        # the body's centre keeps half its width (worldgen.AGENT_HALF, 0.5 m) from the floor's edge; a random start
        # falls back to start_position when its box is full, so that must lie on the floor either way
        a = self.agent
        hx, hy = self.arena.size[0] / 2 - 0.5, self.arena.size[1] / 2 - 0.5
        x, y = a.start_position
        if abs(x) > hx or abs(y) > hy:
            raise ValueError(
                f"agent.start_position = [{x:g}, {y:g}] is off the floor: the body's centre must lie "
                f"within x in [{-hx:g}, {hx:g}], y in [{-hy:g}, {hy:g}] "
                f"(arena.size {list(self.arena.size)})"
            )
        if a.start == "random":
            for axis, (lo, hi), half in (("x", a.spawn_x, hx), ("y", a.spawn_y, hy)):
                if hi < -half or lo > half:
                    raise ValueError(
                        f"agent.spawn_{axis} = [{lo:g}, {hi:g}] misses the floor, where the body's "
                        f"centre lies within [{-half:g}, {half:g}] (arena.size {list(self.arena.size)})"
                    )
        return self

    @model_validator(mode="after")
    def _far_plane_beyond_near(self) -> Level:
        near = self.sensors.vision.near
        dn = self.daynight
        if dn.enabled:
            for name in ("day_far", "night_far"):
                far = getattr(dn, name)
                if far <= near:
                    raise ValueError(
                        f"daynight.{name} ({far:g}) must exceed sensors.vision.near ({near:g}): the "
                        "far plane would hide everything"
                    )
        return self


# --------------------------------------------------------------------------------------------------- loading
#: Largest level file read (bytes).  The packaged levels are 0.5-3.5 KB, and a landmark pattern of 100 x 100 cells
#: is 30 KB; PyYAML's pure-Python parser reads about 50-200 KB/s, so a file at the limit parses in about a second.
MAX_FILE_BYTES = 64 * 1024
#: Deepest nesting of a level file or an override value (the schema nests 7 deep).  Parsing, merging and the
#: error messages stay far from Python's recursion limit, and libyaml's loader, which crashed the process at
#: 100,000 levels, is never used.
MAX_DEPTH = 32
#: Most values (mappings, lists and scalars, counting each use of an alias as a copy of what it names) in one level
#: file: ten times the largest landmark pattern.  A 7 x 7 alias chain would expand to 8e5, a 9 x 9 one to 4e8.
MAX_NODES = 100_000
#: Longest ``extends:`` chain, the file itself included (the packaged levels' longest, 4-2's, is 9 files)
MAX_EXTENDS = 32
#: keys of a level file about the file itself, not the level: they are not inherited through ``extends:``
_FILE_KEYS = ("extends", "order")

# error messages quote what was given, cut short: a value can be a whole level, or an alias expanded millions of times
_EXCERPT = reprlib.Repr()
_EXCERPT.maxlevel, _EXCERPT.maxstring, _EXCERPT.maxother = 2, 60, 60
_EXCERPT.maxlist = _EXCERPT.maxtuple = _EXCERPT.maxset = _EXCERPT.maxfrozenset = _EXCERPT.maxdict = 4
EXCERPT_CHARS = 120


def excerpt(value: Any) -> str:
    """``repr(value)`` cut to at most :data:`EXCERPT_CHARS` characters (nesting, items and text elided with ...)."""
    text = _EXCERPT.repr(value)
    return text if len(text) <= EXCERPT_CHARS else text[: EXCERPT_CHARS - 3] + "..."


#: Most digits of an integer in a level file: a level's integers lie within MAX_INTEGER (10 digits), and Python
#: refuses to read one of more than 4,300 digits (a raw ValueError) or takes quadratic time below that
MAX_INTEGER_DIGITS = 100
_INT = "tag:yaml.org,2002:int"


def _yaml11_form(node: yaml.ScalarNode) -> str | None:
    """What is wrong with a plain scalar PyYAML (YAML 1.1) resolved to a number or a flag that YAML 1.2, which the
    level files are written in, reads otherwise (octal 010, base-60 1:30, binary 0b1, yes/no/on/off), or with an
    integer too long to read; None when nothing is."""
    if node.style is not None:  # quoted or a block: text in both versions
        return None
    text, number = node.value, node.value.lstrip("+-").replace("_", "")
    if node.tag == _INT and len(number) > MAX_INTEGER_DIGITS:
        return (
            f"an integer of {len(number)} digits; a level's integers lie within [-{MAX_INTEGER:.0e}, {MAX_INTEGER:.0e}]"
        )
    if node.tag in (_INT, "tag:yaml.org,2002:float") and ":" in text:
        return (
            f"{excerpt(text)} is a base-60 number in YAML 1.1 ({yaml.safe_load(text)}) and text in YAML 1.2; "
            "write the number you mean"
        )
    if node.tag == _INT and number[:2].lower() == "0b":
        return f"{excerpt(text)} is binary in YAML 1.1 ({yaml.safe_load(text)}) and text in YAML 1.2; write the number you mean"
    if node.tag == _INT and len(number) > 1 and number[0] == "0" and number[1].lower() != "x":
        decimal = ("-" if text.startswith("-") else "") + (number.lstrip("0") or "0")
        return (
            f"{excerpt(text)} is octal in YAML 1.1 ({yaml.safe_load(text)}) and {decimal} in YAML 1.2; write the "
            "number you mean without a leading 0"
        )
    if node.tag == "tag:yaml.org,2002:bool" and text.lower() not in ("true", "false"):
        return f"{excerpt(text)} is {str(yaml.safe_load(text)).lower()} in YAML 1.1 and text in YAML 1.2; write true or false (or quote it)"
    return None


class _Refused(yaml.YAMLError):
    """A level file that breaks a limit of :class:`_LevelLoader` or uses YAML that is not level data."""

    def __init__(self, message: str, mark: yaml.Mark | None):
        super().__init__(message if mark is None else f"{message} (line {mark.line + 1}, column {mark.column + 1})")


class _LevelLoader(yaml.SafeLoader):
    """PyYAML's pure-Python safe loader, with limits: nesting depth, values after alias expansion, duplicate keys,
    plain data only (no sets, binary, ordered maps; dates stay text).

    The C loader is not used: its composer recurses in C, so deep nesting overflows the C stack.  The Python
    composer recurses too, but :meth:`compose_node` stops it at :data:`MAX_DEPTH`.  Aliases are counted as the
    values they stand for, so an alias chain is refused while it is read, before anything expands it.
    """

    def __init__(self, stream: str):
        super().__init__(stream)
        self._depth = 0  # of the node being composed (the document's root is 1)
        self._deepest = 0  # deepest level reached inside the anchored node being composed, aliases expanded
        self._nodes = 0
        self._anchored: dict[str, tuple[int, int]] = {}  # anchor -> (values it stands for, its height)
        self._checked: set[int] = set()  # lists whose scalars _check_scalars has checked

    def _count(self, nodes: int, deepest: int, mark: yaml.Mark) -> None:
        self._nodes += nodes
        self._deepest = max(self._deepest, deepest)
        if deepest > MAX_DEPTH:
            raise _Refused(f"nested deeper than {MAX_DEPTH} levels (the limit of a level file)", mark)
        if self._nodes > MAX_NODES:
            raise _Refused(
                f"more than {MAX_NODES} values, counting what each alias stands for (the limit of a level file)", mark
            )

    def compose_node(self, parent: yaml.Node | None, index: Any) -> yaml.Node:
        event = self.peek_event()
        if isinstance(event, yaml.AliasEvent):
            if event.anchor in self.anchors and event.anchor not in self._anchored:
                raise _Refused(
                    f"the alias *{excerpt(event.anchor)[1:-1]} lies inside the value it names: a level "
                    "cannot contain itself",
                    event.start_mark,
                )
            node = super().compose_node(parent, index)  # an undefined alias raises here
            nodes, height = self._anchored[event.anchor]
            self._count(nodes, self._depth + height, event.start_mark)
            return node
        self._depth += 1
        outer_deepest, self._deepest = self._deepest, self._depth
        start = self._nodes
        self._count(1, self._depth, event.start_mark)
        node = super().compose_node(parent, index)
        if event.anchor is not None:
            self._anchored[event.anchor] = (self._nodes - start, self._deepest - self._depth + 1)
        self._deepest = max(outer_deepest, self._deepest)
        self._depth -= 1
        return node

    def compose_mapping_node(self, anchor: str | None) -> yaml.MappingNode:
        node = super().compose_mapping_node(anchor)
        seen: set[tuple[str, str]] = set()
        for key, value in node.value:
            if isinstance(key, yaml.ScalarNode):
                if (key.tag, key.value) in seen:  # a later key would silently win over the earlier one
                    if key.tag == "tag:yaml.org,2002:merge":
                        raise _Refused(
                            "the merge key << is repeated (the last would silently win); merge several mappings "
                            "with one key: <<: [*a, *b]",
                            key.start_mark,
                        )
                    raise _Refused(f"the key {excerpt(key.value)} is repeated", key.start_mark)
                seen.add((key.tag, key.value))
            self._check_scalars(excerpt(key.value)[1:-1] if isinstance(key, yaml.ScalarNode) else "a key", value)
        return node

    def _check_scalars(self, where: str, node: yaml.Node) -> None:
        """Refuse a plain scalar in ``node`` (a mapping's value, or a list's items, named ``where``) that YAML 1.1
        reads otherwise than YAML 1.2 (:func:`_yaml11_form`) or whose integer Python would not read."""
        if isinstance(node, yaml.ScalarNode):
            problem = _yaml11_form(node)
            if problem:
                raise _Refused(f"{where}: {problem}", node.start_mark)
        elif isinstance(node, yaml.SequenceNode) and id(node) not in self._checked:
            self._checked.add(id(node))  # a list an alias repeats is checked once
            for i, item in enumerate(node.value):
                self._check_scalars(f"{where}[{i}]", item)

    def _not_level_data(self, node: yaml.Node) -> Any:
        raise _Refused(
            f"{node.tag.replace('tag:yaml.org,2002:', '!!')} is not level data (numbers, true/false, "
            "text, lists and mappings)",
            node.start_mark,
        )


def _construct_int(loader: _LevelLoader, node: yaml.ScalarNode) -> int:
    # a key is not checked by _check_scalars: an integer Python will not read (over 4,300 digits) is refused here
    if len(node.value) > MAX_INTEGER_DIGITS:
        raise _Refused(_yaml11_form(node) or "an integer too long to read", node.start_mark)
    return yaml.SafeLoader.construct_yaml_int(loader, node)


_LevelLoader.add_constructor(_INT, _construct_int)
for _tag in ("set", "binary", "omap", "pairs"):
    _LevelLoader.add_constructor(f"tag:yaml.org,2002:{_tag}", _LevelLoader._not_level_data)
# a date is text to a level (a description may start with one), not a datetime no field accepts
_LevelLoader.add_constructor("tag:yaml.org,2002:timestamp", yaml.SafeLoader.construct_yaml_str)
# YAML 1.2's numbers: PyYAML (YAML 1.1) reads 1e-3 and 1e6 as text, which strict fields would refuse
_LevelLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."),
)


def parse_level_text(data: bytes, label: str) -> dict[str, Any]:
    """The mapping in a level file's bytes, parsed within the limits above.  Raises :class:`LevelError`, one line
    naming ``label`` (the file) and what is wrong."""
    if len(data) > MAX_FILE_BYTES:
        raise LevelError(
            f"level file '{label}' is larger than {MAX_FILE_BYTES // 1024} KiB (the limit of a level file)"
        )
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise LevelError(
            f"level file '{label}' is not UTF-8 text: byte {err.object[err.start]:#04x} at offset "
            f"{err.start} ({err.reason})"
        ) from None
    try:
        loader = _LevelLoader(text)
    except yaml.reader.ReaderError as err:  # raised while checking the whole text, before any parsing
        raise LevelError(
            f"level file '{label}' is not valid YAML: character {err.character:#06x} at offset "
            f"{err.position} is not allowed"
        ) from None
    try:
        tree = loader.get_single_data()
    except _Refused as err:
        raise LevelError(f"level file '{label}': {err}") from None
    except yaml.YAMLError as err:
        raise LevelError(f"level file '{label}' is not valid YAML: {_yaml_problem(err)}") from None
    finally:
        loader.dispose()
    if tree is None:
        return {}
    if not isinstance(tree, dict):
        raise LevelError(f"level file '{label}' must hold a mapping at the top, not {type(tree).__name__}")
    return tree


def _yaml_problem(err: yaml.YAMLError) -> str:
    """A PyYAML error in one line of bounded length (its message can quote the file's text)."""
    problem = getattr(err, "problem", None) or str(err)
    mark = getattr(err, "problem_mark", None)
    where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
    text = " ".join(str(problem).split())
    return (text if len(text) <= 200 else text[:200] + "...") + where


#: the packaged level files, including the bases (``_defaults``, ``_testbed``): the only names ``extends:`` and
#: :func:`load_level` resolve inside the package
PACKAGED_FILES = tuple(
    sorted(entry.name[:-5] for entry in resources.files("evaaa.levels").iterdir() if entry.name.endswith(".yaml"))
)


def _is_path(name: str | os.PathLike) -> bool:
    """A level given as a file (``my.yaml``, ``levels/my.yml``, a ``Path``) rather than a packaged level's name."""
    return isinstance(name, os.PathLike) or str(name).endswith((".yaml", ".yml"))


def _read_file(source: str | Path) -> dict[str, Any]:
    """The mapping of a packaged level file (a name of :data:`PACKAGED_FILES`) or of a file the user named."""
    if isinstance(source, Path):
        try:
            if not source.is_file():  # a FIFO or a device would block or never end
                raise LevelError(
                    f"level file '{source}' cannot be read: "
                    + ("not a regular file" if source.exists() else "no such file")
                )
            # without blocking: a file swapped for a FIFO since the check above must not hang the open
            with open(os.open(source, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0)), "rb") as f:
                if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):
                    raise LevelError(f"level file '{source}' cannot be read: not a regular file")
                data = f.read(MAX_FILE_BYTES + 1)
        except OSError as err:
            raise LevelError(f"level file '{source}' cannot be read: {err.strerror or err}") from None
        return parse_level_text(data, str(source))
    return _packaged_file(source)


@functools.cache
def _packaged_file(name: str) -> dict[str, Any]:
    """A packaged file's mapping, parsed once (the pure-Python parser is 7x slower than libyaml's): shared, so
    never changed in place (:func:`_raw_level` copies its top, :func:`_set_dotted` what it changes)."""
    assert name in PACKAGED_FILES, name
    return parse_level_text(resources.files("evaaa.levels").joinpath(f"{name}.yaml").read_bytes(), f"{name}.yaml")


def _parent(parent: Any, child: str | Path, root: Path | None) -> str | Path:
    """Where ``extends: <parent>`` of ``child`` leads: a packaged file, or a file of the user's in ``root`` (the
    folder of the file the user named) or below it."""
    label = f"{child}" if isinstance(child, Path) else f"{child}.yaml"
    usage = (
        f"a packaged level ({', '.join(n for n in PACKAGED_FILES)}) or, in a file of your own, a .yaml file in "
        "its folder or below it"
    )
    if not isinstance(parent, str) or not parent:
        what = "null (leave extends out to start from _defaults)" if parent is None else excerpt(parent)
        raise LevelError(f"level file '{label}': extends must name {usage}; got {what}")
    if not _is_path(parent):
        if parent not in PACKAGED_FILES:
            raise LevelError(f"level file '{label}': extends: {excerpt(parent)} is not {usage}")
        return parent
    if not isinstance(child, Path) or root is None:
        raise LevelError(f"level file '{label}': a packaged level extends packaged levels only, not {excerpt(parent)}")
    path = child.parent / parent
    if not path.resolve().is_relative_to(root):  # '..', an absolute path or a link out of the folder
        raise LevelError(
            f"level file '{label}': extends: {excerpt(parent)} leads out of {root}; a level file "
            "extends files in its own folder or below it only"
        )
    return path


def _packaged_files() -> dict[str, dict[str, Any]]:
    """Every packaged level file that is a level (not a ``_base`` shared by others), by name."""
    return {name: _read_file(name) for name in PACKAGED_FILES if not name.startswith("_")}


def _listed_levels() -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The training levels and the testbeds, each in the ``order:`` their files give (then by name).

    A level's ``kind`` may come from the file it extends (the testbeds inherit it from ``_testbed``); ``order`` is
    the file's own."""
    files = _packaged_files()
    groups: dict[str, list[tuple[float, str]]] = {"training": [], "testbed": []}
    for name, data in files.items():
        kind = _raw_level(name).get("kind")
        if kind not in groups:
            raise LevelError(f"level file '{name}.yaml': kind must be training or testbed, got {kind!r}")
        groups[kind].append((data.get("order", math.inf), name))
    return tuple(n for _, n in sorted(groups["training"])), tuple(n for _, n in sorted(groups["testbed"]))


def _deep_merge(base: dict[str, Any], update: Mapping[str, Any]) -> dict[str, Any]:
    """``update`` merged into a shallow copy of ``base``; mappings merge key by key, ``None`` deletes a key.

    Nothing is deep-copied: both trees are freshly parsed and nested at most :data:`MAX_DEPTH` deep, and
    :func:`_set_dotted` copies what it changes."""
    out = dict(base)
    for key, value in update.items():
        if value is None:
            out.pop(key, None)
        elif isinstance(value, Mapping) and isinstance(out.get(key), dict):
            out[key] = _deep_merge(out[key], value)
        else:
            out[key] = value
    return out


def _raw_level(source: str | Path, _seen: tuple[str, ...] = (), root: Path | None = None) -> dict[str, Any]:
    """The merged tree of a level file and the files it extends (``root``: the folder a user's files stay in)."""
    key = str(source.resolve()) if isinstance(source, Path) else source
    if key in _seen:
        raise LevelError(f"level '{source}' extends itself through {' -> '.join(_seen + (key,))}")
    if len(_seen) >= MAX_EXTENDS:  # each file is a frame of this recursion, and up to 64 KiB read
        raise LevelError(
            f"level file '{_seen[0]}': its extends: chain is longer than {MAX_EXTENDS} files (the limit; the "
            f"packaged levels' longest is 9) at '{source}'"
        )
    data = dict(_read_file(source))
    if "extends" in data:
        parent = _parent(data.pop("extends"), source, root)
    else:
        parent = "_defaults" if source != "_defaults" else None
    for file_key in _FILE_KEYS:
        data.pop(file_key, None)
    if parent is None:
        return data
    return _deep_merge(_raw_level(parent, _seen + (key,), root), data)


def _set_dotted(tree: dict[str, Any], path: str, value: Any) -> None:
    keys = path.split(".")
    node = tree
    for i, key in enumerate(keys[:-1]):
        child = node.get(key)
        if not isinstance(child, dict):
            where = ".".join(keys[: i + 1])
            if child is None:
                allowed = ", ".join(sorted(node)) or "(none)"
                raise LevelError(f"override '{path}': '{where}' is not a field; allowed here: {allowed}")
            raise LevelError(f"override '{path}': '{where}' is a value ({excerpt(child)}), not a section")
        # a copy: the same mapping may sit elsewhere in the tree too (a YAML alias), which must not change with it
        node[key] = child = dict(child)
        node = child
    if value is None:  # as in level files, None removes an entry (e.g. a resource group)
        if keys[-1] not in node:
            raise LevelError(f"override '{path}': nothing to remove; present here: {', '.join(sorted(node))}")
        del node[keys[-1]]
    else:
        node[keys[-1]] = value


def _check_value(path: str, value: Any) -> None:
    """Refuse an override value nested deeper than a level file may be, or holding a cycle or a set (walked without
    recursion: the value may come from anywhere)."""
    stack, nodes = [(value, 1)], 0
    while stack:
        item, depth = stack.pop()
        nodes += 1
        if depth > MAX_DEPTH or nodes > MAX_NODES:
            raise LevelError(
                f"override '{path}': the value nests deeper than {MAX_DEPTH} levels or holds more than "
                f"{MAX_NODES} values (the limits of a level)"
            )
        if isinstance(item, (set, frozenset)):
            raise LevelError(f"override '{path}': expected a list, got a set {excerpt(item)}")
        if isinstance(item, Mapping):
            stack.extend((v, depth + 1) for v in item.values())
        elif isinstance(item, (list, tuple)):
            stack.extend((v, depth + 1) for v in item)


def _flatten_overrides(overrides: Mapping[str, Any], prefix: str = "", depth: int = 1) -> dict[str, Any]:
    """Accept both ``{"agent.move_speed": 10}`` and ``{"agent": {"move_speed": 10}}``; ``None`` removes an entry."""
    if depth > MAX_DEPTH:
        raise LevelError(f"override '{prefix[:200]}...' nests deeper than {MAX_DEPTH} levels")
    flat: dict[str, Any] = {}
    for key, value in overrides.items():
        if not isinstance(key, str) or not key:
            raise LevelError(f"override keys must be non-empty strings, got {excerpt(key)}")
        path = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(_flatten_overrides(value, path + ".", depth + 1))  # an empty mapping changes nothing
        else:
            _check_value(path, value)
            flat[path] = value
    return flat


def _model_at(loc: tuple[Any, ...]) -> type[BaseModel] | None:
    """The schema class that owns the field at ``loc`` (for listing allowed keys)."""
    model: Any = Level
    for part in loc:
        if isinstance(model, type) and issubclass(model, BaseModel):
            field = model.model_fields.get(str(part))
            if field is None:
                return None
            model = field.annotation
        elif getattr(model, "__origin__", None) is dict:
            model = model.__args__[1]
        else:
            return None
    if getattr(model, "__origin__", None) is dict:
        return None
    return model if isinstance(model, type) and issubclass(model, BaseModel) else None


def _format_errors(name: str, err: ValidationError) -> str:
    lines = []
    unknown: dict[tuple[Any, ...], list[str]] = {}  # a section's unknown fields, said on one line
    for e in err.errors():
        loc = tuple(e["loc"])
        where = ".".join(str(p) for p in loc)
        if e["type"] == "extra_forbidden":
            if loc[:-1] not in unknown:
                unknown[loc[:-1]] = []
                lines.append(loc[:-1])  # placeholder, filled in below
            unknown[loc[:-1]].append(where)
        elif e["type"] == "missing":
            lines.append(f"{where}: required field is missing")
        else:
            got = e.get("input")
            got_text = "" if isinstance(got, dict) else f" (got {excerpt(got)})"
            msg = e["msg"].removeprefix("Value error, ")
            # a rule across sections (loc empty) names its fields itself
            lines.append(f"{where}: {msg}{got_text}" if where else msg)
    for i, line in enumerate(lines):
        if isinstance(line, tuple):
            fields, owner = unknown[line], _model_at(line)
            named = ", ".join(excerpt(f)[1:-1] for f in fields[:5]) + (
                f" and {len(fields) - 5} more" if len(fields) > 5 else ""
            )
            lines[i] = (
                f"{named}: unknown field{'s' if len(fields) > 1 else ''}; allowed: "
                f"{', '.join(owner.model_fields) if owner else '?'}"
            )
    shown = lines[:10] + ([f"... and {len(lines) - 10} more"] if len(lines) > 10 else [])
    return f"invalid level '{name}':\n  " + "\n  ".join(shown)


def load_level(name: str | os.PathLike, overrides: Mapping[str, Any] | None = None) -> Level:
    """Load a level by name, or from the user's own YAML file (a path ending in ``.yaml``), apply dotted-path
    overrides and validate it.

    A file outside the package is read as the packaged ones are: it starts from ``_defaults.yaml`` and may
    ``extends:`` a packaged level by name (or another file in its own folder or below it).  Its level's name is the
    file's stem unless it says ``name:``.  Every file is parsed within limits (:data:`MAX_FILE_BYTES`,
    :data:`MAX_DEPTH`, :data:`MAX_NODES`), and only these files are read.

    >>> load_level("1-1", {"agent.move_speed": 10}).agent.move_speed
    10.0
    """
    root = None
    if isinstance(name, str) and name in _USER_FILES:
        source, label = _USER_FILES[name], name
    elif isinstance(name, (str, os.PathLike)) and _is_path(name):
        source, label = Path(name), Path(name).stem
    elif not isinstance(name, str) or name not in level_names():
        raise LevelError(
            f"unknown level {excerpt(name)}; available: {', '.join(level_names())}, or a path to a .yaml level file"
        )
    else:
        source = label = name
    if isinstance(source, Path):
        root = _resolved(source).parent
    raw = _raw_level(source, root=root)
    for path, value in _flatten_overrides(overrides or {}).items():
        if path in ("name", "kind"):
            raise LevelError(f"override '{path}' cannot change a level's identity")
        _set_dotted(raw, path, value)
    raw.setdefault("name", label)
    try:
        return Level.model_validate(raw)
    except ValidationError as err:
        raise LevelError(_format_errors(str(name), err)) from None


#: the packaged training levels and testbeds, in their files' ``order:``
LEVELS, TESTBEDS = _listed_levels()
#: levels from the user's own files that :func:`register_level` made loadable by name in this process
_USER_FILES: dict[str, Path] = {}


def _resolved(path: Path) -> Path:
    """``path`` made absolute, links followed; a loop of links is a LevelError (Path.resolve raises RuntimeError)."""
    try:
        return path.resolve()
    except RuntimeError:  # Python before 3.13: "Symlink loop from '<path>'", which would name the file twice
        raise LevelError(f"level file '{path}' cannot be read: Symlink loop (its links lead back to it)") from None
    except OSError as err:
        raise LevelError(f"level file '{path}' cannot be read: {err.strerror or err}") from None


def register_level(path: str | os.PathLike) -> str:
    """Make the level in the user's YAML file at ``path`` loadable by its name (the file's stem) in this process,
    e.g. for code that takes level names, and return the name.  The file is loaded (and so checked) at once."""
    path = _resolved(Path(path))
    if not _is_path(path):
        raise LevelError(f"a level file must end in .yaml or .yml, got '{path}'")
    name = path.stem
    if not LEVEL_NAME.fullmatch(name):  # it becomes a level name, and a run's folder (train.py level=file)
        raise LevelError(f"level file '{path}': its name {excerpt(name)} (the file's stem) must be {LEVEL_NAME_RULE}")
    if name in LEVELS + TESTBEDS or _USER_FILES.get(name, path) != path:
        taken = "a packaged level" if name in LEVELS + TESTBEDS else f"the file '{_USER_FILES[name]}'"
        raise LevelError(f"level file '{path}': its name '{name}' is already {taken}'s; rename the file")
    load_level(path)
    _USER_FILES[name] = path
    return name


def registered_levels() -> tuple[str, ...]:
    """The names :func:`register_level` made loadable in this process."""
    return tuple(_USER_FILES)


def level_names() -> tuple[str, ...]:
    """Every packaged level: the training levels, then the testbeds."""
    return LEVELS + TESTBEDS
