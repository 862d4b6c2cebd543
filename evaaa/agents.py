"""Reference agents for evaluations: a random agent, one that stands still, and a privileged scripted oracle.

Random and stand-still bracket what "survived longer than random" can mean: random dies of damage (it walks into
walls), while standing still survives until an EV runs out, with no foraging at all; an agent that learned must beat
the better of the two.

The oracle reads the simulator's true state through the world's queries (:class:`evaaa.sensors.World`: positions
of items, obstacles, fires, predators, the EVs, the floor's temperature, the night) and shows that a task is
solvable as configured.  Each decision it picks the need to serve by the priority the task expects — the most
urgent EV that has a source — plans a route on an occupancy grid (the predators' path finder, with hot ground
counted as blocked), walks it, and for the last few metres searches
the short action sequences that bring the item into its eating zone.  At night-sensitive tasks it waits for
the predators to sleep.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from .predator import NavGrid
from .sensors import World
from .sim import EAT, FORWARD, LEFT, NONE, NUM_ACTIONS, RIGHT

#: one Forward decision in the open moves the body this far (drag and floor friction over 5 substeps)
FORWARD_STEP = 1.9069
#: the oracle's occupancy grid: cell size and the room it keeps from obstacles beyond its body's half-width
CELL = 0.5
CLEARANCE = 0.6
SATIATION, HYDRATION, TEMPERATURE = 0, 1, 2
#: where the thermal sensors sit around the body (the oracle ignores their turning: it wants the average)
#: a need is served until its EV reaches this; another need interrupts when it would run out within CRITICAL
COMFORT = {SATIATION: 3.0, HYDRATION: 3.0, TEMPERATURE: 6.0}
CRITICAL = 60.0
_STENCIL = np.array([(0, 1), (0, -1), (-1, 0), (1, 0), (-1, 1), (1, 1), (-1, -1), (1, -1)], float)


class RandomAgent:
    """Uniformly random actions from its own generator."""

    name = "random"

    def __init__(self, seed: int | None = None):
        self.rng = np.random.default_rng(seed)

    def act(self, sim: World) -> np.ndarray:
        return self.rng.integers(0, NUM_ACTIONS, size=sim.n)


class StillAgent:
    """Stands still: the "none" action every decision (no moving, no eating)."""

    name = "still"

    def act(self, sim: World) -> np.ndarray:
        return np.full(sim.n, NONE, dtype=np.int64)


class MotionPlanner:
    """Shortest action sequences on (cell, heading) states, with the agent's own moves.

    Headings are the start heading plus whole turns (turns are exact), positions are grid cells; Forward moves
    one step along the heading if the way is free.  Every action costs one decision plus the warming the
    ground at its end would cause, so the planner finds quick routes that skirt fires and does its turning on
    cool ground.
    """

    def __init__(self, grid: NavGrid, heading0: float, turn: float, heat: np.ndarray):
        self.grid = grid
        self.k = int(round(2 * math.pi / turn))
        self.headings = (heading0 + turn * np.arange(self.k)) % (2 * math.pi)
        gx, gy = grid.shape
        cells = np.argwhere(np.ones(grid.shape, bool))
        centres = grid.centre(cells)
        n = gx * gy * self.k
        node = np.arange(n).reshape(gx * gy, self.k)
        weight = 1.0 + heat.reshape(-1)  # per destination cell
        free = ~grid.blocked.reshape(-1)
        rows, cols, wts = [], [], []
        # moves may start in a blocked cell (the body can end up closer to a wall than planned) but never end
        # in one
        for shift in (1, -1):  # turning in place
            src = node.reshape(-1)
            dst = np.roll(node, -shift, axis=1).reshape(-1)
            rows.append(src), cols.append(dst), wts.append(weight[src // self.k])
        for k, h in enumerate(self.headings):  # forward
            move = FORWARD_STEP * np.array([math.sin(h), math.cos(h)])
            ends = centres + move
            inside = np.all(np.abs(ends) < grid.size / 2, axis=1)
            idx = np.clip(np.floor((ends - grid.origin) / grid.cell).astype(int), 0, np.array(grid.shape) - 1)
            dst_cell = idx[:, 0] * gy + idx[:, 1]
            ok = inside & free[dst_cell]
            for frac in (0.5, 0.75):  # the way itself must be free
                mid = np.clip(
                    np.floor((centres + frac * move - grid.origin) / grid.cell).astype(int), 0, np.array(grid.shape) - 1
                )
                ok &= free[mid[:, 0] * gy + mid[:, 1]]
            src = node[np.flatnonzero(ok), k]
            rows.append(src), cols.append(node[dst_cell[ok], k]), wts.append(weight[dst_cell[ok]])
        self.graph = sp.coo_matrix(
            (np.concatenate(wts), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)
        ).tocsr()
        self.reverse = self.graph.T.tocsr()
        self.centres = centres
        self._cost_to_go: dict = {}

    def state(self, pos: np.ndarray, heading: float) -> int:
        ix, iy = self.grid.cell_of(pos)
        k = int(np.argmin(np.abs((self.headings - heading + math.pi) % (2 * math.pi) - math.pi)))
        return (ix * self.grid.shape[1] + iy) * self.k + k

    def cost_to_go(self, key, goals: np.ndarray) -> np.ndarray:
        """Cost from every state to the nearest of ``goals`` (state indices), cached under ``key``."""
        if key not in self._cost_to_go:
            if len(self._cost_to_go) > 16:
                self._cost_to_go.pop(next(iter(self._cost_to_go)))
            self._cost_to_go[key] = dijkstra(self.reverse, indices=goals, min_only=True) if len(goals) else None
        return self._cost_to_go[key]

    def next_action(self, pos: np.ndarray, heading: float, cost: np.ndarray) -> int | None:
        """The move (FORWARD, LEFT or RIGHT) that goes down the cost-to-go; None if no way leads there."""
        s = self.state(pos, heading)
        row = self.graph.getrow(s)
        if not row.nnz or not np.isfinite(cost[row.indices]).any():
            return None
        total = row.data + cost[row.indices]
        best = row.indices[np.argmin(total)]
        if best // self.k == s // self.k:
            return RIGHT if (best % self.k) == (s % self.k + 1) % self.k else LEFT
        return FORWARD


class OracleAgent:
    """A scripted agent with privileged access to the simulator's state."""

    name = "oracle"

    def __init__(self):
        self._grids: list[NavGrid | None] = []
        self._planners: list[MotionPlanner | None] = []
        self._current: list[int | None] = []

    # ------------------------------------------------------------------------------------------ per episode
    def _prepare(self, sim: World) -> None:
        if len(self._grids) != sim.n:
            self._grids, self._planners = [None] * sim.n, [None] * sim.n
            self._current = [None] * sim.n
        for w in range(sim.n):
            if sim.steps[w] == 0 or self._grids[w] is None:
                self._current[w] = None
                self._grids[w], heat = self._grid(sim, w)
                self._planners[w] = MotionPlanner(
                    self._grids[w], sim.heading_rad[w], math.radians(sim.level.agent.turn_degrees), heat
                )

    @staticmethod
    def _grid(sim: World, w: int) -> NavGrid:
        """Half-metre cells: obstacles and solid items grown by the body's half-width (and a hand's breadth) are
        blocked; hot ground costs what crossing it would heat the body, and lethal ground is blocked."""
        grid = NavGrid.from_boxes(sim.level.arena.size, *sim.obstacle_slices(w), inflate=CLEARANCE, cell=CELL)
        felt = OracleAgent._felt(sim, w, grid.centre(np.argwhere(np.ones(grid.shape, bool))))
        # warming per decision of a body at 0 standing there; a degree of it weighs like 10 decisions, so fires
        # are skirted as widely as the room allows
        heating = (8 * sim.params.thermal_coupling * np.maximum(felt, 0.0)).reshape(grid.shape)
        return grid, 10.0 * heating

    @staticmethod
    def _felt(sim: World, w: int, xy: np.ndarray) -> np.ndarray:
        """The temperature a body at ``xy`` relaxes toward: the mean of its 8 sensors (1 m around it)."""
        return sum(sim.ground_temperature(w, xy + d) for d in _STENCIL) / len(_STENCIL)

    # ------------------------------------------------------------------------------------------ decisions
    def act(self, sim: World) -> np.ndarray:
        self._prepare(sim)
        return np.array([self._act_world(sim, w) for w in range(sim.n)], dtype=np.int64)

    def _act_world(self, sim: World, w: int) -> int:
        if sim.predators.k and sim.level.daynight.enabled and not sim.is_night()[w]:
            return NONE  # wait for the predators to sleep
        need = self._need(sim, w)
        if need is None:
            return NONE
        planner = self._planners[w]
        if need == TEMPERATURE:
            spot = self._warm_spot(sim, w)
            if spot is None or np.linalg.norm(spot - sim.pos[w]) < 1.5:
                return NONE  # stand where the ground is right
            near = np.linalg.norm(planner.centres - spot, axis=1) < 1.0
            goals = (np.flatnonzero(near)[:, None] * planner.k + np.arange(planner.k)).reshape(-1)
            cost = planner.cost_to_go(("spot", tuple(np.round(spot))), goals)
        else:
            slots = self._items(sim, w, need)
            if not len(slots):
                return NONE
            for slot in slots:
                if sim.can_eat(w, slot, sim.pos[w], sim.heading_rad[w]):
                    return EAT
            # the nearest item the planner can reach (one hard against a wall may have no standing room)
            here = planner.state(sim.pos[w], sim.heading_rad[w])
            cost = None
            for slot in slots[:3]:
                candidate = self._item_cost(sim, w, slot)
                if candidate is not None and np.isfinite(candidate[here]):
                    cost = candidate
                    break
        if cost is None:
            return NONE
        action = planner.next_action(sim.pos[w], sim.heading_rad[w], cost)
        return NONE if action is None else action

    def _need(self, sim: World, w: int) -> int | None:
        """The EV to serve now: the most urgent one that has a source in this world."""
        ev = sim.ev[w]
        low = sim.params.low
        rule = sim.level.episode.success.rule
        feeds = {SATIATION: sim.res_present[w] & sim.res_is_food, HYDRATION: sim.res_present[w] & sim.res_is_water}
        if rule == "survive" and sim.level.episode.single_trial:  # eating would end the trial: only keep warm
            feeds = {e: np.zeros_like(f) for e, f in feeds.items()}
        heat = bool((sim.obstacles.temperature > 0).any())
        if rule.startswith("consume"):
            # one consumption ends the trial: the needier of hunger and thirst, whose source exists
            options = [e for e in (SATIATION, HYDRATION) if feeds[e].any()]
            return min(options, key=lambda e: ev[e]) if options else None
        # survival: keep serving the current need until it is comfortable, unless another runs out sooner
        time_left = {}
        for e in (SATIATION, HYDRATION):
            if feeds[e].any():
                rate = -sim.params.decay[e]
                time_left[e] = (ev[e] - low[e]) / rate if rate > 0 else math.inf
        if heat:
            field_here = float(sim.thermal_readings[w].mean())
            cooling = sim.params.thermal_coupling * 8 * (ev[TEMPERATURE] - field_here)
            time_left[TEMPERATURE] = (ev[TEMPERATURE] - low[TEMPERATURE]) / cooling if cooling > 0 else math.inf
        if not time_left:
            return None
        current = self._current[w]
        critical = [e for e in time_left if time_left[e] < CRITICAL and e != current]
        if current in time_left and ev[current] < COMFORT[current] and not critical:
            return current
        wanting = [e for e in time_left if ev[e] < COMFORT[e]]
        if not wanting:  # all comfortable: stay on mild ground (or idle)
            self._current[w] = TEMPERATURE if heat else None
            return self._current[w]
        self._current[w] = min(wanting, key=lambda e: time_left[e])
        return self._current[w]

    def _items(self, sim: World, w: int, need: int) -> np.ndarray:
        """Present items that serve ``need``, nearest first."""
        feeds = sim.res_is_food if need == SATIATION else sim.res_is_water
        slots = np.flatnonzero(sim.res_present[w] & feeds)
        return slots[np.argsort(np.linalg.norm(sim.res_xy[w, slots] - sim.pos[w], axis=1))]

    def _item_cost(self, sim: World, w: int, slot: int) -> np.ndarray | None:
        """Cost-to-go to the states that can eat item ``slot`` (cached per item position)."""
        planner = self._planners[w]
        key = ("item", int(slot), tuple(np.round(sim.res_xy[w, slot], 2)))
        if key not in planner._cost_to_go:
            free = np.repeat(~self._grids[w].blocked.reshape(-1), planner.k)
            # a goal state must reach the item from anywhere in its cell, not only from the cell's centre; an
            # item with no such state (tucked against a wall) accepts states that reach it from the centre
            reach = np.ones((len(planner.centres), planner.k), dtype=bool)
            for dx, dy in ((0, 0), (-1, -1), (-1, 1), (1, -1), (1, 1)):
                corner = planner.centres + 0.45 * CELL * np.array([dx, dy])
                reach &= sim.can_eat(w, slot, corner[:, None, :], planner.headings[None, :])
                goals = np.flatnonzero(reach.reshape(-1) & free)
                if dx == 0 and dy == 0:
                    centre_goals = goals
            planner.cost_to_go(key, goals if len(goals) else centre_goals)
        return planner.cost_to_go(key, None)

    def _warm_spot(self, sim: World, w: int) -> np.ndarray | None:
        """A free spot whose ground brings the body toward a comfortable temperature: hot ground while it is
        cold, mild ground once it is warm (the body relaxes toward the ground under it)."""
        grid = self._grids[w]
        free = np.argwhere(~grid.blocked)
        if not len(free):
            return None
        centres = grid.centre(free)
        target = float(np.clip(8.0 - 3.0 * (sim.ev[w, TEMPERATURE] - 2.0), -5.0, 50.0))
        felt = self._felt(sim, w, centres)
        cost = np.abs(felt - target) + 0.5 * np.linalg.norm(centres - sim.pos[w], axis=1)
        return centres[np.argmin(cost)]
