"""A run's logs: the CSV files a stage appends to (``episodes.csv``, ``eval.csv``: :class:`CsvLog`, their columns),
the counters its loop checkpoints, and its scalar log as TorchRL's ``CSVLogger`` writes it and as a committed record
keeps it.

While a run trains, the CSV logger writes one file per scalar, ``logs/scalars/<tag>.csv`` (rows ``step,value``;
``<tag>`` is ``episode/return``, ``train/updates``, ``time/env_steps_per_s`` ...).  A protocol's committed record
holds dozens of runs, so :func:`pack` folds a run's files into one, ``logs/scalars.csv`` (rows
``tag,step,value``, the values' text unchanged), and :func:`read_scalar` reads a scalar from either form — the
packed rows first, then those of a file the run wrote since (a packed run that was resumed).
"""

from __future__ import annotations

import csv
import io
import os
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from evaaa import END_TYPES, EV_NAMES
from evaaa.records import DiskError

#: where the CSV logger writes a run's scalars, one file per tag
SCALARS = Path("logs") / "scalars"
#: a run's scalars packed into one file (:func:`pack`)
PACKED = Path("logs") / "scalars.csv"
PACKED_HEADER = ["tag", "step", "value"]
#: Columns of ``eval.csv``: one row per episode of every periodic evaluation, on the run's validation worlds
#: (``worlds``), acting as ``acting`` says (:func:`~.rollout.acting_mode`).  Files written before held one row per
#: evaluation (``episodes, survival_mean, survival_min, survival_max, return_mean, end_types``): reports read both.
#: ``cpu_seconds``: the CPU seconds the stage had taken when the evaluation ended (its earlier sessions included, as
#: ``max_cpu_minutes`` counts them), so that curves can be drawn against compute as well as env steps.
EVAL_COLUMNS = (
    "env_steps",
    "stage",
    "level",
    "worlds",
    "acting",
    "episode",
    "steps",
    "return",
    "end_type",
    "food_eaten",
    "water_eaten",
    "collisions",
    "damage_taken",
    "wall_time",
    "cpu_seconds",
)
#: the columns of ``eval.csv`` files begun before ``cpu_seconds``: a run begun so goes on without it
EVAL_COLUMNS_BEFORE_CPU = EVAL_COLUMNS[:-1]


def _packed_rows(run_dir: Path) -> list[list[str]]:
    path = Path(run_dir) / PACKED
    if not path.is_file():
        return []
    with path.open(newline="") as f:
        rows = list(csv.reader(f))
    if not rows or rows[0] != PACKED_HEADER:
        raise ValueError(f"{path}: not a packed scalar log (its first row must be {','.join(PACKED_HEADER)})")
    return rows[1:]


def tags(run_dir: str | os.PathLike) -> list[str]:
    """Every scalar the run logged, packed or not, sorted."""
    run_dir = Path(run_dir)
    found = {row[0] for row in _packed_rows(run_dir)}
    found |= {p.relative_to(run_dir / SCALARS).with_suffix("").as_posix() for p in (run_dir / SCALARS).rglob("*.csv")}
    return sorted(found)


def has_scalar(run_dir: str | os.PathLike, tag: str) -> bool:
    """Whether the run logged ``tag`` (in its packed file or its own)."""
    return tag in tags(run_dir)


def read_scalar(run_dir: str | os.PathLike, tag: str) -> list[tuple[str, str]]:
    """The ``(step, value)`` rows of ``tag`` as text, in the order they were logged: the packed rows, then the
    rows of ``logs/scalars/<tag>.csv`` if the run wrote one since."""
    run_dir = Path(run_dir)
    rows = [(step, value) for t, step, value in _packed_rows(run_dir) if t == tag]
    own = run_dir / SCALARS / f"{tag}.csv"
    if own.is_file():
        with own.open(newline="") as f:
            rows += [(r[0], r[1]) for r in csv.reader(f) if r]
    return rows


def scalar_csv(run_dir: str | os.PathLike, tag: str) -> io.StringIO:
    """``tag``'s rows as the CSV text the logger writes (``step,value`` lines, no header), for ``pandas.read_csv``."""
    return io.StringIO("".join(f"{step},{value}\n" for step, value in read_scalar(run_dir, tag)))


def pack(run_dir: str | os.PathLike) -> int:
    """Fold the run's ``logs/scalars/**/*.csv`` into ``logs/scalars.csv`` (appending to one already there), check
    that every scalar reads back the same, then delete the folded files and the folders they leave empty.  Returns
    how many files were folded (0: nothing to do)."""
    run_dir = Path(run_dir)
    files = sorted((run_dir / SCALARS).rglob("*.csv"))
    if not files:
        return 0
    before = {t: read_scalar(run_dir, t) for t in tags(run_dir)}
    rows = _packed_rows(run_dir)
    for path in files:
        tag = path.relative_to(run_dir / SCALARS).with_suffix("").as_posix()
        with path.open(newline="") as f:
            rows += [[tag, r[0], r[1]] for r in csv.reader(f) if r]
    target = run_dir / PACKED
    partial = target.with_name(target.name + ".partial")
    with partial.open("w", newline="") as f:
        writer = csv.writer(f, lineterminator="\n")
        writer.writerow(PACKED_HEADER)
        writer.writerows(rows)
    with partial.open(newline="") as f:
        written: dict[str, list[tuple[str, str]]] = {}
        for tag, step, value in list(csv.reader(f))[1:]:
            written.setdefault(tag, []).append((step, value))
    if written != {
        t: r for t, r in before.items() if r
    }:  # the files changed while they were read: leave everything as it was
        partial.unlink()
        raise RuntimeError(f"{run_dir}: the packed scalar log does not read back as the files it would replace")
    os.replace(partial, target)
    for path in files:
        path.unlink()
    for folder in sorted((run_dir / SCALARS).rglob("*"), key=lambda p: -len(p.parts)):
        if folder.is_dir() and not any(folder.iterdir()):
            folder.rmdir()
    if (run_dir / SCALARS).is_dir() and not any((run_dir / SCALARS).iterdir()):
        (run_dir / SCALARS).rmdir()
    return len(files)


# ------------------------------------------------------------------------------------------------ csv files
def timestamp() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S")


class CsvLog:
    """A CSV file written one flushed row at a time, appending; :meth:`size` / ``truncate_to`` let a resumed run cut
    it back to what it held at the checkpoint."""

    def __init__(self, path: Path, columns: Sequence[str], truncate_to: int | None = None):
        self.path, self.columns = Path(path), tuple(columns)
        self._failed_at: int | None = None
        try:
            self._file = open(path, "a+", newline="")
            if truncate_to is not None:
                self._file.truncate(truncate_to)
            self._file.seek(0, os.SEEK_END)
            self._writer = csv.writer(self._file)
            if self._file.tell() == 0:
                self._writer.writerow(self.columns)
                self._file.flush()
        except OSError as exc:
            raise DiskError(path, exc) from None

    def write(self, row: Mapping[str, Any]) -> None:
        """Append one row; a disk that refuses it raises :class:`DiskError`, the file keeping its earlier rows whole."""
        size = self._file.tell()
        try:
            self._writer.writerow([f"{v:.6g}" if isinstance(v, float) else v for v in (row[c] for c in self.columns)])
            self._file.flush()
        except OSError as exc:
            self._discard(size)
            raise DiskError(self.path, exc) from None

    def _discard(self, size: int) -> None:
        """Drop what a failed write left, in the file and in its buffer (a later flush would write it again); the
        log stays closed, at ``size``."""
        try:
            self._file.close()
        except OSError:
            pass
        try:
            os.truncate(self.path, size)
        except OSError:
            pass
        self._failed_at = size

    def size(self) -> int:
        return self._failed_at if self._failed_at is not None else self._file.tell()

    def close(self) -> None:
        if self._file.closed:
            return
        try:
            self._file.close()
        except OSError as exc:
            raise DiskError(self.path, exc) from None


def eval_columns(path: Path, fresh: bool = False) -> tuple[str, ...]:
    """The columns a stage goes on writing ``eval.csv`` with: the file's own where it was begun before
    ``cpu_seconds`` (one header per file), else :data:`EVAL_COLUMNS`.  A run begun before evaluations were written
    one row per episode cannot go on in the same file; ``fresh``: a file begun empty."""
    if fresh:
        return EVAL_COLUMNS
    header: tuple[str, ...] = ()
    if path.is_file():
        with open(path, newline="") as f:
            header = tuple(next(csv.reader(f), []))
    if header == EVAL_COLUMNS_BEFORE_CPU:
        return header
    if header and header != EVAL_COLUMNS:
        raise ValueError(
            f"{path} holds one row per evaluation (written by an earlier evaaa), and this version "
            f"writes one row per episode on validation worlds: finish that run with the version "
            f"that began it, or train it again (start_over=true keeps the old run aside)"
        )
    return EVAL_COLUMNS


class Counters(dict):
    """Plain integer counters of an algorithm's loop, checkpointed like any stateful component."""

    def state_dict(self) -> dict:
        return dict(self)

    def load_state_dict(self, state: Mapping) -> None:
        self.update(state)


def episode_row(nxt: Mapping, world: int, **where: Any) -> dict[str, Any]:
    """The ``episodes.csv`` row of the episode that ended in ``world`` at a step (``nxt``: the step's ``"next"``),
    where the stage was (``env_steps``, ``stage``, ``level``, ``episode``) first."""
    info = nxt["info"]
    return {
        **where,
        "world": world,
        "steps": int(info["step_count"][world]),
        "return": float(nxt["episode_reward"][world]),
        "end_type": END_TYPES[int(info["end_type"][world])],
        **{f"final_{ev}": float(info[ev][world]) for ev in EV_NAMES},
        "wall_time": timestamp(),
    }


def episode_metrics(row: Mapping[str, Any]) -> dict[str, float]:
    """An episode's scalars (``episode/*``) from its ``episodes.csv`` row."""
    return {
        "episode/survival_steps": row["steps"],
        "episode/return": row["return"],
        **{f"episode/{ev}": row[f"final_{ev}"] for ev in EV_NAMES},
        # one 0/1 series per end type: its running mean is how often episodes end that way
        **{f"episode/end/{name}": float(name == row["end_type"]) for name in END_TYPES[1:]},
    }
