"""A short rollout of a policy through the TorchRL env, as a video and plots.

Plays ``policy`` (random by default; oracle, still, a checkpoint file, or ``zoo:<name>``, a trained network shipped
with the baselines: ``scripts/zoo.py`` lists them) on the test worlds of ``level`` (``num_envs`` worlds of
``seed``, built as ``scripts/evaluate.py`` builds them: a checkpoint with its own observation keys and transforms),
through ``env.step_and_maybe_reset`` (so worlds whose episode ended start a new one), and writes, for world 0, to
``out``:

* ``rollout.mp4``     each decision: the egocentric view (upscaled x4) beside bars of the four essential variables
                      with their viable ranges (10 fps, H.264 that browsers play; PNG frames if no mp4 can be
                      written);
* ``final_frame.png`` the last video frame;
* ``ev_traces.png``   the four EVs over the rollout with their bounds (dashed) and episode ends marked;
* ``gif=<path>``      optionally an animated GIF too, small enough for a README (every ``gif_every``-th frame,
                      scaled by ``gif_scale``).

At the end it prints the env's steps per second over the rollout (worlds x decisions per second of env time;
choosing actions, drawing and encoding the video are not counted) and the paths written.

    python scripts/demo.py                                   # random actions on 1-1, 500 steps -> outputs/demo/
    python scripts/demo.py level=1-2 steps=2000 num_envs=4 seed=1 out=/tmp/demo
    python scripts/demo.py policy=zoo:ppo-1-1 level=1-1 steps=600 out=outputs/demo-ppo   # the trained agent
    python scripts/demo.py policy=zoo:ppo-1-1 level=1-1 steps=600 gif=docs/media/ppo-1-1.gif   # the README's GIF

Arguments are ``key=value``, the keys of :class:`DemoConfig`; ``--help`` lists them.  The frames and the traces are
drawn by :mod:`evaaa.pictures`, the video written by :class:`evaaa.video.VideoSink`.  A policy that does not see
pixels (the reference agents, a checkpoint of a pixel-free ablation) is shown the eye view rendered after each step
(on a step that ends an episode, that is the next episode's first view).
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
from evaaa import END_TYPES, EV_NAMES
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
    policy: str = option(
        "random",
        "oracle, random, still (stands still), a checkpoint file of a baseline, or zoo:NAME (a shipped network: "
        "scripts/zoo.py lists them)",
        check=(cli.policy_ok, "oracle, random, still, zoo:NAME or an existing checkpoint file"),
    )
    sample: bool = option(
        False, "for checkpoints: sample actions from the policy's distribution instead of taking the most likely one"
    )
    gif: Path | None = option(None, "also write an animated GIF of the rollout here (e.g. docs/media/ppo-1-1.gif)")
    gif_every: int = option(2, "the GIF keeps every n-th frame", check=(lambda v: v >= 1, "a positive integer"))
    gif_scale: float = option(0.5, "the GIF's size relative to the video's", check=(lambda v: 0 < v <= 1, "in (0, 1]"))


def main(argv=None) -> int:
    args = cli.parse(
        DemoConfig,
        argv,
        prog="demo.py",
        description="Roll out a policy (random by default, or oracle, still, a checkpoint, zoo:NAME) through the "
        "evaaa TorchRL env on test worlds and write, for world 0, an H.264 video of the egocentric view beside the "
        "four essential-variable bars (rollout.mp4), its last frame (final_frame.png), a plot of the EVs over "
        "time (ev_traces.png) and, with gif=, an animated GIF. Prints the env's steps/s (acting, video drawing "
        "and encoding excluded).",
        examples=["level=1-2 steps=1000 num_envs=2 seed=3", "policy=zoo:ppo-1-1 level=1-1 steps=600"],
    )
    # the env, torch and the video writer load once --help and the command line have passed
    import torch

    from evaaa.pictures import PANEL_WIDTH, FrameDrawer, plot_traces
    from evaaa.video import VideoSink
    from evaaa_baselines.evaluation import EvaluatedPolicy, EvaluationError

    level = evaaa.load_level(args.level)
    try:
        policy = EvaluatedPolicy(args.policy, args.seed, sample=args.sample)
        env = policy.make_env(args.level, args.num_envs, args.seed, worlds="test")
    except EvaluationError as err:  # a checkpoint that does not load, or one made for other observations
        cli.fail("demo.py", str(err))
    args.out.mkdir(parents=True, exist_ok=True)
    sim = env.sim if hasattr(env, "sim") else env.base_env.sim
    try:
        params = sim.params
        n = args.num_envs
        eye_hw = (level.sensors.vision.height, level.sensors.vision.width)
        drawer = FrameDrawer(params, args.level, eye_hw, policy=policy.name)
        size = (drawer.eye_width + PANEL_WIDTH, drawer.height)
        sink = VideoSink(args.out, size, gif=args.gif, gif_every=args.gif_every, gif_scale=args.gif_scale)
        torch.manual_seed(args.seed)  # sampled actions (sample=true) repeat from run to run

        env_time = 0.0
        start = time.perf_counter()
        td = env.reset()
        env_time += time.perf_counter() - start

        evs = np.empty((args.steps, 4))
        ends: list[tuple[int, str]] = []
        episodes_done = 0
        episode = 1
        frame = None
        for t in tqdm(range(args.steps), desc=f"demo {policy.name} on {args.level}", unit="step", dynamic_ncols=True):
            td["action"] = policy.act(env, td).reshape(env.action_spec.shape)
            start = time.perf_counter()
            stepped, td = env.step_and_maybe_reset(td)
            env_time += time.perf_counter() - start

            nxt = stepped["next"]
            ev = np.array([float(nxt["info", name][0]) for name in EV_NAMES])
            evs[t] = ev
            done = nxt["done"].reshape(n)
            episodes_done += int(done.sum())
            end = None
            if bool(done[0]):
                end = END_TYPES[int(nxt["info", "end_type"][0])]
                ends.append((t + 1, end))
            eye = nxt["pixels"][0].numpy() if "pixels" in nxt.keys() else sim.render_eye(np.arange(1))[0]
            frame = drawer.draw(np.asarray(eye), ev, t + 1, episode, end)
            sink.write(frame)
            if end is not None:
                episode += 1
        sink.close()
    finally:
        env.close()

    final = args.out / "final_frame.png"
    cv2.imwrite(str(final), frame)
    traces = args.out / "ev_traces.png"
    plot_traces(traces, evs, ends, params, args.level, policy=policy.name)

    rate = args.steps * n / env_time
    print(
        f"env steps/s: {rate:.1f} ({n} world(s) x {args.steps} decisions in {env_time:.2f} s of env time, "
        f"acting, video drawing and encoding excluded; {episodes_done} episode(s) ended)"
    )
    if sink.note:
        print(f"note: {sink.note}")
    for p in (sink.path, final, traces, *([args.gif] if args.gif is not None else [])):
        print(p)
    return 0


if __name__ == "__main__":
    sys.exit(main())
