"""Where each cell of a protocol stands, read from the files it writes: done (its done-marker newer than what it
needs), partial or todo; the commands that bring it to done from there; the stamps the runner dates things with."""

from __future__ import annotations

import json
import subprocess
from collections.abc import Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Literal

from .cells import Cell, Command, Layout
from .protocol import (
    CHECKPOINTS,
)


# ------------------------------------------------------------------------------------------------ status
def _written(path: Path) -> float:
    """When ``path`` was last written: the time of the commit that last changed it where git tracks it unchanged (a
    clone writes every file at checkout, in its own order, so there its modification time says nothing), otherwise
    its modification time."""
    git = ["git", "-C", str(path.parent)]
    try:
        dirty = subprocess.run([*git, "status", "--porcelain", "--", path.name], capture_output=True, text=True)
        committed = subprocess.run([*git, "log", "-1", "--format=%ct", "--", path.name], capture_output=True, text=True)
    except OSError:  # no git on this machine
        return path.stat().st_mtime
    if dirty.returncode or committed.returncode or dirty.stdout.strip() or not committed.stdout.strip():
        return path.stat().st_mtime  # not in a work tree, not committed, or changed since its commit
    return float(committed.stdout.strip())


def _newest(paths: Sequence[Path]) -> float:
    return max((_written(q) for q in paths if q.exists()), default=0.0)


#: how the runner stamps a time (done-markers, logs, folders moved aside): UTC to the second
STAMP = "%Y%m%dT%H%M%SZ"


def utc_stamp() -> str:
    """Now, as :data:`STAMP`."""
    return datetime.now(timezone.utc).strftime(STAMP)


def _stamp_time(stamp: str) -> float:
    """A done-marker's finished stamp (:data:`STAMP`, UTC) in seconds since the epoch."""
    return datetime.strptime(stamp, STAMP).replace(tzinfo=timezone.utc).timestamp()


def _finished(cell: Cell, lay: Layout) -> str | None:
    """The UTC stamp the runner wrote into ``cell``'s done-marker when it finished it (None: no marker, or none
    readable)."""
    try:
        stamp = json.loads(lay.marker(cell.name).read_text()).get("finished")
    except (OSError, ValueError, AttributeError):
        return None
    return stamp if isinstance(stamp, str) else None


def _newer(cell: Cell, report: Cell, lay: Layout) -> bool:
    """Whether ``cell`` was (re)done after ``report`` was made.  The done-markers' finished stamps decide where both
    have one: git keeps no modification times, so a clone writes the record's files in its own order.  A cell without
    a stamp (an evaluation made by hand) is compared by when its files were written (their commit's time where git
    has them unchanged) with the report's stamp; one stamped in the report's second, with the report's marker."""
    mine, theirs = _finished(cell, lay), _finished(report, lay)
    if mine is not None and theirs is not None and mine != theirs:
        return mine > theirs  # YYYYmmddTHHMMSSZ: in time order as text
    if theirs is not None and mine is None:  # the stamp is cut to its second: a file within it came before
        return _newest(outputs(cell, lay)) >= _stamp_time(theirs) + 1
    return _newest(outputs(cell, lay)) > _written(lay.marker(report.name))


def outputs(cell: Cell, lay: Layout) -> list[Path]:
    """The files whose presence makes ``cell`` done."""
    if cell.kind == "train":
        return [cell.final_model, lay.marker(cell.name)]  # type: ignore[list-item]
    if cell.kind in ("eval", "ref"):
        return [c.out / "episodes.csv" for c in cell.commands if c.out is not None]
    if cell.kind == "choose":
        return [cell.choice]  # type: ignore[list-item]
    return [cell.report_out / "report.md", lay.marker(cell.name)]  # type: ignore[operator]


def status(cell: Cell, lay: Layout, cells: Sequence[Cell] = ()) -> Literal["done", "partial", "todo"]:
    """done: every output complete; partial: started (a run directory, an ``out`` folder) but not complete; todo."""
    outs = outputs(cell, lay)
    lost = cell.kind == "train" and not cell.final_model.exists()  # type: ignore[union-attr]
    if lost and lay.marker(cell.name).exists():
        # finished, and its models are gone (a clone of committed results holds no checkpoints): done while every
        # evaluation of it is; otherwise it is trained again for the evaluations still to make
        dependents = [c for c in cells if c.kind == "eval" and cell.name in c.needs_cells]
        return "done" if all(status(c, lay) == "done" for c in dependents) else "partial"
    if all(o.exists() for o in outs):
        if cell.kind != "report":
            return "done"
        others = [c for c in cells if c.kind != "report"]
        if all(status(c, lay) == "done" for c in others) and not any(_newer(c, cell, lay) for c in others):
            return "done"
        return "partial"  # written before some cell was (re)done
    if cell.kind == "train":
        return (
            "partial" if cell.run_dir is not None and cell.run_dir.is_dir() and any(cell.run_dir.iterdir()) else "todo"
        )
    if cell.kind in ("eval", "ref"):
        return "partial" if any(c.out is not None and c.out.exists() for c in cell.commands) else "todo"
    return "partial" if any(o.exists() for o in outs) else "todo"


def command_now(cell: Cell, lay: Layout, redo: bool = False) -> list[Command]:
    """The commands that bring ``cell`` to done from where it stands: a started training run continues
    (``resume=true``; with ``redo``: ``start_over=true``); evaluations whose ``episodes.csv`` exists are skipped (all
    run again with ``redo``)."""
    if cell.kind == "train":
        (cmd,) = cell.commands
        if lay.marker(cell.name).exists() and not cell.final_model.exists():  # type: ignore[union-attr]
            # a finished run whose models are gone, with evaluations still to make: trained again from zero (the
            # old run directory is moved aside by train.py, never deleted)
            return [Command([*cmd.argv, "start_over=true"])]
        started = cell.run_dir is not None and cell.run_dir.is_dir() and any(cell.run_dir.iterdir())
        pruned = not any((cell.run_dir / n).exists() for n in CHECKPOINTS)  # type: ignore[operator]
        if started and not redo and cell.final_model.exists() and pruned:  # type: ignore[union-attr]
            return []  # finished, checkpoints deleted: only the done-marker is missing
        if started:
            # without a checkpoint (never reached, or a clone of committed files) there is nothing to resume
            return [Command([*cmd.argv, "start_over=true" if redo or pruned else "resume=true"])]
        return [cmd]
    if cell.kind in ("eval", "ref"):
        return [c for c in cell.commands if redo or not (c.out / "episodes.csv").exists()]  # type: ignore[operator]
    return list(cell.commands)
