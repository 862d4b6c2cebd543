"""World generation: a level spec and a random generator in, a concrete layout out.

Pure numpy (and scipy for the patrol hull); nothing here builds or touches MuJoCo.  The scene keeps one pooled
body per resource, obstacle and predator slot, so a layout is just arrays: where every slot sits and whether it
is present, where the agent starts, where the landmarks are.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np

from .entities import FEEDS, OBSTACLE_KINDS, RESOURCE_KINDS, centre_z, footprint_half
from .level import Level, LevelError

FOOD, WATER = 0, 1
#: Where hidden or unused pooled bodies wait: far below the floor, out of sight and out of reach of rays.
PARKED_Z = -100.0
AGENT_HALF = 0.5
PLACEMENT_TRIES = 100
#: candidates an obstacle may draw before the episode's layout is declared impossible
PLACEMENT_LIMIT = 1000


@dataclass(frozen=True)
class ResourcePool:
    """The fixed slots of a level's resources, concatenated over its groups (P slots)."""

    names: tuple[str, ...]  # group name per group
    group: np.ndarray  # (P,) group index of each slot
    kind: np.ndarray  # (P,) name of each slot's kind
    feeds: np.ndarray  # (P,) FOOD or WATER
    low: np.ndarray  # (P, 2) lower corner of the slot's placement box
    high: np.ndarray  # (P, 2)
    extents: np.ndarray  # (P, 3)
    heading: np.ndarray  # (P,) radians, compass
    respawn: np.ndarray  # (P,) "random", "static" or "grouped"
    solid: np.ndarray  # (P,) the body collides with it (ponds)
    odour: np.ndarray  # (P, 10)

    @property
    def size_total(self) -> int:
        return len(self.group)

    @property
    def size(self) -> np.ndarray:
        """Largest extent of each slot (a cube's edge)."""
        return self.extents.max(axis=1)

    @classmethod
    def from_level(cls, level: Level) -> ResourcePool:
        rows = []
        for g, spec in enumerate(level.resources.values()):
            kind = RESOURCE_KINDS[spec.kind]
            rows += [
                (
                    g,
                    spec.kind,
                    FEEDS[spec.kind],
                    (spec.x[0], spec.y[0]),
                    (spec.x[1], spec.y[1]),
                    spec.extents,
                    np.radians(spec.heading),
                    spec.respawn,
                    kind.solid,
                    kind.odour,
                )
            ] * spec.count
        cols = list(zip(*rows)) if rows else [()] * 10
        return cls(
            names=tuple(level.resources),
            group=np.array(cols[0], dtype=np.int64),
            kind=np.array(cols[1], dtype=object),
            feeds=np.array(cols[2], dtype=np.int64),
            low=np.array(cols[3], dtype=np.float64).reshape(-1, 2),
            high=np.array(cols[4], dtype=np.float64).reshape(-1, 2),
            extents=np.array(cols[5], dtype=np.float64).reshape(-1, 3),
            heading=np.array(cols[6], dtype=np.float64),
            respawn=np.array(cols[7], dtype=object),
            solid=np.array(cols[8], dtype=bool),
            odour=np.array(cols[9], dtype=np.float64).reshape(-1, 10),
        )

    def centre_z(self) -> np.ndarray:
        """Height of each slot's centre when resting on the floor."""
        return self.extents[:, 2] / 2

    @property
    def grouped_groups(self) -> np.ndarray:
        """Indices of the groups that take turns holding items (respawn: grouped)."""
        return np.unique(self.group[self.respawn == "grouped"])


def place_resources(pool: ResourcePool, rng: np.random.Generator, slots: np.ndarray | None = None) -> np.ndarray:
    """Uniform positions (len(slots), 2) inside each slot's box (all slots if ``slots`` is None)."""
    low, high = (pool.low, pool.high) if slots is None else (pool.low[slots], pool.high[slots])
    return rng.uniform(low, high)


def draw_grouped(pool: ResourcePool, rng: np.random.Generator) -> int:
    """The grouped group that holds items next (uniform over grouped groups; -1 if the level has none)."""
    groups = pool.grouped_groups
    return int(rng.choice(groups)) if len(groups) else -1


def resources_present(pool: ResourcePool, active_group: int) -> np.ndarray:
    """Which slots hold an item at the start of an episode (or after a grouped group is drawn)."""
    return (pool.respawn != "grouped") | (pool.group == active_group)


# ------------------------------------------------------------------------------------------------ obstacles
@dataclass(frozen=True)
class ObstaclePool:
    """The fixed slots of a level's obstacles (O slots), static ones first."""

    names: tuple[str, ...]
    group: np.ndarray  # (O,)
    kind: np.ndarray  # (O,) kind name
    static: np.ndarray  # (O,) placed once at its fixed spot
    low: np.ndarray  # (O, 2)
    high: np.ndarray  # (O, 2)
    extents: np.ndarray  # (O, 3) drawn once per level (one compiled model serves every world and episode)
    heading: np.ndarray  # (O,) radians
    padding: np.ndarray  # (O,)
    temperature: np.ndarray  # (O,)
    half: np.ndarray  # (O, 2) half-sides of the axis-aligned box around each footprint
    lift: np.ndarray  # (O,) metres raised from resting on the floor (negative: sunk into it)

    @property
    def size_total(self) -> int:
        return len(self.group)

    @classmethod
    def from_level(cls, level: Level) -> ObstaclePool:
        # a generator of its own, so the sizes are a fixed property of the level
        rng = np.random.default_rng(zlib.crc32(f"evaaa-obstacles-{level.name}".encode()))
        rows = []
        for g, spec in enumerate(level.obstacles.values()):
            kind = OBSTACLE_KINDS[spec.kind]
            for _ in range(spec.count):
                scale = [rng.uniform(lo, hi) for lo, hi in spec.scale]
                extents = np.array(kind.base) * scale
                rows.append(
                    (
                        g,
                        spec.kind,
                        spec.static,
                        (spec.x[0], spec.y[0]),
                        (spec.x[1], spec.y[1]),
                        extents,
                        np.radians(spec.heading),
                        spec.padding,
                        spec.temperature,
                        spec.lift,
                    )
                )
        rows.sort(key=lambda r: not r[2])  # static obstacles first: random ones are placed around them
        cols = list(zip(*rows)) if rows else [()] * 10
        kinds = np.array(cols[1], dtype=object)
        extents = np.array(cols[5], dtype=np.float64).reshape(-1, 3)
        heading = np.array(cols[6], dtype=np.float64)
        half = np.zeros((len(kinds), 2))
        for k in set(kinds):
            m = kinds == k
            half[m] = footprint_half(OBSTACLE_KINDS[k], extents[m], heading[m])
        return cls(
            names=tuple(level.obstacles),
            group=np.array(cols[0], dtype=np.int64),
            kind=kinds,
            static=np.array(cols[2], dtype=bool),
            low=np.array(cols[3], dtype=np.float64).reshape(-1, 2),
            high=np.array(cols[4], dtype=np.float64).reshape(-1, 2),
            extents=extents,
            heading=heading,
            padding=np.array(cols[7], dtype=np.float64),
            temperature=np.array(cols[8], dtype=np.float64),
            half=half,
            lift=np.array(cols[9], dtype=np.float64),
        )

    def centre_z(self) -> np.ndarray:
        """Height of each slot's centre: resting on the floor, raised by its lift."""
        out = self.lift.copy()
        for k in set(self.kind):
            m = self.kind == k
            out[m] += centre_z(OBSTACLE_KINDS[k], self.extents[m])
        return out


def _overlaps(candidates: np.ndarray, half: np.ndarray, placed_xy: np.ndarray, placed_half: np.ndarray) -> np.ndarray:
    """Whether each candidate box (C, 2) with half-sides ``half`` (2,) overlaps any placed box."""
    if not len(placed_xy):
        return np.zeros(len(candidates), dtype=bool)
    gap_x = np.abs(candidates[:, 0, None] - placed_xy[None, :, 0])  # (C, K)
    gap_y = np.abs(candidates[:, 1, None] - placed_xy[None, :, 1])
    return ((gap_x < half[0] + placed_half[None, :, 0]) & (gap_y < half[1] + placed_half[None, :, 1])).any(axis=1)


def place_obstacles(pool: ObstaclePool, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Positions (O, 2) and presence (O,) of the obstacles of an episode.

    Static obstacles stand at their fixed spot.  Each other obstacle draws candidates in its box and takes the
    first where a square of half-side ``padding`` around the candidate's centre touches no obstacle placed before
    it (their whole footprints count).  That is the original's test: it sized the candidate's box from the
    prefab asset's collider, whose bounds Unity reports as empty, so only the padding remained.  The original
    gave up after 100 candidates and left the obstacle out; here a level always holds every obstacle it lists:
    after 100 candidates more are drawn, and after :data:`PLACEMENT_LIMIT` the episode cannot be built and a
    :class:`~evaaa.level.LevelError` names the group.
    """
    xy = np.zeros((pool.size_total, 2))
    present = np.zeros(pool.size_total, dtype=bool)
    placed_xy, placed_half, m = np.zeros((pool.size_total, 2)), np.zeros((pool.size_total, 2)), 0
    # the first 100 tries of every obstacle that moves are drawn up front, in obstacle order (the generator's
    # stream does not depend on how many are needed), and tested a few at a time: most fit at the first try
    moving = np.flatnonzero(~pool.static)
    tries = rng.uniform(pool.low[moving, None, :], pool.high[moving, None, :], size=(len(moving), PLACEMENT_TRIES, 2))
    row = np.full(pool.size_total, -1)
    row[moving] = np.arange(len(moving))
    for o in range(pool.size_total):
        if pool.static[o]:
            spot = pool.low[o]
        else:
            spot = _first_free(tries[row[o]], np.full(2, pool.padding[o]), placed_xy[:m], placed_half[:m])
            drawn = PLACEMENT_TRIES
            while spot is None and drawn < PLACEMENT_LIMIT:  # a crowded level: keep looking
                more = rng.uniform(pool.low[o], pool.high[o], size=(PLACEMENT_TRIES, 2))
                spot = _first_free(more, np.full(2, pool.padding[o]), placed_xy[:m], placed_half[:m])
                drawn += PLACEMENT_TRIES
            if spot is None:
                group = pool.names[pool.group[o]]
                number = int((pool.group[:o] == pool.group[o]).sum()) + 1
                total = int((pool.group == pool.group[o]).sum())
                raise LevelError(
                    f"obstacles.{group}: obstacle {number} of {total} found no free spot in {PLACEMENT_LIMIT} "
                    f"candidates (padding {pool.padding[o]:g} m around its centre must touch no other obstacle); "
                    f"lower obstacles.{group}.count or padding, or widen its x/y box"
                )
        xy[o], present[o] = spot, True
        placed_xy[m], placed_half[m] = spot, pool.half[o]
        m += 1
    return xy, present


def _first_free(
    candidates: np.ndarray, half: np.ndarray, placed_xy: np.ndarray, placed_half: np.ndarray
) -> np.ndarray | None:
    """The first candidate (2,) whose box overlaps no placed box, or None."""
    for chunk in (candidates[:8], candidates[8:]):
        free = np.flatnonzero(~_overlaps(chunk, half, placed_xy, placed_half))
        if len(free):
            return chunk[free[0]]
    return None


# ------------------------------------------------------------------------------------------------ agent
def sample_agent_start(
    level: Level,
    rng: np.random.Generator,
    blocker_xy: np.ndarray,
    blocker_half: np.ndarray,
    tries: int = PLACEMENT_TRIES,
) -> tuple[np.ndarray, float]:
    """The agent's start position (2,) and compass heading (degrees).

    A random start is drawn uniformly in the spawn box (kept inside the floor) and rejected while a square of
    half-side 0.5 + ``spawn_padding`` around it overlaps a blocker's box (``blocker_xy`` (B, 2) centres,
    ``blocker_half`` (B, 2) or (B,) half-sides); after ``tries`` rejections the fixed start is used.
    """
    a = level.agent
    if a.start == "fixed":
        return np.array(a.start_position, dtype=np.float64), float(a.start_heading) % 360.0
    half_floor = np.array(level.arena.size) / 2 - AGENT_HALF
    low = np.maximum([a.spawn_x[0], a.spawn_y[0]], -half_floor)
    high = np.minimum([a.spawn_x[1], a.spawn_y[1]], half_floor)
    candidates = rng.uniform(low, high, size=(tries, 2))
    heading = float(rng.uniform(0.0, 360.0))
    # (B, 1) or (B, 2); reshaped to (B, -1) only when B > 0 (numpy cannot infer -1 from an empty array)
    blocker_half = np.asarray(blocker_half, dtype=np.float64)
    blocker_half = np.broadcast_to(
        blocker_half.reshape(len(blocker_xy), -1) if len(blocker_xy) else np.zeros((0, 2)), (len(blocker_xy), 2)
    )
    blocked = _overlaps(candidates, np.full(2, AGENT_HALF + a.spawn_padding), blocker_xy, blocker_half)
    free = np.flatnonzero(~blocked)
    if len(free) == 0:
        return np.array(a.start_position, dtype=np.float64), heading
    return candidates[free[0]], heading


# ------------------------------------------------------------------------------------------------ landmarks
def landmark_candidates(level: Level) -> np.ndarray:
    """Every landmark point the pattern asks for, (L, 2); the first pattern row is the north (+y) edge."""
    spec = level.landmarks
    if spec is None:
        return np.zeros((0, 2))
    rows, cols = len(spec.pattern), len(spec.pattern[0])
    width, depth = level.arena.size
    cell_w, cell_d = width / cols, depth / rows
    points = []
    for r, row in enumerate(spec.pattern):
        for c, n in enumerate(row):
            if n <= 0:
                continue
            x0, y1 = -width / 2 + c * cell_w, depth / 2 - r * cell_d
            offsets = (np.arange(n) + 0.5) / n
            for fx in offsets:
                for fy in offsets:
                    points.append((x0 + fx * cell_w, y1 - fy * cell_d))
    return np.array(points, dtype=np.float64).reshape(-1, 2)


def place_landmarks(level: Level, obstacle_xy: np.ndarray, obstacle_half: np.ndarray) -> np.ndarray:
    """The landmark points of an episode: candidates whose square (side 2 radius, grown by the padding) is
    clear of the episode's obstacles."""
    spec = level.landmarks
    candidates = landmark_candidates(level)
    if spec is None or not len(candidates):
        return candidates
    half = np.full(2, spec.radius + spec.padding / 2)
    keep = ~_overlaps(candidates, half, obstacle_xy, obstacle_half)
    return candidates[keep] if keep.any() else candidates


class PatrolArea:
    """The convex hull of the landmarks: predators keep inside it."""

    def __init__(self, points: np.ndarray):
        from scipy.spatial import ConvexHull, QhullError  # here: `import evaaa` need not load scipy.spatial

        self.points = points
        try:
            hull = ConvexHull(points)
            self.equations = hull.equations  # (F, 3): inside where a.x + b.y + c <= 0
            self.vertices = points[hull.vertices]
        except (QhullError, ValueError):
            # fewer than three points, or all on a line: fall back to their bounding box
            lo, hi = points.min(axis=0) - 1.0, points.max(axis=0) + 1.0
            self.equations = np.array([[-1, 0, lo[0]], [1, 0, -hi[0]], [0, -1, lo[1]], [0, 1, -hi[1]]], float)
            self.vertices = np.array([lo, (hi[0], lo[1]), hi, (lo[0], hi[1])])

    def contains(self, xy: np.ndarray, tolerance: float = 1e-6) -> np.ndarray:
        xy = np.atleast_2d(xy)
        return np.all(xy @ self.equations[:, :2].T + self.equations[:, 2] <= tolerance, axis=1)


def sample_predator_starts(level: Level, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Start positions (K, 2) and compass headings (K,) radians of every predator slot."""
    xy, heading = [], []
    for spec in level.predators.values():
        for _ in range(spec.count):
            xy.append(rng.uniform((spec.x[0], spec.y[0]), (spec.x[1], spec.y[1])))
            heading.append(np.radians(spec.heading))
    return np.array(xy, dtype=np.float64).reshape(-1, 2), np.array(heading, dtype=np.float64)
