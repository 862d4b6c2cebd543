"""How cells run: one cell as subprocesses on a worker, its done-marker written last (:func:`run_cell`), and the
engines that run many — a thread pool here, Ray tasks, or submitit (SLURM) jobs — for :class:`.running.Runner`."""

from __future__ import annotations

import itertools
import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..machine import processor
from . import evaluate_many
from .cell_status import command_now, status, utc_stamp
from .cells import Cell, Command, Layout, read_clock, rounded
from .plan import cell_resources, provenance
from .protocol import CHECKPOINTS, REPO, Protocol, ProtocolError


def _move_aside(out: Path, why: str) -> Path:
    """Rename an evaluation's folder to ``<out>.<why>-<UTC time>`` (kept, never deleted); returns the new path."""
    aside = out.with_name(f"{out.name}.{why}-{utc_stamp()}")
    out.rename(aside)
    return aside


#: seconds a cell asked to stop (one SIGINT: a training writes its checkpoint) gets before it is killed
STOP_GRACE_SECONDS = 120.0


class CellFailed(RuntimeError):
    """A cell that did not finish (raised on the worker, or by the driver for a lost worker): ``rc`` its command's
    exit status (None: no status, e.g. lost with its worker); the driver tries it again ``retries`` times."""

    def __init__(self, message: str, rc: int | None = None):
        super().__init__(message, rc)
        self.message, self.rc = message, rc

    def __str__(self) -> str:
        return self.message


@dataclass
class CellTask:
    """Everything a worker needs to bring one cell to done, picklable (a Ray task's or a submitit job's argument).
    Every decision is taken on the worker from the files (:func:`status`, :func:`command_now`), so that a task run
    again — Ray retrying it after its worker was lost, the next reproduce.py — continues what the lost one began
    and never does a done cell again."""

    p: Protocol
    cells: list[Cell]  # all of the protocol's: a report's status and provenance need them
    name: str
    root: Path
    redo: bool = False
    selects: str | None = None
    python: str = sys.executable
    deadline: float | None = None  # time.time() after which the task starts nothing (max_minutes)

    @property
    def cell(self) -> Cell:
        return next(c for c in self.cells if c.name == self.name)


@dataclass
class CellResult:
    name: str
    ran: bool  # False: done already, or past the deadline
    late: bool = False  # past max_minutes' deadline: not started
    outdated: list[str] = field(default_factory=list)  # evaluations moved aside: to be made again
    messages: list[str] = field(default_factory=list)


#: set by the local executor's driver on Ctrl-C: its worker threads pass one SIGINT to their cell (a Ray task or a
#: submitit job gets a KeyboardInterrupt or SIGTERM in its own process instead)
STOP = threading.Event()


def _die_with_parent() -> None:
    """In the child, before exec: be killed when the worker that started it dies (Linux ``PR_SET_PDEATHSIG``), so
    that a cell lost with its Ray worker or SLURM job never runs on beside the retry that resumes it."""
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # 1: PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def run_cell(task: CellTask) -> CellResult:
    """Bring ``task``'s cell to done on this worker: its commands as subprocesses (one session each, a log per cell,
    CPU and wall time added to its account), then its done-marker. Raises :class:`CellFailed` on a non-zero exit;
    on KeyboardInterrupt or SIGTERM passes exactly one SIGINT to the running command (a second one would stop a
    training without its checkpoint), waits for it, and raises KeyboardInterrupt."""
    if threading.current_thread() is not threading.main_thread():
        return _run_cell(task)
    # scancel and a Ray worker's shutdown send SIGTERM: stopped like a Ctrl-C, the time so far kept
    previous = signal.signal(signal.SIGTERM, raise_interrupt)
    try:
        return _run_cell(task)
    finally:
        signal.signal(signal.SIGTERM, previous)


def raise_interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


#: how to stop the command this process is running (one SIGINT, then wait): set while :func:`_run_command` runs it
_RUNNING: list[Callable[[], None]] = []


class CellJob:
    """:func:`run_cell` as a submitit job that SLURM may requeue (submitit's checkpointing: a callable with a
    ``checkpoint`` method). On SIGUSR2 — what submitit has SLURM send ``signal_delay_s`` ahead of the job's time
    limit, and on pre-emption — submitit calls :meth:`checkpoint`: the running command is stopped as a Ctrl-C stops
    it (one SIGINT: a training writes its checkpoint), and the same task is handed back, which submitit requeues in
    the job's place; the requeued job continues the cell from its files (a started training with resume=true)."""

    def __call__(self, task: CellTask) -> CellResult:
        return run_cell(task)

    def checkpoint(self, task: CellTask) -> Any:
        import submitit

        for stop in list(_RUNNING):
            stop()
        return submitit.helpers.DelayedSubmission(self, task)


def _run_cell(task: CellTask) -> CellResult:
    cell, lay = task.cell, Layout(task.root)
    result = CellResult(cell.name, ran=False)
    if not task.redo and status(cell, lay, task.cells) == "done":
        return result  # done by an earlier try whose report was lost with its worker: never done twice
    if task.deadline is not None and time.time() > task.deadline:
        result.late = True
        return result
    commands = command_now(cell, lay, task.redo)
    if task.redo:
        lay.marker(cell.name).unlink(missing_ok=True)  # not done until it is again
    if not commands:
        _finish(task, result)
        return result
    if task.redo or "start_over=true" in commands[0].argv or status(cell, lay) == "todo":
        lay.clock(cell.name).unlink(missing_ok=True)  # nothing of it is left: timed anew
    if "start_over=true" in commands[0].argv:
        # a training from zero makes new models: what was evaluated from the old ones no longer describes them
        # (training is not reproducible to the bit), so it is evaluated again
        result.outdated = _outdated_evaluations(task, result)
    result.ran = True
    env = {**os.environ, "EVAAA_THREADS": str(task.p.threads), "PYTHONUNBUFFERED": "1"}
    for cmd in commands:
        if cmd.out is not None and cmd.out.exists() and not (cmd.out / "episodes.csv").exists():
            aside = _move_aside(cmd.out, "partial")  # an interrupted evaluation: kept, out of the way
            result.messages.append(f"{cell.name}: moved the unfinished evaluation {cmd.out} to {aside}")
        if cmd.out is not None and task.redo and (cmd.out / "episodes.csv").exists():
            aside = _move_aside(cmd.out, "old")
            result.messages.append(f"{cell.name}: redo: moved the earlier evaluation {cmd.out} to {aside}")
    if cell.kind == "report":
        commands = [_report_command(cmd) for cmd in commands]
    for cmd, own_header in _processes(commands, task.p.threads):
        rc = _run_command(cmd, cell, lay, env, task, header=own_header)
        if rc != 0:
            raise CellFailed(f"{cell.name}: FAILED (exit status {rc}); see {lay.log(cell.name)}", rc)
    _finish(task, result)
    return result


def _processes(commands: list[Command], threads: int) -> list[tuple[Command, bool]]:
    """The processes that run ``commands``, in order: consecutive evaluate.py commands share one
    (:mod:`.evaluate_many`: the imports once), any other runs alone; each with whether the runner writes its
    ``== <time> <command>`` line to the log (a shared process writes one per command itself)."""
    out: list[tuple[Command, bool]] = []
    for batchable, group in itertools.groupby(commands, key=evaluate_many.batchable):
        group = list(group)
        if batchable and len(group) > 1:
            out.append((evaluate_many.batch_command(group, threads), False))
        else:
            out.extend((cmd, True) for cmd in group)
    return out


def _run_command(
    cmd: Command, cell: Cell, lay: Layout, env: dict[str, str], task: CellTask, header: bool = True
) -> int:
    """Run one command of ``cell`` to its end; its wall time and CPU time (its own ``rusage``: the CPU it used,
    however many processes shared the cores) are added to the cell's account (:meth:`Layout.clock`)."""
    log_path = lay.log(cell.name)
    log_path.parent.mkdir(parents=True, exist_ok=True)
    with open(log_path, "a") as log:
        if header:
            log.write(f"\n== {utc_stamp()} {cmd.text(task.p.threads)}\n")
            log.flush()
        # a session of its own: a Ctrl-C at the terminal reaches reproduce.py only, which passes exactly one on
        proc = subprocess.Popen(
            [task.python, *cmd.argv],
            cwd=REPO,
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,
            preexec_fn=_die_with_parent,
        )
        began = time.monotonic()

        def reap(block: bool) -> int | None:
            pid, st, usage = os.wait4(proc.pid, 0 if block else os.WNOHANG)
            if pid == 0:
                return None
            proc.returncode = os.waitstatus_to_exitcode(st)
            path = lay.clock(cell.name)
            path.parent.mkdir(parents=True, exist_ok=True)
            account = read_clock(path)
            account["seconds"] += time.monotonic() - began
            cpu = usage.ru_utime + usage.ru_stime
            account["cpu_seconds"] += cpu
            here = processor()
            account["processors"][here] = account["processors"].get(here, 0.0) + cpu
            path.write_text(json.dumps(rounded(account)) + "\n")
            return proc.returncode

        def stop() -> None:
            if proc.returncode is not None:
                return
            proc.send_signal(signal.SIGINT)  # one: a training writes its checkpoint and stops
            deadline = time.monotonic() + STOP_GRACE_SECONDS
            while reap(False) is None and time.monotonic() < deadline:
                time.sleep(0.2)
            if proc.returncode is None:
                proc.kill()
                reap(True)

        _RUNNING.append(stop)
        try:
            while (rc := reap(False)) is None:
                if STOP.is_set():
                    raise KeyboardInterrupt
                time.sleep(0.2)
            return rc
        except KeyboardInterrupt:
            stop()
            raise
        finally:
            _RUNNING.remove(stop)


def _report_command(cmd: Command) -> Command:
    """The report over the evaluations that are complete (the others are not passed: report.py would refuse a
    folder without episodes.csv)."""
    argv = []
    for a in cmd.argv:
        if a.startswith("evals=["):
            done = [x for x in a[len("evals=[") : -1].split(",") if x and (REPO / x / "episodes.csv").exists()]
            a = "evals=[" + ",".join(done) + "]"
        argv.append(a)
    return Command(argv)


def _outdated_evaluations(task: CellTask, result: CellResult) -> list[str]:
    """The evaluation cells of the training ``task`` that have results, their folders moved aside
    (``<out>.old-<UTC time>``, never deleted) so that they are made again from the models about to be trained."""
    lay, outdated = Layout(task.root), []
    for dep in task.cells:
        if dep.kind != "eval" or task.name not in dep.needs_cells:
            continue
        moved = False
        for cmd in dep.commands:
            if cmd.out is not None and cmd.out.exists():
                aside = _move_aside(cmd.out, "old")
                result.messages.append(
                    f"{task.name} trains from zero: moved its earlier evaluation {cmd.out} to {aside}"
                )
                moved = True
        if moved:
            lay.clock(dep.name).unlink(missing_ok=True)
            outdated.append(dep.name)
    return outdated


def _finish(task: CellTask, result: CellResult) -> None:
    """Mark the cell done (every kind gets a marker with the wall and CPU seconds its commands took, over every
    session; only a training's and the report's marker count for :func:`status`)."""
    cell, lay = task.cell, Layout(task.root)
    if cell.kind == "train" and not cell.final_model.exists():  # type: ignore[union-attr]
        raise CellFailed(f"{cell.name}: train.py exited 0 but {cell.final_model} is missing; not marked done")
    clock = lay.clock(cell.name)
    account = rounded(read_clock(clock)) if clock.exists() else {"seconds": None, "cpu_seconds": None}
    marker = lay.marker(cell.name)
    marker.parent.mkdir(parents=True, exist_ok=True)
    tmp = marker.with_name(f".{marker.name}.tmp")  # written whole or not at all: a lost worker leaves no half marker
    tmp.write_text(json.dumps({"finished": utc_stamp(), "protocol": task.p.name, **account}) + "\n")
    tmp.replace(marker)
    clock.unlink(missing_ok=True)
    if cell.kind == "report" and (cell.report_out / "report.md").exists():  # type: ignore[operator]
        with open(cell.report_out / "report.md", "a") as report:  # type: ignore[operator]
            report.write("\n" + "\n".join(provenance(task.p, task.cells, lay, task.selects)))
    if cell.kind == "train" and not cell.keep_checkpoints:
        for name in CHECKPOINTS:
            (cell.run_dir / name).unlink(missing_ok=True)  # type: ignore[operator]


# ------------------------------------------------------------------------------------------------ engines
class Engine:
    """One engine's submit, wait and stop; the engine queues, places, runs and (Ray) retries the cells.
    ``capacity``: how many cells it runs at once where that is known (the runner then hands it no more, so that a
    cell that becomes ready later, an evaluation, runs before the cells after it in the protocol's order rather
    than after every cell already queued); None: a cluster's scheduler takes all that are ready."""

    capacity: int | None = None

    def submit(self, tasks: list[CellTask]) -> list[Any]:
        raise NotImplementedError

    def wait(self, handles: list[Any], timeout: float) -> list[tuple[Any, CellResult | BaseException]]:
        raise NotImplementedError

    def stop(self, handles: list[Any]) -> None:
        raise NotImplementedError

    def close(self) -> None:
        pass


class LocalEngine(Engine):
    """``jobs`` worker threads of a standard pool, each running one cell's subprocesses at a time."""

    def __init__(self, jobs: int):
        from concurrent.futures import ThreadPoolExecutor

        STOP.clear()
        self.capacity = jobs
        self.pool = ThreadPoolExecutor(max_workers=jobs, thread_name_prefix="cell")

    def submit(self, tasks):
        return [self.pool.submit(run_cell, t) for t in tasks]

    def wait(self, handles, timeout):
        from concurrent.futures import FIRST_COMPLETED, wait

        done, _ = wait(handles, timeout=timeout, return_when=FIRST_COMPLETED)
        return [(f, f.exception() or f.result()) for f in done]

    def stop(self, handles):
        from concurrent.futures import wait

        for f in handles:
            f.cancel()  # queued: never starts
        STOP.set()  # running: one SIGINT each, then they end
        wait(handles)

    def close(self):
        self.pool.shutdown(wait=True, cancel_futures=True)


class RayEngine(Engine):
    """Every cell a Ray task with the CPUs and GPUs it needs; a task whose worker (or node) is lost is run again by
    Ray (``max_retries``) and continues from the files the lost one left."""

    def __init__(self, p: Protocol, address: str | None, jobs: int, retries_on_loss: int):
        try:
            import ray
        except ImportError:
            raise ProtocolError("executor=ray needs Ray: pip install -e '.[cluster]'") from None
        self.ray, self.p = ray, p
        self.started = not ray.is_initialized()
        if self.started:
            # address=None: a Ray instance on this machine with `jobs` CPUs (so `jobs` cells of one core at once)
            kw: dict[str, Any] = {"address": address} if address else {"num_cpus": jobs * p.threads}
            self.capacity = None if address else jobs
            ray.init(**kw, include_dashboard=False, log_to_driver=False, configure_logging=False)
        self.remote = ray.remote(max_retries=retries_on_loss, retry_exceptions=False)(run_cell)

    def submit(self, tasks):
        refs = []
        for t in tasks:
            cpus, gpus = cell_resources(self.p, t.cell)
            refs.append(self.remote.options(num_cpus=cpus, num_gpus=gpus, name=t.name).remote(t))
        return refs

    def wait(self, handles, timeout):
        ready, _ = self.ray.wait(handles, num_returns=1, timeout=timeout)
        out = []
        for ref in ready:
            try:
                out.append((ref, self.ray.get(ref)))
            except self.ray.exceptions.RayTaskError as err:  # the cell's own exception (CellFailed)
                out.append((ref, getattr(err, "cause", None) or err))
            except self.ray.exceptions.RayError as err:  # the worker lost more often than max_retries
                out.append((ref, CellFailed(f"lost with its Ray worker: {type(err).__name__}")))
        return out

    def stop(self, handles):
        for ref in handles:
            self.ray.cancel(ref)  # a KeyboardInterrupt in the task: one SIGINT to its command
        self.ray.wait(handles, num_returns=len(handles), timeout=STOP_GRACE_SECONDS + 10)

    def close(self):
        if self.started:
            self.ray.shutdown()


class SubmititEngine(Engine):
    """Cells as SLURM jobs through submitit: those released together go as one job array per (CPUs, GPUs);
    ``cluster="local"``: submitit's local executor (subprocesses of this machine, the same code path). Each job is a
    :class:`CellJob`: at its time limit (or on pre-emption) its training writes a checkpoint and submitit requeues
    it, up to ``requeues`` times (pre-emptions do not count)."""

    def __init__(self, p: Protocol, lay: Layout, cluster: str, slurm: dict[str, Any], requeues: int = 10):
        try:
            import submitit
        except ImportError:
            raise ProtocolError("executor=slurm needs submitit: pip install -e '.[cluster]'") from None
        self.submitit, self.p = submitit, p
        self.executor = submitit.AutoExecutor(
            folder=lay.root / "submitit" / "%j", cluster=cluster, **{f"{cluster}_max_num_timeout": requeues}
        )
        self.executor.update_parameters(**slurm)

    def submit(self, tasks):
        groups: dict[tuple[int, float], list[CellTask]] = {}
        for t in tasks:
            groups.setdefault(cell_resources(self.p, t.cell), []).append(t)
        jobs: dict[str, Any] = {}
        for (cpus, gpus), group in groups.items():
            self.executor.update_parameters(cpus_per_task=cpus, gpus_per_node=int(gpus + 0.999))
            with self.executor.batch():  # one job array
                for t in group:
                    jobs[t.name] = self.executor.submit(CellJob(), t)
        return [jobs[t.name] for t in tasks]

    def wait(self, handles, timeout):
        deadline = time.monotonic() + timeout
        while True:
            done = [j for j in handles if j.done()]
            if done or time.monotonic() >= deadline:
                break
            time.sleep(0.5)
        out = []
        for j in done:
            try:
                out.append((j, j.result()))
            except self.submitit.core.utils.FailedJobError as err:
                cause = str(err).strip().splitlines()
                out.append(
                    (
                        j,
                        CellFailed(
                            next(
                                (ln for ln in reversed(cause) if "CellFailed" in ln),
                                f"job {j.job_id} failed; see {j.paths.stderr}",
                            )
                        ),
                    )
                )
            except Exception as err:  # noqa: BLE001 - a job that vanished (cancelled, node lost): not done
                out.append((j, CellFailed(f"job {j.job_id}: {type(err).__name__}: {err}")))
        return out

    def stop(self, handles):
        for j in handles:
            if not j.done():
                j.cancel(check=False)  # scancel: SIGTERM, one SIGINT to the command
        deadline = time.monotonic() + STOP_GRACE_SECONDS + 10
        while any(not j.done() for j in handles) and time.monotonic() < deadline:
            time.sleep(0.5)
