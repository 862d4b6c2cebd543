"""Olfaction: a 10-D smell, five food channels then five water channels.

Every item within ``radius`` of the agent's centre adds its odour vector times 1/distance (distances clamped
below at ``min_distance``).  One array operation over all worlds and items.
"""

from __future__ import annotations

import numpy as np

from ..worldgen import AGENT_HALF
from .base import Sensor, World


class Olfaction(Sensor):
    key = "olfaction"
    order = 2

    def __init__(self, sim: World):
        super().__init__(sim)
        spec = sim.level.sensors.olfaction
        self.radius2 = spec.radius**2
        self.min_distance2 = spec.min_distance**2
        self.odour = sim.pool.odour.astype(np.float64)  # (P, 10)
        self.dz2 = (sim.pool.centre_z() - AGENT_HALF) ** 2  # (P,) items rest on the floor, the nose is at 0.5 m

    @property
    def shape(self) -> tuple[int, ...]:
        return (10,)

    def read(self, worlds: np.ndarray) -> np.ndarray:
        sim = self.sim
        d2 = sim.item_distances2()[worlds] + self.dz2
        smelled = sim.res_present[worlds] & (d2 <= self.radius2)
        weight = np.where(smelled, 1.0 / np.sqrt(np.maximum(d2, self.min_distance2)), 0.0)
        return (weight @ self.odour).astype(np.float32)
