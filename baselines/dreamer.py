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

The networks, losses and optimisers live on ``device`` (``run.device``).  The replay buffer (about 12.4 kB per
transition with pixels, 12.4 GB for S's million) is memory-mapped under the run directory by default
(``algo.buffer_on_disk``): the checkpoint holds its cursor and the few rows the next checkpoint interval could
overwrite, not the rows again.  In memory (``buffer_on_disk=false``) it sits on the device, must fit the memory
there, and the checkpoint holds the rows written so far.  Either way ``resume=true`` continues exactly.
"""

from __future__ import annotations

import logging
import os
import shutil
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictModuleBase, TensorDictSequential
from torch import nn
from torch.nn import functional as F
from torchrl.data import Composite, LazyMemmapStorage, LazyTensorStorage, OneHot, ReplayBuffer, SliceSampler, Unbounded
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

from .checkpoint import CHECKPOINT, load_checkpoint
from .nets import compile_networks, symlog
from .runtime import Counters, Run, parameter_count

log = logging.getLogger(__name__)

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
                out.append(self._symexp(self.heads[key](hidden)))
        return tuple(out)

    def vector(self, key: str, state: torch.Tensor, belief: torch.Tensor) -> torch.Tensor:
        """One vector key's reconstruction alone (raw units), without decoding the pixels."""
        return self.vectors(state, belief, (key,))[key]

    def vectors(self, state: torch.Tensor, belief: torch.Tensor,
                keys: Sequence[str] | None = None) -> dict[str, torch.Tensor]:
        """The vector keys' reconstructions (raw units; all of them by default), without decoding the pixels."""
        hidden = self.mlp(torch.cat([state, belief], dim=-1))
        return {key: self._symexp(self.heads[key](hidden)) for key in (self.heads if keys is None else keys)}

    @staticmethod
    def _symexp(y: torch.Tensor) -> torch.Tensor:
        return torch.sign(y) * torch.expm1(y.abs())


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


def imagination_env(model: DreamerModel, device: torch.device | str = "cpu") -> DreamerEnv:
    """torchrl's ``DreamerEnv`` on the prior and the reward head: the latent world the actor is trained in, on the
    device the model is on."""
    transition = TensorDictModule(model.prior, in_keys=["state", "belief", "action"], out_keys=["_", *LATENT])
    reward = TensorDictSequential(
        TensorDictModule(model.reward, in_keys=list(LATENT), out_keys=["reward_logits"]),
        TensorDictModule(model.two_hot, in_keys=["reward_logits"], out_keys=["reward"]),
    )
    env = DreamerEnv(WorldModelWrapper(transition, reward), prior_shape=(model.state_dim,),
                     belief_shape=(model.belief_dim,), device=device)
    env.observation_spec = Composite(state=Unbounded(model.state_dim, device=device),
                                     belief=Unbounded(model.belief_dim, device=device), device=device)
    env.state_spec = env.observation_spec.clone()
    env.action_spec = OneHot(NUM_ACTIONS, device=device)
    env.reward_spec = Unbounded((1,), device=device)
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


def prefill_policy(td: TensorDictBase) -> TensorDictBase:
    """Uniform random actions (and the matching ``prev_action``), as sheeprl's DreamerV3 fills its buffer before the
    first gradient step: the untrained networks would act about as randomly, at the cost of a forward pass per step
    (with size S on a CPU, most of the prefill's time).  The carried latent stays zero until the policy takes over."""
    action = torch.randint(NUM_ACTIONS, td.batch_size)
    td["action"], td["prev_action"] = action, _one_hot(action)
    return td


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

    A torchrl ``ReplayBuffer`` on a two-dimensional storage (rows = time, one column per world; ``capacity``
    transitions in all) with a ``SliceSampler`` whose trajectories are the worlds' streams (``world``), so a sequence
    may run across an episode's end: ``is_init`` marks where the RSSM restarts, as in DreamerV3.

    The storage is a ``LazyMemmapStorage`` in ``directory`` (files of the full size, filled as the run goes; only the
    pages in use take memory) or, without a directory, a ``LazyTensorStorage`` on ``device``.  Sampled batches are
    moved to ``device`` (from pinned memory on a GPU).

    Checkpoint state: in memory, the rows written so far and the writer's cursor.  On disk, the rows are already
    there: the state is the cursor, the length, and a copy of the rows the next ``guard_rows`` writes would
    overwrite (none until the buffer is full and wraps), so that a run killed after its checkpoint, whose later
    writes have reached the files, resumes on exactly the rows it checkpointed.
    """

    def __init__(self, capacity: int, num_envs: int, sequence_length: int, batch_size: int, *,
                 directory: Path | None = None, device: torch.device | str = "cpu", guard_rows: int = 0,
                 consume_share: float = 0.0, terminal_share: float = 0.0):
        if capacity // num_envs < sequence_length:
            raise ValueError(f"algo.buffer_size ({capacity}) holds fewer than algo.sequence_length "
                             f"({sequence_length}) steps of each of the {num_envs} worlds")
        self.num_envs, self.sequence_length, self.batch_size = num_envs, sequence_length, batch_size
        self.directory, self.device, self.guard_rows = directory, torch.device(device), guard_rows
        for name, share in (("consume_share", consume_share), ("terminal_share", terminal_share)):
            if not 0.0 <= share <= 1.0:
                raise ValueError(f"algo.{name} must lie in [0, 1], got {share}")
        if consume_share + terminal_share > 1.0:
            raise ValueError(f"algo.consume_share + algo.terminal_share must be at most 1, got {consume_share} + "
                             f"{terminal_share}")
        #: sequences of each training batch drawn around a step that ate or drank (the rest: uniformly)
        self.consume_sequences = round(consume_share * batch_size)
        #: sequences of each training batch drawn around a step that ended an episode (``terminated``)
        self.terminal_sequences = min(round(terminal_share * batch_size), batch_size - self.consume_sequences)
        self._sampled = torch.Generator().manual_seed(0)
        self.capacity = capacity - capacity % num_envs
        if directory is not None:
            storage = LazyMemmapStorage(self.capacity, scratch_dir=directory, ndim=2, existsok=True)
        else:
            storage = LazyTensorStorage(self.capacity, ndim=2, device=self.device)
        self.buffer = ReplayBuffer(
            storage=storage,
            sampler=SliceSampler(slice_len=sequence_length, traj_key="world", truncated_key=None),
            batch_size=batch_size * sequence_length,
        )

    @property
    def rows(self) -> int:
        """Steps stored per world."""
        return len(self.buffer) // self.num_envs

    @property
    def place(self) -> str:
        return f"memory-mapped in {self.directory}" if self.directory is not None else f"in memory on {self.device}"

    def extend(self, transition: TensorDictBase) -> None:
        """One step of every world (batch ``[num_envs]``)."""
        transition["world"] = torch.arange(self.num_envs, device=transition.device)
        self.buffer.extend(transition.unsqueeze(1))  # [world, time]; the storage keeps time first

    @property
    def pins(self) -> bool:
        """Whether sampled batches go to the device through pinned memory: memory-mapped rows are read on the host;
        a buffer in memory already lives on the device (its batches are there, nothing to pin)."""
        return self.device.type == "cuda" and self.directory is not None

    def _to_device(self, batch: TensorDictBase) -> TensorDictBase:
        if self.pins:
            return batch.pin_memory().to(self.device, non_blocking=True)
        return batch.to(self.device)

    def sample(self, sequences: int | None = None, length: int | None = None) -> TensorDictBase:
        """``[sequences, length]`` consecutive steps of random worlds (default: the training batch), on the device."""
        if sequences is None and length is None:
            around = [part for key, count in ((("next", "terminated"), self.terminal_sequences),
                                              (("next", "consumed"), self.consume_sequences))
                      if count and (part := self._around(key, count)) is not None]
            if not around:
                batch = self.buffer.sample()
                return self._to_device(batch.reshape(self.batch_size, self.sequence_length))
            uniform = self.batch_size - sum(len(part) for part in around)
            if uniform:
                index, _ = self.buffer.sampler.sample(self.buffer.storage, uniform * self.sequence_length)
                around.insert(0, self.buffer.storage[index].reshape(uniform, self.sequence_length))
            return self._to_device(torch.cat(around, dim=0))
        sampler = SliceSampler(slice_len=length, traj_key="world", truncated_key=None)
        index, _ = sampler.sample(self.buffer.storage, sequences * length)
        return self._to_device(self.buffer.storage[index].reshape(sequences, length))

    def _around(self, key: tuple[str, str], count: int) -> TensorDictBase | None:
        """``count`` sequences, each holding a stored step whose ``key`` is set (``("next", "consumed")``: it ate or
        drank; ``("next", "terminated")``: it ended an episode) at a uniformly drawn position, or None while there is
        none (or too few rows).  A sequence never runs across the writer's cursor, where the newest rows meet the
        oldest."""
        rows, length = self.rows, self.sequence_length
        if rows < length:
            return None
        storage = self.buffer.storage
        eaten = storage._storage[key][:rows].reshape(rows, self.num_envs)
        where = eaten.nonzero()
        if not len(where):
            return None
        storage_rows = self.capacity // self.num_envs
        cursor = int(self.buffer._writer._cursor) % storage_rows
        full = rows == storage_rows
        picks = where[torch.randint(len(where), (4 * count,), generator=self._sampled)]
        offset = torch.randint(length, (len(picks),), generator=self._sampled)
        start = (picks[:, 0] - offset).clamp(0, rows - length)
        if full:  # the rows [start, start + length) must not hold the cursor's row unless it is the first
            crosses = (cursor > start) & (cursor < start + length)
            start, picks = start[~crosses], picks[~crosses]
        if len(start) < count:
            return None
        start, world = start[:count], picks[:count, 1]
        time = start[:, None] + torch.arange(length)
        return storage._storage[time, world[:, None]]

    def _overwritten_next(self) -> torch.Tensor:
        """Rows holding data now that the next ``guard_rows`` writes go to, in writing order."""
        storage_rows = self.capacity // self.num_envs
        cursor = int(self.buffer._writer._cursor) % storage_rows
        ahead = (cursor + torch.arange(min(self.guard_rows, storage_rows))) % storage_rows
        return ahead[ahead < self.rows]

    def state_dict(self) -> dict:
        storage = self.buffer.storage
        writer = self.buffer._writer.state_dict()
        if self.directory is None:
            rows = storage._storage[: self.rows].clone() if self.rows else None
            return {"rows": rows, "writer": writer}
        guard = self._overwritten_next() if self.rows else torch.zeros(0, dtype=torch.long)
        self.flush()
        return {"on_disk": str(self.directory), "length": len(self.buffer), "writer": writer,
                "guard_index": guard, "guard_rows": storage._storage[guard].clone() if len(guard) else None}

    def load_state_dict(self, state: Mapping) -> None:
        if ("on_disk" in state) != (self.directory is not None):
            raise ValueError("the checkpoint's replay buffer was " + ("on disk" if "on_disk" in state else "in memory")
                             + f"; this run's is {self.place}: resume with the algo.buffer_on_disk it was made with")
        self.buffer.empty()
        if self.directory is None:
            if state["rows"] is not None:
                self.buffer.extend(state["rows"].transpose(0, 1))  # rows 0.. in storage order, as they were
            self.buffer._writer.load_state_dict(state["writer"])
            return
        if state["length"]:
            if not (self.directory / "meta.json").exists():
                raise FileNotFoundError(f"the checkpoint's replay buffer is memory-mapped in {self.directory}, which "
                                        "is missing: this run cannot resume exactly")
            storage = self.buffer.storage
            storage._storage = TensorDict.load_memmap(self.directory, mode="r+")
            storage.initialized = True
            storage._len = state["length"]
            if state["guard_rows"] is not None:  # the rows the killed process overwrote after its checkpoint
                storage._storage[state["guard_index"]] = state["guard_rows"]
        self.buffer._writer.load_state_dict(state["writer"])

    def flush(self) -> None:
        """Write the memory-mapped rows to the disk (so a checkpoint never refers to rows only in the page cache)."""
        if self.directory is None or not self.directory.exists():
            return
        for path in self.directory.rglob("*.memmap"):
            fd = os.open(path, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)


def transition_bytes(env, stored: Sequence) -> int:
    """Bytes one world's transition takes in the replay buffer (what :func:`train` stores, plus the world index)."""
    fake = env.fake_tensordict().select(*stored, strict=False)  # ("next", "consumed") is added by train()
    per_world = sum(t.element_size() * t.numel() for t in fake.values(True, True)) // env.batch_size.numel()
    return per_world + torch.tensor(0).element_size() + int(("next", "consumed") in stored)  # a bool


def available_memory(device: torch.device) -> int | None:
    """Bytes free for a buffer on ``device``: the GPU's free memory, or the system's MemAvailable."""
    if device.type == "cuda":
        return torch.cuda.mem_get_info(device)[0]
    try:
        with open("/proc/meminfo") as f:
            info = dict(line.split(":", 1) for line in f)
        return int(info["MemAvailable"].split()[0]) * 1024
    except (OSError, KeyError, ValueError):
        return None


def _gb(n: float) -> str:
    return f"{n / 1e9:.3g} GB"


# ------------------------------------------------------------------------------------------------ pictures
@torch.no_grad()
def openloop_frames(model: DreamerModel, sequences: TensorDictBase, context: int) -> tuple[torch.Tensor, ...]:
    """Real and predicted frames of ``sequences`` (``[n, T]`` from the replay buffer): the world model filters the
    first ``context`` steps (posterior), then imagines the rest from the real actions alone (prior, open loop).
    Returns uint8 ``[n, T, H, W, 3]`` truth and model."""
    n, length = sequences.shape
    seq = sequences.select("action", "is_init", *_next(*model.obs_keys)).clone()
    device = next(model.parameters()).device
    seq["state"] = torch.zeros(n, length, model.state_dim, device=device)
    seq["belief"] = torch.zeros(n, length, model.belief_dim, device=device)
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
    return truth.cpu(), (predicted.float().clamp(0, 1) * 255).round().to(torch.uint8).cpu()


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

    device = next(model.parameters()).device
    with torch.random.fork_rng(devices=[device] if device.type == "cuda" else []):
        torch.manual_seed(len(replay.buffer))
        sequences = replay.sample(cfg.openloop.sequences, length)
        truth, predicted = openloop_frames(model, sequences, cfg.openloop.context)
    path.parent.mkdir(parents=True, exist_ok=True)
    matplotlib.image.imsave(path, openloop_grid(truth, predicted, cfg.openloop.context))
    return path


# ------------------------------------------------------------------------------------------------ diagnostics
def consumed(transition: TensorDictBase) -> torch.Tensor:
    """Whether each world ate or drank on this step (its food or water count grew): the replay keeps it as
    ``("next", "consumed")`` so that :func:`diagnostics` can tell the reward head's error on those rare steps."""
    before, after = transition["info"], transition["next", "info"]
    return (after["food_eaten"] + after["water_eaten"]) > (before["food_eaten"] + before["water_eaten"])


def _run_replay(run_dir: str | Path) -> tuple[dict, TensorDictBase, int, int]:
    """A DreamerV3 run's last checkpoint and the rows its memory-mapped replay holds ``[rows, worlds]``, with the
    number of worlds and of rows; refused for another algorithm, a run without interoception or a replay kept in
    memory."""
    state = load_checkpoint(Path(run_dir) / CHECKPOINT)
    if state.get("algo") not in ("dreamer", "dreamer_xs") or "interoception" not in state["obs_keys"]:
        raise ValueError(f"{run_dir}: not a DreamerV3 run that observes interoception")
    replay = state["components"]["replay"]
    if "on_disk" not in replay:
        raise ValueError(f"{run_dir}: its replay buffer was kept in memory (algo.buffer_on_disk=false), not on disk")
    num_envs = int(state["num_envs"])
    rows = replay["length"] // num_envs
    return state, TensorDict.load_memmap(replay["on_disk"])[:rows], num_envs, rows


def _probe_replay(run_dir: str | Path, sequences: int, model_file: str | Path | None = None
                  ) -> tuple[dict, DictConfig, DreamerModel, TensorDictBase, int]:
    """A DreamerV3 run's last checkpoint (its state, config and model; with ``model_file``, the networks of that file
    instead, e.g. ``model-best-0-1-1.pt``), ``sequences`` replayed sequences of 32 steps from its memory-mapped
    replay, around the last eating steps stored (spread over the replay where there are too few), with the zero
    initial latent the world model starts from, and the env steps the networks had trained for: what the probes
    read."""
    state, data, num_envs, rows = _run_replay(run_dir)
    networks, steps = state, int(state["counters"]["steps"])
    if model_file is not None:
        networks = load_checkpoint(Path(model_file))
        if networks.get("algo") != state["algo"] or networks.get("obs_shapes") != state["obs_shapes"]:
            raise ValueError(f"model={model_file}: not the networks of this run's algorithm and observations "
                             f"({state['algo']}, {sorted(state['obs_shapes'])})")
        steps = int(networks.get("env_steps") or networks.get("counters", {}).get("steps", 0))
    cfg = OmegaConf.create(networks["config"])
    model = make_model(cfg.algo, {k: tuple(v) for k, v in state["obs_shapes"].items()})
    model.load_state_dict(networks["model"])
    model.eval()
    length = min(32, rows)
    eaten = data["next", "consumed"].reshape(rows, num_envs).nonzero()
    spread = torch.stack([torch.arange(sequences) * rows // sequences, torch.arange(sequences) % num_envs], dim=1)
    anchors = torch.cat([eaten[-sequences:], spread])[:sequences]  # too few eating steps: others, spread out
    start = (anchors[:, 0] - length // 2).clamp(0, rows - length)
    batch = data[start[:, None] + torch.arange(length), anchors[:, 1:2]].clone()
    batch["state"] = torch.zeros(*batch.shape, model.state_dim)
    batch["belief"] = torch.zeros(*batch.shape, model.belief_dim)
    return state, cfg, model, batch, steps


def ev_decoding_errors(run_dir: str | Path, sequences: int = 64, model_file: str | Path | None = None
                       ) -> dict[str, Any]:
    """How well a DreamerV3 run's world model knows the EVs: the mean absolute error, in raw units, of the
    interoception decoded from the posterior, on the eating steps and on the other steps of ``sequences`` replayed
    sequences of 32 steps around the last eating steps stored (spread over the replay where there are too few),
    with the run's last checkpoint and its memory-mapped replay.  The reward is computed from the EVs: a latent
    that does not hold them cannot predict it."""
    from evaaa import EV_NAMES

    _, _, model, batch, steps = _probe_replay(run_dir, sequences, model_file)
    with torch.no_grad():
        out = world_model(model)(batch)
    error = (out["next", "reco_interoception"] - out["next", "interoception"]).abs()
    at = out["next", "consumed"].reshape(batch.shape)
    result: dict[str, Any] = {"env_steps": steps, "sequences": len(batch),
                              "eating_steps": int(at.sum())}
    for name, mask in (("eating", at), ("other", ~at)):
        per_ev = error[mask].mean(0) if mask.any() else torch.full((len(EV_NAMES),), float("nan"))
        result[name] = dict(zip(EV_NAMES, per_ev.tolist()))
    # where the EVs are lost: a linear read-out of them from each stage, fitted on half of the sequences and
    # measured on the other half as the share of their variance it explains (the decoder is one read-out; these say
    # whether the information is there at all)
    target = out["next", "interoception"].float().reshape(-1, len(EV_NAMES))
    fit = (torch.arange(len(batch)) % 2 == 0)[:, None].expand(batch.shape).reshape(-1)
    nxt = out["next"]
    # "nothing": a constant feature (the fitted rows' mean, about 0 by construction): the check of the read-out
    sources = {"nothing": torch.zeros(*batch.shape, 1), "embedding": nxt["encoded_latents"],
               "stochastic latent": nxt["state"],
               "deterministic state": nxt["belief"], "latent (both)": torch.cat([nxt["state"], nxt["belief"]], -1)}
    result["linear_probe"] = {
        name: dict(zip(EV_NAMES, linear_probe_r2(x.float().reshape(len(target), -1), target, fit).tolist()))
        for name, x in sources.items()} if bool(fit.any()) and bool((~fit).any()) else {}
    return result


def fit_world_model(run_dir: str | Path, updates: int, every: int, overrides: Sequence[str] = (),
                    held_out: float = 0.1, seed: int = 0, report: Any = None, keys: Sequence[str] | None = None,
                    device: str | torch.device = "cpu") -> list[dict[str, float]]:
    """How fast a fresh world model learns what eating does, from a DreamerV3 run's stored replay alone: no env,
    no actor, no critic, so world-model settings can be compared in minutes on the same data.

    Builds the run's world model anew (its config with ``overrides``, dotted ``algo`` keys such as
    ``model.stochastic=32`` or ``consume_share=0.5``), trains it for ``updates`` gradient steps on the first
    ``1 - held_out`` of the replay's rows (batches as the run drew them: ``batch_size`` sequences of
    ``sequence_length`` steps, ``consume_share`` of them around an eating step), and every ``every`` steps measures
    on the held-out rows' eating steps: from the posterior before each, one imagined step of every action
    (:func:`imagine_each_action`), and the decoded satiation plus hydration change of eating against the mean of the
    other four actions (``eat_effect``), beside the same on the eat actions that found nothing
    (``eat_effect_nothing``, which should stay near 0), the real change (``real_effect``) and the change decoded
    from the posterior that saw the observation after eating (``posterior_effect``: whether the latent holds it).
    ``keys``: the observation keys the new model sees (default: the run's; interoception is needed).  ``device``:
    where the model and its batches live (the replay stays memory-mapped; each batch is copied there).
    ``report(row)`` is called with each measurement.  The last row adds ``latent_auc_embedding``,
    ``latent_auc_state``, ``latent_auc_belief`` and ``latent_auc_belief_after_eat``: how well a logistic read-out of
    the trained encoder's embedding and latent on the observation an eat press was made on (and of the deterministic
    state the eat action leads to) tells a press that ate from a fruitless one, on the held-out rows
    (:func:`eat_success_readout` does the same from the observation itself)."""
    state, data, num_envs, rows = _run_replay(run_dir)
    cfg = OmegaConf.merge(OmegaConf.create(state["config"]).algo, OmegaConf.from_dotlist(list(overrides)))
    shapes = {k: tuple(v) for k, v in state["obs_shapes"].items()}
    if keys is not None:
        if "interoception" not in keys or not set(keys) <= set(shapes):
            raise ValueError(f"keys must include interoception and come from the run's {sorted(shapes)}, got "
                             f"{list(keys)}")
        shapes = {k: v for k, v in shapes.items() if k in keys}
    torch.manual_seed(seed)
    model = make_model(cfg, shapes).to(device)
    loss = WorldModelLoss(cfg, model).to(device)
    optimizer = torch.optim.Adam(model.world_model_parameters(), lr=cfg.world_model.lr, eps=cfg.world_model.eps)
    length, context = cfg.sequence_length, 16
    split = int(rows * (1 - held_out))
    if split < length or rows - split < context + 1:
        raise ValueError(f"{run_dir}: {rows} rows per world are too few to hold out {held_out} of them")
    eaten = data["next", "consumed"].reshape(rows, num_envs)
    # an episode's first step was taken on its reset observation, which the replay does not store (the row before
    # holds the previous episode's last one): such steps are left out of the measurements below
    first = data["is_init"].reshape(rows, num_envs)
    train_eaten = eaten[:split].nonzero()
    consume = round(float(cfg.get("consume_share", 0.0)) * cfg.batch_size) if len(train_eaten) else 0
    gen = torch.Generator().manual_seed(seed)

    def sequences(starts: torch.Tensor, worlds: torch.Tensor, steps: int) -> TensorDictBase:
        batch = data[starts[:, None] + torch.arange(steps), worlds[:, None]].clone().to(device)
        batch["state"] = torch.zeros(*batch.shape, model.state_dim, device=device)
        batch["belief"] = torch.zeros(*batch.shape, model.belief_dim, device=device)
        return batch

    # held out: the context before each eating step (and each fruitless eat), the step itself last
    eat = ACTION_NAMES.index("eat")
    test_eaten = (eaten[split:] & ~first[split:]).nonzero()
    test_eaten = test_eaten[test_eaten[:, 0] >= context]
    pressed = ((data["action"][split:] == eat) & ~eaten[split:] & ~first[split:]).nonzero()
    pressed = pressed[pressed[:, 0] >= context]
    pressed = pressed[torch.randperm(len(pressed), generator=gen)[:256]]
    # the same measurement on eating steps the model trains on: learnt there but not held out is too few meals
    seen_eaten = train_eaten[(train_eaten[:, 0] >= context) & ~first[train_eaten[:, 0], train_eaten[:, 1]]]
    seen_eaten = seen_eaten[torch.randperm(len(seen_eaten), generator=gen)[:64]]

    def decoded(latent: Mapping[str, torch.Tensor]) -> torch.Tensor:  # satiation + hydration
        return model.decoder.vector("interoception", latent["state"], latent["belief"])[..., :2].sum(-1)

    @torch.no_grad()
    def eat_effect(where: torch.Tensor, offset: int = split) -> tuple[float, float, float]:
        if not len(where):
            return float("nan"), float("nan"), float("nan")
        batch = sequences(offset + where[:, 0] - context, where[:, 1], context + 1)
        nxt = world_model(model)(batch)["next"]
        # the posterior after the step before the action; the action's own step is the last row
        before = {k: nxt[k][:, -2] for k in LATENT}
        step = imagine_each_action(model.prior, before["state"], before["belief"], 8,
                                   ev=lambda st, be: model.decoder.vector("interoception", st, be)[..., :2])
        change = step["ev"].sum(-1) - decoded(before)[:, None]
        others = [i for i in range(NUM_ACTIONS) if i != eat]
        effect = float((change[:, eat] - change[:, others].mean(1)).mean())
        real = float((batch["next", "interoception"][:, -1, :2] - batch["next", "interoception"][:, -2, :2])
                     .float().sum(-1).mean())
        # the same change read from the posteriors, which saw the observation after eating: what the latent holds
        seen = float((decoded({k: nxt[k][:, -1] for k in LATENT}) - decoded(before)).mean())
        return effect, real, seen

    rows_out: list[dict[str, float]] = []
    began = time.perf_counter()
    for update in range(updates + 1):
        if update % every == 0 or update == updates:
            model.eval()
            effect, real, seen = eat_effect(test_eaten)
            nothing, _, _ = eat_effect(pressed)
            trained, _, _ = eat_effect(seen_eaten, 0)
            row = {"updates": update, "seconds": time.perf_counter() - began, "eat_effect": effect,
                   "eat_effect_nothing": nothing, "eat_effect_trained": trained, "real_effect": real,
                   "posterior_effect": seen,
                   "held_out_eating_steps": len(test_eaten),
                   "world_model_parameters": sum(p.numel() for p in model.world_model_parameters())}
            rows_out.append(row)
            if report is not None:
                report(row)
            model.train()
        if update == updates:
            break
        uniform = cfg.batch_size - consume
        starts = torch.randint(split - length + 1, (uniform,), generator=gen)
        worlds = torch.randint(num_envs, (uniform,), generator=gen)
        if consume:
            picks = train_eaten[torch.randint(len(train_eaten), (consume,), generator=gen)]
            offset = torch.randint(length, (consume,), generator=gen)
            starts = torch.cat([starts, (picks[:, 0] - offset).clamp(0, split - length)])
            worlds = torch.cat([worlds, picks[:, 1]])
        total, *_ = loss(sequences(starts, worlds, length))
        optimizer.zero_grad(set_to_none=True)
        total.backward()
        nn.utils.clip_grad_norm_(model.world_model_parameters(), cfg.world_model.grad_clip)
        optimizer.step()
    # what the trained latent keeps of "this press will eat": a logistic read-out, fitted on the training rows'
    # presses and scored on the held-out ones, as eat_success_readout does from the observation itself
    model.eval()
    presses = ((data["action"][context:] == eat) & ~first[context:]).nonzero()
    presses[:, 0] += context
    success = eaten[presses[:, 0], presses[:, 1]]
    fruitless = presses[~success]
    presses = torch.cat([presses[success], fruitless[torch.randperm(len(fruitless), generator=gen)[:1500]]])
    labels = eaten[presses[:, 0], presses[:, 1]]
    features: dict[str, list[torch.Tensor]] = {"embedding": [], "state": [], "belief": [], "belief_after_eat": []}
    with torch.no_grad():
        for chunk in presses.split(256):
            nxt = world_model(model)(sequences(chunk[:, 0] - context, chunk[:, 1], context + 1))["next"]
            features["embedding"].append(nxt["encoded_latents"][:, -2])  # the encoder's, before the latent
            features["state"].append(nxt["state"][:, -2])  # the posterior on the observation pressed on
            features["belief"].append(nxt["belief"][:, -2])
            features["belief_after_eat"].append(nxt["belief"][:, -1])  # the eat action taken, its outcome unseen
    rows_out[-1] |= {f"latent_auc_{name}": logistic_readout_auc(torch.cat(x).cpu(), labels, presses[:, 0] < split)
                     for name, x in features.items()}
    return rows_out


def logistic_readout_auc(features: torch.Tensor, labels: torch.Tensor, fit: torch.Tensor) -> float:
    """How well a logistic regression from ``features`` [N, F], fitted (classes balanced, L-BFGS) on the rows where
    ``fit`` is true, tells ``labels`` apart on the other rows: the area under the ROC curve there (0.5: no better
    than chance; 1: perfectly), from the Mann-Whitney U of the scores.  NaN without both labels on both sides."""
    from scipy.stats import mannwhitneyu

    y = labels.bool()
    if not (y[fit].any() and (~y[fit]).any() and y[~fit].any() and (~y[~fit]).any()):
        return float("nan")
    x = features.double()
    mean, std = x[fit].mean(0), x[fit].std(0).clamp_min(1e-6)
    x = (x - mean) / std
    weights = torch.zeros(x.shape[1], dtype=x.dtype, requires_grad=True)
    bias = torch.zeros((), dtype=x.dtype, requires_grad=True)
    balance = (~y[fit]).sum() / y[fit].sum()
    optimizer = torch.optim.LBFGS([weights, bias], max_iter=200, line_search_fn="strong_wolfe")

    def closure() -> torch.Tensor:
        optimizer.zero_grad()
        loss = F.binary_cross_entropy_with_logits(x[fit] @ weights + bias, y[fit].double(), pos_weight=balance)
        loss = loss + 1e-4 * weights.pow(2).sum()
        loss.backward()
        return loss

    optimizer.step(closure)
    with torch.no_grad():
        score = (x[~fit] @ weights).numpy()
    test = y[~fit].numpy()
    u = mannwhitneyu(score[test], score[~test]).statistic
    return float(u / (test.sum() * (~test).sum()))


def eat_success_readout(run_dir: str | Path, held_out: float = 0.2) -> dict[str, Any]:
    """Whether the observations say when eating will work: for every stored eat press of a DreamerV3 run's replay,
    the observation it was pressed on, and whether it ate or drank.  A logistic read-out per vector key (and of all
    of them together) is fitted on the first ``1 - held_out`` of the rows; its held-out AUC says how much of "food
    within reach" the key carries, the information a world model needs to predict what eating does."""
    state, data, num_envs, rows = _run_replay(run_dir)
    # row r's action was taken on the observation stored as row r - 1's next; a reset's first one is not stored
    pressed = (data["action"][1:] == ACTION_NAMES.index("eat")) & ~data["is_init"][1:].reshape(rows - 1, num_envs)
    where = pressed.nonzero()
    ate = data["next", "consumed"].reshape(rows, num_envs)[1:][pressed]
    fit = where[:, 0] < int((rows - 1) * (1 - held_out))
    keys = [k for k in state["obs_keys"] if k != "pixels"]
    seen = {k: data["next", k][:-1][where[:, 0], where[:, 1]].float().reshape(len(where), -1) for k in keys}
    auc = {k: logistic_readout_auc(x, ate, fit) for k, x in seen.items()}
    auc["all of them"] = logistic_readout_auc(torch.cat(list(seen.values()), -1), ate, fit)
    return {"presses": len(where), "ate": int(ate.sum()), "held_out_ate": int(ate[~fit].sum()), "auc": auc}


def linear_probe_r2(features: torch.Tensor, target: torch.Tensor, fit: torch.Tensor,
                    ridge: float = 1e-3) -> torch.Tensor:
    """Per target column, the share of ``symlog(target)``'s variance (as the model codes the EVs) that a ridge
    regression from ``features`` explains on the rows where ``fit`` is false, fitted on the rows where it is true:
    1 holds it all, 0 nothing beyond the fitted mean (below 0: worse than that mean).  Features are standardised on
    the fitted rows; ``ridge`` times the number of fitted rows is the penalty."""
    x, y = features[fit].double(), symlog(target[fit].double())
    mean, std = x.mean(0), x.std(0).clamp_min(1e-6)  # a constant column: zeros, only the intercept is fitted
    x = torch.cat([(x - mean) / std, torch.ones(len(x), 1, dtype=x.dtype)], 1)
    gram = x.T @ x + ridge * len(x) * torch.eye(x.shape[1], dtype=x.dtype)
    weights = torch.linalg.solve(gram, x.T @ y)
    test = torch.cat([(features[~fit].double() - mean) / std, torch.ones(int((~fit).sum()), 1, dtype=x.dtype)], 1)
    truth = symlog(target[~fit].double())
    residual = ((test @ weights) - truth).pow(2).sum(0)
    spread = (truth - y.mean(0)).pow(2).sum(0).clamp_min(1e-12)
    return (1 - residual / spread).float()


def imagine_each_action(prior: Any, state: torch.Tensor, belief: torch.Tensor, samples: int = 8,
                        **heads: Any) -> dict[str, torch.Tensor]:
    """Every action taken once from each latent ``[N, ...]`` through ``prior`` (``(state, belief, one-hot) ->
    (logits, state, belief)``), the next latent drawn ``samples`` times: each head ``(state, belief) -> [N, ...]``
    read on it, averaged over the draws, as ``[N, actions, ...]``.  What imagination believes one action does."""
    out: dict[str, list[torch.Tensor]] = {name: [] for name in heads}
    for a in range(NUM_ACTIONS):
        onehot = _one_hot(torch.full(state.shape[:-1], a, dtype=torch.long, device=state.device))
        totals: dict[str, torch.Tensor] = {}
        for _ in range(samples):
            _, next_state, next_belief = prior(state, belief, onehot)
            for name, head in heads.items():
                totals[name] = totals.get(name, 0) + head(next_state, next_belief) / samples
        for name in heads:
            out[name].append(totals[name])
    return {name: torch.stack(values, dim=1) for name, values in out.items()}


@torch.no_grad()
def imagined_action_values(run_dir: str | Path, sequences: int = 64, samples: int = 8,
                           model_file: str | Path | None = None) -> dict[str, Any]:
    """What a DreamerV3 run's world model and critic say each action is worth, from the posterior states of
    ``sequences`` replayed sequences (as :func:`ev_decoding_errors` picks them): one imagined step of every action,
    then the critic, ``r + γ·c·v`` (``samples`` draws of the next latent), beside the actor's probabilities and the
    EVs decoded before and after the step.  Grouped by what really followed each state: every state, the steps that
    ate or drank, the eat actions that found nothing, and the five steps before an eating step.  Where imagination
    ranks the actions the same way in every group, and eating raises no decoded EV where real eating did, the actor
    has nothing to learn from but a bias (docs/training.md, "What was tried on level 1-1")."""
    from evaaa import EV_NAMES

    state, cfg, model, batch, steps = _probe_replay(run_dir, sequences, model_file)
    nxt = world_model(model)(batch)["next"]
    # start from the posterior after each observation; what really followed it is the next row's action and outcome
    shape = (len(batch), batch.shape[1] - 1)
    latent = {k: nxt[k][:, :-1].reshape(-1, nxt[k].shape[-1]).float() for k in LATENT}
    action = batch["action"][:, 1:].reshape(-1)
    ate = batch["next", "consumed"][:, 1:].reshape(shape)
    fresh = batch["is_init"][:, 1:].reshape(-1)
    evs = nxt["interoception"].float()
    real_change = (evs[:, 1:] - evs[:, :-1]).reshape(-1, len(EV_NAMES))

    def reward(s: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        return model.two_hot(model.reward(s, b)).squeeze(-1)

    def value(s: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        return model.two_hot(model.value(s, b)).squeeze(-1)

    def going_on(s: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(model.cont(s, b)).squeeze(-1)

    def interoception(s: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        return model.decoder.vector("interoception", s, b)

    step = imagine_each_action(model.prior, latent["state"], latent["belief"], samples, reward=reward,
                               value=value, going_on=going_on, interoception=interoception)
    q = step["reward"] + cfg.algo.gamma * step["going_on"] * step["value"]
    now = interoception(latent["state"], latent["belief"])
    ev_change = step["interoception"] - now[:, None]
    probs = model.actor.get_dist(TensorDict(latent, [len(action)])).probs
    norm = state["components"]["return_norm"]
    scale = max(float(norm["high"].max() - norm["low"].min()), 1.0) if "high" in norm else float("nan")
    before = torch.zeros(shape, dtype=torch.bool)
    for d in range(1, 6):
        before[:, :-d] |= ate[:, d:]
    ate, before = ate.reshape(-1), before.reshape(-1)
    eat = ACTION_NAMES.index("eat")
    groups = {"every state": ~fresh, "ate or drank": ate & ~fresh,
              "ate nothing": (action == eat) & ~ate & ~fresh, "1-5 steps before eating": before & ~ate & ~fresh}
    result: dict[str, Any] = {"env_steps": steps, "sequences": len(batch), "return_scale": scale, "groups": {}}
    for name, mask in groups.items():
        if not bool(mask.any()):
            result["groups"][name] = {"states": 0}
            continue
        result["groups"][name] = {
            "states": int(mask.sum()),
            "policy": dict(zip(ACTION_NAMES, probs[mask].mean(0).tolist())),
            "value_over_mean": dict(zip(ACTION_NAMES, (q[mask] - q[mask].mean(1, keepdim=True)).mean(0).tolist())),
            "best_share": dict(zip(ACTION_NAMES, (torch.bincount(q[mask].argmax(1), minlength=NUM_ACTIONS)
                                                  / int(mask.sum())).tolist())),
            "ev_change": {a: dict(zip(EV_NAMES, ev_change[mask][:, i].mean(0).tolist()))
                          for i, a in enumerate(ACTION_NAMES)},
            "real_ev_change": dict(zip(EV_NAMES, real_change[mask].mean(0).tolist())),
        }
    return result


def _masked_mean(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    return x[mask].mean() if bool(mask.any()) else x.new_tensor(float("nan"))


@torch.no_grad()
def diagnostics(model: DreamerModel, critic: TensorDictSequential, posterior: TensorDictBase,
                imagined: TensorDictBase, return_scale: torch.Tensor) -> dict[str, torch.Tensor]:
    """What tells a collapsing DreamerV3 from a learning one, from one gradient step's replayed batch
    (``posterior``: the world model's outputs) and imagination (``imagined``):

    * ``reward_error_consume`` / ``reward_error_other``: the reward head's mean absolute error on the steps that ate
      or drank and on the others (``reward_true_consume`` / ``reward_pred_consume``: the true and predicted reward
      on those steps; ``consume_share``: how many of the batch's steps they are);
    * ``continue_terminal`` / ``continue_error_other``: the continue head's probability of going on where the
      episode ended (should be 0) and of stopping where it went on (should be 0);
    * ``critic_value``: the critic's value of the replayed states;
    * ``policy_<action>``: the actor's mean probability of each action on the replayed states;
    * ``advantage_<action>``: the normalised advantage (λ-return minus the critic's value, over the return scale)
      of imagination's first step, by the action taken: what the actor's REINFORCE gradient pushes each action by.
    """
    nxt = posterior["next"]
    error = (nxt["reward"] - nxt["true_reward"]).abs()
    event = nxt["consumed"]
    out = {"reward_error_consume": _masked_mean(error, event), "reward_error_other": _masked_mean(error, ~event),
           "reward_true_consume": _masked_mean(nxt["true_reward"], event),
           "reward_pred_consume": _masked_mean(nxt["reward"], event), "consume_share": event.float().mean()}
    go_on = torch.sigmoid(nxt["continue_pred"].float())
    ended = nxt["terminated"]
    out["continue_terminal"] = _masked_mean(go_on, ended)
    out["continue_error_other"] = _masked_mean(1 - go_on, ~ended)
    latents = TensorDict({k: nxt[k].reshape(-1, nxt[k].shape[-1]).float() for k in LATENT}, [nxt.numel()])
    out["critic_value"] = critic(latents.clone())["state_value"].mean()
    probs = model.actor.get_dist(latents).probs.mean(0)
    first = imagined[:, 0]
    values = critic(first.select(*LATENT).clone())["state_value"]
    advantage = (first["lambda_target"] - values) / return_scale
    taken = first["action"].float()  # one-hot [N, actions]
    per_action = (taken * advantage).sum(0) / taken.sum(0).clamp_min(1)
    for i, name in enumerate(ACTION_NAMES):
        out[f"policy_{name}"] = probs[i]
        out[f"advantage_{name}"] = per_action[i] if bool(taken[:, i].any()) else per_action.new_tensor(float("nan"))
    return out


# ------------------------------------------------------------------------------------------------ training
def vector_reconstruction(posterior: TensorDictBase, keys: Sequence[str], raw: Sequence[str] = ()) -> torch.Tensor:
    """The vector keys' reconstruction loss as ``DreamerV3ModelLoss`` counts it (squared error in symlog space, or
    in raw units for the keys in ``raw``, summed over each key's entries, averaged over the replayed steps), summed
    over ``keys``.  With pixels it is a small part of the loss (4 EVs against 12,288 pixel values):
    ``algo.world_model.vector_scale`` weighs it more."""
    return _vector_error({k: posterior["next", k] for k in keys}, {k: posterior["next", f"reco_{k}"] for k in keys},
                         raw)


def _vector_error(target: Mapping[str, torch.Tensor], predicted: Mapping[str, torch.Tensor],
                  raw: Sequence[str] = ()) -> torch.Tensor:
    def space(k: str, x: torch.Tensor) -> torch.Tensor:
        return x.float() if k in raw else symlog(x.float())

    return sum(((space(k, target[k]) - space(k, predicted[k])) ** 2).sum(-1).mean() for k in target)


def prior_vector_reconstruction(posterior: TensorDictBase, decoder: DreamerDecoder, keys: Sequence[str],
                                raw: Sequence[str] = (), unimix: float = 0.01) -> torch.Tensor:
    """The vector keys of each next observation decoded from the *prior* (a straight-through draw of its latent,
    with the deterministic state the action led to) instead of the posterior that saw it, scored as
    :func:`vector_reconstruction`: a one-step latent overshooting term (``algo.world_model.prior_vector_scale``)
    that trains the transition, through the decoder, to predict what an action does to the EVs.  Without it only
    the dynamics KL teaches the prior, and a meal, under 1 % of the steps, barely moves it (docs/training.md)."""
    nxt = posterior["next"]
    probs = torch.softmax(nxt["prior_logits"].float(), dim=-1)
    probs = (1 - unimix) * probs + unimix / probs.shape[-1]
    state = torch.distributions.OneHotCategoricalStraightThrough(probs=probs).rsample().flatten(-2)
    predicted = decoder.vectors(state, nxt["belief"], keys)
    return _vector_error({k: nxt[k] for k in keys}, predicted, raw)


class WorldModelLoss(nn.Module):
    """The world model's loss on a replayed batch: torchrl's ``DreamerV3ModelLoss`` (KL balancing with dynamics /
    representation weights, free nats and unimix; pixels as x/255 and the vector keys in symlog space; two-hot
    reward; continue predicted from ``terminated``, not truncation), plus ``algo.world_model.vector_scale - 1``
    times the vector keys' reconstruction.  The keys in ``algo.world_model.raw_keys`` are reconstructed in raw units
    instead of symlog space: symlog squeezes a meal's +3.3 satiation at -8 to a change of 0.34.  Returns the total,
    the loss's terms, the posterior (detached) and the vector keys' reconstruction loss (None without vector
    keys)."""

    def __init__(self, cfg: DictConfig, model: DreamerModel):
        super().__init__()
        keys = model.obs_keys
        self.vector_keys = [k for k in keys if k != "pixels"]
        self.vector_extra = float(cfg.world_model.get("vector_scale", 1.0)) - 1.0
        self.prior_scale = float(cfg.world_model.get("prior_vector_scale", 0.0))
        if self.prior_scale < 0 or (self.prior_scale and not self.vector_keys):
            raise ValueError(f"algo.world_model.prior_vector_scale must be >= 0, and 0 without vector observation "
                             f"keys (this run has {self.vector_keys}), got {self.prior_scale}")
        self.decoder, self.unimix = model.decoder, float(cfg.model.unimix)
        raw = cfg.world_model.get("raw_keys", ())
        self.raw_keys = (raw,) if isinstance(raw, str) else tuple(raw)  # one key may come as a plain string
        if not set(self.raw_keys) <= set(self.vector_keys):
            raise ValueError(f"algo.world_model.raw_keys must name vector observation keys of this run "
                             f"({self.vector_keys}), got {list(self.raw_keys)}")
        symlogged = [k != "pixels" and k not in self.raw_keys for k in keys]
        self.loss = DreamerV3ModelLoss(
            world_model(model), kl_mode="separate", lambda_dynamic=cfg.world_model.kl_dynamic,
            lambda_representation=cfg.world_model.kl_representation, free_bits=cfg.world_model.free_nats,
            unimix=cfg.model.unimix, lambda_continue=cfg.world_model.continue_scale, reco_loss="l2",
            reco_symlog=symlogged, reward_two_hot=True, num_reward_bins=cfg.model.bins,
            # the vector keys' extra reconstruction term needs the graph; everything else reads the output detached
            detach_output=not (self.vector_extra or self.prior_scale))
        self.loss.set_keys(pixels=list(keys), reco_pixels=[f"reco_{k}" for k in keys])

    def forward(self, batch: TensorDictBase) -> tuple[torch.Tensor, TensorDictBase, TensorDictBase,
                                                       torch.Tensor | None]:
        losses, posterior = self.loss(batch)
        total = sum(v for k, v in losses.items() if k.startswith("loss_")).squeeze()
        vector_reco = None
        if self.prior_scale:
            total = total + self.prior_scale * prior_vector_reconstruction(posterior, self.decoder, self.vector_keys,
                                                                           self.raw_keys, self.unimix)
        if self.vector_extra:
            vector_reco = vector_reconstruction(posterior, self.vector_keys, self.raw_keys)
            total = total + self.vector_extra * vector_reco
        elif self.vector_keys:  # a metric only
            with torch.no_grad():
                vector_reco = vector_reconstruction(posterior, self.vector_keys, self.raw_keys)
        if self.vector_extra or self.prior_scale:
            posterior = posterior.detach()
        return total, losses, posterior, vector_reco


def replay_value_loss(value_loss: DreamerV3ValueLoss, posterior: TensorDictBase, imagined: TensorDictBase,
                      cfg: DictConfig) -> torch.Tensor:
    """The critic's loss on the replayed sequences themselves (DreamerV3's ``repval``, ``algo.critic.replay_scale``):
    each posterior state's λ-return from the real rewards and episode ends that follow it in the sequence,
    bootstrapped from its first imagined return, so that the critic also learns what really followed — a death
    whose penalty the reward and continue heads still miss — and not only what imagination predicts.  The states
    carry no gradient into the world model (its optimiser is separate)."""
    nxt = posterior["next"]
    replay = TensorDict({k: nxt[k].detach().float() for k in LATENT}, posterior.shape)
    replay["bootstrap"] = imagined["lambda_target"][:, 0].detach().reshape(posterior.shape)
    replay["next", "reward"] = nxt["true_reward"].float()
    replay["next", "done"], replay["next", "terminated"] = nxt["done"], nxt["terminated"]
    return value_loss.replay_value_loss(replay, horizon=1 / (1 - cfg.gamma), lmbda=cfg.lmbda)["loss_replay_value"]


def _updates_due(cfg: DictConfig, steps: int, rows: int, num_envs: int) -> int:
    """Gradient steps owed after ``steps`` env steps: ``replay_ratio`` per env step once ``learning_starts`` env
    steps are stored and every world holds a sequence."""
    start = max(cfg.learning_starts, cfg.sequence_length * num_envs)
    if steps < start or rows < cfg.sequence_length:
        return 0
    return int(cfg.replay_ratio * (steps - start)) + 1


def replay_directory(run: Run) -> Path:
    """Where a stage's memory-mapped replay buffer lives: ``replay/<stage>-<level>/`` in the run directory."""
    return run.dir / "replay" / f"{run.stage.index}-{run.stage.level}"


def make_replay(run: Run, num_envs: int, row_bytes: int) -> SequenceReplay:
    """The stage's replay buffer, on disk or in memory (``algo.buffer_on_disk``), after checking that it fits."""
    cfg = run.cfg.algo
    full = cfg.buffer_size * row_bytes
    # a stage's rows are rewritten at most every checkpoint.every env steps: a checkpoint keeps a copy of those
    guard = -(-int(run.cfg.checkpoint.every) // num_envs) + 2
    if cfg.buffer_on_disk:
        directory = replay_directory(run)
        if run.resume_state is None and directory.exists():
            shutil.rmtree(directory)  # a stage started afresh: rows left by a run killed before its first checkpoint
        directory.mkdir(parents=True, exist_ok=True)
        for stale in sorted(directory.parent.glob("*-*")):  # stages before the previous one: no checkpoint needs them
            if stale != directory and int(stale.name.split("-", 1)[0]) < run.stage.index - 1:
                shutil.rmtree(stale)
        free = shutil.disk_usage(directory).free
        if full > free:
            log.warning("replay: a full buffer (algo.buffer_size=%s, %s) needs more than the %s free on the disk of "
                        "%s; lower algo.buffer_size before it fills", f"{cfg.buffer_size:,}", _gb(full), _gb(free),
                        directory)
        return SequenceReplay(cfg.buffer_size, num_envs, cfg.sequence_length, cfg.batch_size, directory=directory,
                              device=run.device, guard_rows=guard, consume_share=cfg.get("consume_share", 0.0),
                              terminal_share=cfg.get("terminal_share", 0.0))
    free = available_memory(run.device)
    if free is not None and full > free:
        raise ValueError(f"algo.buffer_size={cfg.buffer_size:,} transitions need {_gb(full)} when full, but "
                         f"{run.device} has {_gb(free)} available: use algo.buffer_on_disk=true (memory-mapped under "
                         f"the run directory) or algo.buffer_size<={free // row_bytes:,}")
    return SequenceReplay(cfg.buffer_size, num_envs, cfg.sequence_length, cfg.batch_size, device=run.device,
                          consume_share=cfg.get("consume_share", 0.0), terminal_share=cfg.get("terminal_share", 0.0))


def train(run: Run) -> None:
    cfg = run.cfg.algo
    device = run.device
    model = make_model(cfg, run.obs_shapes).to(device)
    env = run.train_env(make_transforms(cfg, run.obs_keys, model))
    num_envs = env.batch_size.numel()
    policy = run.acting(acting_policy(model))
    keys = run.obs_keys
    if run.cfg.get("compile"):
        # the plain-torch networks the loops call many times: the RSSM in every replayed and imagined step
        compile_networks(model, (DreamerEncoder, DreamerDecoder, RSSMPriorV3, RSSMPosteriorV3, DreamerV3MLP))

    model_loss = WorldModelLoss(cfg, model)
    critic = value_model(model)
    actor_loss = DreamerV3ActorLoss(
        model.actor, critic, imagination_env(model, device), continuation_model=continuation_model(model),
        imagination_horizon=cfg.horizon, use_reinforce=True, entropy_bonus=cfg.actor.entropy,
        return_normalization=True, return_normalization_rate=1 - cfg.actor.return_decay,
        return_normalization_quantiles=tuple(cfg.actor.return_percentiles), return_normalization_min_scale=1.0)
    actor_loss.make_value_estimator(ValueEstimators.TDLambda, gamma=cfg.gamma, lmbda=cfg.lmbda)
    value_loss = DreamerV3ValueLoss(critic, value_loss="two_hot", num_value_bins=cfg.model.bins,
                                    actor_loss=actor_loss, slow_critic_regularization=cfg.critic.slow_regularizer)
    model_loss.to(device), actor_loss.to(device), value_loss.to(device)
    slow_critic = SoftUpdate(value_loss, tau=cfg.critic.tau)
    replay_scale = float(cfg.critic.get("replay_scale", 0.0))
    reward_scale = float(cfg.get("reward_scale", 1.0))

    def adam(params, section: DictConfig) -> torch.optim.Adam:
        return torch.optim.Adam(params, lr=section.lr, eps=section.eps, fused=True)  # fused: ~5x faster on CPU

    optimizers = {"world_model": adam(model.world_model_parameters(), cfg.world_model),
                  "actor": adam(model.actor.parameters(), cfg.actor),
                  "critic": adam(model.value.parameters(), cfg.critic)}
    stored = ["action", "is_init", *_next(*keys, "reward", "done", "terminated", "consumed")]
    row_bytes = transition_bytes(env, stored)
    replay = make_replay(run, num_envs, row_bytes)
    counters = Counters(updates=0)
    start = max(cfg.learning_starts, cfg.sequence_length * num_envs)  # env steps before the first gradient step
    run.planned_updates = lambda steps: _updates_due(cfg, steps, cfg.sequence_length, num_envs)

    def world_model_parameters() -> int:
        return sum(p.numel() for p in model.world_model_parameters())

    log.info("DreamerV3 size %s on %s: %s parameters (world model %s, actor %s, critic %s)", cfg.size, device,
             f"{parameter_count(model):,}", f"{world_model_parameters():,}", f"{parameter_count(model.actor):,}",
             f"{parameter_count(model.value):,}")
    log.info("replay: %s transitions (%s when full, %s each), %s", f"{cfg.buffer_size:,}",
             _gb(cfg.buffer_size * row_bytes), f"{row_bytes / 1e3:.3g} kB", replay.place)
    log.info("prefill: %s env steps of %s before the first gradient step; then %g gradient steps per env step, "
             "each on %d sequences of %d steps", f"{start:,}",
             "random actions" if cfg.prefill_random else "the untrained policy", cfg.replay_ratio, cfg.batch_size,
             cfg.sequence_length)

    def step(name: str, loss: torch.Tensor, params: list[nn.Parameter], clip: float) -> torch.Tensor:
        optimizer = optimizers[name]
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        norm = nn.utils.clip_grad_norm_(params, clip)
        optimizer.step()
        return norm

    def update() -> dict[str, torch.Tensor]:
        batch = replay.sample()
        batch["state"] = torch.zeros(*batch.shape, model.state_dim, device=device)
        batch["belief"] = torch.zeros(*batch.shape, model.belief_dim, device=device)
        with run.autocast():
            wm_loss, losses, posterior, vector_reco = model_loss(batch)
        wm_norm = step("world_model", wm_loss, model.world_model_parameters(), cfg.world_model.grad_clip)
        # behaviour learning starts from every posterior latent of the batch, without gradient into the model
        latents = TensorDict({k: posterior["next", k].reshape(-1, posterior["next", k].shape[-1]).float()
                              for k in LATENT}, [batch.numel()], device=device)
        with run.autocast():
            actor_out, imagined = actor_loss(latents)
        actor_norm = step("actor", actor_out["loss_actor"], list(model.actor.parameters()), cfg.actor.grad_clip)
        with run.autocast():
            critic_out, _ = value_loss(imagined.detach())
            critic_loss = critic_out["loss_value"]
            if replay_scale:
                replay_loss = replay_value_loss(value_loss, posterior, imagined, cfg)
                critic_loss = critic_loss + replay_scale * replay_loss
        critic_norm = step("critic", critic_loss, list(model.value.parameters()), cfg.critic.grad_clip)
        slow_critic.step()
        # tensors, not floats: run.log reads them (a host sync on a GPU) only when a log is due
        metrics = {f"model_{k.removeprefix('loss_model_')}": v.detach() for k, v in losses.items()}
        metrics |= {"model_loss": wm_loss.detach(), "model_grad_norm": wm_norm,
                    "actor_loss": actor_out["loss_actor"].detach(), "actor_entropy": actor_out["actor_entropy"],
                    "return_scale": actor_out["return_scale"], "actor_grad_norm": actor_norm,
                    "imagined_reward": imagined["next", "reward"].mean(),
                    "imagined_continuation": actor_out["continuation_mean"],
                    "critic_loss": critic_loss.detach(), "critic_grad_norm": critic_norm,
                    "imagined_return": imagined["lambda_target"].mean()}
        if replay_scale:
            metrics["critic_replay_loss"] = replay_loss.detach()
        if vector_reco is not None:
            metrics["model_reco_vector"] = vector_reco.detach()
        if "interoception" in keys:  # how well the latent knows the EVs the reward is computed from (raw units)
            metrics["interoception_error"] = (posterior["next", "reco_interoception"].detach().float()
                                              - posterior["next", "interoception"].float()).abs().mean()
        if run.log_due:
            metrics |= diagnostics(model, critic, posterior, imagined, actor_out["return_scale"])
        return metrics

    td = run.start(model, {**{f"optimizer_{k}": v for k, v in optimizers.items()}, "value_loss": value_loss,
                           "return_norm": actor_loss.retnorm, "replay": replay, "counters": counters})
    run.updates = counters["updates"]  # a resumed run's bar counts on from its checkpoint
    first_update = counters["updates"] == 0
    # a gradient step of size S takes a minute on a CPU: a Ctrl-C stops between two of them (Run.stop_now), and the
    # resume of such a checkpoint first makes the gradient steps its iteration still owed, as the whole run did
    run.stops_between_updates = True
    owed = counters["updates"] < _updates_due(cfg, run.steps, replay.rows, num_envs)
    while not run.done or owed:
        if not owed:
            transition, td = run.step(prefill_policy if cfg.prefill_random and run.steps < start else policy, td)
            transition["next", "consumed"] = consumed(transition)
            stored_td = transition.select(*stored)
            if reward_scale != 1.0:  # the world model learns the scaled reward; the episodes' returns stay the env's
                stored_td["next", "reward"] = stored_td["next", "reward"] * reward_scale
            replay.extend(stored_td)
        owed = False
        metrics = None
        due = _updates_due(cfg, run.steps, replay.rows, num_envs)
        run.set_phase("prefill" if due == 0 else None)
        while counters["updates"] < due:
            if run.stop_requested():
                run.stop_now(td)
            began = time.perf_counter()
            metrics = update()
            counters["updates"] += 1
            seconds = time.perf_counter() - began
            run.updated(1, seconds, counters["updates"], counters["updates"] / max(run.steps - start + 1, 1))
            if first_update:
                first_update = False
                log.info("first gradient step at env step %s: %.3g s (%.0f s after the stage began)",
                         f"{run.steps:,}", seconds, time.perf_counter() - run._session[0])
            if cfg.openloop.every and counters["updates"] % cfg.openloop.every == 0:
                save_openloop(model, replay, cfg, run.dir / "openloop" /
                              f"openloop-{run.stage.index}-{run.stage.level}-{run.steps:09d}.png")
        if metrics is not None:
            run.log(metrics | {"updates": counters["updates"], "replay_steps": len(replay.buffer)})
        run.end_iteration(td)
