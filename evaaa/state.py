"""What a simulator's worlds are in, and what one decision did to them.

:class:`WorldState` holds every per-world array that changes while the worlds run; its fields are exactly the
arrays a snapshot saves.  :class:`StepEvents` is the frozen record of one decision's events (eating, contact,
triggers, what the action cost) that the EV update, the reward and the info read.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np


@dataclass(eq=False)
class WorldState:
    """Per-world state, world on the first axis.  Which code writes each field is noted beside it."""

    # the body (the step: physics moves it, the action turns it, the physiology advances its EVs)
    pos: np.ndarray  # (N, 2) floor position of the body's centre
    heading_rad: np.ndarray  # (N,) compass heading
    ev: np.ndarray  # (N, 4) essential variables, ordered as physiology.EV_NAMES
    steps: np.ndarray  # (N,) decisions taken this episode
    # items (evaaa.resources.Resources): positions and presence per slot of the pool
    res_xy: np.ndarray  # (N, P, 2)
    res_present: np.ndarray  # (N, P)
    # the floor's temperature: the field drawn at reset, the day/night offset over all of it, and the readings of
    # the body's eight thermal sensors
    fields: np.ndarray  # (N, *grid)
    field_offset: np.ndarray  # (N,)
    thermal_readings: np.ndarray  # (N, 8)
    active_group: np.ndarray  # (N,) the grouped resource group holding items (Resources), -1: none
    # obstacles (evaaa.obstacles.Obstacles): positions and presence per slot of the obstacle pool
    obs_xy: np.ndarray  # (N, O, 2)
    obs_present: np.ndarray  # (N, O)
    sun_angle: np.ndarray  # (N,) degrees (evaaa.daynight.DayNight)
    attacked: np.ndarray  # (N,) a predator attacked in the last decision
    # event triggers (evaaa.triggers.Triggers)
    trigger_count: np.ndarray  # (N, E) times each trigger fired this episode
    trigger_inside: np.ndarray  # (N, E) whether the body stands in each trigger
    triggered: np.ndarray  # (N,) a trigger fired this episode

    @classmethod
    def empty(
        cls,
        n: int,
        items: int,
        obstacles: int,
        triggers: int,
        grid: tuple[int, int],
        ev_start: np.ndarray,
        sun_start: float,
    ) -> WorldState:
        """The state of ``n`` worlds before their first reset."""
        return cls(
            pos=np.zeros((n, 2)),
            heading_rad=np.zeros(n),
            ev=np.tile(ev_start, (n, 1)),
            steps=np.zeros(n, dtype=np.int64),
            res_xy=np.zeros((n, items, 2)),
            res_present=np.zeros((n, items), dtype=bool),
            fields=np.zeros((n, *grid)),
            field_offset=np.zeros(n),
            thermal_readings=np.zeros((n, 8)),
            active_group=np.full(n, -1, dtype=np.int64),
            obs_xy=np.zeros((n, obstacles, 2)),
            obs_present=np.zeros((n, obstacles), dtype=bool),
            sun_angle=np.full(n, sun_start),
            attacked=np.zeros(n, dtype=bool),
            trigger_count=np.zeros((n, triggers), dtype=np.int64),
            trigger_inside=np.zeros((n, triggers), dtype=bool),
            triggered=np.zeros(n, dtype=bool),
        )

    def arrays(self) -> dict[str, np.ndarray]:
        """A copy of every field, by name (a snapshot's ``arrays``)."""
        return {f.name: getattr(self, f.name).copy() for f in fields(self)}

    def load(self, arrays: dict[str, np.ndarray]) -> None:
        """Take the fields ``arrays`` holds (copies of them); fields it lacks, saved before they existed, are kept."""
        known = {f.name for f in fields(self)}
        unknown = sorted(set(arrays) - known)
        if unknown:
            raise ValueError(f"snapshot arrays {unknown} are not part of a world's state; known: {sorted(known)}")
        for name, value in arrays.items():
            setattr(self, name, np.array(value, copy=True))


@dataclass(frozen=True, slots=True)
class StepEvents:
    """What happened in every world during one decision, (N,) arrays."""

    food_count: np.ndarray  # items of food eaten
    water_count: np.ndarray  # items of water eaten
    food_eaten: np.ndarray  # some food was eaten
    water_eaten: np.ndarray  # some water was eaten
    damage: np.ndarray  # damage taken from contacts and attacks
    collided: np.ndarray  # a contact was hard enough to count as a collision
    crossed: np.ndarray  # the body entered an event trigger that fired
    costly: np.ndarray  # the action was one the reward charges for (Forward, Eat)

    @classmethod
    def none(cls, n: int) -> StepEvents:
        """Nothing happened (the record an episode starts with)."""
        return cls(
            food_count=np.zeros(n, dtype=np.int64),
            water_count=np.zeros(n, dtype=np.int64),
            food_eaten=np.zeros(n, dtype=bool),
            water_eaten=np.zeros(n, dtype=bool),
            damage=np.zeros(n, dtype=np.float64),
            collided=np.zeros(n, dtype=bool),
            crossed=np.zeros(n, dtype=bool),
            costly=np.zeros(n, dtype=bool),
        )
