"""bench_train.py: the rates it derives from a run's log, the peak memory of the training process, the first gradient
step and device from its log, and one real (tiny) run end to end."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest
from helpers import load_script


def load_bench():
    return load_script("bench_train")


def write_log(run_dir: Path, rows: list[tuple[int, float]], updates: list[tuple[int, int]] | None) -> None:
    scalars = run_dir / "logs" / "scalars"
    (scalars / "time").mkdir(parents=True)
    (scalars / "time" / "env_steps_per_s.csv").write_text("".join(f"{s},{r}\n" for s, r in rows))
    if updates is not None:
        (scalars / "train").mkdir()
        (scalars / "train" / "updates.csv").write_text("".join(f"{s},{u}\n" for s, u in updates))


def test_rates_come_from_the_session_rate_log(tmp_path):
    # a fast warm-up (1,000 steps in 1 s) then 100 steps/s; the session rate column is steps / elapsed seconds
    times = {1000: 1.0, 2000: 11.0, 3000: 21.0, 4000: 31.0, 5000: 41.0}
    write_log(
        tmp_path, [(s, s / t) for s, t in times.items()], [(1000, 0), (2000, 30), (3000, 60), (4000, 90), (5000, 120)]
    )
    got = load_bench().read_throughput(tmp_path, "dreamer_xs", skip=0.25)
    assert got.env_steps == 5000 and got.seconds == pytest.approx(41.0)
    assert got.env_steps_per_s == pytest.approx(5000 / 41.0)
    # the row nearest 25% of 41 s is the one at 11 s: the steady rate leaves the warm-up out
    assert got.steady_env_steps_per_s == pytest.approx(100.0)
    assert got.gradient_steps == 120 and got.steady_gradient_steps_per_s == pytest.approx(3.0)


def test_without_an_update_counter_gradient_rates_are_absent(tmp_path):
    write_log(tmp_path, [(100, 50.0), (200, 50.0), (300, 50.0)], None)
    got = load_bench().read_throughput(tmp_path, "ppo")
    assert got.steady_env_steps_per_s == pytest.approx(50.0) and got.steady_gradient_steps_per_s is None


def test_a_run_that_logged_nothing_is_a_clear_error(tmp_path):
    with pytest.raises(SystemExit, match="no logs/scalars/time/env_steps_per_s.csv"):
        load_bench().read_throughput(tmp_path, "ppo")


def test_unknown_algorithm_names_the_allowed_ones(capsys):
    with pytest.raises(SystemExit) as exit_:
        load_bench().main(["algos=[ppo,a2c]"])
    assert exit_.value.code == 2
    assert (
        "algos=[ppo,a2c]: 'a2c' is not allowed; allowed: dqn, dreamer, dreamer_xs, ppo, ppo_lstm"
        in capsys.readouterr().err
    )


@pytest.mark.slow
def test_a_short_real_run_reports_env_and_gradient_steps(tmp_path):
    out = tmp_path / "bench.json"
    code = load_bench().main(
        [
            "algos=[ppo]",
            "minutes=0.25",
            "threads=1",
            f"keep={tmp_path / 'runs'}",
            f"json={out}",
            "overrides=[preset=debug]",
        ]
    )
    assert code == 0
    row = json.loads(out.read_text())["rows"][0]
    assert row["algo"] == "ppo" and row["env_steps"] > 0 and row["steady_env_steps_per_s"] > 0
    # debug PPO: every iteration of frames_per_batch env steps makes epochs x minibatches updates
    assert row["gradient_steps"] > 0 and row["steady_gradient_steps_per_s"] > 0
    # where its CPU time went: each phase PPO passes through, and the rest, adding up to the whole
    split = row["cpu_split"]
    assert all(split[p] > 0 for p in ("env", "act", "advantage", "forward", "backward", "optimizer", "replay"))
    assert split["eval"] == 0.0  # evaluations are pushed past the budget
    assert sum(v for k, v in split.items() if k != "total") == pytest.approx(split["total"])


def test_existing_runs_are_reported_with_their_algorithm(tmp_path, capsys):
    run = tmp_path / "run"
    write_log(run, [(100, 50.0), (200, 50.0), (300, 50.0)], [(100, 10), (200, 20), (300, 30)])
    (run / ".hydra").mkdir()
    (run / ".hydra" / "config.yaml").write_text("algo:\n  name: dqn\n")
    assert load_bench().main([f"runs=[{tmp_path}/r*]", f"json={tmp_path / 'out.json'}"]) == 0  # a pattern
    row = json.loads((tmp_path / "out.json").read_text())["rows"][0]
    assert row["algo"] == "dqn" and row["steady_gradient_steps_per_s"] == pytest.approx(5.0)
    with pytest.raises(SystemExit) as exit_:
        load_bench().main([f"runs={tmp_path}"])
    assert exit_.value.code == 2 and "not a run directory" in capsys.readouterr().err


def test_a_resumed_run_adds_its_sessions_wall_time(tmp_path):
    # session 1: 1,000 steps at 10 steps/s (100 s); resumed at step 1000, session 2: 1,000 more at 20 steps/s (50 s)
    rows = [(500, 10.0), (1000, 10.0), (1500, 20.0), (2000, 20.0)]
    write_log(tmp_path, rows, [(500, 5), (1000, 10), (1500, 15), (2000, 20)])
    (tmp_path / "train.log").write_text(
        "[x][evaaa_baselines.training][INFO] - resuming /r at stage 0 (1-1), env step 1000\n"
    )
    got = load_bench().read_throughput(tmp_path, "dqn", skip=0.0)
    assert got.seconds == pytest.approx(150.0) and got.env_steps_per_s == pytest.approx(2000 / 150)
    # steady from the first row (50 s) to the last (150 s): 1,500 steps and 15 updates in 100 s
    assert got.steady_env_steps_per_s == pytest.approx(15.0)
    assert got.steady_gradient_steps_per_s == pytest.approx(0.15)


def test_peak_memory_is_the_training_process_own(tmp_path):
    # a child that holds 300 MB, started while this process holds 1.2 GB more: the child's peak resident set comes
    # back, not this process's (a child started directly from here counts this process's high-water mark as its own)
    import sys

    import numpy as np

    ballast = np.ones(1_200_000_000 // 8)
    code = "import numpy as np; a = np.ones(300_000_000 // 8); print(a.sum())"
    status, peak = load_bench().run_measured([sys.executable, "-c", code], tmp_path / "out.txt")
    assert status == 0 and (tmp_path / "out.txt").read_text().strip() == "37500000.0"
    assert 300e6 < peak < 1e9 and ballast.sum() == 150_000_000


def test_first_gradient_step_and_device_come_from_the_run_log(tmp_path):
    from datetime import datetime

    (tmp_path / "train.log").write_text(
        "[2026-11-25 08:00:05,000][evaaa_baselines.runtime][INFO] - dreamer on 1-1: 20,327,000 parameters on cpu (bf16 ...\n"
        "[2026-11-25 08:00:05,000][evaaa_baselines.dreamer][INFO] - prefill: 1,024 env steps of random actions before the "
        "first gradient step; then ...\n"
        "[2026-11-25 08:00:41,500][evaaa_baselines.dreamer][INFO] - first gradient step at env step 1,032: 30 s (36 s ...)\n"
    )
    bench = load_bench()
    launched = datetime(2026, 11, 25, 8, 0, 0).timestamp()
    assert bench.first_gradient_step(tmp_path, launched) == pytest.approx(41.5)
    assert bench.run_device(tmp_path) == "cpu"
    assert bench.first_gradient_step(tmp_path / "missing", launched) is None


def test_an_absent_device_is_refused_in_one_line(capsys):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    with pytest.raises(SystemExit) as refused:
        load_bench().main(["algos=[ppo]", "device=cuda"])
    err = capsys.readouterr().err
    assert refused.value.code == 2 and err.count("\n") == 1
    assert "bench_train.py: error: device=cuda: no CUDA device is available here" in err


def test_a_run_too_slow_to_log_twice_reports_its_session_totals(tmp_path):
    # DreamerV3 S on a CPU: 10 minutes, fewer env steps than log_every; train.log's last session line has the totals
    (tmp_path / "train.log").write_text(
        "[2026-11-25 09:11:29,839][evaaa_baselines.runtime][INFO] - dreamer on 1-1: 20,306,279 parameters on cpu (bf16 ...\n"
        "[2026-11-25 09:22:25,542][evaaa_baselines.runtime][INFO] - dreamer on 1-1: 1064 env steps, 1.62 env steps/s this "
        "session, 41 gradient steps\n"
    )
    got = load_bench().read_throughput(tmp_path, "dreamer")
    assert (got.env_steps, got.gradient_steps, got.device) == (1064, 41, "cpu")
    assert got.env_steps_per_s == pytest.approx(1.62) and got.seconds == pytest.approx(1064 / 1.62)
    assert got.steady_gradient_steps_per_s is None


def write_evaluations(run_dir: Path, evals: list[tuple[int, float, list[int], float]]) -> None:
    """``eval.csv`` rows (env steps, the stage's CPU seconds, each episode's survival) and each evaluation's own
    CPU seconds in the log, as a run writes them."""
    rows = ["env_steps,stage,level,worlds,acting,episode,steps,cpu_seconds"]
    for steps, cpu, survival, _ in evals:
        rows += [f"{steps},0,1-1,validation,sample,{i},{s},{cpu}" for i, s in enumerate(survival)]
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "eval.csv").write_text("\n".join(rows) + "\n")
    (run_dir / "logs" / "scalars" / "eval").mkdir(parents=True)
    (run_dir / "logs" / "scalars" / "eval" / "cpu_seconds.csv").write_text(
        "".join(f"{steps},{own}\n" for steps, _, _, own in evals)
    )


def test_cpu_minutes_to_learn_leave_the_evaluations_out(tmp_path):
    # evaluations every 10 k env steps, each taking 30 CPU s; the bar is 2,224 (2 x stand-still's 1,112)
    evals = [
        (10_000, 150.0, [1000, 1200], 30.0),
        (20_000, 330.0, [2000, 2600], 30.0),  # mean 2,300: first above; 330 - 60 s of evaluations = 4.5 minutes
        (30_000, 500.0, [2100, 2200], 30.0),  # mean 2,150: fell back below
        (40_000, 660.0, [3000, 3000], 30.0),
    ]
    write_evaluations(tmp_path, evals)
    got = load_bench().learning(tmp_path, "ppo", "none", 0, bar=2224.0)
    assert got.cpu_minutes_to_learn == pytest.approx(4.5) and got.env_steps_to_learn == 20_000
    assert got.stays is False and got.final_learned is True and got.final_survival == 3000
    assert got.train_cpu_minutes == pytest.approx((660 - 120) / 60)


def test_finished_runs_are_read_with_their_own_acting_mode_and_folder(tmp_path, monkeypatch, capsys):
    # a protocol's record: a PPO run evaluated sampled, a greedy DQN run (mode), neither logging its evaluations'
    # CPU (runs older than issue 61), so their CPU counts whole
    bench = load_bench()
    ppo, dqn = tmp_path / "ppo" / "matched-1-1" / "seed1", tmp_path / "dqn" / "matched-1-1" / "seed0"
    write_evaluations(ppo, [(10_000, 120.0, [1000, 1200], 0.0), (20_000, 300.0, [2500, 2600], 0.0)])
    (ppo / "logs" / "scalars" / "eval" / "cpu_seconds.csv").unlink()
    write_evaluations(dqn, [(10_000, 60.0, [3000, 3000], 0.0)])
    (dqn / "logs" / "scalars" / "eval" / "cpu_seconds.csv").unlink()
    (dqn / "eval.csv").write_text((dqn / "eval.csv").read_text().replace(",sample,", ",mode,"))
    for run, algo, seed in ((ppo, "ppo", 1), (dqn, "dqn", 0)):
        (run / ".hydra").mkdir()
        (run / ".hydra" / "config.yaml").write_text(f"algo:\n  name: {algo}\nseed: {seed}\n")
    monkeypatch.setattr(bench, "standstill_survival", lambda run_dir: 1112.0)
    out = tmp_path / "learn.json"
    assert bench.main(["learn=true", f"runs=[{tmp_path}/*/matched-1-1/seed*]", f"json={out}"]) == 0
    got = {r["algo"]: r for r in json.loads(out.read_text())["runs"]}
    assert json.loads(out.read_text())["processor"]
    assert got["ppo"]["preset"] == "ppo/matched-1-1" and got["ppo"]["seed"] == 1
    assert got["ppo"]["cpu_minutes_to_learn"] == pytest.approx(5.0) and got["ppo"]["acting"] == "sample"
    assert got["ppo"]["eval_cpu_left_out"] is False and got["ppo"]["bar"] == pytest.approx(2224.0)
    assert got["dqn"]["acting"] == "mode" and got["dqn"]["cpu_minutes_to_learn"] == pytest.approx(1.0)
    assert "ppo/matched-1-1" in capsys.readouterr().out
    with pytest.raises(SystemExit) as refused:  # a run directory without evaluations
        (tmp_path / "bare" / ".hydra").mkdir(parents=True)
        (tmp_path / "bare" / ".hydra" / "config.yaml").write_text("algo:\n  name: ppo\n")
        bench.main(["learn=true", f"runs=[{tmp_path / 'bare'}]"])
    assert refused.value.code == 2 and "has no eval.csv" in capsys.readouterr().err


def test_learning_reads_the_sampled_rows_of_both_modes_and_old_files_by_their_config(tmp_path):
    bench = load_bench()
    # eval.both_modes: each evaluation's episodes played again by the most likely action, rows of their own; only
    # the sampled ones measure learning (the greedy ones here would pass the bar 10 k steps earlier)
    both = tmp_path / "both"
    write_evaluations(both, [(10_000, 120.0, [1000, 1200], 0.0), (20_000, 300.0, [2500, 2600], 0.0)])
    text = (both / "eval.csv").read_text()
    mode_rows = [r.replace(",sample,", ",mode,") for r in text.splitlines()[1:]]
    mode_rows[0] = mode_rows[0].replace(",1000,", ",9000,")
    (both / "eval.csv").write_text(text + "\n".join(mode_rows) + "\n")
    got = bench.learning(both, "ppo", "none", 0, bar=2224.0)
    assert got.acting == "sample" and got.env_steps_to_learn == 20_000 and len(got.evaluations) == 2
    # a file written before eval.csv named its acting mode: as the run's eval.sample said (sampled here; most likely
    # action where it was false, and for DQN whatever it said)
    for name, config, algo, acting in (
        ("sampled", "eval:\n  sample: true\n", "ppo", "sample"),
        ("greedy", "eval:\n  sample: false\n", "ppo", "mode"),
        ("dqn", "eval:\n  sample: true\n", "dqn", "mode"),
    ):
        old = tmp_path / name
        write_evaluations(old, [(10_000, 120.0, [3000, 3000], 0.0)])
        rows = [r.split(",") for r in (old / "eval.csv").read_text().splitlines()]
        (old / "eval.csv").write_text("\n".join(",".join(r[:4] + r[5:]) for r in rows) + "\n")  # no acting
        (old / ".hydra").mkdir()
        (old / ".hydra" / "config.yaml").write_text(config)
        got = bench.learning(old, algo, "none", 0, bar=2224.0)
        assert got.acting == acting and got.env_steps_to_learn == 10_000


def test_the_median_counts_a_seed_that_never_learned_as_slower_than_any(tmp_path):
    bench = load_bench()
    runs = []
    for seed, survival in enumerate([[3000, 3000], [1000, 1000], [2500, 2300]]):
        write_evaluations(tmp_path / str(seed), [(10_000, 120.0, survival, 0.0)])
        runs.append(bench.learning(tmp_path / str(seed), "ppo", "none", seed, bar=2224.0))
    (row,) = bench.learning_summary(runs)
    assert row["learned"] == 2 and row["median_cpu_minutes_to_learn"] == pytest.approx(2.0)
    assert row["cpu_minutes_to_learn"] == [2.0, None, 2.0]
    (worse,) = bench.learning_summary(runs[1:2] * 2 + runs[:1])
    assert worse["median_cpu_minutes_to_learn"] is None  # two of three never learned


@pytest.mark.slow
def test_learn_mode_trains_evaluates_and_reports_the_cpu_minutes_to_learn(tmp_path):
    # a debug PPO run to a few CPU seconds, evaluated every 64 env steps; the bar is 0.5 x stand-still's 48
    # decisions (the debug episodes' step limit), which any policy reaches: learned at its first evaluation
    out = tmp_path / "learn.json"
    args = [
        "learn=true",
        "algos=[ppo]",
        "presets=[debug]",
        "seeds=[0]",
        "cpu_minutes=0.05",
        "eval_every=64",
        "bar=0.5",
        f"keep={tmp_path / 'runs'}",
        f"json={out}",
    ]
    assert load_bench().main(args) == 0
    report = json.loads(out.read_text())
    (run,) = report["runs"]
    assert report["bar"]["by_run"] == {"debug/ppo/seed0": 24.0}
    assert run["evaluations"] and run["evaluations"][0]["env_steps"] == 64
    assert run["env_steps_to_learn"] == 64 and run["cpu_minutes_to_learn"] >= 0
    assert report["summary"][0]["learned"] == 1 and report["processor"]
    # the same command again finds the final model and trains nothing more
    before = (tmp_path / "runs" / "debug" / "ppo" / "seed0" / "eval.csv").read_text()
    assert load_bench().main(args) == 0
    assert (tmp_path / "runs" / "debug" / "ppo" / "seed0" / "eval.csv").read_text() == before


def test_an_algorithm_that_cannot_be_measured_leaves_the_others_figures(tmp_path, monkeypatch, capsys):
    bench = load_bench()
    measured = bench.Throughput("ppo", 100, 10.0, 10.0, 10.0, None, None, device="cpu")

    def run_one(algo, *args, **kwargs):
        if algo == "dreamer_xs":
            raise SystemExit("bench_train.py: dreamer_xs: fewer than two log rows")
        return replace(measured, algo=algo)

    monkeypatch.setattr(bench, "run_one", run_one)
    out = tmp_path / "bench.json"
    assert bench.main(["algos=[ppo,dreamer_xs,dqn]", "device=cpu", f"json={out}"]) == 1
    written = json.loads(out.read_text())
    assert [r["algo"] for r in written["rows"]] == ["ppo", "dqn"]
    assert written["not_measured"] == {"dreamer_xs": "bench_train.py: dreamer_xs: fewer than two log rows"}
    assert "dreamer_xs: not measured" in capsys.readouterr().out


def test_learning_runs_are_pinned_to_the_cores_named(tmp_path, monkeypatch, capsys):
    bench = load_bench()
    pinned = []

    def run_learning(job, args, root, core):
        pinned.append((job[2], core))
        raise SystemExit("stop here")  # the pinning is what is checked, not the training

    monkeypatch.setattr(bench, "run_learning", run_learning)
    with pytest.raises(SystemExit, match="stop here"):
        bench.main(["learn=true", "seeds=[3]", "cores=[1]", f"keep={tmp_path}"])
    assert pinned == [(3, 1)]
    with pytest.raises(SystemExit) as refused:
        bench.main(["learn=true", "cores=[4096]"])
    assert refused.value.code == 2 and "cores=[4096]: expected a core number below" in capsys.readouterr().err
