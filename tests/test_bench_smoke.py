"""bench_env.py runs end to end and reports every figure (speed itself is never asserted in tests)."""

from __future__ import annotations

import json

import pytest
from helpers import load_script

from evaaa.sim import default_threads


def load_bench():
    return load_script("bench_env")


def test_bench_reports_ratios_reset_cost_and_memory(tmp_path):
    out = tmp_path / "bench.json"
    code = load_bench().main(
        ["steps=80", "num_envs=2", "resets=2", "memory_steps=2000", "skip_parallel=true", "peer=false", f"json={out}"]
    )
    assert code == 0
    figures = json.loads(out.read_text())
    names = [row["setting"] for row in figures["settings"]]
    # each setting is measured with its default and the other way
    other = "one thread" if default_threads() > 1 else "2 threads"
    assert names == ["1 env", f"1 env, {other}", "num_envs=2 (1 process)", f"num_envs=2 (1 process), {other}"]
    threads = [row["threads"] for row in figures["settings"]]
    assert set(threads[:2]) == {1, 2} and set(threads[2:]) == {1, 2}
    floor = figures["torchrl_floor"]  # TorchRL's own step path bounds what one env can keep of raw
    raw_s, idle_s = floor["raw_seconds_per_step"], floor["seconds_per_step"]
    assert floor["ceiling_ratio_1_env"] == pytest.approx(raw_s / (raw_s + idle_s))
    assert 0 < floor["ceiling_ratio_1_env"] < 1
    one_env = figures["settings"][threads.index(1)]
    assert floor["seconds_per_step"] < 1 / one_env["env_steps_per_s"]  # doing nothing is faster than simulating
    for row in figures["settings"]:
        assert row["env_steps_per_s"] > 0 and row["raw_steps_per_s"] > 0
        assert row["ratio"] == pytest.approx(row["env_steps_per_s"] / row["raw_steps_per_s"])
        assert 0 < row["cores"] < 4
        assert row["ratio_per_core"] == pytest.approx(row["ratio"] / row["cores"])
    assert figures["reset"]["in_steps"] > 0
    assert len(figures["memory"]["samples_mb"]) == 2
    assert figures["gymnasium"]["steps_per_s"] > 0 and "peer" not in figures
    assert figures["rollout"]["steps_per_s"] > 0 and figures["rollout_info"]["steps_per_s"] > 0


def fake_peer_venv(root, rate: float):
    """A stand-in for the peer's virtual environment: its python 'has' miniworld and its loop prints ``rate``."""
    python = root / "bin" / "python"
    python.parent.mkdir(parents=True)
    python.write_text(f"""#!/bin/sh
case "$*" in *"import miniworld"*) exit 0;; esac
echo '{{"steps_per_s": {rate}, "cores": 1.0}}'
""")
    python.chmod(0o755)
    return root


def test_the_peer_is_timed_in_the_same_run_and_given_as_ratios(tmp_path, capsys):
    out = tmp_path / "bench.json"
    venv = fake_peer_venv(tmp_path / "peer", rate=50.0)
    assert (
        load_bench().main(
            [
                "steps=80",
                "num_envs=2",
                "resets=2",
                "memory_steps=2000",
                "skip_parallel=true",
                f"peer_venv={venv}",
                f"json={out}",
            ]
        )
        == 0
    )
    figures = json.loads(out.read_text())
    peer = figures["peer"]
    assert peer["steps_per_s"] == 50.0
    assert peer["torchrl_ratio"] == pytest.approx(figures["rollout"]["steps_per_s"] / 50.0)  # as users step it
    assert peer["gymnasium_ratio"] == pytest.approx(figures["gymnasium"]["steps_per_s"] / 50.0)
    assert "1 env / peer: TorchRL (env.rollout)" in capsys.readouterr().out


def test_a_peer_that_cannot_be_installed_is_skipped_with_the_reason(tmp_path, capsys):
    blocked = tmp_path / "file"
    blocked.write_text("not a directory")
    out = tmp_path / "bench.json"
    assert (
        load_bench().main(
            [
                "steps=80",
                "num_envs=1",
                "resets=2",
                "memory_steps=2000",
                "skip_parallel=true",
                f"peer_venv={blocked}/venv",
                f"json={out}",
            ]
        )
        == 0
    )
    reason = json.loads(out.read_text())["peer"]["skipped"]
    assert str(blocked) in reason
    assert f"peer MiniWorld-CollectHealth skipped: {reason}" in capsys.readouterr().out


@pytest.mark.parametrize(
    "args, message",
    [
        (["steps=10"], "steps=10: expected more than 60"),
        (["level=1-3"], "level=1-3: '1-3' is not allowed (did you mean 1-2 or 1-1?); allowed: 1-1, 1-2"),
        (["steps=abc"], "steps=abc: expected an integer"),
        (["--steps", "80"], "'--steps' is not of the form key=value"),
    ],
)
def test_bench_rejects_bad_arguments_in_one_line(args, message, capsys):
    with pytest.raises(SystemExit) as exit_:
        load_bench().main(args)
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.count("\n") == 1 and message in err, err


def test_profile_lists_the_render_and_the_physics_among_the_costliest_calls(capsys):
    assert load_script("profile_env").main(["steps=30", "num_envs=2", "top=40"]) == 0
    printed = capsys.readouterr().out
    assert printed.startswith("evaaa profile_env: level 1-1, num_envs=2, 30 steps")
    assert "mjr_render" in printed and "mj_step" in printed
    with pytest.raises(SystemExit) as exit_:
        load_script("profile_env").main(["level=9-9"])
    assert exit_.value.code == 2 and "level=9-9: '9-9' is not allowed" in capsys.readouterr().err


def test_bench_host_cost_reports_each_backend_level_and_size(tmp_path):
    out = tmp_path / "host.json"
    code = load_bench().main(["host_cost=true", "worlds=[8]", "host_steps=3", "levels=[1-1,4-2]", f"json={out}"])
    assert code == 0
    figures = json.loads(out.read_text())
    assert figures["processor"] and "physics" in figures["stubbed"] and len(figures["load_average"]) == 3
    rows = figures["rows"]
    assert [(r["level"], r["worlds"], r["backend"]) for r in rows] == [
        ("1-1", 8, "cpu"),
        ("1-1", 8, "warp"),
        ("4-2", 8, "cpu"),
        ("4-2", 8, "warp"),
    ]
    for row in rows:
        assert row["us_per_world_decision"] > 0
        phases = row["phases_us"]
        assert phases["apply actions"] > 0 and phases["physiology and senses"] > 0
        if row["backend"] == "warp":
            assert phases["push"] > 0 and phases["pull"] > 0
        assert sum(phases.values()) == pytest.approx(row["us_per_world_decision"])
    assert next(r for r in rows if r["level"] == "4-2")["phases_us"]["predators"] > 0
