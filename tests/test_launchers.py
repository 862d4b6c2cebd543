"""train.py -m through the launcher presets of conf/hydra/launcher/ (tiny budgets): submitit's local executor,
SLURM (sbatch, srun and sacct stand-ins that run each array task on this machine) and evaaa's Ray launcher on a real
local Ray cluster. The default preset (joblib) is tests/test_train.py::test_train_script_multirun_sweeps_seeds.
Needs the `cluster` extra (scripts/setup.sh installs it)."""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from helpers import ray_head
from omegaconf import OmegaConf

from evaaa_baselines import checkpoint

pytest.importorskip("ray")
pytest.importorskip("submitit")


@pytest.fixture(scope="module")
def ray_cluster(tmp_path_factory):
    """A Ray head on 127.0.0.1 with two worker CPUs; its address."""
    with ray_head(tmp_path_factory.mktemp("ray")) as address:
        yield address


FAKE_SBATCH = """#!{python}
# sbatch: runs every task of the submitted script (an array: each index) on this machine, in the background, with the
# variables SLURM sets; records its exit status for sacct
import os, pathlib, re, subprocess, sys
script = pathlib.Path(sys.argv[-1])
text = script.read_text()
state = pathlib.Path(os.environ["FAKE_SLURM"])
state.mkdir(exist_ok=True)
job = str(1000 + len(list(state.glob("*.sbatch"))))
(state / f"{{job}}.sbatch").write_text(text)
array = re.search(r"^#SBATCH --array=(\\d+)-(\\d+)", text, re.M)
for task in range(int(array[1]), int(array[2]) + 1) if array else [None]:
    name = job if task is None else f"{{job}}_{{task}}"
    env = dict(os.environ, SLURM_JOB_ID=job, SLURM_NTASKS="1", SLURM_JOB_NUM_NODES="1", SLURM_NODEID="0",
               SLURM_JOB_NODELIST="localhost", SLURM_PROCID="0", SLURM_LOCALID="0")
    if task is not None:
        env.update(SLURM_ARRAY_JOB_ID=job, SLURM_ARRAY_TASK_ID=str(task))
    (state / f"{{name}}.task").write_text("")
    # a task that `scontrol requeue` marked runs again when it ends, as SLURM requeues it
    run = (f"while :; do bash {{script}}; rc=$?; if [ -e {{state / name}}.requeue ]; then "
           f"rm {{state / name}}.requeue; echo >> {{state / name}}.requeued; continue; fi; echo $rc > {{state / name}}.rc; "
           "break; done")
    subprocess.Popen(["bash", "-c", run], env=env,
                     stdout=subprocess.DEVNULL, stderr=open(state / f"{{name}}.err", "w"), start_new_session=True)
print(f"Submitted batch job {{job}}")
"""

FAKE_SRUN = """#!{python}
# srun: the command after the options, its output and error in the files asked for (SLURM's %j %A %a %t filled in);
# its process id in <task>.pid, for a test to signal it as SLURM signals a job step
import os, pathlib, sys
task = os.environ["SLURM_JOB_ID"] + ("_" + os.environ["SLURM_ARRAY_TASK_ID"] if "SLURM_ARRAY_TASK_ID" in os.environ else "")
(pathlib.Path(os.environ["FAKE_SLURM"]) / f"{{task}}.pid").write_text(str(os.getpid()))
args, files = sys.argv[1:], {{}}
while args and args[0].startswith("--"):
    opt = args.pop(0)
    if opt in ("--output", "--error"):
        files[opt] = args.pop(0)
fill = {{"%j": os.environ["SLURM_JOB_ID"], "%A": os.environ.get("SLURM_ARRAY_JOB_ID", ""),
        "%a": os.environ.get("SLURM_ARRAY_TASK_ID", ""), "%t": "0"}}
for opt, fd in (("--output", 1), ("--error", 2)):
    if opt in files:
        path = files[opt]
        for k, v in fill.items():
            path = path.replace(k, v)
        os.dup2(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND), fd)
os.execvp(args[0], args)
"""

FAKE_SACCT = """#!{python}
# sacct -o JobID,State,NodeList --parsable2 -j ID ...: each task's state from the files sbatch keeps
import os, pathlib
state = pathlib.Path(os.environ["FAKE_SLURM"])
print("JobID|State|NodeList")
for task in sorted(state.glob("*.task")):
    rc = task.with_suffix(".rc")
    done = rc.exists() and rc.read_text().strip()
    print(f"{{task.stem}}|{{'RUNNING' if not done else 'COMPLETED' if done == '0' else 'FAILED'}}|localhost")
"""


FAKE_SCONTROL = """#!{python}
# scontrol requeue JOBID: the task runs again once it ends (sbatch's loop reads the mark)
import os, pathlib, sys
assert sys.argv[1] == "requeue", sys.argv
(pathlib.Path(os.environ["FAKE_SLURM"]) / f"{{sys.argv[2]}}.requeue").write_text("")
"""


def _fake_slurm(tmp_path: Path) -> dict[str, str]:
    """sbatch, srun, sacct, scontrol (requeue) and scancel that run SLURM jobs on this machine: the environment that
    puts them first."""
    bin_dir = tmp_path / "fake-slurm-bin"
    bin_dir.mkdir()
    scripts = {
        "sbatch": FAKE_SBATCH,
        "srun": FAKE_SRUN,
        "sacct": FAKE_SACCT,
        "scontrol": FAKE_SCONTROL,
        "scancel": "#!{python}\n",
    }
    for name, text in scripts.items():
        (bin_dir / name).write_text(text.format(python=sys.executable))
        (bin_dir / name).chmod(0o755)
    return {"PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}", "FAKE_SLURM": str(tmp_path / "fake-slurm")}


@pytest.mark.slow
@pytest.mark.parametrize("launcher", ["slurm_local", "slurm", "ray_cluster"])
def test_train_multirun_through_a_launcher_preset(tmp_path, launcher, request):
    root = Path(__file__).parents[1]
    env = {**os.environ, "HYDRA_FULL_ERROR": "1"}
    extra = []
    if launcher == "slurm":
        # SLURM itself is not here: sbatch, srun and sacct stand-ins run each array task on this machine
        env.update(_fake_slurm(tmp_path))
        extra = ["hydra.launcher.partition=debug", "hydra.launcher.cpus_per_task=1"]
    elif launcher == "ray_cluster":
        # the two-worker Ray cluster on 127.0.0.1; one CPU per run
        extra = [f"hydra.launcher.address={request.getfixturevalue('ray_cluster')}", "hydra.launcher.num_cpus=1"]
    cmd = [
        sys.executable,
        str(root / "scripts" / "train.py"),
        "-m",
        f"hydra/launcher={launcher}",
        *extra,
        "algo=ppo",
        "preset=debug",
        "logger=csv",
        "progress=false",
        "threads=1",
        "total_steps=64",
        "seed=0,1",
        f"run.root={tmp_path}",
        f"hydra.sweep.dir={tmp_path / 'sweep'}",
    ]
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=400, env=env)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    for seed in (0, 1):
        # the launchers put each job's run directory under the sweep folder
        run_dir = tmp_path / "sweep" / "1-1" / "ppo" / "all-squared-debug" / f"seed{seed}"
        assert (run_dir / "model-0-1-1.pt").exists()
    if launcher.startswith("slurm"):
        assert list((tmp_path / "sweep").rglob("*_submitted.pkl"))  # the jobs went through submitit
    if launcher == "slurm":
        # one job array of two tasks (at most 64 at once: submitit writes no more than there are), with the preset's
        # settings and the overrides
        (script,) = (tmp_path / "fake-slurm").glob("*.sbatch")
        text = script.read_text()
        assert "#SBATCH --array=0-1%2" in text and "#SBATCH --partition=debug" in text
        assert "#SBATCH --time=2880" in text and "#SBATCH --cpus-per-task=1" in text and "MUJOCO_GL=egl" in text
        assert "#SBATCH --mem=16GB" in text and "#SBATCH --signal=USR2@180" in text
    if launcher == "ray_cluster":
        # every run was a Ray task: Ray's worker prefixes its output with the task's name
        assert "(_run_one pid=" in done.stdout + done.stderr


@pytest.mark.slow
def test_a_slurm_time_limit_checkpoints_the_run_and_requeues_it_to_continue(tmp_path):
    """SIGUSR2, what submitit has SLURM send ahead of the time limit (and on pre-emption), to a task mid-training: the
    run writes its checkpoint, submitit requeues the task (scontrol requeue), and the requeued task continues the run
    from that checkpoint (the launcher adds resume=true) to its end."""
    root = Path(__file__).parents[1]
    env = {**os.environ, "HYDRA_FULL_ERROR": "1", **_fake_slurm(tmp_path)}
    state = Path(env["FAKE_SLURM"])
    cmd = [
        sys.executable,
        str(root / "scripts" / "train.py"),
        "-m",
        "hydra/launcher=slurm",
        "hydra.launcher.partition=debug",
        "hydra.launcher.cpus_per_task=1",
        "algo=ppo",
        "preset=debug",
        "logger=csv",
        "progress=false",
        "threads=1",
        "total_steps=1024",
        "checkpoint.every=100000",  # no checkpoint but the one the signal asks for (and the end's)
        "eval.every=100000",
        "seed=0",
        f"run.root={tmp_path}",
        f"hydra.sweep.dir={tmp_path / 'sweep'}",
    ]
    sweep = subprocess.Popen(cmd, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    run_dir = tmp_path / "sweep" / "1-1" / "ppo" / "all-squared-debug" / "seed0"
    try:
        deadline = time.monotonic() + 300
        while not (run_dir / "logs").exists() or not list((run_dir / "logs").rglob("*.csv")):  # it trains
            assert sweep.poll() is None and time.monotonic() < deadline, sweep.stdout.read() if sweep.stdout else ""
            time.sleep(0.2)
        (pid_file,) = state.glob("*.pid")
        os.kill(int(pid_file.read_text()), signal.SIGUSR2)
        out, _ = sweep.communicate(timeout=400)
    finally:
        if sweep.poll() is None:
            sweep.kill()
    assert sweep.returncode == 0, out[-3000:]
    (task,) = [p.stem for p in state.glob("*.task")]
    assert (state / f"{task}.requeued").read_text() == "\n"  # requeued once, through scontrol
    logs = "".join(p.read_text() for p in (tmp_path / "sweep").rglob("*_log.err"))
    stopped = re.search(r"interrupted at env step ([\d,]+) of 1-1: checkpoint written to", logs)
    assert stopped, logs[-3000:]
    assert 0 < int(stopped[1].replace(",", "")) < 1024
    # the requeued task continued that run (resume=true) to its end, its first session's overrides kept beside
    assert "resume=true" in (run_dir / ".hydra" / "overrides.yaml").read_text()
    assert "resume=true" not in (run_dir / ".hydra" / "overrides.session-1.yaml").read_text()
    assert (run_dir / "model-0-1-1.pt").exists()
    steps = checkpoint.load_checkpoint(run_dir / checkpoint.CHECKPOINT)["counters"]["steps"]
    assert steps >= 1024


@pytest.mark.slow
def test_ray_cluster_puts_runs_of_a_relative_run_root_under_the_driver_s_directory(tmp_path, ray_cluster):
    """run.root relative (the default, runs): the driver writes multirun.yaml under its own directory, and every run
    lands under that same root, not under the Ray worker's directory."""
    driver = tmp_path / "driver"
    driver.mkdir()
    root = Path(__file__).parents[1]
    relative = f"runs-{tmp_path.name}"  # were it taken from a worker's directory, a folder no other test makes
    cmd = [
        sys.executable,
        str(root / "scripts" / "train.py"),
        "-m",
        "hydra/launcher=ray_cluster",
        f"hydra.launcher.address={ray_cluster}",
        "hydra.launcher.num_cpus=1",
        "algo=ppo",
        "preset=debug",
        "logger=csv",
        "progress=false",
        "threads=1",
        "total_steps=64",
        "seed=0",
        f"run.root={relative}",
    ]
    env = {**os.environ, "HYDRA_FULL_ERROR": "1"}
    done = subprocess.run(cmd, cwd=driver, capture_output=True, text=True, timeout=400, env=env)
    strays = [p for p in {root / relative, Path.cwd() / relative} if p.exists() and not p.is_relative_to(tmp_path)]
    for stray in strays:  # the runs of the code before the fix: under the worker's directory
        shutil.rmtree(stray)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert not strays, strays
    assert (driver / relative / "multirun.yaml").exists()
    run_dir = driver / relative / "1-1" / "ppo" / "all-squared-debug" / "seed0"
    assert (run_dir / "model-0-1-1.pt").exists()
    assert OmegaConf.load(run_dir / ".hydra" / "config.yaml").run.root == str(driver / relative)
