"""Files and disks that fight back (issue 45): hostile level files end in one line naming the file and the limit,
level files read only what the user named, and a disk that refuses a write ends in one line naming the path and
the cause, with what was there before intact and no temporary file left."""

from __future__ import annotations

import builtins
import errno
import io
import os
import re
import time
from pathlib import Path

import pytest
import torch
from helpers import load_script

import evaaa
from evaaa.level import LevelError
from evaaa.level_files import load_level
from evaaa.records import DiskError, StepLog, append_rows, read_rows
from evaaa_baselines import checkpoint, logs
from evaaa_baselines.checkpoint import load_checkpoint, save_checkpoint
from evaaa_baselines.logs import CsvLog

#: a hang, not a slow machine
HANG_SECONDS = 10


def refused(path: Path) -> str:
    """The LevelError message loading ``path`` gives, within the time bound."""
    start = time.monotonic()
    with pytest.raises(LevelError) as info:
        load_level(path)
    assert time.monotonic() - start < HANG_SECONDS
    return str(info.value)


def level_file(tmp_path: Path, text: str | bytes, name: str = "mine.yaml") -> Path:
    path = tmp_path / name
    path.write_bytes(text.encode() if isinstance(text, str) else text)
    return path


# ------------------------------------------------------------------------------------------------ 1. nesting
@pytest.mark.parametrize("depth", [40, 3000, 30_000, 100_000])
@pytest.mark.parametrize("brackets", ["[]", "{}"])
def test_deep_nesting_is_refused_in_one_line(tmp_path, depth, brackets):
    # 100,000 deep (200 KB) crashed libyaml's loader (SIGSEGV); 3,000 deep overflowed copy.deepcopy's recursion
    opening, closing = ("[", "]") if brackets == "[]" else ("{a: ", "}")
    path = level_file(tmp_path, "description: " + opening * depth + "1" + closing * depth + "\n")
    message = refused(path)
    assert "\n" not in message and str(path) in message
    assert "nested deeper than 32 levels" in message or "larger than 64 KiB" in message


def test_deep_override_values_are_refused_too():
    deep: list = []
    for _ in range(5000):
        deep = [deep]
    with pytest.raises(LevelError, match="override 'description': the value nests deeper than 32"):
        load_level("1-1", {"description": deep})
    cycle: dict = {}
    cycle["a"] = cycle
    with pytest.raises(LevelError, match="nests deeper than 32"):
        load_level("1-1", {"agent": cycle})


# ------------------------------------------------------------------------------------------------ 2. aliases
def alias_bomb(width: int, field: str = "description") -> str:
    lines = [f"a0: &a0 [{', '.join(['lol'] * width)}]"]
    lines += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * width)}]" for i in range(1, width)]
    return "\n".join(lines) + f"\n{field}: *a{width - 1}\n"


@pytest.mark.parametrize("width", [7, 9])
def test_an_alias_bomb_is_refused_before_it_expands(tmp_path, width):
    # 7 x 7 gave a 4.4 MB error message; 9 x 9 hung the loader
    message = refused(level_file(tmp_path, alias_bomb(width)))
    assert "\n" not in message and len(message) < 300
    assert "more than 100000 values, counting what each alias stands for" in message


def test_error_messages_quote_a_bounded_excerpt(tmp_path):
    # within the limits, but a long value where a number belongs: the message quotes a part of it
    path = level_file(tmp_path, "agent: {mass: [" + ", ".join(["12345"] * 5000) + "]}\n")
    message = refused(path)
    assert "agent.mass: Input should be a valid number" in message and len(message) < 500
    message = refused(level_file(tmp_path, "agent: {mass: '" + "x" * 60_000 + "'}\n"))
    assert len(message) < 500


# ------------------------------------------------------------------------------------------------ 4. extends
def test_extends_reaches_packaged_levels_and_the_users_folder_only(tmp_path):
    outside = level_file(tmp_path, "description: read from outside\n", "outside.yaml")
    folder = tmp_path / "levels"
    folder.mkdir()
    # a packaged level's name that walks out of the package folder to the file above
    up = "../" * 12 + str(outside.with_suffix(""))[1:]
    message = refused(level_file(folder, f"extends: '{up}'\n"))
    assert "is not a packaged level" in message and "read from outside" not in message
    for parent in ("../outside.yaml", str(outside)):
        message = refused(level_file(folder, f"extends: '{parent}'\n"))
        assert "leads out of" in message and str(folder / "mine.yaml") in message
    (folder / "sub").mkdir()
    level_file(folder / "sub", 'extends: "1-2"\ndescription: below\n', "base.yaml")
    assert load_level(level_file(folder, "extends: sub/base.yaml\n")).description == "below"


# ------------------------------------------------------------------------------------------------ 5. types and text
@pytest.mark.parametrize(
    "text, message",
    [
        (b"description: caf\xe9\n", "is not UTF-8 text: byte 0xe9 at offset 16"),
        ("description: x\n".encode("utf-16"), "is not UTF-8 text"),
        ("extends: ''\n", "extends must name a packaged level"),
        ("extends: null\n", "extends must name a packaged level .* got null"),
        ("agent: {mass: true}\n", "agent.mass: Input should be a valid number"),
        ("agent: {mass: '3'}\n", "agent.mass: Input should be a valid number"),
        ("agent: {mass: !!binary Mw==}\n", "!!binary is not level data"),
        ("episode: {max_steps: 100.0}\n", "episode.max_steps: Input should be a valid integer"),
        ("agent: {auto_eat: 1}\n", "agent.auto_eat: Input should be a valid boolean"),
        ("agent: {spawn_x: !!set {1, 2}}\n", "!!set is not level data"),
        ("agent: {mass: 5}\nagent: {mass: 6}\n", "the key 'agent' is repeated \\(line 2"),
        ("agent: {mass: 5, mass: 6}\n", "the key 'mass' is repeated"),
    ],
)
def test_strict_types_duplicate_keys_and_encodings(tmp_path, text, message):
    path = level_file(tmp_path, text)
    got = refused(path)
    assert str(path) in got.splitlines()[0]
    assert re.search(message, got), got


def test_sets_are_no_intervals_in_overrides_either():
    with pytest.raises(LevelError, match="agent.spawn_x': expected a list, got a set"):
        load_level("1-1", {"agent.spawn_x": {-5.0, 5.0}})
    assert load_level("1-1", {"agent.mass": 1e3}).agent.mass == 1000.0  # numbers as numbers still work


def test_yaml_numbers_with_exponents_and_dates_read_as_level_files_mean_them(tmp_path):
    level = load_level(level_file(tmp_path, "agent: {mass: 1e3, linear_drag: 5E-1}\ndescription: 2020-01-01\n"))
    assert (level.agent.mass, level.agent.linear_drag, level.description) == (1000.0, 0.5, "2020-01-01")


# ------------------------------------------------------------------------------------------------ 6. disks
class _Disk(io.RawIOBase):
    """A file whose disk fills up after ``room`` bytes."""

    def __init__(self, f, room: int, code: int = errno.ENOSPC):
        self.f, self.room, self.code = f, room, code

    def writable(self) -> bool:
        return True

    def write(self, data) -> int:
        if len(data) > self.room:
            raise OSError(self.code, os.strerror(self.code))
        self.room -= len(data)
        return self.f.write(data)

    def flush(self) -> None:
        if not self.f.closed:
            self.f.flush()

    def fileno(self) -> int:
        return self.f.fileno()

    def close(self) -> None:
        super().close()
        self.f.close()


def filling(room: int, code: int = errno.ENOSPC):
    """An ``open`` whose binary files opened for writing hold at most ``room`` bytes more."""

    def fake_open(file, mode="r", *args, **kwargs):
        f = builtins.open(file, mode, *args, **kwargs)
        return _Disk(f, room, code) if "w" in mode and "b" in mode else f

    return fake_open


class _HalfWrites:
    """A text file that, once ``full`` is set, gets half of what is written and then refuses (a disk filling up)."""

    full = False

    def __init__(self, f):
        self.f = f

    def write(self, text: str) -> int:
        if not _HalfWrites.full:
            return self.f.write(text)
        self.f.write(text[: len(text) // 2])
        self.f.flush()
        raise OSError(errno.ENOSPC, "No space left on device")

    def __getattr__(self, name):
        return getattr(self.f, name)


@pytest.mark.parametrize(
    "code, cause", [(errno.ENOSPC, "No space left on device"), (errno.EROFS, "Read-only file system")]
)
def test_a_checkpoint_the_disk_refuses_leaves_the_previous_one_and_no_temporary(tmp_path, monkeypatch, code, cause):
    path = tmp_path / "checkpoint.pt"
    save_checkpoint({"w": torch.arange(10.0)}, path, keep_previous=True)
    before = path.read_bytes()
    monkeypatch.setattr(checkpoint, "open", filling(1000, code), raising=False)
    with pytest.raises(DiskError) as info:
        save_checkpoint({"w": torch.zeros(100_000)}, path, keep_previous=True)
    assert str(info.value) == f"cannot write {path}: {cause}"
    assert info.value.errno == code
    assert path.read_bytes() == before and torch.equal(load_checkpoint(path)["w"], torch.arange(10.0))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["checkpoint.pt"]


def test_a_training_log_row_the_disk_refuses_leaves_the_earlier_rows_whole(tmp_path, monkeypatch):
    path = tmp_path / "episodes.csv"
    monkeypatch.setattr(logs, "open", lambda *a, **k: _HalfWrites(builtins.open(*a, **k)), raising=False)
    monkeypatch.setattr(_HalfWrites, "full", False)
    log = CsvLog(path, ["step", "value"])
    log.write({"step": 1, "value": 0.5})
    before = path.read_bytes()
    _HalfWrites.full = True
    with pytest.raises(DiskError, match=f"^cannot write {path}: No space left on device$"):
        log.write({"step": 2, "value": 0.25})
    log.close()
    assert path.read_bytes() == before  # no half row
    monkeypatch.setattr(logs, "open", lambda *a, **k: (_ for _ in ()).throw(OSError(errno.EACCES, "Permission denied")))
    with pytest.raises(DiskError, match=f"^cannot write {tmp_path / 'eval.csv'}: Permission denied$"):
        CsvLog(tmp_path / "eval.csv", ["step"])


def test_episode_records_and_step_logs_the_disk_refuses(tmp_path, monkeypatch):
    path = tmp_path / "episodes.csv"
    row = {"policy": "human", "level": "1-1", "episode": 0, "steps": 3}
    append_rows(path, [row])
    before = path.read_bytes()
    real_fsync = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: (_ for _ in ()).throw(OSError(errno.ENOSPC, "No space left on device")))
    with pytest.raises(DiskError, match=f"^cannot write {path}: No space left on device$"):
        append_rows(path, [row | {"episode": 1}] * 50)
    with pytest.raises(DiskError):
        append_rows(tmp_path / "new.csv", [row])
    monkeypatch.setattr(os, "fsync", real_fsync)
    assert path.read_bytes() == before and len(read_rows(path)) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["episodes.csv"]
    with pytest.raises(DiskError, match="cannot write .*steps.csv: Read-only file system"):
        monkeypatch.setattr(
            Path, "open", lambda *a, **k: (_ for _ in ()).throw(OSError(errno.EROFS, "Read-only file system"))
        )
        StepLog(tmp_path / "steps.csv")


# ------------------------------------------------------------------------------------------------ 6, 7. evaluations
def test_an_evaluation_the_disk_stops_says_so_and_the_same_command_completes_it(tmp_path, monkeypatch, capsys):
    from evaaa_baselines import reports  # where the evaluation's figures are drawn

    script = load_script("evaluate")
    out = tmp_path / "eval"
    args = ["policy=random", "levels=[two-resource-food]", "episodes=2", "num_envs=2", f"out={out}"]
    real_plot = reports.plot_outcomes
    monkeypatch.setattr(
        reports,
        "plot_outcomes",
        lambda rows, path: (_ for _ in ()).throw(OSError(errno.ENOSPC, "No space left on device", str(path))),
    )
    with pytest.raises(SystemExit) as info:
        script.main(args)
    message = str(info.value.code)
    assert "\n" not in message and "No space left on device" in message and "episodes.csv is complete" in message
    episodes = (out / "episodes.csv").read_bytes()
    assert not (out / "summary.md").exists() and not list(out.glob(".*"))  # no partial figure, no temporary
    monkeypatch.setattr(reports, "plot_outcomes", real_plot)
    assert script.main(args) == 0  # the same command writes what is missing, from the episodes it has
    assert (out / "episodes.csv").read_bytes() == episodes
    assert {p.name for p in out.iterdir()} == {"episodes.csv", "summary.md", "success.png", "outcomes.png"}
    # killed between episodes.csv and summary.md: the same again
    summary = (out / "summary.md").read_text()
    (out / "summary.md").unlink()
    assert script.main(args) == 0 and (out / "summary.md").read_text() == summary
    with pytest.raises(SystemExit, match="already holds an evaluation"):
        script.main(args)
    # another command's episodes are not summarised as this one's
    (out / "summary.md").unlink()
    with pytest.raises(SystemExit, match="holds other episodes than this command's"):
        script.main([*args[:2], "episodes=3", *args[3:]])
    assert not (out / "summary.md").exists()


def test_an_evaluation_on_a_full_disk_refuses_before_its_first_episode_and_writes_nothing(tmp_path, monkeypatch):
    import evaaa_baselines.evaluation as evaluation

    script = load_script("evaluate")
    out = tmp_path / "eval"
    played = []
    monkeypatch.setattr(evaluation, "episode_records", lambda *a, **k: played.append(a) or [])
    monkeypatch.setattr(os, "fsync", lambda fd: (_ for _ in ()).throw(OSError(errno.ENOSPC, "No space left on device")))
    with pytest.raises(SystemExit) as info:
        script.main(["policy=random", "levels=[two-resource-food]", "episodes=2", "num_envs=2", f"out={out}"])
    message = str(info.value.code)
    assert "\n" not in message and "No space left on device" in message and "no episode was played" in message
    assert played == [] and not out.exists()
    assert evaaa.TESTBEDS  # (the level list stayed importable)
