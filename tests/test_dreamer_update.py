"""DreamerV3's gradient step in three phases (``baselines/dreamer/update.py``, issue 46): the same numbers as the
single eager function it replaced, nothing read on the host inside it, the replay's O(batch) sampler drawing
exactly the batches torchrl's ``SliceSampler`` drew, and exact resumes with the next batch drawn ahead
(``algo.update.prefetch``)."""

from __future__ import annotations

import copy
import os
import signal

import pytest
import torch
from hydra import compose, initialize_config_dir
from tensordict import TensorDict
from torch import nn
from torchrl.data import SliceSampler
from torchrl.objectives import DreamerV3ActorLoss, DreamerV3ValueLoss, SoftUpdate
from torchrl.objectives.utils import ValueEstimators

from evaaa_baselines import checkpoint
from evaaa_baselines import run as run_loop
from evaaa_baselines.config import observation_keys, register_levels
from evaaa_baselines.dreamer import model as dreamer_model
from evaaa_baselines.dreamer.losses import WorldModelLoss, diagnostics, replay_value_loss
from evaaa_baselines.dreamer.model import LATENT, continuation_model, imagination_env, value_model
from evaaa_baselines.dreamer.replay import SequenceReplay
from evaaa_baselines.dreamer.update import Learner, update_options
from evaaa_baselines.paths import CONF_DIR
from evaaa_baselines.training import train

register_levels()
SHAPES = {"pixels": (64, 64, 3), "interoception": (4,), "olfaction": (10,), "thermoception": (8,), "collision": (10,)}
#: every optional loss path of the gradient step on (as tests/dreamer_reference.py's "aids" run)
AIDS = (
    "algo.critic.replay_scale=0.3",
    "algo.world_model.vector_scale=10",
    "algo.world_model.prior_vector_scale=1",
    "algo.world_model.raw_keys=[interoception]",
)


def debug_cfg(*extra: str):
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        return compose(
            "config",
            overrides=["algo=dreamer", "preset=debug", "logger=csv", "progress=false", "threads=1", *extra],
        )


# ------------------------------------------------------------------------------------------------ the old update
class EagerUpdate:
    """The gradient step exactly as ``baselines/dreamer/loop.py`` ran it before it was split into phases (one
    eager function, its diagnostics inside): the reference the phased :class:`Learner` must equal."""

    def __init__(self, cfg, model, device="cpu"):
        self.cfg, self.model = cfg, model
        self.model_loss = WorldModelLoss(cfg, model)
        self.critic = value_model(model)
        self.actor_loss = DreamerV3ActorLoss(
            model.actor,
            self.critic,
            imagination_env(model, device),
            continuation_model=continuation_model(model),
            imagination_horizon=cfg.horizon,
            use_reinforce=True,
            entropy_bonus=cfg.actor.entropy,
            return_normalization=True,
            return_normalization_rate=1 - cfg.actor.return_decay,
            return_normalization_quantiles=tuple(cfg.actor.return_percentiles),
            return_normalization_min_scale=1.0,
        )
        self.actor_loss.make_value_estimator(ValueEstimators.TDLambda, gamma=cfg.gamma, lmbda=cfg.lmbda)
        self.value_loss = DreamerV3ValueLoss(
            self.critic,
            value_loss="two_hot",
            num_value_bins=cfg.model.bins,
            actor_loss=self.actor_loss,
            slow_critic_regularization=cfg.critic.slow_regularizer,
        )
        self.slow_critic = SoftUpdate(self.value_loss, tau=cfg.critic.tau)

        def adam(params, section):
            return torch.optim.Adam(params, lr=section.lr, eps=section.eps, fused=True)

        self.optimizers = {
            "world_model": adam(model.world_model_parameters(), cfg.world_model),
            "actor": adam(model.actor.parameters(), cfg.actor),
            "critic": adam(model.value.parameters(), cfg.critic),
        }

    def step(self, name, loss, params, clip):
        optimizer = self.optimizers[name]
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        norm = nn.utils.clip_grad_norm_(params, clip)
        optimizer.step()
        return norm

    def __call__(self, batch, log_due):
        cfg, model = self.cfg, self.model
        replay_scale = float(cfg.critic.get("replay_scale", 0.0))
        batch["state"] = torch.zeros(*batch.shape, model.state_dim)
        batch["belief"] = torch.zeros(*batch.shape, model.belief_dim)
        wm_loss, losses, posterior, vector_reco = self.model_loss(batch)
        wm_norm = self.step("world_model", wm_loss, model.world_model_parameters(), cfg.world_model.grad_clip)
        latents = TensorDict(
            {k: posterior["next", k].reshape(-1, posterior["next", k].shape[-1]).float() for k in LATENT},
            [batch.numel()],
        )
        actor_out, imagined = self.actor_loss(latents)
        actor_norm = self.step("actor", actor_out["loss_actor"], list(model.actor.parameters()), cfg.actor.grad_clip)
        critic_out, _ = self.value_loss(imagined.detach())
        critic_loss = critic_out["loss_value"]
        if replay_scale:
            replay_loss = replay_value_loss(self.value_loss, posterior, imagined, cfg)
            critic_loss = critic_loss + replay_scale * replay_loss
        critic_norm = self.step("critic", critic_loss, list(model.value.parameters()), cfg.critic.grad_clip)
        self.slow_critic.step()
        metrics = {f"model_{k.removeprefix('loss_model_')}": v.detach() for k, v in losses.items()}
        metrics |= {
            "model_loss": wm_loss.detach(),
            "model_grad_norm": wm_norm,
            "actor_loss": actor_out["loss_actor"].detach(),
            "actor_entropy": actor_out["actor_entropy"],
            "return_scale": actor_out["return_scale"],
            "actor_grad_norm": actor_norm,
            "imagined_reward": imagined["next", "reward"].mean(),
            "imagined_continuation": actor_out["continuation_mean"],
            "critic_loss": critic_loss.detach(),
            "critic_grad_norm": critic_norm,
            "imagined_return": imagined["lambda_target"].mean(),
        }
        if replay_scale:
            metrics["critic_replay_loss"] = replay_loss.detach()
        if vector_reco is not None:
            metrics["model_reco_vector"] = vector_reco.detach()
        if "interoception" in model.obs_keys:
            metrics["interoception_error"] = (
                (posterior["next", "reco_interoception"].detach().float() - posterior["next", "interoception"].float())
                .abs()
                .mean()
            )
        if log_due:
            metrics |= diagnostics(model, self.critic, posterior, imagined, actor_out["return_scale"])
        return metrics


# ------------------------------------------------------------------------------------------------ helpers
def random_batch(keys, generator: torch.Generator, shape=(3, 8)) -> TensorDict:
    """A replayed batch of the shape the replay gives (``[sequences, steps]``), with eating, deaths and episode
    starts in it."""
    rand = lambda *s: torch.rand(*shape, *s, generator=generator)  # noqa: E731
    nxt = {}
    for key in keys:
        if key == "pixels":
            nxt[key] = (rand(*SHAPES[key]) * 255).to(torch.uint8)
        else:
            nxt[key] = rand(*SHAPES[key]) * 4 - 2
    terminated = rand(1) < 0.1
    nxt |= {"reward": rand(1) - 0.5, "terminated": terminated, "done": terminated | (rand(1) < 0.05)}
    nxt["consumed"] = rand() < 0.2
    return TensorDict(
        {
            "action": torch.randint(dreamer_model.NUM_ACTIONS, shape, generator=generator),
            "is_init": rand(1) < 0.1,
            "next": nxt,
        },
        list(shape),
    )


def make_pair(*overrides: str):
    cfg = debug_cfg(*overrides)
    keys = observation_keys(cfg)
    torch.manual_seed(0)
    model = dreamer_model.make_model(cfg.algo, {k: SHAPES[k] for k in keys})
    twin = copy.deepcopy(model)
    return cfg, keys, EagerUpdate(cfg.algo, model), Learner(cfg.algo, twin, torch.device("cpu"))


def assert_same_state(old: EagerUpdate, new: Learner) -> None:
    for (name, a), (_, b) in zip(old.model.state_dict().items(), new.model.state_dict().items(), strict=True):
        assert torch.equal(a, b), name
    for name in ("world_model", "actor", "critic"):
        a, b = old.optimizers[name].state_dict()["state"], new.optimizers[name].state_dict()["state"]
        assert a.keys() == b.keys() and a
        for i in a:
            for k, v in a[i].items():
                assert torch.equal(v, b[i][k]), (name, i, k)
    for (name, a), (_, b) in zip(
        old.value_loss.state_dict().items(), new.value_loss.state_dict().items(), strict=True
    ):  # the critic and its slow copy
        assert torch.equal(a, b), name
    for (name, a), (_, b) in zip(
        old.actor_loss.retnorm.state_dict().items(), new.actor_loss.retnorm.state_dict().items(), strict=True
    ):
        assert torch.equal(a, b), name


# ------------------------------------------------------------------------------------------------ tests
@pytest.mark.parametrize("overrides", [(), AIDS], ids=["defaults", "every_loss_path"])
def test_the_phased_update_equals_the_eager_one_after_three_steps(overrides):
    cfg, keys, old, new = make_pair(*overrides)
    data = torch.Generator().manual_seed(1)
    batches = [random_batch(keys, data) for _ in range(3)]
    for i, batch in enumerate(batches):
        log_due = i == 2  # the last step computes its diagnostics too
        torch.manual_seed(100 + i)
        expected = old(batch.clone(), log_due)
        torch.manual_seed(100 + i)
        got = new.update(batch.clone())
        if log_due:
            got |= new.diagnostics()
        assert list(got) == list(expected)
        for k in expected:
            assert torch.equal(got[k], expected[k]) or (got[k].isnan().all() and expected[k].isnan().all()), k
    assert_same_state(old, new)
    # the slow critic moved away from the critic (three soft updates), and return normalisation moved too
    slow = new.value_loss.target_value_model_params.flatten_keys()
    fast = new.value_loss.value_model_params.flatten_keys()
    assert any(not torch.equal(slow[k], fast[k]) for k in fast.keys())
    assert not torch.equal(new.actor_loss.retnorm.high, torch.zeros_like(new.actor_loss.retnorm.high))


class HostRead(AssertionError):
    """A value went from the device to the host inside the update."""


#: the ways a tensor's value reaches Python: each a host synchronisation on a GPU
HOST_READS = ("item", "tolist", "__bool__", "__int__", "__float__", "__index__", "cpu", "numpy", "nonzero")


def guarded(patch: pytest.MonkeyPatch) -> list[str]:
    """Make every host read of a tensor raise :class:`HostRead` (and note it)."""
    seen: list[str] = []
    for name in HOST_READS:
        original = getattr(torch.Tensor, name)

        def refuse(self, *args, _name=name, _original=original, **kwargs):
            seen.append(_name)
            raise HostRead(f"Tensor.{_name} inside the gradient step")

        patch.setattr(torch.Tensor, name, refuse)

    def refuse_nonzero(*args, **kwargs):
        seen.append("torch.nonzero")
        raise HostRead("torch.nonzero inside the gradient step")

    patch.setattr(torch, "nonzero", refuse_nonzero)
    return seen


@pytest.mark.parametrize("overrides", [(), AIDS], ids=["defaults", "every_loss_path"])
def test_the_update_reads_nothing_on_the_host(overrides, monkeypatch):
    cfg, keys, _, learner = make_pair(*overrides)
    if cfg.algo.critic.replay_scale:
        # the critic's loss on the replayed sequences: torchrl's vectorised lambda-return splits the sequences at
        # their episode ends (shapes read on the host) when it runs eagerly, and takes its sequential estimator
        # when a CUDA graph is captured (or under torch.compile); the phases run that one under algo.update.graphs
        import torchrl.objectives.dreamer_v3 as torchrl_dreamer

        monkeypatch.setattr(torchrl_dreamer, "_is_dynamo_compiling", lambda: True)
    data = torch.Generator().manual_seed(2)
    learner.update(random_batch(keys, data))  # a first step outside the guard (lazy initialisations)
    batch = random_batch(keys, data)
    with pytest.MonkeyPatch.context() as patch:
        seen = guarded(patch)
        metrics = learner.update(batch)
        assert seen == []
        # the guard works: the diagnostics, computed after the update when a log is due, do read the host
        with pytest.raises(HostRead):
            learner.diagnostics()
        assert seen
    assert all(torch.isfinite(v) for v in metrics.values())


def test_the_update_options_are_checked_naming_the_key():
    cfg = debug_cfg()
    assert update_options(cfg.algo, torch.device("cpu")) == {"graphs": False, "compile": False, "prefetch": False}
    with pytest.raises(ValueError, match=r"algo.update.graphs=true .* needs a CUDA device"):
        update_options(debug_cfg("algo.update.graphs=true").algo, torch.device("cpu"))
    with pytest.raises(ValueError, match=r"algo.update.prefetch must be one of \[False, True\]"):
        update_options(debug_cfg("algo.update.prefetch=sometimes").algo, torch.device("cpu"))
    with pytest.raises(ValueError, match=r"algo.update has no option \['graph'\]"):
        update_options(debug_cfg("+algo.update.graph=true").algo, torch.device("cpu"))


# ------------------------------------------------------------------------------------------------ replay
def fill(replay: SequenceReplay, steps: int, num_envs: int, generator: torch.Generator) -> None:
    for _ in range(steps):
        replay.extend(
            TensorDict(
                {
                    "action": torch.randint(dreamer_model.NUM_ACTIONS, (num_envs,), generator=generator),
                    "is_init": torch.rand(num_envs, 1, generator=generator) < 0.1,
                    ("next", "reward"): torch.randn(num_envs, 1, generator=generator),
                    ("next", "terminated"): torch.rand(num_envs, 1, generator=generator) < 0.05,
                    ("next", "consumed"): torch.rand(num_envs, generator=generator) < 0.05,
                    ("next", "pixels"): torch.randint(0, 255, (num_envs, 4, 4, 3), dtype=torch.uint8),
                },
                [num_envs],
            )
        )


@pytest.mark.parametrize("on_disk", [False, True], ids=["memory", "disk"])
@pytest.mark.parametrize("steps", [8, 40, 64, 100, 192], ids=lambda s: f"{s}_steps")
def test_the_o_batch_sampler_draws_exactly_the_slice_samplers_batches(on_disk, steps, tmp_path):
    # 64 rows per world: 8 and 40 steps part-fill the buffer, 64 fill it, 100 and 192 wrap it (cursor at 36 and 0)
    replay = SequenceReplay(64 * 3, 3, 8, 4, directory=tmp_path if on_disk else None)
    fill(replay, steps, 3, torch.Generator().manual_seed(steps))
    torch.manual_seed(0)
    for _ in range(4):
        state = torch.get_rng_state()
        before = replay.buffer.sample().reshape(4, 8)  # what SequenceReplay.sample returned before issue 46
        after = torch.get_rng_state()
        torch.set_rng_state(state)
        now = replay.sample()
        assert torch.equal(torch.get_rng_state(), after)  # the same draws from the global RNG
        assert set(now.keys(True, True)) == set(before.keys(True, True)) and now.batch_size == before.batch_size
        for key in before.keys(True, True):
            assert now[key].dtype == before[key].dtype and torch.equal(now[key], before[key]), key
        # any sequence shape (open-loop pictures, probes): SliceSampler's draws too
        state = torch.get_rng_state()
        index, _ = SliceSampler(slice_len=5, traj_key="world", truncated_key=None).sample(replay.buffer.storage, 30)
        expected = replay.buffer.storage[index].reshape(6, 5)
        torch.set_rng_state(state)
        assert (replay.sample(6, 5) == expected).all()


def test_prefetched_batches_come_from_the_replays_own_generator_and_its_state_is_kept():
    def replay():
        r = SequenceReplay(64 * 2, 2, 8, 4, consume_share=0.5)
        fill(r, 50, 2, torch.Generator().manual_seed(5))
        r.use_own_generator(7)
        return r

    a, b = replay(), replay()
    global_state = torch.get_rng_state()
    a.prefetch()
    assert torch.equal(torch.get_rng_state(), global_state)  # nothing drawn from the training's stream
    state = a.state_dict()  # a checkpoint with a batch pending keeps the generators from before its draw
    b.load_state_dict(state)
    assert (a.sample() == b.sample()).all()
    assert (a.sample() == b.sample()).all()
    with pytest.raises(ValueError, match="algo.update.prefetch=true"):
        SequenceReplay(64 * 2, 2, 8, 4).load_state_dict(state)


# ------------------------------------------------------------------------------------------------ resume
def same_training(a: dict, b: dict) -> None:
    assert a["counters"] == b["counters"]
    for name, value in a["model"].items():
        assert torch.equal(value, b["model"][name]), name
    for name in ("optimizer_world_model", "optimizer_actor", "optimizer_critic"):
        x, y = a["components"][name]["state"], b["components"][name]["state"]
        assert all(torch.equal(v, y[i][k]) for i in x for k, v in x[i].items()), name
    for name, value in a["components"]["value_loss"].items():
        assert torch.equal(value, b["components"]["value_loss"][name]), name
    for name, value in a["components"]["return_norm"].items():
        assert torch.equal(value, b["components"]["return_norm"][name]), name


def test_a_run_stopped_with_a_batch_drawn_ahead_resumes_exactly(tmp_path, monkeypatch):
    # two gradient steps per iteration: the Ctrl-C after the 31st leaves the 32nd's batch drawn ahead (prefetch)
    # and owed; the resumed run draws it again, and ends where the uninterrupted run ended
    run = ("algo.replay_ratio=1.0", "total_steps=96", "algo.update.prefetch=true", "algo.consume_share=0.5")
    train(debug_cfg(*run), tmp_path / "whole")
    updated = run_loop.Run.updated

    def ctrl_c_after_31(self, count, seconds, total, ratio=None):
        updated(self, count, seconds, total, ratio)
        if total == 31:
            os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(run_loop.Run, "updated", ctrl_c_after_31)
    with pytest.raises(run_loop.Interrupted):
        train(debug_cfg(*run), tmp_path / "resumed")
    monkeypatch.undo()
    at_stop = checkpoint.load_checkpoint(tmp_path / "resumed" / checkpoint.CHECKPOINT)
    assert at_stop["components"]["counters"]["updates"] == 31
    assert set(at_stop["components"]["replay"]["generators"]) == {"sampled", "prefetch"}
    train(debug_cfg(*run, "resume=true"), tmp_path / "resumed")
    whole = checkpoint.load_checkpoint(tmp_path / "whole" / checkpoint.CHECKPOINT)
    resumed = checkpoint.load_checkpoint(tmp_path / "resumed" / checkpoint.CHECKPOINT)
    same_training(whole, resumed)
    # and the prefetched run is another run than the default one (its batches come from another stream)
    default = tmp_path / "default"
    train(debug_cfg(*run[:2], "algo.consume_share=0.5"), default)
    other = checkpoint.load_checkpoint(default / checkpoint.CHECKPOINT)
    assert not torch.equal(next(iter(other["model"].values())), next(iter(whole["model"].values())))
