"""A stage's clock from plain numbers: where its time goes (the time split), how fast it goes (:class:`Progress`),
and the words the bar and the logs say about it (durations, rates).

The time split — wall-clock and CPU seconds per phase of the loop.  Every algorithm times the same named phases
through :meth:`Run.timed <evaaa_baselines.run.Run.timed>`:

* ``env``: the worlds' step and reset (physics, camera, senses, the env's transforms such as frame stacking);
* ``act``: the policy's forward pass while collecting (and exploration);
* ``replay``: storing transitions and drawing batches (DQN's and DreamerV3's replay; PPO's minibatch split);
* ``advantage``: PPO's GAE and return scaling (the critic over the whole batch, no gradient);
* ``forward``: the loss's forward pass in a gradient step (DreamerV3: world model, imagination, actor and critic);
* ``backward``: the backward pass;
* ``optimizer``: gradient clipping, the optimiser's step, target or slow-critic updates;
* ``eval``: the periodic evaluations on validation worlds; ``checkpoint``: checkpoints and models written.

CPU seconds are the process's (``time.process_time``: every thread, the env's threads included), so a phase that
runs on two threads counts twice its wall time; what no phase covers (logging, the progress bar, the loop's own
Python) is the rest of the session's total.  On a CUDA device the gradient step's phases measure the host's side
(kernel launches); the split is made for the CPU, where every operation finishes before the next starts.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager

#: the phases in the order a loop passes through them (the logs and bench_train.py's table use it)
PHASES = ("env", "act", "replay", "advantage", "forward", "backward", "optimizer", "eval", "checkpoint")


class TimeSplit:
    """Wall-clock and CPU seconds spent in each phase since it was made (one session of a stage)."""

    def __init__(self) -> None:
        self.wall: dict[str, float] = dict.fromkeys(PHASES, 0.0)
        self.cpu: dict[str, float] = dict.fromkeys(PHASES, 0.0)
        self._start = (time.perf_counter(), time.process_time())

    @contextmanager
    def __call__(self, phase: str) -> Iterator[None]:
        if phase not in self.wall:
            raise ValueError(f"no phase {phase!r} in the time split: its phases are {', '.join(PHASES)}")
        wall, cpu = time.perf_counter(), time.process_time()
        try:
            yield
        finally:
            self.wall[phase] += time.perf_counter() - wall
            self.cpu[phase] += time.process_time() - cpu

    def totals(self) -> tuple[float, float]:
        """Wall-clock and CPU seconds since the split began."""
        return time.perf_counter() - self._start[0], time.process_time() - self._start[1]

    def scalars(self) -> dict[str, float]:
        """Cumulative seconds per phase as log scalars (``time/cpu/<phase>``, ``time/wall/<phase>``), with the
        session's totals (``time/cpu/total``, ``time/wall/total``)."""
        wall, cpu = self.totals()
        out = {f"time/cpu/{p}": s for p, s in self.cpu.items()} | {f"time/wall/{p}": s for p, s in self.wall.items()}
        return out | {"time/cpu/total": cpu, "time/wall/total": wall}


def shares(seconds: Mapping[str, float], total: float) -> dict[str, float]:
    """Each phase's share of ``total``, and ``other``: what no phase covers."""
    out = {p: s / total for p, s in seconds.items()} if total > 0 else dict.fromkeys(seconds, 0.0)
    out["other"] = max(0.0, 1.0 - sum(out.values()))
    return out


# ------------------------------------------------------------------------------------------------ progress
def duration(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "?"
    seconds = max(0.0, seconds)
    if seconds >= 2 * 86400:
        return f"{seconds / 86400:.1f} d"
    if seconds >= 3600:
        return f"{int(seconds // 3600)}:{int(seconds % 3600 // 60):02d} h"
    return f"{int(seconds // 60)}:{int(seconds % 60):02d}"


def about(seconds: float) -> str:
    """A duration in words for a log line: "about 14 minutes", "about 2.3 hours", "about 3.1 days"."""
    if not math.isfinite(seconds):
        return "an unknown time"
    if seconds < 90:
        return f"about {seconds:.0f} seconds"
    if seconds < 5400:
        return f"about {seconds / 60:.0f} minutes"
    if seconds < 2 * 86400:
        return f"about {seconds / 3600:.1f} hours"
    return f"about {seconds / 86400:.1f} days"


def rate_text(x: float) -> str:
    return f"{x:.3g}" if x < 100 else f"{x:.0f}"


class Progress:
    """What the progress bar says about speed, from the times the loop reports.

    Every report adds the env steps, gradient steps and seconds since the previous one to sums that decay with a
    time constant of ``window`` seconds: the rates are over roughly the last ``window`` seconds of the whole loop, so
    PPO's alternation of fast collection and slow updates, or DreamerV3's few long gradient steps, do not make the
    rate swing.  The session's average (env steps / seconds since :meth:`__init__`) is given beside it.

    The ETA adds the two costs of what is left: env steps still to take times the time one takes outside gradient
    steps (acting, logging, evaluation), and gradient steps still owed times the time one takes.
    """

    def __init__(self, window: float, steps: int, now: float | None = None):
        self.window = float(window)
        now = time.perf_counter() if now is None else now
        self.start, self.start_steps, self.last, self.steps = now, steps, now, steps
        self.sums = {"seconds": 0.0, "steps": 0.0, "update_seconds": 0.0, "updates": 0.0}

    def add(self, steps: int, updates: int = 0, update_seconds: float = 0.0, now: float | None = None) -> None:
        """The loop is at ``steps`` env steps and made ``updates`` gradient steps, taking ``update_seconds``, since
        the last report."""
        now = time.perf_counter() if now is None else now
        elapsed = max(now - self.last, 0.0)
        decay = math.exp(-elapsed / self.window)
        increments = {
            "seconds": elapsed,
            "steps": steps - self.steps,
            "update_seconds": min(update_seconds, elapsed),
            "updates": updates,
        }
        for key, value in increments.items():
            self.sums[key] = self.sums[key] * decay + value
        self.last, self.steps = now, steps

    @property
    def env_rate(self) -> float:
        """Env steps per second of the whole loop over the window."""
        return self.sums["steps"] / self.sums["seconds"] if self.sums["seconds"] > 0 else math.nan

    @property
    def session_rate(self) -> float:
        """Env steps per second of the whole loop since the session began."""
        seconds = self.last - self.start
        return (self.steps - self.start_steps) / seconds if seconds > 0 else math.nan

    @property
    def update_rate(self) -> float:
        return self.sums["updates"] / self.sums["seconds"] if self.sums["seconds"] > 0 else math.nan

    @property
    def seconds_per_update(self) -> float:
        return self.sums["update_seconds"] / self.sums["updates"] if self.sums["updates"] > 0 else math.nan

    @property
    def seconds_per_step(self) -> float:
        """Seconds of one env step outside gradient steps (acting, logging, evaluation)."""
        acting = self.sums["seconds"] - self.sums["update_seconds"]
        return acting / self.sums["steps"] if self.sums["steps"] > 0 else math.nan

    def eta(self, steps_left: int, updates_left: int | None) -> float:
        """Seconds until the stage ends: the steps left at the acting cost, plus the gradient steps still owed at
        their cost (``updates_left=None``: an algorithm without gradient steps to count, only the whole-loop rate)."""
        if steps_left <= 0:
            return 0.0
        if updates_left is None:
            return steps_left / self.env_rate if self.env_rate > 0 else math.nan
        cost = steps_left * self.seconds_per_step
        if updates_left > 0:
            cost += updates_left * self.seconds_per_update
        return cost
