"""Collision (proximity) sensing: horizontal rays from the body centre, grouped into sectors of 0 or 1.

Ray i points ``i * 360 / rays`` degrees clockwise from straight ahead; sector k holds rays
``k * rays/sectors`` ... and reads 1 if any of them hits something (wall, obstacle, item, predator) within
``range`` of the centre.

The rays are horizontal at the body centre's height, so each thing they can meet is a 2-D slice there: a
rectangle (boxes) or an ellipse (ellipsoids, domes, cylinders), in the thing's own frame.  Only things within
reach are cast against, all rays at once, in numpy.  ``mj_multiRay`` would give the same answer (a test checks
that it does) but tests every ray against every geom of the scene, which costs ~0.1 ms per world on a level
with a hundred obstacles; this costs a few microseconds per nearby thing.
"""

from __future__ import annotations

import numpy as np

from ..entities import ELLIPSE, OBSTACLE_KINDS, PREDATOR, RECT, RESOURCE_KINDS, cross_section
from .base import Sensor, World


class CollisionRays(Sensor):
    key = "collision"
    order = 4
    bounds = (0.0, 1.0)  # one 0/1 flag per sector

    def __init__(self, sim: World):
        super().__init__(sim)
        spec = sim.level.sensors.collision
        self.rays, self.sectors, self.range = spec.rays, spec.sectors, spec.range
        self.offsets = np.radians(np.arange(self.rays) * 360.0 / self.rays)
        z = sim.agent_z
        level, obstacles, pool = sim.level, sim.obstacles, sim.pool

        # things, in this order: walls, obstacles, items, predators
        shapes, halves, headings = [], [], []
        hx, hy = np.array(level.arena.size) / 2
        self._walls = np.array([(hx + 0.5, 0.0), (-hx - 0.5, 0.0), (0.0, hy + 0.5), (0.0, -hy - 0.5)])
        wall_half = np.array([(0.5, hy + 1), (0.5, hy + 1), (hx + 1, 0.5), (hx + 1, 0.5)])
        if not level.arena.walls:  # open arenas are bounded by invisible walls the rays do not see
            wall_half[:] = 0.0
        shapes += [RECT] * 4
        halves.append(wall_half)
        headings.append(np.zeros(4))
        for kinds, names, extents, heading, lift in (
            (OBSTACLE_KINDS, obstacles.kind, obstacles.extents, obstacles.heading, obstacles.lift),
            (RESOURCE_KINDS, pool.kind, pool.extents, pool.heading, np.zeros(pool.size_total)),
        ):
            half = np.zeros((len(names), 2))
            for name in set(names):
                m = names == name
                # a thing raised by ``lift`` is cut at the rays' height where a resting one is cut lower by as much
                _, half[m] = cross_section(kinds[name], extents[m], z - lift[m])
            shapes += [RECT if kinds[name].shape == "box" else ELLIPSE for name in names]
            halves.append(half)
            headings.append(heading)
        k = sim.predators.k
        _, predator_half = cross_section(PREDATOR, np.array(PREDATOR.base), z)
        shapes += [RECT] * k
        halves.append(np.tile(predator_half, (k, 1)))
        headings.append(np.zeros(k))
        self._shape = np.array(shapes, dtype=np.int64)
        self._half = np.concatenate(halves)
        self._heading = np.concatenate(headings)
        self._reach = np.hypot(*self._half.T)  # a thing's slice lies within this distance of its centre
        self._reach[:4] = 0.0  # walls are tested against their sides below, not a bounding circle
        self._near2 = (self.range + self._reach) ** 2  # squared centre distance within which a thing may be hit
        self._counts = (4, obstacles.size_total, pool.size_total, k)
        # per-world buffers of the things' centres, headings and presence: the walls' rows and the fixed headings
        # are written once here, the rest on every read
        solid = self._half[:, 0] > 0  # things of no extent (the walls of an open arena) are never there
        self._solid = solid
        self._centres = np.zeros((sim.n, len(solid), 2))
        self._centres[:, :4] = self._walls
        self._present = np.broadcast_to(solid, (sim.n, len(solid))).copy()
        self._headings = np.broadcast_to(self._heading, (sim.n, len(solid))).copy()

    @property
    def shape(self) -> tuple[int, ...]:
        return (self.sectors,)

    def _things(self, worlds: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Centres (W, T, 2), headings (W, T) and presence (W, T) of every thing in ``worlds`` (views of buffers
        that the next call overwrites)."""
        sim = self.sim
        n = len(worlds)
        _, o, p, k = self._counts
        items, preds = 4 + o, 4 + o + p
        centres, present, headings = self._centres[:n], self._present[:n], self._headings[:n]
        if n == sim.n:  # every world (``worlds`` holds distinct indices in order): slices copy without gathering
            worlds = slice(None)
        centres[:, 4:items] = sim.obs_xy[worlds]
        centres[:, items:preds] = sim.res_xy[worlds]
        np.logical_and(sim.obs_present[worlds], self._solid[4:items], out=present[:, 4:items])
        np.logical_and(sim.res_present[worlds], self._solid[items:preds], out=present[:, items:preds])
        if k:
            centres[:, preds:] = sim.predators.xy[worlds]
            headings[:, preds:] = sim.predators.heading[worlds]
        return centres, headings, present

    def read(self, worlds: np.ndarray) -> np.ndarray:
        sim = self.sim
        centres, headings, present = self._things(worlds)
        pos = sim.pos[worlds]
        delta = pos[:, None, :] - centres  # (W, T, 2) ray origin relative to each thing
        near = present & (delta[..., 0] ** 2 + delta[..., 1] ** 2 <= self._near2)
        # walls: near when the body centre is within range of the wall's inner face
        wall_gap = np.abs(delta[:, :4]) - self._half[:4]
        near[:, :4] = present[:, :4] & (wall_gap.max(axis=-1) <= self.range)
        out = np.zeros((len(worlds), self.sectors), dtype=np.float32)
        rows, things = np.nonzero(near)  # every (world, thing) pair within reach, world by world
        if len(rows):
            directions = sim.heading_rad[worlds[rows]][:, None] + self.offsets  # (K, R) compass directions
            hits = self._cast(
                delta[rows, things], headings[rows, things], things, np.sin(directions), np.cos(directions)
            )
            # a ray hits if it meets any thing of its world: OR the pairs of each world together
            change = np.empty(len(rows), dtype=bool)
            change[0] = True
            np.not_equal(rows[1:], rows[:-1], out=change[1:])
            starts = np.flatnonzero(change)
            per_world = np.logical_or.reduceat(hits, starts, axis=0)  # (worlds with a pair, R)
            out[rows[starts]] = per_world.reshape(len(starts), self.sectors, -1).any(axis=2)
        return out

    def _cast(
        self, origin: np.ndarray, heading: np.ndarray, things: np.ndarray, dx: np.ndarray, dy: np.ndarray
    ) -> np.ndarray:
        """(K, R) whether ray r of pair k meets the pair's thing within range: origins relative to the things
        (K, 2), the things' headings (K,), their indices (K,) and the rays' directions (K, R)."""
        c, s = np.cos(heading)[:, None], np.sin(heading)[:, None]
        # into each thing's frame (a thing at compass heading h is turned by -h)
        ox = origin[:, 0:1] * c - origin[:, 1:2] * s
        oy = origin[:, 0:1] * s + origin[:, 1:2] * c
        rx = dx * c - dy * s  # (K, R)
        ry = dx * s + dy * c
        half = self._half[things]
        a, b = half[:, 0:1], half[:, 1:2]
        rect = self._shape[things] == RECT
        if rect.all():  # boxes only (the common case): no masking
            return self._cast_rect(ox, oy, rx, ry, a, b)
        hit = np.zeros(rx.shape, dtype=bool)
        if rect.any():
            hit[rect] = self._cast_rect(ox[rect], oy[rect], rx[rect], ry[rect], a[rect], b[rect])
        ell = ~rect
        if ell.any():
            # scale the ellipse to the unit circle and solve |o + t d|^2 = 1 for the ray parameter t
            px, py = ox[ell] / a[ell], oy[ell] / b[ell]
            qx, qy = rx[ell] / a[ell], ry[ell] / b[ell]
            qa = qx**2 + qy**2
            qb = 2.0 * (px * qx + py * qy)
            qc = px**2 + py**2 - 1.0
            disc = qb**2 - 4.0 * qa * qc
            root = np.sqrt(np.maximum(disc, 0.0))
            t_near = (-qb - root) / (2.0 * qa)
            t_far = (-qb + root) / (2.0 * qa)
            hit[ell] = (qc <= 0) | ((disc >= 0) & (t_far >= 0) & (t_near <= self.range))
        return hit

    def _cast_rect(self, ox, oy, rx, ry, a, b) -> np.ndarray:
        """Slab test of rays (origins ``ox, oy``, directions ``rx, ry``) against boxes of half-sides ``a, b``,
        all in the boxes' frames."""
        with np.errstate(divide="ignore", invalid="ignore"):  # a ray parallel to a side: +-inf, handled below
            tx1, tx2 = (-a - ox) / rx, (a - ox) / rx
            ty1, ty2 = (-b - oy) / ry, (b - oy) / ry
            t_near = np.maximum(np.minimum(tx1, tx2), np.minimum(ty1, ty2))
            t_far = np.minimum(np.maximum(tx1, tx2), np.maximum(ty1, ty2))
        return (t_far >= np.maximum(t_near, 0.0)) & (t_near <= self.range)
