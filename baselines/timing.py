"""Where a training loop's time goes: wall-clock and CPU seconds per phase of the loop.

Every algorithm times the same named phases through :meth:`Run.timed <evaaa_baselines.run.Run.timed>`:

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
