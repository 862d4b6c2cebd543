"""PPO and PPO+LSTM on TorchRL, as the paper's sheeprl baselines (SPEC §12; hyperparameters in conf/algo/ppo*.yaml).

Reads top to bottom: the networks (a shared trunk — multimodal encoder, and with ``algo.lstm`` an ``LSTMModule`` —
under an actor head and a critic head, as torchrl's ``ActorValueOperator``), the env transforms they need (4 stacked
pixel frames; for the LSTM ``InitTracker`` and the LSTM's tensordict primer), then :func:`train`: collection
(``frames_per_batch`` transitions split over the worlds), GAE, ``ClipPPOLoss``, Adam/AdamW with linear annealing of
learning rate and clip, and the loop.

The networks, the loss and the optimiser live on ``device`` (``run.device``): each collected batch goes there once,
for GAE and every epoch of minibatches.

The recurrent variant trains on sequences of ``sequence_length`` steps cut from each world's rollout; each sequence
starts from the LSTM state stored when it was collected, and the state is reset where an episode starts
(``is_init``), so no state leaks across episodes.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import torch
from gymnasium.wrappers.utils import RunningMeanStd
from omegaconf import DictConfig
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictModuleBase, TensorDictSequential
from torch import nn
from torchrl.data import Categorical
from torchrl.envs import CatFrames, InitTracker, Transform
from torchrl.modules import ActorValueOperator, LSTMModule, ProbabilisticActor, ValueOperator, set_recurrent_mode
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from evaaa import ACTION_NAMES

from .devices import to_device
from .nets import MultimodalEncoder, compile_networks, head, stacked_shapes
from .run import Run

LOSS_TERMS = ("loss_objective", "loss_critic", "loss_entropy")
LOGGED = ("entropy", "kl_approx", "clip_fraction")  # the loss's diagnostics worth a curve


# ------------------------------------------------------------------------------------------------ networks
def make_model(cfg: DictConfig, obs_shapes: Mapping[str, Sequence[int]]) -> ActorValueOperator:
    """Trunk (encoder [+ LSTM]) -> ``"hidden"``; actor head -> ``"logits"`` -> action; critic head -> value."""
    keys = list(obs_shapes)
    encoder = MultimodalEncoder(
        stacked_shapes(obs_shapes, ["pixels"], cfg.frame_stack),
        cfg.encoder.cnn,
        cfg.encoder.mlp,
        cfg.encoder.get("mlp_default"),
    )
    features = encoder.out_features
    if cfg.lstm:
        trunk = TensorDictSequential(
            TensorDictModule(encoder, in_keys=keys, out_keys=["embed"]),
            LSTMModule(input_size=features, hidden_size=cfg.lstm.hidden, in_key="embed", out_key="hidden"),
        )
        features = cfg.lstm.hidden
    else:
        trunk = TensorDictModule(encoder, in_keys=keys, out_keys=["hidden"])
    actor = ProbabilisticActor(
        TensorDictModule(
            head(features, cfg.head.units, len(ACTION_NAMES), cfg.head.layer_norm),
            in_keys=["hidden"],
            out_keys=["logits"],
        ),
        in_keys=["logits"],
        spec=Categorical(len(ACTION_NAMES)),
        distribution_class=torch.distributions.Categorical,
        return_log_prob=True,
    )
    critic = ValueOperator(head(features, cfg.head.units, 1, cfg.head.layer_norm), in_keys=["hidden"])
    return ActorValueOperator(trunk, actor, critic)


def _lstm(model: nn.Module) -> LSTMModule | None:
    return next((m for m in model.modules() if isinstance(m, LSTMModule)), None)


def make_transforms(cfg: DictConfig, obs_keys: Sequence[str], model: nn.Module) -> list[Transform]:
    """Stacked pixel frames; for the LSTM, episode-start flags and zeroed LSTM state at every reset."""
    transforms: list[Transform] = []
    if "pixels" in obs_keys and cfg.frame_stack > 1:  # one frame needs no stacking (and its copy each step)
        transforms.append(CatFrames(N=cfg.frame_stack, dim=-1, in_keys=["pixels"]))
    lstm = _lstm(model)
    if lstm is not None:
        transforms += [InitTracker(), lstm.make_tensordict_primer()]
    return transforms


def make_policy(model: ActorValueOperator) -> TensorDictModuleBase:
    """Observations -> ``"action"`` (sampled, or the distribution's mode under a deterministic exploration type)."""
    return model.get_policy_operator()


def _minibatches(batch: TensorDictBase, cfg: DictConfig) -> Iterator[TensorDictBase]:
    """One epoch of shuffled minibatches: transitions, or (LSTM) whole sequences of ``sequence_length`` steps."""
    if cfg.lstm:
        worlds, steps = batch.shape
        units = batch.reshape(worlds, steps // cfg.sequence_length, cfg.sequence_length).flatten(0, 1)
    else:
        units = batch.reshape(-1)
    # drawn on the CPU on every device (the same minibatches everywhere), sent to the batch's device once per epoch
    order = torch.randperm(units.shape[0])
    if units.device is not None and units.device.type == "cuda":
        order = order.to(units.device, non_blocking=True)
    for index in order.chunk(cfg.num_minibatches):
        yield units[index]


def make_advantage(cfg: DictConfig, model: ActorValueOperator) -> Callable[[TensorDictBase], None]:
    """GAE over a ``[worlds, steps]`` batch, in place: ``"advantage"`` and ``"value_target"`` (and the critic's
    ``"state_value"``).

    GAE runs the whole critic: trunk and head, for the LSTM over each world's rollout from the stored state, and
    without vmap, which has no batching rule for the LSTM.  Without the LSTM the critic runs once over each world's
    steps and its last next observation (torchrl's ``shifted``), not twice over the steps and their next
    observations: the next observation of step t is the observation of step t + 1 except where an episode ended; a
    termination needs no next value and the true next observation is inserted after a truncation (budget 2: one
    truncation and the rollout's end; a rollout with more truncations in one world is computed the long way).
    """
    recurrent = bool(cfg.lstm)
    estimators = [
        GAE(
            gamma=cfg.gamma,
            lmbda=cfg.gae_lambda,
            value_network=model.get_value_operator(),
            average_gae=False,
            deactivate_vmap=True,
            shifted=shifted,
            shifted_budget=2,
        )
        for shifted in ([True, False] if not recurrent else [False])
    ]

    def advantage(batch: TensorDictBase) -> None:
        batch = batch.refine_names(..., "time")
        estimators[0](batch)
        valid = batch.pop("shifted_valid", None)
        if valid is not None and not valid.all():
            estimators[-1](batch)
        batch.names = None

    return advantage


class ReturnScale:
    """Rewards divided by the running standard deviation of the discounted return, as gymnasium's
    ``NormalizeReward`` wrapper and CleanRL's PPO do (``algo.normalize_reward``).

    The paper's reward (-0.01 x the squared drive per step, -100 at an episode's end) gives returns in the hundreds:
    the critic's squared error then dwarfs the policy's loss in the shared trunk and the gradient clip
    (``max_grad_norm``) scales the policy's share down to almost nothing.  Dividing by the return's scale keeps the
    value targets of order one; the relative size of rewards, hence the optimal policy, is unchanged.  Each world's
    discounted return is accumulated step by step (reset when its episode ends) and the mean and variance of all of
    them is kept by gymnasium's ``RunningMeanStd``; each step's reward is divided by the scale known at that step.
    """

    def __init__(self, num_envs: int, gamma: float, epsilon: float = 1e-8):
        self.gamma, self.epsilon = gamma, epsilon
        self.returns = np.zeros(num_envs)
        self.rms = RunningMeanStd()

    @property
    def scale(self) -> float:
        return float(np.sqrt(self.rms.var + self.epsilon))

    def __call__(self, batch: TensorDictBase) -> TensorDictBase:
        """Rescales ``("next", "reward")`` of a ``[worlds, steps]`` batch in place; returns the batch."""
        reward = batch["next", "reward"]
        raw = reward.squeeze(-1).double().cpu().numpy()
        done = batch["next", "done"].squeeze(-1).cpu().numpy()
        scaled = np.empty_like(raw)
        for t in range(raw.shape[1]):
            self.returns = self.returns * self.gamma + raw[:, t]
            self.rms.update(self.returns)
            scaled[:, t] = raw[:, t] / self.scale
            self.returns[done[:, t]] = 0.0
        batch["next", "reward"] = torch.as_tensor(scaled, dtype=reward.dtype, device=reward.device).unsqueeze(-1)
        return batch

    def state_dict(self) -> dict:
        return {
            "returns": torch.as_tensor(self.returns),
            "mean": float(self.rms.mean),
            "var": float(self.rms.var),
            "count": float(self.rms.count),
        }

    def load_state_dict(self, state: Mapping) -> None:
        self.returns = state["returns"].double().numpy().copy()
        self.rms.mean, self.rms.var, self.rms.count = (np.float64(state[k]) for k in ("mean", "var", "count"))


# ------------------------------------------------------------------------------------------------ training
def check_config(cfg: DictConfig) -> str | None:
    """Why ``cfg`` (the whole training config) cannot train PPO, in one line; None when it can.  ``train.py`` asks
    before it writes anything."""
    algo, num_envs = cfg.algo, cfg.env.num_envs
    if algo.frames_per_batch % num_envs:
        return (
            f"algo.frames_per_batch={algo.frames_per_batch}: expected a multiple of env.num_envs ({num_envs}): "
            f"each world takes the same number of steps per update"
        )
    rollout = algo.frames_per_batch // num_envs
    if algo.lstm and rollout % algo.sequence_length:
        return (
            f"algo.sequence_length={algo.sequence_length}: each world's rollout ({rollout} steps = "
            f"algo.frames_per_batch / env.num_envs) must be a multiple of it"
        )
    if algo.frames_per_batch < algo.num_minibatches:
        return (
            f"algo.num_minibatches={algo.num_minibatches}: more minibatches than transitions per update "
            f"(algo.frames_per_batch={algo.frames_per_batch})"
        )
    return None


@dataclass
class _Update:
    """PPO's update of one iteration's batch: the advantage, then ``epochs`` passes of minibatch gradient steps."""

    cfg: DictConfig
    run: Run
    model: nn.Module
    advantage: Callable[[TensorDictBase], TensorDictBase]
    loss_fn: ClipPPOLoss
    optimizer: torch.optim.Optimizer
    scheduler: torch.optim.lr_scheduler.LRScheduler
    return_scale: ReturnScale | None
    remaining: Callable[[int], float]  # 1 -> 0 over the stage's iterations: the annealing factor

    def anneal_clip(self) -> None:
        """The clip range at this point of the stage (``anneal_clip``)."""
        cfg = self.cfg
        if cfg.anneal_clip:
            clip = cfg.clip * self.remaining(self.run.steps // cfg.frames_per_batch)
            self.loss_fn.clip_epsilon.fill_(clip)
            if cfg.clip_value_loss:
                self.loss_fn.clip_value.fill_(clip)

    def with_advantage(self, batch: TensorDictBase) -> TensorDictBase:
        """The batch on the device with its advantage and value target, without the next step."""
        run = self.run
        with run.timed("advantage"):
            if self.return_scale is not None:
                self.return_scale(batch)  # the episodes' logged returns stay the env's own
            batch = to_device(batch, run.device)  # on a GPU through pinned memory, without blocking the host
            with torch.no_grad(), set_recurrent_mode(bool(self.cfg.lstm)), run.autocast():
                self.advantage(batch)
            # the loss reads the advantage, not the next step: the minibatches copy half the frames without it
            return batch.exclude("next")

    def epochs(self, batch: TensorDictBase, began: float) -> dict[str, torch.Tensor | float]:
        """The gradient steps on ``batch`` (``began``: when the iteration's update started, for the first step's
        time); returns the iteration's metrics."""
        cfg, run = self.cfg, self.run
        # summed on the device: read (one host sync) when logged
        totals: dict[str, torch.Tensor] = {}
        updates = 0
        for _ in range(cfg.epochs):
            with run.timed("replay"):
                minibatches = list(_minibatches(batch, cfg))
            for minibatch in minibatches:
                stats = self._gradient_step(minibatch)
                updates += 1
                for key, value in stats.items():
                    totals[key] = totals.get(key, 0.0) + value.detach().float()
                # each gradient step reported as it ends (the first with the advantage's time): the bar moves, and
                # the run's time estimate comes with the first one instead of after the iteration's last
                now = time.perf_counter()
                run.updated(1, now - began, run.updates + 1)
                began = now
        self.scheduler.step()
        done_updates = -(-run.steps // cfg.frames_per_batch) * updates  # every iteration makes as many
        return {
            **{k: v / updates for k, v in totals.items()},
            "lr": self.optimizer.param_groups[0]["lr"],
            "clip": self.loss_fn.clip_epsilon,
            "updates": done_updates,
            **({"reward_scale": self.return_scale.scale} if self.return_scale else {}),
        }

    def _gradient_step(self, minibatch: TensorDictBase) -> dict[str, torch.Tensor]:
        run = self.run
        with run.timed("forward"), set_recurrent_mode(bool(self.cfg.lstm)), run.autocast():
            losses = self.loss_fn(minibatch)
            loss = sum(losses[k] for k in LOSS_TERMS)
        with run.timed("backward"):
            self.optimizer.zero_grad(set_to_none=True)
            loss.backward()
        with run.timed("optimizer"):
            grad_norm = nn.utils.clip_grad_norm_(self.model.parameters(), self.cfg.max_grad_norm)
            self.optimizer.step()
        return {k: losses[k] for k in (*LOSS_TERMS, *LOGGED)} | {"grad_norm": grad_norm}


def _make_update(run: Run, cfg: DictConfig, model: nn.Module, policy: TensorDictModuleBase, num_envs: int) -> _Update:
    """The loss, optimiser, learning-rate schedule and reward scaling of a stage."""
    advantage = make_advantage(cfg, model)
    # the loss's critic is the value head alone: it reads the trunk features the actor's pass has just written into
    # the same minibatch, so the shared trunk runs once per minibatch and receives the gradients of both losses
    loss_fn = ClipPPOLoss(
        policy,
        model.get_value_head(),
        clip_epsilon=cfg.clip,
        entropy_coeff=cfg.entropy_coef,
        critic_coeff=cfg.value_coef,
        loss_critic_type="l2",
        normalize_advantage=cfg.normalize_advantage,
        clip_value=cfg.clip_value_loss,
    ).to(run.device)
    optimizer_cls = {"adam": torch.optim.Adam, "adamw": torch.optim.AdamW}[cfg.optimizer.name]
    optimizer = optimizer_cls(
        model.parameters(), lr=cfg.lr, eps=cfg.optimizer.eps, weight_decay=cfg.optimizer.weight_decay, fused=True
    )  # fused: ~5x faster step on CPU
    iterations = -(-run.stage.budget // cfg.frames_per_batch)

    def remaining(iteration: int) -> float:  # 1 -> 0 over the stage: the annealing factor
        return max(0.0, 1.0 - iteration / iterations)

    scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, remaining if cfg.anneal_lr else lambda _: 1.0)
    return_scale = ReturnScale(num_envs, cfg.gamma) if cfg.normalize_reward else None
    return _Update(cfg, run, model, advantage, loss_fn, optimizer, scheduler, return_scale, remaining)


def train(run: Run) -> None:
    cfg = run.cfg.algo
    model = make_model(cfg, run.obs_shapes).to(run.device)
    if run.cfg.get("compile"):
        compile_networks(model)
    env = run.train_env(make_transforms(cfg, run.obs_keys, model))
    num_envs = env.batch_size.numel()
    problem = check_config(run.cfg)
    if problem:
        raise ValueError(problem)
    rollout = cfg.frames_per_batch // num_envs
    run.iteration = (cfg.frames_per_batch, f"{num_envs} worlds x {rollout} steps, then an update")
    policy = make_policy(model)
    acting = run.acting(policy)
    update = _make_update(run, cfg, model, policy, num_envs)
    per_batch = cfg.epochs * cfg.num_minibatches

    def planned(steps: int) -> int:  # the gradient steps of the iterations these env steps take
        return -(-steps // cfg.frames_per_batch) * per_batch

    state = {"optimizer": update.optimizer, "scheduler": update.scheduler}
    state |= {"return_scale": update.return_scale} if update.return_scale else {}
    td = run.start(model, state, make_policy(model), make_transforms(cfg, run.obs_keys, model), planned)
    run.updates = planned(run.steps)  # a resumed run's bar counts on from its checkpoint
    while not run.done:
        update.anneal_clip()
        batch, td = run.collect(acting, td, rollout)
        began = time.perf_counter()
        metrics = update.epochs(update.with_advantage(batch), began)
        run.log(metrics)
        run.end_iteration(td)
