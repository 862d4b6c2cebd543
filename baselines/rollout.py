"""Deterministic (or sampling) episodes of a policy on a batch of worlds, as the training loop's periodic
evaluations and ``scripts/evaluate.py`` run them: :func:`wrap_env` (the algorithm's transforms and the episode
return), :func:`evaluate` (one episode per world), and how a policy acts (:func:`acting_mode`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.envs import Compose, EnvBase, RewardSum, Transform, TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type

from evaaa import EV_NAMES
from evaaa.records import EpisodeTracker

from .algos import algorithm


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


def evaluate(
    env: EnvBase,
    policy: TensorDictModuleBase | Callable[[TensorDictBase], TensorDictBase],
    *,
    sample: bool = False,
    on_episode: Callable[[], Any] | None = None,
) -> EvalResult:
    """Run ``policy`` until every world of ``env`` has finished one episode (from a reset).

    The policy acts deterministically (greedy Q-values, the mode of its action distribution), or with
    ``sample=True`` samples its actions from that distribution.

    ``env`` must emit the keys the policy reads (see :meth:`LoadedPolicy.wrap`) and the ``"info"`` fields of
    :data:`EVALUATION_INFO`; episodes end by death or by the
    level's ``episode.max_steps``.  Worlds that finish early keep stepping, unrecorded, until the last one ends.
    ``on_episode`` is called as each world's episode ends (a progress bar's update).
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
                    if on_episode is not None:
                        on_episode()
    return EvalResult([row | {"episode": w} for w, row in enumerate(rows)])
