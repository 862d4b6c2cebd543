"""evaaa: a TorchRL-native benchmark for homeostatic, internally motivated reinforcement learning.

>>> import evaaa
>>> env = evaaa.make_env("1-1", num_envs=4, seed=0)
>>> td = env.rollout(100)
"""

from __future__ import annotations

import os

# Headless rendering: these must be set before mujoco is first imported (MuJoCo reads MUJOCO_GL at import, Mesa
# reads LP_NUM_THREADS when the context is made).  LP_NUM_THREADS=0 makes llvmpipe draw in the calling thread,
# which is faster for 64x64 frames and keeps parallel workers from fighting over cores.
os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])
os.environ.setdefault("LP_NUM_THREADS", "0")

import logging  # noqa: E402

import mujoco  # noqa: E402

from .backends import BACKENDS  # noqa: E402
from .level import Level, LevelError  # noqa: E402
from .level_files import LEVELS, TESTBEDS, load_level, register_level  # noqa: E402
from .physiology import END_TYPES, EV_NAMES, REWARDS  # noqa: E402
from .sensors import MODALITIES  # noqa: E402
from .sim import ACTION_NAMES  # noqa: E402
from .worlds import WORLD_SETS  # noqa: E402

__version__ = "0.1.0"

#: imported when first used (they load torch, TorchRL and tensordict): ``import evaaa`` alone stays light, so
#: the gymnasium adapter and the scripts' ``--help`` do not wait for torch
_LAZY = {"EvaaaEnv": "env", "make_env": "env"}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})


__all__ = [
    "ACTION_NAMES",
    "BACKENDS",
    "END_TYPES",
    "EV_NAMES",
    "EvaaaEnv",
    "LEVELS",
    "Level",
    "LevelError",
    "MODALITIES",
    "REWARDS",
    "TESTBEDS",
    "WORLD_SETS",
    "load_level",
    "make_env",
    "register_level",
]


def _mujoco_warning(message: str) -> None:
    logging.getLogger("mujoco").warning("MuJoCo: %s", message.strip())


# MuJoCo's own warning handler also appends every warning to MUJOCO_LOG.TXT in the working directory; send them
# to Python's logging instead (stderr unless configured), unless the program installed a handler of its own
if mujoco.get_mju_user_warning() is None:
    mujoco.set_mju_user_warning(_mujoco_warning)

# gymnasium.make("evaaa/<level>-v0") should work after a plain `import evaaa`
from .gym import register_envs  # noqa: E402

register_envs()
