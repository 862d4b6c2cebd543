"""DreamerV3's gradient step, :class:`Learner`: the world model, then the actor in imagination, then the critic, each
with its own optimiser and gradient clipping, then the slow critic (``SoftUpdate``).

Each of the three parts is a *phase*: a function of tensors (a TensorDict in, a TensorDict out) that runs the
forward pass and the backward pass and leaves the gradients in the parameters' ``.grad``; gradient clipping, the
optimiser steps and the slow critic's update run between the phases, outside them.  A phase reads nothing from the
host and decides nothing on a tensor's value, so it can be replayed as a CUDA graph (``algo.update.graphs``) or
compiled (``algo.update.compile``); without either option it runs as plain eager code, the same operations in the
same order as before the split (``tests/test_dreamer_update.py`` holds both to the same weights, optimiser moments,
return normalisation and slow critic).

Nothing in :meth:`Learner.update` waits for the device: its metrics stay tensors until the caller reads them (when
a log is due), and the diagnostics of a logged step (:meth:`Learner.diagnostics`) are computed afterwards, from the
last update's outputs.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Mapping

import torch
from omegaconf import DictConfig
from tensordict import TensorDict, TensorDictBase
from torch import nn
from torchrl.objectives import DreamerV3ActorLoss, DreamerV3ValueLoss, SoftUpdate
from torchrl.objectives.utils import ValueEstimators

from .losses import WorldModelLoss, diagnostics, replay_value_loss
from .model import LATENT, DreamerModel, continuation_model, imagination_env, value_model

#: the options of ``algo.update`` and what each may be
UPDATE_OPTIONS = {"graphs": (False, True), "compile": (False, True), "prefetch": (False, True)}


def update_options(cfg: DictConfig, device: torch.device) -> dict[str, bool]:
    """``algo.update`` checked: each option a bool, and CUDA graphs only on a CUDA device."""
    section = cfg.get("update") or {}
    unknown = set(section) - set(UPDATE_OPTIONS)
    if unknown:
        raise ValueError(f"algo.update has no option {sorted(unknown)}: its options are {sorted(UPDATE_OPTIONS)}")
    options = {}
    for name, allowed in UPDATE_OPTIONS.items():
        value = section.get(name, False)
        if not isinstance(value, bool):
            raise ValueError(f"algo.update.{name} must be one of {list(allowed)}, got {value!r}")
        options[name] = value
    if options["graphs"] and device.type != "cuda":
        raise ValueError(
            f"algo.update.graphs=true captures CUDA graphs and needs a CUDA device; this run's device is {device} "
            "(use algo.update.graphs=false)"
        )
    return options


def check_config(cfg: DictConfig) -> str | None:
    """The training command's check (before anything is written): ``algo.update``'s options, and a stage long
    enough for a gradient step; None, or the problem."""
    from ..devices import DeviceError, resolve_device

    try:
        update_options(cfg.algo, resolve_device(cfg.device))
    except (ValueError, DeviceError) as err:
        return str(err)
    return prefill_problem(cfg)


def prefill_problem(cfg: DictConfig) -> str | None:
    """Why a stage would end before its first gradient step, in one line: every stage fills its own replay with
    ``algo.learning_starts`` env steps (at least one sequence per world) before DreamerV3 learns anything, and a
    stage whose env-step budget is no longer would write an untrained network as its final model."""
    start = max(int(cfg.algo.learning_starts), int(cfg.algo.sequence_length) * int(cfg.env.num_envs))
    curriculum = "stages" in cfg.level
    key = "level.stage_steps" if curriculum else "total_steps"
    budget = int(cfg.level.stage_steps if curriculum else cfg.total_steps)
    if budget > start:
        return None
    return (
        f"{key}={budget}: DreamerV3 takes its first gradient step after {start:,} env steps of prefill "
        f"(max of algo.learning_starts={cfg.algo.learning_starts} and algo.sequence_length x env.num_envs), so a "
        f"stage of {budget:,} would end untrained; give {key} more than {start:,} or lower algo.learning_starts"
    )


class Phase:
    """One phase of the gradient step, ``fn(TensorDict) -> TensorDict``, run eagerly or replayed as a CUDA graph.

    With ``graph=True`` the first ``warmup`` calls run eagerly on a side stream (as ``torch.cuda.graphs`` asks:
    cuDNN and cuBLAS pick their kernels, the optimisers' state exists); the next call captures ``fn`` on static
    copies of its input, and every later call copies its input into them (without waiting for the host) and
    replays the graph.  The output is then the graph's own memory, overwritten by the next replay: a caller keeps
    what it needs (:class:`Learner` copies its metrics).  The parameters' gradients live in the graph's memory
    too: ``fn`` sets them to None before its backward pass, which at capture makes the backward pass allocate them
    there, and nothing outside may set them to None afterwards (the optimisers' ``zero_grad`` is not called).
    """

    def __init__(self, fn: Callable[[TensorDictBase], TensorDictBase], *, graph: bool = False, warmup: int = 3):
        self.fn, self.graph, self.warmup = fn, graph, warmup
        self.calls = 0
        self._graph: torch.cuda.CUDAGraph | None = None
        self._input: TensorDictBase | None = None
        self._output: TensorDictBase | None = None

    def __call__(self, td: TensorDictBase) -> TensorDictBase:
        if not self.graph:
            return self.fn(td)
        self.calls += 1
        if self.calls <= self.warmup:
            side = torch.cuda.Stream()
            side.wait_stream(torch.cuda.current_stream())
            with torch.cuda.stream(side):
                out = self.fn(td)
            torch.cuda.current_stream().wait_stream(side)
            return out
        if self._graph is None:
            self._input = td.clone()
            self._graph = torch.cuda.CUDAGraph()
            with torch.cuda.graph(self._graph):
                self._output = self.fn(self._input)
        else:
            self._input.update_(td, non_blocking=True)
        self._graph.replay()
        return self._output


class Learner:
    """DreamerV3's losses, optimisers and slow critic on ``model``, and :meth:`update`, one gradient step.

    ``options`` are ``algo.update``'s (:func:`update_options`): ``graphs`` replays each phase as a CUDA graph,
    ``compile`` compiles each phase with ``torch.compile`` and the world model's RSSM step
    (``RSSMRolloutV3.compile_rollout``); ``prefetch`` belongs to the training loop.
    """

    def __init__(
        self,
        cfg: DictConfig,
        model: DreamerModel,
        device: torch.device,
        *,
        bf16: bool = False,
        options: Mapping[str, bool] | None = None,
        timed: Callable[[str], contextlib.AbstractContextManager] | None = None,
    ):
        self.cfg, self.model, self.device = cfg, model, torch.device(device)
        self.options = dict(options or {})
        # the time split (Run.timed): forward, backward and optimizer inside eager phases; a compiled or captured
        # phase is one block, counted as its forward pass
        untimed = lambda phase: contextlib.nullcontext()  # noqa: E731
        self._timed_outside = timed or untimed
        eager = not (self.options.get("graphs") or self.options.get("compile"))
        self._timed = self._timed_outside if eager else untimed  # inside a phase
        self._timed_phase = untimed if eager else self._timed_outside  # around a whole phase
        self.bf16 = bool(bf16)
        self.model_loss = WorldModelLoss(cfg, model)
        self.critic = value_model(model)
        self.actor_loss = DreamerV3ActorLoss(
            model.actor,
            self.critic,
            imagination_env(model, self.device),
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
        self.model_loss.to(self.device), self.actor_loss.to(self.device), self.value_loss.to(self.device)
        self.slow_critic = SoftUpdate(self.value_loss, tau=cfg.critic.tau)
        self.replay_scale = float(cfg.critic.get("replay_scale", 0.0))

        def adam(params, section: DictConfig) -> torch.optim.Adam:
            return torch.optim.Adam(params, lr=section.lr, eps=section.eps, fused=True)  # fused: ~5x faster on CPU

        self.params = {
            "world_model": model.world_model_parameters(),
            "actor": list(model.actor.parameters()),
            "critic": list(model.value.parameters()),
        }
        self.clip = {
            "world_model": cfg.world_model.grad_clip,
            "actor": cfg.actor.grad_clip,
            "critic": cfg.critic.grad_clip,
        }
        self.optimizers = {name: adam(self.params[name], section) for name, section in self._sections().items()}
        graph = self.options.get("graphs", False)
        phases = {
            "world_model": self._world_model_phase,
            "actor": self._actor_phase,
            "critic": self._critic_phase,
        }
        if self.options.get("compile", False):
            self.compile_replay_step()
            phases = {name: torch.compile(fn, dynamic=False) for name, fn in phases.items()}
        self.phases = {name: Phase(fn, graph=graph) for name, fn in phases.items()}
        self._last: dict[str, TensorDictBase] | None = None

    def compile_replay_step(self) -> None:
        """``torch.compile`` the step of the world model's replayed RSSM loop (``RSSMRolloutV3.compile_rollout``):
        the loop calls the prior's and posterior's methods, which a compiled module's ``__call__`` never sees."""
        self.model_loss.loss.world_model[2].compile_rollout("step", dynamic=False)

    def _sections(self) -> dict[str, DictConfig]:
        return {"world_model": self.cfg.world_model, "actor": self.cfg.actor, "critic": self.cfg.critic}

    def components(self) -> dict:
        """What a checkpoint keeps of the learner besides the model: optimisers, critic with its slow copy, return
        normalisation."""
        return {
            **{f"optimizer_{k}": v for k, v in self.optimizers.items()},
            "value_loss": self.value_loss,
            "return_norm": self.actor_loss.retnorm,
        }

    def autocast(self):
        """bf16 autocast of the phases' forward passes (``bf16=true``); the weight-cast cache off under CUDA graphs,
        which cannot replay it."""
        if not self.bf16:
            return contextlib.nullcontext()
        return torch.autocast(self.device.type, dtype=torch.bfloat16, cache_enabled=not self.options.get("graphs"))

    # ------------------------------------------------------------------------------------------ phases
    def _zero_grad(self, name: str) -> None:
        for p in self.params[name]:
            p.grad = None

    def _world_model_phase(self, batch: TensorDictBase) -> TensorDictBase:
        """The world model's loss on a replayed batch, and its gradients."""
        batch = batch.copy()
        batch["state"] = torch.zeros(*batch.shape, self.model.state_dim, device=batch.device)
        batch["belief"] = torch.zeros(*batch.shape, self.model.belief_dim, device=batch.device)
        with self._timed("forward"), self.autocast():
            loss, terms, posterior, vector_reco = self.model_loss(batch)
        with self._timed("backward"):
            self._zero_grad("world_model")
            loss.backward()
        out = TensorDict(
            {"loss": loss.detach(), "terms": terms.detach(), "posterior": posterior}, [], device=batch.device
        )
        if vector_reco is not None:
            out["vector_reco"] = vector_reco.detach()
        return out

    def _actor_phase(self, latents: TensorDictBase) -> TensorDictBase:
        """The actor's loss in imagination from every posterior latent of the batch (``[batch, time]`` state and
        belief, no gradient into the world model), and its gradients."""
        flat = TensorDict(
            {k: latents[k].reshape(-1, latents[k].shape[-1]).float() for k in LATENT},
            [latents.numel()],
            device=latents.device,
        )
        with self._timed("forward"), self.autocast():
            actor_out, imagined = self.actor_loss(flat)
        with self._timed("backward"):
            self._zero_grad("actor")
            actor_out["loss_actor"].backward()
        return TensorDict({"out": actor_out.detach(), "imagined": imagined}, [], device=latents.device)

    def _critic_phase(self, td: TensorDictBase) -> TensorDictBase:
        """The critic's loss on the imagined returns (and, with ``algo.critic.replay_scale``, on the replayed
        sequences), and its gradients."""
        imagined, posterior = td["imagined"], td.get("posterior", None)
        with self._timed("forward"), self.autocast():
            critic_out, _ = self.value_loss(imagined.detach())
            loss = critic_out["loss_value"]
            out = TensorDict({}, [], device=imagined.device)
            if self.replay_scale:
                replay_loss = replay_value_loss(self.value_loss, posterior, imagined, self.cfg)
                loss = loss + self.replay_scale * replay_loss
                out["replay_loss"] = replay_loss.detach()
        with self._timed("backward"):
            self._zero_grad("critic")
            loss.backward()
        out["loss"] = loss.detach()
        return out

    # ------------------------------------------------------------------------------------------ the step
    def _step(self, name: str) -> torch.Tensor:
        """Clip the phase's gradients and step its optimiser (outside the phase); returns the gradient norm."""
        with self._timed_outside("optimizer"):
            norm = nn.utils.clip_grad_norm_(self.params[name], self.clip[name])
            self.optimizers[name].step()
        return norm

    def update(self, batch: TensorDictBase) -> dict[str, torch.Tensor]:
        """One gradient step on a replayed batch (``[batch, time]``, on the device): the world model, then the actor
        in imagination from the batch's posterior latents, then the critic, each with its own optimiser and
        clipping; then the slow critic.  Returns the metrics as tensors (nothing waits for the device)."""
        with self._timed_phase("forward"):
            wm = self.phases["world_model"](batch)
        wm_norm = self._step("world_model")
        posterior = wm["posterior"]
        with self._timed_phase("forward"):
            actor = self.phases["actor"](posterior["next"].select(*LATENT))
        actor_norm = self._step("actor")
        imagined, actor_out = actor["imagined"], actor["out"]
        critic_in = TensorDict({"imagined": imagined}, [], device=imagined.device)
        if self.replay_scale:
            critic_in["posterior"] = posterior
        with self._timed_phase("forward"):
            critic = self.phases["critic"](critic_in)
        critic_norm = self._step("critic")
        with self._timed_outside("optimizer"):
            self.slow_critic.step()
        self._last = {"posterior": posterior, "imagined": imagined, "return_scale": actor_out["return_scale"]}
        metrics = {f"model_{k.removeprefix('loss_model_')}": v for k, v in wm["terms"].items()}
        metrics |= {
            "model_loss": wm["loss"],
            "model_grad_norm": wm_norm,
            "actor_loss": actor_out["loss_actor"],
            "actor_entropy": actor_out["actor_entropy"],
            "return_scale": actor_out["return_scale"],
            "actor_grad_norm": actor_norm,
            "imagined_reward": imagined["next", "reward"].mean(),
            "imagined_continuation": actor_out["continuation_mean"],
            "critic_loss": critic["loss"],
            "critic_grad_norm": critic_norm,
            "imagined_return": imagined["lambda_target"].mean(),
        }
        if self.replay_scale:
            metrics["critic_replay_loss"] = critic["replay_loss"]
        if "vector_reco" in wm.keys():
            metrics["model_reco_vector"] = wm["vector_reco"]
        if "interoception" in self.model.obs_keys:  # how well the latent knows the EVs the reward is computed from
            nxt = posterior["next"]
            metrics["interoception_error"] = (
                (nxt["reco_interoception"].detach().float() - nxt["interoception"].float()).abs().mean()
            )
        if self.options.get("graphs"):  # the graphs' outputs are overwritten by the next replay: keep a copy
            metrics = dict(zip(metrics, torch.stack([v.float().reshape(()) for v in metrics.values()]).unbind()))
        return metrics

    def diagnostics(self) -> dict[str, torch.Tensor]:
        """The diagnostics of the last update (:func:`.losses.diagnostics`), computed from its outputs: called when
        a log is due, after :meth:`update` (they read values on the host, which the update itself never does)."""
        if self._last is None:
            raise RuntimeError("Learner.diagnostics needs an update first")
        last = self._last
        return diagnostics(self.model, self.critic, last["posterior"], last["imagined"], last["return_scale"])
