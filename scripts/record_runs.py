"""Record seeded short training runs of every algorithm on this code, and compare a later code with the recording.

    python scripts/record_runs.py out=../recordings/main-ce12fe5/runs
    python scripts/record_runs.py compare=../recordings/main-ce12fe5/runs

Each run of :data:`RUNS` (every algorithm with ``preset=debug`` on 1-1: 256 env steps in 2 worlds, gradient steps,
checkpoints every 64 steps, evaluations at 128 and 256; and a two-stage curriculum of PPO) trains with ``seed`` on
the CPU, one thread, in this process.  Recorded per run, under ``<run>/``: every CSV and text file the run wrote
(episodes.csv, eval.csv, every scalar of logs/scalars/, the logged hyperparameters), verbatim, and every leaf of
every checkpoint and model file (weights, optimiser and replay state, counters, the worlds' snapshot) in
``checkpoints.npz`` (arrays) and ``checkpoints.json`` (the rest); ``manifest.json`` holds the commit and settings.

``compare=`` trains the recording's runs again (in a temporary folder) and prints one line per run: ``identical``
or the first difference (file, row and column, or checkpoint leaf and index; recorded and new value); exit status
1 when a run differs.  Everything compares exactly but the clock columns and scalars named in :data:`CLOCKS`
(when a row was written, CPU and wall seconds, speeds), whose rows must still be there, and the rows of a replay
storage beyond those written (memory left uninitialised, saved as found).
"""

from __future__ import annotations

import csv
import fnmatch
import json
import os
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from evaaa_baselines import cli
from evaaa_baselines.cli import option
from evaaa_baselines.recordings import (
    RecordingError,
    check_out,
    check_recording,
    default_out,
    first_difference,
    write_manifest,
)

EXAMPLES = [
    "out=../recordings/main-ce12fe5/runs",
    "compare=../recordings/main-ce12fe5/runs runs=[ppo] keep=../kept-runs",
]
PROG = "record_runs.py"
TOOL = "record_runs"
#: every run recorded: name -> train.py overrides (beside :data:`COMMON`)
RUNS = {
    "dqn": ["algo=dqn"],
    "ppo": ["algo=ppo"],
    "ppo_lstm": ["algo=ppo_lstm"],
    "dreamer_xs": ["algo=dreamer_xs"],
    "ppo-curriculum": ["algo=ppo", "level=curriculum", "level.stages=[1-1,1-2]", "total_steps=128"],
}
#: what every run shares: the smoke sizes, the CPU, one thread, CSV logs
COMMON = ["preset=debug", "logger=csv", "progress=false", "device=cpu", "threads=1", "deterministic=true"]
#: what two identical runs differ in, and is not compared: CSV columns (by name), scalar tags and checkpoint leaves
#: (shell patterns over ``logs/scalars/<tag>`` and over a leaf's path in its file, ``checkpoint.pt:time/seconds``).
#: A clock scalar's steps are compared, not its values; a clock column's presence, not its values.
CLOCKS = {
    "columns": ("wall_time", "cpu_seconds"),
    "scalars": ("time/*", "eval/cpu_seconds"),
    "leaves": (
        "*.pt:time/*",
        "*.pt:logs/*/cpu_seconds",
        "*.pt:logs/logger/*/scalars/time/*/1",  # the logger's (step, value) pairs: the value
        "*.pt:logs/logger/*/scalars/eval/cpu_seconds/*/1",
        "*.pt:logs/eval_csv",  # where eval.csv ended: its cpu_seconds column's text varies in width
    ),
}
#: where a checkpoint holds a replay buffer's storage: only its first ``_len`` rows were written (:func:`written`)
STORAGE = "/_storage/_storage/"
#: the files of a run recorded verbatim (checkpoints are read leaf by leaf)
TEXTS = ("*.csv", "*.txt")


@dataclass
class RunsConfig:
    runs: list[str] = option(
        list(RUNS), "runs to record (compare: to replay, default all the recording holds)", choices=list(RUNS)
    )
    out: str | None = option(None, "folder to record into (new or empty; outside the repository)")
    compare: str | None = option(None, "a recording's folder: train its runs again here and report the differences")
    seed: int = option(0, "seed of every run", check=cli.SEED)
    keep: str | None = option(None, "compare: keep the new runs' folders here (default: a temporary folder, removed)")


def check(cfg: RunsConfig, argv: list[str]) -> tuple[RunsConfig, dict[str, list[str]]]:
    """The settings to record or compare with, and each run's train.py overrides (compare: the recording's own), or
    one line and exit 2."""
    if cfg.compare is not None:
        if cfg.out is not None:
            cli.fail(PROG, "give out= (record) or compare= (train a recording's runs again), not both")
        if cli.given(argv, "seed"):
            cli.fail(PROG, "seed=: compare= replays the recording's own seed")
        try:
            manifest = check_recording(Path(cfg.compare), TOOL)
        except RecordingError as err:
            cli.fail(PROG, str(err))
        recorded = list(manifest["runs"])
        asked = cfg.runs if cli.given(argv, "runs") else recorded
        missing = [name for name in asked if name not in recorded]
        if missing:
            cli.fail(PROG, f"runs={cli.given(argv, 'runs')}: '{missing[0]}' is not in the recording")
        cfg = RunsConfig(**{**asdict(cfg), "seed": manifest["settings"]["seed"], "runs": asked})
        return cfg, {n: manifest["settings"]["overrides"][n] for n in asked}
    if cfg.keep is not None:
        cli.fail(PROG, "keep= is for compare=")
    try:
        cfg.out = str(check_out(Path(cfg.out) if cfg.out is not None else default_out("runs")))
    except RecordingError as err:
        cli.fail(PROG, str(err))
    return cfg, {n: overrides(n, cfg.seed) for n in cfg.runs}


# ------------------------------------------------------------------------------------------------- a run's contents
def overrides(name: str, seed: int) -> list[str]:
    return [*RUNS[name], *COMMON, f"seed={seed}"]


def train_run(overrides: list[str], run_dir: Path) -> None:
    from hydra import compose, initialize_config_dir

    from evaaa_baselines.config import register_levels
    from evaaa_baselines.paths import CONF_DIR
    from evaaa_baselines.training import train

    register_levels()
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        cfg = compose("config", overrides=overrides)
    train(cfg, run_dir)


def leaves(value, path: str, arrays: dict, plain: dict) -> None:
    """Every leaf of a loaded checkpoint under its path: tensors and numpy arrays into ``arrays``, the rest (numbers,
    strings, None, empty containers) into ``plain``."""
    import torch

    if isinstance(value, dict):
        for key, item in value.items():
            leaves(item, f"{path}/{key}", arrays, plain)
        if not value:
            plain[path] = {}
    elif isinstance(value, (list, tuple)):
        for i, item in enumerate(value):
            leaves(item, f"{path}/{i}", arrays, plain)
        if not value:
            plain[path] = []
    elif isinstance(value, torch.Tensor):
        value = value.detach().cpu()
        arrays[path] = (value.view(torch.int16) if value.dtype == torch.bfloat16 else value).numpy()
    elif isinstance(value, np.ndarray):
        arrays[path] = value
    elif hasattr(value, "state_dict") or hasattr(value, "items"):  # a tensordict or a config
        leaves(dict(value.items()), path, arrays, plain)
    else:
        plain[path] = value if isinstance(value, (int, float, str, bool, type(None))) else repr(value)


def contents(run_dir: Path) -> tuple[dict[str, list[list[str]]], dict[str, np.ndarray], dict]:
    """A run folder as ``(texts, arrays, plain)``: each CSV or text file's rows by its relative path, and every
    checkpoint leaf (``<file>.pt:<path>``)."""
    from evaaa_baselines.checkpoint import load_checkpoint

    texts, arrays, plain = {}, {}, {}
    for path in sorted(p for pattern in TEXTS for p in run_dir.rglob(pattern)):
        with path.open(newline="") as f:
            texts[path.relative_to(run_dir).as_posix()] = list(csv.reader(f))
    for path in sorted(run_dir.glob("*.pt")):
        leaves(load_checkpoint(path), f"{path.name}:", arrays, plain)
    # where the run was trained is no part of what it did (the logger keeps its folder)
    plain = {k: v.replace(str(run_dir), "<run>") if isinstance(v, str) else v for k, v in plain.items()}
    return (
        texts,
        {k.replace(":/", ":"): v for k, v in arrays.items()},
        {k.replace(":/", ":"): v for k, v in plain.items()},
    )


def is_clock_leaf(key: str) -> bool:
    return any(fnmatch.fnmatchcase(key, pattern) for pattern in CLOCKS["leaves"])


def text_difference(name: str, recorded: list[list[str]], now: list[list[str]]) -> str | None:
    """The first differing row and column of a CSV or text file, clocks left out (:data:`CLOCKS`)."""
    tag = name.removeprefix("logs/scalars/").removesuffix(".csv") if name.startswith("logs/scalars/") else None
    clock_scalar = tag is not None and any(fnmatch.fnmatchcase(tag, p) for p in CLOCKS["scalars"])
    header = recorded[0] if recorded and name.endswith(".csv") and tag is None else []
    skip = {i for i, column in enumerate(header) if column in CLOCKS["columns"]}
    if clock_scalar:
        skip = {1}  # the value; its step is compared
    for row, (a, b) in enumerate(zip(recorded, now)):
        if len(a) != len(b):
            return f"{name} row {row + 1}: {len(a)} columns recorded, {len(b)} now"
        for i, (x, y) in enumerate(zip(a, b)):
            if i not in skip and x != y:
                column = header[i] if header else f"{i + 1}"
                return f"{name} row {row + 1} column {column}: recorded {x!r}, now {y!r}"
    if len(recorded) != len(now):
        return f"{name}: {len(recorded)} rows recorded, {len(now)} now"
    return None


def written(key: str, array: np.ndarray, plain: dict) -> np.ndarray:
    """The rows of a replay storage that were written (its ``_len`` beside it); the rest is memory torch left
    uninitialised (``torch.empty``), which a checkpoint saves as it found it.  Other arrays whole."""
    if STORAGE not in key:
        return array
    length = plain.get(key.split(STORAGE)[0] + "/_storage/_len")
    return array[:length] if isinstance(length, int) else array


def same(a, b) -> bool:
    """Equal plain values, NaN equal to NaN."""
    return a == b or (isinstance(a, float) and isinstance(b, float) and a != a and b != b)


def difference(recorded: tuple, now: tuple) -> str | None:
    """The first difference between two runs' :func:`contents`, or None."""
    (texts_a, arrays_a, plain_a), (texts_b, arrays_b, plain_b) = recorded, now
    for kind, a, b in (("files", texts_a, texts_b), ("checkpoint arrays", arrays_a, arrays_b)):
        if set(a) != set(b):
            gone, new = sorted(set(a) - set(b)), sorted(set(b) - set(a))
            return f"{kind} differ: recorded only {gone[:3]}, new {new[:3]}"
    for name in texts_a:
        problem = text_difference(name, texts_a[name], texts_b[name])
        if problem:
            return problem
    for key in sorted(set(plain_a) | set(plain_b)):
        if not is_clock_leaf(key) and not same(plain_a.get(key, "<missing>"), plain_b.get(key, "<missing>")):
            return f"{key}: recorded {plain_a.get(key, '<missing>')!r}, now {plain_b.get(key, '<missing>')!r}"
    for key in sorted(arrays_a):
        a, b = written(key, arrays_a[key], plain_a), written(key, arrays_b[key], plain_b)
        diff = None if is_clock_leaf(key) else first_difference(a, b)
        if diff is not None:
            return f"{key} {diff}"
    return None


def save(out: Path, run_dir: Path) -> tuple:
    """Copy a run's texts into ``out`` and its checkpoints' leaves into ``checkpoints.npz`` / ``.json``."""
    found = contents(run_dir)
    texts, arrays, plain = found
    for name in texts:
        (out / "files" / name).parent.mkdir(parents=True, exist_ok=True)
        (out / "files" / name).write_bytes((run_dir / name).read_bytes())
    np.savez_compressed(out / "checkpoints.npz", **arrays)
    (out / "checkpoints.json").write_text(json.dumps(plain, indent=0, default=repr) + "\n")
    return found


def load(folder: Path) -> tuple:
    texts = {}
    for path in sorted(p for pattern in TEXTS for p in (folder / "files").rglob(pattern)):
        with path.open(newline="") as f:
            texts[path.relative_to(folder / "files").as_posix()] = list(csv.reader(f))
    with np.load(folder / "checkpoints.npz") as data:
        arrays = dict(data)
    return texts, arrays, json.loads((folder / "checkpoints.json").read_text())


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    cfg, plan = check(
        cli.parse(RunsConfig, argv, prog=PROG, description=__doc__.split("\n\n")[0], examples=EXAMPLES), argv
    )
    os.environ.setdefault("EVAAA_THREADS", "1")  # the worlds stepped in the calling thread, as the learner

    from tqdm import tqdm

    comparing = cfg.compare is not None
    folder = Path(cfg.compare if comparing else cfg.out)
    work = Path(cfg.keep) if cfg.keep else Path(tempfile.mkdtemp(prefix="record_runs-"))
    lines, took, failed = [], {}, False
    began = time.process_time()
    try:
        for name in tqdm(cfg.runs, desc="compare" if comparing else "record", unit="run", dynamic_ncols=True):
            start = time.process_time()
            run_dir = work / name
            train_run(plan[name], run_dir)
            if comparing:
                problem = difference(load(folder / name), contents(run_dir))
            else:
                (folder / name).mkdir(parents=True)
                found = save(folder / name, run_dir)
                problem = difference(load(folder / name), found)  # the recording reads back as it was made
            took[name] = round(time.process_time() - start, 1)
            failed |= problem is not None
            lines.append(
                f"{name}: {'identical' if comparing else 'recorded'}" if problem is None else f"{name}: {problem}"
            )
    finally:
        if not cfg.keep:
            import shutil

            shutil.rmtree(work, ignore_errors=True)
    if not comparing:
        settings = {"seed": cfg.seed, "overrides": plan, "clocks": CLOCKS}
        write_manifest(folder, TOOL, settings, runs=took, cpu_seconds=round(time.process_time() - began, 1))
    print("\n".join(lines))
    print(f"{'compared with' if comparing else 'recorded in'} {folder} in {time.process_time() - began:.0f} s of CPU")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
