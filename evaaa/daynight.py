"""The day/night cycle: the sun's angle, the hour, the five phases, and what they change.

The functions are pure numpy over worlds; :class:`DayNight` applies a level's cycle to a simulator's worlds (their
``sun_angle`` and ``field_offset``) and lights each world's frame.  The sun's angle a (degrees) advances every
decision; a = 0 is sunrise (06:00), 90 noon, 180 sunset (18:00), 270 midnight.  Predators only know day
(a <= 170 or a >= 350) and night.  The hour sets the temperature offset added to the whole floor (day offset at
noon, night offset at 04:00, linear between) and the visibility (fog and far plane); the sun's height sets the
light.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import mujoco
import numpy as np

if TYPE_CHECKING:
    from .level import DayNight as DayNightSpec
    from .state import WorldState

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


_NIGHT_FOG = (0.02, 0.02, 0.05, 1.0)


class DayNight:
    """A level's cycle over a batch of worlds: the sun's start and course, the floor's offset, and the light.

    With the cycle off the sun stands still and the floor keeps the day's offset.
    """

    def __init__(self, spec: DayNightSpec, n: int):
        self.spec = spec
        self.enabled = spec.enabled
        self._day = np.zeros(n, dtype=bool)
        #: per world being drawn: darkness, sun direction, sun strength, fog end and far plane (see :meth:`plan`)
        self.light_plan: list[tuple] = []

    def reset_world(self, state: WorldState, w: int, rng: np.random.Generator) -> None:
        """The sun and the floor's offset at the start of an episode in world ``w``."""
        dn = self.spec
        if dn.enabled:
            state.sun_angle[w] = rng.uniform(0.0, 360.0) if dn.random_start else dn.start_angle % 360.0
        state.field_offset[w] = self.temperature_offset(state.sun_angle[w : w + 1])[0]

    def advance(self, state: WorldState) -> None:
        """The sun moves on by one decision and the floor's offset follows it."""
        if self.enabled:
            state.sun_angle = advance(state.sun_angle, self.spec.degrees_per_step)
            state.field_offset = self.temperature_offset(state.sun_angle)

    def temperature_offset(self, angle: np.ndarray) -> np.ndarray:
        """The offset over the whole floor with the sun at ``angle`` (the day's offset when the cycle is off)."""
        dn = self.spec
        if not dn.enabled:
            return np.full(len(angle), dn.day_temperature)
        return temperature_offset(hour(angle), dn.day_temperature, dn.night_temperature)

    def night(self, angle: np.ndarray) -> np.ndarray:
        """(N,) night as predators see it (never, when the cycle is off)."""
        return is_night(angle) if self.enabled else self._day

    # ------------------------------------------------------------------------------------------------ light
    def plan(self, angle: np.ndarray) -> None:
        """Plan the light of the worlds about to be drawn, whose suns stand at ``angle``: sun direction and
        strength, darkness, fog and far plane (read back by :meth:`light_world`)."""
        dn = self.spec
        dark = darkness(hour(angle))
        direction, strength = sun(angle)
        # the light follows evaaa's darkness; fog and far plane follow it too unless the level asks for the
        # original's schedule
        haze = original_darkness(hour(angle)) if dn.fog_schedule == "original" else dark
        density = dn.night_fog_density * haze
        # exponential-squared fog of this density hides ~95% at sqrt(3)/density; MuJoCo's fog is linear
        fog_end = np.where(density > 0, np.sqrt(3.0) / np.maximum(density, 1e-9), 0.0)
        far = dn.day_far + (dn.night_far - dn.day_far) * haze
        self.light_plan = list(
            zip(dark.tolist(), direction.tolist(), (0.6 * strength).tolist(), fog_end.tolist(), far.tolist())
        )

    def light_world(self, row: int, scene: mujoco.MjvScene, context: mujoco.MjrContext) -> None:
        """Set the sun, the sky and the fog of the ``row``-th world being drawn (worlds share one model)."""
        dark, direction, diffuse, fog_end, far = self.light_plan[row]
        head = 1.0 - 0.8 * dark
        for i in range(scene.nlight):
            light = scene.lights[i]
            if light.headlight:
                light.ambient[:] = 0.35 * head
                light.diffuse[:] = 0.3 * head
            else:
                light.dir[:] = direction
                light.diffuse[:] = diffuse
        scene.flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = dark < 0.5
        scene.flags[mujoco.mjtRndFlag.mjRND_FOG] = fog_end > 0
        if fog_end > 0:
            context.fogStart = 0.0
            context.fogEnd = fog_end
            context.fogRGBA[:] = _NIGHT_FOG
        scene.camera[0].frustum_far = far
        scene.camera[1].frustum_far = far
