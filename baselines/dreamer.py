"""DreamerV3 on TorchRL, as the paper's sheeprl DreamerV3 baseline (SPEC §12; hyperparameters in
conf/algo/dreamer*.yaml).

Reads top to bottom: the networks (a multimodal encoder and decoder, torchrl's DreamerV3 RSSM — ``RSSMPriorV3`` /
``RSSMPosteriorV3`` — two-hot symlog reward and critic heads, a continue head, ``DreamerV3DiscreteActor``), their
wiring into tensordict modules (the world model over replayed sequences, the imagination env, the acting policy that
carries its recurrent state from step to step), the env transforms that state needs, the sequence replay buffer, the
open-loop prediction pictures, then :func:`train`: one env step in every world, then as many gradient steps as the
replay ratio owes, each one world-model step (``DreamerV3ModelLoss``: KL balancing with free nats and unimix,
reconstruction, reward, continue), one actor step (``DreamerV3ActorLoss``: REINFORCE in imagination, returns
normalised by their 5–95 % percentile range) and one critic step (``DreamerV3ValueLoss``: two-hot, with a slow
critic updated by ``SoftUpdate``).

Only the enabled observation keys are encoded and decoded: an ablation removes the key from both.

The replay buffer is part of the checkpoint (exact resume): the rows written so far, about 12.4 kB per transition
with pixels (e.g. 1.2 GB for 100,000 transitions).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictModuleBase, TensorDictSequential
from torch import nn
from torch.nn import functional as F
from torchrl.data import Composite, LazyTensorStorage, OneHot, ReplayBuffer, SliceSampler, Unbounded
from torchrl.envs import InitTracker, TensorDictPrimer, Transform
from torchrl.envs.model_based.dreamer import DreamerEnv
from torchrl.modules import (
    DreamerV3DiscreteActor,
    DreamerV3ImageDecoder,
    DreamerV3ImageEncoder,
    DreamerV3MLP,
    DreamerV3SeededPolicy,
    RSSMPosteriorV3,
    RSSMPriorV3,
    RSSMRolloutV3,
    RSSMStateEstimatorV3,
    SymExpTwoHot,
    WorldModelWrapper,
)
from torchrl.objectives import DreamerV3ActorLoss, DreamerV3ModelLoss, DreamerV3ValueLoss, SoftUpdate
from torchrl.objectives.utils import ValueEstimators

from evaaa import ACTION_NAMES

from .nets import symlog
from .runtime import Counters, Run

NUM_ACTIONS = len(ACTION_NAMES)
LATENT = ("state", "belief")  # the stochastic sample z (flattened one-hots) and the GRU's deterministic state h


# ------------------------------------------------------------------------------------------------ networks
class DreamerEncoder(nn.Module):
    """Observation tensors, in ``obs_shapes`` order, to one embedding.

    ``pixels`` (uint8 ``[..., H, W, C]``) go through torchrl's ``DreamerV3ImageEncoder`` (stride-2 convolutions of
    ``cnn.depth × cnn.mults`` channels, RMS norm, SiLU; it scales to x/255 − 0.5 itself); the vector keys are
    symlog-ed, concatenated and go through one ``DreamerV3MLP`` (``mlp_layers`` × ``dense``), as sheeprl's MLP
    encoder. :attr:`out_features` is the embedding size.
    """

    def __init__(self, obs_shapes: Mapping[str, Sequence[int]], cfg: DictConfig):
        super().__init__()
        self.keys = tuple(obs_shapes)
        self.out_features = 0
        if "pixels" in obs_shapes:
            height, width, channels = obs_shapes["pixels"]
            self.cnn = DreamerV3ImageEncoder(in_channels=channels, depth=cfg.cnn.depth, mults=tuple(cfg.cnn.mults),
                                             kernel_size=cfg.cnn.kernel, norm_eps=cfg.norm_eps)
            self.out_features += self.cnn.output_features((channels, height, width))
        vector_features = sum(shape[-1] for key, shape in obs_shapes.items() if key != "pixels")
        if vector_features:
            self.mlp = DreamerV3MLP(vector_features, None, depth=cfg.mlp_layers, num_cells=cfg.dense,
                                    norm_eps=cfg.norm_eps)
            self.out_features += cfg.dense

    def forward(self, *obs: torch.Tensor) -> torch.Tensor:
        features, vectors = [], []
        for key, x in zip(self.keys, obs, strict=True):
            if key == "pixels":
                features.append(self.cnn(x.movedim(-1, -3)))  # [..., H, W, C] -> [..., C, H, W]
            else:
                vectors.append(symlog(x))
        if vectors:
            features.append(self.mlp(torch.cat(vectors, dim=-1)))
        return torch.cat(features, dim=-1)


class DreamerDecoder(nn.Module):
    """The latent (``state``, ``belief``) to a reconstruction of every observation key, in ``obs_shapes`` order.

    ``pixels`` come from torchrl's ``DreamerV3ImageDecoder`` (mirroring the encoder) as ``[..., H, W, C]`` floats
    on the x/255 scale; the vector keys from one ``DreamerV3MLP`` trunk with a linear head per key, predicted in
    symlog space and returned raw (symexp), since ``DreamerV3ModelLoss`` compares the symlogs of prediction and
    target.
    """

    def __init__(self, obs_shapes: Mapping[str, Sequence[int]], latent: int, cfg: DictConfig):
        super().__init__()
        self.keys = tuple(obs_shapes)
        if "pixels" in obs_shapes:
            height, width, channels = obs_shapes["pixels"]
            self.cnn = DreamerV3ImageDecoder(latent, (channels, height, width), depth=cfg.cnn.depth,
                                             mults=tuple(cfg.cnn.mults), kernel_size=cfg.cnn.kernel, num_blocks=1,
                                             norm_eps=cfg.norm_eps)
        vectors = {key: shape[-1] for key, shape in obs_shapes.items() if key != "pixels"}
        if vectors:
            self.mlp = DreamerV3MLP(latent, None, depth=cfg.mlp_layers, num_cells=cfg.dense, norm_eps=cfg.norm_eps)
            self.heads = nn.ModuleDict({key: nn.Linear(cfg.dense, size) for key, size in vectors.items()})

    def forward(self, state: torch.Tensor, belief: torch.Tensor) -> tuple[torch.Tensor, ...]:
        latent = torch.cat([state, belief], dim=-1)
        hidden = self.mlp(latent) if hasattr(self, "mlp") else None
        out = []
        for key in self.keys:
            if key == "pixels":
                out.append(self.cnn(latent).movedim(-3, -1))
            else:
                y = self.heads[key](hidden)
                out.append(torch.sign(y) * torch.expm1(y.abs()))  # symexp
        return tuple(out)


class DreamerModel(nn.Module):
    """Every trained network of DreamerV3: world model (encoder, RSSM prior and posterior, decoder, reward and
    continue heads), actor and critic.  Plain modules; :func:`world_model`, :func:`imagination_env`,
    :func:`acting_policy` wire them into tensordict modules that share their parameters."""

    def __init__(self, cfg: DictConfig, obs_shapes: Mapping[str, Sequence[int]]):
        super().__init__()
        m = cfg.model
        self.obs_keys = tuple(obs_shapes)
        self.state_dim = m.stochastic * m.classes
        self.belief_dim = m.recurrent
        latent = self.state_dim + self.belief_dim
        self.encoder = DreamerEncoder(obs_shapes, m)
        self.prior = RSSMPriorV3(action_shape=(NUM_ACTIONS,), action_dim=NUM_ACTIONS, hidden_dim=m.hidden,
                                 rnn_hidden_dim=m.recurrent, num_categoricals=m.stochastic, num_classes=m.classes,
                                 recurrent_model=m.recurrent_model, norm_eps=m.norm_eps, unimix=m.unimix)
        self.posterior = RSSMPosteriorV3(hidden_dim=m.hidden, num_categoricals=m.stochastic, num_classes=m.classes,
                                         rnn_hidden_dim=m.recurrent, obs_embed_dim=self.encoder.out_features,
                                         use_rms_norm=True, norm_eps=m.norm_eps, unimix=m.unimix)
        self.decoder = DreamerDecoder(obs_shapes, latent, m)
        # reward and critic: two-hot over symexp-spaced bins, zero-initialised outputs (DreamerV3's outscale 0)
        self.reward = DreamerV3MLP(latent, m.bins, depth=m.mlp_layers, num_cells=m.dense, outscale=0.0,
                                   norm_eps=m.norm_eps)
        self.two_hot = SymExpTwoHot(m.bins)
        self.cont = DreamerV3MLP(latent, 1, depth=m.mlp_layers, num_cells=m.dense, norm_eps=m.norm_eps)
        self.actor = DreamerV3DiscreteActor(latent, NUM_ACTIONS, depth=m.mlp_layers, num_cells=m.dense,
                                            norm_eps=m.norm_eps, unimix=m.unimix)
        self.value = DreamerV3MLP(latent, m.bins, depth=m.mlp_layers, num_cells=m.dense, outscale=0.0,
                                  norm_eps=m.norm_eps)

    def world_model_parameters(self) -> list[nn.Parameter]:
        return [p for name in ("encoder", "prior", "posterior", "decoder", "reward", "cont")
                for p in getattr(self, name).parameters()]


def make_model(cfg: DictConfig, obs_shapes: Mapping[str, Sequence[int]]) -> DreamerModel:
    return DreamerModel(cfg, obs_shapes)


# ------------------------------------------------------------------------------------------------ wiring
def _next(*keys: str) -> list[tuple[str, str]]:
    return [("next", k) for k in keys]


def _one_hot(action: torch.Tensor) -> torch.Tensor:
    return F.one_hot(action, NUM_ACTIONS).float()


def world_model(model: DreamerModel) -> TensorDictSequential:
    """Replayed sequences ``[batch, time]`` (``action``, ``is_init``, ``("next", <obs>)``, zero initial latent) to
    what ``DreamerV3ModelLoss`` reads under ``"next"``: prior and posterior logits, posterior latent,
    reconstructions ``reco_<key>``, reward logits and value, continue logit.  The RSSM restarts from zeros where
    ``is_init`` marks an episode's first step (``RSSMRolloutV3``)."""
    keys = model.obs_keys
    rollout = RSSMRolloutV3(
        TensorDictModule(model.prior, in_keys=["state", "belief", "action_onehot"],
                         out_keys=_next("prior_logits", "state", "belief")),
        TensorDictModule(model.posterior, in_keys=_next("belief", "encoded_latents"),
                         out_keys=_next("posterior_logits", "state")),
        reset_key="is_init",
    )
    return TensorDictSequential(
        TensorDictModule(_one_hot, in_keys=["action"], out_keys=["action_onehot"]),
        TensorDictModule(model.encoder, in_keys=_next(*keys), out_keys=_next("encoded_latents")),
        rollout,
        TensorDictModule(model.decoder, in_keys=_next(*LATENT), out_keys=_next(*(f"reco_{k}" for k in keys))),
        TensorDictModule(model.reward, in_keys=_next(*LATENT), out_keys=_next("reward_logits")),
        TensorDictModule(model.two_hot, in_keys=_next("reward_logits"), out_keys=_next("reward")),
        TensorDictModule(model.cont, in_keys=_next(*LATENT), out_keys=_next("continue_pred")),
    )


def imagination_env(model: DreamerModel) -> DreamerEnv:
    """torchrl's ``DreamerEnv`` on the prior and the reward head: the latent world the actor is trained in."""
    transition = TensorDictModule(model.prior, in_keys=["state", "belief", "action"], out_keys=["_", *LATENT])
    reward = TensorDictSequential(
        TensorDictModule(model.reward, in_keys=list(LATENT), out_keys=["reward_logits"]),
        TensorDictModule(model.two_hot, in_keys=["reward_logits"], out_keys=["reward"]),
    )
    env = DreamerEnv(WorldModelWrapper(transition, reward), prior_shape=(model.state_dim,),
                     belief_shape=(model.belief_dim,))
    env.observation_spec = Composite(state=Unbounded(model.state_dim), belief=Unbounded(model.belief_dim))
    env.state_spec = env.observation_spec.clone()
    env.action_spec = OneHot(NUM_ACTIONS)
    env.reward_spec = Unbounded((1,))
    return env


def continuation_model(model: DreamerModel) -> TensorDictSequential:
    """The continue head as a probability, for the discounts of imagined returns."""
    return TensorDictSequential(
        TensorDictModule(model.cont, in_keys=list(LATENT), out_keys=["continue_logits"]),
        TensorDictModule(torch.sigmoid, in_keys=["continue_logits"], out_keys=["continuation"]),
    )


def value_model(model: DreamerModel) -> TensorDictSequential:
    return TensorDictSequential(
        TensorDictModule(model.value, in_keys=list(LATENT), out_keys=["state_value_logits"]),
        TensorDictModule(model.two_hot, in_keys=["state_value_logits"], out_keys=["state_value"]),
    )


def _carry(action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    # the one-hot is the next step's previous action; the env takes its index
    return action.float(), action.argmax(-1)


def acting_policy(model: DreamerModel) -> TensorDictSequential:
    """Observations and the carried latent to ``"action"``: encode, one RSSM filtering step
    (``RSSMStateEstimatorV3``, which zeroes the latent where ``is_init``), the actor.  The updated ``state`` /
    ``belief`` and ``prev_action`` are written in place; the primer of :func:`make_transforms` carries them into the
    next step and zeroes them at a reset."""
    return TensorDictSequential(
        TensorDictModule(model.encoder, in_keys=list(model.obs_keys), out_keys=["embed"]),
        RSSMStateEstimatorV3(model.prior, model.posterior,
                             in_keys=[*LATENT, "prev_action", "embed", "is_init"], out_keys=list(LATENT)),
        model.actor,
        TensorDictModule(_carry, in_keys=["action"], out_keys=["prev_action", "action"]),
    )


class _EvaluationPolicy(TensorDictModuleBase):
    """The acting policy on its own random stream (torchrl's ``DreamerV3SeededPolicy``), restarted whenever every
    world starts an episode: an evaluation from a reset depends on the weights and the worlds' seed alone, and draws
    nothing from the training RNGs (the RSSM samples its latent even when the actor takes its mode)."""

    def __init__(self, policy: TensorDictModuleBase, seed: int = 0):
        super().__init__()
        self.seeded = DreamerV3SeededPolicy(policy, seed)
        self.in_keys, self.out_keys = policy.in_keys, policy.out_keys

    def forward(self, td: TensorDictBase) -> TensorDictBase:
        if bool(td["is_init"].all()):
            self.seeded.reset_counter()
        return self.seeded(td)


def make_policy(model: DreamerModel) -> TensorDictModuleBase:
    """The policy evaluations and ``load_policy`` use (deterministic: the actor's mode, under
    ``ExplorationType.DETERMINISTIC``)."""
    return _EvaluationPolicy(acting_policy(model))


def make_transforms(cfg: DictConfig, obs_keys: Sequence[str], model: DreamerModel) -> list[Transform]:
    """Episode-start flags and the carried latent and previous action, zeroed at every reset."""
    return [
        InitTracker(),
        TensorDictPrimer(random=False, default_value=0.0, expand_specs=True,
                         state=Unbounded(model.state_dim), belief=Unbounded(model.belief_dim),
                         prev_action=Unbounded(NUM_ACTIONS)),
    ]


# ------------------------------------------------------------------------------------------------ replay
class SequenceReplay:
    """Every world's transitions in time order, sampled as sequences.

    A torchrl ``ReplayBuffer`` on a two-dimensional ``LazyTensorStorage`` (rows = time, one column per world;
    ``capacity`` transitions in all) with a ``SliceSampler`` whose trajectories are the worlds' streams (``world``),
    so a sequence may run across an episode's end: ``is_init`` marks where the RSSM restarts, as in DreamerV3.
    Its state for a checkpoint is the rows written so far and the writer's cursor (not the whole preallocated
    storage).
    """

    def __init__(self, capacity: int, num_envs: int, sequence_length: int, batch_size: int):
        if capacity // num_envs < sequence_length:
            raise ValueError(f"algo.buffer_size ({capacity}) holds fewer than algo.sequence_length "
                             f"({sequence_length}) steps of each of the {num_envs} worlds")
        self.num_envs, self.sequence_length, self.batch_size = num_envs, sequence_length, batch_size
        self.buffer = ReplayBuffer(
            storage=LazyTensorStorage(capacity - capacity % num_envs, ndim=2),
            sampler=SliceSampler(slice_len=sequence_length, traj_key="world", truncated_key=None),
            batch_size=batch_size * sequence_length,
        )

    @property
    def rows(self) -> int:
        """Steps stored per world."""
        return len(self.buffer) // self.num_envs

    def extend(self, transition: TensorDictBase) -> None:
        """One step of every world (batch ``[num_envs]``)."""
        transition["world"] = torch.arange(self.num_envs)
        self.buffer.extend(transition.unsqueeze(1))  # [world, time]; the storage keeps time first

    def sample(self, sequences: int | None = None, length: int | None = None) -> TensorDictBase:
        """``[sequences, length]`` consecutive steps of random worlds (default: the training batch)."""
        if sequences is None and length is None:
            batch = self.buffer.sample()
            return batch.reshape(self.batch_size, self.sequence_length)
        sampler = SliceSampler(slice_len=length, traj_key="world", truncated_key=None)
        index, _ = sampler.sample(self.buffer.storage, sequences * length)
        return self.buffer.storage[index].reshape(sequences, length)

    def state_dict(self) -> dict:
        storage = self.buffer.storage
        rows = storage._storage[: self.rows].clone() if self.rows else None
        return {"rows": rows, "writer": self.buffer._writer.state_dict()}

    def load_state_dict(self, state: Mapping) -> None:
        self.buffer.empty()
        if state["rows"] is not None:
            self.buffer.extend(state["rows"].transpose(0, 1))  # rows 0.. in storage order, as they were
        self.buffer._writer.load_state_dict(state["writer"])


# ------------------------------------------------------------------------------------------------ pictures
@torch.no_grad()
def openloop_frames(model: DreamerModel, sequences: TensorDictBase, context: int) -> tuple[torch.Tensor, ...]:
    """Real and predicted frames of ``sequences`` (``[n, T]`` from the replay buffer): the world model filters the
    first ``context`` steps (posterior), then imagines the rest from the real actions alone (prior, open loop).
    Returns uint8 ``[n, T, H, W, 3]`` truth and model."""
    n, length = sequences.shape
    seq = sequences.select("action", "is_init", *_next(*model.obs_keys)).clone()
    seq["state"] = torch.zeros(n, length, model.state_dim)
    seq["belief"] = torch.zeros(n, length, model.belief_dim)
    filtered = world_model(model)[:3](seq[:, :context])  # one-hot, encoder, RSSM rollout
    state, belief = filtered["next", "state"][:, -1], filtered["next", "belief"][:, -1]
    states, beliefs = [filtered["next", "state"]], [filtered["next", "belief"]]
    actions = _one_hot(seq["action"][:, context:])
    for t in range(length - context):
        _, state, belief = model.prior(state, belief, actions[:, t])
        states.append(state.unsqueeze(1))
        beliefs.append(belief.unsqueeze(1))
    pixel_index = model.obs_keys.index("pixels")
    predicted = model.decoder(torch.cat(states, 1), torch.cat(beliefs, 1))[pixel_index]
    truth = seq["next", "pixels"]
    return truth, (predicted.clamp(0, 1) * 255).round().to(torch.uint8)


def openloop_grid(truth: torch.Tensor, predicted: torch.Tensor, context: int) -> np.ndarray:
    """Per sequence three rows — real frames, the model's, their absolute difference — one column per step; a
    white bar under the filtered (context) steps tells them from the imagined ones."""
    n, length, height, width, _ = truth.shape
    gap = 2
    error = (truth.float() - predicted.float()).abs().clamp(0, 255).to(torch.uint8)
    cell_h, cell_w = height + gap, width + gap
    grid = np.full((n * (3 * cell_h + 2 * gap), length * cell_w, 3), 32, dtype=np.uint8)
    for i in range(n):
        top = i * (3 * cell_h + 2 * gap)
        for r, frames in enumerate((truth, predicted, error)):
            for t in range(length):
                y, x = top + r * cell_h, t * cell_w
                grid[y:y + height, x:x + width] = frames[i, t].numpy()
        bar = top + 3 * cell_h
        grid[bar:bar + gap, : context * cell_w - gap] = 255
    return grid


def save_openloop(model: DreamerModel, replay: SequenceReplay, cfg: DictConfig, path: Path) -> Path | None:
    """An open-loop picture of ``cfg.openloop.sequences`` random replayed sequences (``context`` filtered steps,
    then ``horizon`` imagined ones) as a PNG; drawn on its own RNG stream, so training does not depend on it."""
    length = cfg.openloop.context + cfg.openloop.horizon
    if "pixels" not in model.obs_keys or replay.rows < length:
        return None
    import matplotlib.image

    with torch.random.fork_rng():
        torch.manual_seed(len(replay.buffer))
        sequences = replay.sample(cfg.openloop.sequences, length)
        truth, predicted = openloop_frames(model, sequences, cfg.openloop.context)
    path.parent.mkdir(parents=True, exist_ok=True)
    matplotlib.image.imsave(path, openloop_grid(truth, predicted, cfg.openloop.context))
    return path


# ------------------------------------------------------------------------------------------------ training
def _updates_due(cfg: DictConfig, steps: int, rows: int, num_envs: int) -> int:
    """Gradient steps owed after ``steps`` env steps: ``replay_ratio`` per env step once ``learning_starts`` env
    steps are stored and every world holds a sequence."""
    start = max(cfg.learning_starts, cfg.sequence_length * num_envs)
    if steps < start or rows < cfg.sequence_length:
        return 0
    return int(cfg.replay_ratio * (steps - start)) + 1


def train(run: Run) -> None:
    cfg = run.cfg.algo
    model = make_model(cfg, run.obs_shapes)
    env = run.train_env(make_transforms(cfg, run.obs_keys, model))
    num_envs = env.batch_size.numel()
    policy = acting_policy(model)
    keys = run.obs_keys

    # world model: KL balancing (dynamics / representation weights, free nats, unimix), pixels as x/255 and the
    # vector keys in symlog space, two-hot reward, continue predicted from "terminated" (not truncation)
    model_loss = DreamerV3ModelLoss(
        world_model(model), kl_mode="separate", lambda_dynamic=cfg.world_model.kl_dynamic,
        lambda_representation=cfg.world_model.kl_representation, free_bits=cfg.world_model.free_nats,
        unimix=cfg.model.unimix, lambda_continue=cfg.world_model.continue_scale, reco_loss="l2",
        reco_symlog=[k != "pixels" for k in keys], reward_two_hot=True, num_reward_bins=cfg.model.bins)
    model_loss.set_keys(pixels=list(keys), reco_pixels=[f"reco_{k}" for k in keys])
    critic = value_model(model)
    actor_loss = DreamerV3ActorLoss(
        model.actor, critic, imagination_env(model), continuation_model=continuation_model(model),
        imagination_horizon=cfg.horizon, use_reinforce=True, entropy_bonus=cfg.actor.entropy,
        return_normalization=True, return_normalization_rate=1 - cfg.actor.return_decay,
        return_normalization_quantiles=tuple(cfg.actor.return_percentiles), return_normalization_min_scale=1.0)
    actor_loss.make_value_estimator(ValueEstimators.TDLambda, gamma=cfg.gamma, lmbda=cfg.lmbda)
    value_loss = DreamerV3ValueLoss(critic, value_loss="two_hot", num_value_bins=cfg.model.bins,
                                    actor_loss=actor_loss, slow_critic_regularization=cfg.critic.slow_regularizer)
    slow_critic = SoftUpdate(value_loss, tau=cfg.critic.tau)

    def adam(params, section: DictConfig) -> torch.optim.Adam:
        return torch.optim.Adam(params, lr=section.lr, eps=section.eps, fused=True)  # fused: ~5x faster on CPU

    optimizers = {"world_model": adam(model.world_model_parameters(), cfg.world_model),
                  "actor": adam(model.actor.parameters(), cfg.actor),
                  "critic": adam(model.value.parameters(), cfg.critic)}
    replay = SequenceReplay(cfg.buffer_size, num_envs, cfg.sequence_length, cfg.batch_size)
    stored = ["action", "is_init", *_next(*keys, "reward", "done", "terminated")]
    counters = Counters(updates=0)

    def step(name: str, loss: torch.Tensor, params: list[nn.Parameter], clip: float) -> torch.Tensor:
        optimizer = optimizers[name]
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        norm = nn.utils.clip_grad_norm_(params, clip)
        optimizer.step()
        return norm

    def update() -> dict[str, float]:
        batch = replay.sample()
        batch["state"] = torch.zeros(*batch.shape, model.state_dim)
        batch["belief"] = torch.zeros(*batch.shape, model.belief_dim)
        losses, posterior = model_loss(batch)
        wm_loss = sum(v for k, v in losses.items() if k.startswith("loss_")).squeeze()
        wm_norm = step("world_model", wm_loss, model.world_model_parameters(), cfg.world_model.grad_clip)
        # behaviour learning starts from every posterior latent of the batch, without gradient into the model
        start = TensorDict({k: posterior["next", k].reshape(-1, posterior["next", k].shape[-1]) for k in LATENT},
                           [batch.numel()])
        actor_out, imagined = actor_loss(start)
        actor_norm = step("actor", actor_out["loss_actor"], list(model.actor.parameters()), cfg.actor.grad_clip)
        critic_out, _ = value_loss(imagined.detach())
        critic_norm = step("critic", critic_out["loss_value"], list(model.value.parameters()), cfg.critic.grad_clip)
        slow_critic.step()
        metrics = {f"model_{k.removeprefix('loss_model_')}": v.item() for k, v in losses.items()}
        metrics |= {"model_loss": wm_loss.item(), "model_grad_norm": wm_norm.item(),
                    "actor_loss": actor_out["loss_actor"].item(), "actor_entropy": actor_out["actor_entropy"].item(),
                    "return_scale": actor_out["return_scale"].item(), "actor_grad_norm": actor_norm.item(),
                    "imagined_reward": imagined["next", "reward"].mean().item(),
                    "imagined_continuation": actor_out["continuation_mean"].item(),
                    "critic_loss": critic_out["loss_value"].item(), "critic_grad_norm": critic_norm.item(),
                    "imagined_return": imagined["lambda_target"].mean().item()}
        return metrics

    td = run.start(model, {**{f"optimizer_{k}": v for k, v in optimizers.items()}, "value_loss": value_loss,
                           "return_norm": actor_loss.retnorm, "replay": replay, "counters": counters})
    while not run.done:
        transition, td = run.step(policy, td)
        replay.extend(transition.select(*stored))
        metrics = None
        while counters["updates"] < _updates_due(cfg, run.steps, replay.rows, num_envs):
            metrics = update()
            counters["updates"] += 1
            if cfg.openloop.every and counters["updates"] % cfg.openloop.every == 0:
                save_openloop(model, replay, cfg, run.dir / "openloop" /
                              f"openloop-{run.stage.index}-{run.stage.level}-{run.steps:09d}.png")
        if metrics is not None:
            run.log(metrics | {"updates": counters["updates"], "replay_steps": len(replay.buffer)})
        run.end_iteration(td)
