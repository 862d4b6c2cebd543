"""A level's obstacles (rocks, walls, bonfires, ...): where each episode puts them, and the heat of the hot ones.

:class:`ObstacleLayout` holds the pool's fixed per-slot data it needs; the per-world positions and presence it
places are the ``obs_xy`` and ``obs_present`` of :class:`~evaaa.state.WorldState`.
"""

from __future__ import annotations

import mujoco
import numpy as np

from .entities import OBSTACLE_KINDS, footprint_half
from .state import WorldState
from .worldgen import PARKED_Z, ObstaclePool, place_obstacles

#: "near heat" in the episode records: within this many metres of a hot obstacle's footprint
NEAR_HEAT = 3.0


class ObstacleLayout:
    """The obstacles of one level, for a batch of worlds.

    Args:
        pool: the level's obstacle slots.
        mocap: the scene's mocap index of each slot, -1 for the static ones (built into the scene).
    """

    def __init__(self, pool: ObstaclePool, mocap: np.ndarray):
        self.pool = pool
        self.moving = mocap >= 0
        self.mocap = mocap[self.moving]
        self.z = pool.centre_z()
        self.heat = pool.temperature != 0
        self.hot = np.flatnonzero(self.heat)
        self.heat_half = np.zeros((pool.size_total, 2))  # half-sides of the axis-aligned box around each footprint
        for kind in set(pool.kind):
            m = pool.kind == kind
            self.heat_half[m] = footprint_half(OBSTACLE_KINDS[kind], pool.extents[m], pool.heading[m])

    def reset_world(self, state: WorldState, w: int, rng: np.random.Generator) -> np.ndarray:
        """Place world ``w``'s obstacles for a new episode; returns the hot ones' footprints (H, 5): x from, x to,
        y from, y to, temperature (what :func:`evaaa.thermal.build_field` warms the floor with)."""
        state.obs_xy[w], state.obs_present[w] = place_obstacles(self.pool, rng)
        hot = self.heat & state.obs_present[w]
        xy, half = state.obs_xy[w, hot], self.heat_half[hot]
        return np.column_stack(
            [
                xy[:, 0] - half[:, 0],
                xy[:, 0] + half[:, 0],
                xy[:, 1] - half[:, 1],
                xy[:, 1] + half[:, 1],
                self.pool.temperature[hot],
            ]
        )

    def write(self, state: WorldState, w: int, data: mujoco.MjData) -> None:
        """Put world ``w``'s movable obstacles into its scene (absent ones parked under the floor)."""
        if not len(self.mocap):
            return
        moving = self.moving
        mocap = data.mocap_pos
        mocap[self.mocap, 0] = state.obs_xy[w, moving, 0]
        mocap[self.mocap, 1] = state.obs_xy[w, moving, 1]
        mocap[self.mocap, 2] = np.where(state.obs_present[w, moving], self.z[moving], PARKED_Z)

    def near_heat(self, state: WorldState) -> np.ndarray | None:
        """(N,) whether each body stands within :data:`NEAR_HEAT` of a placed hot obstacle's footprint (None
        when the level has no hot obstacle)."""
        if not len(self.hot):
            return None
        hot = self.hot
        gap = np.abs(state.pos[:, None, :] - state.obs_xy[:, hot]) - self.heat_half[hot]  # (N, H, 2)
        dist = np.linalg.norm(np.maximum(gap, 0.0), axis=-1)
        return (state.obs_present[:, hot] & (dist <= NEAR_HEAT)).any(axis=1)
