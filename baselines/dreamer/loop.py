"""DreamerV3's training loop, :func:`train`: one env step in every world, then as many gradient steps as the replay
ratio owes, each one world-model step (``DreamerV3ModelLoss``: KL balancing with free nats and unimix,
reconstruction, reward, continue), one actor step (``DreamerV3ActorLoss``: REINFORCE in imagination, returns
normalised by their 5–95 % percentile range) and one critic step (``DreamerV3ValueLoss``: two-hot, with a slow
critic updated by ``SoftUpdate``); the gradient step is ``update`` inside :func:`train`.

The networks, losses and optimisers live on ``device`` (``run.device``); the replay buffer on disk or on that device
(:mod:`.replay`).
"""

from __future__ import annotations

import logging
import time

import torch
from omegaconf import DictConfig
from tensordict import TensorDict
from torch import nn
from torchrl.modules import DreamerV3MLP, RSSMPosteriorV3, RSSMPriorV3
from torchrl.objectives import DreamerV3ActorLoss, DreamerV3ValueLoss, SoftUpdate
from torchrl.objectives.utils import ValueEstimators

from ..nets import compile_networks
from ..run import Counters, Run, parameter_count
from .losses import WorldModelLoss, diagnostics, replay_value_loss
from .model import (
    LATENT,
    DreamerDecoder,
    DreamerEncoder,
    _next,
    acting_policy,
    continuation_model,
    imagination_env,
    make_model,
    make_transforms,
    prefill_policy,
    value_model,
)
from .openloop import save_openloop
from .replay import _gb, consumed, make_replay, transition_bytes

# the package's logger, not the module's: a run's train.log names DreamerV3's lines as before the package split
log = logging.getLogger(__package__)


def _updates_due(cfg: DictConfig, steps: int, rows: int, num_envs: int) -> int:
    """Gradient steps owed after ``steps`` env steps: ``replay_ratio`` per env step once ``learning_starts`` env
    steps are stored and every world holds a sequence."""
    start = max(cfg.learning_starts, cfg.sequence_length * num_envs)
    if steps < start or rows < cfg.sequence_length:
        return 0
    return int(cfg.replay_ratio * (steps - start)) + 1


def train(run: Run) -> None:
    """One stage of DreamerV3 training: builds the model, losses, optimisers and replay, then drives ``run`` until
    ``run.done``; ``update`` below is one gradient step."""
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
        model.actor,
        critic,
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
    actor_loss.make_value_estimator(ValueEstimators.TDLambda, gamma=cfg.gamma, lmbda=cfg.lmbda)
    value_loss = DreamerV3ValueLoss(
        critic,
        value_loss="two_hot",
        num_value_bins=cfg.model.bins,
        actor_loss=actor_loss,
        slow_critic_regularization=cfg.critic.slow_regularizer,
    )
    model_loss.to(device), actor_loss.to(device), value_loss.to(device)
    slow_critic = SoftUpdate(value_loss, tau=cfg.critic.tau)
    replay_scale = float(cfg.critic.get("replay_scale", 0.0))
    reward_scale = float(cfg.get("reward_scale", 1.0))

    def adam(params, section: DictConfig) -> torch.optim.Adam:
        return torch.optim.Adam(params, lr=section.lr, eps=section.eps, fused=True)  # fused: ~5x faster on CPU

    optimizers = {
        "world_model": adam(model.world_model_parameters(), cfg.world_model),
        "actor": adam(model.actor.parameters(), cfg.actor),
        "critic": adam(model.value.parameters(), cfg.critic),
    }
    stored = ["action", "is_init", *_next(*keys, "reward", "done", "terminated", "consumed")]
    row_bytes = transition_bytes(env, stored)
    replay = make_replay(run, num_envs, row_bytes)
    counters = Counters(updates=0)
    start = max(cfg.learning_starts, cfg.sequence_length * num_envs)  # env steps before the first gradient step
    run.planned_updates = lambda steps: _updates_due(cfg, steps, cfg.sequence_length, num_envs)

    def world_model_parameters() -> int:
        return sum(p.numel() for p in model.world_model_parameters())

    log.info(
        "DreamerV3 size %s on %s: %s parameters (world model %s, actor %s, critic %s)",
        cfg.size,
        device,
        f"{parameter_count(model):,}",
        f"{world_model_parameters():,}",
        f"{parameter_count(model.actor):,}",
        f"{parameter_count(model.value):,}",
    )
    log.info(
        "replay: %s transitions (%s when full, %s each), %s",
        f"{cfg.buffer_size:,}",
        _gb(cfg.buffer_size * row_bytes),
        f"{row_bytes / 1e3:.3g} kB",
        replay.place,
    )
    log.info(
        "prefill: %s env steps of %s before the first gradient step; then %g gradient steps per env step, "
        "each on %d sequences of %d steps",
        f"{start:,}",
        "random actions" if cfg.prefill_random else "the untrained policy",
        cfg.replay_ratio,
        cfg.batch_size,
        cfg.sequence_length,
    )

    def step(name: str, loss: torch.Tensor, params: list[nn.Parameter], clip: float) -> torch.Tensor:
        optimizer = optimizers[name]
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        norm = nn.utils.clip_grad_norm_(params, clip)
        optimizer.step()
        return norm

    def update() -> dict[str, torch.Tensor]:
        """One gradient step on a replayed batch: the world model, then the actor in imagination from the
        batch's posterior latents, then the critic, each with its own optimiser and clipping; then the slow
        critic."""
        batch = replay.sample()
        batch["state"] = torch.zeros(*batch.shape, model.state_dim, device=device)
        batch["belief"] = torch.zeros(*batch.shape, model.belief_dim, device=device)
        with run.autocast():
            wm_loss, losses, posterior, vector_reco = model_loss(batch)
        wm_norm = step("world_model", wm_loss, model.world_model_parameters(), cfg.world_model.grad_clip)
        # behaviour learning starts from every posterior latent of the batch, without gradient into the model
        latents = TensorDict(
            {k: posterior["next", k].reshape(-1, posterior["next", k].shape[-1]).float() for k in LATENT},
            [batch.numel()],
            device=device,
        )
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
        if "interoception" in keys:  # how well the latent knows the EVs the reward is computed from (raw units)
            metrics["interoception_error"] = (
                (posterior["next", "reco_interoception"].detach().float() - posterior["next", "interoception"].float())
                .abs()
                .mean()
            )
        if run.log_due:
            metrics |= diagnostics(model, critic, posterior, imagined, actor_out["return_scale"])
        return metrics

    td = run.start(
        model,
        {
            **{f"optimizer_{k}": v for k, v in optimizers.items()},
            "value_loss": value_loss,
            "return_norm": actor_loss.retnorm,
            "replay": replay,
            "counters": counters,
        },
    )
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
                log.info(
                    "first gradient step at env step %s: %.3g s (%.0f s after the stage began)",
                    f"{run.steps:,}",
                    seconds,
                    run.session_seconds(),
                )
            if cfg.openloop.every and counters["updates"] % cfg.openloop.every == 0:
                save_openloop(
                    model,
                    replay,
                    cfg,
                    run.dir / "openloop" / f"openloop-{run.stage.index}-{run.stage.level}-{run.steps:09d}.png",
                )
        if metrics is not None:
            run.log(metrics | {"updates": counters["updates"], "replay_steps": len(replay.buffer)})
        run.end_iteration(td)
