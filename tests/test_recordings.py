"""The recordings that prove a restructuring changes nothing (scripts/record_trajectories.py, scripts/record_runs.py):
a recording compares equal to a rerun of the same code, and a difference — in the code or in the recording — is
reported with its level (or run), step and key, and exit status 1."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import load_script

from evaaa_baselines.recordings import REPO, first_difference

TINY = ["levels=[1-1]", "steps=12", "snapshot_at=6"]


def run(module, *args: str) -> int:
    try:
        return module.main(list(args))
    except SystemExit as exit_:
        return exit_.code


def test_first_difference_is_bitwise_for_floats_unless_a_tolerance_is_given():
    a = np.zeros((3, 2), np.float32)
    b = a.copy()
    assert first_difference(a, b) is None
    b[2, 1] = -0.0  # equal as numbers, not as bits
    assert first_difference(a, b).index == (2, 1)
    b[1, 0] = 1e-6
    found = first_difference(a, b)
    assert found.index == (1, 0) and found.recorded == 0.0 and found.now == pytest.approx(1e-6)
    assert first_difference(a, b, atol=1e-5) is None
    assert "dtype" in str(first_difference(a, b.astype(np.float64)))
    assert first_difference(np.array([1, 2]), np.array([1, 3])).index == (1,)


def test_a_trajectory_recording_equals_a_rerun_and_a_difference_is_named(tmp_path, capsys, monkeypatch):
    script = load_script("record_trajectories")
    rec = tmp_path / "rec"
    assert run(script, *TINY, f"out={rec}") == 0
    assert sorted(p.name for p in rec.iterdir()) == ["1-1.npz", "1-1.snapshot.pt", "manifest.json"]
    with np.load(rec / "1-1.npz") as data:
        assert data["next/pixels"].shape == (12, 2, 64, 64, 3) and "next/info/damage_taken" in data
    capsys.readouterr()
    assert run(script, f"compare={rec}") == 0
    assert capsys.readouterr().out.startswith("1-1: identical (12 steps x 2 worlds")

    # the code changes: every reward from the 8th step on is a little larger
    import evaaa.env

    step = evaaa.env.EvaaaEnv._step
    calls = []

    def bumped(self, td):
        out = step(self, td)
        calls.append(1)
        if len(calls) > 7:
            out["reward"] = out["reward"] + 1e-4
        return out

    monkeypatch.setattr(evaaa.env.EvaaaEnv, "_step", bumped)
    assert run(script, f"compare={rec}") == 1
    out = capsys.readouterr().out
    assert out.startswith("1-1: step 7, key next/reward, world 0, at [0]: recorded "), out
    calls.clear()
    assert run(script, f"compare={rec}", "atol=1e-3") == 0  # within the tolerance asked for
    monkeypatch.undo()

    # the recording changes: one pixel of world 1 at step 9
    with np.load(rec / "1-1.npz") as data:
        arrays = dict(data)
    arrays["next/pixels"][9, 1, 30, 31, 2] ^= 1
    np.savez_compressed(rec / "1-1.npz", **arrays)
    capsys.readouterr()
    assert run(script, f"compare={rec}") == 1
    assert capsys.readouterr().out.startswith("1-1: step 9, key next/pixels, world 1, at [30, 31, 2]: recorded ")


def test_trajectory_recordings_are_refused_inside_the_repository_and_over_another(tmp_path, capsys):
    script = load_script("record_trajectories")
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("")
    for args, message in [
        ([f"out={REPO / 'docs' / 'recordings'}"], "inside the repository; recordings are large"),
        ([f"out={tmp_path / 'full'}"], "already holds files"),
        ([f"compare={tmp_path}", "steps=5"], "steps=: compare= replays the recording's own"),
        (["snapshot_at=400"], "snapshot_at=400: expected a step below steps (300)"),
    ]:
        assert run(script, *args) == 2
        err = capsys.readouterr().err
        assert err.startswith("record_trajectories.py: error: ") and err.count("\n") == 1 and message in err, err


def test_a_run_recording_equals_a_rerun_and_a_difference_is_named(tmp_path, capsys, monkeypatch):
    script = load_script("record_runs")
    rec, kept = tmp_path / "rec", tmp_path / "kept"
    assert run(script, "runs=[ppo]", f"out={rec}") == 0
    files = {p.relative_to(rec / "ppo" / "files").as_posix() for p in (rec / "ppo" / "files").rglob("*.csv")}
    assert {"episodes.csv", "eval.csv", "logs/scalars/train/loss_objective.csv"} <= files
    with np.load(rec / "ppo" / "checkpoints.npz") as data:
        weights = [k for k in data if k.startswith("model-0-1-1.pt:model/")]
    assert weights
    capsys.readouterr()
    # a second training of the same seed (in the same process, after the first) is the same, clocks left out
    assert run(script, f"compare={rec}", f"keep={kept}") == 0
    assert capsys.readouterr().out.startswith("ppo: identical")

    # later differences, without training again: the compared run is the kept one
    monkeypatch.setattr(script, "train_run", lambda overrides, run_dir: None)
    eval_csv = rec / "ppo" / "files" / "eval.csv"
    rows = eval_csv.read_text().splitlines()
    header = rows[0].split(",")
    cells = rows[2].split(",")
    cells[header.index("wall_time")] = "1999-01-01T00:00:00"  # a clock: not compared
    eval_csv.write_text("\n".join([*rows[:2], ",".join(cells), *rows[3:]]) + "\n")
    assert run(script, f"compare={rec}", f"keep={kept}") == 0
    cells[header.index("return")] = "12345"
    eval_csv.write_text("\n".join([*rows[:2], ",".join(cells), *rows[3:]]) + "\n")
    capsys.readouterr()
    assert run(script, f"compare={rec}", f"keep={kept}") == 1
    assert capsys.readouterr().out.startswith("ppo: eval.csv row 3 column return: recorded '12345', now ")

    eval_csv.write_text("\n".join(rows) + "\n")
    with np.load(rec / "ppo" / "checkpoints.npz") as data:
        arrays = dict(data)
    arrays[weights[0]].reshape(-1)[3] += 1.0
    np.savez_compressed(rec / "ppo" / "checkpoints.npz", **arrays)
    assert run(script, f"compare={rec}", f"keep={kept}") == 1
    out = capsys.readouterr().out
    assert out.startswith(f"ppo: {weights[0]} at [") and "recorded" in out, out


def test_a_replay_storage_is_compared_in_the_rows_written():
    """A checkpoint saves a replay storage whole; past its ``_len`` the rows are uninitialised memory."""
    script = load_script("record_runs")
    key = "checkpoint.pt:components/buffer/_storage/_storage/action"
    plain = {"checkpoint.pt:components/buffer/_storage/_len": 4}
    recorded = np.arange(8)
    now = recorded.copy()
    now[6] = 12345  # never written
    assert script.difference(({}, {key: recorded}, plain), ({}, {key: now}, plain)) is None
    now[2] = -1
    found = script.difference(({}, {key: recorded}, plain), ({}, {key: now}, plain))
    assert found == f"{key} at [2]: recorded 2, now -1"
