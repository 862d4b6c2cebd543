"""Recordings of today's behaviour that a restructuring is compared against (``scripts/record_trajectories.py``,
``scripts/record_runs.py``; docs/development.md, "Changing the simulator or the training loop safely").

What the two tools share: where a recording may go (never inside the repository: recordings are tens of megabytes),
its manifest (the commit it was made on and the settings a comparison replays), and the first difference between two
arrays — exact for integers, booleans and pixels, bitwise for floats unless a tolerance is asked for.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

#: the repository this module was installed from (an editable install: the checkout itself)
REPO = Path(__file__).resolve().parents[1]
MANIFEST = "manifest.json"
#: where recordings go when ``out=`` is not given: ``$EVAAA_RECORDINGS/<short commit>/<kind>``
DEFAULT_ROOT = Path("~/.cache/evaaa/recordings")


class RecordingError(ValueError):
    """A recording folder that cannot be written or read as asked (one line, for the scripts' refusals)."""


def commit() -> tuple[str, bool]:
    """``(commit, dirty)`` of the repository's checkout: dirty when a tracked file differs from the commit."""
    try:
        sha = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True, text=True, check=True
        ).stdout.strip()
        changed = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"], cwd=REPO, capture_output=True, text=True
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown", True
    return sha, bool(changed)


def default_out(kind: str) -> Path:
    """``$EVAAA_RECORDINGS/<short commit>/<kind>`` (``~/.cache/evaaa/recordings`` when the variable is unset)."""
    root = Path(os.environ.get("EVAAA_RECORDINGS") or DEFAULT_ROOT).expanduser()
    sha, dirty = commit()
    return root / (sha[:10] + ("-dirty" if dirty else "")) / kind


def check_out(out: Path) -> Path:
    """``out`` resolved, or :class:`RecordingError`: inside the repository, or already holding files."""
    out = Path(out).expanduser().resolve()
    if out == REPO or REPO in out.parents:
        raise RecordingError(f"out={out}: inside the repository; recordings are large: write them elsewhere")
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise RecordingError(f"out={out}: already holds files; a recording is written once (choose a new folder)")
    return out


def check_recording(folder: Path, tool: str) -> dict:
    """The manifest of the recording in ``folder`` made by ``tool``, or :class:`RecordingError`."""
    path = Path(folder).expanduser() / MANIFEST
    if not path.is_file():
        raise RecordingError(f"compare={folder}: no {MANIFEST} there (not a recording of {tool}.py)")
    manifest = json.loads(path.read_text())
    if manifest.get("tool") != tool:
        raise RecordingError(f"compare={folder}: a recording of {manifest.get('tool')}.py, not of {tool}.py")
    return manifest


def write_manifest(out: Path, tool: str, settings: dict, **extra: Any) -> None:
    """``manifest.json``: the tool, the commit (and whether the checkout differed from it), the settings a
    comparison replays, the library versions and the machine, and ``extra`` (what was recorded, how long it took)."""
    import mujoco
    import torch

    sha, dirty = commit()
    manifest = {
        "tool": tool,
        "commit": sha,
        "dirty": dirty,
        "settings": settings,
        "made": time.strftime("%Y-%m-%dT%H:%M:%S"),
        "versions": {
            "python": platform.python_version(),
            "numpy": np.__version__,
            "torch": torch.__version__,
            "mujoco": mujoco.__version__,
        },
        "machine": platform.platform(),
        "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
        **extra,
    }
    (out / MANIFEST).write_text(json.dumps(manifest, indent=1) + "\n")


# ------------------------------------------------------------------------------------------------- comparing
@dataclass(frozen=True)
class Difference:
    """Where two arrays first differ: ``index`` into them (row-major order), and their values there."""

    index: tuple[int, ...]
    recorded: Any
    now: Any
    note: str = ""

    def __str__(self) -> str:
        if self.note:
            return self.note
        return f"at {list(self.index)}: recorded {self.recorded!r}, now {self.now!r}"


def _bits(a: np.ndarray) -> np.ndarray:
    """A float array as unsigned integers of the same width: equal bits, equal integers (NaNs and -0.0 included)."""
    return np.ascontiguousarray(a).view(f"u{a.dtype.itemsize}")


def first_difference(recorded: np.ndarray, now: np.ndarray, atol: float = 0.0) -> Difference | None:
    """The first element (row-major) where ``now`` differs from ``recorded``, or None where they are the same.

    Integers and booleans compare exactly; floats bit for bit when ``atol`` is 0, else ``|a - b| <= atol`` (NaN
    equal to NaN).  A different dtype or shape is a difference of its own."""
    recorded, now = np.asarray(recorded), np.asarray(now)
    if recorded.dtype != now.dtype:
        return Difference((), recorded.dtype, now.dtype, f"dtype recorded {recorded.dtype}, now {now.dtype}")
    if recorded.shape != now.shape:
        return Difference((), recorded.shape, now.shape, f"shape recorded {recorded.shape}, now {now.shape}")
    if recorded.dtype.kind == "f":
        if atol > 0:
            same = np.isclose(recorded, now, rtol=0.0, atol=atol, equal_nan=True)
        else:
            same = _bits(recorded) == _bits(now)
    else:
        same = recorded == now
    if same.all():
        return None
    index = np.unravel_index(int(np.argmin(same.reshape(-1))), recorded.shape)
    index = tuple(int(i) for i in index)
    return Difference(index, recorded[index].item(), now[index].item())
