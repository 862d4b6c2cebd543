"""The day/night cycle: the sun's angle, the hour, the five phases, and what they change.

Pure numpy over worlds.  The sun's angle a (degrees) advances every decision; a = 0 is sunrise (06:00), 90 noon,
180 sunset (18:00), 270 midnight.  Predators only know day (a <= 170 or a >= 350) and night.  The hour sets the
temperature offset added to the whole floor (day offset at noon, night offset at 04:00, linear between) and the
visibility (fog and far plane); the sun's height sets the light.
"""

from __future__ import annotations

import numpy as np

PHASES: tuple[str, ...] = ("Day", "Sunset", "Night", "DeepNight", "Dawn")
DEGREES_PER_HOUR = 15.0


def advance(angle: np.ndarray, degrees_per_step: float) -> np.ndarray:
    return (angle + degrees_per_step) % 360.0


def hour(angle: np.ndarray) -> np.ndarray:
    """Whole hour of the day, 0..23 (sunrise at 06:00)."""
    return (np.floor(np.asarray(angle) / DEGREES_PER_HOUR).astype(np.int64) + 6) % 24


def is_night(angle: np.ndarray) -> np.ndarray:
    """Night as predators see it: from a little before sunset (170 deg) to a little before sunrise (350 deg)."""
    angle = np.asarray(angle)
    return (angle > 170.0) & (angle < 350.0)


def phase(h: np.ndarray) -> np.ndarray:
    """Index into :data:`PHASES`: Day 07-17, Sunset 18-20, Night 21-23, DeepNight 00-03, Dawn 04-06."""
    h = np.asarray(h)
    out = np.zeros(h.shape, dtype=np.int64)
    out[(h >= 18) & (h <= 20)] = 1
    out[h >= 21] = 2
    out[h <= 3] = 3
    out[(h >= 4) & (h <= 6)] = 4
    return out


def temperature_offset(h: np.ndarray, day: float, night: float) -> np.ndarray:
    """Offset added to the floor's temperature: ``night`` at 04:00 rising to ``day`` at 12:00, then falling
    back over the 16 hours to the next 04:00."""
    h = np.asarray(h, dtype=np.float64)
    rising = night + (day - night) * (h - 4.0) / 8.0
    after_noon = np.where(h < 4, h + 24.0, h)
    falling = day + (night - day) * (after_noon - 12.0) / 16.0
    return np.where((h >= 4) & (h <= 12), rising, falling)


def darkness(h: np.ndarray) -> np.ndarray:
    """0 by day, 1 in the depth of night: fog grows through sunset, holds through the night, lifts at dawn."""
    h = np.asarray(h, dtype=np.float64)
    dusk = np.clip((h - 17.0) / 4.0, 0.0, 1.0) ** 1.5  # 17:00 -> 21:00
    dawn = np.clip((7.0 - h) / 4.0, 0.0, 1.0) ** 2  # 03:00 -> 07:00
    return np.where(h >= 12, dusk, np.where(h < 3, 1.0, dawn))


def original_darkness(h: np.ndarray) -> np.ndarray:
    """The original's fog and far-plane schedule, as a fraction of the night's: 0 by day (07-17); sunset 18-20
    at ((h - 18) / 3)^1.5; night 21-02 from one half at ((h - 21) mod 24 / 6)^2 of the way to full; full at
    03:00; dawn 04-06 lifting as 1 - (1 - (h - 4) / 3)^1.5."""
    h = np.asarray(h, dtype=np.float64)
    sunset = np.clip((h - 18.0) / 3.0, 0.0, 1.0) ** 1.5
    night = 0.5 + 0.5 * (((h - 21.0) % 24.0) / 6.0) ** 2
    dawn = np.clip(1.0 - (h - 4.0) / 3.0, 0.0, 1.0) ** 1.5
    out = np.zeros_like(h)
    out = np.where((h >= 18) & (h <= 20), sunset, out)
    out = np.where((h >= 21) | (h <= 2), night, out)
    out = np.where(h == 3, 1.0, out)
    return np.where((h >= 4) & (h <= 6), dawn, out)


def sun(angle: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Direction the sunlight travels (N, 3) and its strength (N,) in [0, 1] (0 once the sun has set)."""
    a = np.radians(np.asarray(angle, dtype=np.float64))
    # the sun rises in the east (+x), culminates overhead and sets in the west, tilted a little to the south
    towards_sun = np.stack([np.cos(a), -0.3 * np.ones_like(a), np.sin(a)], axis=-1)
    towards_sun /= np.linalg.norm(towards_sun, axis=-1, keepdims=True)
    return -towards_sun, np.clip(np.sin(a) * 1.5, 0.0, 1.0)
