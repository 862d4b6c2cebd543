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

Arguments are ``key=value``, the keys of :class:`DemoConfig`; ``--help`` lists them.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

import evaaa  # noqa: F401  (sets MUJOCO_GL before mujoco loads)
import cv2
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from tqdm import tqdm  # noqa: E402

from evaaa import END_TYPES, EV_NAMES, make_env  # noqa: E402
from evaaa.physiology import PhysiologyParams  # noqa: E402
from evaaa_baselines import cli  # noqa: E402
from evaaa_baselines.cli import option  # noqa: E402

FPS = 10
EYE_SCALE = 4
PANEL_WIDTH = 320
#: BGR colours of the frame's panel
BG = (38, 34, 30)
TEXT = (235, 235, 235)
DIM = (150, 150, 150)
OK = (90, 200, 90)
BAD = (60, 60, 230)
RANGE_FILL = (70, 66, 60)
BOUND = (0, 190, 255)


# ------------------------------------------------------------------------------------------------- one frame
class FrameDrawer:
    """Composes a video frame (BGR uint8): the upscaled eye on the left, the EV bars on the right."""

    def __init__(self, params: PhysiologyParams, level: str, eye_hw: tuple[int, int]):
        self.low, self.high, self.setpoint = params.low, params.high, params.setpoint
        self.level = level
        self.height = eye_hw[0] * EYE_SCALE
        self.eye_width = eye_hw[1] * EYE_SCALE

    def draw(self, pixels: np.ndarray, ev: np.ndarray, step: int, episode: int, end: str | None) -> np.ndarray:
        eye = cv2.resize(pixels, None, fx=EYE_SCALE, fy=EYE_SCALE, interpolation=cv2.INTER_NEAREST)
        frame = np.empty((self.height, self.eye_width + PANEL_WIDTH, 3), dtype=np.uint8)
        frame[:, : self.eye_width] = cv2.cvtColor(eye, cv2.COLOR_RGB2BGR)
        panel = frame[:, self.eye_width:]
        panel[:] = BG
        font = cv2.FONT_HERSHEY_SIMPLEX
        cv2.putText(panel, f"level {self.level}  step {step}  ep {episode}", (10, 20), font, 0.45, TEXT, 1,
                    cv2.LINE_AA)
        if end is not None:
            cv2.putText(panel, f"episode end: {end}", (10, 38), font, 0.42, BAD, 1, cv2.LINE_AA)
        top, row_h = 52, (self.height - 52) // 4
        for i, name in enumerate(EV_NAMES):
            self._bar(panel, top + i * row_h, name, float(ev[i]), float(self.low[i]), float(self.high[i]),
                      float(self.setpoint[i]))
        return frame

    def _bar(self, panel, y, name, value, lo, hi, setpoint):
        font = cv2.FONT_HERSHEY_SIMPLEX
        inside = lo <= value <= hi
        cv2.putText(panel, f"{name}", (10, y + 12), font, 0.45, TEXT, 1, cv2.LINE_AA)
        cv2.putText(panel, f"{value:+.2f}", (120, y + 12), font, 0.45, OK if inside else BAD, 1, cv2.LINE_AA)
        cv2.putText(panel, f"[{lo:g}, {hi:g}]", (200, y + 12), font, 0.38, DIM, 1, cv2.LINE_AA)
        # the bar shows the viable range plus a 10 % margin on each side for values outside it
        x0, x1, by0, by1 = 14, PANEL_WIDTH - 14, y + 20, y + 38
        span = hi - lo if hi > lo else 1.0
        vlo, vhi = lo - 0.1 * span, hi + 0.1 * span

        def px(v: float) -> int:
            return int(round(x0 + (np.clip(v, vlo, vhi) - vlo) / (vhi - vlo) * (x1 - x0)))

        cv2.rectangle(panel, (x0, by0), (x1, by1), (55, 50, 45), -1)
        cv2.rectangle(panel, (px(lo), by0), (px(hi), by1), RANGE_FILL, -1)
        base = min(max(setpoint, lo), hi)
        a, b = sorted((px(base), px(value)))
        cv2.rectangle(panel, (a, by0 + 3), (max(b, a + 1), by1 - 3), OK if inside else BAD, -1)
        for bound in (lo, hi):  # the viable range's ends
            cv2.line(panel, (px(bound), by0 - 4), (px(bound), by1 + 4), BOUND, 2)
        cv2.line(panel, (px(setpoint), by0), (px(setpoint), by1), TEXT, 1)


# ------------------------------------------------------------------------------------------------- video sink
class VideoSink:
    """Writes frames to ``rollout.mp4`` (mp4v); falls back to an animated GIF (imageio) or, last, PNG frames."""

    def __init__(self, out: Path, size_wh: tuple[int, int]):
        self.out = out
        self.kind = "mp4"
        self.path = out / "rollout.mp4"
        self._writer = cv2.VideoWriter(str(self.path), cv2.VideoWriter_fourcc(*"mp4v"), FPS, size_wh)
        self._gif = None
        self.note = ""
        self.frames = 0
        if not self._writer.isOpened():
            self._writer.release()
            self.path.unlink(missing_ok=True)
            try:
                import imageio.v2 as imageio

                self.path = out / "rollout.gif"
                self._gif = imageio.get_writer(self.path, mode="I", duration=1 / FPS, loop=0)
                self.kind = "gif"
                self.note = "OpenCV could not open an mp4v writer; wrote an animated GIF instead"
            except Exception as exc:  # noqa: BLE001 - any failure means: fall back to PNG frames
                self.path = out / "rollout_frames"
                self.path.mkdir(parents=True, exist_ok=True)
                self.kind = "png"
                self.note = f"neither mp4 (OpenCV) nor GIF (imageio: {exc}) could be written; wrote PNG frames"

    def write(self, frame_bgr: np.ndarray) -> None:
        if self.kind == "mp4":
            self._writer.write(frame_bgr)
        elif self.kind == "gif":
            self._gif.append_data(cv2.cvtColor(frame_bgr, cv2.COLOR_BGR2RGB))
        else:
            cv2.imwrite(str(self.path / f"frame_{self.frames:05d}.png"), frame_bgr)
        self.frames += 1

    def close(self) -> None:
        if self.kind == "mp4":
            self._writer.release()
        elif self.kind == "gif":
            self._gif.close()


# ------------------------------------------------------------------------------------------------- traces
def plot_traces(path: Path, evs: np.ndarray, ends: list[tuple[int, str]], params: PhysiologyParams, level: str):
    """The EVs of world 0 (T, 4) against the decision, bounds dashed, episode ends as vertical lines."""
    steps = np.arange(1, len(evs) + 1)
    fig, axes = plt.subplots(4, 1, figsize=(9, 8.5), sharex=True, dpi=110)
    colours = ("tab:red", "tab:blue", "tab:orange", "tab:purple")
    for i, (ax, name) in enumerate(zip(axes, EV_NAMES)):
        # one line per episode, so a reset does not draw a jump
        cuts = [0] + [t for t, _ in ends if t < len(evs)] + [len(evs)]
        for a, b in zip(cuts[:-1], cuts[1:]):
            ax.plot(steps[a:b], evs[a:b, i], color=colours[i], lw=1.4)
        for bound in (params.low[i], params.high[i]):
            ax.axhline(bound, color="k", ls="--", lw=1, alpha=0.7)
        ax.axhline(params.setpoint[i], color="gray", ls=":", lw=0.8)
        for k, (t, why) in enumerate(ends):
            ax.axvline(t, color="crimson", lw=1.2, alpha=0.8, label="episode end" if k == 0 and i == 0 else None)
            if i == 0:
                ax.annotate(why, (t, 1.0), xycoords=("data", "axes fraction"), xytext=(2, -10),
                            textcoords="offset points", fontsize=7, color="crimson", rotation=90, va="top")
        ax.set_ylabel(name)
        ax.grid(alpha=0.25)
    axes[-1].set_xlabel("decision")
    axes[-1].set_xlim(0, max(len(evs), 1))
    title = f"Random policy on level {level}, world 0: essential variables (dashed: viable range)"
    if not ends:
        title += "; no episode ended"
    else:
        axes[0].legend(loc="lower left", fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


# ------------------------------------------------------------------------------------------------- main
@dataclass
class DemoConfig:
    level: str = option("1-1", "level or testbed to play", choices=lambda: [*evaaa.LEVELS, *evaaa.TESTBEDS])
    steps: int = option(500, "decisions to take", check=(lambda v: v >= 1, "a positive integer"))
    num_envs: int = option(1, "worlds stepped together; the video shows world 0",
                           check=(lambda v: v >= 1, "a positive integer"))
    seed: int = option(0, "seed of the env and of the random actions")
    out: Path = option(Path("outputs/demo"), "output directory, created if missing")


def main(argv=None) -> int:
    args = cli.parse(DemoConfig, argv, prog="demo.py",
                     description="Roll out a random policy through the evaaa TorchRL env and write, for world 0, a "
                                 "video of the egocentric view beside the four essential-variable bars "
                                 "(rollout.mp4), its last frame (final_frame.png) and a plot of the EVs over time "
                                 "(ev_traces.png). Prints the env's steps/s (video drawing and encoding excluded).",
                     examples=["level=1-2 steps=1000 num_envs=2 seed=3"])
    level = evaaa.load_level(args.level)
    args.out.mkdir(parents=True, exist_ok=True)

    env = make_env(args.level, num_envs=args.num_envs, seed=args.seed)
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
    print(f"env steps/s: {rate:.1f} ({n} world(s) x {args.steps} decisions in {env_time:.2f} s of env time, "
          f"video drawing and encoding excluded; {episodes_done} episode(s) ended)")
    if sink.note:
        print(f"note: {sink.note}")
    for p in (sink.path, final, traces):
        print(p)
    return 0


if __name__ == "__main__":
    sys.exit(main())
