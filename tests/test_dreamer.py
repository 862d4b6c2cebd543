"""DreamerV3 (``algo=dreamer`` / ``dreamer_xs``): the sizes compose as documented; only the enabled observation keys
are encoded and decoded; a debug smoke run trains (world-model, actor and critic losses finite and logged), keeps its
replay buffer memory-mapped in the run directory (not copied into the checkpoint) and writes open-loop pictures; a run
killed between checkpoints and resumed ends exactly where an uninterrupted run ends, also after the buffer has wrapped
and the killed process overwrote rows, also resumed on another ``device`` setting, and with the buffer in memory; the
bar says prefill, then counts gradient steps; the loaded policy carries its recurrent state and
``scripts/evaluate.py`` evaluates a Dreamer checkpoint."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
from pathlib import Path

import matplotlib.image
import pytest
import torch
import yaml
from helpers import RESUME_DEVICE, load_script, read_csv, train_scalars
from hydra import compose, initialize_config_dir
from tensordict import TensorDict

import evaaa
from evaaa_baselines import checkpoint, dreamer, evaluate, load_policy
from evaaa_baselines import run as run_loop
from evaaa_baselines.config import observation_keys, register_levels
from evaaa_baselines.devices import resolve_device
from evaaa_baselines.dreamer import model as dreamer_model
from evaaa_baselines.dreamer import probes as dreamer_probes
from evaaa_baselines.dreamer import replay as dreamer_replay
from evaaa_baselines.nets import symlog
from evaaa_baselines.paths import CONF_DIR
from evaaa_baselines.training import train

register_levels()

ROOT = Path(__file__).resolve().parents[1]
TOTAL = 256  # env steps: 128 per world with the debug preset's 2 worlds
KILL_AT = 160  # the last checkpoint before it is at 128 (debug: every 64 env steps)
SHAPES = {"pixels": (64, 64, 3), "interoception": (4,), "olfaction": (10,), "thermoception": (8,), "collision": (10,)}


def make_cfg(*overrides: str):
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        return compose("config", overrides=list(overrides))


def debug_cfg(*extra: str, algo: str = "dreamer"):
    # one torch thread: these tiny networks gain nothing from more, and tests may share the machine
    return make_cfg(
        f"algo={algo}", "preset=debug", "logger=csv", "progress=false", "threads=1", f"total_steps={TOTAL}", *extra
    )


# ------------------------------------------------------------------------------------------------ config and model
def test_sizes_s_as_the_paper_xs_and_debug_smaller():
    s, xs, debug = make_cfg("algo=dreamer").algo, make_cfg("algo=dreamer_xs").algo, debug_cfg().algo
    assert (s.name, s.size, xs.name, xs.size) == ("dreamer", "S", "dreamer_xs", "XS")
    assert (s.model.dense, s.model.mlp_layers, s.model.cnn.depth, s.model.recurrent, s.model.hidden) == (
        512,
        2,
        32,
        512,
        512,
    )  # SPEC §12, size S
    assert (s.model.stochastic, s.model.classes, s.model.bins, s.horizon) == (32, 32, 255, 15)
    assert (s.batch_size, s.sequence_length, s.replay_ratio, s.buffer_size) == (16, 64, 1.0, 1_000_000)
    for small in (xs, debug):
        assert small.model.dense < s.model.dense and small.model.recurrent < s.model.recurrent
        assert small.model.cnn.depth < s.model.cnn.depth and small.model.stochastic < s.model.stochastic
    assert debug_cfg(algo="dreamer_xs").algo.model.dense == debug.model.dense
    assert make_cfg("algo=dreamer_xs", "modality=no_vision").run.name == "1-1/dreamer_xs/no_vision-squared_death/seed0"


@pytest.mark.parametrize("modality", ["all", "no_vision", "no_olfaction"])
def test_only_the_enabled_keys_are_encoded_and_decoded(modality):
    cfg = debug_cfg(f"modality={modality}")
    keys = observation_keys(cfg)
    model = dreamer.make_model(cfg.algo, {k: SHAPES[k] for k in keys})
    assert hasattr(model.encoder, "cnn") == ("pixels" in keys) == hasattr(model.decoder, "cnn")
    vectors = [k for k in keys if k != "pixels"]
    assert sorted(model.decoder.heads) == sorted(vectors)
    assert model.encoder.mlp.model[0].in_features == sum(SHAPES[k][0] for k in vectors)
    n = 3
    latent = model.decoder(torch.zeros(n, model.state_dim), torch.zeros(n, model.belief_dim))
    assert [tuple(x.shape[1:]) for x in latent] == [SHAPES[k] for k in keys]


def test_without_pixel_decoding_the_pixels_are_encoded_and_learn_from_the_rest_of_the_loss():
    from test_dreamer_update import random_batch

    from evaaa_baselines.dreamer.update import Learner

    cfg = debug_cfg("algo.world_model.decode_pixels=false")
    keys = observation_keys(cfg)
    torch.manual_seed(0)
    model = dreamer.make_model(cfg.algo, {k: SHAPES[k] for k in keys})
    assert "pixels" in keys and hasattr(model.encoder, "cnn") and not hasattr(model.decoder, "cnn")
    assert model.decoder.keys == tuple(k for k in keys if k != "pixels")
    learner = Learner(cfg.algo, model, torch.device("cpu"))
    batch = random_batch(keys, torch.Generator().manual_seed(0))
    assert "pixels" not in learner.model_loss.loss.tensor_keys.pixels  # the reconstruction loss's keys
    before = [p.detach().clone() for p in model.encoder.cnn.parameters()]
    metrics = learner.update(batch)
    assert all(torch.isfinite(v).all() for v in metrics.values())
    # the image encoder still learns: through the posterior, from the vector keys', reward's and continue's losses
    assert any(not torch.equal(a, b) for a, b in zip(before, model.encoder.cnn.parameters(), strict=True))
    with pytest.raises(ValueError, match="decode_pixels=false needs a vector observation key"):
        dreamer.make_model(cfg.algo, {"pixels": SHAPES["pixels"]})


# ------------------------------------------------------------------------------------------------ runs
class Killed(Exception):
    """Stands for the process being killed between two checkpoints."""


def killed_and_resumed(run_dir: Path, *overrides: str, resume_with: tuple[str, ...] = ()) -> dict:
    """Train until KILL_AT env steps and stop as a kill would (that iteration's checkpoint is lost), then resume;
    returns the checkpoint the kill left."""
    end_iteration = run_loop.Run.end_iteration

    def killing(self, td):
        if self.steps >= KILL_AT:
            raise Killed
        end_iteration(self, td)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(run_loop.Run, "end_iteration", killing)
        with pytest.raises(Killed):
            train(debug_cfg(*overrides), run_dir)
    at_kill = checkpoint.load_checkpoint(run_dir / checkpoint.CHECKPOINT)
    train(debug_cfg(*overrides, *resume_with, "resume=true"), run_dir)
    return at_kill


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """An uninterrupted debug run (device=auto), and the same run killed at KILL_AT then resumed with
    device=RESUME_DEVICE (cpu, or auto on a CUDA machine)."""
    root = tmp_path_factory.mktemp("dreamer")
    train(debug_cfg(), root / "whole")
    at_kill = killed_and_resumed(root / "resumed", resume_with=(f"device={RESUME_DEVICE}",))
    return {
        "whole": root / "whole",
        "resumed": root / "resumed",
        "steps_at_kill_checkpoint": at_kill["counters"]["steps"],
    }


def replay_rows(run_dir: Path) -> TensorDict:
    """The rows a run's memory-mapped replay buffer holds (as its last checkpoint counts them)."""
    state = checkpoint.load_checkpoint(run_dir / checkpoint.CHECKPOINT)["components"]["replay"]
    rows = state["length"] // 2  # the debug preset's 2 worlds
    return TensorDict.load_memmap(run_dir / "replay" / "0-1-1")[:rows]


def same_training(a: dict, b: dict) -> None:
    """Two checkpoints hold the same counters, networks, optimiser states and critics."""
    assert a["counters"] == b["counters"]
    assert a["components"]["counters"] == b["components"]["counters"]
    for name, value in a["model"].items():
        assert torch.equal(value, b["model"][name]), name
    for name in ("optimizer_world_model", "optimizer_actor", "optimizer_critic"):
        x, y = a["components"][name]["state"], b["components"][name]["state"]
        assert x.keys() == y.keys()
        assert all(torch.equal(v, y[i][k]) for i in x for k, v in x[i].items()), name
    for name, value in a["components"]["value_loss"].items():  # critic and its slow target
        assert torch.equal(value, b["components"]["value_loss"][name]), name


def test_smoke_run_trains_logs_finite_losses_and_checkpoints_the_buffer(runs):
    run_dir = runs["whole"]
    state = checkpoint.load_checkpoint(run_dir / checkpoint.CHECKPOINT)
    assert state["algo"] == "dreamer" and state["counters"]["steps"] == TOTAL
    updates = state["components"]["counters"]["updates"]
    cfg = debug_cfg().algo
    assert updates == int(cfg.replay_ratio * (TOTAL - cfg.learning_starts)) + 1  # the replay ratio is kept
    replay = state["components"]["replay"]
    # the rows are in the memory-mapped files, not in the checkpoint; the buffer has not wrapped: nothing to guard
    assert replay["on_disk"].endswith("replay/0-1-1") and replay["length"] == TOTAL and replay["guard_rows"] is None
    rows = replay_rows(run_dir)
    assert rows.shape == (TOTAL // 2, 2) and rows["next", "pixels"].dtype == torch.uint8  # every step of both worlds
    assert rows["next", "pixels"].float().std() > 0 and (rows["world"] == torch.arange(2)).all()
    assert {"optimizer_world_model", "optimizer_actor", "optimizer_critic", "value_loss", "return_norm"} <= set(
        state["components"]
    )
    assert (run_dir / "model-0-1-1.pt").exists() and not list(run_dir.glob(".*.tmp"))

    scalars = train_scalars(run_dir)
    for name in (
        "model_reco",
        "model_reward",
        "model_continue",
        "model_dynamic",
        "model_representation",
        "actor_loss",
        "actor_entropy",
        "critic_loss",
        "return_scale",
    ):
        assert scalars.get(name), f"{name} is not logged"
        assert all(math.isfinite(float(v)) for v in scalars[name].values()), name
    assert [int(r["env_steps"]) for r in read_csv(run_dir / "eval.csv")] == [128, 128, 256, 256]  # 2 episodes each
    assert len(read_csv(run_dir / "episodes.csv")) >= 2


def test_open_loop_pictures_show_real_and_imagined_frames(runs):
    pictures = sorted((runs["whole"] / "openloop").glob("openloop-0-1-1-*.png"))
    assert pictures, "no open-loop picture written"
    image = matplotlib.image.imread(pictures[-1])
    o = debug_cfg().algo.openloop
    # per sequence: real, model and error rows of 64-pixel frames (2-pixel gaps); one column per step
    assert image.shape[0] == o.sequences * (3 * 66 + 4) and image.shape[1] == (o.context + o.horizon) * 66
    assert image[:64, :64].std() > 0  # a real frame, not a blank


def test_killed_and_resumed_run_equals_uninterrupted_run(runs):
    # killed under device=auto, resumed under device=cpu (on a CPU machine): the checkpoint loads under either setting
    assert runs["steps_at_kill_checkpoint"] < KILL_AT
    whole = checkpoint.load_checkpoint(runs["whole"] / checkpoint.CHECKPOINT)
    resumed = checkpoint.load_checkpoint(runs["resumed"] / checkpoint.CHECKPOINT)
    assert (whole["config"]["device"], resumed["config"]["device"]) == ("auto", RESUME_DEVICE)
    same_training(whole, resumed)
    assert (replay_rows(runs["whole"]) == replay_rows(runs["resumed"])).all()
    assert train_scalars(runs["whole"]) == train_scalars(runs["resumed"])
    assert read_csv(runs["whole"] / "episodes.csv") == read_csv(runs["resumed"] / "episodes.csv")
    assert read_csv(runs["whole"] / "eval.csv") == read_csv(runs["resumed"] / "eval.csv")


def test_a_wrapped_buffer_resumes_exactly_although_the_killed_run_overwrote_rows(tmp_path):
    # 32 rows per world, written 80 times by the kill: the buffer has wrapped, and after its last checkpoint (at 128)
    # the killed process overwrote 16 rows that the resumed run samples (16 gradient steps) before rewriting them
    small = ("algo.buffer_size=64", "checkpoint.every=32", "algo.replay_ratio=0.5")
    train(debug_cfg(*small), tmp_path / "whole")
    at_kill = killed_and_resumed(tmp_path / "resumed", *small)
    guarded = at_kill["components"]["replay"]
    assert at_kill["counters"]["steps"] == 128
    assert guarded["length"] == 64 and len(guarded["guard_index"]) == 18  # checkpoint.every / 2 worlds + 2
    whole = checkpoint.load_checkpoint(tmp_path / "whole" / checkpoint.CHECKPOINT)
    resumed = checkpoint.load_checkpoint(tmp_path / "resumed" / checkpoint.CHECKPOINT)
    same_training(whole, resumed)
    assert (replay_rows(tmp_path / "whole") == replay_rows(tmp_path / "resumed")).all()


def test_a_buffer_in_memory_is_checkpointed_and_resumes_exactly(tmp_path):
    train(debug_cfg("algo.buffer_on_disk=false"), tmp_path / "whole")
    killed_and_resumed(tmp_path / "resumed", "algo.buffer_on_disk=false")
    whole = checkpoint.load_checkpoint(tmp_path / "whole" / checkpoint.CHECKPOINT)
    resumed = checkpoint.load_checkpoint(tmp_path / "resumed" / checkpoint.CHECKPOINT)
    assert not (tmp_path / "whole" / "replay").exists()
    rows = whole["components"]["replay"]["rows"]
    assert rows.shape == (TOTAL // 2, 2) and (rows == resumed["components"]["replay"]["rows"]).all()
    same_training(whole, resumed)
    with pytest.raises(ValueError, match="algo.buffer_on_disk"):  # a checkpoint's buffer stays where it was made
        train(debug_cfg("resume=true", "total_steps=512"), tmp_path / "whole")


def test_only_memory_mapped_batches_go_to_a_gpu_through_pinned_memory(tmp_path):
    # a buffer in memory lives on the training device: its batches are there already and cannot be pinned (on a GPU
    # that raised at the first gradient step); memory-mapped rows are read on the host and pinned for the copy
    shape = dict(capacity=64, num_envs=2, sequence_length=8, batch_size=2)
    in_memory = dreamer_replay.SequenceReplay(**shape)
    mapped = dreamer_replay.SequenceReplay(**shape, directory=tmp_path / "replay")
    assert not in_memory.pins and not mapped.pins  # on the CPU nothing is pinned
    in_memory.device = mapped.device = torch.device("cuda")  # as a run with device=cuda makes them (CPU-only here)
    assert not in_memory.pins and mapped.pins


def test_a_buffer_larger_than_the_memory_is_refused_naming_both(tmp_path, monkeypatch):
    monkeypatch.setattr(dreamer_replay, "available_memory", lambda device: 10_000_000)
    where = resolve_device("auto").type  # a buffer in memory lives on the training device
    with pytest.raises(
        ValueError,
        match=rf"algo.buffer_size=1,024 transitions need .* but {where} has 0.01 GB "
        r"available: use algo.buffer_on_disk=true",
    ):
        train(debug_cfg("algo.buffer_on_disk=false"), tmp_path / "run")


def test_the_bar_says_prefill_then_counts_gradient_steps(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)  # the bar is drawn in a terminal only
    train(debug_cfg("progress=true", "total_steps=64"), tmp_path / "run")
    bar = capsys.readouterr().err.replace("\r", "\n")
    assert "dreamer 1-1 prefill:" in bar  # before learning_starts
    trained = [line for line in bar.splitlines() if line.startswith("dreamer 1-1:") and "s/update" in line]
    assert trained, bar[-2000:]
    assert all(k in trained[-1] for k in ("env ", "/s (avg ", "grad ", "ratio ", "ETA ")), trained[-1]
    assert "64/64" in trained[-1]


def test_a_budget_within_the_prefill_is_refused_before_anything_is_written(tmp_path):
    # DreamerV3-XS fills 16,384 env steps before it learns: 2,000 would write an untrained "final model"
    done = subprocess.run(
        [sys.executable, "scripts/train.py", "algo=dreamer_xs", "total_steps=2000", f"run.root={tmp_path}"],
        cwd=Path(__file__).resolve().parents[1],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert "total_steps=2000: DreamerV3 takes its first gradient step after 16,384 env steps" in done.stderr
    assert not any(tmp_path.iterdir())
    # a curriculum's stages each fill their own replay: the per-stage budget is what is checked
    cfg = make_cfg("algo=dreamer_xs", "level=curriculum", "level.stage_steps=16384")
    assert dreamer.check_config(cfg).startswith("level.stage_steps=16384:")
    assert dreamer.check_config(make_cfg("algo=dreamer_xs", "total_steps=16385")) is None


def test_dreamer_xs_trains_on_squared_death_unless_the_command_names_a_reward():
    # conf/algo/dreamer_xs.yaml and docs/training.md: the reward DreamerV3-XS is meant for
    xs = make_cfg("algo=dreamer_xs")
    assert xs.reward.name == "squared_death" and xs.reward.overrides.terminal_penalty == -3000.0
    assert xs.run.name == "1-1/dreamer_xs/all-squared_death/seed0"
    for reward in ("squared", "original"):  # a reward named in the command wins
        assert make_cfg("algo=dreamer_xs", f"reward={reward}").reward.name == reward
    for algo in ("dreamer", "ppo", "dqn", "ppo_lstm"):  # the others keep the project's default
        assert make_cfg(f"algo={algo}").reward.name == "squared"
    # recorded protocols name their rewards, so their commands compose as they ran
    for path in sorted((CONF_DIR / "protocol").glob("*.yaml")):
        arm = (yaml.safe_load(path.read_text()).get("algorithms") or {}).get("dreamer_xs")
        if arm is not None:
            assert any(str(o).startswith("reward=") for o in arm.get("overrides", [])), path.name


def test_a_time_budget_spent_within_the_prefill_says_the_final_model_is_untrained(tmp_path, caplog):
    train(debug_cfg("max_minutes=0.00001"), tmp_path / "run")
    assert "before its first gradient step (at 32): its final model is the untrained network" in caplog.text
    assert (tmp_path / "run" / "model-0-1-1.pt").is_file()


# ------------------------------------------------------------------------------------------------ loading
def test_loaded_policy_carries_its_recurrent_state(runs):
    loaded = load_policy(runs["whole"] / "model-0-1-1.pt", modalities=evaaa.MODALITIES)
    assert loaded.algo == "dreamer" and loaded.obs_keys == evaaa.MODALITIES
    env = loaded.make_env(num_envs=2, seed=3)
    try:
        td = env.reset()
        assert td["is_init"].all() and not td["belief"].any()
        td = loaded(td)
        belief, action = td["belief"].clone(), td["prev_action"].clone()
        assert belief.any() and td["action"].shape == (2,) and (action.argmax(-1) == td["action"]).all()
        _, td = env.step_and_maybe_reset(td)
        assert not td["is_init"].any()
        assert torch.equal(td["belief"], belief) and torch.equal(td["prev_action"], action)  # carried over
        env.set_seed(3, static_seed=True)
        first = evaluate(env, loaded.policy)
        env.set_seed(3, static_seed=True)
        second = evaluate(env, loaded.policy)
        assert len(first.survival) == 2 and all(0 < s <= 48 for s in first.survival)
        assert first == second  # an evaluation from a reset depends on the weights and the seed alone
    finally:
        env.close()


def test_evaluate_script_runs_a_dreamer_checkpoint(runs, tmp_path):
    cmd = [
        sys.executable,
        str(ROOT / "scripts" / "evaluate.py"),
        f"policy={runs['whole'] / 'checkpoint.pt'}",
        "levels=[1-1]",
        "episodes=2",
        "num_envs=2",
        f"out={tmp_path}",
    ]
    done = subprocess.run(
        cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300, env={**os.environ, "OMP_NUM_THREADS": "1"}
    )
    assert done.returncode == 0, done.stderr[-3000:]
    rows = read_csv(tmp_path / "episodes.csv")
    assert len(rows) == 2 and all(r["level"] == "1-1" for r in rows)


def test_the_probe_decodes_the_evs_of_a_run_and_says_how_far_off_they_are(runs, capsys):
    from evaaa import EV_NAMES

    result = dreamer_probes.ev_decoding_errors(runs["whole"], sequences=4)
    assert result["sequences"] == 4 and result["env_steps"] > 0
    assert list(result["other"]) == list(EV_NAMES)
    assert all(math.isfinite(v) and v >= 0 for v in result["other"].values())
    assert result["eating_steps"] > 0 or all(math.isnan(v) for v in result["eating"].values())
    assert list(result["linear_probe"]) == [
        "nothing",
        "embedding",
        "stochastic latent",
        "deterministic state",
        "latent (both)",
    ]
    assert all(math.isfinite(v) and v <= 1 for shares in result["linear_probe"].values() for v in shares.values())
    values = dreamer_probes.imagined_action_values(runs["whole"], sequences=4, samples=2)
    assert list(values["groups"]) == ["every state", "ate or drank", "ate nothing", "1-5 steps before eating"]
    every = values["groups"]["every state"]
    assert every["states"] > 0 and values["return_scale"] >= 1
    assert list(every["policy"]) == list(evaaa.ACTION_NAMES)
    assert sum(every["policy"].values()) == pytest.approx(1, abs=1e-5)
    assert sum(every["value_over_mean"].values()) == pytest.approx(0, abs=1e-3)  # against the mean of the five
    assert sum(every["best_share"].values()) == pytest.approx(1)
    assert list(every["ev_change"]["eat"]) == list(EV_NAMES)
    probe = load_script("probe_dreamer")
    assert probe.main([f"run={runs['whole']}", "sequences=4", "samples=2"]) == 0
    out = capsys.readouterr().out
    assert "mean absolute error of the decoded EVs" in out and "deterministic state" in out
    assert "one imagined step of each action" in out and "ate nothing" in out


def test_the_probe_reads_other_networks_of_the_run_on_its_replay(runs, capsys, tmp_path):
    # networks whose actor has no preference (its logits head zeroed): the probe must read these, not the checkpoint's
    state = checkpoint.load_checkpoint(runs["whole"] / "model-0-1-1.pt")
    for k in ("actor.module.0.module.logits_head.weight", "actor.module.0.module.logits_head.bias"):
        state["model"][k] = torch.zeros_like(state["model"][k])
    state["env_steps"] = 12
    flat = tmp_path / "model-flat.pt"
    checkpoint.save_checkpoint(state, flat)
    own = dreamer_probes.imagined_action_values(runs["whole"], sequences=4, samples=2)["groups"]["every state"][
        "policy"
    ]
    values = dreamer_probes.imagined_action_values(runs["whole"], sequences=4, samples=2, model_file=flat)
    assert values["env_steps"] == 12
    assert list(values["groups"]["every state"]["policy"].values()) == pytest.approx([0.2] * 5)
    assert list(own.values()) != pytest.approx([0.2] * 5)
    assert dreamer_probes.ev_decoding_errors(runs["whole"], sequences=4, model_file=flat)["env_steps"] == 12
    probe = load_script("probe_dreamer")
    assert probe.main([f"run={runs['whole']}", f"model={flat}", "sequences=4", "samples=2"]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"{flat}: 12 env steps") and "(the run's last checkpoint's)" in out
    other = {**state, "algo": "ppo"}
    checkpoint.save_checkpoint(other, tmp_path / "ppo.pt")
    with pytest.raises(SystemExit):
        probe.main([f"run={runs['whole']}", f"model={tmp_path / 'ppo.pt'}"])
    assert "not the networks of this run's algorithm and observations (dreamer, " in capsys.readouterr().err


def test_a_fresh_world_model_fits_a_runs_replay_and_measures_what_eating_does(runs, capsys, tmp_path):
    seen = []
    rows = dreamer_probes.fit_world_model(
        runs["whole"], updates=6, every=3, overrides=["consume_share=0.5"], held_out=0.25, report=seen.append
    )
    assert [r["updates"] for r in rows] == [0, 3, 6] and seen == rows
    assert all(math.isfinite(r["eat_effect_nothing"]) or math.isnan(r["eat_effect_nothing"]) for r in rows)
    # with no held-out eating step there is nothing to measure: NaN, not a made-up 0
    assert all(math.isnan(r["eat_effect"]) == (r["held_out_eating_steps"] == 0) for r in rows)
    assert all("eat_effect_trained" in r for r in rows)  # the same on eating steps it trains on
    # the trained latent's read-out of "this press will eat" comes with the last measurement only
    assert {"latent_auc_embedding", "latent_auc_belief"} <= set(rows[-1]) and "latent_auc_belief" not in rows[0]
    blind = dreamer_probes.fit_world_model(
        runs["whole"], updates=1, every=1, held_out=0.25, keys=["interoception", "olfaction"]
    )
    assert len(blind) == 2  # without the pixels' encoder and decoder
    assert blind[0]["world_model_parameters"] < rows[0]["world_model_parameters"]
    with pytest.raises(ValueError, match="keys must include interoception"):
        dreamer_probes.fit_world_model(runs["whole"], updates=1, every=1, held_out=0.25, keys=["pixels"])
    with pytest.raises(ValueError, match="too few to hold out"):
        dreamer_probes.fit_world_model(runs["whole"], updates=1, every=1, held_out=0.99)
    fit = load_script("fit_world_model")
    out = tmp_path / "fit.csv"
    assert fit.main([f"run={runs['whole']}", "updates=2", "every=1", "held_out=0.25", f"out={out}", "threads=1"]) == 0
    printed = capsys.readouterr().out
    assert "eat effect" in printed and "on trained" in printed and "held-out AUC" in printed
    assert "read-out of the trained latent" in printed
    readout = dreamer_probes.eat_success_readout(runs["whole"])
    assert readout["ate"] <= readout["presses"] and "all of them" in readout["auc"]
    assert [r["updates"] for r in read_csv(out)] == ["0", "1", "2"]


def test_the_world_model_fit_leaves_out_steps_taken_on_a_reset_observation_it_never_stored(runs, monkeypatch):
    # an episode's first step was taken on the reset observation, which the replay does not store: no measurement
    # may read the previous episode's last observation as the one eaten on
    state, data, num_envs, rows = dreamer_probes._run_replay(runs["whole"])
    data = data.clone()  # in memory: the run's own files stay as they are
    held_out_rows = torch.arange(int(rows * 0.75) + 16, rows)[:3]  # beyond the 16 steps of context before each
    assert len(held_out_rows) == 3
    data["next", "consumed"].zero_()
    data["next", "consumed"][held_out_rows, 0] = True
    data["is_init"].zero_()
    monkeypatch.setattr(dreamer_probes, "_run_replay", lambda run_dir: (state, data, num_envs, rows))
    fit = dreamer_probes.fit_world_model(runs["whole"], updates=0, every=1, held_out=0.25)
    assert fit[0]["held_out_eating_steps"] == 3
    data["is_init"][held_out_rows[:2], 0] = True  # two of the three meals were an episode's first step
    row = dreamer_probes.fit_world_model(runs["whole"], updates=0, every=1, held_out=0.25)[0]
    assert row["held_out_eating_steps"] == 1


@pytest.mark.skipif(torch.cuda.is_available(), reason="the refusal is for machines without CUDA")
def test_the_world_model_fit_refuses_a_device_this_machine_lacks_naming_the_key(runs, capsys):
    fit = load_script("fit_world_model")
    with pytest.raises(SystemExit):
        fit.main([f"run={runs['whole']}", "updates=1", "device=cuda"])
    assert "fit_world_model.py: error: device=cuda: no CUDA device is available here" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        fit.main([f"run={runs['whole']}", "updates=1", "device=tpu"])
    assert "device=tpu: not a device; allowed: auto, cpu, cuda, cuda:N" in capsys.readouterr().err


def test_the_logistic_readout_tells_what_the_features_carry_and_not_what_they_lack():
    gen = torch.Generator().manual_seed(0)
    labels = torch.rand(600, generator=gen) < 0.1  # rare, as eating is
    carrying = torch.randn(600, 5, generator=gen)
    carrying[:, 2] += 3 * labels  # one feature says it
    fit = torch.arange(600) % 2 == 0
    assert dreamer_probes.logistic_readout_auc(carrying, labels, fit) > 0.95
    assert abs(dreamer_probes.logistic_readout_auc(torch.randn(600, 5, generator=gen), labels, fit) - 0.5) < 0.15
    assert math.isnan(dreamer_probes.logistic_readout_auc(carrying, torch.zeros(600, dtype=torch.bool), fit))


def test_imagining_each_action_takes_that_action_and_averages_the_draws():
    draws = iter(range(100))

    def prior(state, belief, onehot):  # the next belief is the action taken; the next state a new draw each time
        return None, torch.full_like(state, float(next(draws))), onehot

    state, belief = torch.zeros(3, 2), torch.zeros(3, 5)
    out = dreamer_probes.imagine_each_action(
        prior,
        state,
        belief,
        samples=4,
        paid=lambda s, b: b[:, evaaa.ACTION_NAMES.index("eat")] * 10,
        drawn=lambda s, b: s[:, 0],
    )
    assert out["paid"].shape == (3, dreamer_model.NUM_ACTIONS)
    assert out["paid"][:, evaaa.ACTION_NAMES.index("eat")].eq(10).all()  # only eating pays, in every state
    assert out["paid"].sum(1).eq(10).all()
    # action a's four draws are 4a .. 4a + 3: their mean
    assert out["drawn"][0].tolist() == [4 * a + 1.5 for a in range(dreamer_model.NUM_ACTIONS)]


def test_the_linear_probe_reads_what_the_features_hold_and_not_what_they_lack():
    gen = torch.Generator().manual_seed(0)
    target = torch.randn(400, 4, generator=gen) * 5
    fit = torch.arange(400) % 2 == 0
    mixing = torch.randn(4, 16, generator=gen)
    # the targets' symlog (as the model codes them), linearly mixed
    holding = symlog(target) @ mixing + 0.001 * torch.randn(400, 16, generator=gen)
    lacking = torch.randn(400, 16, generator=gen)  # nothing of them
    assert float(dreamer_probes.linear_probe_r2(holding, target, fit).min()) > 0.99
    assert float(dreamer_probes.linear_probe_r2(lacking, target, fit).max()) < 0.1
    nothing = dreamer_probes.linear_probe_r2(torch.zeros(400, 1), target, fit)  # the fitted mean
    assert float(nothing.abs().max()) < 0.05


def test_ctrl_c_stops_between_two_gradient_steps_and_the_resume_finishes_the_iteration(tmp_path, monkeypatch):
    # two gradient steps per iteration (replay ratio 1, two worlds): the Ctrl-C after the 40th of them leaves the
    # 41st owed by the same iteration; a size-S gradient step takes a minute on a CPU, an iteration several
    ratio = ("algo.replay_ratio=1.0", "total_steps=96")
    train(debug_cfg(*ratio), tmp_path / "whole")
    updated = run_loop.Run.updated

    def ctrl_c_after_40(self, count, seconds, total, ratio=None):
        updated(self, count, seconds, total, ratio)
        if total == 40:
            os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(run_loop.Run, "updated", ctrl_c_after_40)
    with pytest.raises(run_loop.Interrupted, match="interrupted at env step"):
        train(debug_cfg(*ratio), tmp_path / "resumed")
    monkeypatch.undo()
    at_stop = checkpoint.load_checkpoint(tmp_path / "resumed" / checkpoint.CHECKPOINT)
    assert at_stop["components"]["counters"]["updates"] == 40  # not the 41st: the step under way was the last
    train(debug_cfg(*ratio, "resume=true"), tmp_path / "resumed")
    whole = checkpoint.load_checkpoint(tmp_path / "whole" / checkpoint.CHECKPOINT)
    resumed = checkpoint.load_checkpoint(tmp_path / "resumed" / checkpoint.CHECKPOINT)
    same_training(whole, resumed)
    assert read_csv(tmp_path / "whole" / "eval.csv") == read_csv(tmp_path / "resumed" / "eval.csv")
