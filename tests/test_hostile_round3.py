"""Hostile inputs, round three (issue 65): level names that would reach the MuJoCo XML or a file name, refused level
files through ``train.py level=file``, a play reset that cannot be built, and crafted checkpoints."""

from __future__ import annotations

import json
import os
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import pytest

import evaaa
from evaaa.pictures import render_level
from evaaa.scene import build_mjcf
from evaaa.spec import LevelError, load_level, register_level, registered_levels
from evaaa.worldgen import ResourcePool

#: a hang, not a slow machine
HANG_SECONDS = 10


def level_file(folder: Path, text: str, name: str = "mine.yaml") -> Path:
    path = folder / name
    path.write_text(text)
    return path


# ------------------------------------------------------------------------------------------------ 1. level names
def xml_breaking_names(tmp_path: Path) -> list[str]:
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)  # an <include> of a FIFO hung make_env
    return [
        f'a"><include file="{fifo}"/></mujoco><mujoco model="b',
        "a'><x/>",
        "a&b",
        "a<b",
        "../../x",
        "a/b",
        ".hidden",
        "x y",
        "a\nb",
        "",
        "x" * 65,
    ]


def test_a_level_name_that_could_break_the_xml_or_a_path_is_refused_at_load(tmp_path):
    for name in xml_breaking_names(tmp_path):
        path = level_file(tmp_path, f"extends: '1-1'\nname: {json.dumps(name)}\n")  # a JSON string is YAML
        start = time.monotonic()
        with pytest.raises(LevelError) as info:
            evaaa.make_env(path, num_envs=1)
        assert time.monotonic() - start < HANG_SECONDS
        message = str(info.value)
        assert str(path) in message.splitlines()[0]
        assert "name: must be 1 to 64 letters, digits, '-', '_' or '.', starting with a letter or digit" in message


def test_every_packaged_level_name_and_a_plain_users_name_stay_valid(tmp_path):
    for name in (*evaaa.LEVELS, *evaaa.TESTBEDS):
        assert load_level(name).name == name
    assert load_level(level_file(tmp_path, "extends: '1-1'\nname: My_level.v2-b\n")).name == "My_level.v2-b"


def test_a_level_file_whose_stem_is_no_level_name_is_not_registered(tmp_path):
    # Path('...yaml').stem is '..': as a run's folder name it would lead out of runs/
    for stem in ("..", "my level"):
        path = level_file(tmp_path, "extends: '1-1'\nname: fine\n", f"{stem}.yaml")
        with pytest.raises(LevelError, match=r"\(the file's stem\) must be 1 to 64 letters"):
            register_level(path)
        assert stem not in registered_levels()


def _unchecked(name: str):
    """Level 1-1 renamed without validation, as code that builds a Level by hand could."""
    return load_level("1-1").model_copy(update={"name": name})


def test_the_mjcf_quotes_a_level_name_it_is_given(tmp_path):
    name = f'a"><include file="{tmp_path / "nowhere.xml"}"/></mujoco><mujoco model="b&<'
    level = _unchecked(name)
    text = build_mjcf(level, ResourcePool.from_level(level))
    root = ET.fromstring(text)  # one well-formed model: the name ended no attribute and added no element
    assert root.tag == "mujoco" and root.get("model") == f"evaaa-{name}"
    assert root.find(".//include") is None
    model = mujoco.MjModel.from_xml_string(text)  # MuJoCo opens no file either (the include's file does not exist)
    assert model.nbody > 1


def test_pictures_of_a_level_stay_in_their_folder(tmp_path):
    out = tmp_path / "a" / "b"
    out.mkdir(parents=True)
    with pytest.raises(LevelError, match="would write its picture outside"):
        render_level(_unchecked("../../x"), out, seed=0)
    assert [p for p in tmp_path.rglob("*") if p.is_file()] == []
