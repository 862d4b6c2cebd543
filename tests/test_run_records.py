"""Runs and results as records nobody's work is lost from: checkpoint files hold only tensors and plain data (a
crafted file cannot run code), carry a checksum, keep the previous one; a command that would change an existing run
is refused before it writes anything (Hydra's files included), or moves the old run aside on request; presets never
share a run folder; Ctrl-C stops a run in one line with a checkpoint that ``resume=true`` continues; an evaluation
never appends to an earlier one."""

from __future__ import annotations

import logging
import os
import random
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers import load_script
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf
from tensordict import TensorDict

from evaaa_baselines import checkpoint, load_policy
from evaaa_baselines.checkpoint import CheckpointError, load_checkpoint, load_latest, save_checkpoint
from evaaa_baselines.config import register_levels
from evaaa_baselines.evaluation import EvaluatedPolicy, EvaluationError
from evaaa_baselines.paths import CONF_DIR
from evaaa_baselines.training import RunExists, train

register_levels()

ROOT = Path(__file__).resolve().parents[1]
TRAIN = [sys.executable, str(ROOT / "scripts" / "train.py")]


def make_cfg(*overrides: str):
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        return compose("config", overrides=list(overrides))


def debug_cfg(*extra: str):
    # one torch thread, as tests/test_dreamer.py: tiny networks, and the suite's workers share the cores
    return make_cfg("algo=ppo", "preset=debug", "logger=csv", "progress=false", "threads=1", "total_steps=64", *extra)


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (hidden ones included) with its bytes."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def zero_inside(path: Path, tensor: torch.Tensor, count: int = 1024) -> None:
    """Overwrite ``count`` bytes of ``tensor``'s data inside the checkpoint file ``path`` with zeros."""
    data = bytearray(path.read_bytes())
    start = data.find(tensor.detach().contiguous().numpy().tobytes()[:256])
    assert start >= 0, "the tensor's bytes are stored as they are"
    data[start + 256 : start + 256 + count] = bytes(count)
    path.write_bytes(bytes(data))


# ------------------------------------------------------------------------------------------------ checkpoint files
def test_a_checkpoint_gives_back_numpy_arrays_tensordicts_rng_states_and_metadata(tmp_path):
    td = TensorDict({"obs": torch.randn(2, 3), "next": {"reward": torch.ones(2, 1)}}, batch_size=[2])
    td.set_non_tensor("note", "kept")
    module_state = torch.nn.BatchNorm1d(3).state_dict()  # an OrderedDict with a _metadata attribute (its version)
    dtypes = ("uint32", "float16", "bool", "int64")
    state = {
        "arrays": {dt: (np.arange(6) % 3).astype(dt).reshape(2, 3) for dt in dtypes},
        "scalar": np.float32(0.25),
        "td": td,
        "rng": checkpoint.rng_state(),
        "bn": module_state,
        "config": OmegaConf.create({"algo": {"lr": 1e-4}}),
        "big": 2**100,
        "pair": (1, None),
    }
    path = tmp_path / "state.pt"
    save_checkpoint(state, path)
    back = load_checkpoint(path, map_location=torch.device("cpu"))
    for name, array in state["arrays"].items():
        assert back["arrays"][name].dtype == array.dtype and np.array_equal(back["arrays"][name], array)
    assert type(back["scalar"]) is np.float32 and back["scalar"] == np.float32(0.25)
    assert back["td"].batch_size == (2,) and torch.equal(back["td"]["next", "reward"], td["next", "reward"])
    assert back["td"]["note"] == "kept"
    assert back["rng"]["python"] == state["rng"]["python"] and np.array_equal(
        back["rng"]["numpy"][1], state["rng"]["numpy"][1]
    )
    assert back["bn"]._metadata == module_state._metadata
    assert back["config"] == {"algo": {"lr": 1e-4}} and back["big"] == 2**100 and back["pair"] == (1, None)
    with pytest.raises(TypeError, match=r"state\.fn: .*cannot be stored"):
        save_checkpoint({"fn": len}, tmp_path / "other.pt")


def test_zeroed_bytes_and_truncation_are_detected_and_the_previous_checkpoint_is_used(tmp_path):
    weights = [torch.randn(16, 3, 8, 8, generator=torch.Generator().manual_seed(i)) for i in range(2)]
    latest, previous = tmp_path / checkpoint.CHECKPOINT, tmp_path / checkpoint.PREVIOUS
    for step, w in enumerate(weights, 1):
        save_checkpoint({"model": {"conv.weight": w}, "counters": {"steps": step}}, latest, keep_previous=True)
    assert load_checkpoint(previous)["counters"] == {"steps": 1}

    zero_inside(latest, weights[1])
    with pytest.raises(CheckpointError, match=re.escape(str(latest)) + " is damaged"):
        load_checkpoint(latest)
    state, used, note = load_latest(tmp_path)
    assert used == previous and torch.equal(state["model"]["conv.weight"], weights[0])
    assert str(latest) in note and "previous" in note

    latest.write_bytes(latest.read_bytes()[:3000])  # cut short, as by a full disk
    with pytest.raises(CheckpointError, match=re.escape(str(latest)) + " is unreadable"):
        load_checkpoint(latest)
    assert load_latest(tmp_path)[1] == previous
    zero_inside(previous, weights[0])
    with pytest.raises(CheckpointError, match="no usable checkpoint"):
        load_latest(tmp_path)


class Payload:
    """Unpickling this runs code: it creates ``marker``."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return exec, (f"open({str(self.marker)!r}, 'w').close()",)


def test_a_crafted_checkpoint_cannot_run_code(tmp_path, capsys):
    marker, path = tmp_path / "marker", tmp_path / "model-0-1-1.pt"
    torch.save({"evaaa_checkpoint": 1, "checksum": "", "state": {"format": 2, "model": Payload(marker)}}, path)
    with pytest.raises(CheckpointError, match=re.escape(str(path)) + " is refused"):
        load_checkpoint(path)
    with pytest.raises(ValueError, match="is refused"):
        load_policy(path)
    with pytest.raises(EvaluationError, match="is refused"):
        EvaluatedPolicy(str(path), seed=0)
    with pytest.raises(SystemExit) as refused:  # evaluate.py says so in one line
        load_script("evaluate").main([f"policy={path}", f"out={tmp_path / 'eval'}"])
    assert refused.value.code == 2 and "is refused" in capsys.readouterr().err
    assert not marker.exists()
    torch.load(path, weights_only=False)  # the file is a real attack: a trusting loader runs it
    assert marker.exists()


# ------------------------------------------------------------------------------------------------ run directories
@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """A finished smoke run (64 env steps) made by scripts/train.py, so that Hydra's own files are there too."""
    root = tmp_path_factory.mktemp("runs")
    cmd = [*TRAIN, "algo=ppo", "preset=debug", "logger=csv", "progress=false", "total_steps=64", "threads=1"]
    cmd.append(f"run.root={root}")
    done = subprocess.run(cmd, cwd=root, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    run_dir = root / "1-1" / "ppo" / "all-squared-debug" / "seed0"
    assert {".hydra/config.yaml", ".hydra/overrides.yaml", "train.log", "model-0-1-1.pt"} <= set(snapshot(run_dir))
    return cmd, root, run_dir


def test_refused_training_commands_leave_every_file_of_the_run_as_it_was(finished, tmp_path):
    cmd, root, run_dir = finished
    before = snapshot(run_dir)
    refused = [
        (["eval.episodes=3"], "already holds a run (checkpoint.pt)"),  # the same folder, whatever the settings
        (["resume=true", "modality=no_vision", "run.name=1-1/ppo/all-squared-debug/seed0"], "another experiment"),
    ]
    for extra, message in refused:
        done = subprocess.run([*cmd, *extra], cwd=root, capture_output=True, text=True, timeout=300)
        assert done.returncode == 1 and message in done.stderr, done.stderr[-3000:]
        assert "Traceback" not in done.stderr and len(done.stderr.strip().splitlines()) == 1
        assert snapshot(run_dir) == before, extra
    assert [p.name for p in run_dir.parent.iterdir()] == ["seed0"]


def test_a_run_without_its_checkpoint_is_not_wiped_by_resume(finished, tmp_path):
    cmd, root, _ = finished
    copy = tmp_path / "copy"
    subprocess.run(["cp", "-a", str(root), str(copy)], check=True)
    run_dir = copy / "1-1" / "ppo" / "all-squared-debug" / "seed0"
    (run_dir / checkpoint.CHECKPOINT).unlink()  # deleted to save space
    before = snapshot(run_dir)
    with pytest.raises(RunExists, match="no checkpoint .*start_over=true"):
        train(debug_cfg("resume=true"), run_dir)
    with pytest.raises(RunExists, match="already holds a run's results"):
        train(debug_cfg(), run_dir)
    assert snapshot(run_dir) == before


def test_start_over_moves_the_old_run_aside_and_says_where(finished, tmp_path, caplog):
    _, root, _ = finished
    copy = tmp_path / "copy"
    subprocess.run(["cp", "-a", str(root), str(copy)], check=True)
    run_dir = copy / "1-1" / "ppo" / "all-squared-debug" / "seed0"
    before = snapshot(run_dir)
    with caplog.at_level(logging.INFO, logger="evaaa_baselines.training"):
        train(debug_cfg("start_over=true", "total_steps=32"), run_dir)
    aside = [p for p in run_dir.parent.iterdir() if p.name != "seed0"]
    assert len(aside) == 1 and aside[0].name.startswith(".seed0.replaced-") and str(aside[0]) in caplog.text
    assert snapshot(aside[0]) == before
    assert load_checkpoint(run_dir / checkpoint.CHECKPOINT)["counters"]["steps"] == 32


def test_presets_never_share_a_run_folder():
    presets = sorted(p.stem for p in (CONF_DIR / "preset").glob("*.yaml"))
    names = {make_cfg(f"preset={p}").run.name for p in presets}
    assert len(presets) >= 2 and len(names) == len(presets)
    assert make_cfg("preset=none").run.name == "1-1/ppo/all-squared/seed0"


# ------------------------------------------------------------------------------------------------ interrupts
def interrupt(cmd: list[str], cwd: Path, ready, delay: float) -> subprocess.CompletedProcess:
    """Start ``cmd``, wait until ``ready()`` and ``delay`` seconds more, send SIGINT, and collect what it printed."""
    proc = subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 240
    while not ready() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(delay)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=240)
    return subprocess.CompletedProcess(cmd, proc.returncode, out, err)


@pytest.mark.slow  # two training processes: about a minute on a busy 2-core box
def test_ctrl_c_while_training_leaves_a_checkpoint_that_resume_continues(tmp_path):
    rng = random.Random(os.getpid())  # a different moment on each run of the suite
    cmd = [
        *TRAIN,
        "algo=ppo",
        "preset=debug",
        "logger=csv",
        "progress=false",
        "total_steps=100000",
        "threads=1",
        f"run.root={tmp_path}",
    ]
    run_dir = tmp_path / "1-1" / "ppo" / "all-squared-debug" / "seed0"
    delay = rng.uniform(0.0, 3.0)
    done = interrupt(cmd, tmp_path, lambda: (run_dir / "episodes.csv").exists(), delay)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 130 and "Traceback" not in done.stderr + done.stdout, (delay, done.stderr[-3000:])
    assert len(lines) == 1 and lines[0].startswith("train.py: interrupted at env step"), (delay, done.stderr)
    steps = int(re.search(r"env step ([\d,]+)", lines[0]).group(1).replace(",", ""))
    assert load_checkpoint(run_dir / checkpoint.CHECKPOINT)["counters"]["steps"] == steps

    resumed = subprocess.run(
        [*cmd[:-2], f"total_steps={steps + 64}", "resume=true", cmd[-1]],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert f"resuming {run_dir} from checkpoint.pt at stage 0 (1-1), env step {steps}" in resumed.stdout
    assert load_checkpoint(run_dir / checkpoint.CHECKPOINT)["counters"]["steps"] >= steps + 64


@pytest.mark.slow  # DreamerV3 size S on the CPU: a minute or two on a busy 2-core box
def test_a_second_ctrl_c_stops_a_dreamer_s_run_within_seconds_inside_a_gradient_step(tmp_path):
    # one world and a 64-step prefill: once the first gradient step is logged (with its duration), the second is
    # under way within milliseconds, and both Ctrl-Cs arrive inside it, where Python runs no handler until it ends
    cmd = [
        *TRAIN,
        "algo=dreamer",
        "device=cpu",
        "env.num_envs=1",
        "algo.learning_starts=64",
        "logger=csv",
        "progress=false",
        "eval.every=0",
        "threads=1",
        "total_steps=100000",
        f"run.root={tmp_path}",
    ]
    log = tmp_path / "1-1" / "dreamer" / "all-squared" / "seed0" / "train.log"
    proc = subprocess.Popen(cmd, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline, first = time.monotonic() + 600, None
    while first is None and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.1)
        first = (
            re.search(r"first gradient step at env step [\d,]+: ([\d.]+) s", log.read_text()) if log.exists() else None
        )
    assert first is not None, "no gradient step was logged"
    step = float(first.group(1))  # what one gradient step takes here
    time.sleep(0.5)
    proc.send_signal(signal.SIGINT)
    time.sleep(2.0)
    proc.send_signal(signal.SIGINT)
    sent = time.monotonic()
    try:
        out, err = proc.communicate(timeout=300)
    finally:
        proc.kill()
    took = time.monotonic() - sent
    # within 10 s, and (where a gradient step is long enough to tell) without waiting for the one under way to end
    assert proc.returncode == 130 and took < 10 and (step < 8 or took < step - 4), (took, step, err[-3000:])
    assert "Ctrl-C: stopping after the gradient step under way" in out  # the first said what it waits for
    assert err.strip().splitlines()[-1].startswith("train.py: stopped at once"), err[-3000:]


def test_ctrl_c_before_training_stops_in_one_line_and_writes_nothing(tmp_path):
    cmd = [*TRAIN, "algo=ppo", "preset=debug", "logger=csv", f"run.root={tmp_path}"]
    started = time.monotonic()
    done = interrupt(cmd, tmp_path, lambda: time.monotonic() - started > 1.0, 0.0)  # still importing torch
    assert done.returncode == 130 and "Traceback" not in done.stderr, done.stderr[-3000:]
    assert done.stderr.strip().splitlines() == ["train.py: interrupted while no run was training; nothing was lost"]
    assert not list(tmp_path.iterdir())


def test_resume_with_no_checkpoint_yet_starts_from_zero_and_says_so(tmp_path, caplog):
    run_dir = tmp_path / "run"
    (run_dir / ".hydra").mkdir(parents=True)
    (run_dir / "train.log").write_text("started\n")
    (run_dir / "episodes.csv").write_text("env_steps,stage\n")  # stopped before any episode and checkpoint
    with caplog.at_level(logging.INFO, logger="evaaa_baselines.training"):
        train(debug_cfg("resume=true", "total_steps=32"), run_dir)
    assert "holds no checkpoint yet: starting from zero" in caplog.text
    assert (run_dir / "train.log").read_text() == "started\n"


# ------------------------------------------------------------------------------------------------ evaluations
def test_evaluating_twice_into_one_folder_is_refused_and_changes_nothing(tmp_path):
    script = load_script("evaluate")
    out = tmp_path / "eval"
    args = ["policy=random", "levels=[two-resource-food]", "episodes=2", "num_envs=2", f"out={out}"]
    out.mkdir()
    (out / ".episodes.csv.partial").write_text("left by an interrupted evaluation\n")
    assert script.main(args) == 0
    assert not (out / ".episodes.csv.partial").exists()
    before = snapshot(out)
    assert len(before["episodes.csv"].decode().strip().splitlines()) == 1 + 2
    with pytest.raises(SystemExit, match=re.escape(str(out)) + r" already holds an evaluation \(episodes.csv"):
        script.main(args)
    assert snapshot(out) == before
