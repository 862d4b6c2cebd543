"""Running a protocol's cells: :class:`Runner` hands each to an engine (:mod:`.engines`) once the files it needs exist,
as many at a time as the engine has slots, and reports what finished, failed or was left for the next session."""

from __future__ import annotations

import fnmatch
import signal
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

from .cells import Cell, Layout
from .engines import CellResult, CellTask, Engine, LocalEngine, RayEngine, SubmititEngine, raise_interrupt
from .plan import minutes_left
from .protocol import Protocol, ProtocolError


# ------------------------------------------------------------------------------------------------ running
def select(cells: Sequence[Cell], patterns: Sequence[str]) -> list[Cell]:
    """The cells named by ``patterns`` (names or shell patterns, ``eval/ppo/*``); an unmatched one is an error."""
    chosen: list[Cell] = []
    for pat in patterns:
        hits = [c for c in cells if fnmatch.fnmatchcase(c.name, pat)]
        if not hits:
            raise ProtocolError(f"cells: no cell named {pat!r} (plan=true lists them)")
        chosen += [c for c in hits if c not in chosen]
    return [c for c in cells if c in chosen]


#: how reproduce.py runs cells: a pool of subprocesses on this machine, Ray tasks, SLURM jobs through submitit
EXECUTORS = ("local", "ray", "slurm")


class Runner:
    """Runs cells on an engine (``executor``: local, ray or slurm). The runner only hands a cell to the engine once
    the files it needs exist — the engine queues, places, runs and retries it — and the done-markers the workers
    write are the only record of what is done."""

    def __init__(
        self,
        p: Protocol,
        cells: Sequence[Cell],
        lay: Layout,
        *,
        executor: str = "local",
        jobs: int = 1,
        max_minutes: float | None = None,
        end_minutes: float | None = None,
        redo: bool = False,
        retries: int = 0,
        python: str = sys.executable,
        progress: bool = True,
        echo: Callable[[str], None] = print,
        selects: str | None = None,
        ray_address: str | None = None,
        ray_retries: int = 3,
        submitit_cluster: str = "slurm",
        slurm: dict[str, Any] | None = None,
        slurm_requeues: int = 10,
    ):
        if executor not in EXECUTORS:
            raise ProtocolError(f"executor={executor}: not an executor; allowed: {', '.join(EXECUTORS)}")
        self.p, self.cells, self.lay, self.jobs, self.retries = p, list(cells), lay, jobs, retries
        self.selects = selects  # reproduce.py's protocol=, root=, out= as given: the report's commands repeat them
        self.max_minutes, self.redo, self.python, self.progress, self.echo = max_minutes, redo, python, progress, echo
        self.end_minutes = end_minutes
        self.executor, self.ray_address, self.ray_retries = executor, ray_address, ray_retries
        self.submitit_cluster, self.slurm, self.slurm_requeues = submitit_cluster, dict(slurm or {}), slurm_requeues

    def _engine(self) -> Engine:
        if self.executor == "ray":
            return RayEngine(self.p, self.ray_address, self.jobs, self.ray_retries)
        if self.executor == "slurm":
            return SubmititEngine(self.p, self.lay, self.submitit_cluster, self.slurm, self.slurm_requeues)
        return LocalEngine(self.jobs)

    def _ready(self, cell: Cell, finished: set[str], failed: set[str], selected: set[str]) -> bool | None:
        """True: may start; False: wait; None: can never start in this session (a needed cell failed or is not
        being run and its files are missing)."""
        if cell.kind == "report":
            pending = [n for n in cell.needs_cells if n in selected and n not in finished]
            if any(n in failed for n in pending):
                return None
            return not pending
        if all(f.exists() for f in cell.needs):
            return True
        # the cells whose files are missing (``needs`` and ``needs_cells`` pair up where they are as many: an
        # evaluation that waits for its model and for the choice of the compared mode waits on whichever is missing)
        paired = len(cell.needs) == len(cell.needs_cells)
        missing = [n for f, n in zip(cell.needs, cell.needs_cells) if not f.exists()] if paired else cell.needs_cells
        if any(n in failed or n in finished or n not in selected for n in missing):
            return None
        return False

    def _left_for_later(
        self, cell: Cell, ready: bool | None, late: set[str], end: float | None, waited: int | None = None
    ) -> bool:
        """Whether ``cell`` is left for the next session: a cell it needs was, or it could start but its estimate
        (less what it has run already, :func:`minutes_left`) does not fit in the minutes ``end_minutes`` leaves.
        ``waited``: the number of slots, when the cell was ready while every one was taken: it stopped fitting while
        it waited, so the two numbers would read equal, and the message says that instead."""
        if ready is False:
            return any(n in late for n in cell.needs_cells)
        if not ready or end is None:
            return False
        left, spent = minutes_left(cell, self.lay)
        if 60 * left > end - time.time():
            now = max(end - time.time(), 0) / 60
            if waited:
                ran = f", less the {spent:.0f} CPU-minutes it has run ({left:.3g} left)," if spent else ","
                self.echo(
                    f"{cell.name}: not started: it waited for a free slot (jobs={waited}) until its estimate "
                    f"(plan=true), {cell.minutes:.3g} minutes{ran} no longer fit in the minutes "
                    f"end_minutes={self.end_minutes:g} leaves"
                )
                return True
            # whole minutes, or as many decimals as it takes for the two not to read equal ("58 does not fit in the 58")
            d = next((d for d in range(3) if f"{left:.{d}f}" != f"{now:.{d}f}"), 3)
            need = f"{cell.minutes:.{d if not spent else 0}f} minutes,"
            ran = f" less the {spent:.0f} CPU-minutes it has run, {left:.{d}f} left," if spent else ""
            self.echo(
                f"{cell.name}: not started: its estimate (plan=true), {need}{ran} does not fit "
                f"in the {now:.{d}f} minutes end_minutes={self.end_minutes:g} leaves"
            )
            return True
        return False

    def run(self, todo: Sequence[Cell]) -> int:
        """Run ``todo`` (in its order, as their needs allow); returns 0 when every one finished, else 1."""
        deadline = None if self.max_minutes is None else time.time() + 60 * self.max_minutes
        # end_minutes: every cell must end by then (a machine that keeps no files past a session: a cell cut short
        # there would start over next time), so a cell starts only while its estimate fits in the minutes left
        end = None if self.end_minutes is None else time.time() + 60 * self.end_minutes
        bar = None
        if self.progress:
            from tqdm import tqdm

            bar = tqdm(total=len(todo), desc="cells", unit="cell", dynamic_ncols=True)
        sched = _Schedule(self, todo, bar, deadline, end)
        previous = signal.signal(signal.SIGTERM, raise_interrupt)
        engine = self._engine()
        try:
            while sched.waiting or sched.running:
                release = sched.release(engine.capacity)
                if release:
                    sched.running.update(zip(engine.submit(release), (t.name for t in release)))
                if not sched.running:
                    sched.block_waiting()  # nothing runs and nothing could start: nothing ever will
                    break
                for handle, outcome in engine.wait(list(sched.running), timeout=0.5):
                    sched.receive(handle, outcome)
                sched.check_deadline()
        except KeyboardInterrupt:
            self.echo(
                f"reproduce: stopping: {len(sched.running)} running cell(s) asked to stop (training writes a "
                "checkpoint; an evaluation stops and is run again next time)"
            )
            engine.stop(list(sched.running))
            raise
        finally:
            engine.close()
            signal.signal(signal.SIGTERM, previous)
            if bar is not None:
                bar.close()
        return sched.summary()


class _Schedule:
    """The state of one :meth:`Runner.run`: which cells wait, run, finished, failed, were left for later."""

    def __init__(self, runner: Runner, todo: Sequence[Cell], bar: Any, deadline: float | None, end: float | None):
        self.r, self.bar, self.deadline, self.end = runner, bar, deadline, end
        self.selected = {c.name for c in todo}
        self.by_name = {c.name: c for c in runner.cells}
        self.waiting = list(todo)
        self.running: dict[Any, str] = {}
        self.finished: set[str] = set()
        self.failed: set[str] = set()
        self.late: set[str] = set()
        self.queued: set[str] = set()
        self.blocked: list[str] = []
        self.tries: dict[str, int] = {}

    def _count(self) -> None:
        if self.bar is not None:
            self.bar.update(1)

    def release(self, capacity: int | None) -> list[CellTask]:
        """The waiting cells that may start now, as many as the engine has free slots for."""
        r, release = self.r, []
        free = None if capacity is None else capacity - len(self.running)
        for cell in list(self.waiting):
            ready = r._ready(cell, self.finished, self.failed, self.selected)
            if r._left_for_later(cell, ready, self.late, self.end, capacity if cell.name in self.queued else None):
                self.waiting.remove(cell)
                self.late.add(cell.name)
                self._count()
            elif ready is None:
                self.waiting.remove(cell)
                self.blocked.append(cell.name)
                self.failed.add(cell.name)
                self._count()
            elif ready and free is not None and len(release) >= free:
                self.queued.add(cell.name)  # ready, every slot taken
            elif ready:
                self.waiting.remove(cell)
                # a retry continues what the first try began
                redo = r.redo and cell.name not in self.tries
                release.append(CellTask(r.p, r.cells, cell.name, r.lay.root, redo, r.selects, r.python, self.deadline))
        return release

    def block_waiting(self) -> None:
        self.blocked += [c.name for c in self.waiting]
        self.failed.update(c.name for c in self.waiting)

    def receive(self, handle: Any, outcome: CellResult | BaseException) -> None:
        """What an engine reports of a cell: failed (tried again while retries are left), late or finished."""
        r, name = self.r, self.running.pop(handle)
        if isinstance(outcome, KeyboardInterrupt):
            raise outcome
        if isinstance(outcome, BaseException):
            rc = getattr(outcome, "rc", None)
            if self.tries.get(name, 0) < r.retries and rc not in (130, -signal.SIGINT):
                # e.g. the renderer's crash: the same cell again, continuing from what it left
                self.tries[name] = self.tries.get(name, 0) + 1
                r.echo(
                    f"{name}: exit status {rc}; trying again ({self.tries[name]} of {r.retries}); see {r.lay.log(name)}"
                )
                self.waiting.insert(0, self.by_name[name])
                return
            self.failed.add(name)
            r.echo(str(outcome))
        elif outcome.late:
            self.late.add(name)
        else:
            for m in outcome.messages:
                r.echo(m)
            self.finished.add(name)
            for dep in outcome.outdated:  # evaluations of old models: made again
                if dep not in self.selected:
                    self.selected.add(dep)
                    self.waiting.append(self.by_name[dep])
                    if self.bar is not None:
                        self.bar.total += 1
        self._count()

    def check_deadline(self) -> None:
        """Past ``max_minutes``: no new cell starts; the bar names the running ones."""
        if self.deadline is not None and time.time() > self.deadline and self.waiting:
            self.r.echo(
                f"max_minutes={self.r.max_minutes:g} reached: no new cell starts; the {len(self.running)} running finish"
            )
            self.late.update(c.name for c in self.waiting)
            self.waiting = []
        if self.bar is not None:
            self.bar.set_postfix_str(", ".join(self.running.values())[:80])

    def summary(self) -> int:
        """What did not start and why; 0 when every selected cell finished, else 1."""
        if self.blocked:
            self.r.echo(
                "not started (a cell they need failed or was not selected, and its files are missing): "
                + ", ".join(self.blocked)
            )
        if self.late:
            self.r.echo(f"{len(self.late)} cell(s) not started (max_minutes, end_minutes); the same command continues")
        return 0 if len(self.finished) == len(self.selected) else 1
