"""Evaluating trained baselines: deterministic episodes on a batch of worlds, and loading a checkpoint as a policy.

:func:`load_policy` is what ``scripts/evaluate.py`` and the reports build on: it rebuilds the network an
algorithm trained from the checkpoint's own record (algorithm, config, observation keys and shapes), refuses a
checkpoint made for another observation set, and gives the env transforms (frame stacks, LSTM state) the policy
expects, so that ``loaded.make_env("two-resource-food")`` or ``loaded.wrap(env)`` yields tensordicts it can act on.
:class:`EvaluatedPolicy` and :func:`episode_records` are ``scripts/evaluate.py``'s engine: the reference agents
(oracle, random) and checkpoints run on a level as episode records (:mod:`evaaa.records`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import nn
from torchrl.envs import Compose, EnvBase, RewardSum, Transform, TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type

import evaaa
from evaaa import EV_NAMES
from evaaa.agents import OracleAgent, RandomAgent, StillAgent
from evaaa.records import EpisodeTracker, StepLog
from evaaa.sensors import resolve_modalities

from .algos import algorithm
from .checkpoint import CHECKPOINT_FORMAT, load_checkpoint


def wrap_env(env: EnvBase, transforms: Sequence[Transform]) -> TransformedEnv:
    """The env a policy acts in: the algorithm's transforms (frame stacks, LSTM state), then the episode return."""
    return TransformedEnv(env, Compose(*transforms, RewardSum()))


#: the diagnostics :func:`evaluate` reads: the env it steps must emit them (``evaaa.make_env(info=...)``)
EVALUATION_INFO = (
    "step_count",
    "end_type",
    *EV_NAMES,
    "food_eaten",
    "water_eaten",
    "collision",
    "damage_taken",
    "success",
)


def samples_actions(algo: str) -> bool:
    """Whether a policy of ``algo`` has an action distribution to sample from (DQN's Q-values have none)."""
    return getattr(algorithm(algo), "SAMPLES_ACTIONS", True)


def acting_mode(algo: str | None, sample: bool, epsilon: float = 0.0) -> str:
    """How a checkpoint of ``algo`` acts, as every evaluation row records it: ``mode`` (the most likely action:
    greedy Q-values, the mode of the action distribution) or ``sample`` (drawn from the distribution; an algorithm
    without one, such as DQN, acts by ``mode`` whatever is asked), with ``+epsilon=<e>`` when a uniformly random
    action replaces it with chance ``epsilon``.  ``algo=None``: a reference agent, which has no mode (``""``)."""
    if algo is None:
        return ""
    return ("sample" if sample and samples_actions(algo) else "mode") + (f"+epsilon={epsilon:g}" if epsilon else "")


@dataclass(frozen=True)
class EvalResult:
    """The first episode of every world, one row each (:class:`evaaa.records.EpisodeTracker`'s columns: ``steps``
    survived, ``return``, ``end_type``, food and water eaten, collisions ...), in the order of the worlds."""

    rows: list[dict]

    @property
    def survival(self) -> list[int]:
        return [r["steps"] for r in self.rows]

    @property
    def returns(self) -> list[float]:
        return [r["return"] for r in self.rows]

    @property
    def end_types(self) -> list[str]:
        return [r["end_type"] for r in self.rows]

    @property
    def survival_mean(self) -> float:
        return float(np.mean(self.survival))

    @property
    def return_mean(self) -> float:
        return float(np.mean(self.returns))


def evaluate(env: EnvBase, policy: TensorDictModuleBase, *, sample: bool = False) -> EvalResult:
    """Run ``policy`` until every world of ``env`` has finished one episode (from a reset).

    The policy acts deterministically (greedy Q-values, the mode of its action distribution), or with
    ``sample=True`` samples its actions from that distribution.

    ``env`` must emit the keys the policy reads (see :meth:`LoadedPolicy.wrap`) and the ``"info"`` fields of
    :data:`EVALUATION_INFO`; episodes end by death or by the
    level's ``episode.max_steps``.  Worlds that finish early keep stepping, unrecorded, until the last one ends.
    """
    emitted = env.observation_spec.keys(include_nested=True)
    missing = [field for field in EVALUATION_INFO if ("info", field) not in emitted]
    if missing:
        raise ValueError(
            f"evaluate reads info fields {list(EVALUATION_INFO)} the env does not emit ({missing}): "
            f"make it with evaaa.make_env(..., info={list(EVALUATION_INFO)}) or info=True"
        )
    n = env.batch_size.numel()
    level = getattr(env, "base_env", env).level
    tracker = EpisodeTracker(n, level.name, "", judged=level.episode.success.rule != "none")
    rows: list[dict | None] = [None] * n
    acting = ExplorationType.RANDOM if sample else ExplorationType.DETERMINISTIC
    with torch.no_grad(), set_exploration_type(acting):
        td = env.reset()
        while any(r is None for r in rows):
            out, td = env.step_and_maybe_reset(policy(td))
            nxt = out["next"]
            done = nxt["done"].reshape(n).numpy()
            finished = tracker.update(nxt["reward"].reshape(n).numpy(), nxt["info"], done, actions=out["action"])
            for w, row in zip(np.flatnonzero(done), finished):
                if rows[w] is None:  # a world's later episodes are not counted
                    rows[w] = row
    return EvalResult([row | {"episode": w} for w, row in enumerate(rows)])


@dataclass
class LoadedPolicy:
    """A trained policy and what it was trained on.

    Call it on tensordicts of an env made by :meth:`make_env` or :meth:`wrap` to get ``"action"`` (deterministic:
    greedy Q-values, or the mode of the action distribution).  A recurrent policy keeps its state in the
    tensordict (``recurrent_state_h/c``), which those envs carry from step to step.
    """

    path: Path
    algo: str
    config: dict
    level: str
    modalities: tuple[str, ...]
    obs_keys: tuple[str, ...]
    env_overrides: dict
    model: nn.Module
    policy: TensorDictModuleBase

    def __call__(self, td: TensorDictBase, *, deterministic: bool = True) -> TensorDictBase:
        """``"action"`` for ``td``: the deterministic one, or (``deterministic=False``) one sampled from the
        policy's action distribution (PPO, DreamerV3; DQN's Q-values have no distribution and stay greedy)."""
        mode = ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM
        with torch.no_grad(), set_exploration_type(mode):
            return self.policy(td)

    def transforms(self) -> list[Transform]:
        """Fresh instances of the env transforms the policy expects (one set per env)."""
        return algorithm(self.algo).make_transforms(OmegaConf.create(self.config["algo"]), self.obs_keys, self.model)

    def wrap(self, env: EnvBase) -> TransformedEnv:
        """``env`` (an evaaa env emitting exactly this policy's observation keys) with the policy's transforms."""
        emitted = tuple(k for k in evaaa.MODALITIES if k in env.observation_spec.keys())
        if set(emitted) != set(self.obs_keys):
            raise ValueError(
                f"{self.path}: the policy reads observation keys {list(self.obs_keys)}, the env emits {list(emitted)}"
            )
        return wrap_env(env, self.transforms())

    def make_env(
        self,
        level: str | None = None,
        *,
        num_envs: int = 1,
        seed: int | None = None,
        overrides: Mapping[str, Any] | None = None,
        worlds: str = "test",
    ) -> TransformedEnv:
        """An env of ``level`` (default: the one trained on) with this policy's observation keys and transforms,
        on the seed's ``worlds`` (:mod:`evaaa.worlds`; default the test worlds, which no training run steps).

        ``overrides`` default to the training run's level overrides (reward, episode length, ...); pass ``{}`` for
        the level as it is.
        """
        overrides = self.env_overrides if overrides is None else overrides
        env = evaaa.make_env(
            level or self.level,
            num_envs=num_envs,
            seed=seed,
            modalities=self.obs_keys,
            info=True,
            worlds=worlds,
            **overrides,
        )
        return self.wrap(env)


def load_policy(
    path: str | Path, *, modalities: Iterable[str] | str | None = None, device: str | torch.device = "cpu"
) -> LoadedPolicy:
    """Load a checkpoint (``checkpoint.pt`` or ``model-*.pt`` of a run directory) as a policy.

    Args:
        path: the checkpoint file.
        modalities: the observation keys the caller will feed (e.g. an ablation's); if given and different from
            the keys the checkpoint was trained on, a ``ValueError`` says which keys differ.
        device: where the network runs (``auto``, ``cpu``, ``cuda``, ``cuda:N``), whatever device trained it; the
            policy still acts on tensordicts of CPU worlds.

    A file that is damaged, cut short or holds anything but tensors and plain data (so could run code) is refused
    with a :class:`~baselines.checkpoint.CheckpointError` (a ``ValueError``) naming it.
    """
    from .runtime import OnDevice, resolve_device  # runtime imports this module

    device = resolve_device(device)

    path = Path(path)
    state = load_checkpoint(path)
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT or "model" not in state:
        raise ValueError(f"{path} is not an evaaa baseline checkpoint (format {CHECKPOINT_FORMAT})")
    obs_keys = tuple(state["obs_keys"])
    if modalities is not None:
        wanted = resolve_modalities(modalities)
        if set(wanted) != set(obs_keys):
            missing, extra = sorted(set(obs_keys) - set(wanted)), sorted(set(wanted) - set(obs_keys))
            raise ValueError(
                f"{path} was trained on observation keys {list(obs_keys)}, not {list(wanted)}: "
                f"missing {missing}, unexpected {extra}"
            )
    try:
        algo = algorithm(state["algo"])
    except ValueError as err:
        raise ValueError(f"{path}: {err}") from None
    algo_cfg: DictConfig = OmegaConf.create(state["config"]["algo"])
    model = algo.make_model(algo_cfg, {k: tuple(s) for k, s in state["obs_shapes"].items()})
    model.load_state_dict(state["model"])
    model.to(device).eval()
    return LoadedPolicy(
        path=path,
        algo=state["algo"],
        config=state["config"],
        level=state["level"],
        modalities=tuple(state["modalities"]),
        obs_keys=obs_keys,
        env_overrides=state["env_overrides"],
        model=model,
        policy=OnDevice(algo.make_policy(model), device),
    )


# ------------------------------------------------------------------------------------------------ evaluate.py
#: the policies of an evaluation that are not checkpoints (evaaa.agents): the privileged oracle, uniformly random
#: actions, and standing still
REFERENCE_AGENTS = ("oracle", "random", "still")
_REFERENCE = {"oracle": lambda seed: OracleAgent(), "random": RandomAgent, "still": lambda seed: StillAgent()}


class EvaluationError(ValueError):
    """A policy cannot be evaluated as asked (its checkpoint, its device, the level); the message says why."""


class EvaluatedPolicy:
    """One policy of an evaluation — ``oracle``, ``random``, ``still`` or a checkpoint file — that builds the env of
    a level and picks actions for a batch of worlds.

    ``sample``: a checkpoint draws its actions from its distribution instead of taking the most likely one;
    ``epsilon``: the chance of a uniformly random action instead, at each step (drawn from a generator seeded with
    ``seed``, so runs repeat).  :attr:`name` and :attr:`acting` go into every episode row.
    """

    def __init__(
        self,
        spec: str,
        seed: int,
        modalities: list[str] | None = None,
        epsilon: float = 0.0,
        sample: bool = False,
        device: str = "cpu",
    ):
        self.spec = spec
        self.seed = seed
        self.epsilon = epsilon
        self.sample = sample
        self.rng = torch.Generator().manual_seed(seed)  # epsilon's draws: the same for every run of the command
        self.loaded: LoadedPolicy | None = None
        if spec not in REFERENCE_AGENTS:
            path = Path(spec)
            if not path.is_file():
                raise EvaluationError(f"policy {spec!r} is neither {', '.join(REFERENCE_AGENTS)} nor a checkpoint file")
            try:
                self.loaded = load_policy(path, modalities=modalities, device=device)
            except ValueError as err:  # e.g. modalities= names keys the checkpoint was not trained on
                raise EvaluationError(f"policy={spec}: {err}") from None
        # a checkpoint is named by its path: reports look the run's configuration up from it
        self.name = spec if self.loaded is None else str(path)
        # how it acts, recorded with every episode so that evaluations made in different ways stay apart
        self.acting = acting_mode(None if self.loaded is None else self.loaded.algo, sample, epsilon)

    def make_env(self, level: str, num_envs: int, seed: int, worlds: str = "test") -> EnvBase:
        """The ``worlds`` (``test`` or ``validation``: :mod:`evaaa.worlds`) of ``level`` this policy acts in (a
        reference agent reads the simulator; the env gives it the EVs only)."""
        if worlds not in ("test", "validation"):  # published numbers never come from a training world
            raise EvaluationError(f"worlds must be test or validation, got {worlds!r}")
        if self.loaded is not None:
            try:
                return self.loaded.make_env(level, num_envs=num_envs, seed=seed, overrides={}, worlds=worlds)
            except ValueError as err:
                raise EvaluationError(str(err)) from None
        self.agent = _REFERENCE[self.spec](seed)
        return evaaa.make_env(
            level, num_envs=num_envs, seed=seed, modalities=["interoception"], info=True, worlds=worlds
        )

    def act(self, env: EnvBase, td: TensorDictBase) -> torch.Tensor:
        if self.loaded is not None:
            action = self.loaded(td, deterministic=not self.sample)["action"]
            if self.epsilon > 0:  # epsilon-greedy evaluation: a uniformly random action instead, now and then
                explore = torch.rand(action.shape, generator=self.rng) < self.epsilon
                other = torch.randint(0, len(evaaa.ACTION_NAMES), action.shape, generator=self.rng)
                action = torch.where(explore, other, action)
            return action
        sim = env.sim if hasattr(env, "sim") else env.base_env.sim
        return torch.from_numpy(self.agent.act(sim))


def episode_records(
    policy: EvaluatedPolicy,
    level: str,
    *,
    episodes: int,
    num_envs: int,
    seed: int,
    worlds: str = "test",
    step_log: StepLog | None = None,
    on_episode: Callable[[], None] | None = None,
) -> list[dict]:
    """``episodes`` episodes of ``policy`` on ``level`` in ``num_envs`` of the ``worlds`` (``test`` or ``validation``)
    of ``seed``, as episode rows (:class:`evaaa.records.EpisodeTracker`, with a ``worlds`` column; ``episode``
    numbered from 0 in the order they ended).  Each world runs its share of the episodes; ``step_log`` gets every
    decision; ``on_episode`` is called per counted episode."""
    env = policy.make_env(level, num_envs, seed, worlds)
    torch.manual_seed(seed)  # sampled actions (sample=true) repeat from run to run
    n = num_envs
    quota = np.full(n, episodes // n) + (np.arange(n) < episodes % n)  # episodes each world runs
    tracker = EpisodeTracker(n, level, policy.name, seed=seed, acting=policy.acting, worlds=worlds)
    rows: list[dict] = []
    td = env.reset()
    if step_log is not None:
        step_log.start(level, td["info"], seed=seed, policy=policy.name, acting=policy.acting)
    done_count = np.zeros(n, dtype=int)
    while (done_count < quota).any():
        td["action"] = policy.act(env, td).reshape(env.action_spec.shape)
        step, td = env.step_and_maybe_reset(td)
        nxt = step["next"]
        info = {k: v.reshape(n, -1) for k, v in nxt["info"].items()}
        done = nxt["done"].reshape(n).numpy()
        finished = tracker.update(nxt["reward"].reshape(n).numpy(), info, done, actions=step["action"])
        if step_log is not None:
            step_log.update(step["action"], nxt["reward"], info, done, td["info"])
        for w, row in zip(np.flatnonzero(done), finished):  # rows come in the order of the finished worlds
            if done_count[w] < quota[w]:  # a world's episodes beyond its quota are not counted
                rows.append(row)
                if on_episode is not None:
                    on_episode()
            done_count[w] += 1
    env.close()
    for i, row in enumerate(rows):
        row["episode"] = i
    return rows
