"""Where an env step's time goes: cProfile over TorchRL steps (random actions), the costliest functions first.

    python scripts/profile_env.py                        # level 1-1, 1 world, 2000 steps
    python scripts/profile_env.py --level 4-2 --num-envs 8 --steps 500 --top 30

The profiler adds its own cost per Python call; compare the shares, and take speeds from scripts/bench_env.py.
The env steps and draws every world in the calling thread here (``threads=1``), so that the profile shows it all:
cProfile sees one thread only.
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats

import torch

import evaaa


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--level", default="1-1", choices=[*evaaa.LEVELS, *evaaa.TESTBEDS])
    parser.add_argument("--num-envs", type=int, default=1)
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--top", type=int, default=20, help="functions listed, by own time")
    args = parser.parse_args(argv)
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
