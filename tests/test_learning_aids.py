"""What helps the baselines learn the paper's reward and tells why they do not: PPO's return-scale normalisation
(``algo.normalize_reward``) gives discounted returns of unit spread, restarts each world's return at its episode's
end and resumes exactly from its state; DreamerV3's diagnostics (reward-head error on the steps that eat, continue
head, critic value, policy and first-step advantage per action) compute what they say on hand-made inputs, and the
replay marks the steps that ate."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from tensordict import TensorDict

from evaaa import ACTION_NAMES
from evaaa_baselines import dreamer
from evaaa_baselines.config import register_levels
from evaaa_baselines.dreamer import losses as dreamer_losses
from evaaa_baselines.dreamer import model as dreamer_model
from evaaa_baselines.dreamer import replay as dreamer_replay
from evaaa_baselines.paths import CONF_DIR
from evaaa_baselines.ppo import ReturnScale

register_levels()


def batch(rewards: np.ndarray, dones: np.ndarray) -> TensorDict:
    """A ``[worlds, steps]`` batch of rewards and done flags, shaped like a collected PPO batch."""
    return TensorDict(
        {
            "next": {
                "reward": torch.as_tensor(rewards, dtype=torch.float32).unsqueeze(-1),
                "done": torch.as_tensor(dones).unsqueeze(-1),
            }
        },
        list(rewards.shape),
    )


# ------------------------------------------------------------------------------------------------ PPO
def test_return_scale_gives_discounted_returns_of_unit_spread():
    rng = np.random.default_rng(0)
    gamma, worlds, steps = 0.99, 4, 128
    scale = ReturnScale(worlds, gamma)
    scaled = []
    for _ in range(40):  # rewards like the paper's: hundreds per return, -100 at episode ends
        raw = -rng.uniform(0, 3, (worlds, steps))
        done = rng.random((worlds, steps)) < 0.002
        raw[done] = -100.0
        scaled.append(scale(batch(raw, done))["next", "reward"].squeeze(-1).numpy())
    scaled = np.concatenate(scaled, axis=1)
    returns, discounted = np.zeros(worlds), []
    for t in range(scaled.shape[1]):
        returns = returns * gamma + scaled[:, t]
        discounted.append(returns.copy())
    spread = np.std(np.concatenate(discounted[1000:]))
    assert 0.5 < spread < 2.0, spread  # the raw returns' spread is about 100 times larger
    assert scale.scale > 30


def test_return_scale_divides_each_reward_and_restarts_a_world_at_its_episode_end():
    scale = ReturnScale(2, gamma=0.5)
    raw = np.array([[2.0, 2.0, 2.0], [4.0, 4.0, 4.0]])
    done = np.array([[False, True, False], [False, False, False]])
    out = scale(batch(raw, done))["next", "reward"].squeeze(-1).numpy()
    # every reward is divided by one positive scale per step
    ratio = raw / out
    assert np.allclose(ratio[0], ratio[1]) and (ratio > 0).all()
    # world 0 ended at step 1: its running return restarted there, world 1's kept accumulating
    assert scale.returns[0] == pytest.approx(2.0) and scale.returns[1] == pytest.approx(4 + 0.5 * (4 + 0.5 * 4))


def test_return_scale_resumes_exactly_from_its_state():
    rng = np.random.default_rng(1)
    batches = [(rng.normal(size=(3, 16)), rng.random((3, 16)) < 0.1) for _ in range(3)]
    whole = ReturnScale(3, 0.9)
    expected = [whole(batch(r, d))["next", "reward"] for r, d in batches]
    first = ReturnScale(3, 0.9)
    first(batch(*batches[0]))
    resumed = ReturnScale(3, 0.9)
    resumed.load_state_dict(first.state_dict())
    for (r, d), want in zip(batches[1:], expected[1:]):
        assert torch.equal(resumed(batch(r, d))["next", "reward"], want)


# ------------------------------------------------------------------------------------------------ DreamerV3
def test_consumed_marks_the_steps_whose_food_or_water_count_grew():
    counts = {"food_eaten": torch.tensor([[0], [2], [5]]), "water_eaten": torch.tensor([[1], [0], [0]])}
    after = {"food_eaten": torch.tensor([[0], [3], [0]]), "water_eaten": torch.tensor([[2], [0], [0]])}
    td = TensorDict({"info": counts, "next": {"info": after}}, [3])
    # world 0 drank, world 1 ate, world 2's counts restarted (an episode's first step), which is no eating
    assert dreamer_replay.consumed(td).squeeze(-1).tolist() == [True, True, False]


@pytest.fixture(scope="module")
def model():
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        cfg = compose("config", overrides=["algo=dreamer", "preset=debug"])
    torch.manual_seed(0)
    return dreamer.make_model(cfg.algo, {"interoception": (4,)})


def test_diagnostics_say_what_the_heads_and_the_actor_do(model):
    batch_size, time = 2, 3
    latents = {
        "state": torch.randn(batch_size, time, model.state_dim),
        "belief": torch.randn(batch_size, time, model.belief_dim),
    }
    true = torch.tensor([[0.0, 5.0, 0.0], [0.0, 0.0, 3.0]]).unsqueeze(-1)
    pred = torch.tensor([[0.5, 1.0, 0.0], [0.1, 0.0, 3.0]]).unsqueeze(-1)
    eaten = true > 0
    logits = torch.tensor([[2.0, 0.0, 0.0], [0.0, -3.0, 1.0]]).unsqueeze(-1)
    ended = torch.tensor([[False, False, False], [False, True, False]]).unsqueeze(-1)
    posterior = TensorDict(
        {
            "next": {
                **latents,
                "reward": pred,
                "true_reward": true,
                "consumed": eaten,
                "continue_pred": logits,
                "terminated": ended,
            }
        },
        [batch_size, time],
    )
    horizon, n = 4, 6
    actions = torch.tensor([0, 1, 1, 4, 4, 4])  # "left" and "right" never taken
    imagined = TensorDict(
        {
            "state": torch.randn(n, horizon, model.state_dim),
            "belief": torch.randn(n, horizon, model.belief_dim),
            "action": torch.nn.functional.one_hot(actions, len(ACTION_NAMES)).unsqueeze(1).expand(n, horizon, -1),
            "lambda_target": torch.arange(n * horizon, dtype=torch.float32).reshape(n, horizon, 1),
        },
        [n, horizon],
    )
    critic = dreamer_model.value_model(model)
    out = dreamer_losses.diagnostics(model, critic, posterior, imagined, torch.tensor(2.0))

    assert out["reward_error_consume"].item() == pytest.approx((4.0 + 0.0) / 2)
    assert out["reward_error_other"].item() == pytest.approx((0.5 + 0.0 + 0.1 + 0.0) / 4)
    assert out["reward_true_consume"].item() == pytest.approx(4.0)
    assert out["reward_pred_consume"].item() == pytest.approx(2.0)
    assert out["consume_share"].item() == pytest.approx(2 / 6)
    assert out["continue_terminal"].item() == pytest.approx(torch.sigmoid(torch.tensor(-3.0)).item())
    others = torch.tensor([2.0, 0.0, 0.0, 0.0, 1.0])
    assert out["continue_error_other"].item() == pytest.approx((1 - torch.sigmoid(others)).mean().item())
    assert sum(out[f"policy_{a}"].item() for a in ACTION_NAMES) == pytest.approx(1.0)
    # the first step's advantage per action: (lambda-return - critic value) / return scale, averaged by action
    first = imagined[:, 0]
    values = critic(first.select("state", "belief").clone())["state_value"].squeeze(-1)
    advantage = (first["lambda_target"].squeeze(-1) - values) / 2.0
    assert out["advantage_none"].item() == pytest.approx(advantage[0].item(), rel=1e-5)
    assert out["advantage_forward"].item() == pytest.approx(advantage[1:3].mean().item(), rel=1e-5)
    assert out["advantage_eat"].item() == pytest.approx(advantage[3:].mean().item(), rel=1e-5)
    assert math.isnan(out["advantage_left"].item()) and math.isnan(out["advantage_right"].item())


def test_the_replay_value_loss_targets_the_real_rewards_after_each_state(model):
    from torchrl.objectives import DreamerV3ValueLoss
    from torchrl.objectives.dreamer_v3 import two_hot_cross_entropy

    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        cfg = compose("config", overrides=["algo=dreamer", "preset=debug"]).algo
    critic = dreamer_model.value_model(model)
    loss = DreamerV3ValueLoss(
        critic, value_loss="two_hot", num_value_bins=cfg.model.bins, slow_critic_regularization=0.0
    )
    torch.manual_seed(1)
    time = 3
    latents = {"state": torch.randn(1, time, model.state_dim), "belief": torch.randn(1, time, model.belief_dim)}
    reward = torch.tensor([[0.5, -2.0, 4.0]]).unsqueeze(-1)
    no = torch.zeros(1, time, 1, dtype=torch.bool)
    posterior = TensorDict({"next": {**latents, "true_reward": reward, "done": no, "terminated": no}}, [1, time])
    bootstrap = torch.tensor([10.0, 20.0, 30.0])  # each state's first imagined return, in the batch's order
    imagined = TensorDict({"lambda_target": torch.stack([bootstrap, bootstrap - 1], 1).unsqueeze(-1)}, [time, 2])
    got = dreamer_losses.replay_value_loss(loss, posterior, imagined, cfg)

    gamma, lmbda = cfg.gamma, cfg.lmbda
    # state k's return: the reward of the step after it, then its successor's bootstrap and return
    second = 4.0 + gamma * 30.0
    first = -2.0 + gamma * ((1 - lmbda) * 20.0 + lmbda * second)
    logits = critic(TensorDict({k: v[0, :2] for k, v in latents.items()}, [2]))["state_value_logits"]
    want = two_hot_cross_entropy(logits, torch.tensor([first, second]), loss.value_bins).mean()
    assert got.item() == pytest.approx(want.item(), rel=1e-5)


def test_the_replay_stores_the_scaled_reward_and_the_episodes_keep_the_envs(tmp_path):
    from evaaa_baselines.training import train

    def run(scale: float):
        with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
            cfg = compose(
                "config",
                overrides=[
                    "algo=dreamer",
                    "preset=debug",
                    "logger=csv",
                    "progress=false",
                    "threads=1",
                    "total_steps=96",
                    "algo.learning_starts=1000",
                    f"algo.reward_scale={scale}",
                ],
            )
        train(cfg, tmp_path / str(scale))
        rows = TensorDict.load_memmap(tmp_path / str(scale) / "replay" / "0-1-1")
        episodes = [line.split(",")[:-1] for line in (tmp_path / str(scale) / "episodes.csv").read_text().splitlines()]
        return rows["next", "reward"][:48], episodes  # every row but its wall time

    plain, plain_episodes = run(1.0)
    scaled, scaled_episodes = run(10.0)
    # no gradient step in either run (learning starts later): the same actions, the stored reward times 10
    assert plain.abs().sum() > 0
    assert torch.allclose(scaled, 10 * plain)
    # the episodes' logged returns are the env's, unscaled
    assert len(plain_episodes) >= 3 and scaled_episodes == plain_episodes


def test_a_ppo_run_made_without_reward_scaling_resumes_only_with_it_off(tmp_path):
    from evaaa_baselines.training import train

    def cfg(*extra):
        with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
            return compose(
                "config", overrides=["algo=ppo", "preset=debug", "logger=csv", "progress=false", "threads=1", *extra]
            )

    train(cfg("total_steps=64", "algo.normalize_reward=false"), tmp_path / "run")
    with pytest.raises(ValueError, match="no state for return_scale.*algo.normalize_reward=false"):
        train(cfg("total_steps=128", "resume=true"), tmp_path / "run")
    train(cfg("total_steps=128", "resume=true", "algo.normalize_reward=false"), tmp_path / "run")
    assert (tmp_path / "run" / "model-0-1-1.pt").exists()


def fill_replay(share: float, *, rows: int, eaten_at: list[tuple[int, int]], capacity: int | None = None):
    """A 2-world in-memory replay of ``rows`` steps per world whose ``step`` entry counts the rows written, with
    ``("next", "consumed")`` set at (row, world) for ``eaten_at``."""
    replay = dreamer_replay.SequenceReplay(capacity or 2 * rows, 2, 8, 10, consume_share=share)
    for t in range(rows):
        replay.extend(
            TensorDict(
                {
                    "step": torch.full((2,), t),
                    "next": {"consumed": torch.tensor([(t, w) in eaten_at for w in range(2)]).unsqueeze(-1)},
                },
                [2],
            )
        )
    return replay


def test_a_share_of_the_replayed_sequences_hold_an_eating_step():
    torch.manual_seed(0)
    eaten_at = [(40, 0), (90, 1)]
    replay = fill_replay(0.3, rows=120, eaten_at=eaten_at)
    assert replay.consume_sequences == 3
    seen = []
    for _ in range(20):
        batch = replay.sample()
        assert batch.shape == (10, 8)
        steps = batch["step"]
        assert ((steps[:, 1:] - steps[:, :-1]) == 1).all()  # consecutive steps of one world
        holds = batch["next", "consumed"].reshape(10, 8).any(-1)
        assert holds[-3:].all()  # the last three sequences are drawn around an eating step
        seen.append(holds[:-3].float().mean())
    assert float(torch.stack(seen).mean()) < 0.5  # the others are uniform: 2 eating rows in 240 are seldom seen
    # where the eating step sits in its sequence is drawn, not fixed
    positions = {int(replay.sample()["next", "consumed"][-1].reshape(8).nonzero()[0]) for _ in range(30)}
    assert len(positions) > 3


def test_a_share_of_the_replayed_sequences_hold_a_death_beside_those_around_eating():
    torch.manual_seed(0)
    replay = dreamer_replay.SequenceReplay(240, 2, 8, 10, consume_share=0.2, terminal_share=0.3)
    assert (replay.consume_sequences, replay.terminal_sequences) == (2, 3)
    for t in range(120):
        replay.extend(
            TensorDict(
                {
                    "step": torch.full((2,), t),
                    "next": {
                        "consumed": torch.tensor([(t, w) == (40, 0) for w in range(2)]).unsqueeze(-1),
                        "terminated": torch.tensor([(t, w) in [(70, 1), (100, 0)] for w in range(2)]).unsqueeze(-1),
                    },
                },
                [2],
            )
        )
    seen = []
    for _ in range(20):
        batch = replay.sample()
        assert batch.shape == (10, 8)
        assert ((batch["step"][:, 1:] - batch["step"][:, :-1]) == 1).all()
        died = batch["next", "terminated"].reshape(10, 8).any(-1)
        ate = batch["next", "consumed"].reshape(10, 8).any(-1)
        assert died[5:8].all() and ate[8:].all()  # three around a death, then two around eating
        seen.append(died[:5].float().mean())
    assert float(torch.stack(seen).mean()) < 0.5  # the first five are uniform
    with pytest.raises(ValueError, match=r"algo.terminal_share must lie in \[0, 1\], got -0.1"):
        dreamer_replay.SequenceReplay(100, 2, 8, 10, terminal_share=-0.1)
    with pytest.raises(
        ValueError, match=r"algo.consume_share \+ algo.terminal_share must be at most 1, got 0.6 \+ 0.5"
    ):
        dreamer_replay.SequenceReplay(100, 2, 8, 10, consume_share=0.6, terminal_share=0.5)


def test_the_uniform_replay_is_left_alone_and_a_share_outside_zero_one_is_refused():
    plain = fill_replay(0.0, rows=50, eaten_at=[(10, 0)])
    assert plain.consume_sequences == 0 and plain.sample().shape == (10, 8)
    none_yet = fill_replay(0.5, rows=50, eaten_at=[])
    assert none_yet.sample().shape == (10, 8)  # nothing eaten yet: all uniform
    with pytest.raises(ValueError, match=r"algo.consume_share must lie in \[0, 1\], got 1.5"):
        dreamer_replay.SequenceReplay(100, 2, 8, 10, consume_share=1.5)


def test_sequences_around_eating_never_run_across_the_writers_cursor():
    # 40 rows per world, 70 steps written: the cursor is at row 30, where the newest step (69, row 29) meets the
    # oldest (30, row 30); steps 68 and 32 were eaten, two and three rows from it
    replay = fill_replay(1.0, rows=70, eaten_at=[(68, 0), (32, 1)], capacity=80)
    for _ in range(40):
        steps = replay.sample()["step"]
        assert ((steps[:, 1:] - steps[:, :-1]) == 1).all()


def test_the_vector_reconstruction_is_the_symlog_squared_error_summed_per_key():
    truth = torch.tensor([[[3.0, -1.0], [0.0, 0.0]]])  # [batch 1, time 2, 2 entries]
    reco = torch.tensor([[[math.e - 1, -1.0], [0.0, 1.0]]])  # symlog(e - 1) = 1, symlog(3) = log 4
    smell = torch.tensor([[[2.0], [2.0]]])
    posterior = TensorDict(
        {"next": {"interoception": truth, "reco_interoception": reco, "olfaction": smell, "reco_olfaction": smell}},
        [1, 2],
    )
    first = (math.log(4.0) - 1.0) ** 2  # step 0: one entry off
    second = math.log(2.0) ** 2  # step 1: symlog(1) = log 2
    expected = (first + second) / 2
    got = dreamer_losses.vector_reconstruction(posterior, ["interoception", "olfaction"])
    assert float(got) == pytest.approx(expected, rel=1e-5)
    assert float(dreamer_losses.vector_reconstruction(posterior, ["olfaction"])) == 0.0
    # in raw units: step 0 is off by 3 - (e - 1), step 1 by 1
    raw = ((3.0 - (math.e - 1)) ** 2 + 1.0) / 2
    assert float(
        dreamer_losses.vector_reconstruction(posterior, ["interoception"], raw=["interoception"])
    ) == pytest.approx(raw, rel=1e-5)


def test_raw_keys_must_be_vector_keys_of_the_run():
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        cfg = compose("config", overrides=["algo=dreamer", "preset=debug", "algo.world_model.raw_keys=[pixels]"])
    model = dreamer.make_model(cfg.algo, {"pixels": (64, 64, 3), "interoception": (4,)})
    with pytest.raises(ValueError, match="raw_keys must name vector observation keys"):
        dreamer_losses.WorldModelLoss(cfg.algo, model)
    cfg.algo.world_model.raw_keys = "interoception"  # one key as a plain string (a dotted override's value)
    loss = dreamer_losses.WorldModelLoss(cfg.algo, model)
    assert loss.raw_keys == ("interoception",) and loss.loss.reco_symlog == [False, False]


def test_vector_scale_changes_what_the_world_model_learns(tmp_path):
    """The vector keys' extra reconstruction term reaches the world model's gradient: the same run with
    vector_scale 1 and 10 takes the same first batch but a different gradient, and logs its own loss."""
    from evaaa_baselines.training import train

    def run(scale: float) -> dict[str, list[float]]:
        with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
            cfg = compose(
                "config",
                overrides=[
                    "algo=dreamer",
                    "preset=debug",
                    "logger=csv",
                    "progress=false",
                    "threads=1",
                    "total_steps=64",
                    f"algo.world_model.vector_scale={scale}",
                ],
            )
        train(cfg, tmp_path / str(scale))
        scalars = tmp_path / str(scale) / "logs" / "scalars" / "train"
        return {
            name: [float(line.split(",")[1]) for line in (scalars / f"{name}.csv").read_text().splitlines()]
            for name in ("model_grad_norm", "model_reco_vector", "model_loss")
        }

    plain, weighted = run(1.0), run(10.0)
    assert weighted["model_reco_vector"][0] == pytest.approx(plain["model_reco_vector"][0])  # the same batch
    assert weighted["model_loss"][0] == pytest.approx(
        plain["model_loss"][0] + 9 * plain["model_reco_vector"][0], rel=1e-4
    )
    assert weighted["model_grad_norm"][0] != pytest.approx(plain["model_grad_norm"][0], rel=1e-3)


def test_the_prior_term_trains_the_transition_to_predict_the_evs_and_a_negative_weight_is_refused():
    """``algo.world_model.prior_vector_scale``: the vector keys decoded from the prior's latent reach the prior's
    own head (which the posterior's reconstruction never does), scaled into the loss; < 0 is refused."""
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        cfg = compose("config", overrides=["algo=dreamer", "preset=debug"])
    shapes = {"interoception": (4,), "olfaction": (10,)}
    torch.manual_seed(0)
    model = dreamer.make_model(cfg.algo, shapes)
    batch = TensorDict(
        {
            "action": torch.randint(5, (2, 6)),
            "is_init": torch.zeros(2, 6, 1, dtype=torch.bool),
            "state": torch.zeros(2, 6, model.state_dim),
            "belief": torch.zeros(2, 6, model.belief_dim),
            "next": {"interoception": torch.randn(2, 6, 4), "olfaction": torch.rand(2, 6, 10)},
        },
        [2, 6],
    )
    out = dreamer_model.world_model(model)(batch)
    head = list(model.prior.rnn_to_prior_projector.parameters())

    def grads(loss: torch.Tensor) -> list[torch.Tensor | None]:
        return torch.autograd.grad(loss, head, allow_unused=True, retain_graph=True)

    assert all(g is None or not g.any() for g in grads(dreamer_losses.vector_reconstruction(out, list(shapes))))
    prior = dreamer_losses.prior_vector_reconstruction(out, model.decoder, list(shapes))
    assert float(prior.detach()) > 0 and any(g is not None and g.abs().sum() > 0 for g in grads(prior))
    cfg.algo.world_model.prior_vector_scale = 3.0
    loss = dreamer_losses.WorldModelLoss(cfg.algo, model)
    assert loss.prior_scale == 3.0 and not loss.loss.detach_output  # the term needs the graph
    cfg.algo.world_model.prior_vector_scale = -1.0
    with pytest.raises(ValueError, match="prior_vector_scale must be >= 0"):
        dreamer_losses.WorldModelLoss(cfg.algo, model)
