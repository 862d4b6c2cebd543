"""The batched simulator: N worlds of one level in one process, stepped together.

This is the engine under both the TorchRL env and the gymnasium adapter.  It owns one compiled MuJoCo model,
one ``MjData`` per world, one shared renderer and the per-world state arrays (pose, EVs, resources, thermal
field).  Work that is the same for every world runs once over the batch in numpy; only the MuJoCo calls (the
physics substeps, the rays and the render) loop over worlds.

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
from concurrent.futures import ThreadPoolExecutor

import mujoco
import numpy as np

from . import daynight
from . import physiology as phys
from .entities import OBSTACLE_KINDS, PREDATOR, RESOURCE_KINDS, footprint_half
from .predator import PREDATOR_HALF, NavGrid, Predators
from .render import BatchRenderer, SplitRenderer
from .scene import GROUP_AGENT, build_model
from .sensors import SENSORS, resolve_modalities
from .spec import Level
from .thermal import FieldSampler, build_field, hotspot_cells
from .worldgen import (
    AGENT_HALF,
    FOOD,
    PARKED_Z,
    WATER,
    ObstaclePool,
    ResourcePool,
    draw_grouped,
    place_landmarks,
    place_obstacles,
    place_resources,
    resources_present,
    sample_agent_start,
    sample_predator_starts,
)

NUM_ACTIONS = 5
ACTION_NAMES: tuple[str, ...] = ("none", "forward", "left", "right", "eat")
NONE, FORWARD, LEFT, RIGHT, EAT = range(NUM_ACTIONS)
SUBSTEPS = 5
#: the eating sphere's centre sits this far below the body centre
EAT_DROP = 0.065
_NIGHT_FOG = (0.02, 0.02, 0.05, 1.0)
#: "near heat" in the episode records: within this many metres of a hot obstacle's footprint
NEAR_HEAT = 3.0


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
            raise ValueError(f"EVAAA_THREADS must be an integer >= 1 (1: everything in the calling thread), "
                             f"got {setting!r}")
        return threads
    return 2 if usable_cores() >= 2 else 1


class Simulator:
    """N worlds of one level.  Arrays are indexed by world first.

    Args:
        level: a validated level.
        num_worlds: worlds stepped together.
        modalities: observation keys to produce (None: all).
        seed: seed of the per-world generators (None: fresh entropy).
        threads: how many threads work at once.  A batch is split into that many shares (at most one per world):
            the physics of each share on a thread (the calling one and helpers) and the frames of each on a render
            thread.  A single world with ``threads`` >= 2 (and vision on) draws its frame on the calling thread
            while a helper advances the EVs and reads the other senses.  1: everything in the calling thread;
            None: :func:`default_threads` (2 when two cores are free to the process).  Results are the same
            whatever the number.
    """

    def __init__(self, level: Level, num_worlds: int = 1, modalities=None, seed: int | None = None,
                 threads: int | None = None):
        if not isinstance(num_worlds, int) or isinstance(num_worlds, bool) or num_worlds < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_worlds!r}")
        self.level = level
        self.n = num_worlds
        self.modalities = resolve_modalities(modalities)
        self.params = phys.PhysiologyParams.from_level(level)
        self.pool = ResourcePool.from_level(level)
        self.obstacles = ObstaclePool.from_level(level)
        self.model, self.index = build_model(level, self.pool, self.obstacles)
        self.predators = Predators(level, num_worlds)
        self.datas = [mujoco.MjData(self.model) for _ in range(num_worlds)]
        self.dt = float(self.model.opt.timestep)
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
        # helper threads, made when first needed: in a batch they step the physics of all shares but the first
        # (mj_step frees the GIL); beside a single world's frame, one does the physiology and the other senses
        self._helpers: ThreadPoolExecutor | None = None

        n, p = num_worlds, self.pool.size_total
        a = level.agent
        self.turn_rad = math.radians(a.turn_degrees)
        self.move_speed = a.move_speed
        self.eat_radius2 = a.eat_radius**2
        self.eat_offset = a.eat_offset
        self.res_half3 = self.pool.extents / 2  # (P, 3) half-extents in each item's own frame
        self.res_half = np.zeros((p, 2))  # (P, 2) half-sides of the axis-aligned box around each footprint
        for kind in set(self.pool.kind):
            m = self.pool.kind == kind
            self.res_half[m] = footprint_half(RESOURCE_KINDS[kind], self.pool.extents[m], self.pool.heading[m])
        self.res_cos, self.res_sin = np.cos(self.pool.heading), np.sin(self.pool.heading)
        self.res_is_food = self.pool.feeds == FOOD
        self.res_is_water = self.pool.feeds == WATER
        self.res_respawns = self.pool.respawn == "random"
        self.res_grouped = self.pool.respawn == "grouped"
        self.res_solid = self.pool.solid
        dmg = a.collision_damage
        self._damage_rule = (dmg.constant, dmg.rate, dmg.offset, dmg.cap, dmg.event_threshold)

        # per-world state
        self.pos = np.zeros((n, 2))
        self.heading_rad = np.zeros(n)  # compass heading
        self.ev = np.tile(self.params.start, (n, 1))
        self.steps = np.zeros(n, dtype=np.int64)
        self.res_xy = np.zeros((n, p, 2))
        self.res_present = np.zeros((n, p), dtype=bool)
        self.fields = np.zeros((n, *level.thermal.grid))
        self.field_offset = np.zeros(n)  # day/night offset added to the whole field
        self.thermal_readings = np.zeros((n, 8))
        self.active_group = np.full(n, -1, dtype=np.int64)  # the grouped resource group holding items
        self.obs_xy = np.zeros((n, self.obstacles.size_total, 2))
        self.obs_present = np.zeros((n, self.obstacles.size_total), dtype=bool)
        self.sun_angle = np.full(n, level.daynight.start_angle % 360.0)
        self.attacked = np.zeros(n, dtype=bool)
        events = list(level.events.values())
        self._trigger_xy = np.array([(e.x, e.y) for e in events], dtype=np.float64).reshape(-1, 2)
        self._trigger_cos = np.cos(np.radians([e.heading for e in events]))
        self._trigger_sin = np.sin(np.radians([e.heading for e in events]))
        # the body enters a trigger when any part of it does: grow the box by the body's half-width
        self._trigger_half = np.array([e.size for e in events], dtype=np.float64).reshape(-1, 2) / 2 + AGENT_HALF
        self._trigger_max = np.array([e.max_count for e in events], dtype=np.int64)
        self._trigger_set = np.array([[np.nan if getattr(e.set, ev) is None else getattr(e.set, ev)
                                       for ev in phys.EV_NAMES] for e in events], dtype=np.float64).reshape(-1, 4)
        self.trigger_count = np.zeros((n, len(events)), dtype=np.int64)
        self.trigger_inside = np.zeros((n, len(events)), dtype=bool)
        self.triggered = np.zeros(n, dtype=bool)  # an event fired this episode
        self.last_obs: dict[str, np.ndarray] = {}
        self._res_d2: np.ndarray | None = None
        self._all = np.arange(n)
        self._zeros_bool = np.zeros(n, dtype=bool)
        self._agent_z_col = np.full((n, 1), AGENT_HALF)
        # vertical gap between the eating sphere's centre and each item's box (it sits a little below the eye)
        self._eat_dz2 = np.maximum(np.abs(AGENT_HALF - EAT_DROP - self.pool.centre_z()) - self.res_half3[:, 2],
                                   0.0) ** 2
        self._obs_z = self.obstacles.centre_z()
        self._heat = self.obstacles.temperature != 0
        self._heat_half = np.zeros((self.obstacles.size_total, 2))
        for kind in set(self.obstacles.kind):
            m = self.obstacles.kind == kind
            self._heat_half[m] = footprint_half(OBSTACLE_KINDS[kind], self.obstacles.extents[m],
                                                self.obstacles.heading[m])

        self.sensors = [SENSORS[k](self) for k in self.modalities]
        self._shaping_senses = (SENSORS["olfaction"](self), SENSORS["thermoception"](self))
        if "pixels" in self.modalities:
            self._make_renderer()
        self.seed(seed)

    # ------------------------------------------------------------------------------------------------ set-up
    def _make_renderer(self) -> None:
        v = self.level.sensors.vision
        adjust = self._light_world if self.level.daynight.enabled else None
        if min(self.threads, self.n) > 1:
            self._renderer = SplitRenderer(self.model, v.height, v.width, hidden_groups=(GROUP_AGENT,),
                                           adjust=adjust, threads=self.threads)
        else:
            self._renderer = BatchRenderer(self.model, v.height, v.width, hidden_groups=(GROUP_AGENT,),
                                           adjust=adjust)

    def seed(self, seed: int | None) -> None:
        """Give every world its own generator, derived from ``seed`` (None: fresh entropy)."""
        children = np.random.SeedSequence(seed).spawn(self.n)
        self.rngs = [np.random.default_rng(s) for s in children]

    @property
    def observation_shapes(self) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
        return {s.key: (s.shape, s.dtype) for s in self.sensors}

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
        self._info_reset(worlds)
        return obs

    def _reset_world(self, w: int) -> None:
        level, pool, rng = self.level, self.pool, self.rngs[w]
        obstacles = self.obstacles
        self.obs_xy[w], self.obs_present[w] = place_obstacles(obstacles, rng)
        hot = self._heat & self.obs_present[w]
        heat = np.column_stack([
            self.obs_xy[w, hot, 0] - self._heat_half[hot, 0], self.obs_xy[w, hot, 0] + self._heat_half[hot, 0],
            self.obs_xy[w, hot, 1] - self._heat_half[hot, 1], self.obs_xy[w, hot, 1] + self._heat_half[hot, 1],
            obstacles.temperature[hot],
        ])
        self.fields[w] = build_field(level, hotspot_cells(level, rng), heat)
        self.active_group[w] = draw_grouped(pool, rng)
        self.res_xy[w] = place_resources(pool, rng)
        self.res_present[w] = resources_present(pool, self.active_group[w])
        placed = self.obs_present[w]
        blockers = np.concatenate([self.obs_xy[w, placed], self.res_xy[w, self.res_present[w]]])
        blocker_half = np.concatenate([obstacles.half[placed], self.res_half[self.res_present[w]]])
        xy, heading = sample_agent_start(level, rng, blockers, blocker_half)
        self.pos[w] = xy
        self.heading_rad[w] = math.radians(heading)
        self.ev[w] = self.params.start
        self.steps[w] = 0
        dn = level.daynight
        if dn.enabled:
            self.sun_angle[w] = rng.uniform(0.0, 360.0) if dn.random_start else dn.start_angle % 360.0
        self.field_offset[w] = self._temperature_offset(self.sun_angle[w: w + 1])[0]
        if self.predators.k:
            landmarks = place_landmarks(level, self.obs_xy[w, placed], obstacles.half[placed])
            solid_items = self.res_present[w] & self.res_solid
            grid = NavGrid.from_boxes(
                level.arena.size,
                np.concatenate([self.obs_xy[w, placed], self.res_xy[w, solid_items]]),
                np.concatenate([obstacles.extents[placed, :2], pool.extents[solid_items, :2]]) / 2,
                np.concatenate([obstacles.heading[placed], pool.heading[solid_items]]),
                inflate=PREDATOR_HALF,
            )
            start_xy, start_heading = sample_predator_starts(level, rng)
            self.predators.reset_world(w, rng, start_xy, start_heading, landmarks, grid)
        self.attacked[w] = False
        self.trigger_count[w] = 0
        self.triggered[w] = False
        self.trigger_inside[w] = self._inside_triggers(self.pos[w: w + 1])[0]
        data = self.datas[w]
        mujoco.mj_resetData(self.model, data)
        data.qpos[:3] = (xy[0], xy[1], math.pi / 2 - self.heading_rad[w])
        self._write_resources(w)
        self._write_obstacles(w)
        self._write_predators(w)
        mujoco.mj_forward(self.model, data)
        self.thermal_readings[w] = self._sample_thermal(np.array([w]))[0]

    def _temperature_offset(self, angle: np.ndarray) -> np.ndarray:
        dn = self.level.daynight
        if not dn.enabled:
            return np.full(len(angle), dn.day_temperature)
        return daynight.temperature_offset(daynight.hour(angle), dn.day_temperature, dn.night_temperature)

    def _sample_thermal(self, worlds: np.ndarray) -> np.ndarray:
        readings = self.sampler.sample(self.fields, self.pos[worlds], self.heading_rad[worlds], worlds)
        return readings + self.field_offset[worlds, None]

    def _write_obstacles(self, w: int) -> None:
        moving = self.index.obstacle_mocap >= 0
        if not moving.any():
            return
        ids = self.index.obstacle_mocap[moving]
        mocap = self.datas[w].mocap_pos
        mocap[ids, 0] = self.obs_xy[w, moving, 0]
        mocap[ids, 1] = self.obs_xy[w, moving, 1]
        mocap[ids, 2] = np.where(self.obs_present[w, moving], self._obs_z[moving], PARKED_Z)

    def _write_predators(self, w: int) -> None:
        if not self.predators.k:
            return
        data, ids, k = self.datas[w], self.index.predator_mocap, self.predators.k
        pose = np.empty((k, 7))
        pose[:, :2] = self.predators.xy[w]
        pose[:, 2] = PREDATOR.base[2] / 2
        half = -self.predators.heading[w] / 2  # a body at compass heading h is turned by -h about z
        pose[:, 3], pose[:, 4:6], pose[:, 6] = np.cos(half), 0.0, np.sin(half)
        data.mocap_pos[ids] = pose[:, :3]
        data.mocap_quat[ids] = pose[:, 3:]

    def _write_resources(self, w: int) -> None:
        z = np.where(self.res_present[w], self.pool.centre_z(), PARKED_Z)
        mocap = self.datas[w].mocap_pos
        ids = self.index.resource_mocap
        mocap[ids, 0] = self.res_xy[w, :, 0]
        mocap[ids, 1] = self.res_xy[w, :, 1]
        mocap[ids, 2] = z

    # ------------------------------------------------------------------------------------------------ snapshots
    #: per-world state arrays that, with the MuJoCo states and the generators, make up a simulator's state
    _STATE_ARRAYS = ("pos", "heading_rad", "ev", "steps", "res_xy", "res_present", "fields", "field_offset",
                     "thermal_readings", "active_group", "obs_xy", "obs_present", "sun_angle", "attacked",
                     "trigger_count", "trigger_inside", "triggered")
    _PREDATOR_ARRAYS = ("xy", "heading", "state", "rest_count", "search_count", "route_age")

    def snapshot(self) -> dict:
        """Everything needed to continue exactly from here (for checkpoints that resume mid-episode)."""
        what = mujoco.mjtState.mjSTATE_INTEGRATION
        size = mujoco.mj_stateSize(self.model, what)
        physics = np.empty((self.n, size))
        for w, data in enumerate(self.datas):
            mujoco.mj_getState(self.model, data, physics[w], what)
        return {
            "level": self.level.model_dump(mode="json"),
            "num_worlds": self.n,
            "arrays": {name: getattr(self, name).copy() for name in self._STATE_ARRAYS},
            "physics": physics,
            "rngs": [rng.bit_generator.state for rng in self.rngs],
            "predators": {name: getattr(self.predators, name).copy() for name in self._PREDATOR_ARRAYS}
            | {"routes": [[None if r is None else r.copy() for r in world] for world in self.predators.routes],
               "grids": list(self.predators.grids), "areas": list(self.predators.areas),
               "landmarks": [p.copy() for p in self.predators.landmarks]},
            "last_obs": {k: v.copy() for k, v in self.last_obs.items()},
            "last_info": {k: v.copy() for k, v in getattr(self, "last_info", {}).items()},
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
        for name, value in snapshot["arrays"].items():
            setattr(self, name, value.copy())
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
        self.predators.grids = list(predators["grids"])
        self.predators.areas = list(predators["areas"])
        self.predators.landmarks = [p.copy() for p in predators["landmarks"]]
        self.last_obs = {k: v.copy() for k, v in snapshot["last_obs"].items()}
        self.last_info = {k: v.copy() for k, v in snapshot["last_info"].items()}
        self._res_d2 = None

    # ------------------------------------------------------------------------------------------------ state editing
    def set_agent_pose(self, world: int, xy, heading_deg: float) -> None:
        """Move world ``world``'s agent to ``xy`` facing compass ``heading_deg`` (for tests and scripted set-ups)."""
        self.pos[world] = xy
        self.heading_rad[world] = math.radians(heading_deg % 360.0)
        data = self.datas[world]
        data.qpos[:3] = (xy[0], xy[1], math.pi / 2 - self.heading_rad[world])
        data.qvel[:] = 0.0
        mujoco.mj_forward(self.model, data)
        self._res_d2 = None
        self._refresh_observation(world)

    def place_item(self, world: int, slot: int, xy, present: bool = True) -> None:
        """Put resource ``slot`` of world ``world`` at ``xy`` (or remove it) (for tests and scripted set-ups)."""
        self.res_xy[world, slot] = xy
        self.res_present[world, slot] = present
        self._write_resources(world)
        mujoco.mj_kinematics(self.model, self.datas[world])
        self._res_d2 = None
        self._refresh_observation(world)

    def _refresh_observation(self, world: int) -> None:
        self.thermal_readings[world] = self._sample_thermal(np.array([world]))[0]
        if self.last_obs:
            self._observe(np.array([world]))

    # ------------------------------------------------------------------------------------------------ step
    def step(self, actions: np.ndarray):
        """Advance every world by one decision.

        Returns ``(obs, reward, terminated, truncated, info)``: dict of (N, ...) arrays, (N,) float32, (N,) bool,
        (N,) bool, dict of (N, ...) arrays.
        """
        actions = self._check_actions(actions)
        self.apply_actions(actions)
        return self.advance(actions)

    def apply_actions(self, actions: np.ndarray) -> None:
        """Set each world's heading and velocity from its (validated) action; physics has not run yet."""
        turn = (actions == RIGHT).astype(np.float64) - (actions == LEFT)
        heading = (self.heading_rad + self.turn_rad * turn) % (2 * math.pi)
        self.heading_rad = heading
        speed = self.move_speed * (actions == FORWARD)
        vx, vy = (speed * np.sin(heading)).tolist(), (speed * np.cos(heading)).tolist()
        psi = (math.pi / 2 - heading).tolist()
        for w, data in enumerate(self.datas):
            data.qpos[2] = psi[w]
            qvel = data.qvel
            qvel[0] = vx[w]
            qvel[1] = vy[w]
            qvel[2] = 0.0

    def _physics(self, worlds, damage: np.ndarray, collided: np.ndarray) -> None:
        """The physics substeps of ``worlds``, adding each one's collision damage and whether it hit something."""
        model, pos, datas = self.model, self.pos, self.datas
        for w in worlds:
            data = datas[w]
            for _ in range(SUBSTEPS):
                mujoco.mj_step(model, data)
                if data.ncon:
                    d, hit = self._contact_damage(data)
                    damage[w] += d
                    collided[w] |= hit
            # mj_step leaves positions computed before its last integration; bring them up to date
            mujoco.mj_kinematics(model, data)
            mujoco.mj_camlight(model, data)
            pos[w] = data.qpos[:2]

    def advance(self, actions: np.ndarray):
        """The rest of a decision after :meth:`apply_actions` set the (validated) ``actions``: physics, eating,
        the EVs, the end of the episode and the observations; returns what :meth:`step` returns.  A caller that
        inspects or records the physics' starting state does so between the two."""
        previous = self.pos.copy()
        # 2. physics
        damage = np.zeros(self.n)
        collided = np.zeros(self.n, dtype=bool)
        shares = min(self.threads, self.n)
        if shares > 1:  # the first share here, the others on the helpers
            bounds = [self.n * i // shares for i in range(shares + 1)]
            others = [self._helper_pool().submit(self._physics, range(a, b), damage, collided)
                      for a, b in zip(bounds[1:-1], bounds[2:])]
            self._physics(range(bounds[1]), damage, collided)
            for share in others:
                share.result()
        else:
            self._physics(range(self.n), damage, collided)
        model, pos = self.model, self.pos
        self._res_d2 = None  # distances to items changed with the pose

        # 3. eating
        eating = actions == EAT if not self.level.agent.auto_eat else np.ones(self.n, dtype=bool)
        consumed = self._consume(eating)
        if consumed is None:
            food_count, water_count = np.zeros(self.n, dtype=np.int64), np.zeros(self.n, dtype=np.int64)
            food_eaten = water_eaten = self._zeros_bool
        else:
            food_count = (consumed & self.res_is_food).sum(1)
            water_count = (consumed & self.res_is_water).sum(1)
            food_eaten, water_eaten = food_count > 0, water_count > 0

        crossed = self._cross_triggers(previous) if len(self._trigger_max) else self._zeros_bool

        # 4. predators and the sun
        if self.predators.k:
            night = daynight.is_night(self.sun_angle) if self.level.daynight.enabled else self._zeros_bool
            attack = self.predators.step(pos, night, self.rngs)
            self.attacked = attack != 0
            damage = damage + attack
            for w in range(self.n):
                self._write_predators(w)
                mujoco.mj_kinematics(model, self.datas[w])
        if self.level.daynight.enabled:
            self.sun_angle = daynight.advance(self.sun_angle, self.level.daynight.degrees_per_step)
            self.field_offset = self._temperature_offset(self.sun_angle)

        # 5. physiology and 6. senses; one world's frame is drawn here while a helper does the rest
        costly = (actions == FORWARD) | (actions == EAT)  # what an action cost in the reward charges
        if self.threads > self.n:
            jobs = []

            def start_helper():  # once the scene is ready: from here on this thread holds the GIL only briefly
                jobs.append(self._helper_pool().submit(self._conclude, food_eaten, water_eaten, food_count,
                                                       water_count, damage, collided, crossed, costly,
                                                       skip_pixels=True))

            try:
                frame = self.render_eye(self._all, before_draw=start_helper)
            finally:
                if jobs:
                    obs, reward, terminated, truncated, info = jobs[0].result()
            obs = {"pixels": frame, **obs}  # the canonical order: pixels first
            self.last_obs = obs
            return obs, reward, terminated, truncated, info
        return self._conclude(food_eaten, water_eaten, food_count, water_count, damage, collided, crossed, costly)

    def _helper_pool(self) -> ThreadPoolExecutor:
        if self._helpers is None:
            self._helpers = ThreadPoolExecutor(self.threads - 1, "evaaa-helper")
        return self._helpers

    def _conclude(self, food_eaten, water_eaten, food_count, water_count, damage, collided, crossed, costly,
                  skip_pixels: bool = False):
        """Steps 5 and 6 of a decision: the EVs, the episode end, the reward, the senses (all but the frame with
        ``skip_pixels``) and the info."""
        # 5. physiology
        self.steps += 1
        self.thermal_readings = self._sample_thermal(self._all)
        ev_before = self.ev
        thermal_sum = self.thermal_readings.sum(axis=1) - 8.0 * ev_before[:, 2]
        self.ev = phys.step_evs(ev_before, self.params, food_eaten=food_eaten, water_eaten=water_eaten,
                                thermal_sum=thermal_sum, damage_taken=damage)
        end = phys.end_types(self.ev, self.params, resource_consumed=food_eaten | water_eaten,
                             single_trial=self.level.episode.single_trial, steps=self.steps,
                             max_steps=self.level.episode.max_steps)
        shaping = {}
        if self.params.reward == "shaped":  # the original's hand-shaped reward reads the senses, enabled or not
            shaping = dict(odour=self._shaping_senses[0].read(self._all),
                           thermal=self._shaping_senses[1].read(self._all), consumed=food_eaten | water_eaten,
                           collided=collided)
        reward = phys.reward(ev_before, self.ev, end, self.params, costly=costly, **shaping)
        truncated = end == phys.END_MAX_STEPS
        terminated = (end != phys.END_NONE) & ~truncated
        success = self._success(end, food_eaten, water_eaten)

        # 6. senses
        obs = self._observe(self._all, skip_pixels=skip_pixels)
        info = self._info(food=food_count, water=water_count, collided=collided, damage=damage, end=end,
                          success=success, crossed=crossed)
        return obs, reward, terminated, truncated, info

    # ------------------------------------------------------------------------------------------------ events
    def _inside_triggers(self, xy: np.ndarray) -> np.ndarray:
        """(M, E) whether points ``xy`` (M, 2) lie in each trigger box (grown by the body's half-width)."""
        rel = xy[:, None, :] - self._trigger_xy
        local_x = rel[..., 0] * self._trigger_cos - rel[..., 1] * self._trigger_sin
        local_y = rel[..., 0] * self._trigger_sin + rel[..., 1] * self._trigger_cos
        return (np.abs(local_x) <= self._trigger_half[:, 0]) & (np.abs(local_y) <= self._trigger_half[:, 1])

    def _cross_triggers(self, previous: np.ndarray) -> np.ndarray:
        """Fire the triggers the bodies entered during this decision; (N,) whether one fired."""
        # a decision covers up to 2 m: test points along the way so that a thin trigger is not stepped over
        along = np.linspace(0.2, 1.0, 5)[:, None, None]
        path = previous[None] + (self.pos - previous)[None] * along  # (5, N, 2)
        inside = self._inside_triggers(path.reshape(-1, 2)).reshape(5, self.n, -1)
        entered = inside.any(axis=0) & ~self.trigger_inside
        self.trigger_inside = inside[-1]
        fire = entered & (self.trigger_count < self._trigger_max)
        fired = fire.any(axis=1)
        for w in np.flatnonzero(fired):
            for e in np.flatnonzero(fire[w]):
                values = self._trigger_set[e]
                chosen = ~np.isnan(values)
                self.ev[w, chosen] = np.clip(values[chosen], self.params.low[chosen], self.params.high[chosen])
                self.trigger_count[w, e] += 1
        self.triggered |= fired
        return fired

    def _success(self, end: np.ndarray, food_eaten: np.ndarray, water_eaten: np.ndarray) -> np.ndarray:
        """(N,) whether an episode that ends here met its level's success rule (False while it goes on)."""
        rule = self.level.episode.success
        if rule.rule == "survive":
            return end == phys.END_MAX_STEPS
        if rule.rule == "consume_any":
            return end == phys.END_RESOURCE
        if rule.rule.startswith("consume"):
            eaten = food_eaten if rule.resource == "food" else water_eaten
            ok = (end == phys.END_RESOURCE) & eaten
            return ok & self.triggered if rule.rule == "consume_after_trigger" else ok
        return np.zeros(self.n, dtype=bool)

    def near_heat(self) -> np.ndarray:
        """(N,) whether each agent stands within 3 m of a hot obstacle's footprint."""
        if not self._heat.any():
            return self._zeros_bool
        hot = np.flatnonzero(self._heat)
        gap = np.abs(self.pos[:, None, :] - self.obs_xy[:, hot]) - self._heat_half[hot]  # (N, H, 2)
        dist = np.linalg.norm(np.maximum(gap, 0.0), axis=-1)
        return (self.obs_present[:, hot] & (dist <= NEAR_HEAT)).any(axis=1)

    def _check_actions(self, actions) -> np.ndarray:
        a = np.asarray(actions).reshape(-1)
        if a.shape != (self.n,):
            raise ValueError(f"expected {self.n} actions (one per world), got shape {np.shape(actions)}")
        if a.dtype.kind not in "iu":
            if a.dtype.kind != "f" or not np.all(a == np.round(a)):
                raise ValueError(f"actions must be integers in 0..{NUM_ACTIONS - 1}, got {a.tolist()}")
            a = a.astype(np.int64)
        if not ((a >= 0) & (a < NUM_ACTIONS)).all():
            raise ValueError(
                f"actions must be in 0..{NUM_ACTIONS - 1} ({', '.join(ACTION_NAMES)}), got {a.tolist()}"
            )
        return a

    def item_distances2(self) -> np.ndarray:
        """Squared horizontal distances (N, P) from each agent to each item slot, cached per decision."""
        if self._res_d2 is None:
            delta = self.res_xy - self.pos[:, None, :]
            self._res_d2 = delta[..., 0] ** 2 + delta[..., 1] ** 2
        return self._res_d2

    def _contact_damage(self, data: mujoco.MjData) -> tuple[float, bool]:
        """Collision damage of one substep: the impulse of each touching body, through the damage rule."""
        constant, rate, offset, cap, threshold = self._damage_rule
        agent = self.index.agent_geom
        force = np.zeros(6)
        per_body: dict[int, np.ndarray] = {}
        for c in range(data.ncon):
            contact = data.contact[c]
            if contact.geom1 == agent:
                other = contact.geom2
            elif contact.geom2 == agent:
                other = contact.geom1
            else:
                continue
            mujoco.mj_contactForce(self.model, data, c, force)
            world = force[:3] @ contact.frame.reshape(3, 3)
            body = int(self.model.geom_bodyid[other])
            per_body[body] = per_body.get(body, 0.0) + world
        total, hit = 0.0, False
        for vec in per_body.values():
            impulse = math.sqrt(float(vec @ vec)) * self.dt  # the norm, as np.linalg.norm computes it
            d = phys.contact_damage(impulse, constant, rate, offset, cap)
            total += d
            hit |= d > threshold
        return total, hit

    def can_eat(self, world: int, slot: int, pos: np.ndarray, heading) -> np.ndarray:
        """Whether the eating sphere of a body at ``pos`` (..., 2) facing ``heading`` (radians, compass) in
        ``world`` would overlap item ``slot`` (present or not): the test :meth:`_consume` applies, for planners."""
        centre = self._eat_centre(np.asarray(pos, dtype=np.float64), np.asarray(heading, dtype=np.float64))
        return self._eat_dist2(centre, self.res_xy[world, slot], slot) <= self.eat_radius2

    def _eat_centre(self, pos: np.ndarray, heading: np.ndarray) -> np.ndarray:
        """The eating sphere's centre, ``eat_offset`` ahead of a body at ``pos`` (..., 2) facing ``heading``."""
        return pos + self.eat_offset * np.stack([np.sin(heading), np.cos(heading)], axis=-1)

    def _eat_dist2(self, centre: np.ndarray, item_xy: np.ndarray, slots) -> np.ndarray:
        """Squared distance from the eating sphere's centre to the nearest point of the items' boxes (``slots``:
        an index or slice of the pool), measured in each item's own frame (items are turned by a fixed heading)."""
        rel = centre - item_xy
        cos, sin = self.res_cos[slots], self.res_sin[slots]
        local_x = rel[..., 0] * cos - rel[..., 1] * sin
        local_y = rel[..., 0] * sin + rel[..., 1] * cos
        gap_x = np.maximum(np.abs(local_x) - self.res_half3[slots, 0], 0.0)
        gap_y = np.maximum(np.abs(local_y) - self.res_half3[slots, 1], 0.0)
        return gap_x**2 + gap_y**2 + self._eat_dz2[slots]

    def _consume(self, eating: np.ndarray) -> np.ndarray | None:
        """Items consumed this decision, (N, P) bool (None if nothing was); respawns them and updates the scene."""
        if not eating.any() or self.pool.size_total == 0:
            return None
        worlds = np.flatnonzero(eating)
        centre = self._eat_centre(self.pos[worlds], self.heading_rad[worlds])
        dist2 = self._eat_dist2(centre[:, None, :], self.res_xy[worlds], slice(None))  # (W, P): sphere-box overlap
        hits = (dist2 <= self.eat_radius2) & self.res_present[worlds]
        if not hits.any():
            return None
        consumed = np.zeros(self.res_present.shape, dtype=bool)
        consumed[worlds] = hits
        for row, w in enumerate(worlds):
            slots = np.flatnonzero(hits[row])
            if not len(slots):
                continue
            moving = slots[self.res_respawns[slots]]
            if len(moving):
                self.res_xy[w, moving] = place_resources(self.pool, self.rngs[w], moving)
            eaten_grouped = slots[self.res_grouped[slots]]
            if len(eaten_grouped):
                self.res_present[w, eaten_grouped] = False
                if not (self.res_present[w] & self.res_grouped).any():  # the group is bare: another one grows
                    self.active_group[w] = draw_grouped(self.pool, self.rngs[w])
                    fresh = np.flatnonzero(self.pool.group == self.active_group[w])
                    self.res_xy[w, fresh] = place_resources(self.pool, self.rngs[w], fresh)
                    self.res_present[w, fresh] = True
            self._write_resources(w)
            mujoco.mj_kinematics(self.model, self.datas[w])
        self._res_d2 = None
        return consumed

    def _plan_light(self, worlds: np.ndarray) -> None:
        """Per world about to be rendered: sun direction and strength, darkness, fog and far plane."""
        dn = self.level.daynight
        angle = self.sun_angle[worlds]
        dark = daynight.darkness(daynight.hour(angle))
        direction, strength = daynight.sun(angle)
        # the light follows evaaa's darkness; fog and far plane follow it too unless the level asks for the
        # original's schedule
        haze = daynight.original_darkness(daynight.hour(angle)) if dn.fog_schedule == "original" else dark
        density = dn.night_fog_density * haze
        # exponential-squared fog of this density hides ~95% at sqrt(3)/density; MuJoCo's fog is linear
        fog_end = np.where(density > 0, np.sqrt(3.0) / np.maximum(density, 1e-9), 0.0)
        far = dn.day_far + (dn.night_far - dn.day_far) * haze
        self._light_plan = list(zip(dark.tolist(), direction.tolist(), (0.6 * strength).tolist(),
                                    fog_end.tolist(), far.tolist()))

    def _light_world(self, row: int, scene: mujoco.MjvScene, context: mujoco.MjrContext) -> None:
        """Set the sun, the sky and the fog of the world being rendered (worlds share one model)."""
        dark, direction, diffuse, fog_end, far = self._light_plan[row]
        head = 1.0 - 0.8 * dark
        for i in range(scene.nlight):
            light = scene.lights[i]
            if light.headlight:
                light.ambient[:] = 0.35 * head
                light.diffuse[:] = 0.3 * head
            else:
                light.dir[:] = direction
                light.diffuse[:] = diffuse
        scene.flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = dark < 0.5
        scene.flags[mujoco.mjtRndFlag.mjRND_FOG] = fog_end > 0
        if fog_end > 0:
            context.fogStart = 0.0
            context.fogEnd = fog_end
            context.fogRGBA[:] = _NIGHT_FOG
        scene.camera[0].frustum_far = far
        scene.camera[1].frustum_far = far

    # ------------------------------------------------------------------------------------------------ observation
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
                merged = self.last_obs[sensor.key].copy()
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
        if self.level.daynight.enabled:
            self._plan_light(worlds)
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
    def _info_reset(self, worlds: np.ndarray) -> None:
        def zeros(dtype):
            return np.zeros(self.n, dtype=dtype)

        self._info(food=zeros(np.int64), water=zeros(np.int64), collided=zeros(bool), damage=zeros(np.float64),
                   end=zeros(np.int64), success=zeros(bool), crossed=zeros(bool))

    def _info(self, *, food, water, collided, damage, end, success, crossed) -> dict[str, np.ndarray]:
        ev = self.ev.astype(np.float32)
        info = {
            "position": np.concatenate([self.pos, self._agent_z_col], axis=1).astype(np.float32),
            "yaw": np.degrees(self.heading_rad).astype(np.float32).reshape(-1, 1),
            "satiation": ev[:, 0:1],
            "hydration": ev[:, 1:2],
            "temperature": ev[:, 2:3],
            "damage": ev[:, 3:4],
            "food_eaten": food.reshape(-1, 1),
            "water_eaten": water.reshape(-1, 1),
            "collision": collided.reshape(-1, 1),
            "damage_taken": damage.astype(np.float32).reshape(-1, 1),
            "attacked": self.attacked.reshape(-1, 1).copy(),
            "step_count": self.steps.reshape(-1, 1).copy(),
            "end_type": end.reshape(-1, 1),
            "success": success.reshape(-1, 1).copy(),
            "trigger_crossed": crossed.reshape(-1, 1).copy(),
            "near_heat": self.near_heat().reshape(-1, 1).copy(),
        }
        self.last_info = info
        return info

    def close(self) -> None:
        for r in (self._renderer, self._top_renderer):
            if r is not None:
                r.close()
        self._renderer = self._top_renderer = None
        if self._helpers is not None:
            self._helpers.shutdown()
            self._helpers = None
