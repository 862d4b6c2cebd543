"""Train a baseline: ``python scripts/train.py algo=<dqn|ppo|ppo_lstm|dreamer|dreamer_xs> level=<level|curriculum>``.

Hydra composes conf/config.yaml with its groups (algo, level, modality, reward, logger, preset); the run directory
is ``runs/<level>/<algo>/<modality>-<reward>/seed<seed>`` (``run.root``, ``run.name``), for single runs and for
sweeps (``-m seed=0,1,2``) alike, so the same command with ``resume=true`` continues a killed run.  See
docs/training.md.

    python scripts/train.py algo=ppo level=1-1
    python scripts/train.py algo=dqn level=curriculum resume=true
    python scripts/train.py -m algo=dqn,ppo seed=0,1 preset=debug logger=csv
"""

from __future__ import annotations

import faulthandler
import logging
import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing

import evaaa  # noqa: E402,F401  (sets MUJOCO_GL before mujoco loads)
from baselines import train  # noqa: E402
from baselines.runtime import DeviceError  # noqa: E402
from baselines.config import CONF_DIR, register_levels  # noqa: E402

register_levels()
# a crash in native code (MuJoCo, OpenGL, torch) leaves every thread's Python stack in the run's output
faulthandler.enable(all_threads=True)


@hydra.main(config_path=str(CONF_DIR), config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    run_dir = HydraConfig.get().runtime.output_dir
    try:
        train(cfg, run_dir)
    except DeviceError as err:  # a setting, not a bug: one line, not a traceback
        print(f"train.py: {err}", file=sys.stderr)
        raise SystemExit(2) from None
    except KeyboardInterrupt:
        logging.getLogger(__name__).warning("interrupted: the same command with resume=true continues %s from its "
                                            "last checkpoint", run_dir)
        raise SystemExit(130) from None


if __name__ == "__main__":
    main()
