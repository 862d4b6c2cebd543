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
    code = load_bench().main(["steps=80", "num_envs=2", "resets=2", "memory_steps=2000", "skip_parallel=true",
                              f"json={out}"])
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


@pytest.mark.parametrize("args, message", [
    (["steps=10"], "steps=10: expected more than 60"),
    (["level=1-3"], "level=1-3: '1-3' is not allowed; allowed: 1-1, 1-2"),
    (["steps=abc"], "steps=abc: expected an integer"),
    (["--steps", "80"], "'--steps' is not of the form key=value"),
])
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
