"""``EvaaaEnv``: the TorchRL environment over the batched simulator.

Specs are built once; ``batch_size=(num_envs,)`` holds several worlds in one process; partial resets follow the
``"_reset"`` mask; ``terminated`` (an EV left its range, or a single-trial resource was consumed) is kept apart
from ``truncated`` (``episode.max_steps`` reached); diagnostics live under the nested ``"info"`` key.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from .backends import check_backend, make_simulator
from .level import Level
from .level_files import load_level
from .sim import ACTION_NAMES, NUM_ACTIONS

_TORCH_DTYPE = {np.dtype(np.float32): torch.float32, np.dtype(np.uint8): torch.uint8}

#: Entries of ``"info"``: name -> (shape per world, dtype).
INFO_FIELDS: dict[str, tuple[tuple[int, ...], torch.dtype]] = {
    "position": ((3,), torch.float32),
    "yaw": ((1,), torch.float32),
    "satiation": ((1,), torch.float32),
    "hydration": ((1,), torch.float32),
    "temperature": ((1,), torch.float32),
    "damage": ((1,), torch.float32),
    "food_eaten": ((1,), torch.int64),
    "water_eaten": ((1,), torch.int64),
    "collision": ((1,), torch.bool),
    "damage_taken": ((1,), torch.float32),
    "attacked": ((1,), torch.bool),
    "step_count": ((1,), torch.int64),
    "end_type": ((1,), torch.int64),
    "success": ((1,), torch.bool),
    "trigger_crossed": ((1,), torch.bool),
    "near_heat": ((1,), torch.bool),
}


class EvaaaEnv(EnvBase):
    """A homeostatic survival task in a 3-D MuJoCo world.

    Args:
        level: a level name (``evaaa.LEVELS`` / ``evaaa.TESTBEDS``), the path of a level's ``.yaml`` file (see
            :func:`evaaa.load_level`) or a loaded :class:`~evaaa.level.Level`.
        num_envs: independent worlds stepped together in this process (the env's batch size).
        seed: seed for the worlds' generators; same seed and actions give the same trajectories.
        worlds: which of the seed's three disjoint sets of worlds to step (:mod:`evaaa.worlds`): ``train`` (the
            default), ``validation`` (periodic evaluations and anything tuned) or ``test`` (published numbers).
        modalities: observation keys to emit (default all): ``pixels``, ``interoception``, ``olfaction``,
            ``thermoception``, ``collision``.  A dropped modality's key is absent, not zeroed.
        device: where the returned tensors live.
        overrides: dotted-path changes to the level (``{"agent.move_speed": 10}``).
        info: the diagnostics to emit under the nested ``"info"`` key: ``True`` for every field of
            :data:`INFO_FIELDS`, a list of some of them, or ``False`` (the default: no ``"info"`` entry, and none of
            its cost on every step).
        threads: how many threads work at once (1: everything in the calling thread; None: 2 when the process may
            use two cores, or as the environment variable ``EVAAA_THREADS`` says).  A batch is split into that many
            shares, stepped and drawn at once; a single world's frame is drawn while a helper advances its EVs and
            reads its other senses.  Observations are the same either way.  Ignored by the ``warp`` backend.
        backend: where the physics and the camera run: ``cpu`` (the default: MuJoCo and OpenGL, world by world) or
            ``warp`` (MuJoCo Warp, every world at once on the first GPU, else on Warp's CPU device; frames stay on
            that device; needs the optional extra ``warp``: docs/backends.md).  Same keys, shapes, dtypes and specs.
    """

    # numpy does the work; the output tensordicts are assembled once per call
    _has_dynamic_specs = False
    batch_locked = True

    def __init__(
        self,
        level: str | Level = "1-1",
        *,
        num_envs: int = 1,
        seed: int | None = None,
        modalities: Iterable[str] | str | None = None,
        device: str | torch.device = "cpu",
        overrides: Mapping[str, Any] | None = None,
        threads: int | None = None,
        info: bool | Iterable[str] = False,
        worlds: str = "train",
        backend: str = "cpu",
    ):
        check_backend(backend)
        self._info_keys = _info_keys(info)
        spec = level if isinstance(level, Level) else load_level(level, overrides)
        if isinstance(level, Level) and overrides:
            spec = load_level(level.name, overrides)
        device = torch.device(device)
        # the Warp backend steps on the env's GPU, or on the first GPU (else Warp's CPU device) for a CPU env
        warp_device = str(device) if device.type == "cuda" else None
        self.sim = make_simulator(
            spec, num_envs, modalities, seed=seed, threads=threads, worlds=worlds, backend=backend, device=warp_device
        )
        super().__init__(batch_size=torch.Size([num_envs]), device=device)
        self.level = spec
        self.num_envs = num_envs
        self._make_specs()
        self._seed_value = seed
        self.is_closed = False  # as TorchRL's wrappers do once built: close() (or garbage collection) frees the GL

    # ---------------------------------------------------------------------------------------------- specs
    def _make_specs(self) -> None:
        n = self.num_envs
        obs = {}
        bounds = {sensor.key: sensor.bounds for sensor in self.sim.sensors}
        for key, (shape, dtype) in self.sim.observation_shapes.items():
            if dtype == np.uint8:
                obs[key] = Bounded(0, 255, shape=(n, *shape), dtype=torch.uint8, device=self.device)
            elif bounds[key] is not None:
                obs[key] = Bounded(
                    *bounds[key], shape=(n, *shape), dtype=_TORCH_DTYPE[np.dtype(dtype)], device=self.device
                )
            else:
                obs[key] = Unbounded(shape=(n, *shape), dtype=_TORCH_DTYPE[np.dtype(dtype)], device=self.device)
        info = {}
        for key in self._info_keys:
            shape, dtype = INFO_FIELDS[key]
            if dtype is torch.bool:
                info[key] = Categorical(2, shape=(n, *shape), dtype=torch.bool, device=self.device)
            else:
                info[key] = Unbounded(shape=(n, *shape), dtype=dtype, device=self.device)
        if info:
            obs["info"] = Composite(info, shape=(n,), device=self.device)
        self.observation_spec = Composite(obs, shape=(n,), device=self.device)
        self.action_spec = Categorical(NUM_ACTIONS, shape=(n,), dtype=torch.int64, device=self.device)
        self.reward_spec = Unbounded(shape=(n, 1), dtype=torch.float32, device=self.device)
        done = Categorical(2, shape=(n, 1), dtype=torch.bool, device=self.device)
        self.done_spec = Composite(
            done=done.clone(), terminated=done.clone(), truncated=done.clone(), shape=(n,), device=self.device
        )

    # ---------------------------------------------------------------------------------------------- plumbing
    def _to_td(self, obs: dict[str, np.ndarray], info: dict[str, np.ndarray], extra: dict[str, torch.Tensor]):
        device = self.device
        on_cpu = device.type == "cpu"
        # numpy arrays, and the Warp backend's frames: torch tensors on its device
        source: dict[str, Any] = {k: v if isinstance(v, torch.Tensor) else torch.from_numpy(v) for k, v in obs.items()}
        source.update(extra)
        if not on_cpu or self.sim.backend != "cpu":
            source = {k: v.to(device, non_blocking=True) for k, v in source.items()}
        if self._info_keys:
            info_td = {k: torch.from_numpy(info[k]) for k in self._info_keys}
            if not on_cpu:
                info_td = {k: v.to(device, non_blocking=True) for k, v in info_td.items()}
            # the tensors are fresh, well-shaped and on the env's device: skip tensordict's per-entry validation
            source["info"] = TensorDict._new_unsafe(info_td, batch_size=self.batch_size, device=device)
        return TensorDict._new_unsafe(source, batch_size=self.batch_size, device=device)

    def _check_open(self) -> None:
        # a closed env has freed its renderer; bringing it back silently would hide a use-after-close bug
        if self.__dict__.get("is_closed", False):
            raise RuntimeError(f"this EvaaaEnv ({self.level.name}) was closed; make a new one with evaaa.make_env(...)")

    def _action(self, tensordict: TensorDictBase) -> np.ndarray:
        """The ``"action"`` entry as one integer per world, or a clear error."""
        n = self.num_envs
        action = tensordict.get("action", None)
        if action is None or action.dtype.is_floating_point or action.numel() != n:
            raise ValueError(self._action_error(action))  # the message is built only when it is needed
        return action.reshape(n).cpu().numpy()

    def _action_error(self, action: torch.Tensor | None) -> str:
        n = self.num_envs
        allowed = f"an integer tensor of shape ({n},) with values in 0..{NUM_ACTIONS - 1} ({', '.join(ACTION_NAMES)})"
        if action is None:
            return f"the input has no 'action' entry: set td['action'] to {allowed}"
        if action.dtype.is_floating_point:
            return f"action must be {allowed}; got dtype {action.dtype}"
        if action.numel() == n * NUM_ACTIONS and action.shape[-1] == NUM_ACTIONS:
            return (
                f"action has shape {tuple(action.shape)}, like a one-hot encoding; this env takes {allowed} "
                "(for a one-hot tensor, pass action.argmax(-1))"
            )
        return f"action must be {allowed}; got shape {tuple(action.shape)}"

    def extra_repr(self) -> str:
        # what repr(env) shows between the parentheses (EnvBase is an nn.Module)
        info = "all" if len(self._info_keys) == len(INFO_FIELDS) else list(self._info_keys) or False
        return (
            f"level={self.level.name!r}, num_envs={self.num_envs}, modalities={list(self.sim.modalities)}, "
            f"info={info}, device={self.device}, seed={self._seed_value}, worlds={self.worlds}, "
            f"threads={self.sim.threads}" + ("" if self.backend == "cpu" else f", backend={self.backend!r}")
        )

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        self._check_open()
        mask = None
        if tensordict is not None:
            reset = tensordict.get("_reset", None)
            if reset is not None:
                mask = reset.reshape(self.num_envs).cpu().numpy()
        obs = self.sim.reset(mask)
        false = torch.zeros((self.num_envs, 1), dtype=torch.bool)
        return self._to_td(
            obs, self.sim.last_info, {"done": false, "terminated": false.clone(), "truncated": false.clone()}
        )

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        self._check_open()
        obs, reward, terminated, truncated, info = self.sim.step(self._action(tensordict))
        term = torch.from_numpy(terminated).unsqueeze(-1)
        trunc = torch.from_numpy(truncated).unsqueeze(-1)
        return self._to_td(
            obs,
            info,
            {
                "reward": torch.from_numpy(reward).unsqueeze(-1),
                "done": term | trunc,
                "terminated": term,
                "truncated": trunc,
            },
        )

    @property
    def backend(self) -> str:
        """Where the physics and the camera run (``cpu`` or ``warp``: see :class:`EvaaaEnv`)."""
        return self.sim.backend

    @property
    def worlds(self) -> str:
        """The set of worlds this env steps (``train``, ``validation`` or ``test``; see :mod:`evaaa.worlds`)."""
        return self.sim.worlds

    def snapshot(self) -> dict:
        """The full state of every world (physics, EVs, layout, generators): restore it to continue exactly."""
        return self.sim.snapshot()

    def restore(self, snapshot: dict) -> None:
        """Continue from a :meth:`snapshot` (of an env of the same level and ``num_envs``)."""
        self.sim.restore(snapshot)

    def _set_seed(self, seed: int | None) -> None:
        self.sim.seed(seed)
        self._seed_value = seed

    def close(self, *, raise_if_closed: bool = True) -> None:
        sim = self.__dict__.get("sim")
        if sim is not None:
            sim.close()
        super().close(raise_if_closed=raise_if_closed)


def make_env(
    name: str = "1-1",
    *,
    num_envs: int = 1,
    seed: int | None = None,
    modalities: Iterable[str] | str | None = None,
    device: str | torch.device = "cpu",
    threads: int | None = None,
    info: bool | Iterable[str] = False,
    worlds: str = "train",
    backend: str = "cpu",
    **overrides: Any,
) -> EvaaaEnv:
    """Build the TorchRL env of a level or testbed.

    Overrides reach any level field by dotted path, e.g.
    ``make_env("1-1", **{"agent.move_speed": 10, "episode.max_steps": 1000})``, or as nested dicts,
    ``make_env("1-1", episode={"max_steps": 1000})``.  ``threads``, ``info``, ``worlds``: see :class:`EvaaaEnv`;
    ``make_env("1-1", seed=0, worlds="test")`` gives held-out worlds that no training run of any seed steps.
    ``backend``: one of :data:`evaaa.backends.BACKENDS`, ``make_env("1-1", num_envs=4096, backend="warp",
    device="cuda")`` steps every world on the GPU with MuJoCo Warp (docs/backends.md).
    """
    return EvaaaEnv(
        name,
        num_envs=num_envs,
        seed=seed,
        modalities=modalities,
        device=device,
        overrides=overrides,
        threads=threads,
        info=info,
        worlds=worlds,
        backend=backend,
    )


def _info_keys(info: bool | Iterable[str]) -> tuple[str, ...]:
    """``info=`` as the fields to emit, in :data:`INFO_FIELDS` order, or a clear error."""
    if info is True:
        return tuple(INFO_FIELDS)
    if info is False or info is None:
        return ()
    if isinstance(info, str):
        info = [info]
    try:
        asked = set(info)
    except TypeError:
        raise ValueError(
            f"info must be True, False or a list of fields of {', '.join(INFO_FIELDS)}; got {info!r}"
        ) from None
    unknown = sorted(str(k) for k in asked - set(INFO_FIELDS))
    if unknown:
        raise ValueError(f"info names unknown fields {unknown}; allowed: {', '.join(INFO_FIELDS)}")
    return tuple(k for k in INFO_FIELDS if k in asked)
