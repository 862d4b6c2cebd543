"""Baselines for evaaa on TorchRL — DQN, PPO, PPO+LSTM and DreamerV3 — trained by ``scripts/train.py``.

An algorithm is one module (``dqn.py``, ``ppo.py``; PPO+LSTM is ``ppo.py`` with its own config) or package (``dreamer/``)
providing ``make_model(cfg, obs_shapes)``, ``make_transforms(cfg, obs_keys, model)``, ``make_policy(model)`` and
``train(run)``, plus its config ``conf/algo/<name>.yaml``; :func:`~.algos.algorithm` finds it by ``algo.name``.
:func:`load_policy` turns a checkpoint back into a policy; :func:`evaluate` runs deterministic episodes.
"""

from __future__ import annotations

import importlib

#: what ``from evaaa_baselines import X`` gives, by module: imported when first used, so that a command's
#: ``--help`` and its argument checks run before torch loads
_EXPORTS = {
    "algorithm": "algos",
    "register": "algos",
    "LoadedPolicy": "policies",
    "load_policy": "policies",
    "EvalResult": "rollout",
    "evaluate": "rollout",
    "train": "training",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        value = getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *_EXPORTS})
