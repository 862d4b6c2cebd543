"""A level's event triggers: boxes on the floor that set EVs when the body walks in.

:class:`Triggers` holds the boxes and what each sets; per world, how often each fired, whether the body stands in
it and whether any fired this episode are the ``trigger_*`` and ``triggered`` fields of
:class:`~evaaa.state.WorldState`.
"""

from __future__ import annotations

import numpy as np

from .level import Level
from .physiology import EV_NAMES, PhysiologyParams
from .state import WorldState
from .worldgen import AGENT_HALF


class Triggers:
    """The event triggers of one level (E of them, perhaps none)."""

    def __init__(self, level: Level, params: PhysiologyParams):
        events = list(level.events.values())
        self.params = params
        self.xy = np.array([(e.x, e.y) for e in events], dtype=np.float64).reshape(-1, 2)
        self.cos = np.cos(np.radians([e.heading for e in events]))
        self.sin = np.sin(np.radians([e.heading for e in events]))
        # the body enters a trigger when any part of it does: grow the box by the body's half-width
        self.half = np.array([e.size for e in events], dtype=np.float64).reshape(-1, 2) / 2 + AGENT_HALF
        self.max_count = np.array([e.max_count for e in events], dtype=np.int64)
        #: (E, 4) the EV each trigger sets, NaN where it leaves one alone
        self.sets = np.array(
            [[np.nan if getattr(e.set, ev) is None else getattr(e.set, ev) for ev in EV_NAMES] for e in events],
            dtype=np.float64,
        ).reshape(-1, 4)

    def __len__(self) -> int:
        return len(self.max_count)

    def inside(self, xy: np.ndarray) -> np.ndarray:
        """(M, E) whether points ``xy`` (M, 2) lie in each trigger box (grown by the body's half-width)."""
        rel = xy[:, None, :] - self.xy
        local_x = rel[..., 0] * self.cos - rel[..., 1] * self.sin
        local_y = rel[..., 0] * self.sin + rel[..., 1] * self.cos
        return (np.abs(local_x) <= self.half[:, 0]) & (np.abs(local_y) <= self.half[:, 1])

    def reset_world(self, state: WorldState, w: int) -> None:
        """A new episode in world ``w``, whose body already stands at its start."""
        state.trigger_count[w] = 0
        state.triggered[w] = False
        state.trigger_inside[w] = self.inside(state.pos[w : w + 1])[0]

    def cross(self, state: WorldState, previous: np.ndarray) -> np.ndarray:
        """Fire the triggers the bodies entered on their way from ``previous`` (N, 2) to where they stand, setting
        the EVs they set; (N,) whether one fired."""
        n = len(previous)
        # a decision covers up to 2 m: test points along the way so that a thin trigger is not stepped over
        along = np.linspace(0.2, 1.0, 5)[:, None, None]
        path = previous[None] + (state.pos - previous)[None] * along  # (5, N, 2)
        inside = self.inside(path.reshape(-1, 2)).reshape(5, n, -1)
        entered = inside.any(axis=0) & ~state.trigger_inside
        state.trigger_inside = inside[-1]
        fire = entered & (state.trigger_count < self.max_count)
        fired = fire.any(axis=1)
        low, high = self.params.low, self.params.high
        for e in np.flatnonzero(fire.any(axis=0)):  # in trigger order: a later one sets an EV over an earlier one
            chosen = ~np.isnan(self.sets[e])
            state.ev[np.ix_(fire[:, e], chosen)] = np.clip(self.sets[e, chosen], low[chosen], high[chosen])
        state.trigger_count += fire
        state.triggered |= fired
        return fired
