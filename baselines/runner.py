"""A training run from a composed config: its stages (one level, or the curriculum's levels in order), a fresh start
or the resume of a killed run, and the logger the stages share.

``scripts/train.py`` calls :func:`train` with Hydra's run directory; tests call it with a config from Hydra's
compose API.  A run directory holds one run: starting again where a checkpoint exists needs ``resume=true``.
"""

from __future__ import annotations

import logging
from pathlib import Path

import torch
from omegaconf import DictConfig, OmegaConf
from torchrl.record.loggers import Logger, get_logger

from .checkpoint import CHECKPOINT, load_checkpoint, seed_everything
from .config import observation_keys, stages
from .runtime import Run, resolve_device

log = logging.getLogger(__name__)


def make_logger(cfg: DictConfig, run_dir: Path, state: dict | None) -> Logger:
    """TorchRL's logger of ``cfg.logger.backend`` writing under ``run_dir`` (``state``: continue a checkpointed one)."""
    backend = cfg.logger.backend
    if backend == "wandb":
        kwargs = {"wandb_kwargs": {"offline": cfg.logger.offline, "project": cfg.logger.project}}
        name = cfg.run.name  # a W&B run name; its files go to <run_dir>/wandb
    else:
        kwargs, name = {}, "logs"  # a sub-directory of the run directory
    return get_logger(backend, str(run_dir), name, state_dict=state, **kwargs)


def flat_hparams(cfg: DictConfig) -> dict[str, int | float | str | bool]:
    """The config as ``{"algo.lr": 0.0001, ...}`` with scalar values, as every logger's ``log_hparams`` accepts."""
    flat: dict[str, int | float | str | bool] = {}

    def visit(node, prefix: str) -> None:
        if isinstance(node, dict):
            for key, value in node.items():
                visit(value, f"{prefix}{key}.")
        else:
            flat[prefix[:-1]] = node if isinstance(node, (int, float, str, bool)) else str(node)

    visit(OmegaConf.to_container(cfg, resolve=True), "")
    return flat


def _check_same_run(state: dict, cfg: DictConfig, plan: list) -> None:
    """Refuse to resume a checkpoint of a different experiment; note the settings that changed."""
    saved = state["config"]
    expected = {
        "algo": (state["algo"], cfg.algo.name),
        "observation keys": (list(state["obs_keys"]), list(observation_keys(cfg))),
        "levels": ([s["level"] for s in saved["stages"]], [s.level for s in plan]),
        "seed": (saved["seed"], cfg.seed),
        "env.num_envs": (state["num_envs"], cfg.env.num_envs),
    }
    wrong = {k: v for k, v in expected.items() if v[0] != v[1]}
    if wrong:
        detail = "; ".join(f"{k}: checkpoint {a}, now {b}" for k, (a, b) in wrong.items())
        raise ValueError(f"cannot resume: the checkpoint belongs to another experiment ({detail})")
    now, before = flat_hparams(cfg), flat_hparams(OmegaConf.create(saved))
    changed = sorted(k for k in now.keys() | before.keys()
                     if k != "resume" and not k.startswith("stages") and now.get(k) != before.get(k))
    if changed:
        log.warning("resuming with changed settings in: %s", ", ".join(changed))


def train(cfg: DictConfig, run_dir: str | Path) -> Path:
    """Train the configured algorithm on the configured level(s) in ``run_dir``; returns the run directory.

    Writes ``checkpoint.pt`` (latest state, every ``checkpoint.every`` env steps and at the end of each stage),
    ``model-<stage>-<level>.pt`` (the weights at the end of each stage), ``episodes.csv``, ``eval.csv`` and the
    logger's files.  With ``resume=true`` a run with a checkpoint continues exactly where that checkpoint was taken.
    """
    from . import ALGOS

    resolve_device(cfg.get("device", "auto"))  # a device this machine lacks fails here, before anything is written
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    if cfg.algo.name not in ALGOS:
        raise ValueError(f"unknown algo {cfg.algo.name!r}; known: {', '.join(ALGOS)}")
    algo = ALGOS[cfg.algo.name]
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    plan = stages(cfg)

    latest = run_dir / CHECKPOINT
    state = None
    if latest.exists():
        if not cfg.resume:
            raise FileExistsError(f"{run_dir} already holds a run (checkpoint.pt): pass resume=true to continue it, "
                                  "or choose another run.name / run.root")
        state = load_checkpoint(latest)
        _check_same_run(state, cfg, plan)
        log.info("resuming %s at stage %d (%s), env step %d", run_dir, state["stage"], state["level"],
                 state["counters"]["steps"])
    else:
        if cfg.resume:
            log.info("nothing to resume in %s: starting afresh", run_dir)
        seed_everything(cfg.seed)

    # the stage plan goes into the saved config, so a resume can check it trains the same levels in the same order
    cfg = cfg.copy()
    OmegaConf.set_struct(cfg, False)
    cfg.stages = [{"level": s.level, "budget": s.budget} for s in plan]

    logger = make_logger(cfg, run_dir, state["logs"]["logger"] if state else None)
    if state is None:
        logger.log_hparams(flat_hparams(cfg))
    weights = None
    try:
        for stage in plan[state["stage"] if state else 0:]:
            run = Run(cfg, run_dir, stage, algo, logger, resume=state, init_weights=weights,
                      fresh_logs=state is None and stage.index == 0)
            try:
                algo.train(run)
            finally:
                run.close()
            weights = run.model.state_dict()
            state = None
    finally:
        logger.shutdown()
    return run_dir
