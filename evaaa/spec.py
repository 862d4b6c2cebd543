"""Level specifications: the typed schema of a level file, and loading with clear errors.

A level is data (``evaaa/levels/<name>.yaml``); this module owns what a level may say and how a file, the
files it extends and the user's overrides are merged and validated.  Every level starts from
``levels/_defaults.yaml`` (the values common to all levels), may ``extends:`` another level, and may be changed
by dotted-path overrides (``{"agent.move_speed": 10}``).  Any mistake raises :class:`LevelError` naming the
field and what it accepts.
"""

from __future__ import annotations

import copy
import math
import os
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from .entities import OBSTACLE_KINDS, RESOURCE_KINDS
from .physiology import REWARDS

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


#: A closed interval ``[low, high]``.
Interval = Annotated[tuple[float, float], AfterValidator(_ordered)]
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
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    @field_validator("*", mode="after")
    @classmethod
    def _bounded(cls, value: Any) -> Any:
        _check_bounded(value)
        return value


# --------------------------------------------------------------------------------------------------- arena / agent
class Arena(_Spec):
    """The floor (centred on the origin; walking surface at z = 0) and its walls."""

    size: tuple[Annotated[float, Field(ge=MIN_ARENA_SIDE, le=MAX_ARENA_SIDE)],
                Annotated[float, Field(ge=MIN_ARENA_SIDE, le=MAX_ARENA_SIDE)]]
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
    start_position: tuple[float, float]
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
    def _start_inside_bounds(self) -> "Physiology":
        for ev in EVs.model_fields:
            lo, hi = getattr(self.bounds, ev)
            value = getattr(self.start, ev)
            if not lo <= value <= hi:
                raise ValueError(f"start.{ev} = {value} lies outside bounds.{ev} = [{lo}, {hi}]")
        return self


# --------------------------------------------------------------------------------------------------- resources
Extents = Annotated[tuple[Positive, Positive, Positive], Field(description="width (x), depth (y), height (z)")]


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
    scale: tuple[Interval, Interval, Interval] = ((1.0, 1.0), (1.0, 1.0), (1.0, 1.0))
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

    pattern: list[list[Annotated[int, Field(ge=0, le=10)]]]
    radius: Positive = 1.5
    padding: NonNegative = 2.0

    @model_validator(mode="after")
    def _rectangular(self) -> "Landmarks":
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
    size: tuple[Positive, Positive]
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
    grid: tuple[Annotated[int, Field(ge=1, le=1000)], Annotated[int, Field(ge=1, le=1000)]]
    base_temperature: float
    hotspots: Hotspots
    #: Gaussian smoothing in cells (0: none)
    sigma: Annotated[float, Field(ge=0, le=100)]
    #: thermoception reads T_sensor - body temperature instead of T_sensor
    relative: bool

    @model_validator(mode="after")
    def _smoothing_affordable(self) -> "Thermal":
        # the field is rebuilt and smoothed at every reset: two passes of a 2*ceil(3 sigma)+1 kernel over the grid
        gx, gy = self.grid
        work = 2 * gx * gy * (2 * math.ceil(3 * self.sigma) + 1)
        if self.sigma > 0 and work > MAX_SMOOTHING_WORK:
            raise ValueError(f"sigma = {self.sigma:g} cells over a grid of {gx} x {gy} cells is too much work for "
                             f"every reset ({work:.2g} > {MAX_SMOOTHING_WORK:.0e} cell operations): lower sigma or "
                             "the grid")
        spots = self.hotspots
        painted = spots.count * min(spots.size, gx) * min(spots.size, gy)
        if painted > MAX_SMOOTHING_WORK:
            raise ValueError(f"hotspots.count = {spots.count} squares of hotspots.size = {spots.size} cells paint "
                             f"{painted:.2g} cells at every reset; at most {MAX_SMOOTHING_WORK:.0e}")
        return self


# --------------------------------------------------------------------------------------------------- sensors
class Vision(_Spec):
    width: Annotated[int, Field(ge=8, le=1024)]
    height: Annotated[int, Field(ge=8, le=1024)]
    fovy: Annotated[float, Field(gt=0, lt=180)]
    near: Positive
    far: Positive

    @model_validator(mode="after")
    def _near_before_far(self) -> "Vision":
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
    def _rays_fill_sectors(self) -> "CollisionSensor":
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
    def _resource_when_consuming(self) -> "Success":
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
    name: Literal[REWARDS]  # type: ignore[valid-type]  # evaaa.physiology.REWARD_FUNCTIONS
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


# --------------------------------------------------------------------------------------------------- level
class Level(_Spec):
    name: str
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

    @model_validator(mode="after")
    def _inside_arena(self) -> "Level":
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
    def _entities_fit(self) -> "Level":
        solid = sum(g.count for g in self.obstacles.values()) + sum(
            g.count for g in self.resources.values() if getattr(RESOURCE_KINDS.get(g.kind), "solid", False))
        if solid > MAX_SOLID_BODIES:
            raise ValueError(f"the obstacles' count and the solid resources' (ponds) count add up to {solid} bodies "
                             f"the agent collides with; at most {MAX_SOLID_BODIES} in all")
        items = sum(g.count for g in self.resources.values())
        if items > MAX_ITEMS:
            raise ValueError(f"the resources' count adds up to {items} items; at most {MAX_ITEMS} in all")
        return self

    @model_validator(mode="after")
    def _predators_need_landmarks(self) -> "Level":
        if any(g.count for g in self.predators.values()) and self.landmarks is None:
            raise ValueError("predators patrol the convex hull of the landmarks: set landmarks.pattern")
        return self

    @model_validator(mode="after")
    def _agent_starts_on_the_floor(self) -> "Level":
        # the body's centre keeps half its width (worldgen.AGENT_HALF, 0.5 m) from the floor's edge; a random start
        # falls back to start_position when its box is full, so that must lie on the floor either way
        a = self.agent
        hx, hy = self.arena.size[0] / 2 - 0.5, self.arena.size[1] / 2 - 0.5
        x, y = a.start_position
        if abs(x) > hx or abs(y) > hy:
            raise ValueError(f"agent.start_position = [{x:g}, {y:g}] is off the floor: the body's centre must lie "
                             f"within x in [{-hx:g}, {hx:g}], y in [{-hy:g}, {hy:g}] "
                             f"(arena.size {list(self.arena.size)})")
        if a.start == "random":
            for axis, (lo, hi), half in (("x", a.spawn_x, hx), ("y", a.spawn_y, hy)):
                if hi < -half or lo > half:
                    raise ValueError(f"agent.spawn_{axis} = [{lo:g}, {hi:g}] misses the floor, where the body's "
                                     f"centre lies within [{-half:g}, {half:g}] (arena.size {list(self.arena.size)})")
        return self

    @model_validator(mode="after")
    def _far_plane_beyond_near(self) -> "Level":
        near = self.sensors.vision.near
        dn = self.daynight
        if dn.enabled:
            for name in ("day_far", "night_far"):
                far = getattr(dn, name)
                if far <= near:
                    raise ValueError(f"daynight.{name} ({far:g}) must exceed sensors.vision.near ({near:g}): the "
                                     "far plane would hide everything")
        return self


# --------------------------------------------------------------------------------------------------- loading
#: libyaml's safe loader where PyYAML was built with it (same documents, about 7x faster than the Python one)
_YAML_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
#: keys of a level file about the file itself, not the level: they are not inherited through ``extends:``
_FILE_KEYS = ("extends", "order")


def _is_path(name: str | os.PathLike) -> bool:
    """A level given as a file (``my.yaml``, ``levels/my.yml``, a ``Path``) rather than a packaged level's name."""
    return isinstance(name, os.PathLike) or str(name).endswith((".yaml", ".yml"))


def _read_yaml(name: str | os.PathLike) -> dict[str, Any]:
    """The mapping of a packaged level file (by name) or of the user's file (by path); safe YAML only."""
    if _is_path(name):
        path = Path(name)
        try:
            text = path.read_text()
        except OSError as err:
            raise LevelError(f"level file '{path}' cannot be read: {err.strerror or err}") from None
        label = str(path)
    else:
        try:
            text = resources.files("evaaa.levels").joinpath(f"{name}.yaml").read_text()
        except FileNotFoundError:
            raise LevelError(f"level file '{name}.yaml' is missing from evaaa/levels") from None
        label = f"{name}.yaml"
    try:
        data = yaml.load(text, Loader=_YAML_LOADER) or {}
    except yaml.YAMLError as err:
        raise LevelError(f"level file '{label}' is not valid YAML: {err}") from None
    if not isinstance(data, dict):
        raise LevelError(f"level file '{label}' must hold a mapping at the top")
    return data


def _packaged_files() -> dict[str, dict[str, Any]]:
    """Every packaged level file that is a level (not a ``_base`` shared by others), by name."""
    return {entry.name[:-5]: _read_yaml(entry.name[:-5])
            for entry in resources.files("evaaa.levels").iterdir()
            if entry.name.endswith(".yaml") and not entry.name.startswith("_")}


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
    """Merge ``update`` into a copy of ``base``; mappings merge key by key, ``None`` deletes a key."""
    out = copy.deepcopy(base)
    for key, value in update.items():
        if value is None:
            out.pop(key, None)
        elif isinstance(value, Mapping) and isinstance(out.get(key), dict):
            out[key] = _deep_merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def _raw_level(name: str | os.PathLike, _seen: tuple[str, ...] = ()) -> dict[str, Any]:
    key = str(Path(name).resolve()) if _is_path(name) else name
    if key in _seen:
        raise LevelError(f"level '{name}' extends itself through {' -> '.join(_seen + (key,))}")
    data = _read_yaml(name)
    parent = data.pop("extends", "_defaults" if name != "_defaults" else None)
    for file_key in _FILE_KEYS:
        data.pop(file_key, None)
    if parent is None:
        return data
    if not isinstance(parent, str):
        raise LevelError(f"level '{name}': extends must be a level's name or a file, got {parent!r}")
    if _is_path(parent) and _is_path(name):  # a user's file may extend another file beside it
        parent = Path(name).parent / parent
    return _deep_merge(_raw_level(parent, _seen + (key,)), data)


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
            raise LevelError(f"override '{path}': '{where}' is a value ({child!r}), not a section")
        node = child
    if value is None:  # as in level files, None removes an entry (e.g. a resource group)
        if keys[-1] not in node:
            raise LevelError(f"override '{path}': nothing to remove; present here: {', '.join(sorted(node))}")
        del node[keys[-1]]
    else:
        node[keys[-1]] = value


def _flatten_overrides(overrides: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Accept both ``{"agent.move_speed": 10}`` and ``{"agent": {"move_speed": 10}}``; ``None`` removes an entry."""
    flat: dict[str, Any] = {}
    for key, value in overrides.items():
        if not isinstance(key, str) or not key:
            raise LevelError(f"override keys must be non-empty strings, got {key!r}")
        path = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(_flatten_overrides(value, path + "."))  # an empty mapping changes nothing
        else:
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
    for e in err.errors():
        loc = tuple(e["loc"])
        where = ".".join(str(p) for p in loc)
        if e["type"] == "extra_forbidden":
            owner = _model_at(loc[:-1])
            allowed = ", ".join(owner.model_fields) if owner else "?"
            lines.append(f"{where}: unknown field; allowed: {allowed}")
        elif e["type"] == "missing":
            lines.append(f"{where}: required field is missing")
        else:
            got = e.get("input")
            got_text = "" if isinstance(got, dict) else f" (got {got!r})"
            msg = e["msg"].removeprefix("Value error, ")
            # a rule across sections (loc empty) names its fields itself
            lines.append(f"{where}: {msg}{got_text}" if where else msg)
    return f"invalid level '{name}':\n  " + "\n  ".join(lines)


def load_level(name: str | os.PathLike, overrides: Mapping[str, Any] | None = None) -> Level:
    """Load a level by name, or from the user's own YAML file (a path ending in ``.yaml``), apply dotted-path
    overrides and validate it.

    A file outside the package is read as the packaged ones are: it starts from ``_defaults.yaml`` and may
    ``extends:`` a packaged level by name (or another file, relative to its own folder).  Its level's name is the
    file's stem unless it says ``name:``.

    >>> load_level("1-1", {"agent.move_speed": 10}).agent.move_speed
    10.0
    """
    if isinstance(name, str) and name in _USER_FILES:
        name, label = _USER_FILES[name], name
    elif isinstance(name, (str, os.PathLike)) and _is_path(name):
        label = Path(name).stem
    elif not isinstance(name, str) or name not in level_names():
        raise LevelError(f"unknown level {name!r}; available: {', '.join(level_names())}, or a path to a .yaml "
                         "level file")
    else:
        label = name
    raw = _raw_level(name)
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


def register_level(path: str | os.PathLike) -> str:
    """Make the level in the user's YAML file at ``path`` loadable by its name (the file's stem) in this process,
    e.g. for code that takes level names, and return the name.  The file is loaded (and so checked) at once."""
    path = Path(path).resolve()
    if not _is_path(path):
        raise LevelError(f"a level file must end in .yaml or .yml, got '{path}'")
    name = path.stem
    if name in LEVELS + TESTBEDS or _USER_FILES.get(name, path) != path:
        taken = "a packaged level" if name in LEVELS + TESTBEDS else f"the file '{_USER_FILES[name]}'"
        raise LevelError(f"level file '{path}': its name '{name}' is already {taken}'s; rename the file")
    load_level(path)
    _USER_FILES[name] = path
    return name


def level_names() -> tuple[str, ...]:
    """Every packaged level: the training levels, then the testbeds."""
    return LEVELS + TESTBEDS
