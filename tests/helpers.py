"""Helpers shared by the tests: importing a script, reading a run directory's CSV files."""

from __future__ import annotations

import csv
import importlib.util
import sys
from pathlib import Path

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def load_script(name: str):
    """Import ``scripts/<name>.py`` as a module (the scripts directory is not a package); it is registered in
    ``sys.modules`` because dataclasses look their module up there."""
    spec = importlib.util.spec_from_file_location(f"evaaa_scripts_{name}", SCRIPTS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def read_csv(path: Path) -> list[dict]:
    """A run's CSV rows without their wall-clock column (the one thing two identical runs differ in)."""
    with open(path, newline="") as f:
        return [{k: v for k, v in row.items() if k != "wall_time"} for row in csv.DictReader(f)]


def train_scalars(run_dir: Path) -> dict[str, dict[int, str]]:
    """The logger's training metrics, the last value written per step (a resumed run re-logs the lost steps)."""
    out = {}
    for path in sorted((run_dir / "logs" / "scalars" / "train").glob("*.csv")):
        with open(path) as f:
            out[path.stem] = {int(step): value for step, value in csv.reader(f)}
    return out
