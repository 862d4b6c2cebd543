"""A checkpoint loaded back as a policy: :func:`load_policy` rebuilds the network an algorithm trained from the
checkpoint's own record (algorithm, config, observation keys and shapes), refuses a checkpoint made for another
observation set, and gives the env transforms (frame stacks, LSTM state) the policy expects, so that
``loaded.make_env("two-resource-food")`` or ``loaded.wrap(env)`` yields tensordicts it can act on.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import nn
from torchrl.envs import EnvBase, Transform, TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type

import evaaa
from evaaa.sensors import resolve_modalities

from .algos import algorithm
from .checkpoint import CHECKPOINT_FORMAT, load_checkpoint
from .devices import OnDevice, resolve_device
from .rollout import wrap_env


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
