"""Pictures of a world for people: the agent's eye enlarged, the world from above with the agent marked, and the
floor's temperature field with the food, water and agent on it (``scripts/render_levels.py`` writes them for every
level; the play server shows the top-down view as its map); a video frame of the eye beside the four essential
variables' bars, and their traces over a rollout (``scripts/demo.py``).

Figures are drawn on ``matplotlib.figure.Figure`` objects, not through pyplot, so that drawing them leaves the
caller's matplotlib backend and open figures alone.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
from matplotlib.figure import Figure

from .level import LEVEL_NAME_RULE, Level, LevelError, excerpt
from .physiology import EV_NAMES, PhysiologyParams
from .sim import Simulator
from .worldgen import AGENT_HALF, FOOD, WATER

EYE_SCALE = 4
TOP_SIZE = 512
#: marker colours (RGB, 0..1) shared by the pictures
AGENT_COLOUR = (0.1, 0.95, 0.2)


# ------------------------------------------------------------------------------------------------- pieces
def eye_image(sim: Simulator, world: int = 0, scale: int = EYE_SCALE) -> np.ndarray:
    """The egocentric frame of ``world`` upscaled ``scale`` times with nearest neighbour, RGB uint8."""
    frame = sim.render_eye(np.array([world]))[0]
    return cv2.resize(frame, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)


def top_projection(sim: Simulator, size: int, z: float = 2 * AGENT_HALF):
    """A function mapping world (x, y) at height ``z`` to pixel (u, v) of the top camera's ``size``-pixel picture.

    The top camera looks straight down from (0, 0, h) with image right = +x and image up = +y (fovy from the model).
    """
    cam = sim.index.top_camera
    height = float(sim.model.cam_pos[cam][2])
    half = (height - z) * math.tan(math.radians(float(sim.model.cam_fovy[cam])) / 2)

    def project(x: float, y: float) -> tuple[float, float]:
        return (x / half + 1) / 2 * size, (1 - y / half) / 2 * size

    return project


def top_image(sim: Simulator, world: int = 0, size: int = TOP_SIZE) -> np.ndarray:
    """The top-down render of ``world`` with the agent circled and an arrow along its heading, RGB uint8."""
    img = np.ascontiguousarray(sim.render_top(world, size))
    project = top_projection(sim, size)
    x, y = sim.pos[world]
    h = float(sim.heading_rad[world])
    arrow_m = 0.07 * sim.level.arena.size[0]  # arrow length in metres, relative to the arena
    u0, v0 = project(x, y)
    u1, v1 = project(x + arrow_m * math.sin(h), y + arrow_m * math.cos(h))
    colour = tuple(int(255 * c) for c in AGENT_COLOUR)
    r = max(4, size // 64)
    cv2.circle(img, (round(u0), round(v0)), r + 2, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.circle(img, (round(u0), round(v0)), r, colour, 2, cv2.LINE_AA)
    cv2.arrowedLine(img, (round(u0), round(v0)), (round(u1), round(v1)), (0, 0, 0), 4, cv2.LINE_AA, tipLength=0.3)
    cv2.arrowedLine(img, (round(u0), round(v0)), (round(u1), round(v1)), colour, 2, cv2.LINE_AA, tipLength=0.3)
    return img


def plot_thermal(ax, sim: Simulator, world: int = 0, *, colorbar: bool = True, fig=None):
    """Draw ``world``'s temperature field with items and the agent into ``ax`` (axes in metres)."""
    level = sim.level
    sx, sy = level.arena.size
    extent = (-sx / 2, sx / 2, -sy / 2, sy / 2)
    field = sim.fields[world]  # indexed [ix, iy]
    im = ax.imshow(field.T, origin="lower", extent=extent, cmap="inferno", interpolation="nearest")
    if colorbar:
        cb = (fig or ax.figure).colorbar(im, ax=ax, fraction=0.046, pad=0.04)
        cb.set_label("floor temperature (°C)")
    present = sim.res_present[world]
    for kind, colour, marker, name in ((FOOD, "red", "s", "food"), (WATER, "dodgerblue", "s", "water")):
        sel = present & (sim.pool.feeds == kind)  # apples count as food, the pond as water
        if sel.any():
            xy = sim.res_xy[world, sel]
            ax.scatter(
                xy[:, 0],
                xy[:, 1],
                s=18,
                c=colour,
                marker=marker,
                edgecolors="white",
                linewidths=0.6,
                label=f"{name} ({int(sel.sum())})",
                zorder=3,
            )
    x, y = sim.pos[world]
    h = float(sim.heading_rad[world])
    arrow = 0.08 * sx
    ax.annotate(
        "",
        xy=(x + arrow * math.sin(h), y + arrow * math.cos(h)),
        xytext=(x, y),
        zorder=5,
        annotation_clip=False,  # an agent facing a wall points off the floor
        arrowprops=dict(arrowstyle="-|>", color=AGENT_COLOUR, lw=2.0, mutation_scale=14),
    )
    ax.scatter(
        [x],
        [y],
        s=90,
        c=[AGENT_COLOUR],
        marker="o",
        edgecolors="black",
        linewidths=1.2,
        label=f"agent (heading {math.degrees(h):.0f}°)",
        zorder=6,
    )
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    ax.set_xlabel("x (m, east)")
    ax.set_ylabel("y (m, north)")
    ax.set_aspect("equal")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.11), ncol=3, fontsize=8, frameon=False)
    return im


def title_of(level: Level) -> str:
    return f"Level {level.name}: {level.description}" if level.description else f"Level {level.name}"


# ------------------------------------------------------------------------------------------------- one level
def _picture_path(out: Path, level: Level, what: str) -> Path:
    """``out/<name>_<what>.png``, refused unless it lies in ``out`` itself: a loaded level's name cannot leave it
    (level.LEVEL_NAME), but a Level built without validation (``model_construct``) could say ``../../x``."""
    path = out / f"{level.name}_{what}.png"
    if path.resolve().parent != out.resolve():
        raise LevelError(f"level name {excerpt(level.name)} would write its picture outside {out}; {LEVEL_NAME_RULE}")
    return path


def render_level(level: Level, out: Path, seed: int) -> list[Path]:
    """Reset one world of ``level`` with ``seed`` and write its four pictures; returns the paths."""
    where = {what: _picture_path(out, level, what) for what in ("eye", "top", "thermal", "overview")}
    sim = Simulator(level, 1, modalities=["interoception"], seed=seed)
    try:
        sim.reset()
        eye = eye_image(sim)
        top = top_image(sim)
        paths = []

        p = where["eye"]
        cv2.imwrite(str(p), cv2.cvtColor(eye, cv2.COLOR_RGB2BGR))
        paths.append(p)

        p = where["top"]
        cv2.imwrite(str(p), cv2.cvtColor(top, cv2.COLOR_RGB2BGR))
        paths.append(p)

        fig = Figure(figsize=(7.2, 6.6), dpi=110)
        ax = fig.subplots()
        plot_thermal(ax, sim)
        ax.set_title(title_of(level), fontsize=10, wrap=True)
        fig.tight_layout()
        p = where["thermal"]
        fig.savefig(p)
        paths.append(p)

        fig = Figure(figsize=(17, 6.2), dpi=100)
        axes = fig.subplots(1, 3, gridspec_kw={"width_ratios": [1, 1, 1.2]})
        axes[0].imshow(eye, interpolation="nearest")
        axes[0].set_title(f"agent's eye ({sim.level.sensors.vision.width}×{sim.level.sensors.vision.height})")
        axes[1].imshow(top)
        axes[1].set_title("top-down view (agent circled, arrow = heading)")
        for a in axes[:2]:
            a.set_xticks([])
            a.set_yticks([])
        plot_thermal(axes[2], sim, fig=fig)
        axes[2].set_title("floor temperature, food, water, agent")
        fig.suptitle(title_of(level), fontsize=13)
        fig.tight_layout()
        p = where["overview"]
        fig.savefig(p)
        paths.append(p)
        return paths
    finally:
        sim.close()


# ------------------------------------------------------------------------------------------------- rollouts
PANEL_WIDTH = 320
#: BGR colours of the frame's panel
BG = (38, 34, 30)
TEXT = (235, 235, 235)
DIM = (150, 150, 150)
OK = (90, 200, 90)
BAD = (60, 60, 230)
RANGE_FILL = (70, 66, 60)
BOUND = (0, 190, 255)


class FrameDrawer:
    """Composes a video frame (BGR uint8): the upscaled eye on the left, the EV bars on the right (under the level,
    step, episode and, when given, the ``policy`` acting)."""

    def __init__(self, params: PhysiologyParams, level: str, eye_hw: tuple[int, int], policy: str = ""):
        self.low, self.high, self.setpoint = params.low, params.high, params.setpoint
        self.level = level
        self.policy = policy
        self.height = eye_hw[0] * EYE_SCALE
        self.eye_width = eye_hw[1] * EYE_SCALE

    def draw(self, pixels: np.ndarray, ev: np.ndarray, step: int, episode: int, end: str | None) -> np.ndarray:
        eye = cv2.resize(pixels, None, fx=EYE_SCALE, fy=EYE_SCALE, interpolation=cv2.INTER_NEAREST)
        frame = np.empty((self.height, self.eye_width + PANEL_WIDTH, 3), dtype=np.uint8)
        frame[:, : self.eye_width] = cv2.cvtColor(eye, cv2.COLOR_RGB2BGR)
        panel = frame[:, self.eye_width :]
        panel[:] = BG
        font = cv2.FONT_HERSHEY_SIMPLEX
        cv2.putText(panel, f"level {self.level}  step {step}  ep {episode}", (10, 20), font, 0.45, TEXT, 1, cv2.LINE_AA)
        if end is not None:
            cv2.putText(panel, f"episode end: {end}", (10, 38), font, 0.42, BAD, 1, cv2.LINE_AA)
        elif self.policy:
            cv2.putText(panel, f"policy {self.policy}", (10, 38), font, 0.42, DIM, 1, cv2.LINE_AA)
        top, row_h = 52, (self.height - 52) // 4
        for i, name in enumerate(EV_NAMES):
            self._bar(
                panel,
                top + i * row_h,
                name,
                float(ev[i]),
                float(self.low[i]),
                float(self.high[i]),
                float(self.setpoint[i]),
            )
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


def plot_traces(
    path: Path,
    evs: np.ndarray,
    ends: list[tuple[int, str]],
    params: PhysiologyParams,
    level: str,
    policy: str = "Random policy",
) -> Path:
    """The EVs of world 0 (T, 4) against the decision, bounds dashed, episode ends (decision, end type) as vertical
    lines; ``policy`` names what acted, in the title."""
    steps = np.arange(1, len(evs) + 1)
    fig = Figure(figsize=(9, 8.5), dpi=110)
    axes = fig.subplots(4, 1, sharex=True)
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
                ax.annotate(
                    why,
                    (t, 1.0),
                    xycoords=("data", "axes fraction"),
                    xytext=(2, -10),
                    textcoords="offset points",
                    fontsize=7,
                    color="crimson",
                    rotation=90,
                    va="top",
                )
        ax.set_ylabel(name)
        ax.grid(alpha=0.25)
    axes[-1].set_xlabel("decision")
    axes[-1].set_xlim(0, max(len(evs), 1))
    title = f"{policy} on level {level}, world 0: essential variables (dashed: viable range)"
    if not ends:
        title += "; no episode ended"
    else:
        axes[0].legend(loc="lower left", fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path)
    return Path(path)
