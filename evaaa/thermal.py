"""The temperature field over the floor: base temperature, warm patches, smoothing, and sampling it.

The field is a grid of cells covering the floor (``thermal.grid``; 100 x 100 by default).  Each episode it is
rebuilt: every cell at ``base_temperature``, ``hotspots.count`` squares of ``hotspots.size`` cells set to
``hotspots.temperature`` at random, then a Gaussian blur of ``sigma`` cells renormalised by the weight that
falls inside the grid (so the border is not pulled toward 0).  Pure numpy/scipy; no MuJoCo.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from scipy.ndimage import gaussian_filter

from .level import Level

#: Thermal sensor offsets in the agent's frame (right, forward), in the order F, B, L, R, FL, FR, BL, BR.
SENSOR_NAMES: tuple[str, ...] = ("F", "B", "L", "R", "FL", "FR", "BL", "BR")
SENSOR_OFFSETS = np.array([(0, 1), (0, -1), (-1, 0), (1, 0), (-1, 1), (1, 1), (-1, -1), (1, -1)], dtype=np.float64)


def _blur(field: np.ndarray, sigma: float) -> np.ndarray:
    # a window of 2*ceil(3 sigma)+1 cells, zero outside the grid; the caller divides by the blurred ones
    return gaussian_filter(field, sigma, mode="constant", cval=0.0, radius=math.ceil(3 * sigma))


@lru_cache(maxsize=16)
def _in_grid_weight(shape: tuple[int, int], sigma: float) -> np.ndarray:
    return _blur(np.ones(shape), sigma)


def smooth(field: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian smoothing that averages only over cells inside the grid."""
    if sigma <= 0:
        return field.astype(np.float64, copy=True)
    return _blur(field.astype(np.float64), sigma) / _in_grid_weight(field.shape, float(sigma))


def hotspot_cells(level: Level, rng: np.random.Generator) -> np.ndarray:
    """Centres (ix, iy) of this episode's random warm patches, (count, 2) integers."""
    gx, gy = level.thermal.grid
    n = level.thermal.hotspots.count
    return np.stack([rng.integers(0, gx, n), rng.integers(0, gy, n)], axis=1)


def build_field(level: Level, hotspots: np.ndarray, heat: np.ndarray | None = None) -> np.ndarray:
    """The smoothed temperature field (grid x, grid y) for one episode.

    ``hotspots`` are the random warm patches' centre cells; ``heat`` rows (xmin, xmax, ymin, ymax, T) are hot
    objects' footprints in metres: every cell they touch is set to T before smoothing.
    """
    t = level.thermal
    field = np.full(t.grid, t.base_temperature, dtype=np.float64)
    half = t.hotspots.size // 2  # an even size grows to the next odd square, as in the original
    for ix, iy in hotspots:
        field[max(ix - half, 0) : ix + half + 1, max(iy - half, 0) : iy + half + 1] = t.hotspots.temperature
    if heat is not None and len(heat):
        sampler = FieldSampler(level)
        lo_x, lo_y = sampler.cells(heat[:, [0, 2]])
        hi_x, hi_y = sampler.cells(heat[:, [1, 3]])
        for x0, x1, y0, y1, temperature in zip(lo_x, hi_x, lo_y, hi_y, heat[:, 4]):
            field[x0 : x1 + 1, y0 : y1 + 1] = temperature
    return smooth(field, t.sigma)


class FieldSampler:
    """Maps world (x, y) positions to grid cells of a level's floor."""

    def __init__(self, level: Level):
        self.grid = np.array(level.thermal.grid)
        size = np.array(level.arena.size, dtype=np.float64)
        self.origin = -size / 2
        self.cell = size / self.grid
        self._inv_cell = 1.0 / self.cell
        self._last = self.grid - 1

    def cells(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cell indices of points ``xy`` (..., 2); points off the floor read the nearest edge cell."""
        idx = np.floor((xy - self.origin) * self._inv_cell).astype(np.int64)
        np.minimum(np.maximum(idx, 0, out=idx), self._last, out=idx)
        return idx[..., 0], idx[..., 1]

    def sensor_points(self, pos: np.ndarray, heading_rad: np.ndarray) -> np.ndarray:
        """World positions (N, 8, 2) of the 8 thermal sensors of agents at ``pos`` (N, 2) facing ``heading``."""
        s, c = np.sin(heading_rad)[:, None], np.cos(heading_rad)[:, None]
        right, fwd = SENSOR_OFFSETS[:, 0], SENSOR_OFFSETS[:, 1]
        # heading is a compass angle: forward = (sin h, cos h), right = (cos h, -sin h)
        x = pos[:, :1] + right * c + fwd * s
        y = pos[:, 1:2] - right * s + fwd * c
        return np.stack([x, y], axis=-1)

    def sample(
        self, fields: np.ndarray, pos: np.ndarray, heading_rad: np.ndarray, worlds: np.ndarray | None = None
    ) -> np.ndarray:
        """Temperatures (W, 8) under the thermal sensors of agents at ``pos`` (W, 2), read from ``fields``
        (N, gx, gy) at rows ``worlds`` (default: row i for agent i)."""
        ix, iy = self.cells(self.sensor_points(pos, heading_rad))
        rows = np.arange(len(pos)) if worlds is None else np.asarray(worlds)
        return fields[rows[:, None], ix, iy]
