"""Vision: the egocentric RGB image (height x width x 3, uint8) from the eye at the front of the body.

One renderer is shared by all worlds of a simulator (creating one costs ~150 ms; rendering a world is a scene
update plus a draw).  The agent's own body is hidden from its eye.
"""

from __future__ import annotations

import numpy as np

from .base import Sensor


class Vision(Sensor):
    key = "pixels"
    order = 0
    dtype = np.uint8

    @property
    def shape(self) -> tuple[int, ...]:
        v = self.sim.level.sensors.vision
        return (v.height, v.width, 3)

    def read(self, worlds: np.ndarray) -> np.ndarray:
        return self.sim.render_eye(worlds)
