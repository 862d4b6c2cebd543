"""A run's scalar log, as TorchRL's ``CSVLogger`` writes it and as a committed record keeps it.

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
from pathlib import Path

#: where the CSV logger writes a run's scalars, one file per tag
SCALARS = Path("logs") / "scalars"
#: a run's scalars packed into one file (:func:`pack`)
PACKED = Path("logs") / "scalars.csv"
PACKED_HEADER = ["tag", "step", "value"]


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
