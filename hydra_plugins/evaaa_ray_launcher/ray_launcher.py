"""A Hydra Launcher that runs every job of a sweep as a Ray task (see the package docstring).

Hydra's Launcher API: ``setup`` hands the launcher the sweep's config, the task function and Hydra's context;
``launch`` gets one override list per job and returns one ``JobReturn`` per job, in order. Each task loads its job's
config from the sweep config and its overrides and runs it with ``hydra.core.utils.run_job``, as Hydra's joblib and
submitit launchers do in their worker processes. Ray is imported when a sweep starts, not when Hydra scans plugins.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hydra.core.hydra_config import HydraConfig
from hydra.core.singleton import Singleton
from hydra.core.utils import JobReturn, configure_log, filter_overrides, run_job, setup_globals
from hydra.plugins.launcher import Launcher
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig, OmegaConf, open_dict

log = logging.getLogger(__name__)


def _run_one(
    idx: int,
    overrides: Sequence[str],
    hydra_context: HydraContext,
    config: DictConfig,
    task_function: TaskFunction,
    singleton_state: dict[Any, Any],
    driver_cwd: str,
) -> JobReturn:
    """One job of the sweep, in a Ray worker: its config, its run directory, the task function. A relative
    ``run.root`` or ``hydra.sweep.dir`` is taken from ``driver_cwd``, the directory train.py was started in, as the
    driver took it for the sweep's multirun.yaml (a worker's own directory is Ray's, or another node's)."""
    setup_globals()
    Singleton.set_state(singleton_state)
    sweep_config = hydra_context.config_loader.load_sweep_config(config, list(overrides))
    with open_dict(sweep_config):
        sweep_config.hydra.job.id = f"{sweep_config.hydra.job.name}_{idx}"
        sweep_config.hydra.job.num = idx
        for key in ("run.root", "hydra.sweep.dir"):
            value = OmegaConf.select(sweep_config, key)
            if value is not None and not Path(str(value)).is_absolute():
                OmegaConf.update(sweep_config, key, str(Path(driver_cwd) / str(value)))
    HydraConfig.instance().set_config(sweep_config)
    return run_job(
        hydra_context=hydra_context,
        config=sweep_config,
        task_function=task_function,
        job_dir_key="hydra.sweep.dir",
        job_subdir_key="hydra.sweep.subdir",
    )


class RayLauncher(Launcher):
    """Every job a Ray task: ``ray.init(address=address, **init)``, ``num_cpus``/``num_gpus`` per task, and
    ``max_retries`` tries again of a task whose worker was lost (pass ``resume=true`` so a retried training continues
    from its checkpoint)."""

    def __init__(
        self,
        address: str | None = None,
        num_cpus: float = 1,
        num_gpus: float = 0,
        max_retries: int = 0,
        init: dict[str, Any] | None = None,
    ) -> None:
        self.address = address
        self.num_cpus = num_cpus
        self.num_gpus = num_gpus
        self.max_retries = max_retries
        self.init = OmegaConf.to_container(init, resolve=True) if OmegaConf.is_config(init) else dict(init or {})
        self.config: DictConfig | None = None
        self.task_function: TaskFunction | None = None
        self.hydra_context: HydraContext | None = None

    def setup(self, *, hydra_context: HydraContext, task_function: TaskFunction, config: DictConfig) -> None:
        self.config = config
        self.task_function = task_function
        self.hydra_context = hydra_context

    def launch(self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int) -> Sequence[JobReturn]:
        try:
            import ray
        except ImportError:
            raise ImportError(
                "hydra/launcher=ray_cluster needs Ray: pip install -e '.[cluster]' (scripts/setup.sh installs it)"
            ) from None

        setup_globals()
        assert self.config is not None and self.task_function is not None and self.hydra_context is not None
        configure_log(self.config.hydra.hydra_logging, self.config.hydra.verbose)
        sweep_dir = Path(str(self.config.hydra.sweep.dir))
        sweep_dir.mkdir(parents=True, exist_ok=True)
        started_here = not ray.is_initialized()
        if started_here:
            ray.init(address=self.address, **self.init)
        where = self.address or "a Ray instance of this machine"
        log.info(
            f"Ray ({where}) is launching {len(job_overrides)} jobs, {self.num_cpus} CPUs and {self.num_gpus} GPUs each"
        )
        log.info(f"Launching jobs, sweep output dir : {sweep_dir}")
        for idx, overrides in enumerate(job_overrides):
            log.info(f"\t#{initial_job_idx + idx} : {' '.join(filter_overrides(overrides))}")
        task = ray.remote(num_cpus=self.num_cpus, num_gpus=self.num_gpus, max_retries=self.max_retries)(_run_one)
        singleton_state = Singleton.get_state()
        driver_cwd = str(self.config.hydra.runtime.cwd)  # where relative run roots are, for every worker
        refs = [
            task.remote(
                initial_job_idx + idx,
                list(overrides),
                self.hydra_context,
                self.config,
                self.task_function,
                singleton_state,
                driver_cwd,
            )
            for idx, overrides in enumerate(job_overrides)
        ]
        try:
            return list(ray.get(refs))
        finally:
            if started_here:
                ray.shutdown()
