"""Fuzzing level overrides: every override set is either refused with a LevelError that names a field it changed,
or gives a world that runs 50 decisions with finite observations and rewards.

The cases (tests/fuzz_levels.py) are seeded: a failure names its seed, and ``draw_case(seed)`` replays it.  The
default suite runs a few hundred cases without vision except where a case changes what the camera sees; the slow
version runs more, every modality on.

Hostile files (``hostile_file``: nesting, aliases, tags, encodings, sizes) must end in a one-line LevelError naming the
file (or, where only the level's values are wrong, the usual list of fields under a first line naming it) or in a
level that runs, each within a time bound.  The families of issue 65's audit (``audit_case``: XML-breaking names,
YAML 1.1 forms, merge keys, symlink loops, FIFOs, long extends chains, huge integers) go through ``make_env`` and
``train.py level=file``.
"""

from __future__ import annotations

import collections
import contextlib
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from fuzz_levels import AUDIT_FAMILIES, YAML11_ONLY, audit_case, draw_case, hostile_file

import evaaa
from evaaa.level import LevelError
from evaaa.level_files import load_level
from evaaa.sim import Simulator

ROOT = Path(__file__).resolve().parents[1]
STEPS = 50
NO_VISION = ("interoception", "olfaction", "thermoception", "collision")
#: fields that change what the camera draws: cases touching them are run with vision
_DRAWN = ("sensors.vision", "daynight")


def _names_a_changed_field(message: str, overrides: dict) -> bool:
    if "found no free spot" in message:
        # obstacle groups are placed in turn, each around the ones before it: changing one group (its kind, size
        # or count) can leave no room for a later one, and the refusal names the group that could not be placed
        return any(path.startswith(("obstacles.", "arena.")) for path in overrides)
    return any(path.split(".")[-1] in message for path in overrides)


def _run(level, seed: int, modalities, steps: int = STEPS) -> str | None:
    """Step a world of ``level`` with random actions; the problem found, or None."""
    sim = Simulator(level, 1, modalities, seed=seed, threads=1)
    try:
        actions = np.random.default_rng(seed).integers(0, 5, size=steps)
        obs = sim.reset()
        for t in range(steps):
            for key, value in obs.items():
                if value.dtype.kind == "f" and not np.isfinite(value).all():
                    return f"observation {key} not finite at step {t}: {value}"
            obs, reward, terminated, truncated, _ = sim.step(actions[t : t + 1])
            if not np.isfinite(reward).all():
                return f"reward not finite at step {t}: {reward}"
            if terminated[0] or truncated[0]:
                obs = sim.reset()
        return None
    finally:
        sim.close()


def _fuzz(seeds, all_modalities: bool) -> tuple[list[str], int, int]:
    failures, refused, ran = [], 0, 0
    for seed in seeds:
        base, overrides = draw_case(seed)
        case = f"seed {seed}: {base} {overrides}"
        try:
            level = load_level(base, overrides)
            drawn = all_modalities or any(p.startswith(_DRAWN) for p in overrides)
            problem = _run(level, seed, None if drawn else NO_VISION)
        except LevelError as exc:  # at load time, or when MuJoCo refuses the scene
            refused += 1
            if not _names_a_changed_field(str(exc), overrides):
                failures.append(f"{case}\n  refused without naming a changed field: {exc}")
            continue
        except Exception as exc:  # noqa: BLE001 - every other error is a failure of the level checks
            failures.append(f"{case}\n  {type(exc).__name__}: {exc}")
            continue
        ran += 1
        if problem:
            failures.append(f"{case}\n  {problem}")
    return failures, refused, ran


def test_fuzzed_levels_are_refused_by_name_or_run_finite():
    failures, refused, ran = _fuzz(range(300), all_modalities=False)
    assert not failures, f"{len(failures)} of 300 cases failed:\n" + "\n".join(failures)
    # the generator must keep producing both kinds of case, or this test would check little
    assert refused >= 100 and ran >= 40, (refused, ran)


@pytest.mark.slow
def test_fuzzed_levels_with_every_modality():
    failures, refused, ran = _fuzz(range(300, 1300), all_modalities=True)
    assert not failures, f"{len(failures)} of 1000 cases failed:\n" + "\n".join(failures)
    assert refused >= 250 and ran >= 150, (refused, ran)


# ------------------------------------------------------------------------------------------------ hostile files
#: longer than any case takes on a slow machine (they take milliseconds): a case past it hangs
HANG_SECONDS = 10


def _hostile(seeds, tmp_path) -> tuple[list[str], collections.Counter]:
    """Load each hostile file: it must end, within the bound, in a LevelError whose first line names the file (a
    single line unless the level's values are what is wrong), or in a level that steps."""
    failures, outcomes = [], collections.Counter()
    for seed in seeds:
        kind, data = hostile_file(seed)
        path = tmp_path / f"hostile-{seed}.yaml"
        path.write_bytes(data)
        case = f"seed {seed} ({kind}, {len(data)} bytes: {data[:80]!r})"
        start = time.monotonic()
        try:
            level = load_level(path)
            problem = _run(level, seed, NO_VISION, steps=10)
            outcomes["level"] += 1
            if problem:
                failures.append(f"{case}\n  {problem}")
        except LevelError as exc:
            message = str(exc)
            lines = message.splitlines()
            outcomes["values" if message.startswith("invalid level") else "file"] += 1
            if str(path) not in lines[0]:
                failures.append(f"{case}\n  the error does not name the file: {message[:300]}")
            if len(message) > 2000 or max(map(len, lines)) > 600:
                failures.append(f"{case}\n  the error is {len(message)} characters long: {message[:300]}")
            if not message.startswith("invalid level") and len(lines) != 1:
                failures.append(f"{case}\n  the error spans {len(lines)} lines: {message[:300]}")
        except Exception as exc:  # noqa: BLE001 - anything else is a crash of the loader
            failures.append(f"{case}\n  {type(exc).__name__}: {str(exc)[:300]}")
        elapsed = time.monotonic() - start
        if elapsed > HANG_SECONDS:
            failures.append(f"{case}\n  took {elapsed:.1f} s")
        path.unlink()
    assert not Path("/tmp/evaaa-pwned").exists(), "a YAML tag ran code"
    return failures, outcomes


def test_hostile_level_files_end_in_a_named_one_line_error_or_a_level(tmp_path):
    failures, outcomes = _hostile(range(150), tmp_path)
    assert not failures, f"{len(failures)} of 150 cases failed:\n" + "\n".join(failures)
    # every kind of ending occurs, or the generator would check little
    assert outcomes["file"] >= 60 and outcomes["values"] >= 5 and outcomes["level"] >= 5, outcomes


@pytest.mark.slow
def test_more_hostile_level_files(tmp_path):
    failures, outcomes = _hostile(range(150, 1650), tmp_path)
    assert not failures, f"{len(failures)} of 1500 cases failed:\n" + "\n".join(failures)
    assert outcomes["file"] >= 600 and outcomes["level"] >= 50, outcomes


# ------------------------------------------------------------------------------------------------ round three
#: a case that builds an env takes well under a second, but the 2-core box is shared: a FIFO's open would never end
AUDIT_HANG_SECONDS = 30


@contextlib.contextmanager
def _deadline(seconds: float):
    """TimeoutError in this (the main) thread after ``seconds``: a FIFO opened for reading would block for ever."""

    def expire(signum, frame):
        raise TimeoutError(f"still running after {seconds} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def _check_refusal(case: str, message: str, folder: Path) -> list[str]:
    """What is wrong with a LevelError's ``message`` for a case made in ``folder``: it must name one of the case's
    files in its first line, and be one line unless the level's values are what is wrong."""
    lines, problems = message.splitlines(), []
    if str(folder) not in lines[0]:
        problems.append(f"{case}\n  the error names none of the case's files: {message[:300]}")
    if not message.startswith("invalid level") and len(lines) != 1:
        problems.append(f"{case}\n  the error spans {len(lines)} lines: {message[:300]}")
    if len(message) > 2000 or max(map(len, lines)) > 600:
        problems.append(f"{case}\n  the error is {len(message)} characters long: {message[:300]}")
    return problems


def test_the_audits_families_through_make_env_end_in_a_named_error_or_an_env(tmp_path):
    """Issue 65's families (XML-breaking names, YAML 1.1 forms, merge keys, symlink loops, FIFOs, long extends chains,
    huge integers) through ``evaaa.make_env``: a one-line LevelError naming a file of the case, or an env that
    steps, within the bound; never a hang or another exception."""
    failures, outcomes = [], collections.Counter()
    for seed in range(42):  # six of each family
        folder = tmp_path / f"case{seed}"
        folder.mkdir()
        family, path = audit_case(seed, folder)
        case = f"seed {seed} ({family}: {path.name})"
        start = time.monotonic()
        try:
            with _deadline(AUDIT_HANG_SECONDS):
                env = evaaa.make_env(str(path), seed=seed, modalities=NO_VISION)
                try:
                    env.rollout(3)
                finally:
                    env.close()
            outcomes[family, "env"] += 1
            text = path.read_text() if path.is_file() and not path.is_symlink() else ""
            if any(f": {v}\n" in text or f"[{v}," in text for v in YAML11_ONLY) or text.count("<<:") > 1:
                failures.append(f"{case}\n  read a YAML 1.1 form or a repeated merge key silently: {text!r}")
        except LevelError as exc:
            outcomes[family, "refused"] += 1
            failures += _check_refusal(case, str(exc), folder)
        except Exception as exc:  # noqa: BLE001 - a raw ValueError, RecursionError, a hang: the loader failed
            failures.append(f"{case}\n  {type(exc).__name__}: {str(exc)[:300]}")
        if time.monotonic() - start > AUDIT_HANG_SECONDS:
            failures.append(f"{case}\n  took {time.monotonic() - start:.1f} s")
    assert not failures, f"{len(failures)} of 42 cases failed:\n" + "\n".join(failures)
    for family in AUDIT_FAMILIES:  # each family is refused at least once, or the generator would check little
        assert outcomes[family, "refused"] >= 1, outcomes
    assert sum(n for (_, how), n in outcomes.items() if how == "env") >= 3, outcomes  # and some are levels


@pytest.mark.parametrize("family", ["yaml 1.1", "extends chain", "huge integer"])
def test_the_audits_families_through_train_py_end_in_one_line_and_write_nothing(tmp_path, family):
    """``train.py level=file`` with the first case of ``family`` that evaaa refuses: exit 2, one line naming
    level.file and the path once, no run folder."""
    for seed in range(AUDIT_FAMILIES.index(family), 700, len(AUDIT_FAMILIES)):
        folder = tmp_path / f"case{seed}"
        folder.mkdir()
        path = audit_case(seed, folder)[1]
        try:
            load_level(path)
        except LevelError as exc:
            # what evaaa says after naming the file, which train.py says too
            expected = str(exc).splitlines()[0].split(f"'{path}'", 1)[-1].lstrip(": ")[:40]
            break
    else:
        pytest.fail(f"no case of {family} is refused")
    root = tmp_path / "runs"
    cmd = [sys.executable, str(ROOT / "scripts" / "train.py"), "algo=ppo", "preset=debug", "logger=csv", "level=file"]
    done = subprocess.run(
        [*cmd, f"level.file={path}", f"run.root={root}"], cwd=tmp_path, capture_output=True, text=True, timeout=120
    )
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, (seed, done.stderr[-3000:])
    assert lines[0].startswith(f"train.py: error: level.file={path}: ") and lines[0].count(str(path)) == 1, lines[0]
    assert expected in lines[0], (expected, lines[0])
    assert not root.exists() and not (tmp_path / "outputs").exists()
