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
from baselines.config import CONF_DIR, ConfigError, compose_checked, help_text, job_overrides, register_levels  # noqa: E402,E501

register_levels()
# a crash in native code (MuJoCo, OpenGL, torch) leaves every thread's Python stack in the run's output
faulthandler.enable(all_threads=True)


@hydra.main(config_path=str(CONF_DIR), config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    run_dir = HydraConfig.get().runtime.output_dir
    try:
        train(cfg, run_dir)
    except KeyboardInterrupt:
        logging.getLogger(__name__).warning("interrupted: the same command with resume=true continues %s from its "
                                            "last checkpoint", run_dir)
        raise SystemExit(130) from None


def check_command_line(argv: list[str]) -> None:
    """Before Hydra starts (and writes anything): ``--help`` lists every key; a malformed value, unknown key or
    option is one line naming it, exit status 2.  Every job of a sweep is composed and checked."""
    from hydra import initialize_config_dir
    from hydra._internal.utils import get_args_parser

    args = get_args_parser().parse_args(argv)  # Hydra's own flags, parsed as Hydra will (bad flags exit 2 here)
    if args.hydra_help or args.info or args.shell_completion:
        return
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        try:
            if args.help:
                print(help_text(args.overrides, "train.py", __doc__.split("\n\n")[0]))
                raise SystemExit(0)
            for job in job_overrides(args.overrides, args.multirun):
                compose_checked(job)
        except ConfigError as err:
            print(f"train.py: error: {err}", file=sys.stderr)
            raise SystemExit(2) from None


if __name__ == "__main__":
    check_command_line(sys.argv[1:])
    main()
