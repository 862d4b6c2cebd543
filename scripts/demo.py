"""A short rollout of a random policy through the TorchRL env, as a video and plots.

Steps ``make_env(level, num_envs=N, seed=S)`` with uniformly random actions through ``env.step_and_maybe_reset``
(so worlds whose episode ended start a new one) and writes, for world 0, to ``out``:

* ``rollout.mp4``     each decision: the egocentric view (upscaled x4) beside bars of the four essential variables
                      with their viable ranges (10 fps, mp4v; an animated GIF or PNG frames if mp4 is unavailable);
* ``final_frame.png`` the last video frame;
* ``ev_traces.png``   the four EVs over the rollout with their bounds (dashed) and episode ends marked.

At the end it prints the env's steps per second over the rollout (worlds x decisions per second of env time;
drawing and encoding the video are not counted) and the paths written.

    python scripts/demo.py                                   # level 1-1, 1 env, 500 steps -> outputs/demo/
    python scripts/demo.py level=1-2 steps=2000 num_envs=4 seed=1 out=/tmp/demo

Arguments are ``key=value``, the keys of :class:`DemoConfig`; ``--help`` lists them.  The frames and the traces are
drawn by :mod:`evaaa.pictures`, the video written by :class:`evaaa.video.VideoSink`.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

import evaaa  # noqa: F401  (sets MUJOCO_GL before mujoco loads)
from evaaa import END_TYPES
from evaaa.pictures import PANEL_WIDTH, FrameDrawer, plot_traces
from evaaa_baselines import cli
from evaaa_baselines.cli import option


# ------------------------------------------------------------------------------------------------- main
@dataclass
class DemoConfig:
    level: str = option("1-1", "level or testbed to play", choices=lambda: [*evaaa.LEVELS, *evaaa.TESTBEDS])
    steps: int = option(500, "decisions to take", check=(lambda v: v >= 1, "a positive integer"))
    num_envs: int = option(
        1, "worlds stepped together; the video shows world 0", check=(lambda v: v >= 1, "a positive integer")
    )
    seed: int = option(0, "seed of the env and of the random actions", check=cli.SEED)
    out: Path = option(Path("outputs/demo"), "output directory, created if missing")


def main(argv=None) -> int:
    args = cli.parse(
        DemoConfig,
        argv,
        prog="demo.py",
        description="Roll out a random policy through the evaaa TorchRL env and write, for world 0, a "
        "video of the egocentric view beside the four essential-variable bars "
        "(rollout.mp4), its last frame (final_frame.png) and a plot of the EVs over time "
        "(ev_traces.png). Prints the env's steps/s (video drawing and encoding excluded).",
        examples=["level=1-2 steps=1000 num_envs=2 seed=3"],
    )
    # the env, torch and the video writer load once --help and the command line have passed
    import torch

    from evaaa import make_env
    from evaaa.video import VideoSink

    level = evaaa.load_level(args.level)
    args.out.mkdir(parents=True, exist_ok=True)

    env = make_env(args.level, num_envs=args.num_envs, seed=args.seed, info=["end_type"])
    try:
        params = env.sim.params
        n = args.num_envs
        eye_hw = (level.sensors.vision.height, level.sensors.vision.width)
        drawer = FrameDrawer(params, args.level, eye_hw)
        sink = VideoSink(args.out, (drawer.eye_width + PANEL_WIDTH, drawer.height))
        rng = np.random.default_rng(args.seed)
        actions = torch.from_numpy(rng.integers(0, env.action_spec.space.n, size=(args.steps, n)))

        env_time = 0.0
        start = time.perf_counter()
        td = env.reset()
        env_time += time.perf_counter() - start

        evs = np.empty((args.steps, 4))
        ends: list[tuple[int, str]] = []
        episodes_done = 0
        episode = 1
        frame = None
        for t in tqdm(range(args.steps), desc=f"demo {args.level}", unit="step", dynamic_ncols=True):
            start = time.perf_counter()
            td["action"] = actions[t]
            stepped, td = env.step_and_maybe_reset(td)
            env_time += time.perf_counter() - start

            nxt = stepped["next"]
            ev = nxt["interoception"][0].numpy()
            evs[t] = ev
            done = nxt["done"].reshape(n)
            episodes_done += int(done.sum())
            end = None
            if bool(done[0]):
                end = END_TYPES[int(nxt["info", "end_type"][0])]
                ends.append((t + 1, end))
            frame = drawer.draw(nxt["pixels"][0].numpy(), ev, t + 1, episode, end)
            sink.write(frame)
            if end is not None:
                episode += 1
        sink.close()
    finally:
        env.close()

    final = args.out / "final_frame.png"
    cv2.imwrite(str(final), frame)
    traces = args.out / "ev_traces.png"
    plot_traces(traces, evs, ends, params, args.level)

    rate = args.steps * n / env_time
    print(
        f"env steps/s: {rate:.1f} ({n} world(s) x {args.steps} decisions in {env_time:.2f} s of env time, "
        f"video drawing and encoding excluded; {episodes_done} episode(s) ended)"
    )
    if sink.note:
        print(f"note: {sink.note}")
    for p in (sink.path, final, traces):
        print(p)
    return 0


if __name__ == "__main__":
    sys.exit(main())
