"""Predators: their state machine (Resting, Searching, Chasing, Attacking) and their navigation.

Predators of every world are stepped together once per decision, after the agent moves.  Each patrols the
convex hull of its world's landmarks: Searching picks a random landmark every ``search_interval`` decisions and
rests after ``max_searching_steps``; Resting waits ``max_resting_steps``; seeing the agent (inside the view
cone and distance, no occlusion test, as in the original) starts a chase; touching it starts an attack, which
adds damage every decision.  At night every predator rests.

Paths go around obstacles: each world gets an occupancy grid of 1 m cells (obstacle footprints grown by the
predator's half-width) and a route is the shortest path on its 8-connected graph (scipy's Dijkstra), taken
straight when the line to the goal is clear.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from .entities import PREDATOR
from .level import Level
from .level_limits import REPLAN_EVERY  # the level's planning bound counts on it
from .worldgen import AGENT_HALF, PatrolArea

RESTING, SEARCHING, CHASING, ATTACKING = range(4)
STATES: tuple[str, ...] = ("Resting", "Searching", "Chasing", "Attacking")
DECISION_SECONDS = 0.1
PREDATOR_HALF = PREDATOR.base[0] / 2
#: centres closer than this touch (the bodies' half-widths and a hand's breadth)
CONTACT_DISTANCE = PREDATOR_HALF + AGENT_HALF + 0.2
#: sizes (grid cells each way) of the groups in which boxes are rasterised together; larger boxes go one by one
BOX_GROUP_CELLS = (8, 32)


class NavGrid:
    """Occupancy grid of one world's floor and shortest paths on it."""

    def __init__(self, arena_size: tuple[float, float], blocked: np.ndarray, cost: np.ndarray | None = None):
        """``cost`` (same shape, >= 0) makes a cell's edges ``1 + cost`` times longer (e.g. hot ground)."""
        self.size = np.asarray(arena_size, dtype=np.float64)
        self.shape = blocked.shape
        self.cell = self.size / np.array(self.shape)
        self.origin = -self.size / 2
        self.blocked = blocked
        self.cost = np.zeros(self.shape) if cost is None else np.asarray(cost, dtype=np.float64)
        self.graph = self._graph(blocked, self.cost)
        self._trees: dict[int, np.ndarray] = {}

    def to_data(self) -> dict[str, np.ndarray]:
        """The grid as plain arrays (what a snapshot or checkpoint holds); :meth:`from_data` rebuilds it."""
        return {"size": self.size.copy(), "blocked": self.blocked.copy(), "cost": self.cost.copy()}

    @classmethod
    def from_data(cls, data) -> NavGrid:
        """A grid from :meth:`to_data`'s arrays (an old in-memory snapshot's grid object is taken as it is)."""
        if isinstance(data, NavGrid):
            return data
        return cls(
            tuple(np.asarray(data["size"], dtype=np.float64)),
            np.asarray(data["blocked"], dtype=bool),
            np.asarray(data["cost"], dtype=np.float64),
        )

    @classmethod
    def from_boxes(
        cls,
        arena_size,
        xy: np.ndarray,
        half: np.ndarray,
        heading: np.ndarray | None = None,
        inflate: float = 0.0,
        cell: float = 1.0,
    ) -> NavGrid:
        """Grid of ``cell``-metre cells, blocked where a cell's centre lies inside a box: centre ``xy`` (K, 2),
        half-sides ``half`` (K, 2) in the box's own frame grown by ``inflate``, turned to compass ``heading``."""
        size = np.asarray(arena_size, dtype=np.float64)
        shape = tuple(int(math.ceil(s / cell)) for s in size)
        step = size / np.array(shape)
        blocked = np.zeros(shape, dtype=bool)
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        grown = np.asarray(half, dtype=np.float64).reshape(-1, 2) + inflate
        heading = np.zeros(len(xy)) if heading is None else np.asarray(heading, dtype=np.float64)
        c, s_ = np.cos(heading), np.sin(heading)
        reach = np.stack(
            [grown[:, 0] * np.abs(c) + grown[:, 1] * np.abs(s_), grown[:, 0] * np.abs(s_) + grown[:, 1] * np.abs(c)],
            axis=1,
        )
        first = np.clip(np.ceil((xy - reach + size / 2) / step - 0.5).astype(int), 0, np.array(shape))
        last = np.clip(np.floor((xy + reach + size / 2) / step - 0.5).astype(int), -1, np.array(shape) - 1)
        # boxes are rasterised in groups by size, each box of a group over a square of cells from its first cell
        # (kept where it lies in the box's range and the cell's centre inside the box); the few huge boxes (long
        # walls) one by one
        span = (last - first + 1).max(axis=1)
        done = np.zeros(len(xy), dtype=bool)
        for cells in BOX_GROUP_CELLS:
            group = np.flatnonzero(~done & (span <= cells))
            done[group] = True
            if not len(group):
                continue
            offsets = np.arange(cells)
            ix = np.broadcast_to(first[group, 0, None, None] + offsets[None, :, None], (len(group), cells, cells))
            iy = np.broadcast_to(first[group, 1, None, None] + offsets[None, None, :], (len(group), cells, cells))
            rx = -size[0] / 2 + (ix + 0.5) * step[0] - xy[group, 0, None, None]
            ry = -size[1] / 2 + (iy + 0.5) * step[1] - xy[group, 1, None, None]
            cs, sn = c[group, None, None], s_[group, None, None]
            lx, ly = rx * cs - ry * sn, rx * sn + ry * cs
            inside = (
                (ix <= last[group, 0, None, None])
                & (iy <= last[group, 1, None, None])
                & (np.abs(lx) <= grown[group, 0, None, None])
                & (np.abs(ly) <= grown[group, 1, None, None])
            )
            blocked[ix[inside], iy[inside]] = True
        for k in np.flatnonzero(~done):
            (x0, y0), (x1, y1) = first[k], last[k]
            if x1 < x0 or y1 < y0:
                continue
            ix, iy = np.meshgrid(np.arange(x0, x1 + 1), np.arange(y0, y1 + 1), indexing="ij")
            rx = -size[0] / 2 + (ix + 0.5) * step[0] - xy[k, 0]
            ry = -size[1] / 2 + (iy + 0.5) * step[1] - xy[k, 1]
            # into the box's frame (a box at compass heading h is turned by -h)
            lx, ly = rx * c[k] - ry * s_[k], rx * s_[k] + ry * c[k]
            inside = (np.abs(lx) <= grown[k, 0]) & (np.abs(ly) <= grown[k, 1])
            blocked[ix[inside], iy[inside]] = True
        return cls(arena_size, blocked)

    @staticmethod
    def _graph(blocked: np.ndarray, cost: np.ndarray) -> sp.csr_matrix:
        """8-connected graph of the free cells; diagonal moves may not cut the corner of a blocked cell."""
        gx, gy = blocked.shape
        free = ~blocked
        rows, cols, weights = [], [], []
        # per direction (dx, dy): the cells (x, y) whose edge to (x + dx, y + dy) exists, in row-major order
        for dx, dy in ((1, 0), (0, 1), (1, 1), (1, -1)):
            y0 = 1 if dy < 0 else 0  # first y with a neighbour at y + dy
            ny = gy - abs(dy)
            a = (slice(0, gx - dx), slice(y0, y0 + ny))  # the cells ...
            b = (slice(dx, gx), slice(y0 + dy, y0 + dy + ny))  # ... and their neighbours
            ok = free[a] & free[b]
            if dx and dy:  # the two cells beside the diagonal
                ok &= free[b[0], a[1]] & free[a[0], b[1]]
            k = np.flatnonzero(ok)
            src = (k // ny) * gy + k % ny + y0
            rows.append(src)
            cols.append(src + dx * gy + dy)
            extra = (cost[a][ok] + cost[b][ok]) / 2
            weights.append(math.hypot(dx, dy) * (1.0 + extra))
        n = gx * gy
        return sp.coo_matrix(
            (np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)
        ).tocsr()

    def cell_of(self, xy: np.ndarray) -> tuple[int, int]:
        i = np.clip(np.floor((np.asarray(xy) - self.origin) / self.cell).astype(int), 0, np.array(self.shape) - 1)
        return int(i[0]), int(i[1])

    def centre(self, cells: np.ndarray) -> np.ndarray:
        return self.origin + (np.asarray(cells) + 0.5) * self.cell

    def clear_line(self, a: np.ndarray, b: np.ndarray) -> bool:
        length = float(np.linalg.norm(b - a))
        t = np.linspace(0.0, 1.0, max(2, int(length / (0.5 * self.cell.min())) + 2))
        points = a + (b - a) * t[:, None]
        i = np.clip(np.floor((points - self.origin) / self.cell).astype(int), 0, np.array(self.shape) - 1)
        return not (self.blocked[i[:, 0], i[:, 1]].any() or self.cost[i[:, 0], i[:, 1]].any())

    def _nearest_free(self, cell: tuple[int, int]) -> tuple[int, int]:
        if not self.blocked[cell]:
            return cell
        free = np.argwhere(~self.blocked)
        if not len(free):
            return cell
        return tuple(free[np.argmin(((free - np.array(cell)) ** 2).sum(1))])

    def route(self, start: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """Waypoints (M, 2) from ``start`` to ``goal``: the goal itself when the line is clear."""
        if self.clear_line(start, goal):
            return goal[None, :].copy()
        gy = self.shape[1]
        s = self._nearest_free(self.cell_of(start))
        g = self._nearest_free(self.cell_of(goal))
        toward = self._tree(g[0] * gy + g[1])
        node, target, cells = s[0] * gy + s[1], g[0] * gy + g[1], []
        while node != target and node >= 0 and len(cells) <= toward.size:
            node = toward[node]
            cells.append(divmod(node, gy))
        if not cells or cells[-1] != g:  # unreachable: walk straight at it
            return goal[None, :].copy()
        path = self.centre(np.array(cells[:-1], dtype=np.float64).reshape(-1, 2))
        return np.concatenate([path, goal[None, :]])

    def _tree(self, goal: int) -> np.ndarray:
        """For every cell, the next cell on a shortest path to ``goal`` (-9999 where none); cached, since
        predators keep returning to the same landmarks."""
        tree = self._trees.get(goal)
        if tree is None:
            _, tree = dijkstra(self.graph, directed=False, indices=goal, return_predecessors=True)
            if len(self._trees) >= 64:
                self._trees.pop(next(iter(self._trees)))
            self._trees[goal] = tree
        return tree


class Predators:
    """The predators of N worlds (K slots each): state, counters, pose and routes."""

    def __init__(self, level: Level, n_worlds: int):
        params = [g for g in level.predators.values() for _ in range(g.count)]
        self.k = len(params)
        self.n = n_worlds

        def col(name):
            return np.array([getattr(g, name) for g in params], dtype=np.float64)

        self.step_length = col("walk_speed") * DECISION_SECONDS
        self.turn_step = np.radians(col("turn_speed") * DECISION_SECONDS)
        self.half_view = np.radians(col("view_angle") / 2)
        self.view2 = col("view_distance") ** 2
        # the original's attack subtracted its damage (it was written when the EV was health)
        sign = np.array([1.0 if g.attack == "harm" else -1.0 for g in params])
        self.damage = sign * np.minimum(col("damage"), col("max_damage"))
        self.max_rest = col("max_resting_steps").astype(np.int64)
        self.max_search = col("max_searching_steps").astype(np.int64)
        self.interval = col("search_interval").astype(np.int64)
        shape = (n_worlds, self.k)
        self.xy = np.zeros((*shape, 2))
        self.heading = np.zeros(shape)
        self.state = np.full(shape, SEARCHING, dtype=np.int64)
        self.rest_count = np.zeros(shape, dtype=np.int64)
        self.search_count = np.zeros(shape, dtype=np.int64)
        self.routes: list[list[np.ndarray | None]] = [[None] * self.k for _ in range(n_worlds)]
        self.route_age = np.zeros(shape, dtype=np.int64)
        self.grids: list[NavGrid | None] = [None] * n_worlds
        self.areas: list[PatrolArea | None] = [None] * n_worlds
        self.landmarks: list[np.ndarray] = [np.zeros((0, 2))] * n_worlds

    # ------------------------------------------------------------------------------------------ episodes
    def reset_world(
        self,
        w: int,
        rng: np.random.Generator,
        xy: np.ndarray,
        heading: np.ndarray,
        landmarks: np.ndarray,
        grid: NavGrid,
    ) -> None:
        self.xy[w], self.heading[w] = xy, heading
        self.state[w] = SEARCHING
        self.search_count[w] = rng.integers(0, self.interval)
        self.rest_count[w] = rng.integers(0, np.maximum(self.max_rest // 2, 1))
        self.routes[w] = [None] * self.k
        self.route_age[w] = 0
        self.landmarks[w] = landmarks
        self.areas[w] = PatrolArea(landmarks)
        self.grids[w] = grid

    def write(self, w: int, data, mocap: np.ndarray) -> None:
        """Put world ``w``'s predators into its scene (``data``, an ``MjData``) at mocap indices ``mocap``."""
        if not self.k:
            return
        pose = self.poses(w)
        data.mocap_pos[mocap] = pose[:, :3]
        data.mocap_quat[mocap] = pose[:, 3:]

    def poses(self, worlds=slice(None)) -> np.ndarray:
        """(..., K, 7) the predators of ``worlds`` (an index or slice; all by default) as mocap poses: position and
        quaternion."""
        xy, heading = self.xy[worlds], self.heading[worlds]
        pose = np.empty((*heading.shape, 7))
        pose[..., :2] = xy
        pose[..., 2] = PREDATOR.base[2] / 2
        half = -heading / 2  # a body at compass heading h is turned by -h about z
        pose[..., 3], pose[..., 4:6], pose[..., 6] = np.cos(half), 0.0, np.sin(half)
        return pose

    # ------------------------------------------------------------------------------------------ decisions
    def sees(self, agent_xy: np.ndarray) -> np.ndarray:
        """(N, K): the agent is within each predator's view distance and cone."""
        delta = agent_xy[:, None, :] - self.xy
        dist2 = (delta**2).sum(-1)
        bearing = np.arctan2(delta[..., 0], delta[..., 1])  # compass angle to the agent
        off = np.abs((bearing - self.heading + np.pi) % (2 * np.pi) - np.pi)
        return (dist2 <= self.view2) & (off < self.half_view)

    def touching(self, agent_xy: np.ndarray) -> np.ndarray:
        return ((agent_xy[:, None, :] - self.xy) ** 2).sum(-1) <= CONTACT_DISTANCE**2

    def step(self, agent_xy: np.ndarray, night: np.ndarray, rngs: list[np.random.Generator]) -> np.ndarray:
        """Advance every predator one decision; return the damage (N,) their attacks deal to the agents (negative
        where predators with ``attack: original`` attack)."""
        damage = np.zeros(self.n)
        if self.k == 0:
            return damage
        sees = self.sees(agent_xy)
        for w in range(self.n):
            if night[w]:
                self.state[w] = RESTING
                self.rest_count[w] = 0
                self.routes[w] = [None] * self.k
                continue
            area = self.areas[w]
            outside = ~area.contains(self.xy[w])
            for k in range(self.k):
                self._decide(w, k, bool(sees[w, k]), bool(outside[k]), agent_xy[w], rngs[w])
            self._move(w, agent_xy[w])
        touching = self.touching(agent_xy) & ~night[:, None]
        self.state[touching] = ATTACKING
        attacking = self.state == ATTACKING
        damage += (attacking * self.damage).sum(axis=1)
        # an attack ends when the agent slips out of reach
        self.state[attacking & ~touching] = SEARCHING
        return damage

    def _new_landmark(self, w: int, k: int, rng: np.random.Generator) -> None:
        points = self.landmarks[w]
        goal = points[rng.integers(len(points))]
        self.routes[w][k] = self.grids[w].route(self.xy[w, k], goal)
        self.route_age[w, k] = 0

    def _decide(self, w: int, k: int, sees: bool, outside: bool, agent: np.ndarray, rng) -> None:
        state = self.state[w, k]
        if outside and state != CHASING:
            self._new_landmark(w, k, rng)
        if state == RESTING:
            self.rest_count[w, k] += 1
            if sees:
                self.state[w, k] = CHASING
            elif self.rest_count[w, k] >= self.max_rest[k]:
                self.state[w, k], self.search_count[w, k] = SEARCHING, 0
        elif state == SEARCHING:
            self.search_count[w, k] += 1
            if self.search_count[w, k] % self.interval[k] == 0:
                self._new_landmark(w, k, rng)
            if sees:
                self.state[w, k] = CHASING
            elif self.search_count[w, k] >= self.max_search[k]:
                self.state[w, k], self.rest_count[w, k] = RESTING, 0
                self.routes[w][k] = None
        elif state == CHASING:
            if outside or not sees:
                self.state[w, k], self.search_count[w, k] = SEARCHING, 0
                self.routes[w][k] = None
                if outside:
                    self._new_landmark(w, k, rng)
            else:
                self.route_age[w, k] += 1
                route = self.routes[w][k]
                stale = route is None or self.route_age[w, k] >= REPLAN_EVERY
                if stale or self.grids[w].clear_line(self.xy[w, k], agent):
                    self.routes[w][k] = self.grids[w].route(self.xy[w, k], agent.copy())
                    self.route_age[w, k] = 0
                else:
                    route[-1] = agent  # keep heading for the agent along the planned corridor
        elif state == ATTACKING:
            if not sees:
                self.state[w, k], self.search_count[w, k] = SEARCHING, 0
                self.routes[w][k] = None

    def _move(self, w: int, agent: np.ndarray) -> None:
        # plain floats: a route has a handful of waypoints and numpy's per-call cost would dominate
        xy, state, routes = self.xy[w], self.state[w], self.routes[w]
        for k in range(self.k):
            route = routes[k]
            if route is None or state[k] == RESTING or state[k] == ATTACKING:
                continue
            budget = float(self.step_length[k])
            x0, y0 = float(xy[k, 0]), float(xy[k, 1])
            px, py = x0, y0
            chasing = state[k] == CHASING
            points, i = route.tolist(), 0
            while budget > 1e-9 and i < len(points):
                dx, dy = points[i][0] - px, points[i][1] - py
                length = math.hypot(dx, dy)
                dist = length
                if chasing and i == len(points) - 1:  # stop when touching, do not walk into the agent
                    dist = max(dist - (CONTACT_DISTANCE - 0.1), 0.0)
                unit = max(length, 1e-9)
                if dist <= budget:
                    px, py = px + dx / unit * dist, py + dy / unit * dist
                    budget -= dist
                    if i < len(points) - 1 or not chasing:
                        i += 1
                    else:
                        break
                else:
                    px, py = px + dx / unit * budget, py + dy / unit * budget
                    budget = 0.0
            mx, my = px - x0, py - y0
            if mx * mx + my * my > 1e-12:
                self._turn(w, k, math.atan2(mx, my))
            xy[k, 0], xy[k, 1] = px, py
            routes[k] = route[i:] if i < len(points) else None

    def _turn(self, w: int, k: int, towards: float) -> None:
        heading, limit = float(self.heading[w, k]), float(self.turn_step[k])
        off = (towards - heading + math.pi) % (2 * math.pi) - math.pi
        self.heading[w, k] = (heading + min(max(off, -limit), limit)) % (2 * math.pi)
