"""The Hydra side of training: where the configs live, the ``level`` options taken from evaaa, and the values the
training code derives from a composed config (observation keys, env overrides, curriculum stages).

Every level and testbed evaaa lists is a ``level=<name>`` option without a file to keep in sync: :func:`register_levels`
stores one ``{name, overrides}`` node per name in Hydra's ConfigStore.  Files in ``conf/level/`` add options
beside them (``curriculum.yaml``) and would take precedence over a registered name.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hydra.core.config_store import ConfigStore
from omegaconf import DictConfig, OmegaConf

import evaaa

CONF_DIR = Path(__file__).resolve().parents[1] / "conf"


def register_levels() -> None:
    """Make ``level=<name>`` available for every name in ``evaaa.LEVELS + evaaa.TESTBEDS``."""
    store = ConfigStore.instance()
    for name in (*evaaa.LEVELS, *evaaa.TESTBEDS):
        store.store(group="level", name=name, node={"name": name, "overrides": {}})


@dataclass(frozen=True)
class Stage:
    """One level trained for ``budget`` env steps; a direct run has one stage, a curriculum several."""

    index: int
    level: str
    budget: int


def stages(cfg: DictConfig) -> list[Stage]:
    """The stages of a run: the level alone, or the curriculum's levels in order (default: ``evaaa.LEVELS``)."""
    if "stages" not in cfg.level:
        return [Stage(0, cfg.level.name, int(cfg.total_steps))]
    names = list(cfg.level.stages) if cfg.level.stages is not None else list(evaaa.LEVELS)
    unknown = [n for n in names if n not in (*evaaa.LEVELS, *evaaa.TESTBEDS)]
    if unknown or not names:
        raise ValueError(f"curriculum stages must be names from evaaa.LEVELS/TESTBEDS, got {names}")
    return [Stage(i, name, int(cfg.level.stage_steps)) for i, name in enumerate(names)]


def observation_keys(cfg: DictConfig) -> tuple[str, ...]:
    """The enabled observation keys, in evaaa's canonical order."""
    unknown = set(cfg.modality.enabled) - set(evaaa.MODALITIES)
    if unknown:
        raise ValueError(f"modality.enabled names unknown keys {sorted(unknown)}; known: {', '.join(evaaa.MODALITIES)}")
    keys = tuple(k for k in evaaa.MODALITIES if cfg.modality.enabled.get(k, False))
    if not keys:
        raise ValueError(f"modality '{cfg.modality.name}' enables no observation key")
    return keys


def env_overrides(cfg: DictConfig) -> dict[str, Any]:
    """Level-field overrides for ``evaaa.make_env``: the level option's, the reward's, then ``env.overrides``."""
    # a reward option names a level reward function, or lists the level's reward fields it sets under ``overrides``
    reward = cfg.reward.get("overrides") or {"name": cfg.reward.name}
    layers = [OmegaConf.to_container(cfg.level.overrides, resolve=True), {"reward": reward},
              OmegaConf.to_container(cfg.env.overrides, resolve=True)]
    return OmegaConf.to_container(OmegaConf.merge(*layers))
