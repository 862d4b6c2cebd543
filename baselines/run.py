"""What every baseline's training loop shares, one stage at a time: the stage's worlds and their evaluation twins,
the step that logs finished episodes, periodic evaluation, the progress bar, and checkpoints that resume exactly.

An algorithm (``baselines/dqn.py``, ``baselines/ppo.py``) owns its networks, buffer, loss and optimiser and calls a
:class:`Run` for the rest, so that every baseline logs, evaluates, checkpoints and resumes the same way.

Exact resume: a checkpoint is written between iterations and holds everything the next iteration reads — network,
optimiser, scheduler and other stateful components, the worlds' full state (``EvaaaEnv.snapshot``), the
frame-stack buffers, the tensordict the next step starts from, the counters, the torch / numpy / python RNG states
and the sizes of ``episodes.csv`` and ``eval.csv`` (cut back to them on resume, so rows written after the
checkpoint by the killed process are not duplicated).  Evaluation uses its own worlds, seeded afresh each time, and a
deterministic policy (or, with ``eval.sample``, a sampling one on a forked torch RNG), so it draws nothing from the
training RNGs.  The model of the best evaluation so far is kept as ``model-best-<stage>-<level>.pt``.

Interrupts: when ``stop_requested`` says so (the first Ctrl-C, see ``baselines/training.py``), the iteration under way
finishes, a checkpoint is written and :class:`Interrupted` says where, so an interrupted run always resumes exactly.

Devices: the worlds live on the CPU; the networks, losses, optimisers and replay live on ``device``
(:func:`resolve_device`).  Acting sends each step's observations to the device and brings the policy's outputs back
(:class:`OnDevice`).  The stage's clock — its budgets, the bar's rates and ETA, the time estimate — is
:class:`~.stage.StageClock`, started by :meth:`Run.start`.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import nn
from torchrl.envs import Transform, TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.record.loggers import Logger
from tqdm import tqdm

import evaaa
from evaaa import EV_NAMES
from evaaa.records import TRAINING_EPISODE_FIELDS

from .checkpoint import CHECKPOINT, CHECKPOINT_FORMAT, CheckpointError, rng_state, save_checkpoint, set_rng_state
from .config import COMPUTE_BOUND_STEPS, Stage, env_overrides, observation_keys
from .devices import OnDevice, autocast, resolve_device
from .logs import Counters, CsvLog, episode_metrics, episode_row, eval_columns, timestamp
from .rollout import EVALUATION_INFO, EvalResult, acting_mode, evaluate, samples_actions, wrap_env
from .stage import StageClock, TimeSplit, budget_text, stop_wait

log = logging.getLogger(__name__)

#: the diagnostics the training env emits (``make_env(info=...)``): episode logging reads the first six, the
#: DreamerV3 replay's consumed flag the last two; the rest would cost every step and be read by no one
TRAINING_INFO = ("step_count", "end_type", *EV_NAMES, "food_eaten", "water_eaten")


class Interrupted(KeyboardInterrupt):
    """Training stopped on request; the message says what a resume continues from, ``signals`` which signals asked
    (SIGINT, SIGTERM, SIGUSR2: ``baselines.training.STOP_SIGNALS``)."""

    signals: tuple[int, ...] = ()


def parameter_count(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


# ------------------------------------------------------------------------------------------------ one stage
class Run:
    """One stage of a training run as an algorithm's loop sees it.

    The contract: what an algorithm's ``train(run)`` does with a Run, in this order (``baselines/ppo.py`` is the
    shortest example):

    1. build its networks from :attr:`obs_shapes` and :attr:`obs_keys` (config in :attr:`cfg`), on :attr:`device`;
    2. optionally say how it steps: :attr:`iteration` (env steps per iteration, and how, for the budget's
       arithmetic), :attr:`stops_between_updates` (it checks :attr:`stop_requested` between gradient steps);
    3. ``env = run.train_env(transforms)``: the stage's training worlds with the algorithm's transforms;
    4. ``td = run.start(model, components, policy, eval_transforms)``: a fresh start, the curriculum's hand-over or
       an exact resume; ``components`` are the stateful objects a checkpoint keeps (optimisers, buffers, counters),
       ``policy`` and ``eval_transforms`` what evaluations act with (its ``make_policy`` and fresh
       ``make_transforms``), ``planned_updates`` the gradient steps owed by a number of env steps (for the ETA);
    5. while not :attr:`done`: act with :meth:`step` or :meth:`collect` (the policy wrapped by :meth:`acting`),
       update under :meth:`autocast` and report the gradient steps with :meth:`updated` (:meth:`set_phase` names a
       phase such as ``prefill``), :meth:`log` metrics when :attr:`log_due`, and end every iteration with
       :meth:`end_iteration` (periodic evaluation, checkpoint, Ctrl-C); one that stops between gradient steps calls
       :meth:`stop_now` when :attr:`stop_requested` says so.

    :attr:`steps`, :attr:`updates`, :attr:`stage` and :attr:`dir` may be read; names starting with ``_`` are the
    Run's own, read by no algorithm (``tests/test_imports.py`` checks).

    Args:
        cfg: the composed config.
        run_dir: where checkpoints and CSVs go.
        stage: the level and budget of this stage.
        logger: TorchRL logger shared by the stages.
        resume: a checkpoint of this stage to continue from.
        init_weights: the previous stage's model weights (curriculum), for a fresh stage.
        fresh_logs: start ``episodes.csv`` / ``eval.csv`` empty (a run's first stage started from scratch).
        stop_requested: asked at the end of every iteration; true: checkpoint now and raise :class:`Interrupted`.
    """

    def __init__(
        self,
        cfg: DictConfig,
        run_dir: Path,
        stage: Stage,
        logger: Logger,
        *,
        resume: dict | None = None,
        init_weights: Mapping | None = None,
        fresh_logs: bool = False,
        stop_requested: Callable[[], bool] | None = None,
    ):
        self.cfg, self.dir, self.stage, self.logger = cfg, Path(run_dir), stage, logger
        self.stop_requested = stop_requested or (lambda: False)
        #: where the networks, losses, optimisers and replay live (the worlds stay on the CPU)
        self.device = resolve_device(cfg.get("device", "auto"))
        self.resume_state, self.init_weights = resume, init_weights
        self.obs_keys = observation_keys(cfg)
        self.overrides = env_overrides(cfg)
        self.base_env = evaaa.make_env(
            stage.level,
            num_envs=cfg.env.num_envs,
            seed=cfg.seed + stage.index,
            modalities=self.obs_keys,
            info=TRAINING_INFO,
            backend=cfg.env.get("backend", "cpu"),
            **self.overrides,
        )
        #: per-world shapes of the enabled observation keys, before any frame stacking
        self.obs_shapes = {k: tuple(self.base_env.observation_spec[k].shape[1:]) for k in self.obs_keys}
        self.counters = Counters(steps=0, episodes=0, logged=0, last_end=0)
        #: wall-clock and CPU seconds of the stage's earlier sessions (a resumed checkpoint's ``time``)
        self._spent_before = (0.0, 0.0)
        #: this session against the stage's budgets, from :meth:`start` on
        self.clock: StageClock | None = None
        #: a time budget was found spent at an iteration's end (decided there once, so that the algorithm's loop and
        #: :meth:`end_iteration` agree on whether the stage is over: the final evaluation and model are written)
        self._timed_out = False
        self.recent: deque[int] = deque(maxlen=cfg.progress_window)
        self.last_eval: float | None = None
        self.best_eval: float | None = None
        offsets = resume["logs"] if resume else {}
        self.episodes_csv = CsvLog(
            self.dir / "episodes.csv", TRAINING_EPISODE_FIELDS, 0 if fresh_logs else offsets.get("episodes_csv")
        )
        columns = eval_columns(self.dir / "eval.csv", fresh=fresh_logs)
        self.eval_csv = CsvLog(self.dir / "eval.csv", columns, 0 if fresh_logs else offsets.get("eval_csv"))
        self.env: TransformedEnv | None = None
        self.model: nn.Module | None = None
        self._eval_env: TransformedEnv | None = None
        self.progress: tqdm | None = None
        #: shown in the bar beside the level, e.g. "prefill" while DreamerV3 or DQN fill their buffer
        self.phase: str | None = None
        #: gradient steps so far (:meth:`updated`)
        self.updates = 0
        #: env steps an iteration takes (all worlds) and how, e.g. (1024, "8 worlds x 128 steps, then an update"):
        #: the stage ends with the iteration that reaches its budget; an algorithm that steps otherwise sets it
        self.iteration: tuple[int, str] = (cfg.env.num_envs, f"one step of each of the {cfg.env.num_envs} worlds")
        #: the algorithm checks :attr:`stop_requested` between its gradient steps and calls :meth:`stop_now`
        self.stops_between_updates = False
        self._ratio: float | None = None
        self._shown = 0.0
        #: wall-clock and CPU seconds per phase of this session (:mod:`.stage`), logged under ``time/cpu/*``
        self.split = TimeSplit()

    # -------------------------------------------------------------------------------------------- set-up
    @property
    def steps(self) -> int:
        """Env steps of this stage so far (transitions summed over the worlds)."""
        return self.counters["steps"]

    @property
    def done(self) -> bool:
        """The stage's env-step budget is spent, or its time budget is: ``max_minutes`` of wall-clock time or
        ``max_cpu_minutes`` of this process's CPU time (every thread), each summed over the stage's sessions.  A time
        budget is read only at an iteration's end (:meth:`end_iteration`): the clock runs on while it evaluates, and a
        stage that ended between that check and the loop's would have no final model."""
        return self.steps >= self.stage.budget or self._timed_out

    def seconds_spent(self) -> tuple[float, float]:
        """Wall-clock and CPU seconds of this stage so far, earlier sessions included (kept in the checkpoint)."""
        return self.clock.seconds_spent()

    def session_seconds(self) -> float:
        """Wall-clock seconds since :meth:`start` began this process's session of the stage (a resumed stage's
        earlier sessions not included: :meth:`seconds_spent` counts those)."""
        return self.clock.session_seconds()

    def train_env(self, transforms: Sequence[Transform]) -> TransformedEnv:
        """The stage's worlds wrapped in the algorithm's transforms."""
        self.env = wrap_env(self.base_env, transforms)
        return self.env

    def start(
        self,
        model: nn.Module,
        components: Mapping[str, Any],
        policy: TensorDictModuleBase,
        eval_transforms: Sequence[Transform],
        planned_updates: Callable[[int], int] | None = None,
    ) -> TensorDictBase:
        """Begin or resume the stage; returns the tensordict the first step acts on.

        ``components`` are the loop's other stateful objects (optimiser, scheduler, loss with target network,
        replay buffer, exploration module, counters): anything with ``state_dict`` / ``load_state_dict``; the rest
        as the class's contract says (``planned_updates`` None: no gradient steps to count).
        """
        self.model, self.components = model, dict(components)
        self.policy = OnDevice(policy, self.device)
        self._eval_transforms = list(eval_transforms)
        if self.resume_state is not None:
            td = self._restore(self.resume_state)
        else:
            if self.init_weights is not None:
                model.load_state_dict(self.init_weights)
            td = self.env.reset()
        log.info(
            "%s on %s: %s parameters on %s (bf16 autocast %s, compile %s), %d worlds on the CPU, %s",
            self.cfg.algo.name,
            self.stage.level,
            f"{parameter_count(model):,}",
            self.device,
            "on" if self.cfg.get("bf16") else "off",
            "on" if self.cfg.get("compile") else "off",
            self.base_env.num_envs,
            budget_text(
                self.stage.budget,
                *self.iteration,
                self.cfg.get("max_cpu_minutes"),
                COMPUTE_BOUND_STEPS,
            ),
        )
        # the bar's own rate and ETA (tqdm's) are left out: they follow the last few updates of the bar and swing
        # with the loop's phases; Progress gives smoothed ones.  disable=None: no bar where the output is not a
        # terminal (a file or a pipe would get one line per refresh)
        self.progress = tqdm(
            total=self.stage.budget,
            initial=self.steps,
            unit="step",
            dynamic_ncols=True,
            desc=self._desc(),
            disable=None if self.cfg.progress else True,
            bar_format="{l_bar}{bar}| {n_fmt}/{total_fmt} [{elapsed}{postfix}]",
        )
        self.split = TimeSplit()
        self.clock = StageClock(
            self.stage.budget,
            self.iteration[0],
            steps=self.steps,
            planned_updates=planned_updates,
            window=self.cfg.get("progress_seconds", 60),
            max_minutes=self.cfg.get("max_minutes"),
            max_cpu_minutes=self.cfg.get("max_cpu_minutes"),
            spent_before=self._spent_before,
        )
        return td

    def _estimate(self) -> None:
        """Log once how long the stage will take (:meth:`.StageClock.estimate`)."""
        text = self.clock.estimate(self.steps, self.updates, self.done)
        if text is not None:
            log.info("time estimate for %s on %s: %s", self.cfg.algo.name, self.stage.level, text)

    def acting(self, policy: TensorDictModuleBase) -> OnDevice:
        """``policy`` (on :attr:`device`) acting on the CPU worlds' tensordicts."""
        return OnDevice(policy, self.device)

    def autocast(self):
        """bf16 autocast for an update's forward passes when ``bf16=true``."""
        return autocast(self.device, self.cfg.get("bf16", False))

    def timed(self, phase: str):
        """Counts the time of the ``with`` block to ``phase`` of the session's time split (:mod:`.stage`)."""
        return self.split(phase)

    def updated(self, count: int, seconds: float, total: int, ratio: float | None = None) -> None:
        """``count`` gradient steps were made in ``seconds``; ``total`` so far this stage; ``ratio``: the replay
        ratio kept (gradient steps per env step since learning began), if the algorithm keeps one."""
        self.updates, self._ratio = total, ratio
        self.clock.add(self.steps, count, seconds)
        self._show()
        # the first timed gradient step completes what the estimate needs: said now, not at the iteration's end
        self._estimate()

    def set_phase(self, phase: str | None) -> None:
        if phase != self.phase:
            self.phase = phase
            if self.progress is not None:
                self.progress.set_description(self._desc(), refresh=False)
                self._show(force=True)

    def _desc(self) -> str:
        desc = f"{self.cfg.algo.name} {self.stage.level}"
        return f"{desc} {self.phase}" if self.phase else desc

    # -------------------------------------------------------------------------------------------- acting
    def step(self, policy: TensorDictModuleBase, td: TensorDictBase) -> tuple[TensorDictBase, TensorDictBase]:
        """One env step in every world with a sampling policy; logs the episodes that end.

        Returns the transition (``td`` with ``"next"``) and the tensordict of the next step (worlds whose episode
        ended already reset).
        """
        with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
            with self.split("act"):
                td = policy(td)
            with self.split("env"):
                out, td = self.env.step_and_maybe_reset(td)
        n = out.batch_size.numel()
        self.counters["steps"] += n
        done = out["next", "done"].reshape(-1)
        if done.any():
            self._log_episodes(out["next"], done)
        self.clock.add(self.steps)
        self._show()
        self.progress.update(n)
        return out, td

    def collect(
        self, policy: TensorDictModuleBase, td: TensorDictBase, steps: int
    ) -> tuple[TensorDictBase, TensorDictBase]:
        """``steps`` env steps in every world: the transitions as ``[num_envs, steps]``, and the next tensordict."""
        transitions = []
        for _ in range(steps):
            out, td = self.step(policy, td)
            transitions.append(out)
        return torch.stack(transitions, dim=1), td

    def _log_episodes(self, nxt: TensorDictBase, done: torch.Tensor) -> None:
        for world in done.nonzero().flatten().tolist():
            self.counters["episodes"] += 1
            where = {"env_steps": self.steps, "stage": self.stage.index, "level": self.stage.level}
            row = episode_row(nxt, world, **where, episode=self.counters["episodes"])
            self.episodes_csv.write(row)
            self.logger.log_metrics(episode_metrics(row), step=self.steps)
            self.recent.append(row["steps"])

    # -------------------------------------------------------------------------------------------- bookkeeping
    @property
    def log_due(self) -> bool:
        """Whether :meth:`log` would write now: an algorithm computes costly diagnostics only then."""
        every = self.cfg.log_every
        return self.steps // every > self.counters["logged"] // every

    def log(self, metrics: Mapping[str, float]) -> None:
        """The latest update's training metrics; written every ``log_every`` env steps, with the session's steps/s."""
        if not self.log_due:
            return
        self.counters["logged"] = self.steps
        timing = {"time/env_steps_per_s": self.clock.steps_per_second(self.steps), **self.split.scalars()}
        if self.device.type == "cuda":
            timing["time/gpu_memory_peak_gb"] = torch.cuda.max_memory_allocated(self.device) / 1e9
        self.logger.log_metrics({**{f"train/{k}": float(v) for k, v in metrics.items()}, **timing}, step=self.steps)

    def end_iteration(self, td: TensorDictBase) -> None:
        """Evaluate and checkpoint when due: every ``eval.every`` / ``checkpoint.every`` env steps, and at the end of
        the stage, where the final model is also written as ``model-<stage>-<level>.pt``; and when a stop was
        requested, after which :class:`Interrupted` is raised."""
        prev, now = self.counters["last_end"], self.steps
        self.counters["last_end"] = now
        self._timed_out = self._timed_out or self.clock.out_of_time(now)
        self._estimate()

        def crossed(every: int) -> bool:
            return every > 0 and now // every > prev // every

        if crossed(self.cfg.eval.every) or (self.done and self.cfg.eval.every > 0):
            with self.split("eval"):
                self.evaluate()
        if self.done:
            with self.split("checkpoint"):
                save_checkpoint(
                    self._identity() | {"model": self.model.state_dict(), "env_steps": now, "time": self._time()},
                    self.model_path,
                )
        stop = self.stop_requested()
        if crossed(self.cfg.checkpoint.every) or self.done or stop:
            with self.split("checkpoint"):
                self._checkpoint(td)
        if stop:
            self._interrupted()

    def stop_now(self, td: TensorDictBase) -> None:
        """A stop was requested inside an iteration, between two gradient steps: checkpoint here and raise
        :class:`Interrupted`.  The algorithm's resume finishes the iteration (the gradient steps still owed, then
        :meth:`end_iteration`) before it takes another env step, so the resumed run is the uninterrupted one."""
        self._checkpoint(td)
        self._interrupted()

    def _interrupted(self) -> None:
        raise Interrupted(
            f"interrupted at env step {self.steps:,} of {self.stage.level}: checkpoint written to "
            f"{self.dir / CHECKPOINT}; the same command with resume=true continues from it"
        )

    def stop_wait(self) -> str:
        """What a first Ctrl-C waits for, in words, with how long it takes here when that is known."""
        between = self.stops_between_updates and self.phase != "prefill"
        return stop_wait(between, self.clock.meter if self.clock is not None else None, self.iteration[0])

    @property
    def model_path(self) -> Path:
        return self.dir / f"model-{self.stage.index}-{self.stage.level}.pt"

    @property
    def best_model_path(self) -> Path:
        """The model of the stage's best evaluation so far (highest mean survival), kept beside the final one."""
        return self.dir / f"model-best-{self.stage.index}-{self.stage.level}.pt"

    def evaluate(self) -> None:
        """A few episodes (deterministic, or sampled with ``eval.sample``) on the run's validation worlds, the same
        worlds every time (:mod:`evaaa.worlds`: never a training world, never a test world); one row per episode in
        ``eval.csv``, and ``model-best-*.pt`` when their mean survival is the best so far.  With
        ``eval.both_modes`` the same episodes are played in the other acting mode too (an algorithm that can
        sample), their rows in ``eval.csv`` with their own ``acting``, so that a protocol can choose the mode it
        compares from validation rows; ``eval.sample``'s mode alone keeps the best model and the bar's figure.  The
        evaluation's own CPU seconds go to the log (``eval/cpu_seconds``), so that a learning curve can be drawn
        against the CPU time of training alone."""
        began = time.process_time()
        if self._eval_env is None:
            base = evaaa.make_env(
                self.stage.level,
                num_envs=self.cfg.eval.episodes,
                modalities=self.obs_keys,
                info=EVALUATION_INFO,
                worlds="validation",
                backend=self.cfg.env.get("backend", "cpu"),
                **self.overrides,
            )
            self._eval_env = wrap_env(base, self._eval_transforms)
        sample = bool(self.cfg.eval.get("sample", False))
        modes = [sample]
        if self.cfg.eval.get("both_modes", False) and samples_actions(self.cfg.algo.name):
            modes.append(not sample)
        # episodes as they end, below the training bar where there is one (the final evaluation follows a full bar)
        shown = self.progress is not None and not self.progress.disable
        with tqdm(
            total=len(modes) * self.cfg.eval.episodes,
            desc=f"{'final ' if self.done else ''}evaluation on {self.stage.level}",
            unit="episode",
            dynamic_ncols=True,
            leave=False,
            disable=not shown,
        ) as bar:
            results = {mode: self._evaluate_once(mode, on_episode=bar.update) for mode in modes}
        result = results[sample]
        self.last_eval = result.survival_mean
        if self.best_eval is None or result.survival_mean > self.best_eval:
            self.best_eval = result.survival_mean
            best = {"model": self.model.state_dict(), "env_steps": self.steps, "eval_survival_mean": self.best_eval}
            save_checkpoint(self._identity() | best, self.best_model_path)
        common = {
            "env_steps": self.steps,
            "stage": self.stage.index,
            "level": self.stage.level,
            "worlds": "validation",
            "wall_time": timestamp(),
            "cpu_seconds": round(self.seconds_spent()[1], 2),
        }
        metrics = {"eval/survival_mean": result.survival_mean, "eval/return_mean": result.return_mean}
        for mode, played in results.items():
            acting = acting_mode(self.cfg.algo.name, mode)
            for row in played.rows:
                self.eval_csv.write(
                    {k: row[k] for k in self.eval_csv.columns if k in row} | common | {"acting": acting}
                )
            if len(results) > 1:
                metrics[f"eval/{acting}/survival_mean"] = played.survival_mean
        self.logger.log_metrics(metrics | {"eval/cpu_seconds": time.process_time() - began}, step=self.steps)
        self._show(force=True)

    def _evaluate_once(self, sample: bool, on_episode: Callable[[], Any] | None = None) -> EvalResult:
        """One episode in each validation world, acting by sampling or by the most likely action."""
        seed = self.cfg.seed
        self._eval_env.set_seed(seed, static_seed=True)
        # a sampling policy draws from torch's RNG: a forked, freshly seeded one leaves the training stream as it was
        with torch.random.fork_rng(devices=[self.device] if self.device.type == "cuda" else []):
            torch.manual_seed(seed)
            return evaluate(self._eval_env, self.policy, sample=sample, on_episode=on_episode)

    def status(self) -> str:
        """The bar's text after the step counter: smoothed and session env steps/s, gradient steps (count, rate,
        seconds each, replay ratio kept), the ETA, the mean survival of recent episodes and the last evaluation."""
        parts = [self.clock.status(self.steps, self.updates, self._ratio)]
        parts.append(f"surv {np.mean(self.recent):.0f}" if self.recent else "surv -")
        if self.last_eval is not None:
            parts.append(f"eval {self.last_eval:.0f}")
        return " | ".join(parts)

    def _show(self, force: bool = False) -> None:
        """Rewrite the bar's text at most twice a second (and redraw it: a long gradient step moves no step count)."""
        if self.progress is None or self.progress.disable:
            return
        now = time.perf_counter()
        if force or now - self._shown >= 0.5:
            self._shown = now
            self.progress.set_postfix_str(self.status(), refresh=True)

    # -------------------------------------------------------------------------------------------- checkpoints
    def _identity(self) -> dict:
        """What a loader needs to rebuild the policy, and to refuse a checkpoint made for other observations."""
        return {
            "format": CHECKPOINT_FORMAT,
            "algo": self.cfg.algo.name,
            "config": OmegaConf.to_container(self.cfg, resolve=True),
            "level": self.stage.level,
            "stage": self.stage.index,
            "modality": self.cfg.modality.name,
            "modalities": list(self.obs_keys),  # one observation key per modality in evaaa
            "obs_keys": list(self.obs_keys),
            "obs_shapes": {k: list(s) for k, s in self.obs_shapes.items()},
            "env_overrides": self.overrides,
        }

    def _time(self) -> dict[str, float]:
        seconds, cpu_seconds = self.seconds_spent()
        return {"seconds": seconds, "cpu_seconds": cpu_seconds}

    def _checkpoint(self, td: TensorDictBase) -> None:
        state = self._identity() | {
            "num_envs": self.base_env.num_envs,
            "model": self.model.state_dict(),
            "components": {name: c.state_dict() for name, c in self.components.items()},
            "env": {"snapshot": self.base_env.snapshot(), "transforms": self.env.transform.state_dict(), "td": td},
            "counters": self.counters.state_dict(),
            "time": self._time(),
            "rng": rng_state(),
            "logs": {
                "episodes_csv": self.episodes_csv.size(),
                "eval_csv": self.eval_csv.size(),
                "logger": self.logger.state_dict(),
                "recent": list(self.recent),
                "last_eval": self.last_eval,
                "best_eval": self.best_eval,
            },
        }
        save_checkpoint(state, self.dir / CHECKPOINT, keep_previous=True)

    def _restore(self, state: dict) -> TensorDictBase:
        try:
            self.model.load_state_dict(state["model"])
        except (KeyError, TypeError, RuntimeError) as err:  # a crafted file, its checksum valid
            raise CheckpointError(
                f"the checkpoint in {self.dir} is malformed: its weights do not fit this run's network "
                f"({type(err).__name__}: {' '.join(str(err).split())[:200]})"
            ) from None
        missing = sorted(set(self.components) - set(state["components"]))
        if missing:  # e.g. a PPO run made before algo.normalize_reward was on by default
            raise ValueError(
                f"the checkpoint in {self.dir} holds no state for {', '.join(missing)}: it was made with "
                "settings that did not use it; resume with the run's own settings (for PPO's "
                "return_scale: algo.normalize_reward=false)"
            )
        for name, component in self.components.items():
            component.load_state_dict(state["components"][name])
        self.env.reset()  # materialises the frame-stack buffers (lazy until the first reset) so they can be loaded
        self.base_env.restore(state["env"]["snapshot"])
        self.env.transform.load_state_dict(state["env"]["transforms"])
        self.counters.load_state_dict(state["counters"])
        spent = state.get("time", {})  # checkpoints made before time was kept: the earlier sessions count as none
        self._spent_before = (float(spent.get("seconds", 0.0)), float(spent.get("cpu_seconds", 0.0)))
        self.recent.extend(state["logs"]["recent"])
        self.last_eval = state["logs"]["last_eval"]
        self.best_eval = state["logs"].get("best_eval")
        set_rng_state(state["rng"])  # last: building the modules above drew from the RNGs
        return state["env"]["td"]

    def close(self) -> None:
        if self.progress is not None:
            self.progress.close()
            if self.steps > self.clock.start_steps:
                summary = self.clock.summary(self.steps, self.updates)
                log.info("%s on %s: %s", self.cfg.algo.name, self.stage.level, summary)
        self.episodes_csv.close()
        self.eval_csv.close()
        # close explicitly: an evaaa env collected later, while another env's GL context is current, frees its
        # GL objects in that context and corrupts that env's frames
        for env in (self.base_env, self._eval_env):
            if env is not None:
                env.close(raise_if_closed=False)
