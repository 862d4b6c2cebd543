"""Hostile inputs, round three (issue 65): level names that would reach the MuJoCo XML or a file name, refused level
files through ``train.py level=file``, a play reset that cannot be built, and crafted checkpoints."""

from __future__ import annotations

import http.client
import json
import os
import socket
import subprocess
import sys
import threading
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import pytest
import torch
from helpers import load_script
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

import evaaa
from evaaa import play
from evaaa.level import LevelError
from evaaa.level_files import load_level, register_level, registered_levels
from evaaa.pictures import render_level
from evaaa.scene import build_mjcf
from evaaa.worldgen import ResourcePool
from evaaa_baselines import checkpoint, load_policy, training
from evaaa_baselines.algos import algorithm
from evaaa_baselines.config import register_levels, stages
from evaaa_baselines.paths import CONF_DIR

ROOT = Path(__file__).resolve().parents[1]
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


# ------------------------------------------------------------------------------------------------ 2. train.py level=file
def _refused_file(folder: Path, case: str) -> str | None:
    """The ``level.file=`` value of a refused level file of kind ``case`` made in ``folder`` (None: not given)."""
    path = folder / "mine.yaml"
    if case == "not given":
        return None
    if case == "missing":
        pass
    elif case == "too large":
        path.write_text("description: '" + "x" * (65 * 1024) + "'\n")
    elif case == "alias bomb":
        lines = ["a0: &a0 [" + ", ".join(["lol"] * 9) + "]"]
        lines += [f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]" for i in range(1, 9)]
        path.write_text("\n".join(lines) + "\ndescription: *a8\n")
    elif case == "yaml tag":
        path.write_text("description: !!python/object/apply:os.system ['touch pwned']\n")
    elif case == "fifo":
        os.mkfifo(path)  # never opened for reading: it would block until a writer came
    elif case == "bad name":
        path.write_text('extends: "1-1"\nname: \'a"><include file="/etc/hostname"/></mujoco><mujoco model="b\'\n')
    elif case == "symlink loop":
        (folder / "other.yaml").symlink_to(path)
        path.symlink_to(folder / "other.yaml")
    return str(path)


@pytest.mark.parametrize(
    "case, message",
    [
        ("not given", "level=file needs level.file=<path of your level's .yaml file>"),
        ("missing", "cannot be read: no such file"),
        ("too large", "is larger than 64 KiB"),
        ("alias bomb", "more than 100000 values"),
        ("yaml tag", "could not determine a constructor for the tag"),
        ("fifo", "cannot be read: not a regular file"),
        ("bad name", "name: must be 1 to 64 letters, digits"),
        ("symlink loop", "cannot be read: Symlink loop"),
    ],
)
def test_train_script_refuses_a_bad_level_file_in_one_line_and_writes_nothing(tmp_path, case, message):
    folder = tmp_path / "levels"
    folder.mkdir()
    file = _refused_file(folder, case)
    root = tmp_path / "runs"
    cmd = [sys.executable, str(ROOT / "scripts" / "train.py"), "algo=ppo", "preset=debug", "logger=csv", "level=file"]
    cmd += [*([f"level.file={file}"] if file else []), f"run.root={root}"]
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=120)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr[-3000:]
    assert lines[0].startswith("train.py: error: level") and message in lines[0], lines[0]
    # the field named with the path as typed, and the path said once (evaaa's own message names it as resolved)
    assert file is None or (lines[0].startswith(f"train.py: error: level.file={file}: ") and lines[0].count(file) == 1)
    assert not root.exists() and not (tmp_path / "outputs").exists()  # no run folder, no Hydra output folder
    assert not (tmp_path / "pwned").exists()


# ------------------------------------------------------------------------------------------------ 3. play resets
def _post(address: tuple[str, int], path: str, body: dict) -> tuple[int, dict]:
    connection = http.client.HTTPConnection(*address, timeout=60)
    connection.request("POST", path, json.dumps(body), {"Content-Type": "application/json"})
    response = connection.getresponse()
    answer = response.status, json.loads(response.read())
    connection.close()
    return answer


def test_a_play_reset_to_a_level_that_cannot_be_built_keeps_the_previous_level(tmp_path):
    folder = tmp_path / "levels"
    folder.mkdir()
    # both validate (the server registers them at start-up); MuJoCo refuses the first, the second's rocks find no room
    level_file(folder, 'extends: "1-1"\nagent: {mass: 1.0e-300}\n', "r3-weightless.yaml")
    level_file(
        folder,
        'extends: "1-1"\nobstacles:\n  rocks: {kind: rock, count: 300, x: [-3, 3], y: [-3, 3]}\n',
        "r3-crowded.yaml",
    )
    play.register_level_dir(folder)
    httpd = play.PlayServer("127.0.0.1", 0, b"<html></html>")
    httpd.session = play.PlaySession(play.PlaySettings(level="1-1", out=tmp_path / "records"))
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    address = httpd.server_address[:2]
    try:
        assert _post(address, "/api/step", {"action": 1})[0] == 200
        for name, reason in (
            ("r3-weightless", "agent.mass: MuJoCo cannot build it"),
            ("r3-crowded", "obstacles.rocks: obstacle"),
        ):
            status, answer = _post(address, "/api/reset", {"level": name})
            assert status == 400, (status, answer)
            assert answer["error"].startswith(f"level {name} cannot be played: ") and reason in answer["error"]
            assert answer["error"].endswith("level 1-1 plays on") and "\n" not in answer["error"]
            status, answer = _post(address, "/api/step", {"action": 1})  # the episode under way goes on
            assert status == 200 and answer["level"] == "1-1" and answer["step"] >= 2, answer
        status, answer = _post(address, "/api/reset", {"level": "1-2"})  # and other levels still open
        assert status == 200 and answer["level"] == "1-2" and answer["step"] == 0
    finally:
        httpd.shutdown()
        httpd.server_close()
        httpd.session.close()


# ------------------------------------------------------------------------------------------------ 4. checkpoints
def _crafted(path: Path, plain) -> Path:
    """A checkpoint file holding ``plain`` as its state, with a valid checksum (as someone crafting it would)."""
    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(50_000)  # the checksum of a deep state recurses; the crafter's machine allows it
    try:
        envelope = {"evaaa_checkpoint": checkpoint.FILE_FORMAT, "checksum": checkpoint.checksum(plain), "state": plain}
        torch.save(envelope, path)
    finally:
        sys.setrecursionlimit(limit)
    return path


def _deep(depth: int) -> list:
    deep: list = []
    for _ in range(depth):
        deep = [deep]
    return deep


def _array(dtype: str, shape: list, size: int) -> dict:
    return {"__evaaa_type__": "ndarray", "dtype": dtype, "shape": shape, "bytes": torch.zeros(size, dtype=torch.uint8)}


CRAFTED = {
    "5,000-deep nesting": ({"steps": _deep(5000)}, "nests deeper than 100 levels"),
    "object-dtype array": ({"a": _array("|O", [1], 8)}, "an array of Python objects"),
    "huge array shape": ({"a": _array("<f4", [10**6, 10**6], 4)}, "an array's bytes do not fit its shape"),
    "negative array shape": ({"a": _array("<f4", [-1], 4)}, "is not a list of non-negative integers"),
    "negative batch size": (
        {"td": {"__evaaa_type__": "tensordict", "batch_size": [-3], "device": None, "items": {}}},
        "a tensordict's batch size [-3] is not a list of non-negative integers",
    ),
    "items beside the batch size": (
        {"td": {"__evaaa_type__": "tensordict", "batch_size": [5], "device": None, "items": {"x": torch.zeros(3)}}},
        "is malformed: RuntimeError",
    ),
    "NaN weights": ({"model": {"w": torch.tensor([1.0, float("nan")])}}, "its network's w holds NaN or infinite"),
}


@pytest.mark.parametrize("case", list(CRAFTED))
def test_a_crafted_checkpoint_with_a_valid_checksum_is_refused_naming_the_file(tmp_path, case):
    plain, message = CRAFTED[case]
    path = _crafted(tmp_path / "checkpoint.pt", plain)
    with pytest.raises(checkpoint.CheckpointError) as info:
        checkpoint.load_checkpoint(path)
    assert str(info.value).startswith(str(path)) and "\n" not in str(info.value)
    assert message in str(info.value), str(info.value)


def test_a_deep_latest_checkpoint_falls_back_to_the_previous_one(tmp_path):
    checkpoint.save_checkpoint({"counters": {"steps": 64}}, tmp_path / checkpoint.PREVIOUS)
    _crafted(tmp_path / checkpoint.CHECKPOINT, {"counters": {"steps": _deep(5000)}})
    state, path, note = checkpoint.load_latest(tmp_path)
    assert path == tmp_path / checkpoint.PREVIOUS and state["counters"]["steps"] == 64
    assert "nests deeper than 100 levels" in note and "env step 64" in note


def _policy_state(**algo_changes) -> dict:
    """What a PPO run on interoception alone saves as a model file, its network built from its own config."""
    register_levels()
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        cfg = compose("config", overrides=["algo=ppo", "modality=no_vision"])
    algo_cfg = OmegaConf.to_container(cfg.algo, resolve=True)
    shapes = {"interoception": [4], "olfaction": [10], "thermoception": [8], "collision": [10]}
    model = algorithm("ppo").make_model(cfg.algo, {k: tuple(v) for k, v in shapes.items()})
    algo_cfg.update(algo_changes)
    return {
        "format": checkpoint.CHECKPOINT_FORMAT,
        "algo": "ppo",
        "config": {"algo": algo_cfg},
        "obs_keys": list(shapes),
        "obs_shapes": shapes,
        "model": model.state_dict(),
        "level": "1-1",
        "modalities": list(shapes),
        "env_overrides": {},
    }


def test_a_policy_whose_weights_do_not_fit_its_config_or_are_not_finite_is_refused(tmp_path):
    path = tmp_path / "model-0-1-1.pt"
    checkpoint.save_checkpoint(_policy_state(), path)
    assert load_policy(path).algo == "ppo"  # the file as written loads
    state = _policy_state()
    key = next(iter(state["model"]))
    state["model"][key] = torch.zeros(3, 3)
    checkpoint.save_checkpoint(state, path)
    with pytest.raises(checkpoint.CheckpointError, match=rf"^{path} is malformed: its config's network has {key} "):
        load_policy(path)
    # a network of 10^6 x 10^6 units per head layer (4 TB): refused by its shapes, before any allocation
    checkpoint.save_checkpoint(_policy_state(head={"units": [10**6, 10**6], "layer_norm": False}), path)
    start = time.monotonic()
    with pytest.raises(checkpoint.CheckpointError, match="its config's network has .* its weights"):
        load_policy(path)
    assert time.monotonic() - start < HANG_SECONDS
    state = _policy_state()
    state["model"][key] = torch.full_like(state["model"][key], float("inf"))
    checkpoint.save_checkpoint(state, path)
    with pytest.raises(checkpoint.CheckpointError, match="holds NaN or infinite values"):
        load_policy(path)


def test_evaluate_refuses_a_nan_network_in_one_line(tmp_path, capsys):
    state = _policy_state()
    for tensor in state["model"].values():
        if tensor.is_floating_point():
            tensor.fill_(float("nan"))
    path = tmp_path / "model-0-1-1.pt"
    checkpoint.save_checkpoint(state, path)
    out = tmp_path / "eval"
    with pytest.raises(SystemExit) as info:
        load_script("evaluate").main([f"policy=[{path}]", "levels=[two-resource-food]", "episodes=1", f"out={out}"])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "holds NaN or infinite values" in err[0] and str(path) in err[0]
    assert not (out / "episodes.csv").exists()


def test_resuming_from_a_checkpoint_with_an_incomplete_record_is_refused_naming_it(tmp_path):
    register_levels()
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        cfg = compose("config", overrides=["algo=ppo", "preset=debug", "resume=true"])
    checkpoint.save_checkpoint(
        {"format": checkpoint.CHECKPOINT_FORMAT, "algo": "ppo"}, tmp_path / checkpoint.CHECKPOINT
    )
    with pytest.raises(checkpoint.CheckpointError) as info:
        training._decide(cfg, tmp_path, stages(cfg))
    message = str(info.value)
    assert "\n" not in message and f"{tmp_path / checkpoint.CHECKPOINT} is malformed" in message
    assert "nothing was changed" in message


# ------------------------------------------------------------------------------------------------ 5. slow clients
class _QuickSession:
    """Stands in for the play session: answers at once."""

    def state(self):
        return {"step": 0}

    def step(self, action):
        return {"step": 1}


def test_clients_trickling_their_bodies_hold_no_request_slot(monkeypatch):
    monkeypatch.setattr(play, "REQUEST_DEADLINE", 1.5, raising=False)  # fails, not errs, without it
    monkeypatch.setattr(play, "MAX_REQUESTS", 2)
    httpd = play.PlayServer("127.0.0.1", 0, b"<html></html>")
    httpd.session = _QuickSession()
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    address = httpd.server_address[:2]
    host = f"127.0.0.1:{address[1]}"
    answers: list[bytes] = []

    def trickle():  # one body byte every 0.3 s: never silent for the idle timeout (10 s)
        with socket.create_connection(address) as sock:
            sock.settimeout(30)
            sock.sendall(f"POST /api/step HTTP/1.1\r\nHost: {host}\r\nContent-Length: 100\r\n\r\n".encode())
            try:
                for byte in b'{"action": 1}' + b" " * 87:
                    sock.sendall(bytes([byte]))
                    time.sleep(0.3)
            except OSError:  # the server answered and closed
                pass
            answers.append(sock.recv(4096))

    trickling = [threading.Thread(target=trickle) for _ in range(4)]
    try:
        for thread in trickling:
            thread.start()
        time.sleep(0.5)  # every slot would be held by now
        for _ in range(3):  # others are answered while the trickling goes on
            connection = http.client.HTTPConnection(*address, timeout=10)
            connection.request("GET", "/api/state")
            assert connection.getresponse().status == 200
            connection.close()
        start = time.monotonic()
        for thread in trickling:
            thread.join(timeout=30)
        assert time.monotonic() - start < 10  # each was cut off at its deadline, not after its 30 s of trickling
        assert len(answers) == 4 and all(b" 408 " in a[:20] for a in answers), answers
    finally:
        httpd.shutdown()
        httpd.server_close()


# ------------------------------------------------------------------------------------------------ 5. predator planning
_AUDIT_PLANNING = """extends: "1-1"
arena: {size: [1000, 1000]}
landmarks: {pattern: [[1, 0], [0, 1]]}
predators:
  pack: {count: 50, x: [-400, 400], y: [-400, 400], search_interval: 1}
obstacles:
  rocks: {kind: rock, count: 1000, x: [-490, 490], y: [-490, 490]}
"""


def test_a_level_whose_predators_would_plan_for_seconds_a_step_is_refused_at_load(tmp_path):
    """The audit's level (20-38 s a step) is refused before anything is built, in one line naming the fields and
    the limit; the same arena with one predator searching every 60 decisions (2.2e5 cells a decision) loads."""
    path = level_file(tmp_path, _AUDIT_PLANNING)
    started = time.process_time()
    with pytest.raises(LevelError) as refused:
        evaaa.make_env(str(path))
    assert time.process_time() - started < HANG_SECONDS
    (line,) = str(refused.value).splitlines()[1:]  # "invalid level '...':" then the one rule it breaks
    assert "predators plan routes over 6e+07 grid cells a decision" in line
    for named in ("arena.size 1000 x 1000", "search_interval", "count", "pack: count 50, search_interval 1"):
        assert named in line, named
    assert line.endswith("at most 1e+06: a smaller arena, fewer predators or a longer search_interval")
    one = level_file(
        tmp_path, _AUDIT_PLANNING.replace("count: 50", "count: 1").replace("interval: 1}", "interval: 60}")
    )
    assert load_level(one).predators["pack"].count == 1


def test_every_packaged_level_and_testbed_plans_within_the_bound():
    from evaaa.level_limits import MAX_PLANNING_WORK, REPLAN_EVERY

    for name in evaaa.LEVELS + evaaa.TESTBEDS:
        level = load_level(name)
        cells = level.arena.size[0] * level.arena.size[1]
        work = cells * sum(g.count * (1 / g.search_interval + 1 / REPLAN_EVERY) for g in level.predators.values())
        assert work <= MAX_PLANNING_WORK / 100, (name, work)  # far inside it: 4-1, the largest, needs 6.4e3


# ------------------------------------------------------------------------------------------------ 8. low items
@pytest.mark.parametrize(
    "text, message",
    [
        ("resources:\n  food: {count: 010}\n", "count: '010' is octal in YAML 1.1 (8) and 10 in YAML 1.2"),
        ("agent: {mass: 1:30}\n", "mass: '1:30' is a base-60 number in YAML 1.1 (90) and text in YAML 1.2"),
        ("episode:\n  max_steps: 1:00:00\n", "max_steps: '1:00:00' is a base-60 number in YAML 1.1 (3600)"),
        ("arena: {size: [0b1010, 20]}\n", "size[0]: '0b1010' is binary in YAML 1.1 (10)"),
        ("arena: {walls: off}\n", "walls: 'off' is false in YAML 1.1 and text in YAML 1.2; write true or false"),
        ("episode: {max_steps: " + "9" * 5000 + "}\n", "max_steps: an integer of 5000 digits"),
        ("<<: {description: a}\n<<: {description: b}\n", "the merge key << is repeated (the last would silently win)"),
    ],
    ids=["octal", "base-60", "base-60 hours", "binary", "yes-no flag", "huge integer", "two merge keys"],
)
def test_yaml_1_1_forms_huge_integers_and_repeated_merge_keys_are_refused_naming_the_field(tmp_path, text, message):
    path = level_file(tmp_path, 'extends: "1-1"\n' + text)
    with pytest.raises(LevelError) as refused:
        load_level(path)
    (line,) = str(refused.value).splitlines()
    assert line.startswith(f"level file '{path}': ") and message in line and "(line " in line, line


def test_yaml_1_2_forms_and_quoted_text_still_read():
    from evaaa.level_files import parse_level_text

    text = b"a: 10\nb: 0x1f\nc: 1_000\nd: '010'\ne: '1:30'\nf: true\ng: 1.5e3\nh: 0\ni: [0, 7]\nj: 'yes'\n"
    assert parse_level_text(text, "f.yaml") == {
        **{"a": 10, "b": 31, "c": 1000, "d": "010", "e": "1:30", "f": True, "g": 1500.0, "h": 0, "i": [0, 7]},
        "j": "yes",
    }


def test_an_extends_chain_of_a_thousand_files_is_refused_in_one_line(tmp_path):
    for i in range(1000):
        (tmp_path / f"c{i}.yaml").write_text(f"extends: c{i + 1}.yaml\n")
    (tmp_path / "c1000.yaml").write_text('extends: "1-1"\n')
    with pytest.raises(LevelError) as refused:  # was a RecursionError
        load_level(tmp_path / "c0.yaml")
    (line,) = str(refused.value).splitlines()
    assert "its extends: chain is longer than 32 files" in line and line.endswith(f"at '{tmp_path / 'c32.yaml'}'")
    assert load_level(tmp_path / "c975.yaml").name == "c975"  # 26 files and 1-1's chain: within the limit


def test_a_fifo_in_the_level_dir_is_refused_naming_it(tmp_path):
    level_file(tmp_path, 'extends: "1-1"\n', "r3-fine.yaml")
    os.mkfifo(tmp_path / "r3-pipe.yaml")  # was skipped without a word
    started = time.monotonic()
    with pytest.raises(LevelError, match=rf"level file '{tmp_path / 'r3-pipe.yaml'}' cannot be read: not a regular"):
        play.register_level_dir(tmp_path)
    assert time.monotonic() - started < HANG_SECONDS


def test_a_request_with_two_host_headers_is_refused():
    httpd = play.PlayServer("127.0.0.1", 0, b"<html></html>")
    httpd.session = _QuickSession()
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    address = httpd.server_address[:2]
    own = f"127.0.0.1:{address[1]}"
    try:
        for hosts, status in (([own], 200), ([own, "evil.example"], 400), (["evil.example", own], 400)):
            with socket.create_connection(address) as sock:
                sock.settimeout(10)
                head = "".join(f"Host: {h}\r\n" for h in hosts)
                sock.sendall(f"GET /api/state HTTP/1.1\r\n{head}Connection: close\r\n\r\n".encode())
                answer = b""
                while chunk := sock.recv(4096):  # to the end: the server closes the connection
                    answer += chunk
                answer = answer.decode()
            assert answer.startswith(f"HTTP/1.0 {status} ") or answer.startswith(f"HTTP/1.1 {status} "), answer
            if status == 400:
                assert "refused: 2 Host headers; a request names its server once" in answer
    finally:
        httpd.shutdown()
        httpd.server_close()
