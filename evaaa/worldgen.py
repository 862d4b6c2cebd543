"""World generation: a level spec and a random generator in, a concrete layout out.

Pure numpy; nothing here builds or touches MuJoCo.  The scene keeps one pooled body per resource slot, so a
layout is just arrays: where every slot sits, whether it is present, where the agent starts.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .spec import Level

FOOD, WATER = 0, 1
KINDS: tuple[str, ...] = ("food", "water")
#: Odour of one item of each kind: five food channels then five water channels, scaled by 1/distance.
ODOUR = {
    "food": np.array([0.1] * 5 + [0.0] * 5),
    "water": np.array([0.0] * 5 + [0.1] * 5),
}
#: Where hidden or unused pooled bodies wait: far below the floor, out of sight and out of reach of rays.
PARKED_Z = -100.0
AGENT_HALF = 0.5


@dataclass(frozen=True)
class ResourcePool:
    """The fixed slots of a level's resources, concatenated over its groups (P slots)."""

    names: tuple[str, ...]  # group name per group
    group: np.ndarray  # (P,) group index of each slot
    kind: np.ndarray  # (P,) FOOD or WATER
    low: np.ndarray  # (P, 2) lower corner of the slot's placement box
    high: np.ndarray  # (P, 2)
    size: np.ndarray  # (P,) cube edge
    respawns: np.ndarray  # (P,) True: a consumed item reappears elsewhere; False: never depletes
    odour: np.ndarray  # (P, 10)

    @property
    def size_total(self) -> int:
        return len(self.kind)

    @classmethod
    def from_level(cls, level: Level) -> "ResourcePool":
        names, group, kind, low, high, size, respawns, odour = [], [], [], [], [], [], [], []
        for g, (name, spec) in enumerate(level.resources.items()):
            names.append(name)
            for _ in range(spec.count):
                group.append(g)
                kind.append(KINDS.index(spec.kind))
                low.append((spec.x[0], spec.y[0]))
                high.append((spec.x[1], spec.y[1]))
                size.append(spec.size)
                respawns.append(spec.respawn == "random")
                odour.append(ODOUR[spec.kind])
        return cls(
            names=tuple(names),
            group=np.array(group, dtype=np.int64),
            kind=np.array(kind, dtype=np.int64),
            low=np.array(low, dtype=np.float64).reshape(-1, 2),
            high=np.array(high, dtype=np.float64).reshape(-1, 2),
            size=np.array(size, dtype=np.float64),
            respawns=np.array(respawns, dtype=bool),
            odour=np.array(odour, dtype=np.float64).reshape(-1, 10),
        )

    def centre_z(self) -> np.ndarray:
        """Height of each slot's centre when resting on the floor."""
        return self.size / 2


def place_resources(pool: ResourcePool, rng: np.random.Generator, slots: np.ndarray | None = None) -> np.ndarray:
    """Uniform positions (len(slots), 2) inside each slot's box (all slots if ``slots`` is None)."""
    low, high = (pool.low, pool.high) if slots is None else (pool.low[slots], pool.high[slots])
    return rng.uniform(low, high)


def sample_agent_start(
    level: Level,
    rng: np.random.Generator,
    blocker_xy: np.ndarray,
    blocker_half: np.ndarray,
    tries: int = 100,
) -> tuple[np.ndarray, float]:
    """The agent's start position (2,) and compass heading (degrees).

    A random start is drawn uniformly in the spawn box (kept inside the floor) and rejected while a square of
    half-side 0.5 + ``spawn_padding`` around it overlaps a blocker's square (``blocker_xy`` (B, 2) centres,
    ``blocker_half`` (B,) half-sides); after ``tries`` rejections the fixed start is used.
    """
    a = level.agent
    if a.start == "fixed":
        return np.array(a.start_position, dtype=np.float64), float(a.start_heading) % 360.0
    half_floor = np.array(level.arena.size) / 2 - AGENT_HALF
    low = np.maximum([a.spawn_x[0], a.spawn_y[0]], -half_floor)
    high = np.minimum([a.spawn_x[1], a.spawn_y[1]], half_floor)
    candidates = rng.uniform(low, high, size=(tries, 2))
    heading = float(rng.uniform(0.0, 360.0))
    if len(blocker_xy):
        reach = AGENT_HALF + a.spawn_padding + blocker_half  # (B,)
        gap = np.abs(candidates[:, None, :] - blocker_xy[None, :, :])  # (tries, B, 2)
        clear = ~np.any(np.all(gap < reach[None, :, None], axis=-1), axis=1)
        free = np.flatnonzero(clear)
        if len(free) == 0:
            return np.array(a.start_position, dtype=np.float64), heading
        return candidates[free[0]], heading
    return candidates[0], heading
