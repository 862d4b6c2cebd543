"""Training: the Hydra config composes for every choice; smoke runs of each baseline (debug preset) finish and write
what a run directory holds; a run killed between checkpoints and resumed ends exactly where an uninterrupted run
ends (parameters, optimiser state, losses, episodes, evaluations), in direct training and in a curriculum, also when
written under ``device=auto`` and resumed under ``device=cpu``; ``device`` names only devices the machine has, and
``scripts/train.py device=cuda`` without CUDA is one line and exit code 2 (the progress bar's rates, ETA and the
time estimate: tests/test_stage.py); the loader refuses a checkpoint trained on other observation keys;
``scripts/train.py`` runs a multirun sweep."""

from __future__ import annotations

import csv
import hashlib
import itertools
import logging
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import torch
from helpers import RESUME_DEVICE, read_csv, train_scalars
from hydra import compose, initialize_config_dir

import evaaa
from evaaa.records import TRAINING_EPISODE_FIELDS
from evaaa_baselines import algos, checkpoint, devices, evaluate, load_policy, logs, training
from evaaa_baselines import run as run_loop
from evaaa_baselines.config import (
    env_overrides,
    observation_keys,
    register_levels,
    stages,
)
from evaaa_baselines.devices import DeviceError, resolve_device
from evaaa_baselines.evaluation import EvaluatedPolicy, EvaluationError
from evaaa_baselines.paths import CONF_DIR
from evaaa_baselines.training import make_logger, summary, train

register_levels()

ROOT = Path(__file__).resolve().parents[1]
#: the algorithms smoke-trained, killed and resumed here: every one there is, but DreamerV3's (tests/test_dreamer.py)
ALGOS = tuple(a for a in algos.names() if algos.algorithm(a).train is not algos.algorithm("dreamer").train)
TOTAL = 256  # env steps of a smoke run: 128 per world with the debug preset's 2 worlds
KILL_AT = 160  # a run "killed" here last checkpointed at 128 (debug: every 64 env steps), so 32+ steps are redone


def options(group: str) -> list[str]:
    return sorted(p.stem for p in (CONF_DIR / group).glob("*.yaml"))


def make_cfg(*overrides: str):
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        return compose("config", overrides=list(overrides))


def debug_cfg(algo: str, *extra: str, total_steps: int = TOTAL):
    # one torch thread, as tests/test_dreamer.py: these tiny networks gain nothing from more, and the suite's workers
    # share the cores (two threads each beside another worker cost more CPU for the same run)
    return make_cfg(
        f"algo={algo}",
        "preset=debug",
        "logger=csv",
        "progress=false",
        "threads=1",
        f"total_steps={total_steps}",
        *extra,
    )


# ------------------------------------------------------------------------------------------------ config
def check_composed(cfg, algo: str, level: str, modality: str, reward: str, logger: str) -> None:
    assert cfg.algo.name == algo and cfg.logger.backend == logger
    assert cfg.level.name == level
    keys = observation_keys(cfg)
    dropped = modality.removeprefix("no_").replace("vision", "pixels")
    assert keys == (evaaa.MODALITIES if modality == "all" else tuple(k for k in evaaa.MODALITIES if k != dropped))
    # an option either names the level's reward function or sets the level's reward fields (original, dqn)
    assert env_overrides(cfg)["reward"]["name"] == cfg.reward.get("overrides", {"name": reward})["name"]
    evaaa.load_level(level if level != "curriculum" else "1-1", env_overrides(cfg))
    assert cfg.run.name == f"{level}/{algo}/{modality}-{reward}/seed{cfg.seed}"
    assert [s.level for s in stages(cfg)] == (list(evaaa.LEVELS) if level == "curriculum" else [level])


def test_group_options_are_the_documented_ones():
    """Every option of a group is in docs/training.md's table of groups, and only those: found, not listed here."""
    table = (ROOT / "docs" / "training.md").read_text()
    for group in ("algo", "modality", "reward", "logger", "preset"):
        row = re.search(rf"^\| `{group}` \| (.*?) \|", table, re.M)
        assert row, f"docs/training.md has no row for the {group} group"
        documented = sorted(re.findall(r"`([^`]+)`", re.sub(r"\([^)]*\)", "", row[1])))  # asides dropped
        assert documented == options(group), group
    assert set(evaaa.REWARDS) <= set(options("reward"))  # every packaged reward function is an option
    assert set(options("algo")) == set(algos.names()) and {"ppo", "dqn"} <= set(ALGOS)
    assert {m.removeprefix("no_") for m in options("modality")} - {"all", "vision"} == set(evaaa.MODALITIES) - {
        "pixels"
    }  # one ablation per sense


def test_squared_death_is_squared_with_a_death_of_minus_3000():
    """DreamerV3-XS's reward option (docs/results.md, DreamerV3-XS): the level's squared reward, only the death costs -3,000."""
    squared = evaaa.load_level("1-1", env_overrides(make_cfg("reward=squared"))).reward
    death = evaaa.load_level("1-1", env_overrides(make_cfg("reward=squared_death"))).reward
    assert death.name == squared.name == "squared" and squared.terminal_penalty == -100.0
    assert death.model_dump() == {**squared.model_dump(), "terminal_penalty": -3000.0}


def test_every_level_and_testbed_has_a_level_config():
    for name in (*evaaa.LEVELS, *evaaa.TESTBEDS):
        cfg = make_cfg(f"level={name}")
        assert cfg.level.name == name
        evaaa.load_level(name, env_overrides(cfg))  # the overrides training passes are valid for this level


@pytest.mark.parametrize("algo", ALGOS)
def test_config_composes_for_every_modality_reward_logger_and_level(algo):
    """The full product of modality × reward × logger on one level, and every level (and the curriculum) once."""
    for modality, reward, logger in itertools.product(options("modality"), options("reward"), options("logger")):
        cfg = make_cfg(f"algo={algo}", f"modality={modality}", f"reward={reward}", f"logger={logger}")
        check_composed(cfg, algo, "1-1", modality, reward, logger)
    for level in (*evaaa.LEVELS, *evaaa.TESTBEDS, "curriculum"):
        check_composed(make_cfg(f"algo={algo}", f"level={level}"), algo, level, "all", "squared", "csv")


def test_debug_preset_shrinks_each_algorithm():
    for algo in ALGOS:
        full, debug = make_cfg(f"algo={algo}"), make_cfg(f"algo={algo}", "preset=debug")
        assert debug.total_steps < full.total_steps and debug.env.num_envs < full.env.num_envs
        assert debug.algo.encoder.cnn.features < full.algo.encoder.cnn.features
        assert debug.algo.name == algo
    assert make_cfg("algo=dqn", "preset=debug").algo.buffer_size < make_cfg("algo=dqn").algo.buffer_size
    assert make_cfg("algo=ppo_lstm", "preset=debug").algo.lstm.hidden < make_cfg("algo=ppo_lstm").algo.lstm.hidden


# ------------------------------------------------------------------------------------------------ runs
class Killed(Exception):
    """Stands for the process being killed between two checkpoints."""


def run_killed(cfg, run_dir: Path, at: int, monkeypatch, stage: int = 0) -> None:
    """Train until ``at`` env steps of ``stage``, then stop as a kill would: that iteration's checkpoint is lost."""
    end_iteration = run_loop.Run.end_iteration

    def killing(self, td):
        if self.stage.index == stage and self.steps >= at:
            raise Killed
        end_iteration(self, td)

    with monkeypatch.context() as patch:
        patch.setattr(run_loop.Run, "end_iteration", killing)
        with pytest.raises(Killed):
            train(cfg, run_dir)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Per algorithm: an uninterrupted smoke run (device=auto), and the same run killed at KILL_AT then resumed with
    device=RESUME_DEVICE (cpu, or auto on a CUDA machine; made once)."""
    made: dict[str, dict] = {}

    def get(algo: str) -> dict:
        if algo not in made:
            root = tmp_path_factory.mktemp(algo)
            train(debug_cfg(algo), root / "whole")
            with pytest.MonkeyPatch.context() as patch:
                run_killed(debug_cfg(algo), root / "resumed", KILL_AT, patch)
            at_kill = checkpoint.load_checkpoint(root / "resumed" / checkpoint.CHECKPOINT)
            train(debug_cfg(algo, "resume=true", f"device={RESUME_DEVICE}"), root / "resumed")
            made[algo] = {
                "whole": root / "whole",
                "resumed": root / "resumed",
                "steps_at_kill_checkpoint": at_kill["counters"]["steps"],
            }
        return made[algo]

    return get


@pytest.mark.parametrize("algo", ALGOS)
def test_smoke_run_writes_checkpoint_csvs_and_final_model(runs, algo):
    run_dir = runs(algo)["whole"]
    state = checkpoint.load_checkpoint(run_dir / checkpoint.CHECKPOINT)
    assert state["algo"] == algo and state["level"] == "1-1" and state["counters"]["steps"] == TOTAL
    assert state["obs_keys"] == list(evaaa.MODALITIES) and state["config"]["algo"]["name"] == algo
    assert {"snapshot", "transforms", "td"} <= set(state["env"]) and {"torch", "numpy", "python"} <= set(state["rng"])
    if algo == "dqn":
        assert len(state["components"]["buffer"]["_storage"]["_storage"]["action"]) > 0  # the replay buffer is saved
    assert (run_dir / "model-0-1-1.pt").exists()
    assert not list(run_dir.glob(".*.tmp"))  # atomic writes leave no temp file behind

    episodes = read_csv(run_dir / "episodes.csv")
    assert list(episodes[0]) == [c for c in TRAINING_EPISODE_FIELDS if c != "wall_time"]  # evaaa.records' format
    assert len(episodes) >= 2  # the debug preset's 48-step episodes end several times in 128 steps per world
    for row in episodes:
        assert row["end_type"] in evaaa.END_TYPES[1:]
        assert 0 < int(row["steps"]) <= 48
        assert (int(row["steps"]) == 48) == (row["end_type"] == "MaxStepReached")
    evaluations = read_csv(run_dir / "eval.csv")
    # one row per episode (eval.episodes=2) of every evaluation: every eval.every, and at the end
    assert [(int(r["env_steps"]), r["episode"]) for r in evaluations] == [
        (128, "0"),
        (128, "1"),
        (256, "0"),
        (256, "1"),
    ]
    assert {(r["worlds"], r["acting"]) for r in evaluations} == {("validation", "mode")}
    assert all(0 < int(r["steps"]) <= 48 and r["end_type"] in evaaa.END_TYPES[1:] for r in evaluations)
    assert all(int(r["food_eaten"]) >= 0 and int(r["collisions"]) >= 0 for r in evaluations)
    best = checkpoint.load_checkpoint(run_dir / "model-best-0-1-1.pt")
    means = [(int(evaluations[i]["steps"]) + int(evaluations[i + 1]["steps"])) / 2 for i in (0, 2)]
    assert best["eval_survival_mean"] == max(means)
    assert best["env_steps"] == (128, 256)[means.index(max(means))]  # the first of equal bests
    assert train_scalars(run_dir), "training metrics reach the logger"


def test_sampling_evaluation_leaves_training_unchanged(runs, tmp_path):
    # the sampling evaluation draws from a forked RNG: the training that follows it is the same as without it
    train(debug_cfg("ppo", "eval.sample=true"), tmp_path / "run")
    whole = checkpoint.load_checkpoint(runs("ppo")["whole"] / checkpoint.CHECKPOINT)
    sampled = checkpoint.load_checkpoint(tmp_path / "run" / checkpoint.CHECKPOINT)
    for name, value in whole["model"].items():
        assert torch.equal(value, sampled["model"][name]), name
    assert read_csv(runs("ppo")["whole"] / "episodes.csv") == read_csv(tmp_path / "run" / "episodes.csv")
    evaluations = read_csv(tmp_path / "run" / "eval.csv")
    assert len(evaluations) == 4 and {r["acting"] for r in evaluations} == {"sample"}


def test_evaluations_in_both_modes_leave_training_and_the_best_model_to_the_chosen_mode(runs, tmp_path):
    # eval.both_modes: the same validation episodes in the other mode too, rows of their own; training unchanged
    train(debug_cfg("ppo", "eval.sample=true", "eval.both_modes=true"), tmp_path / "run")
    whole = checkpoint.load_checkpoint(runs("ppo")["whole"] / checkpoint.CHECKPOINT)
    both = checkpoint.load_checkpoint(tmp_path / "run" / checkpoint.CHECKPOINT)
    for name, value in whole["model"].items():
        assert torch.equal(value, both["model"][name]), name
    evaluations = read_csv(tmp_path / "run" / "eval.csv")
    by_mode = {m: [r for r in evaluations if r["acting"] == m] for m in ("sample", "mode")}
    assert len(by_mode["sample"]) == len(by_mode["mode"]) == 4
    # the sampled rows are those of a run evaluating by sampling alone (the other mode draws nothing from them)
    sampled = [(r["env_steps"], r["steps"]) for r in by_mode["sample"]]
    train(debug_cfg("ppo", "eval.sample=true"), tmp_path / "alone")
    alone = [(r["env_steps"], r["steps"]) for r in read_csv(tmp_path / "alone" / "eval.csv")]
    assert sampled == alone
    best = checkpoint.load_checkpoint(tmp_path / "run" / "model-best-0-1-1.pt")
    means = {}
    for r in by_mode["sample"]:
        means.setdefault(int(r["env_steps"]), []).append(int(r["steps"]))
    assert best["eval_survival_mean"] == max(sum(v) / len(v) for v in means.values())


@pytest.mark.parametrize("algo", ALGOS)
def test_killed_and_resumed_run_equals_uninterrupted_run(runs, algo):
    r = runs(algo)
    assert r["steps_at_kill_checkpoint"] < KILL_AT  # the kill lost work that the resumed run had to redo
    whole = checkpoint.load_checkpoint(r["whole"] / checkpoint.CHECKPOINT)
    resumed = checkpoint.load_checkpoint(r["resumed"] / checkpoint.CHECKPOINT)
    assert (whole["config"]["device"], resumed["config"]["device"]) == ("auto", RESUME_DEVICE)
    assert whole["counters"] == resumed["counters"]
    for name, value in whole["model"].items():
        assert torch.equal(value, resumed["model"][name]), name
    optim_a, optim_b = whole["components"]["optimizer"]["state"], resumed["components"]["optimizer"]["state"]
    assert optim_a.keys() == optim_b.keys()
    for index in optim_a:
        for key, value in optim_a[index].items():
            assert torch.equal(value, optim_b[index][key]), (index, key)
    assert train_scalars(r["whole"]) == train_scalars(r["resumed"])
    assert read_csv(r["whole"] / "episodes.csv") == read_csv(r["resumed"] / "episodes.csv")
    assert read_csv(r["whole"] / "eval.csv") == read_csv(r["resumed"] / "eval.csv")


def test_existing_run_needs_resume_and_the_same_experiment(runs, tmp_path):
    run_dir = runs("ppo")["whole"]
    with pytest.raises(FileExistsError, match="resume=true"):
        train(debug_cfg("ppo"), run_dir)
    with pytest.raises(ValueError, match="observation keys"):
        train(debug_cfg("ppo", "resume=true", "modality=no_vision"), run_dir)
    with pytest.raises(ValueError, match="algo"):
        train(debug_cfg("dqn", "resume=true"), run_dir)


@pytest.mark.parametrize("algo", ["dqn", "ppo"])  # any checkpoint: epsilon over its deterministic action
def test_evaluation_acts_epsilon_greedily_on_request(runs, algo):
    from helpers import load_script

    script = load_script("evaluate")
    path = str(runs(algo)["whole"] / "model-0-1-1.pt")
    with pytest.raises(SystemExit) as exit_:
        script.parse([f"policy={path}", "epsilon=1.5"])
    assert exit_.value.code == 2
    changed = {}
    for eps in (0.0, 0.5, 1.0):
        policy = EvaluatedPolicy(path, seed=0, epsilon=eps)
        env = policy.make_env("1-1", num_envs=2, seed=0)
        try:
            td = env.reset()
            greedy = policy.loaded(td.clone())["action"]
            acts = torch.stack([policy.act(env, td.clone()) for _ in range(400)])
        finally:
            env.close()
        assert acts.shape == (400, 2) and int(acts.min()) >= 0 and int(acts.max()) < 5
        changed[eps] = (acts != greedy).float().mean().item()
    # a random action is another action 4 times in 5
    assert changed[0.0] == 0.0
    assert changed[0.5] == pytest.approx(0.4, abs=0.06) and changed[1.0] == pytest.approx(0.8, abs=0.06)


def test_evaluation_samples_from_the_policy_on_request(runs):
    path = str(runs("ppo")["whole"] / "model-0-1-1.pt")
    distinct = {}
    for sample in (False, True):
        policy = EvaluatedPolicy(path, seed=0, sample=sample)
        env = policy.make_env("1-1", num_envs=2, seed=0)
        try:
            td = env.reset()
            acts = torch.stack([policy.act(env, td.clone()) for _ in range(200)])
        finally:
            env.close()
        distinct[sample] = int(acts[:, 0].unique().numel())
    # the most likely action every time, or draws from a (barely trained, so broad) distribution
    assert distinct[False] == 1 and distinct[True] >= 3


def test_a_dqn_checkpoint_asked_to_sample_takes_its_greedy_action(runs):
    """DQN's policy is its greedy action, so sample=true leaves it as it is, and its rows say so (``mode``): a
    comparison of sampling agents shows that DQN's episodes were not sampled."""
    path = str(runs("dqn")["whole"] / "model-0-1-1.pt")
    policy = EvaluatedPolicy(path, seed=0, sample=True)
    env = policy.make_env("1-1", num_envs=2, seed=0)
    try:
        td = env.reset()
        greedy = policy.loaded(td.clone(), deterministic=True)["action"]
        acts = torch.stack([policy.act(env, td.clone()) for _ in range(100)])
    finally:
        env.close()
    assert policy.acting == "mode" and bool((acts == greedy).all())
    assert EvaluatedPolicy(path, seed=0, sample=True, epsilon=0.05).acting == "mode+epsilon=0.05"


def test_loader_gives_a_policy_and_refuses_other_observation_keys(runs):
    path = runs("ppo_lstm")["whole"] / "model-0-1-1.pt"
    with pytest.raises(ValueError, match="observation keys") as error:
        load_policy(path, modalities=["pixels", "interoception"])
    assert "olfaction" in str(error.value)
    loaded = load_policy(path, modalities=evaaa.MODALITIES)
    assert loaded.algo == "ppo_lstm" and loaded.obs_keys == evaaa.MODALITIES and loaded.level == "1-1"
    with pytest.raises(ValueError, match="observation keys"):
        loaded.wrap(evaaa.make_env("1-1", modalities=["interoception"]))
    env = loaded.make_env(num_envs=2, seed=3)
    try:
        td = loaded(env.reset())
        assert td["action"].shape == (2,) and 0 <= int(td["action"].min()) and int(td["action"].max()) < 5
        result = evaluate(env, loaded.policy)
        assert len(result.survival) == 2 and all(0 < s <= 48 for s in result.survival)
    finally:
        env.close()


def test_curriculum_hands_weights_over_and_resumes_mid_curriculum(tmp_path, monkeypatch):
    overrides = ("level=curriculum", "level.stages=[1-1,1-2]")
    started: list[tuple[int, dict]] = []
    start = run_loop.Run.start

    def recording_start(self, model, components, *evaluation, **planned):
        td = start(self, model, components, *evaluation, **planned)
        started.append((self.stage.index, {k: v.clone() for k, v in model.state_dict().items()}))
        return td

    monkeypatch.setattr(run_loop.Run, "start", recording_start)
    train(debug_cfg("ppo", *overrides, total_steps=128), tmp_path / "whole")
    stage0_final = checkpoint.load_checkpoint(tmp_path / "whole" / "model-0-1-1.pt")["model"]
    stage1_start = dict(started)[1]
    assert all(torch.equal(stage0_final[k], v.cpu()) for k, v in stage1_start.items())  # checkpoints load on the CPU
    assert (tmp_path / "whole" / "model-1-1-2.pt").exists()
    assert {r["level"] for r in read_csv(tmp_path / "whole" / "episodes.csv")} == {"1-1", "1-2"}

    run_killed(debug_cfg("ppo", *overrides, total_steps=128), tmp_path / "resumed", 96, monkeypatch, stage=1)
    at_kill = checkpoint.load_checkpoint(tmp_path / "resumed" / checkpoint.CHECKPOINT)
    assert at_kill["stage"] == 1 and at_kill["counters"]["steps"] < 96
    train(debug_cfg("ppo", *overrides, "resume=true", total_steps=128), tmp_path / "resumed")
    whole = checkpoint.load_checkpoint(tmp_path / "whole" / checkpoint.CHECKPOINT)
    resumed = checkpoint.load_checkpoint(tmp_path / "resumed" / checkpoint.CHECKPOINT)
    assert resumed["stage"] == 1 and resumed["level"] == "1-2"
    assert all(torch.equal(v, resumed["model"][k]) for k, v in whole["model"].items())
    assert read_csv(tmp_path / "whole" / "episodes.csv") == read_csv(tmp_path / "resumed" / "episodes.csv")


def test_atomic_save_keeps_the_previous_checkpoint_when_writing_fails(tmp_path, monkeypatch):
    path = tmp_path / "checkpoint.pt"
    checkpoint.save_checkpoint({"step": 1}, path)

    def failing_save(obj, f):
        f.write(b"partial")
        raise OSError("disk full")

    monkeypatch.setattr(torch, "save", failing_save)
    with pytest.raises(OSError):
        checkpoint.save_checkpoint({"step": 2}, path)
    monkeypatch.undo()
    assert checkpoint.load_checkpoint(path) == {"step": 1}


def assert_same_run(whole: Path, resumed: Path) -> None:
    a = checkpoint.load_checkpoint(whole / checkpoint.CHECKPOINT)
    b = checkpoint.load_checkpoint(resumed / checkpoint.CHECKPOINT)
    assert a["counters"] == b["counters"]
    assert all(torch.equal(v, b["model"][k]) for k, v in a["model"].items())
    assert read_csv(whole / "episodes.csv") == read_csv(resumed / "episodes.csv")
    assert read_csv(whole / "eval.csv") == read_csv(resumed / "eval.csv")


def test_a_damaged_latest_checkpoint_resumes_exactly_from_the_previous_one(runs, tmp_path, monkeypatch, caplog):
    run_dir = tmp_path / "run"
    run_killed(debug_cfg("ppo"), run_dir, KILL_AT, monkeypatch)
    latest = run_dir / checkpoint.CHECKPOINT
    weight = max(checkpoint.load_checkpoint(latest)["model"].values(), key=torch.Tensor.numel)
    data = bytearray(latest.read_bytes())
    start = data.find(weight.numpy().tobytes()[:256])
    data[start + 256 : start + 1280] = bytes(1024)  # 1 KB zeroed inside a weight
    latest.write_bytes(bytes(data))
    (run_dir / ".checkpoint.pt.tmp").write_bytes(b"cut short by a kill")
    with caplog.at_level(logging.INFO, logger="evaaa_baselines.training"):
        train(debug_cfg("ppo", "resume=true"), run_dir)
    assert f"{latest} is damaged" in caplog.text
    assert f"previous checkpoint {run_dir / checkpoint.PREVIOUS}" in caplog.text
    assert not (run_dir / ".checkpoint.pt.tmp").exists() and ".checkpoint.pt.tmp" in caplog.text
    assert_same_run(runs("ppo")["whole"], run_dir)


def test_ctrl_c_checkpoints_after_the_iteration_and_resume_continues_exactly(runs, tmp_path, monkeypatch):
    """The first SIGINT lets the iteration finish, writes a checkpoint and stops; the resumed run is the whole run."""
    end_iteration = run_loop.Run.end_iteration

    def ctrl_c_at(self, td):
        if self.steps == 96:
            os.kill(os.getpid(), signal.SIGINT)
        end_iteration(self, td)

    monkeypatch.setattr(run_loop.Run, "end_iteration", ctrl_c_at)
    before = signal.getsignal(signal.SIGINT)  # Python's default, or SIG_IGN in a job started in the background
    with pytest.raises(run_loop.Interrupted, match="interrupted at env step 96 of 1-1: checkpoint written to"):
        train(debug_cfg("ppo"), tmp_path / "run")
    monkeypatch.undo()
    assert signal.getsignal(signal.SIGINT) is before  # the handler is put back
    assert checkpoint.load_checkpoint(tmp_path / "run" / checkpoint.CHECKPOINT)["counters"]["steps"] == 96
    train(debug_cfg("ppo", "resume=true"), tmp_path / "run")
    assert_same_run(runs("ppo")["whole"], tmp_path / "run")


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGUSR2], ids=["SIGTERM", "SIGUSR2"])
def test_sigterm_and_sigusr2_checkpoint_like_the_first_ctrl_c_and_resume_continues_exactly(
    runs, tmp_path, monkeypatch, signum
):
    """kill/scancel (SIGTERM) and a SLURM time limit through submitit (SIGUSR2) stop the run as the first Ctrl-C
    does, however many of them arrive: a checkpoint after the iteration, and the resumed run is the whole run."""
    end_iteration = run_loop.Run.end_iteration

    def signalled_at(self, td):
        if self.steps == 96:
            os.kill(os.getpid(), signum)
            os.kill(os.getpid(), signum)  # again: still the checkpointed stop, not the one at once
        end_iteration(self, td)

    monkeypatch.setattr(run_loop.Run, "end_iteration", signalled_at)
    before = {s: signal.getsignal(s) for s in training.STOP_SIGNALS}
    with pytest.raises(run_loop.Interrupted, match="interrupted at env step 96 of 1-1: checkpoint written to") as err:
        train(debug_cfg("ppo"), tmp_path / "run")
    monkeypatch.undo()
    assert err.value.signals == (signum,)  # what train.py reads to let submitit requeue the job (SIGUSR2)
    assert {s: signal.getsignal(s) for s in training.STOP_SIGNALS} == before  # the handlers are put back
    assert checkpoint.load_checkpoint(tmp_path / "run" / checkpoint.CHECKPOINT)["counters"]["steps"] == 96
    train(debug_cfg("ppo", "resume=true"), tmp_path / "run")
    assert_same_run(runs("ppo")["whole"], tmp_path / "run")


def test_a_second_ctrl_c_stops_at_once_and_names_the_checkpoint_left(tmp_path, monkeypatch):
    end_iteration = run_loop.Run.end_iteration

    def ctrl_c_twice_at(self, td):
        if self.steps == 96:
            os.kill(os.getpid(), signal.SIGINT)
            os.kill(os.getpid(), signal.SIGINT)
        end_iteration(self, td)

    monkeypatch.setattr(run_loop.Run, "end_iteration", ctrl_c_twice_at)
    latest = tmp_path / "run" / checkpoint.CHECKPOINT
    with pytest.raises(run_loop.Interrupted, match=f"stopped at once: .*from the last one, {re.escape(str(latest))}"):
        train(debug_cfg("ppo"), tmp_path / "run")
    assert checkpoint.load_checkpoint(latest)["counters"]["steps"] == 64  # the last one due (every 64 env steps)


@pytest.mark.parametrize("backend", ["tensorboard", "wandb"])
def test_other_loggers_write_under_the_run_directory(tmp_path, backend):
    cfg = make_cfg(f"logger={backend}")
    assert backend != "wandb" or cfg.logger.offline  # W&B stays on this machine unless asked
    logger = make_logger(cfg, tmp_path, None)
    logger.log_scalar("train/loss", 1.0, step=1)
    logger.shutdown()
    written = [p for p in tmp_path.rglob("*") if p.is_file()]
    assert written and all(tmp_path in p.parents for p in written)
    if backend == "wandb":
        assert list((tmp_path / "wandb").glob("offline-run-*"))


def test_train_script_multirun_sweeps_seeds(tmp_path):
    cmd = [
        sys.executable,
        str(ROOT / "scripts" / "train.py"),
        "-m",
        "algo=ppo",
        "preset=debug",
        "logger=csv",
        "progress=false",
        "total_steps=64",
        "threads=1",
        "seed=0,1",
        f"run.root={tmp_path}",
    ]
    done = subprocess.run(
        cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300, env={**os.environ, "HYDRA_FULL_ERROR": "1"}
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert "Joblib.Parallel(" in done.stdout + done.stderr  # the default launcher preset (hydra/launcher=local)
    for seed in (0, 1):
        run_dir = tmp_path / "1-1" / "ppo" / "all-squared-debug" / f"seed{seed}"  # the preset has its own folders
        assert (run_dir / checkpoint.CHECKPOINT).exists() and (run_dir / ".hydra" / "config.yaml").exists()
        assert checkpoint.load_checkpoint(run_dir / checkpoint.CHECKPOINT)["config"]["seed"] == seed


def test_a_wall_clock_budget_ends_the_stage_early(tmp_path):
    # a budget of 30 ms: the stage stops after its first iteration, still writing its model and evaluation
    cfg = debug_cfg("ppo", "max_minutes=0.0005", "eval.every=100000", total_steps=10 * TOTAL)
    train(cfg, tmp_path / "run")
    rows = list(csv.DictReader(open(tmp_path / "run" / "eval.csv")))
    assert rows and int(rows[-1]["env_steps"]) < 10 * TOTAL
    assert (tmp_path / "run" / "model-0-1-1.pt").exists()


def test_time_budgets_count_every_session_of_a_stage(tmp_path, monkeypatch):
    # a first session checkpoints and is killed; the resumed one is given a CPU budget the first has already spent
    cfg = debug_cfg("ppo", "eval.every=100000", "checkpoint.every=64", total_steps=10 * TOTAL)
    run_killed(cfg, tmp_path / "run", 3 * 64, monkeypatch)
    first = checkpoint.load_checkpoint(tmp_path / "run" / checkpoint.CHECKPOINT)["time"]
    assert first["seconds"] > 0 and first["cpu_seconds"] > 0
    budget = first["cpu_seconds"] / 60 / 2
    train(
        debug_cfg(
            "ppo",
            "eval.every=100000",
            "checkpoint.every=64",
            "resume=true",
            f"max_cpu_minutes={budget}",
            total_steps=10 * TOTAL,
        ),
        tmp_path / "run",
    )
    final = checkpoint.load_checkpoint(tmp_path / "run" / "model-0-1-1.pt")
    # one iteration of the resumed session, then the stage ends: its earlier session counted
    assert final["env_steps"] < 10 * TOTAL
    assert final["time"]["cpu_seconds"] > first["cpu_seconds"] and final["time"]["seconds"] > first["seconds"]


def test_evaluations_record_the_cpu_time_of_the_stage_so_far(tmp_path, monkeypatch):
    # three evaluations, killed after the second checkpoint and resumed: the CPU time goes on from the checkpoint's
    cfg = debug_cfg("ppo", "eval.every=64", "checkpoint.every=64", total_steps=3 * 64)
    run_killed(cfg, tmp_path / "run", 2 * 64, monkeypatch)
    train(debug_cfg("ppo", "eval.every=64", "checkpoint.every=64", "resume=true", total_steps=3 * 64), tmp_path / "run")
    rows = list(csv.DictReader(open(tmp_path / "run" / "eval.csv")))
    per_eval = {int(r["env_steps"]): float(r["cpu_seconds"]) for r in rows}
    assert sorted(per_eval) == [64, 128, 192]
    assert 0 < per_eval[64] < per_eval[128] < per_eval[192]
    final = checkpoint.load_checkpoint(tmp_path / "run" / "model-0-1-1.pt")
    # eval.csv keeps hundredths of a second: the final checkpoint's time, rounded the same way, is never less
    assert per_eval[192] <= round(final["time"]["cpu_seconds"], 2)


def test_a_run_begun_before_the_cpu_column_goes_on_without_it(tmp_path, monkeypatch):
    cfg = debug_cfg("ppo", "eval.every=64", "checkpoint.every=64", total_steps=3 * 64)
    with monkeypatch.context() as patch:  # the version before: eval.csv without cpu_seconds
        patch.setattr(logs, "EVAL_COLUMNS", logs.EVAL_COLUMNS_BEFORE_CPU)
        run_killed(cfg, tmp_path / "run", 2 * 64, monkeypatch)
    train(debug_cfg("ppo", "eval.every=64", "checkpoint.every=64", "resume=true", total_steps=3 * 64), tmp_path / "run")
    with open(tmp_path / "run" / "eval.csv", newline="") as f:
        lines = list(csv.reader(f))
    assert tuple(lines[0]) == logs.EVAL_COLUMNS_BEFORE_CPU  # one header per file: the file's own
    assert {len(line) for line in lines} == {len(logs.EVAL_COLUMNS_BEFORE_CPU)}
    assert sorted({int(line[0]) for line in lines[1:]}) == [64, 128, 192]


# ------------------------------------------------------------------------------------------------ devices
def test_device_names_only_devices_this_machine_has(monkeypatch):

    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device("auto") == torch.device("cuda" if torch.cuda.is_available() else "cpu")
    with pytest.raises(DeviceError, match=r"device=gpu: not a device; allowed: auto, cpu, cuda, cuda:N"):
        resolve_device("gpu")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    for spec in ("cuda", "cuda:1"):
        with pytest.raises(DeviceError, match=rf"device={spec}: no CUDA device is available here"):
            resolve_device(spec)
    assert resolve_device("auto") == torch.device("cpu")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    assert resolve_device("auto") == torch.device("cuda") and resolve_device("cuda:1") == torch.device("cuda", 1)
    with pytest.raises(DeviceError, match=r"device=cuda:2: this machine has 2 CUDA device\(s\): cuda:0 to cuda:1"):
        resolve_device("cuda:2")


def test_deterministic_kernels_are_chosen_on_cuda_only(monkeypatch):
    calls = []
    monkeypatch.setattr(torch, "use_deterministic_algorithms", lambda on, warn_only: calls.append((on, warn_only)))
    monkeypatch.setattr(torch.backends.cudnn, "deterministic", False)
    monkeypatch.delenv("CUBLAS_WORKSPACE_CONFIG", raising=False)
    devices.deterministic_kernels(True, torch.device("cpu"))  # the CPU's kernels repeat as they are
    assert calls == [] and "CUBLAS_WORKSPACE_CONFIG" not in os.environ
    devices.deterministic_kernels(True, torch.device("cuda"))
    assert calls == [(True, True)] and torch.backends.cudnn.deterministic
    assert os.environ["CUBLAS_WORKSPACE_CONFIG"] == ":4096:8"
    devices.deterministic_kernels(False, torch.device("cuda"))
    assert calls[-1] == (False, True) and not torch.backends.cudnn.deterministic
    assert make_cfg("algo=ppo").deterministic is True  # the default


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_a_checkpoint_written_on_cuda_resumes_on_the_cpu(runs, tmp_path, monkeypatch):
    run_killed(debug_cfg("ppo", "device=cuda"), tmp_path / "run", KILL_AT, monkeypatch)
    train(debug_cfg("ppo", "resume=true", "device=cpu"), tmp_path / "run")
    whole = checkpoint.load_checkpoint(runs("ppo")["whole"] / checkpoint.CHECKPOINT)
    resumed = checkpoint.load_checkpoint(tmp_path / "run" / checkpoint.CHECKPOINT)
    assert resumed["config"]["device"] == "cpu" and resumed["counters"] == whole["counters"]
    for name, value in resumed["model"].items():  # the same run, trained on in the CPU's arithmetic
        assert value.shape == whole["model"][name].shape and torch.isfinite(value).all(), name
    assert (tmp_path / "run" / "model-0-1-1.pt").exists()


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has CUDA")
def test_train_script_without_cuda_refuses_device_cuda_in_one_line(tmp_path):
    cmd = [
        sys.executable,
        str(ROOT / "scripts" / "train.py"),
        "algo=ppo",
        "preset=debug",
        "logger=csv",
        "device=cuda",
        f"run.root={tmp_path}",
    ]
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("train.py: error: device=cuda: no CUDA device is available here"), (
        done.stderr
    )
    assert "Traceback" not in done.stdout + done.stderr
    assert not list(tmp_path.iterdir())  # refused before Hydra made the run folder


def test_loaded_policy_moves_to_the_device_asked_for(runs, capsys):
    loaded = load_policy(runs("dqn")["whole"] / "model-0-1-1.pt", device="cpu")
    assert {p.device for p in loaded.model.parameters()} == {torch.device("cpu")}
    with pytest.raises(DeviceError, match="allowed: auto, cpu, cuda, cuda:N"):
        load_policy(runs("dqn")["whole"] / "model-0-1-1.pt", device="tpu")
    from helpers import load_script

    script = load_script("evaluate")
    assert script.parse([f"policy={runs('dqn')['whole'] / 'model-0-1-1.pt'}"]).device == "auto"
    with pytest.raises(EvaluationError, match="device=tpu: not a device; allowed: auto, cpu, cuda"):
        EvaluatedPolicy(str(runs("dqn")["whole"] / "model-0-1-1.pt"), seed=0, device="tpu")
    with pytest.raises(SystemExit) as refused:  # and on the command line, before anything runs
        script.parse([f"policy={runs('dqn')['whole'] / 'model-0-1-1.pt'}", "device=tpu"])
    assert refused.value.code == 2 and "device=tpu: expected auto, cpu, cuda or cuda:N" in capsys.readouterr().err


def test_a_level_from_the_users_own_file_trains(tmp_path):
    """A new level is one YAML file, anywhere: it extends a packaged level and ``level=file`` trains on it."""
    level_file = tmp_path / "levels" / "few-cubes.yaml"
    level_file.parent.mkdir()
    level_file.write_text('extends: "1-2"\ndescription: three food cubes\nresources:\n  food: {count: 3}\n')
    env = evaaa.make_env(str(level_file), num_envs=2, seed=0)
    assert env.level.name == "few-cubes" and env.level.resources["food"].count == 3
    assert env.rollout(4).shape == (2, 4)
    env.close()
    cmd = [
        sys.executable,
        str(ROOT / "scripts" / "train.py"),
        "algo=ppo",
        "preset=debug",
        "logger=csv",
        "progress=false",
        "total_steps=64",
        "threads=1",
        "level=file",
        f"level.file={level_file}",
        f"run.root={tmp_path}",
    ]
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    run_dir = tmp_path / "few-cubes" / "ppo" / "all-squared-debug" / "seed0"  # named after the file's stem
    saved = checkpoint.load_checkpoint(run_dir / checkpoint.CHECKPOINT)
    assert saved["config"]["level"]["file"] == str(level_file)
    assert (run_dir / "model-0-few-cubes.pt").exists()  # the stage carries the registered name


def test_every_algorithm_config_has_its_module():
    """conf/algo/<name>.yaml and the module the registry finds for it are the whole of an algorithm."""
    assert algos.names() == options("algo")
    for name in algos.names():
        module = algos.algorithm(name)
        assert all(callable(getattr(module, f)) for f in algos.FUNCTIONS), name
        assert make_cfg(f"algo={name}").algo.name == name
    assert algos.algorithm("ppo_lstm").train is algos.algorithm("ppo").train  # a variant shares its code
    with pytest.raises(ValueError, match="is not an algorithm: it lacks make_model"):
        algos.algorithm("training")  # a module of the package, but not an algorithm
    with pytest.raises(ValueError, match="unknown algo '../dqn'"):
        algos.algorithm("../dqn")


COIN_FLIP = '''"""Uniform random actions: the smallest algorithm the training loop takes (written by a test)."""
import torch
from tensordict.nn import TensorDictModuleBase
from torch import nn

from evaaa import ACTION_NAMES


class Logits(nn.Module):
    def __init__(self):
        super().__init__()
        self.logits = nn.Parameter(torch.zeros(len(ACTION_NAMES)))


class Flip(TensorDictModuleBase):
    in_keys, out_keys = ["interoception"], ["action"]

    def __init__(self, model):
        super().__init__()
        self.model = model

    def forward(self, td):
        logits = self.model.logits.expand(*td.batch_size, -1)
        td["action"] = torch.distributions.Categorical(logits=logits).sample()
        return td


def make_model(cfg, obs_shapes):
    return Logits()


def make_transforms(cfg, obs_keys, model):
    return []


def make_policy(model):
    return Flip(model)


def train(run):
    model = make_model(run.cfg.algo, run.obs_shapes).to(run.device)
    run.train_env(make_transforms(run.cfg.algo, run.obs_keys, model))
    policy = run.acting(make_policy(model))
    td = run.start(model, {}, make_policy(model), make_transforms(run.cfg.algo, run.obs_keys, model))
    while not run.done:
        _, td = run.step(policy, td)
        run.end_iteration(td)
'''


def test_a_new_algorithm_is_one_module_and_its_config(tmp_path, monkeypatch):
    """A new algorithm is one module plus its config, in a folder of the user's: registered, it trains with the
    debug preset, and its checkpoint loads back through the same registry.  No file of the project is edited."""
    from evaaa_baselines import algos

    (tmp_path / "coin_flip.py").write_text(COIN_FLIP)
    (tmp_path / "conf" / "algo").mkdir(parents=True)
    (tmp_path / "conf" / "algo" / "coin_flip.yaml").write_text("name: coin_flip\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(algos, "_registered", {})
    with pytest.raises(ValueError, match="unknown algo 'coin_flip'; known: dqn, dreamer"):
        algos.algorithm("coin_flip")
    import coin_flip

    algos.register("coin_flip", coin_flip)
    assert algos.algorithm("coin_flip") is coin_flip and "coin_flip" in algos.names()
    with pytest.raises(ValueError, match="lacks make_model"):
        algos.register("broken", object())

    cfg = make_cfg(
        "algo=coin_flip",
        "preset=debug",
        "logger=csv",
        "progress=false",
        f"total_steps={TOTAL}",
        f"hydra.searchpath=[file://{tmp_path / 'conf'}]",
    )
    assert cfg.algo.name == "coin_flip"
    run_dir = train(cfg, tmp_path / "run")
    episodes = read_csv(run_dir / "episodes.csv")
    assert episodes and list(episodes[0]) == [c for c in TRAINING_EPISODE_FIELDS if c != "wall_time"]
    policy = load_policy(run_dir / "model-0-1-1.pt")
    assert policy.algo == "coin_flip"
    env = policy.make_env(num_envs=2, seed=0)
    actions = policy(env.reset())["action"]
    assert actions.shape == (2,) and ((actions >= 0) & (actions < len(evaaa.ACTION_NAMES))).all()
    env.close()


def test_a_time_budget_spent_while_checkpointing_still_ends_with_the_final_model(tmp_path, monkeypatch):
    # the CPU clock runs on while the run evaluates and checkpoints: here the budget is spent during the checkpoint at
    # env step 64.  The stage must still end at an iteration's end that writes the final evaluation and model (it
    # once ended at the loop's own check, after end_iteration had found time left: no final model, and a rerun of
    # bench_train's learn mode trained on)
    from evaaa_baselines import stage

    spent = []
    checkpoint_at = run_loop.Run._checkpoint

    def checkpoint_and_spend(self, td):
        checkpoint_at(self, td)
        spent.append(self.steps)

    monkeypatch.setattr(run_loop.Run, "_checkpoint", checkpoint_and_spend)
    monkeypatch.setattr(stage.StageClock, "out_of_time", lambda self, steps: any(s >= 64 for s in spent))
    cfg = debug_cfg("ppo", "eval.every=64", "checkpoint.every=64", "max_cpu_minutes=1000", total_steps=10**9)
    run_dir = train(cfg, tmp_path / "run")
    final = checkpoint.load_checkpoint(run_dir / "model-0-1-1.pt")
    assert final["env_steps"] == 96  # the iteration after the budget ran out
    assert {r["env_steps"] for r in read_csv(run_dir / "eval.csv")} == {"64", "96"}


def test_a_run_states_its_budget_and_ends_with_its_folder_and_final_evaluation(tmp_path, caplog, capsys):
    # PPO's debug iteration is 32 env steps (2 worlds x 16): 100 asked is 128 trained, and the first line says why;
    # progress=true draws no bar here, where the output is not a terminal
    cfg = debug_cfg("ppo", "progress=true", "eval.every=64", total_steps=100)
    with caplog.at_level(logging.INFO, logger="evaaa_baselines.run"):
        run_dir = train(cfg, tmp_path / "run")
    assert (
        "100 env steps asked: 128 trained, as the stage ends with the iteration that reaches its budget and one "
        "iteration is 32 env steps (2 worlds x 16 steps, then an update)" in caplog.text
    )
    assert "128 env steps (100 asked, in whole iterations of 32)" in caplog.text
    assert "step/s" not in capsys.readouterr().err  # tqdm drew nothing
    final = [r for r in read_csv(run_dir / "eval.csv") if r["env_steps"] == "128"]  # one row per episode
    lines = summary(cfg, run_dir).splitlines()
    assert lines[0] == f"run folder: {run_dir}"
    assert lines[1].startswith(
        f"final evaluation on 1-1 at env step 128 (validation worlds): mean survival "
        f"{sum(int(r['steps']) for r in final) / 2:.0f} steps over 2 episodes"
    )
    assert lines[2].startswith(f"final model: {run_dir / 'model-0-1-1.pt'}")


class _Bars:
    """Stands in for tqdm in baselines/run.py: records every bar's description, total and updates (a bar is drawn as
    though the output were a terminal)."""

    made: list = []

    def __init__(self, *args, total=None, desc="", disable=None, initial=0, **kwargs):
        self.total, self.desc, self.disable, self.n = total, desc, bool(disable), initial
        _Bars.made.append(self)

    def update(self, n=1):
        self.n += n

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        pass

    def set_description(self, desc, refresh=True):
        self.desc = desc

    def set_postfix_str(self, *args, **kwargs):
        pass

    def refresh(self):
        pass


def test_a_finished_run_shows_its_final_evaluation_beside_random_and_stand_still_on_the_same_worlds(
    tmp_path, monkeypatch
):
    # episodes long enough for the three to differ: the debug preset's 48-step cap lifted to 1-1's own
    cfg = debug_cfg("ppo", "progress=true", "eval.episodes=2", "++env.overrides.episode.max_steps=5000", total_steps=32)
    _Bars.made = []
    monkeypatch.setattr(run_loop, "tqdm", _Bars)
    run_dir = train(cfg, tmp_path / "run")
    # the final evaluation counted its episodes on a bar of its own, below the (full) training bar
    (final,) = [b for b in _Bars.made if b.desc.startswith("final evaluation on 1-1")]
    assert final.total == 2 and final.n == 2 and not final.disable
    beside = training.reference_survival(cfg, run_dir)
    assert set(beside) == {"random", "still"}
    # the same worlds and settings as the final evaluation: standing still there lasts as long as a zero action does
    # on the seed's validation worlds with the run's level settings (one episode per world, from the seed's reset)
    env = evaaa.make_env(
        "1-1", num_envs=2, modalities=["interoception"], info=True, worlds="validation", **env_overrides(cfg)
    )
    env.set_seed(cfg.seed, static_seed=True)
    try:
        still = evaluate(env, lambda td: td.set("action", torch.zeros(2, dtype=torch.long)))
    finally:
        env.close()
    assert beside["still"] == still.survival_mean > 48  # past the debug cap: the run's own level settings
    lines = summary(cfg, run_dir, beside).splitlines()
    assert lines[1].startswith("final evaluation on 1-1 at env step 32")
    assert lines[2] == (
        f"on the same worlds: random {beside['random']:.0f}, stand-still {beside['still']:.0f} steps (mean survival)"
    )
    assert lines[3].startswith("final model:")


def test_ppo_reports_each_gradient_step_as_it_ends(tmp_path, monkeypatch):
    reported = []
    real = run_loop.Run.updated

    def updated(self, count, seconds, total, ratio=None):
        reported.append((count, total))
        return real(self, count, seconds, total, ratio)

    monkeypatch.setattr(run_loop.Run, "updated", updated)
    cfg = debug_cfg("ppo", total_steps=64)
    train(cfg, tmp_path / "run")
    per_iteration = cfg.algo.epochs * cfg.algo.num_minibatches
    assert reported == [(1, n) for n in range(1, 2 * per_iteration + 1)]  # two iterations of 32 env steps


def test_two_ctrl_c_inside_one_long_call_still_stop_the_run_at_once(tmp_path, monkeypatch, capsys):
    # Python runs a signal handler only between bytecodes, and two SIGINTs inside one long C call (a gradient step's
    # backward pass) reach it as one call: the watcher thread counts them as they arrive. The long call here is
    # PBKDF2, which releases the GIL and never looks at signals, as a torch backward pass does
    def long_call(iterations: int) -> float:
        began = time.perf_counter()
        hashlib.pbkdf2_hmac("sha256", b"evaaa", b"salt", iterations)
        return time.perf_counter() - began

    iterations = int(100_000 * 2.5 / max(long_call(100_000), 1e-3))  # about 2.5 s here
    ended: list[float] = []
    monkeypatch.setattr(training.StopRequest, "GRACE", 0.5)
    monkeypatch.setattr(training.os, "_exit", lambda code: ended.append(time.perf_counter()) if code == 130 else None)

    def ctrl_c_twice():
        for _ in range(2):
            time.sleep(0.3)
            os.kill(os.getpid(), signal.SIGINT)

    with training._graceful_interrupts(tmp_path / "run"):
        threading.Thread(target=ctrl_c_twice).start()
        try:
            began = time.perf_counter()
            long_call(iterations)
            returned = time.perf_counter()
        except KeyboardInterrupt:  # the handler's own count, had the two signals not arrived inside the call
            returned = time.perf_counter()
    assert ended and ended[0] < returned, (ended, began, returned)  # the process was ended while the call ran
    assert "stopped at once, before the first checkpoint" in capsys.readouterr().err
