"""Thermoception: the temperature under eight sensors around the body, in the order F, B, L, R, FL, FR, BL, BR.

The sensors sit one metre from the centre (the diagonals at one metre along both axes) and turn with the agent.
Levels choose absolute temperatures (training levels) or temperatures relative to the body's (testbeds).
"""

from __future__ import annotations

import numpy as np

from .base import Sensor


class Thermoception(Sensor):
    key = "thermoception"
    order = 3

    @property
    def shape(self) -> tuple[int, ...]:
        return (8,)

    def read(self, worlds: np.ndarray) -> np.ndarray:
        sim = self.sim
        temps = sim.thermal_readings[worlds]
        if sim.level.thermal.relative:
            temps = temps - sim.ev[worlds, 2:3]
        return temps.astype(np.float32)
