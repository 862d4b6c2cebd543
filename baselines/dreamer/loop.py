"""DreamerV3's training loop, :func:`train`: one env step in every world, then as many gradient steps as the replay
ratio owes, each one world-model step (``DreamerV3ModelLoss``: KL balancing with free nats and unimix,
reconstruction, reward, continue), one actor step (``DreamerV3ActorLoss``: REINFORCE in imagination, returns
normalised by their 5–95 % percentile range) and one critic step (``DreamerV3ValueLoss``: two-hot, with a slow
critic updated by ``SoftUpdate``); the gradient step is :meth:`.update.Learner.update`.

The networks, losses and optimisers live on ``device`` (``run.device``); the replay buffer on disk or on that device
(:mod:`.replay`).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

from omegaconf import DictConfig
from tensordict import TensorDictBase
from torchrl.modules import DreamerV3MLP, RSSMPosteriorV3, RSSMPriorV3

from ..logs import Counters
from ..nets import compile_networks
from ..run import Run, parameter_count
from .model import (
    DreamerDecoder,
    DreamerEncoder,
    DreamerModel,
    acting_policy,
    make_model,
    make_policy,
    make_transforms,
    next_keys,
    prefill_policy,
)
from .openloop import save_openloop
from .replay import SequenceReplay, consumed, gb_text, make_replay, transition_bytes
from .update import Learner, update_options

# the package's logger, not the module's: a run's train.log names DreamerV3's lines as before the package split
log = logging.getLogger(__package__)


def _updates_due(cfg: DictConfig, steps: int, rows: int, num_envs: int) -> int:
    """Gradient steps owed after ``steps`` env steps: ``replay_ratio`` per env step once ``learning_starts`` env
    steps are stored and every world holds a sequence."""
    start = max(cfg.learning_starts, cfg.sequence_length * num_envs)
    if steps < start or rows < cfg.sequence_length:
        return 0
    return int(cfg.replay_ratio * (steps - start)) + 1


def _log_sizes(
    cfg: DictConfig, model: DreamerModel, replay: SequenceReplay, row_bytes: int, start: int, device
) -> None:
    """The first lines of a stage: the size and parameter counts, the replay, the prefill."""
    log.info(
        "DreamerV3 size %s on %s: %s parameters (world model %s, actor %s, critic %s)",
        cfg.size,
        device,
        f"{parameter_count(model):,}",
        f"{sum(p.numel() for p in model.world_model_parameters()):,}",
        f"{parameter_count(model.actor):,}",
        f"{parameter_count(model.value):,}",
    )
    log.info(
        "replay: %s transitions (%s when full, %s each), %s",
        f"{cfg.buffer_size:,}",
        gb_text(cfg.buffer_size * row_bytes),
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


@dataclass
class _Stage:
    """What the loop of one stage keeps between its iterations."""

    run: Run
    cfg: DictConfig
    model: DreamerModel
    learner: Learner
    replay: SequenceReplay
    counters: Counters
    options: dict[str, bool]
    stored: list
    start: int  # env steps before the first gradient step
    first_update: bool

    def store(self, transition: TensorDictBase) -> None:
        """One env step's transition into the replay (the reward scaled by ``reward_scale``)."""
        transition["next", "consumed"] = consumed(transition)
        stored_td = transition.select(*self.stored)
        reward_scale = float(self.cfg.get("reward_scale", 1.0))
        if reward_scale != 1.0:  # the world model learns the scaled reward; the episodes' returns stay the env's
            stored_td["next", "reward"] = stored_td["next", "reward"] * reward_scale
        with self.run.timed("replay"):
            self.replay.extend(stored_td)

    def gradient_steps(self, due: int, td: TensorDictBase) -> dict | None:
        """Gradient steps until ``due`` are made (a stop request checkpoints between two); the last one's metrics."""
        run, counters, replay = self.run, self.counters, self.replay
        metrics = None
        while counters["updates"] < due:
            if run.stop_requested():
                run.stop_now(td)
            began = time.perf_counter()
            with run.timed("replay"):
                sample = replay.sample()
            metrics = self.learner.update(sample)
            if self.options["prefetch"] and counters["updates"] + 1 < due:
                with run.timed("replay"):
                    replay.prefetch()  # the next batch, drawn and sent while the device works on this gradient step
            if run.log_due:  # read on the host, so only when a log is due, after the gradient step
                metrics |= self.learner.diagnostics()
            counters["updates"] += 1
            seconds = time.perf_counter() - began
            run.updated(1, seconds, counters["updates"], counters["updates"] / max(run.steps - self.start + 1, 1))
            self._after_step(seconds)
        return metrics

    def _after_step(self, seconds: float) -> None:
        run, cfg, updates = self.run, self.cfg, self.counters["updates"]
        if self.first_update:
            self.first_update = False
            log.info(
                "first gradient step at env step %s: %.3g s (%.0f s after the stage began)",
                f"{run.steps:,}",
                seconds,
                run.session_seconds(),
            )
        if cfg.openloop.every and updates % cfg.openloop.every == 0:
            save_openloop(
                self.model,
                self.replay,
                cfg,
                run.dir / "openloop" / f"openloop-{run.stage.index}-{run.stage.level}-{run.steps:09d}.png",
            )


def train(run: Run) -> None:
    """One stage of DreamerV3 training: builds the model, losses, optimisers and replay, then drives ``run`` until
    ``run.done``; :meth:`.update.Learner.update` is one gradient step."""
    cfg = run.cfg.algo
    device = run.device
    model = make_model(cfg, run.obs_shapes).to(device)
    env = run.train_env(make_transforms(cfg, run.obs_keys, model))
    num_envs = env.batch_size.numel()
    policy = run.acting(acting_policy(model))
    keys = run.obs_keys
    if run.cfg.get("compile"):
        # the plain-torch networks the loops call many times: the RSSM in every imagined and acting step
        compile_networks(model, (DreamerEncoder, DreamerDecoder, RSSMPriorV3, RSSMPosteriorV3, DreamerV3MLP))

    options = update_options(cfg, device)
    learner = Learner(cfg, model, device, bf16=run.cfg.get("bf16", False), options=options, timed=run.timed)
    if run.cfg.get("compile") and not options["compile"]:
        # the replayed RSSM loop calls the prior's and posterior's methods, not the compiled modules: its step
        learner.compile_replay_step()

    stored = ["action", "is_init", *next_keys(*keys, "reward", "done", "terminated", "consumed")]
    row_bytes = transition_bytes(env, stored)
    replay = make_replay(run, num_envs, row_bytes)
    if options["prefetch"]:
        replay.use_own_generator(int(run.cfg.seed) * 1_000 + run.stage.index)
    counters = Counters(updates=0)
    start = max(cfg.learning_starts, cfg.sequence_length * num_envs)  # env steps before the first gradient step
    _log_sizes(cfg, model, replay, row_bytes, start, device)

    td = run.start(
        model,
        {**learner.components(), "replay": replay, "counters": counters},
        make_policy(model),
        make_transforms(cfg, run.obs_keys, model),
        planned_updates=lambda steps: _updates_due(cfg, steps, cfg.sequence_length, num_envs),
    )
    run.updates = counters["updates"]  # a resumed run's bar counts on from its checkpoint
    stage = _Stage(run, cfg, model, learner, replay, counters, options, stored, start, counters["updates"] == 0)
    # a gradient step of size S takes a minute on a CPU: a Ctrl-C stops between two of them (Run.stop_now), and the
    # resume of such a checkpoint first makes the gradient steps its iteration still owed, as the whole run did
    run.stops_between_updates = True
    owed = counters["updates"] < _updates_due(cfg, run.steps, replay.rows, num_envs)
    while not run.done or owed:
        if not owed:
            transition, td = run.step(prefill_policy if cfg.prefill_random and run.steps < start else policy, td)
            stage.store(transition)
        owed = False
        due = _updates_due(cfg, run.steps, replay.rows, num_envs)
        run.set_phase("prefill" if due == 0 else None)
        metrics = stage.gradient_steps(due, td)
        if metrics is not None:
            run.log(metrics | {"updates": counters["updates"], "replay_steps": len(replay.buffer)})
        run.end_iteration(td)
    if counters["updates"] == 0:  # a time budget ended the stage within its prefill (a step budget is refused)
        log.warning(
            "%s on %s ended after %s env steps, before its first gradient step (at %s): its final model is the "
            "untrained network; give the stage more time or lower algo.learning_starts",
            cfg.name,
            run.stage.level,
            f"{run.steps:,}",
            f"{start:,}",
        )
