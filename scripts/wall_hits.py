"""Measure what running into a wall costs: the damage of each decision in which the body hits the wall.

    python scripts/wall_hits.py

The agent starts at rest 4 to 6 m from the north wall of an empty 1-1 arena (41 distances, so the impact falls at
every point of a decision's five substeps), turned 0, 10, 20 or 30 degrees off the wall's normal, and takes four
Forward decisions; the first two are in the open, the impact comes in the third or fourth (a Forward at the wall
drives the body into it again).  Prints, per angle, the range of the damage of the decisions that hit (damage
over 0.01) and of the four decisions' total.  The wall-hit figures of docs/faithfulness.md come from this command.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np

import evaaa
from evaaa.sim import FORWARD, Simulator
from evaaa_baselines import cli
from evaaa_baselines.cli import option


@dataclass
class WallHitsConfig:
    angles: list[float] = option(
        [0.0, 10.0, 20.0, 30.0],
        "headings off the wall's normal, in degrees",
        check=(lambda v: 0.0 <= v < 90.0, "angles in [0, 90)"),
    )


def main(argv: list[str] | None = None) -> int:
    cfg = cli.parse(
        WallHitsConfig, argv, prog="wall_hits.py", description=__doc__.split("\n\n")[0], examples=["angles=[0,45]"]
    )
    level = evaaa.load_level("1-1", {"resources.food.count": 0, "resources.water.count": 0, "agent.start": "fixed"})
    sim = Simulator(level, 1, ["collision"], seed=0, threads=1)
    sim.reset()
    print("angle  damage per decision that hits  total of the four decisions")
    for angle in cfg.angles:
        hits, totals = [], []
        for start in np.linspace(44.0, 46.0, 41):
            sim.reset()
            sim.set_agent_pose(0, (0.0, float(start)), angle)
            damage = [float(sim.step(np.array([FORWARD]))[4]["damage_taken"][0, 0]) for _ in range(4)]
            hits += [d for d in damage if d > 0.01]
            totals.append(sum(damage))
        print(f"{angle:4.0f}°  {min(hits):6.2f} - {max(hits):5.2f}{'':20}{min(totals):6.2f} - {max(totals):5.2f}")
    sim.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
