"""Baselines for evaaa on TorchRL — DQN, PPO, PPO+LSTM and DreamerV3 — trained by ``scripts/train.py``.

``ALGOS`` maps an ``algo.name`` to its module; every module provides ``make_model(cfg, obs_shapes)``,
``make_transforms(cfg, obs_keys, model)``, ``make_policy(model)`` and ``train(run)``.  :func:`load_policy` turns a
checkpoint back into a policy; :func:`evaluate` runs deterministic episodes.
"""

from . import dqn, dreamer, ppo

ALGOS = {"dqn": dqn, "ppo": ppo, "ppo_lstm": ppo, "dreamer": dreamer, "dreamer_xs": dreamer}

from .evaluation import EvalResult, LoadedPolicy, evaluate, load_policy  # noqa: E402
from .runner import train  # noqa: E402

__all__ = ["ALGOS", "EvalResult", "LoadedPolicy", "evaluate", "load_policy", "train"]
