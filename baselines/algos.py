"""The algorithms: an ``algo.name`` -> the module that builds and trains it.

An algorithm is one module and one config.  The module has the four functions of :class:`Algorithm`; the config is
``conf/algo/<name>.yaml``, whose ``name`` is the algorithm's name.  The module (or subpackage) of this package
named like the algorithm is the one (``dqn.py`` for ``algo=dqn``, ``dreamer/`` for ``algo=dreamer``); a variant that
is another's code with a config of its own is named in :data:`VARIANTS` (``ppo_lstm`` is PPO's code, the LSTM chosen
by its config).  A module outside this package joins with :func:`register`.  Modules are imported when first asked for,
so they may import the modules that look them up (``training``, ``policies``, ``rollout``) without an import cycle.
"""

from __future__ import annotations

import importlib
import importlib.util
import re
from collections.abc import Mapping, Sequence
from types import ModuleType
from typing import TYPE_CHECKING, Any, Protocol

from .paths import CONF_DIR

if TYPE_CHECKING:
    from omegaconf import DictConfig
    from tensordict.nn import TensorDictModuleBase
    from torch import nn
    from torchrl.envs import Transform

    from .run import Run


class Algorithm(Protocol):
    """What the training loop and the checkpoint loader call."""

    def make_model(self, cfg: DictConfig, obs_shapes: Mapping[str, Sequence[int]]) -> nn.Module:
        """The networks, from the ``algo`` config and the per-world shapes of the enabled observation keys."""

    def make_transforms(self, cfg: DictConfig, obs_keys: Sequence[str], model: nn.Module) -> list[Transform]:
        """Fresh env transforms the model expects (frame stacking, recurrent state ...)."""

    def make_policy(self, model: nn.Module) -> TensorDictModuleBase:
        """The acting policy of a trained model (what evaluations run)."""

    def train(self, run: Run) -> None:
        """One stage of training, driving :class:`~evaaa_baselines.run.Run` until ``run.done``."""


#: the functions every algorithm module defines
FUNCTIONS = ("make_model", "make_transforms", "make_policy", "train")
_NAME = re.compile(r"[a-z][a-z0-9_]*")
_registered: dict[str, Any] = {}
#: variants: ``algo.name`` -> the module of this package that trains it (its own config says how it differs)
VARIANTS = {"ppo_lstm": "ppo", "dreamer_xs": "dreamer"}


def register(name: str, module: ModuleType | Any) -> None:
    """Make ``module`` (anything with the functions of :class:`Algorithm`) the algorithm ``algo.name=name``: for an
    algorithm that lives outside this package.  Its config still goes to ``conf/algo/<name>.yaml``."""
    _check(name, module)
    _registered[name] = module


def names() -> list[str]:
    """The algorithms there are configs for (``conf/algo/*.yaml``), and those registered."""
    configs = [p.stem for p in (CONF_DIR / "algo").glob("*.yaml")] if (CONF_DIR / "algo").is_dir() else []
    return sorted({*configs, *_registered})


def algorithm(name: str) -> Algorithm:
    """The module of the algorithm ``name`` (a registered one, or this package's module of that name).

    Raises ``ValueError`` naming the known algorithms when there is no such algorithm (also for a checkpoint's
    ``algo`` field: only modules of this package or registered ones are ever imported)."""
    if name in _registered:
        return _registered[name]
    if (
        not isinstance(name, str)
        or not _NAME.fullmatch(name)
        or importlib.util.find_spec(f"{__package__}.{VARIANTS.get(name, name)}") is None
    ):
        raise ValueError(f"unknown algo {name!r}; known: {', '.join(names())}")
    module = importlib.import_module(f"{__package__}.{VARIANTS.get(name, name)}")
    _check(name, module)
    return module


def _check(name: str, module: Any) -> None:
    missing = [f for f in FUNCTIONS if not callable(getattr(module, f, None))]
    if missing:
        raise ValueError(
            f"algo {name!r}: {getattr(module, '__name__', module)!r} is not an algorithm: it lacks "
            f"{', '.join(missing)} (an algorithm module defines {', '.join(FUNCTIONS)})"
        )
