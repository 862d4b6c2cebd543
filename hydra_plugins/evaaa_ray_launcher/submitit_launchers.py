"""Hydra's submitit launchers (hydra-submitit-launcher) with one change: a job that submitit requeues — on SLURM's
time-limit or pre-emption signal, SIGUSR2 — continues its run (resume=true) instead of repeating its command.

The launcher is the callable submitit runs in every job, and submitit's requeue asks it for the job's checkpoint:
``checkpoint(*args)``, a ``DelayedSubmission`` that is submitted again in the job's place (submitit's checkpointing,
``submitit.helpers.Checkpointable``'s protocol). Hydra's returns the same call; these return it with ``resume=true``
in the job's overrides (and without ``start_over=true``, which would move the checkpointed run aside). The training
itself writes its checkpoint first: scripts/train.py stops the run on SIGUSR2 as on Ctrl-C, then hands the signal to
submitit. conf/hydra/launcher/slurm.yaml and slurm_local.yaml name these classes.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from hydra_plugins.hydra_submitit_launcher import submitit_launcher

#: overrides a requeued job drops: it continues its run with resume=true
_REPLACED = ("resume", "start_over")


def resumed(overrides: Sequence[str]) -> list[str]:
    """``overrides`` of a job that continues its run: without resume= and start_over=, with ``resume=true``."""
    kept = [o for o in overrides if o.split("=", 1)[0].lstrip("+~") not in _REPLACED]
    return [*kept, "resume=true"]


class _Resuming:
    def checkpoint(self, sweep_overrides: Sequence[str], *args: Any, **kwargs: Any) -> Any:
        """The job again, continuing its run from the checkpoint the training wrote (submitit requeues it)."""
        return super().checkpoint(resumed(sweep_overrides), *args, **kwargs)  # type: ignore[misc]


class SlurmLauncher(_Resuming, submitit_launcher.SlurmLauncher):
    """hydra/launcher=slurm: Hydra's SLURM launcher whose requeued jobs continue their runs."""


class LocalLauncher(_Resuming, submitit_launcher.LocalLauncher):
    """hydra/launcher=slurm_local: Hydra's submitit-local launcher whose requeued jobs continue their runs."""
