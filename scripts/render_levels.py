"""Pictures of each level right after a reset: what the agent sees, the world from above, and the thermal field.

For every chosen level, after ``reset()`` with ``seed``, four PNGs are written to ``out``:

* ``<level>_eye.png``      the 64x64 egocentric frame, upscaled x4 (nearest neighbour, pixels stay crisp);
* ``<level>_top.png``      the top-down render (512x512) with the agent's position and heading marked;
* ``<level>_thermal.png``  the temperature field in deg C, food (red) and water (blue) items and the agent;
* ``<level>_overview.png`` the three side by side, for the README.

    python scripts/render_levels.py                          # every level in evaaa.LEVELS -> docs/images/
    python scripts/render_levels.py levels=[1-2] seed=3 out=/tmp/pics

Arguments are ``key=value`` (lists as ``[a,b]``), the keys of :class:`RenderConfig`; ``--help`` lists them.  The
pictures are drawn by :mod:`evaaa.pictures`.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import evaaa
from evaaa.pictures import render_level
from evaaa_baselines import cli
from evaaa_baselines.cli import option


# ------------------------------------------------------------------------------------------------- main
@dataclass
class RenderConfig:
    levels: list[str] = option(
        list(evaaa.LEVELS), "levels and testbeds to render", choices=lambda: [*evaaa.LEVELS, *evaaa.TESTBEDS]
    )
    out: Path = option(Path("docs/images"), "output directory, created if missing")
    seed: int = option(0, "seed of the reset that lays out each world", check=cli.SEED)


def main(argv=None) -> int:
    args = cli.parse(
        RenderConfig,
        argv,
        prog="render_levels.py",
        description="Render pictures of evaaa levels after a reset: the agent's 64x64 eye (upscaled "
        "x4), a 512x512 top-down view with the agent marked, the thermal field with "
        "food/water/agent, and an overview combining the three. Writes "
        "<level>_{eye,top,thermal,overview}.png.",
        examples=["levels=[1-1,1-2] out=docs/images seed=0", "levels=[two-resource-food,y-maze]"],
    )
    levels = [evaaa.load_level(name) for name in args.levels]
    args.out.mkdir(parents=True, exist_ok=True)
    for level in levels:
        for path in render_level(level, args.out, args.seed):
            print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
