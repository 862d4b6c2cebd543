"""The limits a level is held to: how large its numbers, arena and body counts may be, and how much route
planning and field smoothing it may ask of the machine.

:mod:`evaaa.level` checks every level against them; the limits on reading a level file (its bytes, nesting and
values) are :mod:`evaaa.level_files`'s.
"""

from __future__ import annotations

from typing import Any

#: Largest magnitude of any number in a level.  Lengths, temperatures, rates and weights all stay far below it, and
#: so do their squares and products in float32 observations and rewards (float32 overflows near 3.4e38).
MAX_MAGNITUDE = 1e6
#: Largest integer in a level (counts, step limits): beyond it a loop or an array would outgrow the machine.
MAX_INTEGER = 10**9
#: Longest side of an arena (m): predators plan on a grid of 1 m cells over the floor.
MAX_ARENA_SIDE = 1000.0
#: Smallest side of an arena (m): the agent's body is 1 m wide.
MIN_ARENA_SIDE = 2.0
#: Bodies the agent collides with (obstacles and ponds), in all: MuJoCo's collision detection ran out of its
#: default memory at 2,000 of them (1,500 worked); this keeps a margin.
MAX_SOLID_BODIES = 1200
#: Resource items in all (measured: 2,000 items step in ~3 ms a decision on one core).
MAX_ITEMS = 2000
#: Landmark points of a patrol pattern (each predator plans routes between them).
MAX_LANDMARKS = 10_000
#: A chasing predator whose straight line to the agent is blocked plans a new route at most this often (decisions).
REPLAN_EVERY = 5
#: Route planning allowed per decision, in grid cells visited: a plan can be a shortest-path search over the whole
#: grid of 1 m cells (scipy's Dijkstra, 400-600 ns a cell on the 2-core box), made by each searching predator every
#: search_interval decisions and by each chasing one every REPLAN_EVERY.  1e6 is about 0.5 s a decision at the worst;
#: 4-1 needs 6.4e3; the audit's 1,000 m arena with 50 predators searching every decision needed 6e7 (20-38 s a step).
MAX_PLANNING_WORK = 1e6
#: Work of one smoothing of the thermal field (cells times kernel width, both passes) allowed at every episode
#: reset: the default 100 x 100 grid at sigma 10 costs 6.1e5; 1000 x 1000 cells at sigma 3 (3.8e7) took 15 ms of
#: CPU on the 2-core box.  Painting the hotspots is held to the same number of cells.
MAX_SMOOTHING_WORK = 5e7


def check_bounded(value: Any) -> None:
    """Raise if a number in ``value`` (a number, or a tuple or list of them) lies beyond the allowed magnitude."""
    if isinstance(value, bool):
        return
    if isinstance(value, float) and abs(value) > MAX_MAGNITUDE:
        raise ValueError(f"must lie within [-{MAX_MAGNITUDE:g}, {MAX_MAGNITUDE:g}]")
    if isinstance(value, int) and abs(value) > MAX_INTEGER:
        raise ValueError(f"must lie within [-{MAX_INTEGER:.0e}, {MAX_INTEGER:.0e}]")
    if isinstance(value, (tuple, list)):
        for item in value:
            check_bounded(item)
