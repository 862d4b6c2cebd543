"""Collision (proximity) sensing: horizontal rays from the body centre, grouped into sectors of 0 or 1.

Ray i points ``i * 360 / rays`` degrees clockwise from straight ahead; sector k holds rays
``k * rays/sectors`` ... and reads 1 if any of them hits something (wall, obstacle, resource) within ``range``
of the centre.

Solid geometry (walls, obstacles) is ray-cast by MuJoCo, one ``mj_multiRay`` call per world and only for worlds
with something solid within reach.  Consumables are axis-aligned cubes; ``mj_multiRay`` tests every ray
against every geom without spatial pruning, so the few cubes within reach are tested here with the slab method
instead of making MuJoCo test all of them.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from ..scene import GROUP_INVISIBLE, GROUP_SOLID
from .base import Sensor


class CollisionRays(Sensor):
    key = "collision"

    def __init__(self, sim):
        super().__init__(sim)
        spec = sim.level.sensors.collision
        self.rays, self.sectors, self.range = spec.rays, spec.sectors, spec.range
        self.offsets = np.radians(np.arange(self.rays) * 360.0 / self.rays)
        self._vec = np.zeros((self.rays, 3))
        self._geomid = np.zeros(self.rays, dtype=np.int32)
        self._dist = np.zeros(self.rays)
        self._solid_groups = np.zeros(6, dtype=np.uint8)
        self._solid_groups[[GROUP_SOLID, GROUP_INVISIBLE]] = 1
        # an item whose centre is farther than this cannot be touched by a ray
        self._item_reach2 = (self.range + math.sqrt(2) * sim.res_half) ** 2  # (P,)
        self._wall_inner = np.array(sim.level.arena.size) / 2 - self.range
        self._ray_z = sim.agent_z

    @property
    def shape(self) -> tuple[int, ...]:
        return (self.sectors,)

    def read(self, worlds: np.ndarray) -> np.ndarray:
        sim = self.sim
        hits = np.zeros((len(worlds), self.rays), dtype=bool)
        near_solid = (np.abs(sim.pos[worlds]) > self._wall_inner).any(axis=1)
        near_items = (sim.item_distances2()[worlds] < self._item_reach2) & sim.res_present[worlds]
        for row in np.flatnonzero(near_solid | near_items.any(axis=1)):
            w = worlds[row]
            directions = sim.heading_rad[w] + self.offsets  # compass: direction (sin, cos)
            dx, dy = np.sin(directions), np.cos(directions)
            if near_solid[row]:
                hits[row] |= self._cast_solid(w, dx, dy)
            items = np.flatnonzero(near_items[row])
            if len(items):
                hits[row] |= self._cast_items(w, items, dx, dy)
        return hits.reshape(len(worlds), self.sectors, -1).any(axis=2).astype(np.float32)

    def _cast_solid(self, w: int, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
        sim = self.sim
        vec, dist = self._vec, self._dist
        vec[:, 0] = dx
        vec[:, 1] = dy
        data, body = sim.datas[w], sim.index.agent_body
        mujoco.mj_multiRay(sim.model, data, data.xpos[body], vec.reshape(-1), self._solid_groups, 1, body,
                           self._geomid, dist, None, self.rays, self.range)
        return (dist >= 0) & (dist <= self.range)

    def _cast_items(self, w: int, items: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
        """Slab test of every ray against the axis-aligned cubes ``items`` of world ``w``."""
        sim = self.sim
        half = sim.res_half[items]  # (K,)
        z_centre = sim.pool.centre_z()[items]
        at_height = np.abs(self._ray_z - z_centre) <= half  # horizontal rays pass over low items
        rel = sim.res_xy[w, items] - sim.pos[w]  # (K, 2) item centre relative to the ray origin
        with np.errstate(divide="ignore", invalid="ignore"):
            inv_x, inv_y = 1.0 / dx, 1.0 / dy  # (R,)
            tx1 = (rel[:, 0:1] - half[:, None]) * inv_x
            tx2 = (rel[:, 0:1] + half[:, None]) * inv_x
            ty1 = (rel[:, 1:2] - half[:, None]) * inv_y
            ty2 = (rel[:, 1:2] + half[:, None]) * inv_y
            t_near = np.maximum(np.minimum(tx1, tx2), np.minimum(ty1, ty2))  # (K, R)
            t_far = np.minimum(np.maximum(tx1, tx2), np.maximum(ty1, ty2))
        hit = (t_far >= np.maximum(t_near, 0.0)) & (t_near <= self.range) & at_height[:, None]
        return hit.any(axis=0)
