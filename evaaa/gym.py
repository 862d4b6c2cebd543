"""The gymnasium adapter: ``EvaaaGymEnv``, one world of a level behind the ``gymnasium.Env`` API, and the
registration of every level as ``evaaa/<name>-v0``.

It sits directly on a one-world :class:`~evaaa.sim.Simulator` (not on the TorchRL env) so that third-party
trainers get plain numpy observations without tensordict in the loop.  ``terminated`` (an EV left its range, or
a single-trial resource was consumed) is kept apart from ``truncated`` (``episode.max_steps`` reached), as in the
TorchRL env.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces

from .backends import check_backend, make_simulator
from .level_files import level_names, load_level
from .physiology import END_TYPES
from .sim import ACTION_NAMES, NUM_ACTIONS

__all__ = ["EvaaaGymEnv", "register_envs"]

_ONE_WORLD = np.arange(1)
_RENDER_MODES = ("rgb_array",)


class EvaaaGymEnv(gymnasium.Env[dict[str, np.ndarray], int]):
    """A homeostatic survival task in a 3-D MuJoCo world, one world, gymnasium API.

    Args:
        level: a level name (``evaaa.LEVELS`` / ``evaaa.TESTBEDS``).
        modalities: observation keys to emit (default all); a dropped modality's key is absent.
        render_mode: None or ``"rgb_array"`` (``render()`` returns the agent's egocentric frame).
        backend: where the physics and the camera run, ``cpu`` (the default) or ``warp`` (MuJoCo Warp: see
            :class:`evaaa.EvaaaEnv`); observations are numpy arrays either way.
        overrides: dotted-path changes to the level (``**{"episode.max_steps": 1000}``) or nested dicts.
    """

    metadata = {"render_modes": list(_RENDER_MODES), "render_fps": 10}

    def __init__(
        self,
        level: str = "1-1",
        modalities: Iterable[str] | str | None = None,
        render_mode: str | None = None,
        backend: str = "cpu",
        **overrides: Any,
    ):
        check_backend(backend)
        if render_mode is not None and render_mode not in _RENDER_MODES:
            raise ValueError(f"render_mode must be None or one of {list(_RENDER_MODES)}, got {render_mode!r}")
        self.level = load_level(level, overrides)
        self.render_mode = render_mode
        # seeded for real on the first reset, from the seed given there or from self.np_random
        self.sim = make_simulator(self.level, 1, modalities, seed=0, backend=backend)
        self._sim_seeded = False
        self._closed = False
        bounds = {sensor.key: sensor.bounds for sensor in self.sim.sensors}
        self.observation_space = spaces.Dict(
            {
                key: spaces.Box(0, 255, shape, np.uint8)
                if np.dtype(dtype) == np.uint8
                else spaces.Box(*(bounds[key] or (-np.inf, np.inf)), shape, np.float32)
                for key, (shape, dtype) in self.sim.observation_shapes.items()
            }
        )
        self.action_space = spaces.Discrete(NUM_ACTIONS)
        registered = load_level(level).episode.max_steps
        if self.level.episode.max_steps > registered:
            # gymnasium.make wraps the env in TimeLimit(the registered cap), which would end episodes early
            gymnasium.logger.warn(
                f"episode.max_steps = {self.level.episode.max_steps} exceeds the {registered} steps evaaa/{level}-v0 "
                f"is registered with: through gymnasium.make, also pass max_episode_steps="
                f"{self.level.episode.max_steps} (TimeLimit would end episodes at {registered})"
            )

    def __repr__(self) -> str:
        return (
            f"EvaaaGymEnv(level={self.level.name!r}, modalities={list(self.sim.modalities)}, "
            f"render_mode={self.render_mode!r}, max_steps={self.level.episode.max_steps})"
        )

    def _check_open(self) -> None:
        # a closed env has freed its renderer; bringing it back silently would hide a use-after-close bug
        if self._closed:
            raise RuntimeError(f"this EvaaaGymEnv ({self.level.name}) was closed; make a new one")

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        self._check_open()
        super().reset(seed=seed)
        if seed is not None:
            self.sim.seed(seed)
            self._sim_seeded = True
        elif not self._sim_seeded:
            self.sim.seed(int(self.np_random.integers(2**63)))
            self._sim_seeded = True
        obs = self.sim.reset()
        return _world0(obs), _info(self.sim.last_info)

    def step(self, action: int) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        self._check_open()
        # True and False are ints to Python (and to Discrete.contains) but never an intended action
        if isinstance(action, (bool, np.bool_)) or not self.action_space.contains(action):
            raise ValueError(
                f"action must be an integer in 0..{NUM_ACTIONS - 1} ({', '.join(ACTION_NAMES)}), got {action!r}"
            )
        obs, reward, terminated, truncated, info = self.sim.step(np.array([int(action)]))
        return _world0(obs), float(reward[0]), bool(terminated[0]), bool(truncated[0]), _info(info)

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            gymnasium.logger.warn("render() was called with render_mode=None; pass render_mode='rgb_array'")
            return None
        self._check_open()
        # the simulator builds its eye renderer on first use, so this works when pixels are not observed
        return _numpy(self.sim.render_eye(_ONE_WORLD)[0])

    def close(self) -> None:
        self._closed = True
        self.sim.close()


def _world0(obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    return {key: _numpy(value[0]) for key, value in obs.items()}


def _numpy(value) -> np.ndarray:
    """A numpy array (the Warp backend's frames are torch tensors on its device)."""
    return value if isinstance(value, np.ndarray) else value.cpu().numpy()


def _info(info: dict[str, np.ndarray]) -> dict[str, Any]:
    """World 0's diagnostics: one-element entries as Python scalars, the rest as arrays, plus the end's name."""
    out = {key: value[0].item() if value[0].size == 1 else value[0] for key, value in info.items()}
    out["end_type_name"] = END_TYPES[out["end_type"]]
    return out


def register_envs() -> None:
    """Register ``evaaa/<name>-v0`` for every level, with the level's step cap as ``max_episode_steps`` (the
    TimeLimit of ``gymnasium.make`` then agrees with the env's own truncation); ids already registered are left
    alone."""
    for name in level_names():
        env_id = f"evaaa/{name}-v0"
        if env_id not in gymnasium.registry:
            gymnasium.register(
                env_id,
                entry_point="evaaa.gym:EvaaaGymEnv",
                kwargs={"level": name},
                max_episode_steps=load_level(name).episode.max_steps,
            )
