"""``scripts/evaluate.py``'s engine: :class:`EvaluatedPolicy` (a reference agent — oracle, random, still — or a
checkpoint, acting on a level's test or validation worlds) and :func:`episode_records`, its episodes as records
(:mod:`evaaa.records`).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from tensordict import TensorDictBase
from torchrl.envs import EnvBase

import evaaa
from evaaa.agents import OracleAgent, RandomAgent, StillAgent
from evaaa.records import EpisodeTracker, StepLog

from .policies import LoadedPolicy, load_policy
from .rollout import acting_mode
from .zoo import is_zoo

#: the policies of an evaluation that are not checkpoints (evaaa.agents): the privileged oracle, uniformly random
#: actions, and standing still
REFERENCE_AGENTS = ("oracle", "random", "still")
_REFERENCE = {"oracle": lambda seed: OracleAgent(), "random": RandomAgent, "still": lambda seed: StillAgent()}


class EvaluationError(ValueError):
    """A policy cannot be evaluated as asked (its checkpoint, its device, the level); the message says why."""


class EvaluatedPolicy:
    """One policy of an evaluation — ``oracle``, ``random``, ``still``, a checkpoint file or ``zoo:<name>`` — that
    builds the env of a level and picks actions for a batch of worlds.

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
            if not (is_zoo(spec) or path.is_file()):
                raise EvaluationError(
                    f"policy {spec!r} is neither {', '.join(REFERENCE_AGENTS)}, zoo:NAME nor a checkpoint file"
                )
            try:
                self.loaded = load_policy(spec if is_zoo(spec) else path, modalities=modalities, device=device)
            except ValueError as err:  # e.g. modalities= names keys the checkpoint was not trained on
                raise EvaluationError(f"policy={spec}: {err}") from None
        # a checkpoint is named by its path: reports look the run's configuration up from it; a zoo network, which
        # has no run here, by its zoo name
        self.name = spec if self.loaded is None or is_zoo(spec) else str(path)
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
