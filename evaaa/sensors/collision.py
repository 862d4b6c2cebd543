"""Collision (proximity) sensing: horizontal rays from the body centre, grouped into sectors of 0 or 1.

Ray i points ``i * 360 / rays`` degrees clockwise from straight ahead; sector k holds rays
``k * rays/sectors`` ... and reads 1 if any of them hits something (wall, obstacle, pond, predator, item)
within ``range`` of the centre.

Solid geometry (walls, obstacles, ponds, predators) is ray-cast by MuJoCo, one ``mj_multiRay`` call per world
and only for worlds with something solid within reach.  Consumables are boxes; ``mj_multiRay`` tests every ray
against every geom without spatial pruning, so the few items within reach are tested here with the slab method
instead of making MuJoCo test all of them.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from ..predator import PREDATOR_HALF
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
        # a thing whose centre is farther than this cannot be touched by a ray
        self._item_reach2 = (self.range + np.hypot(*sim.res_half.T)) ** 2  # (P,)
        self._soft = ~sim.res_solid
        self._obstacle_reach2 = (self.range + np.hypot(*sim.obstacles.half.T)) ** 2  # (O,)
        self._predator_reach2 = (self.range + math.sqrt(2) * PREDATOR_HALF) ** 2
        self._wall_inner = np.array(sim.level.arena.size) / 2 - self.range
        self._ray_z = sim.agent_z

    @property
    def shape(self) -> tuple[int, ...]:
        return (self.sectors,)

    def _near_solid(self, worlds: np.ndarray) -> np.ndarray:
        sim = self.sim
        pos = sim.pos[worlds]
        near = (np.abs(pos) > self._wall_inner).any(axis=1)
        if sim.obstacles.size_total:
            d2 = ((sim.obs_xy[worlds] - pos[:, None, :]) ** 2).sum(-1)
            near |= ((d2 < self._obstacle_reach2) & sim.obs_present[worlds]).any(axis=1)
        if sim.res_solid.any():
            near |= ((sim.item_distances2()[worlds] < self._item_reach2) & sim.res_present[worlds]
                     & sim.res_solid).any(axis=1)
        if sim.predators.k:
            d2 = ((sim.predators.xy[worlds] - pos[:, None, :]) ** 2).sum(-1)
            near |= (d2 < self._predator_reach2).any(axis=1)
        return near

    def read(self, worlds: np.ndarray) -> np.ndarray:
        sim = self.sim
        hits = np.zeros((len(worlds), self.rays), dtype=bool)
        near_solid = self._near_solid(worlds)
        near_items = (sim.item_distances2()[worlds] < self._item_reach2) & sim.res_present[worlds] & self._soft
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
        """Slab test of every ray against the boxes of ``items`` of world ``w``, each in its own frame."""
        sim = self.sim
        half = sim.res_half3[items]  # (K, 3)
        z_centre = sim.pool.centre_z()[items]
        at_height = np.abs(self._ray_z - z_centre) <= half[:, 2]  # horizontal rays pass over low items
        rel = sim.pos[w] - sim.res_xy[w, items]  # (K, 2) ray origin relative to each item
        c, s = sim.res_cos[items, None], sim.res_sin[items, None]
        # rotate origins and directions into each item's frame (items are turned by -heading about z)
        ox = rel[:, 0:1] * c - rel[:, 1:2] * s
        oy = rel[:, 0:1] * s + rel[:, 1:2] * c
        rx = dx[None, :] * c - dy[None, :] * s  # (K, R)
        ry = dx[None, :] * s + dy[None, :] * c
        with np.errstate(divide="ignore", invalid="ignore"):
            tx1 = (-half[:, 0:1] - ox) / rx
            tx2 = (half[:, 0:1] - ox) / rx
            ty1 = (-half[:, 1:2] - oy) / ry
            ty2 = (half[:, 1:2] - oy) / ry
            t_near = np.maximum(np.minimum(tx1, tx2), np.minimum(ty1, ty2))
            t_far = np.minimum(np.maximum(tx1, tx2), np.maximum(ty1, ty2))
        hit = (t_far >= np.maximum(t_near, 0.0)) & (t_near <= self.range) & at_height[:, None]
        return hit.any(axis=0)
