"""Fuzzing level overrides: every override set is either refused with a LevelError that names a field it changed,
or gives a world that runs 50 decisions with finite observations and rewards.

The cases (tests/fuzz_levels.py) are seeded: a failure names its seed, and ``draw_case(seed)`` replays it.  The
default suite runs a few hundred cases without vision except where a case changes what the camera sees; the slow
version runs more, every modality on.

Hostile files (``hostile_file``: nesting, aliases, tags, encodings, sizes) must end in a one-line LevelError naming the
file (or, where only the level's values are wrong, the usual list of fields under a first line naming it) or in a
level that runs, each within a time bound.
"""

from __future__ import annotations

import collections
import time
from pathlib import Path

import numpy as np
import pytest
from fuzz_levels import draw_case, hostile_file

from evaaa.sim import Simulator
from evaaa.spec import LevelError, load_level

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
