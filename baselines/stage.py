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
from collections.abc import Callable, Iterator, Mapping
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


# ------------------------------------------------------------------------------------------------ the stage's clock
def trained_steps(budget: int, iteration: int) -> int:
    """The env steps a stage of ``budget`` takes when it ends with the iteration (of ``iteration`` env steps) that
    reaches its budget: the budget rounded up to whole iterations."""
    return -(-budget // iteration) * iteration


def budget_text(budget: int, iteration: int, how: str, max_cpu_minutes: float | None, compute_bound: int) -> str:
    """The stage's budget as asked and, where whole iterations overshoot it, as trained and why; a compute-bound
    stage (``max_cpu_minutes`` with a step budget of ``compute_bound`` or more, never reached) by its CPU minutes."""
    if max_cpu_minutes is not None and budget >= compute_bound:
        return f"{max_cpu_minutes:g} CPU-minutes (max_cpu_minutes; the budget of {budget:,} env steps is out of reach)"
    text = f"{budget:,} env steps"
    trained = trained_steps(budget, iteration)
    if trained != budget:
        text += (
            f" asked: {trained:,} trained, as the stage ends with the iteration that reaches "
            f"its budget and one iteration is {iteration:,} env steps ({how})"
        )
    return text


def stop_wait(between_updates: bool, meter: Progress | None, iteration: int) -> str:
    """What a first Ctrl-C waits for, in words: the gradient step under way (``between_updates``: the loop stops
    between them) or the iteration under way, with how long one takes at ``meter``'s speed when that is known."""
    if between_updates:
        seconds = meter.seconds_per_update if meter is not None else math.nan
        known = f" ({about(seconds)} each here)" if math.isfinite(seconds) else ""
        return f"the gradient step under way{known}"
    rate = meter.session_rate if meter is not None else math.nan
    known = f" (one takes {about(iteration / rate)} here)" if math.isfinite(rate) and rate > 0 else ""
    return f"the iteration under way{known}"


class StageClock:
    """One session of a stage against its budgets, from plain numbers: the env-step budget (in whole iterations of
    ``iteration`` env steps), the time budgets (``max_minutes`` of wall-clock time, ``max_cpu_minutes`` of this
    process's CPU time, each summed over the stage's sessions: ``spent_before`` holds the earlier ones'), and the
    speed so far (:attr:`meter`, smoothed over ``window`` seconds).  ``planned_updates`` gives the gradient steps
    owed by a number of env steps (None: an algorithm without gradient steps to count).  ``wall`` and ``cpu`` are the
    clocks read (``time.perf_counter`` and ``time.process_time``; a test passes its own)."""

    def __init__(
        self,
        budget: int,
        iteration: int,
        *,
        steps: int = 0,
        planned_updates: Callable[[int], int] | None = None,
        window: float = 60.0,
        max_minutes: float | None = None,
        max_cpu_minutes: float | None = None,
        spent_before: tuple[float, float] = (0.0, 0.0),
        wall: Callable[[], float] = time.perf_counter,
        cpu: Callable[[], float] = time.process_time,
    ):
        self.budget, self.iteration, self.planned_updates = budget, iteration, planned_updates
        self.max_minutes, self.max_cpu_minutes, self.spent_before = max_minutes, max_cpu_minutes, spent_before
        self.wall, self.cpu = wall, cpu
        #: when the session began: wall-clock and CPU seconds, and the env steps the stage had taken then
        self.began, self.began_cpu, self.start_steps = wall(), cpu(), steps
        self.meter = Progress(window, steps, now=self.began)
        self.estimated = False

    @property
    def trained_steps(self) -> int:
        return trained_steps(self.budget, self.iteration)

    def add(self, steps: int, updates: int = 0, update_seconds: float = 0.0) -> None:
        """The loop is at ``steps`` env steps and made ``updates`` gradient steps in ``update_seconds`` since the
        last report (:meth:`Progress.add`)."""
        self.meter.add(steps, updates, update_seconds, now=self.wall())

    def seconds_spent(self) -> tuple[float, float]:
        """Wall-clock and CPU seconds of this stage so far, earlier sessions included."""
        wall, cpu = self.spent_before
        return wall + self.wall() - self.began, cpu + self.cpu() - self.began_cpu

    def session_seconds(self) -> float:
        """Wall-clock seconds of this session (the stage's earlier sessions not included)."""
        return self.wall() - self.began

    def steps_per_second(self, steps: int) -> float:
        """Env steps per second of this session's whole loop, at ``steps`` env steps."""
        return (steps - self.start_steps) / max(self.session_seconds(), 1e-9)

    def out_of_time(self, steps: int) -> bool:
        """A time budget is spent.  A session ends the stage only after an iteration of its own (its final evaluation
        and model come at an iteration's end): one resumed with its time already spent makes one iteration first."""
        if steps == self.start_steps:
            return False
        limits = (self.max_minutes, self.max_cpu_minutes)
        return any(limit is not None and used >= 60.0 * limit for limit, used in zip(limits, self.seconds_spent()))

    def owed(self, at: int, updates: int) -> int | None:
        """Gradient steps still owed by ``at`` env steps, ``updates`` made (None: the algorithm counts none)."""
        return None if self.planned_updates is None else max(self.planned_updates(at) - updates, 0)

    def status(self, steps: int, updates: int, ratio: float | None) -> str:
        """The bar's speed and ETA: smoothed and session env steps/s, gradient steps (count, rate, seconds each,
        replay ratio kept) and the ETA."""
        m = self.meter
        parts = [f"env {rate_text(m.env_rate)}/s (avg {rate_text(m.session_rate)})"]
        if self.planned_updates is not None or updates:
            grad = f"grad {updates:,}"
            if m.sums["updates"] > 0:
                grad += f" {rate_text(m.update_rate)}/s {m.seconds_per_update:.3g} s/update"
            if ratio is not None:
                grad += f" ratio {ratio:.3g}"
            parts.append(grad)
        parts.append(f"ETA {duration(m.eta(self.budget - steps, self.owed(self.budget, updates)))}")
        return " | ".join(parts)

    def estimate(self, steps: int, updates: int, done: bool) -> str | None:
        """How long the stage will take, from this session's own speed so far, in words — once: after 20 s, and once
        gradient steps (whose cost dominates) have been timed where the algorithm makes any; None until then."""
        elapsed = self.session_seconds()
        timed = self.planned_updates is None or self.meter.sums["updates"] > 0
        if self.estimated or elapsed < 20 or not timed or done:
            return None
        self.estimated = True
        trained = self.trained_steps
        left = self.meter.eta(trained - steps, self.owed(trained, updates))
        limit = self.max_minutes
        capped = f"; max_minutes={limit:g} ends it sooner" if limit is not None and left > 60 * limit - elapsed else ""
        session_cpu = self.cpu() - self.began_cpu
        if self.max_cpu_minutes is not None and session_cpu > 0:
            # at this session's speed per CPU second and its share of a core
            cpu_left = max(60.0 * self.max_cpu_minutes - self.seconds_spent()[1], 0.0)
            wall_left = cpu_left * elapsed / session_cpu
            if wall_left < left:
                # at the estimate's own cost per env step for the rest of the budget (acting and the gradient steps
                # it owes), not this session's env steps per CPU second so far: DreamerV3's first 16 k env steps
                # are a prefill without gradient steps, ten times faster than what follows
                reach = steps + (trained - steps) * wall_left / left
                capped += (
                    f"; max_cpu_minutes={self.max_cpu_minutes:g} ends it sooner: in {about(wall_left)}, near "
                    f"{reach:,.0f} env steps"
                )
        speed = f"{rate_text(self.meter.env_rate)} env steps/s"
        if self.meter.sums["updates"] > 0:
            speed += f", {self.meter.seconds_per_update:.3g} s per gradient step"
        return (
            f"{about(left)} more for the {trained:,} env steps ({steps:,} done), from this run's speed over its "
            f"first {elapsed:.0f} s here ({speed}){capped}"
        )

    def summary(self, steps: int, updates: int) -> str:
        """The session's last line: env steps (and the budget asked, where whole iterations overshot it), env
        steps/s, gradient steps and the session's wall-clock time."""
        asked = (
            f" ({self.budget:,} asked, in whole iterations of {self.iteration:,})"
            if steps != self.budget and steps >= self.budget
            else ""
        )
        return (
            f"{steps:,} env steps{asked}, {self.steps_per_second(steps):.3g} env steps/s this session, "
            f"{updates:,} gradient steps, {duration(self.session_seconds())}"
        )
