"""Interoception: the four essential variables in raw units (satiation, hydration, temperature, damage)."""

from __future__ import annotations

import numpy as np

from .base import Sensor


class Interoception(Sensor):
    key = "interoception"
    order = 1

    @property
    def shape(self) -> tuple[int, ...]:
        return (4,)

    def read(self, worlds: np.ndarray) -> np.ndarray:
        return self.sim.ev[worlds].astype(np.float32)
