"""The level schema: what a level file may say, as typed, frozen pydantic models.

A level is data (``evaaa/levels/<name>.yaml``); :class:`Level` and its parts are what such a file means once
:mod:`evaaa.level_files` has read it, merged what it extends and applied the user's overrides.  Numbers, flags and
text are strict, every number is bounded (:mod:`evaaa.level_limits`), and the rules across fields (everything on
the floor, bodies in all, the predators' planning work) are checked when a level is validated.
"""

from __future__ import annotations

import math
import re
import reprlib
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    Strict,
    field_validator,
    model_validator,
)

from . import level_limits as limits
from .entities import OBSTACLE_KINDS, RESOURCE_KINDS
from .physiology import EV_NAMES, REWARD_FUNCTIONS, PhysiologyParams

__all__ = ["Level", "LevelError", "excerpt"]


class LevelError(ValueError):
    """A level name, level file or override is invalid.  The message names the field and what is allowed."""


# error messages quote what was given, cut short: a value can be a whole level, or an alias expanded millions of times
_EXCERPT = reprlib.Repr()
_EXCERPT.maxlevel, _EXCERPT.maxstring, _EXCERPT.maxother = 2, 60, 60
_EXCERPT.maxlist = _EXCERPT.maxtuple = _EXCERPT.maxset = _EXCERPT.maxfrozenset = _EXCERPT.maxdict = 4
EXCERPT_CHARS = 120


def excerpt(value: Any) -> str:
    """``repr(value)`` cut to at most :data:`EXCERPT_CHARS` characters (nesting, items and text elided with ...)."""
    text = _EXCERPT.repr(value)
    return text if len(text) <= EXCERPT_CHARS else text[: EXCERPT_CHARS - 3] + "..."


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


class _Spec(BaseModel):
    # every float of a level is finite: NaN or infinity anywhere would reach the observations or the reward
    # strict: YAML's true, '3' and !!binary are not numbers (lax pydantic would read them as 1.0 and 3.0)
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, strict=True)

    @field_validator("*", mode="after")
    @classmethod
    def _bounded(cls, value: Any) -> Any:
        limits.check_bounded(value)
        return value


# --------------------------------------------------------------------------------------------------- arena / agent
class Arena(_Spec):
    """The floor (centred on the origin; walking surface at z = 0) and its walls."""

    size: Annotated[
        tuple[
            Annotated[float, Field(ge=limits.MIN_ARENA_SIDE, le=limits.MAX_ARENA_SIDE)],
            Annotated[float, Field(ge=limits.MIN_ARENA_SIDE, le=limits.MAX_ARENA_SIDE)],
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
        if points > limits.MAX_LANDMARKS:
            raise ValueError(f"pattern places {points} landmark points; at most {limits.MAX_LANDMARKS}")
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
        if self.sigma > 0 and work > limits.MAX_SMOOTHING_WORK:
            raise ValueError(
                f"sigma = {self.sigma:g} cells over a grid of {gx} x {gy} cells is too much work for "
                f"every reset ({work:.2g} > {limits.MAX_SMOOTHING_WORK:.0e} cell operations): lower sigma or "
                "the grid"
            )
        spots = self.hotspots
        painted = spots.count * min(spots.size, gx) * min(spots.size, gy)
        if painted > limits.MAX_SMOOTHING_WORK:
            raise ValueError(
                f"hotspots.count = {spots.count} squares of hotspots.size = {spots.size} cells paint "
                f"{painted:.2g} cells at every reset; at most {limits.MAX_SMOOTHING_WORK:.0e}"
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
        if solid > limits.MAX_SOLID_BODIES:
            raise ValueError(
                f"the obstacles' count and the solid resources' (ponds) count add up to {solid} bodies "
                f"the agent collides with; at most {limits.MAX_SOLID_BODIES} in all"
            )
        items = sum(g.count for g in self.resources.values())
        if items > limits.MAX_ITEMS:
            raise ValueError(f"the resources' count adds up to {items} items; at most {limits.MAX_ITEMS} in all")
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
        plans = sum(g.count * (1 / g.search_interval + 1 / limits.REPLAN_EVERY) for g in self.predators.values())
        if cells * plans > limits.MAX_PLANNING_WORK:
            named = [f"{n}: count {g.count}, search_interval {g.search_interval}" for n, g in self.predators.items()]
            groups = "; ".join(named[:3]) + (f"; and {len(named) - 3} more" if len(named) > 3 else "")
            raise ValueError(
                f"predators plan routes over {cells * plans:.2g} grid cells a decision (arena.size "
                f"{self.arena.size[0]:g} x {self.arena.size[1]:g} = {cells} cells of 1 m, times the predators' "
                f"count x (1 / search_interval + 1 / {limits.REPLAN_EVERY}), predators {groups}); at most "
                f"{limits.MAX_PLANNING_WORK:.0e}: a smaller arena, fewer predators or a longer search_interval"
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
