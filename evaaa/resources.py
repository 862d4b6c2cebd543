"""A level's items (food, water, apples, ponds): where they lie, which the body's mouth reaches, eating and regrowth.

:class:`Resources` holds the pool's fixed per-slot data and the eating sphere's geometry; the per-world positions,
presence and grouped group it places, consumes and respawns are the ``res_xy``, ``res_present`` and
``active_group`` of :class:`~evaaa.state.WorldState`.
"""

from __future__ import annotations

import mujoco
import numpy as np

from .entities import RESOURCE_KINDS, footprint_half
from .level import Level
from .state import WorldState
from .worldgen import AGENT_HALF, FOOD, PARKED_Z, WATER, ResourcePool, draw_grouped, place_resources, resources_present

#: the eating sphere's centre sits this far below the body centre
EAT_DROP = 0.065


class Resources:
    """The items of one level, for a batch of worlds.

    Args:
        level: the level (its agent's eating radius and reach).
        pool: the level's item slots.
        mocap: the scene's mocap index of each slot (where :meth:`write` puts the items).
    """

    def __init__(self, level: Level, pool: ResourcePool, mocap: np.ndarray):
        self.pool = pool
        self.mocap = mocap
        p = pool.size_total
        self.eat_radius2 = level.agent.eat_radius**2
        self.eat_offset = level.agent.eat_offset
        self.half3 = pool.extents / 2  # (P, 3) half-extents in each item's own frame
        self.half = np.zeros((p, 2))  # (P, 2) half-sides of the axis-aligned box around each footprint
        for kind in set(pool.kind):
            m = pool.kind == kind
            self.half[m] = footprint_half(RESOURCE_KINDS[kind], pool.extents[m], pool.heading[m])
        self.cos, self.sin = np.cos(pool.heading), np.sin(pool.heading)
        self.is_food = pool.feeds == FOOD
        self.is_water = pool.feeds == WATER
        self.respawns = pool.respawn == "random"
        self.grouped = pool.respawn == "grouped"
        self.solid = pool.solid
        self.centre_z = pool.centre_z()
        # vertical gap between the eating sphere's centre and each item's box (it sits a little below the eye)
        self.eat_dz2 = np.maximum(np.abs(AGENT_HALF - EAT_DROP - self.centre_z) - self.half3[:, 2], 0.0) ** 2

    def reset_world(self, state: WorldState, w: int, rng: np.random.Generator) -> None:
        """Lay out world ``w``'s items for a new episode."""
        state.active_group[w] = draw_grouped(self.pool, rng)
        state.res_xy[w] = place_resources(self.pool, rng)
        state.res_present[w] = resources_present(self.pool, state.active_group[w])

    def write(self, state: WorldState, w: int, data: mujoco.MjData) -> None:
        """Put world ``w``'s items into its scene (absent ones parked under the floor)."""
        z = np.where(state.res_present[w], self.centre_z, PARKED_Z)
        mocap = data.mocap_pos
        mocap[self.mocap, 0] = state.res_xy[w, :, 0]
        mocap[self.mocap, 1] = state.res_xy[w, :, 1]
        mocap[self.mocap, 2] = z

    # ------------------------------------------------------------------------------------------------ eating
    def eat_centre(self, pos: np.ndarray, heading: np.ndarray) -> np.ndarray:
        """The eating sphere's centre, ``eat_offset`` ahead of a body at ``pos`` (..., 2) facing ``heading``."""
        return pos + self.eat_offset * np.stack([np.sin(heading), np.cos(heading)], axis=-1)

    def eat_dist2(self, centre: np.ndarray, item_xy: np.ndarray, slots) -> np.ndarray:
        """Squared distance from the eating sphere's centre to the nearest point of the items' boxes (``slots``:
        an index or slice of the pool), measured in each item's own frame (items are turned by a fixed heading)."""
        rel = centre - item_xy
        cos, sin = self.cos[slots], self.sin[slots]
        local_x = rel[..., 0] * cos - rel[..., 1] * sin
        local_y = rel[..., 0] * sin + rel[..., 1] * cos
        gap_x = np.maximum(np.abs(local_x) - self.half3[slots, 0], 0.0)
        gap_y = np.maximum(np.abs(local_y) - self.half3[slots, 1], 0.0)
        return gap_x**2 + gap_y**2 + self.eat_dz2[slots]

    def can_eat(self, item_xy: np.ndarray, slot: int, pos: np.ndarray, heading) -> np.ndarray:
        """Whether the eating sphere of a body at ``pos`` (..., 2) facing ``heading`` (radians, compass) overlaps
        item ``slot`` lying at ``item_xy``: the test :meth:`consume` applies."""
        centre = self.eat_centre(np.asarray(pos, dtype=np.float64), np.asarray(heading, dtype=np.float64))
        return self.eat_dist2(centre, item_xy, slot) <= self.eat_radius2

    def consume(self, state: WorldState, eating: np.ndarray, rngs: list[np.random.Generator]) -> np.ndarray | None:
        """Eat, in the worlds where ``eating``, every present item the eating sphere overlaps, and let each regrow
        by its rule; (N, P) the items eaten (None if none was).  The scenes are the caller's to update."""
        if not eating.any() or self.pool.size_total == 0:
            return None
        worlds = np.flatnonzero(eating)
        centre = self.eat_centre(state.pos[worlds], state.heading_rad[worlds])
        dist2 = self.eat_dist2(centre[:, None, :], state.res_xy[worlds], slice(None))  # (W, P): sphere-box overlap
        hits = (dist2 <= self.eat_radius2) & state.res_present[worlds]
        if not hits.any():
            return None
        consumed = np.zeros(state.res_present.shape, dtype=bool)
        consumed[worlds] = hits
        for w in worlds[hits.any(axis=1)]:  # the worlds that ate (each draws from its own generator)
            self._regrow(state, w, np.flatnonzero(consumed[w]), rngs[w])
        return consumed

    def _regrow(self, state: WorldState, w: int, slots: np.ndarray, rng: np.random.Generator) -> None:
        """Items ``slots`` of world ``w`` were eaten: random ones reappear elsewhere in their box, grouped ones
        are gone until their group is bare, when another group grows."""
        moving = slots[self.respawns[slots]]
        if len(moving):
            state.res_xy[w, moving] = place_resources(self.pool, rng, moving)
        eaten_grouped = slots[self.grouped[slots]]
        if len(eaten_grouped):
            state.res_present[w, eaten_grouped] = False
            if not (state.res_present[w] & self.grouped).any():
                state.active_group[w] = draw_grouped(self.pool, rng)
                fresh = np.flatnonzero(self.pool.group == state.active_group[w])
                state.res_xy[w, fresh] = place_resources(self.pool, rng, fresh)
                state.res_present[w, fresh] = True
