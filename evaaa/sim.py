"""The batched simulator: N worlds of one level in one process, stepped together.

This is the engine under both the TorchRL env and the gymnasium adapter.  It owns one compiled MuJoCo model,
one ``MjData`` per world, one shared renderer and the worlds' state (:class:`~evaaa.state.WorldState`), and runs
a decision's phases in order over the parts that own their data: the items (:mod:`evaaa.resources`), the
obstacles (:mod:`evaaa.obstacles`), the event triggers (:mod:`evaaa.triggers`), contact damage
(:mod:`evaaa.contact`), the predators (:mod:`evaaa.predator`), the sun and the light (:mod:`evaaa.daynight`), the
senses (:mod:`evaaa.sensors`) and the threads (:mod:`evaaa.workers`).  Work that is the same for every world runs
once over the batch in numpy; only the MuJoCo calls (the physics substeps and the render) loop over worlds.
Sensors and scripted agents read the worlds through the queries of :class:`evaaa.sensors.World`.

One decision:
1. the action sets the body's velocity or heading (Eat raises the eat intent);
2. five physics substeps of 0.02 s; contact impulses on the body become collision damage (a batch's worlds may be
   stepped in shares on threads of their own: see ``Simulator``'s ``threads``);
3. with eat intent, every item overlapping the eating sphere is consumed (its EV effect counts once) and
   respawns per its group's rule;
4. predators take their decision and move (attacks add damage); the sun moves on;
5. the thermal sensors are read at the new pose, the EVs advance, the episode end is decided, the reward is
   computed from the EVs;
6. the enabled sensors are read (a batch's frames drawn in shares on render threads, where there are some).
With one world and ``threads`` >= 2, 5 and the other senses of 6 run on a helper thread while the calling thread
draws the frame (MuJoCo's drawing calls free the GIL, so the helper's Python runs meanwhile).
"""

from __future__ import annotations

import math
import os
from operator import attrgetter

import mujoco
import numpy as np

from . import physiology as phys
from .contact import ContactDamage
from .daynight import DayNight
from .level import Level
from .obstacles import ObstacleLayout
from .predator import PREDATOR_HALF, NavGrid, Predators
from .render import BatchRenderer, SplitRenderer
from .resources import Resources
from .scene import GROUP_AGENT, build_model
from .sensors import SENSORS, Sensor, resolve_modalities
from .state import StepEvents, WorldState
from .thermal import FieldSampler, build_field, hotspot_cells
from .triggers import Triggers
from .workers import Workers
from .worldgen import (
    AGENT_HALF,
    ObstaclePool,
    PatrolArea,
    ResourcePool,
    place_landmarks,
    sample_agent_start,
    sample_predator_starts,
)
from .worlds import check_worlds, world_seeds

NUM_ACTIONS = 5
ACTION_NAMES: tuple[str, ...] = ("none", "forward", "left", "right", "eat")
NONE, FORWARD, LEFT, RIGHT, EAT = range(NUM_ACTIONS)
SUBSTEPS = 5


def usable_cores() -> int:
    """CPU cores this process may run on."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def default_threads() -> int:
    """How many threads a simulator works on at once unless told (see :class:`Simulator`).

    The environment variable ``EVAAA_THREADS`` (an integer >= 1) decides when set.  Otherwise 2 when the process may
    use two cores or more, else 1.  On two cores, two shares drew a batch's frames ~1.5x faster and stepped its
    physics ~1.6x faster; a single world, whose frame cannot be shared out, took about a sixth less time per decision with
    its physiology and other senses done on a helper while the frame was drawn.
    """
    setting = os.environ.get("EVAAA_THREADS", "").strip()
    if setting:
        try:
            threads = int(setting)
        except ValueError:
            threads = 0
        if threads < 1:
            raise ValueError(
                f"EVAAA_THREADS must be an integer >= 1 (1: everything in the calling thread), got {setting!r}"
            )
        return threads
    return 2 if usable_cores() >= 2 else 1


def _copy(value):
    """A copy of an observation: a numpy array, or a torch tensor (the Warp backend's frames)."""
    return value.clone() if hasattr(value, "clone") else value.copy()


def _state(name: str, doc: str) -> property:
    """A read-only view of one field of the simulator's :class:`WorldState`."""
    return property(attrgetter(f"state.{name}"), doc=doc)


class Simulator:
    """N worlds of one level.  Arrays are indexed by world first.  Physics and camera on the CPU (MuJoCo, OpenGL);
    :class:`evaaa.mjwarp.WarpSimulator` runs them on MuJoCo Warp (:func:`evaaa.backends.make_simulator`).

    Args:
        level: a validated level.
        num_worlds: worlds stepped together.
        modalities: observation keys to produce (None: all).
        seed: seed of the per-world generators (None: fresh entropy).
        worlds: which of the seed's disjoint sets of worlds (:mod:`evaaa.worlds`): ``train``, ``validation`` or
            ``test``.
        threads: how many threads work at once.  A batch is split into that many shares (at most one per world):
            the physics of each share on a thread (the calling one and helpers) and the frames of each on a render
            thread.  A single world with ``threads`` >= 2 (and vision on) draws its frame on the calling thread
            while a helper advances the EVs and reads the other senses.  1: everything in the calling thread;
            None: :func:`default_threads` (2 when two cores are free to the process).  Results are the same
            whatever the number.
    """

    backend = "cpu"

    def __init__(
        self,
        level: Level,
        num_worlds: int = 1,
        modalities=None,
        seed: int | None = None,
        threads: int | None = None,
        worlds: str = "train",
    ):
        if not isinstance(num_worlds, int) or isinstance(num_worlds, bool) or num_worlds < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_worlds!r}")
        self.worlds = check_worlds(worlds)
        self.level = level
        self.n = n = num_worlds
        self.modalities = resolve_modalities(modalities)
        self.params = level.physiology_params()
        self.pool = ResourcePool.from_level(level)
        self.obstacles = ObstaclePool.from_level(level)
        self.model, self.index = build_model(level, self.pool, self.obstacles)
        self.predators = Predators(level, num_worlds)
        self.datas = [mujoco.MjData(self.model) for _ in range(num_worlds)]
        self.sampler = FieldSampler(level)
        self.agent_z = AGENT_HALF
        self._renderer: BatchRenderer | SplitRenderer | None = None
        self._top_renderer: BatchRenderer | None = None
        if threads is None:
            threads = default_threads()
        if not isinstance(threads, int) or isinstance(threads, bool) or threads < 1:
            raise ValueError(f"threads must be an integer >= 1 (1: everything in the calling thread), got {threads!r}")
        # shares of a batch, or (one world) 2 when a helper works beside the frame being drawn
        self.threads = min(threads, max(num_worlds, 2) if "pixels" in self.modalities else num_worlds)
        self.workers = Workers(self.threads, num_worlds)

        # the parts of a decision, each with the level's fixed data it needs
        self.resources = Resources(level, self.pool, self.index.resource_mocap)
        self.obstacle_layout = ObstacleLayout(self.obstacles, self.index.obstacle_mocap)
        self.triggers = Triggers(level, self.params)
        self.contact = ContactDamage(level, self.model, self.index.agent_geom)
        self.daynight = DayNight(level.daynight, num_worlds)
        self._turn_rad = math.radians(level.agent.turn_degrees)
        self._move_speed = level.agent.move_speed

        self.state = WorldState.empty(
            n,
            self.pool.size_total,
            self.obstacles.size_total,
            len(self.triggers),
            level.thermal.grid,
            self.params.start,
            level.daynight.start_angle % 360.0,
        )
        self.last_obs: dict[str, np.ndarray] = {}
        self.last_info: dict[str, np.ndarray] = {}
        self._res_d2: np.ndarray | None = None
        self._all = np.arange(n)
        self._zeros_bool = np.zeros(n, dtype=bool)
        self._agent_z_col = np.full((n, 1), AGENT_HALF)

        self.sensors = [SENSORS[k](self) for k in self.modalities]
        self._reward_reads = self._reward_readers(phys.reward_reads(self.params.reward))
        if "pixels" in self.modalities:
            self._make_renderer()
        self.seed(seed)

    # ------------------------------------------------------------------------------------------------ set-up
    def _reward_readers(self, reads: tuple[str, ...]) -> dict[str, Sensor | None]:
        """What the level's reward function reads: a sensor of its own for each sensor key (read whether the agent
        observes that sense or not), None for each event of the decision (taken from its :class:`StepEvents`)."""
        unknown = [k for k in reads if k not in SENSORS and k not in phys.REWARD_EVENTS]
        if unknown:
            raise ValueError(
                f"reward {self.params.reward!r} reads {', '.join(unknown)}, which is neither a sensor key "
                f"({', '.join(SENSORS)}) nor an event ({', '.join(phys.REWARD_EVENTS)})"
            )
        return {k: SENSORS[k](self) if k in SENSORS else None for k in reads}

    def _make_renderer(self) -> None:
        v = self.level.sensors.vision
        adjust = self.daynight.light_world if self.daynight.enabled else None
        if min(self.threads, self.n) > 1:
            self._renderer = SplitRenderer(
                self.model, v.height, v.width, hidden_groups=(GROUP_AGENT,), adjust=adjust, threads=self.threads
            )
        else:
            self._renderer = BatchRenderer(self.model, v.height, v.width, hidden_groups=(GROUP_AGENT,), adjust=adjust)

    def seed(self, seed: int | None) -> None:
        """Give every world its own generator, derived from ``seed`` (None: fresh entropy) within this simulator's
        set of worlds (:mod:`evaaa.worlds`)."""
        self.rngs = [np.random.default_rng(s) for s in world_seeds(seed, self.worlds, self.n)]

    @property
    def observation_shapes(self) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
        return {s.key: (s.shape, s.dtype) for s in self.sensors}

    # ------------------------------------------------------------------------------------------------ queries
    # What sensors and scripted agents read (evaaa.sensors.World): views of the state, which readers must not
    # write to, and questions about it.
    pos = _state("pos", "(N, 2) floor position of each body's centre")
    heading_rad = _state("heading_rad", "(N,) compass heading of each body, radians")
    ev = _state("ev", "(N, 4) essential variables, ordered as evaaa.physiology.EV_NAMES")
    steps = _state("steps", "(N,) decisions taken this episode")
    res_xy = _state("res_xy", "(N, P, 2) position of each item slot")
    res_present = _state("res_present", "(N, P) whether each item slot holds an item")
    active_group = _state("active_group", "(N,) the grouped resource group holding items (-1: none)")
    obs_xy = _state("obs_xy", "(N, O, 2) position of each obstacle slot")
    obs_present = _state("obs_present", "(N, O) whether each obstacle slot is placed")
    fields = _state("fields", "(N, *grid) the floor's temperature field, without the day/night offset")
    field_offset = _state("field_offset", "(N,) the day/night offset over the whole floor")
    thermal_readings = _state("thermal_readings", "(N, 8) temperatures at each body's thermal sensors")
    sun_angle = _state("sun_angle", "(N,) the sun's angle, degrees (0: sunrise)")
    attacked = _state("attacked", "(N,) a predator attacked in the last decision")
    trigger_count = _state("trigger_count", "(N, E) times each event trigger fired this episode")
    trigger_inside = _state("trigger_inside", "(N, E) whether each body stands in each event trigger")
    triggered = _state("triggered", "(N,) an event trigger fired this episode")
    res_is_food = property(attrgetter("resources.is_food"), doc="(P,) which item slots are food")
    res_is_water = property(attrgetter("resources.is_water"), doc="(P,) which item slots are water")
    res_solid = property(attrgetter("resources.solid"), doc="(P,) which item slots the body collides with")

    def item_distances2(self) -> np.ndarray:
        """Squared horizontal distances (N, P) from each agent to each item slot, cached per decision."""
        if self._res_d2 is None:
            delta = self.state.res_xy - self.state.pos[:, None, :]
            self._res_d2 = delta[..., 0] ** 2 + delta[..., 1] ** 2
        return self._res_d2

    def can_eat(self, world: int, slot: int, pos: np.ndarray, heading) -> np.ndarray:
        """Whether the eating sphere of a body at ``pos`` (..., 2) facing ``heading`` (radians, compass) in
        ``world`` would overlap item ``slot`` (present or not): the test eating applies, for planners."""
        return self.resources.can_eat(self.state.res_xy[world, slot], slot, pos, heading)

    def obstacle_slices(self, world: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The floor rectangles of what blocks a body in ``world`` (its placed obstacles and present solid items):
        centres (K, 2), half-sides in their own frames (K, 2) and compass headings (K,), radians."""
        state, obstacles, pool = self.state, self.obstacles, self.pool
        placed = state.obs_present[world]
        solid = state.res_present[world] & self.resources.solid
        return (
            np.concatenate([state.obs_xy[world, placed], state.res_xy[world, solid]]),
            np.concatenate([obstacles.extents[placed, :2], pool.extents[solid, :2]]) / 2,
            np.concatenate([obstacles.heading[placed], pool.heading[solid]]),
        )

    def ground_temperature(self, world: int, xy: np.ndarray) -> np.ndarray:
        """The floor's temperature (day/night offset included) in ``world`` under points ``xy`` (..., 2)."""
        ix, iy = self.sampler.cells(xy)
        return self.state.fields[world, ix, iy] + self.state.field_offset[world]

    def is_night(self) -> np.ndarray:
        """(N,) whether it is night as predators see it (never without a day/night cycle)."""
        return self.daynight.night(self.state.sun_angle)

    def near_heat(self) -> np.ndarray:
        """(N,) whether each agent stands within 3 m of a hot obstacle's footprint."""
        near = self.obstacle_layout.near_heat(self.state)
        return self._zeros_bool if near is None else near

    # ------------------------------------------------------------------------------------------------ reset
    def reset(self, mask: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Start new episodes in the worlds where ``mask`` is True (all if None); return every world's observation."""
        if mask is None or not self.last_obs:  # the first reset starts every world
            worlds = np.arange(self.n)
        else:
            worlds = np.flatnonzero(np.asarray(mask).reshape(self.n))
        for w in worlds:
            self._reset_world(int(w))
        self._res_d2 = None
        obs = self._observe(worlds)
        self._info(StepEvents.none(self.n), end=np.zeros(self.n, dtype=np.int64), success=np.zeros(self.n, bool))
        return obs

    def _reset_world(self, w: int) -> None:
        """A new episode in world ``w``: obstacles, floor temperature, items, body, sun, predators and triggers, in
        the order they draw from the world's generator."""
        level, state, rng, obstacles = self.level, self.state, self.rngs[w], self.obstacles
        heat = self.obstacle_layout.reset_world(state, w, rng)
        state.fields[w] = build_field(level, hotspot_cells(level, rng), heat)
        self.resources.reset_world(state, w, rng)
        placed, present = state.obs_present[w], state.res_present[w]
        blockers = np.concatenate([state.obs_xy[w, placed], state.res_xy[w, present]])
        blocker_half = np.concatenate([obstacles.half[placed], self.resources.half[present]])
        xy, heading = sample_agent_start(level, rng, blockers, blocker_half)
        state.pos[w] = xy
        state.heading_rad[w] = math.radians(heading)
        state.ev[w] = self.params.start
        state.steps[w] = 0
        self.daynight.reset_world(state, w, rng)
        if self.predators.k:
            landmarks = place_landmarks(level, state.obs_xy[w, placed], obstacles.half[placed])
            grid = NavGrid.from_boxes(level.arena.size, *self.obstacle_slices(w), inflate=PREDATOR_HALF)
            start_xy, start_heading = sample_predator_starts(level, rng)
            self.predators.reset_world(w, rng, start_xy, start_heading, landmarks, grid)
        state.attacked[w] = False
        self.triggers.reset_world(state, w)
        data = self.datas[w]
        mujoco.mj_resetData(self.model, data)
        data.qpos[:3] = (xy[0], xy[1], math.pi / 2 - state.heading_rad[w])
        self.resources.write(state, w, data)
        self.obstacle_layout.write(state, w, data)
        self.predators.write(w, data, self.index.predator_mocap)
        mujoco.mj_forward(self.model, data)
        state.thermal_readings[w] = self._sample_thermal(np.array([w]))[0]

    # ------------------------------------------------------------------------------------------------ step
    def step(self, actions: np.ndarray):
        """Advance every world by one decision.

        Returns ``(obs, reward, terminated, truncated, info)``: dict of (N, ...) arrays, (N,) float32, (N,) bool,
        (N,) bool, dict of (N, ...) arrays.
        """
        actions = self._check_actions(actions)
        self.apply_actions(actions)
        return self.advance(actions)

    def _check_actions(self, actions) -> np.ndarray:
        a = np.asarray(actions).reshape(-1)
        if a.shape != (self.n,):
            raise ValueError(f"expected {self.n} actions (one per world), got shape {np.shape(actions)}")
        if a.dtype.kind not in "iu":
            if a.dtype.kind != "f" or not np.all(a == np.round(a)):
                raise ValueError(f"actions must be integers in 0..{NUM_ACTIONS - 1}, got {a.tolist()}")
            a = a.astype(np.int64)
        if not ((a >= 0) & (a < NUM_ACTIONS)).all():
            raise ValueError(f"actions must be in 0..{NUM_ACTIONS - 1} ({', '.join(ACTION_NAMES)}), got {a.tolist()}")
        return a

    def apply_actions(self, actions: np.ndarray) -> None:
        """1. Set each world's heading and velocity from its (validated) action; physics has not run yet."""
        turn = (actions == RIGHT).astype(np.float64) - (actions == LEFT)
        heading = (self.state.heading_rad + self._turn_rad * turn) % (2 * math.pi)
        self.state.heading_rad = heading
        speed = self._move_speed * (actions == FORWARD)
        vx, vy = (speed * np.sin(heading)).tolist(), (speed * np.cos(heading)).tolist()
        psi = (math.pi / 2 - heading).tolist()
        for w, data in enumerate(self.datas):
            data.qpos[2] = psi[w]
            qvel = data.qvel
            qvel[0] = vx[w]
            qvel[1] = vy[w]
            qvel[2] = 0.0

    def advance(self, actions: np.ndarray):
        """Phases 2 to 6 of a decision after :meth:`apply_actions` set the (validated) ``actions``; returns what
        :meth:`step` returns.  A caller that inspects or records the physics' starting state does so between the
        two."""
        state = self.state
        previous = state.pos.copy()
        # 2. physics and contact damage, the batch's shares at once
        damage = np.zeros(self.n)
        collided = np.zeros(self.n, dtype=bool)
        self.workers.each_share(self._physics, damage, collided)
        self._res_d2 = None  # distances to items changed with the pose
        # 3. eating, and the event triggers walked into on the way
        food_count, water_count = self._eat(actions)
        crossed = self.triggers.cross(state, previous) if len(self.triggers) else self._zeros_bool
        # 4. predators and the sun
        if self.predators.k:
            damage = damage + self._predators_act()
        self.daynight.advance(state)
        events = StepEvents(
            food_count=food_count,
            water_count=water_count,
            food_eaten=food_count > 0,
            water_eaten=water_count > 0,
            damage=damage,
            collided=collided,
            crossed=crossed,
            costly=(actions == FORWARD) | (actions == EAT),
        )  # what the reward charges for
        # 5. physiology and 6. senses; a single world's frame is drawn here while a helper does the rest
        if not self.workers.beside_frame:
            return self._conclude(events)
        frame, (obs, reward, terminated, truncated, info) = self.workers.while_drawing(
            lambda before_draw: self.render_eye(self._all, before_draw=before_draw),
            lambda: self._conclude(events, skip_pixels=True),
        )
        obs = {"pixels": frame, **obs}  # the canonical order: pixels first
        self.last_obs = obs
        return obs, reward, terminated, truncated, info

    def _physics(self, worlds, damage: np.ndarray, collided: np.ndarray) -> None:
        """2. The physics substeps of ``worlds``, adding each one's collision damage and whether it hit something."""
        model, pos, datas, contact = self.model, self.state.pos, self.datas, self.contact
        for w in worlds:
            data = datas[w]
            for _ in range(SUBSTEPS):
                mujoco.mj_step(model, data)
                if data.ncon:
                    d, hit = contact(data)
                    damage[w] += d
                    collided[w] |= hit
            # mj_step leaves positions computed before its last integration; bring them up to date
            mujoco.mj_kinematics(model, data)
            mujoco.mj_camlight(model, data)
            pos[w] = data.qpos[:2]

    def _eat(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """3. Eat where the action (or the level's auto-eating) says; (N,) items of food and of water eaten."""
        eating = actions == EAT if not self.level.agent.auto_eat else np.ones(self.n, dtype=bool)
        consumed = self.resources.consume(self.state, eating, self.rngs)
        if consumed is None:
            return np.zeros(self.n, dtype=np.int64), np.zeros(self.n, dtype=np.int64)
        for w in np.flatnonzero(consumed.any(axis=1)):
            self.resources.write(self.state, w, self.datas[w])
            mujoco.mj_kinematics(self.model, self.datas[w])
        self._res_d2 = None
        return (consumed & self.resources.is_food).sum(1), (consumed & self.resources.is_water).sum(1)

    def _predators_act(self) -> np.ndarray:
        """4. The predators decide and move; (N,) the damage of their attacks."""
        attack = self.predators.step(self.state.pos, self.is_night(), self.rngs)
        self.state.attacked = attack != 0
        for w, data in enumerate(self.datas):
            self.predators.write(w, data, self.index.predator_mocap)
            mujoco.mj_kinematics(self.model, data)
        return attack

    def _conclude(self, events: StepEvents, skip_pixels: bool = False):
        """Phases 5 and 6 of a decision: the EVs, the episode end, the reward, the senses (all but the frame with
        ``skip_pixels``) and the info."""
        # 5. physiology
        state, params = self.state, self.params
        state.steps += 1
        state.thermal_readings = self._sample_thermal(self._all)
        ev_before = state.ev
        thermal_sum = state.thermal_readings.sum(axis=1) - 8.0 * ev_before[:, 2]
        state.ev = phys.step_evs(
            ev_before,
            params,
            food_eaten=events.food_eaten,
            water_eaten=events.water_eaten,
            thermal_sum=thermal_sum,
            damage_taken=events.damage,
        )
        consumed = events.food_eaten | events.water_eaten
        end = phys.end_types(
            state.ev,
            params,
            resource_consumed=consumed,
            single_trial=self.level.episode.single_trial,
            steps=state.steps,
            max_steps=self.level.episode.max_steps,
        )
        happened = {"consumed": consumed, "collided": events.collided}  # phys.REWARD_EVENTS
        reads = {
            k: happened[k] if sensor is None else sensor.read(self._all) for k, sensor in self._reward_reads.items()
        }
        reward = phys.reward(ev_before, state.ev, end, params, costly=events.costly, **reads)
        truncated = end == phys.END_MAX_STEPS
        terminated = (end != phys.END_NONE) & ~truncated
        success = self._success(end, events)
        # 6. senses
        obs = self._observe(self._all, skip_pixels=skip_pixels)
        info = self._info(events, end=end, success=success)
        return obs, reward, terminated, truncated, info

    def _success(self, end: np.ndarray, events: StepEvents) -> np.ndarray:
        """(N,) whether an episode that ends here met its level's success rule (False while it goes on)."""
        rule = self.level.episode.success
        if rule.rule == "survive":
            return end == phys.END_MAX_STEPS
        if rule.rule == "consume_any":
            return end == phys.END_RESOURCE
        if rule.rule.startswith("consume"):
            eaten = events.food_eaten if rule.resource == "food" else events.water_eaten
            ok = (end == phys.END_RESOURCE) & eaten
            return ok & self.state.triggered if rule.rule == "consume_after_trigger" else ok
        return np.zeros(self.n, dtype=bool)

    # ------------------------------------------------------------------------------------------------ observation
    def _sample_thermal(self, worlds: np.ndarray) -> np.ndarray:
        state = self.state
        readings = self.sampler.sample(state.fields, state.pos[worlds], state.heading_rad[worlds], worlds)
        return readings + state.field_offset[worlds, None]

    def _observe(self, worlds: np.ndarray, skip_pixels: bool = False) -> dict[str, np.ndarray]:
        """Read the enabled sensors for ``worlds``; other worlds keep their last observation.  ``skip_pixels``:
        all but the frame (all worlds only; the caller draws it and completes ``last_obs``)."""
        full = len(worlds) == self.n
        obs = {}
        for sensor in self.sensors:
            if skip_pixels and sensor.key == "pixels":
                continue
            reading = sensor.read(worlds)
            if full:
                obs[sensor.key] = reading
            else:
                merged = _copy(self.last_obs[sensor.key])
                merged[worlds] = reading
                obs[sensor.key] = merged
        self.last_obs = obs
        return obs

    def render_eye(self, worlds: np.ndarray, before_draw=None) -> np.ndarray:
        """The agent's view in ``worlds``, (len(worlds), H, W, 3) uint8 (a fresh array every call).
        ``before_draw``: see :meth:`BatchRenderer.render` (only where the frames are drawn on this thread)."""
        if self._renderer is None:
            self._make_renderer()
        datas = self.datas if len(worlds) == self.n else [self.datas[w] for w in worlds]
        if self.daynight.enabled:
            self.daynight.plan(self.state.sun_angle[worlds])
        if before_draw is not None:
            return self._renderer.render(datas, self.index.eye_camera, before_draw=before_draw)
        return self._renderer.render(datas, self.index.eye_camera)

    def render_top(self, world: int = 0, size: int = 512) -> np.ndarray:
        """A top-down picture of one world, (size, size, 3) uint8 (for figures and videos; not an observation)."""
        if self._top_renderer is None or self._top_renderer.height != size:
            if self._top_renderer is not None:
                self._top_renderer.close()
            self._top_renderer = BatchRenderer(self.model, size, size)
        return self._top_renderer.render([self.datas[world]], self.index.top_camera)[0]

    # ------------------------------------------------------------------------------------------------ info
    def _info(self, events: StepEvents, *, end: np.ndarray, success: np.ndarray) -> dict[str, np.ndarray]:
        state = self.state
        ev = state.ev.astype(np.float32)
        info = {
            "position": np.concatenate([state.pos, self._agent_z_col], axis=1).astype(np.float32),
            "yaw": np.degrees(state.heading_rad).astype(np.float32).reshape(-1, 1),
            "satiation": ev[:, 0:1],
            "hydration": ev[:, 1:2],
            "temperature": ev[:, 2:3],
            "damage": ev[:, 3:4],
            "food_eaten": events.food_count.reshape(-1, 1),
            "water_eaten": events.water_count.reshape(-1, 1),
            "collision": events.collided.reshape(-1, 1),
            "damage_taken": events.damage.astype(np.float32).reshape(-1, 1),
            "attacked": state.attacked.reshape(-1, 1).copy(),
            "step_count": state.steps.reshape(-1, 1).copy(),
            "end_type": end.reshape(-1, 1),
            "success": success.reshape(-1, 1).copy(),
            "trigger_crossed": events.crossed.reshape(-1, 1).copy(),
            "near_heat": self.near_heat().reshape(-1, 1).copy(),
        }
        self.last_info = info
        return info

    # ------------------------------------------------------------------------------------------------ snapshots
    _PREDATOR_ARRAYS = ("xy", "heading", "state", "rest_count", "search_count", "route_age")

    def physics_states(self) -> np.ndarray:
        """(N, size) each world's MuJoCo integration state (``mjSTATE_INTEGRATION``)."""
        what = mujoco.mjtState.mjSTATE_INTEGRATION
        physics = np.empty((self.n, mujoco.mj_stateSize(self.model, what)))
        for w, data in enumerate(self.datas):
            mujoco.mj_getState(self.model, data, physics[w], what)
        return physics

    def snapshot(self) -> dict:
        """Everything needed to continue exactly from here (for checkpoints that resume mid-episode)."""
        return {
            "level": self.level.model_dump(mode="json"),
            "num_worlds": self.n,
            "arrays": self.state.arrays(),
            "physics": self.physics_states(),
            "rngs": [rng.bit_generator.state for rng in self.rngs],
            "predators": {name: getattr(self.predators, name).copy() for name in self._PREDATOR_ARRAYS}
            | {
                "routes": [[None if r is None else r.copy() for r in world] for world in self.predators.routes],
                # plain arrays, so that a checkpoint can hold them: the grids' cells, the patrol areas' landmarks
                "grids": [None if g is None else g.to_data() for g in self.predators.grids],
                "areas": [None if a is None else a.points.copy() for a in self.predators.areas],
                "landmarks": [p.copy() for p in self.predators.landmarks],
            },
            "last_obs": {k: _copy(v) for k, v in self.last_obs.items()},
            "last_info": {k: v.copy() for k, v in self.last_info.items()},
        }

    def restore(self, snapshot: dict) -> None:
        """Return to a state taken by :meth:`snapshot` (same level and number of worlds)."""
        saved = snapshot["level"]
        try:  # a snapshot from before a level field existed holds that field's default
            saved = Level.model_validate(saved).model_dump(mode="json")
        except ValueError:
            pass
        if snapshot["num_worlds"] != self.n or saved != self.level.model_dump(mode="json"):
            raise ValueError("this snapshot was taken from a simulator of another level or number of worlds")
        self.state.load(snapshot["arrays"])
        what = mujoco.mjtState.mjSTATE_INTEGRATION
        for w, data in enumerate(self.datas):
            mujoco.mj_setState(self.model, data, snapshot["physics"][w], what)
            mujoco.mj_forward(self.model, data)
        for rng, state in zip(self.rngs, snapshot["rngs"]):
            rng.bit_generator.state = state
        predators = snapshot["predators"]
        for name in self._PREDATOR_ARRAYS:
            setattr(self.predators, name, predators[name].copy())
        self.predators.routes = [[None if r is None else r.copy() for r in world] for world in predators["routes"]]
        self.predators.grids = [None if g is None else NavGrid.from_data(g) for g in predators["grids"]]
        self.predators.areas = [
            a if a is None or isinstance(a, PatrolArea) else PatrolArea(np.asarray(a)) for a in predators["areas"]
        ]
        self.predators.landmarks = [p.copy() for p in predators["landmarks"]]
        self.last_obs = {k: _copy(v) for k, v in snapshot["last_obs"].items()}
        self.last_info = {k: v.copy() for k, v in snapshot["last_info"].items()}
        self._res_d2 = None

    # ------------------------------------------------------------------------------------------------ state editing
    def set_agent_pose(self, world: int, xy, heading_deg: float) -> None:
        """Move world ``world``'s agent to ``xy`` facing compass ``heading_deg`` (for tests and scripted set-ups)."""
        state = self.state
        state.pos[world] = xy
        state.heading_rad[world] = math.radians(heading_deg % 360.0)
        data = self.datas[world]
        data.qpos[:3] = (xy[0], xy[1], math.pi / 2 - state.heading_rad[world])
        data.qvel[:] = 0.0
        mujoco.mj_forward(self.model, data)
        self._res_d2 = None
        self._refresh_observation(world)

    def place_item(self, world: int, slot: int, xy, present: bool = True) -> None:
        """Put resource ``slot`` of world ``world`` at ``xy`` (or remove it) (for tests and scripted set-ups)."""
        self.state.res_xy[world, slot] = xy
        self.state.res_present[world, slot] = present
        self.resources.write(self.state, world, self.datas[world])
        mujoco.mj_kinematics(self.model, self.datas[world])
        self._res_d2 = None
        self._refresh_observation(world)

    def _refresh_observation(self, world: int) -> None:
        self.state.thermal_readings[world] = self._sample_thermal(np.array([world]))[0]
        if self.last_obs:
            self._observe(np.array([world]))

    # ------------------------------------------------------------------------------------------------ closing
    def close(self) -> None:
        for r in (self._renderer, self._top_renderer):
            if r is not None:
                r.close()
        self._renderer = self._top_renderer = None
        self.workers.close()
