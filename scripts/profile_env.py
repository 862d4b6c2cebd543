"""Where an env step's time goes: cProfile over TorchRL steps (random actions), the costliest functions first.

    python scripts/profile_env.py                        # level 1-1, 1 world, 2000 steps
    python scripts/profile_env.py level=4-2 num_envs=8 steps=500 top=30

The profiler adds its own cost per Python call; compare the shares, and take speeds from scripts/bench_env.py.
The env steps and draws every world in the calling thread here (``threads=1``), so that the profile shows it all:
cProfile sees one thread only.  Arguments are ``key=value``, the keys of :class:`ProfileConfig` (``--help``).
"""

from __future__ import annotations

import cProfile
import os
import pstats
from dataclasses import dataclass

import evaaa
from evaaa_baselines import cli
from evaaa_baselines.cli import option


@dataclass
class ProfileConfig:
    level: str = option("1-1", "level or testbed to step", choices=lambda: [*evaaa.LEVELS, *evaaa.TESTBEDS])
    num_envs: int = option(1, "worlds stepped together", check=(lambda v: v >= 1, "a positive integer"))
    steps: int = option(
        2000, "decisions profiled (after 100 of warm-up)", check=(lambda v: v >= 1, "a positive integer")
    )
    top: int = option(
        20,
        "functions listed, costliest first (by own time; PROFILE_SORT=cumulative sorts by cumulative time)",
        check=(lambda v: v >= 1, "a positive integer"),
    )


def main(argv: list[str] | None = None) -> int:
    args = cli.parse(
        ProfileConfig,
        argv,
        prog="profile_env.py",
        description=__doc__.split("\n\n")[0],
        examples=["level=4-2 num_envs=8 steps=500 top=30"],
    )
    import torch  # once --help and the command line have passed

    torch.set_num_threads(1)
    env = evaaa.EvaaaEnv(args.level, num_envs=args.num_envs, seed=0, threads=1)
    generator = torch.Generator().manual_seed(0)
    td = env.reset()

    def run(steps: int) -> None:
        nonlocal td
        for _ in range(steps):
            td["action"] = torch.randint(0, len(evaaa.ACTION_NAMES), env.action_spec.shape, generator=generator)
            _, td = env.step_and_maybe_reset(td)

    run(100)  # warm-up: first renders, lazy allocations
    profiler = cProfile.Profile()
    profiler.runcall(run, args.steps)
    env.close()
    print(f"evaaa profile_env: level {args.level}, num_envs={args.num_envs}, {args.steps} steps")
    pstats.Stats(profiler).sort_stats(os.environ.get("PROFILE_SORT", "tottime")).print_stats(args.top)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
