"""Baselines for evaaa on TorchRL — DQN, PPO, PPO+LSTM and DreamerV3 — trained by ``scripts/train.py``.

An algorithm is one module (``dqn.py``, ``ppo.py``, ``ppo_lstm.py``, ``dreamer_xs.py``) or package (``dreamer/``)
providing ``make_model(cfg, obs_shapes)``, ``make_transforms(cfg, obs_keys, model)``, ``make_policy(model)`` and
``train(run)``, plus its config ``conf/algo/<name>.yaml``; :func:`~.algos.algorithm` finds it by ``algo.name``.
:func:`load_policy` turns a checkpoint back into a policy; :func:`evaluate` runs deterministic episodes.
"""

from .algos import algorithm, register
from .evaluation import EvalResult, LoadedPolicy, evaluate, load_policy
from .runner import train

__all__ = ["EvalResult", "LoadedPolicy", "algorithm", "evaluate", "load_policy", "register", "train"]
