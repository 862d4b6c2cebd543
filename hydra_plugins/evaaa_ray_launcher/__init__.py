"""evaaa's Hydra launcher for Ray: ``train.py -m hydra/launcher=ray_cluster`` runs every job of a sweep as a Ray task.

Hydra's own Ray launcher (hydra-ray-launcher) cannot be installed beside evaaa's pinned packages (it needs
cloudpickle < 3, joblib >= 1.4 needs cloudpickle >= 3), so this small plugin does the same for the one thing evaaa
needs: each job a task with the CPUs and GPUs the preset asks for, on a Ray instance of this machine or a cluster.
It lives in the ``hydra_plugins`` namespace (Hydra's rule for launchers) and train.py registers it
(``evaaa_baselines.config.register_launchers``); the preset is conf/hydra/launcher/ray_cluster.yaml.

The package also holds evaaa's two subclasses of Hydra's submitit launchers (submitit_launchers.py: a job requeued on
a SLURM time limit continues its run with resume=true), for conf/hydra/launcher/slurm.yaml and slurm_local.yaml.
"""
