"""The interface every sensor implements."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..sim import Simulator


class Sensor:
    """A modality: an observation key, its per-world shape and dtype, and how to read it.

    ``read`` returns a fresh array of shape ``(len(worlds), *shape)`` for the given world indices, from the
    simulator's state after the physics of the current decision.
    """

    key: str = ""
    dtype = np.float32
    #: (low, high) every reading lies in, declared in the observation specs; None: unbounded
    bounds: tuple[float, float] | None = None

    def __init__(self, sim: "Simulator"):
        self.sim = sim

    @property
    def shape(self) -> tuple[int, ...]:
        raise NotImplementedError

    def read(self, worlds: np.ndarray) -> np.ndarray:
        raise NotImplementedError
