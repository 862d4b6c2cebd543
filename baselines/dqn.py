"""DQN on TorchRL, as the paper's custom DQN baseline (SPEC §12; hyperparameters in conf/algo/dqn.yaml).

Reads top to bottom: the Q-network (multimodal encoder over 2 stacked frames of every observation key, then an MLP
to one Q-value per action, as torchrl's ``QValueActor``), the frame-stack transform, then :func:`train`:
epsilon-greedy collection (``EGreedyModule``), a uniform replay buffer (``ReplayBuffer`` + ``LazyTensorStorage``),
``DQNLoss`` (Huber) with a target network copied every ``target_update_every`` updates (``HardUpdate``), Adam with
gradients clamped element-wise, and the loop: one env step in every world, then ``updates_per_step`` updates.

The networks, the target network, the optimiser and the replay buffer live on ``device`` (``run.device``); the
sampled batches are drawn there.  The replay buffer is part of the checkpoint (exact resume); a full
50,000-transition buffer of stacked 64×64 frames is about 2.5 GB on disk.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence

import torch
from omegaconf import DictConfig
from tensordict.nn import TensorDictModule, TensorDictModuleBase, TensorDictSequential
from torch import nn
from torchrl.data import Categorical, LazyTensorStorage, ReplayBuffer
from torchrl.envs import CatFrames, Transform
from torchrl.modules import EGreedyModule, QValueActor
from torchrl.objectives import DQNLoss, HardUpdate

from evaaa import ACTION_NAMES

from .logs import Counters
from .nets import MultimodalEncoder, compile_networks, head, stacked_shapes
from .run import Run

#: Q-values are no distribution to sample from: asked to sample, the policy still acts greedily, and evaluations
#: say so (``mode``)
SAMPLES_ACTIONS = False


# ------------------------------------------------------------------------------------------------ networks
def make_model(cfg: DictConfig, obs_shapes: Mapping[str, Sequence[int]]) -> QValueActor:
    """Observations -> ``"action_value"`` (one Q-value per action) -> greedy ``"action"``."""
    keys = list(obs_shapes)
    encoder = MultimodalEncoder(
        stacked_shapes(obs_shapes, keys, cfg.frame_stack),
        cfg.encoder.cnn,
        cfg.encoder.mlp,
        cfg.encoder.get("mlp_default"),
    )
    q_values = TensorDictSequential(
        TensorDictModule(encoder, in_keys=keys, out_keys=["embed"]),
        TensorDictModule(
            head(encoder.out_features, cfg.head.units, len(ACTION_NAMES), cfg.head.layer_norm),
            in_keys=["embed"],
            out_keys=["action_value"],
        ),
    )
    return QValueActor(q_values, spec=Categorical(len(ACTION_NAMES)))


def make_transforms(cfg: DictConfig, obs_keys: Sequence[str], model: nn.Module) -> list[Transform]:
    """``frame_stack`` frames of every observation key, stacked on the last axis."""
    return [CatFrames(N=cfg.frame_stack, dim=-1, in_keys=list(obs_keys))]


def make_policy(model: QValueActor) -> TensorDictModuleBase:
    """The greedy policy (exploration is added during training only)."""
    return model


# ------------------------------------------------------------------------------------------------ training
def train(run: Run) -> None:
    cfg = run.cfg.algo
    model = make_model(cfg, run.obs_shapes).to(run.device)
    if run.cfg.get("compile"):
        compile_networks(model)
    env = run.train_env(make_transforms(cfg, run.obs_keys, model))
    explore = EGreedyModule(
        env.action_spec, eps_init=cfg.eps_start, eps_end=cfg.eps_end, annealing_num_steps=cfg.eps_anneal_updates
    ).to(run.device)
    policy = run.acting(TensorDictSequential(model, explore))

    # what a transition keeps: stacked observations before and after, the action and the outcome
    stored = [*run.obs_keys, "action", *(("next", k) for k in (*run.obs_keys, "reward", "done", "terminated"))]
    buffer = ReplayBuffer(storage=LazyTensorStorage(cfg.buffer_size, device=run.device), batch_size=cfg.batch_size)

    loss_fn = DQNLoss(model, loss_function=cfg.loss, delay_value=True, action_space=env.action_spec).to(run.device)
    loss_fn.make_value_estimator(gamma=cfg.gamma)
    # HardUpdate copies on every step() when its interval is 0; the loop calls it every target_update_every updates
    # (its own counter would copy every interval + 1 calls and is not part of its state_dict)
    target_update = HardUpdate(loss_fn, value_network_update_interval=0)
    optimizer = torch.optim.Adam(loss_fn.parameters(), lr=cfg.lr, fused=True)  # fused: ~5x faster step on CPU
    counters = Counters(updates=0)
    num_envs = env.batch_size.numel()
    first = -(-cfg.learning_starts // num_envs)  # the first env step (of all worlds) followed by updates
    td = run.start(
        model,
        {"loss": loss_fn, "optimizer": optimizer, "explore": explore, "buffer": buffer, "counters": counters},
        make_policy(model),
        make_transforms(cfg, run.obs_keys, model),
        planned_updates=lambda steps: max(0, steps // num_envs - first + 1) * cfg.updates_per_step,
    )
    run.updates = counters["updates"]  # a resumed run's bar counts on from its checkpoint
    storage = buffer.storage
    if storage.initialized and storage._storage.device != run.device:  # restored rows arrive on the CPU
        storage._storage = storage._storage.to(run.device)
    while not run.done:
        transition, td = run.step(policy, td)
        with run.timed("replay"):
            buffer.extend(transition.select(*stored))
        if len(buffer) < cfg.learning_starts:
            run.set_phase("prefill")
            run.end_iteration(td)
            continue
        run.set_phase(None)
        began = time.perf_counter()
        for _ in range(cfg.updates_per_step):
            with run.timed("replay"):
                sample = buffer.sample()
            with run.timed("forward"), run.autocast():
                losses = loss_fn(sample)
            with run.timed("backward"):
                optimizer.zero_grad(set_to_none=True)
                losses["loss"].backward()
            with run.timed("optimizer"):
                nn.utils.clip_grad_value_(loss_fn.parameters(), cfg.grad_clip_value)
                optimizer.step()
                explore.step()
                counters["updates"] += 1
                if counters["updates"] % cfg.target_update_every == 0:
                    target_update.step()
        run.updated(cfg.updates_per_step, time.perf_counter() - began, counters["updates"])
        # tensors: run.log reads them (a host sync on a GPU) only when a log is due
        run.log({"loss": losses["loss"].detach(), "epsilon": explore.eps, "updates": counters["updates"]})
        run.end_iteration(td)
