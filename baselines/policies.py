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
from .checkpoint import CHECKPOINT_FORMAT, CheckpointError, load_checkpoint
from .devices import OnDevice, resolve_device
from .rollout import wrap_env
from .zoo import checkpoint_path


def _one_line(err: BaseException) -> str:
    return f"{type(err).__name__}: {' '.join(str(err).split())[:200]}"


def _rebuilt(path: Path, algo: Any, cfg: DictConfig, obs_shapes: dict, weights: Any) -> nn.Module:
    """The network the checkpoint's config describes, with its weights.  It is first built on the meta device (no
    memory) and its tensors' shapes compared with the weights': a config whose network the file does not hold (a
    crafted one asking for 160 GB) is refused before anything is allocated.  Raises :class:`CheckpointError`."""
    if not isinstance(weights, Mapping):
        raise CheckpointError(f"{path} is malformed: its network's weights are no state_dict")
    try:
        with torch.device("meta"):
            shapes = {k: tuple(v.shape) for k, v in algo.make_model(cfg, obs_shapes).state_dict().items()}
    except Exception as err:  # noqa: BLE001 - any config the algorithm cannot build from
        raise CheckpointError(f"{path} is malformed: its config builds no network ({_one_line(err)})") from None
    given = {k: tuple(v.shape) for k, v in weights.items() if isinstance(v, torch.Tensor)}
    for key in sorted(shapes.keys() | given.keys()):
        if shapes.get(key) != given.get(key):
            raise CheckpointError(
                f"{path} is malformed: its config's network has {key} "
                f"{'of shape ' + str(list(shapes[key])) if key in shapes else 'not'}, its weights "
                f"{'of shape ' + str(list(given[key])) if key in given else 'none'}"
            )
    try:
        model = algo.make_model(cfg, obs_shapes)
        model.load_state_dict(weights)
    except Exception as err:  # noqa: BLE001 - what the shape comparison did not catch
        raise CheckpointError(f"{path} is malformed: its weights do not fit its network ({_one_line(err)})") from None
    return model


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
    """Load a checkpoint (``checkpoint.pt`` or ``model-*.pt`` of a run directory, or ``zoo:<name>``, a network
    shipped in the zoo: :mod:`baselines.zoo`) as a policy.

    Args:
        path: the checkpoint file, or ``zoo:<name>``.
        modalities: the observation keys the caller will feed (e.g. an ablation's); if given and different from
            the keys the checkpoint was trained on, a ``ValueError`` says which keys differ.
        device: where the network runs (``auto``, ``cpu``, ``cuda``, ``cuda:N``), whatever device trained it; the
            policy still acts on tensordicts of CPU worlds.

    A file that is damaged, cut short or holds anything but tensors and plain data (so could run code) is refused
    with a :class:`~baselines.checkpoint.CheckpointError` (a ``ValueError``) naming it, as is a zoo file whose
    sha256 differs from the zoo's manifest; a name the zoo does not hold with a :class:`~baselines.zoo.ZooError`.
    """
    device = resolve_device(device)

    path = checkpoint_path(path)
    state = load_checkpoint(path)
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT or "model" not in state:
        raise ValueError(f"{path} is not an evaaa baseline checkpoint (format {CHECKPOINT_FORMAT})")
    try:
        obs_keys = tuple(state["obs_keys"])
        algo_cfg: DictConfig = OmegaConf.create(state["config"]["algo"])
        obs_shapes = {k: tuple(int(n) for n in s) for k, s in state["obs_shapes"].items()}
        trained_modalities, env_overrides = tuple(state["modalities"]), dict(state["env_overrides"])
        algo_name, level = str(state["algo"]), str(state["level"])
    except (KeyError, TypeError, ValueError, AttributeError) as err:
        raise CheckpointError(f"{path} is malformed: its record of the run is incomplete ({_one_line(err)})") from None
    if modalities is not None:
        wanted = resolve_modalities(modalities)
        if set(wanted) != set(obs_keys):
            missing, extra = sorted(set(obs_keys) - set(wanted)), sorted(set(wanted) - set(obs_keys))
            raise ValueError(
                f"{path} was trained on observation keys {list(obs_keys)}, not {list(wanted)}: "
                f"missing {missing}, unexpected {extra}"
            )
    try:
        algo = algorithm(algo_name)
    except ValueError as err:
        raise ValueError(f"{path}: {err}") from None
    model = _rebuilt(path, algo, algo_cfg, obs_shapes, state["model"])
    model.to(device).eval()
    return LoadedPolicy(
        path=path,
        algo=algo_name,
        config=state["config"],
        level=level,
        modalities=trained_modalities,
        obs_keys=obs_keys,
        env_overrides=env_overrides,
        model=model,
        policy=OnDevice(algo.make_policy(model), device),
    )
