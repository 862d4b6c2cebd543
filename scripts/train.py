"""Train a baseline: ``python scripts/train.py algo=<dqn|ppo|ppo_lstm|dreamer|dreamer_xs> level=<level|curriculum>``.

Hydra composes conf/config.yaml with its groups (algo, level, modality, reward, logger, preset); the run directory
is ``runs/<level>/<algo>/<modality>-<reward>/seed<seed>`` (``run.root``, ``run.name``; a preset adds its name, e.g.
``all-squared-debug``), for single runs and for sweeps (``-m seed=0,1,2``) alike, so the same command with
``resume=true`` continues a killed run.  A folder that already holds a run is never overwritten: the command is
refused (in one line, changing nothing) unless it says ``resume=true`` or ``start_over=true``.  Ctrl-C writes a
checkpoint after the gradient step (DreamerV3) or iteration under way and stops; a second Ctrl-C stops within
seconds.  SIGTERM and SIGUSR2 stop a run as the first Ctrl-C does; in a SLURM job of ``hydra/launcher=slurm``, SIGUSR2
(submitit's time-limit and pre-emption signal) then has submitit requeue the job, which continues with resume=true.
A finished run prints its folder, its final evaluation beside the random and stand-still agents' survival on the
same worlds, and its model last.  See docs/training.md.

    python scripts/train.py algo=ppo level=1-1
    python scripts/train.py algo=dqn level=curriculum resume=true
    python scripts/train.py -m algo=dqn,ppo seed=0,1 preset=debug logger=csv
"""

from __future__ import annotations

import os
import signal
import sys


def _stop_before_start(signum, frame):
    # Ctrl-C while no run is training (libraries loading, config being composed): no run has anything unsaved
    # (baselines/training.py handles Ctrl-C while a run trains)
    print("train.py: interrupted while no run was training; nothing was lost", file=sys.stderr, flush=True)
    os._exit(130)


_sweep_stopping = False


def _stop_sweep(signum, frame):
    # a sweep's parent process: its jobs (other processes, or this one between jobs) get the same Ctrl-C from the
    # terminal and each stops after writing a checkpoint; exiting here at once would leave them orphaned
    global _sweep_stopping
    if _sweep_stopping:
        raise KeyboardInterrupt
    _sweep_stopping = True
    print(
        "train.py: Ctrl-C: the sweep stops once its running jobs have written their checkpoints (Ctrl-C again to "
        "stop at once)",
        file=sys.stderr,
        flush=True,
    )


def _requeue_through_submitit(stopped: BaseException) -> None:
    """A run stopped by SIGUSR2 in a submitit job (hydra/launcher=slurm, slurm_local): its checkpoint is written, and
    submitit's own handler of that signal — which the training's handler stood in for while it ran — now does what
    it does on a time limit or pre-emption: asks the launcher for the job's checkpoint (``checkpoint()``: the same
    job with resume=true, hydra_plugins/evaaa_ray_launcher/submitit_launchers.py), requeues it and exits."""
    if signal.SIGUSR2 not in getattr(stopped, "signals", ()):
        return
    submitit = sys.modules.get("submitit")
    handler = signal.getsignal(signal.SIGUSR2)
    if submitit is not None and isinstance(
        getattr(handler, "__self__", None), submitit.core.job_environment.SignalHandler
    ):
        handler(signal.SIGUSR2, None)


signal.signal(signal.SIGINT, _stop_before_start)  # first, so that even the imports below stop in one line

import faulthandler  # noqa: E402

import hydra  # noqa: E402
from hydra.core.hydra_config import HydraConfig  # noqa: E402
from omegaconf import DictConfig, OmegaConf  # noqa: E402

import evaaa  # noqa: E402,F401  (sets MUJOCO_GL before mujoco loads)
from evaaa.records import DISK_ERRNOS, DiskError  # noqa: E402
from evaaa_baselines.cli.training import check_command_line  # noqa: E402
from evaaa_baselines.config import register_launchers, register_levels  # noqa: E402
from evaaa_baselines.paths import CONF_DIR  # noqa: E402

register_levels()
register_launchers()
# a crash in native code (MuJoCo, OpenGL, torch) leaves every thread's Python stack in the run's output
faulthandler.enable(all_threads=True)


@hydra.main(config_path=str(CONF_DIR), config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    if _sweep_stopping:  # Ctrl-C between two jobs of a sweep run in this process
        raise SystemExit(130)
    # the training code (torch, TorchRL) loads here, once --help and the command line's checks have passed
    from evaaa_baselines import train
    from evaaa_baselines.checkpoint import CheckpointError
    from evaaa_baselines.devices import DeviceError
    from evaaa_baselines.run import Interrupted
    from evaaa_baselines.training import RunRefused, reference_survival, summary

    hydra_cfg = HydraConfig.get()
    # what Hydra would have written to .hydra/ itself (conf/config.yaml: output_subdir null)
    records = {
        "config.yaml": cfg,
        "hydra.yaml": OmegaConf.create({"hydra": hydra_cfg}),
        "overrides.yaml": OmegaConf.create(list(hydra_cfg.overrides.task)),
    }
    try:
        run_dir = train(cfg, hydra_cfg.runtime.output_dir, records=records)
        # the final evaluation's number beside random's and stand-still's on the same worlds (a few seconds)
        print(summary(cfg, run_dir, beside=reference_survival(cfg, run_dir)), flush=True)
    except (RunRefused, CheckpointError) as err:
        # printed, not logged: logging would append to the existing run's log file
        print(f"train.py: {err}", file=sys.stderr, flush=True)
        raise SystemExit(1) from None
    except DeviceError as err:  # a setting, not a bug: one line, not a traceback
        print(f"train.py: {err}", file=sys.stderr, flush=True)
        raise SystemExit(2) from None
    except Interrupted as err:
        print(f"train.py: {err}", file=sys.stderr, flush=True)
        _requeue_through_submitit(err)  # in a submitit job stopped by SIGUSR2: requeued, and exits there
        raise SystemExit(130) from None
    except OSError as err:  # a full or read-only disk: one line; what was written before stays as it was
        if err.errno not in DISK_ERRNOS:
            raise
        where = err if isinstance(err, DiskError) else DiskError(err.filename or hydra_cfg.runtime.output_dir, err)
        print(
            f"train.py: {where}; the run's earlier files are intact (resume=true continues from its last "
            "checkpoint once the disk takes writes)",
            file=sys.stderr,
            flush=True,
        )
        raise SystemExit(1) from None


if __name__ == "__main__":
    check_command_line(sys.argv[1:], __doc__)  # --help, and a malformed override: before Hydra writes anything
    if {"-m", "--multirun"} & set(sys.argv[1:]):
        signal.signal(signal.SIGINT, _stop_sweep)
    try:
        main()
    except KeyboardInterrupt:  # a second Ctrl-C in a sweep's parent process
        print(
            "train.py: sweep stopped at once; each job resumes from its last checkpoint, if it has one, with "
            "resume=true",
            file=sys.stderr,
            flush=True,
        )
        raise SystemExit(130) from None
