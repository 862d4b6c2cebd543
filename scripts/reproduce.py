"""Run the paper's experiments as a protocol of named cells, resumably: plan them, run what is not done.

A protocol (``conf/protocol/<name>.yaml``, or a path) expands into cells — a training run, the evaluations of one
model, a reference agent's evaluation, the report — each a subprocess of scripts/train.py, evaluate.py or report.py
with EVAAA_THREADS and threads set as the protocol says. ``plan=true`` prints every cell with its status (done,
partial, todo), estimated CPU-minutes and command (a GPU protocol: its plan in GPU-hours); without it the cells not
yet done run — ``jobs`` at a time on this machine, or as Ray tasks or SLURM jobs (``executor=ray|slurm``) — each once
the models it needs exist, with a log per cell under ``root/logs``. Killed, the same command continues where it
stopped: a started training run continues (resume=true), an unfinished evaluation's folder is moved aside
(``<out>.partial-<UTC time>``) and the evaluation run again; a training that has to start from zero (its models
and checkpoints gone, as on a fresh clone) has the evaluations made of its old models moved aside and made again.
See docs/reports.md.
"""

from __future__ import annotations

import fcntl
import os
import sys
from dataclasses import dataclass
from pathlib import Path

from evaaa_baselines import cli
from evaaa_baselines.cli import option
from evaaa_baselines.paper.cell_status import status
from evaaa_baselines.paper.cells import Layout, build_cells, keep_out_of_git
from evaaa_baselines.paper.engines import STOP_GRACE_SECONDS
from evaaa_baselines.paper.plan import plan_text
from evaaa_baselines.paper.protocol import REPO, ProtocolError, load_protocol
from evaaa_baselines.paper.running import EXECUTORS, Runner, select


@dataclass
class ReproduceConfig:
    protocol: str = option(
        "paper_cpu",
        "a protocol of conf/protocol/ (paper_cpu, paper_gpu, paper_learned, paper_settle, paper_settle_pilot, smoke) or "
        "the path of a protocol YAML file",
    )
    root: str | None = option(
        None,
        "folder of the runs, evaluations, logs and done-markers (default: the "
        "protocol's root, else runs/protocol/<protocol name>)",
    )
    plan: bool = option(False, "print the cells, their status, estimated CPU-minutes and commands; run nothing")
    jobs: int = option(
        1, "cells run at once (one core each: threads=1)", check=(lambda v: v >= 1, "a positive integer")
    )
    cells: list[str] = option(
        [],
        "run only these cells (names as plan=true lists them, or shell patterns such as "
        "eval/ppo/*); default: every cell not done",
    )
    redo: bool = option(
        False,
        "with cells=: run those cells again although done (a training run is moved aside by "
        "train.py's start_over=true, an evaluation's folder renamed <out>.old-<UTC time>)",
    )
    max_minutes: float | None = option(
        None,
        "start no new cell after this many minutes (running cells finish)",
        check=(lambda v: v > 0, "a positive number"),
    )
    end_minutes: float | None = option(
        None,
        "every cell must end within this many minutes: a cell starts only while its estimated "
        "CPU-minutes fit in the minutes left (for a machine that keeps no files after a session, "
        "where a cell cut short starts over; a training with a checkpoint counts its estimate less the "
        "CPU-minutes it has run); the cells left are named, the same command continues",
        check=(lambda v: v > 0, "a positive number"),
    )
    retries: int = option(
        1,
        "times a failed cell is tried again in the same session (a training continues from "
        "its checkpoint: the renderer crash of docs/training.md)",
        check=(lambda v: v >= 0, "0 or more"),
    )
    out: str | None = option(None, "the report's folder (default: the protocol's report.out)")
    executor: str = option(
        "local",
        "what runs the cells: local (a pool of jobs subprocesses on this machine), ray "
        "(each cell a Ray task with the CPUs and GPUs it needs) or slurm (each cell a "
        "SLURM job through submitit)",
        choices=EXECUTORS,
    )
    ray_address: str | None = option(
        None,
        "executor=ray: the cluster to join (auto, or ray://<head>:10001); "
        "default: a Ray instance on this machine with jobs CPUs",
    )
    ray_retries: int = option(
        3,
        "executor=ray: times Ray runs a cell again whose worker or node was lost (it "
        "continues from the files the lost one left)",
        check=(lambda v: v >= 0, "0 or more"),
    )
    slurm_partition: str | None = option(None, "executor=slurm: the partition of the jobs")
    slurm_minutes: int = option(
        2880, "executor=slurm: each job's time limit in minutes", check=(lambda v: v > 0, "a positive integer")
    )
    slurm_parallel: int = option(
        64, "executor=slurm: jobs of one array running at once", check=(lambda v: v > 0, "a positive integer")
    )
    slurm_mem_gb: int = option(
        16,
        "executor=slurm: each job's memory request in GB (a DQN run's replay buffer alone takes about 2.5)",
        check=(lambda v: v > 0, "a positive integer"),
    )
    slurm_requeues: int = option(
        10,
        "executor=slurm: times a job is requeued at its time limit, continuing from its checkpoint (a 340-hour "
        "DreamerV3 curriculum needs 8 at 48 hours)",
        check=(lambda v: v >= 0, "0 or more"),
    )
    submitit_cluster: str = option(
        "slurm",
        "executor=slurm: slurm, or local (submitit's local executor: the jobs "
        "as subprocesses of this machine, to try a set-up)",
        choices=("slurm", "local"),
    )
    progress: bool = option(True, "a progress bar over the cells")


def main(argv: list[str] | None = None) -> int:
    cfg = cli.parse(
        ReproduceConfig,
        argv,
        prog="reproduce.py",
        description=__doc__.split("\n\n")[0],
        examples=[
            "protocol=paper_cpu plan=true",
            "protocol=paper_cpu jobs=2",
            "protocol=paper_cpu cells=[eval/ppo/curriculum/seed0/*]",
            "protocol=paper_learned 'cells=[*/dqn/matched-1-1/seed1]'",
        ],
    )
    if cfg.redo and not cfg.cells:
        cli.fail("reproduce.py", "redo=true needs cells=[...]: the cells to run again")
    try:
        p = load_protocol(cfg.protocol)
        lay = Layout(Path(cfg.root) if cfg.root else REPO / p.root if p.root else Path("runs") / "protocol" / p.name)
        cells = build_cells(p, lay.root, Path(cfg.out) if cfg.out else None)
        chosen = select(cells, cfg.cells) if cfg.cells else cells
    except ProtocolError as err:
        cli.fail("reproduce.py", str(err))
    if cfg.plan:
        print(plan_text(p, cells, lay, p.threads))
        return 0
    todo = chosen if cfg.redo else [c for c in chosen if status(c, lay, cells) != "done"]
    if not todo:
        print(
            f"reproduce.py: nothing to do: {'the cells asked for are' if cfg.cells else 'every cell is'} done "
            f"({lay.root})"
        )
        return 0
    lay.root.mkdir(parents=True, exist_ok=True)
    keep_out_of_git(lay)
    lock = open(lay.root / ".reproduce.lock", "a+")
    try:  # two sessions on one root would run the same cells twice, into the same folders
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        lock.seek(0)
        cli.fail(
            "reproduce.py",
            f"another reproduce.py (pid {lock.read().strip() or '?'}) is running on {lay.root}; nothing was started",
        )
    lock.seek(0)
    lock.truncate()
    lock.write(str(os.getpid()))
    lock.flush()
    where = {
        "local": f"{cfg.jobs} at a time",
        "ray": f"as Ray tasks on {cfg.ray_address or 'a local Ray instance'}",
        "slurm": f"as jobs of submitit's {cfg.submitit_cluster} executor",
    }[cfg.executor]
    print(
        f"reproduce.py: {len(todo)} of {len(cells)} cells to run under {lay.root}, {where}; logs in {lay.logs}",
        flush=True,
    )
    slurm = {
        "timeout_min": cfg.slurm_minutes,
        "mem_gb": cfg.slurm_mem_gb,
        "slurm_array_parallelism": cfg.slurm_parallel,
        # SIGUSR2 this long before the time limit: the running command stops as on Ctrl-C (a training writes its
        # checkpoint, within STOP_GRACE_SECONDS) and submitit requeues the job
        "slurm_signal_delay_s": int(STOP_GRACE_SECONDS) + 60,
    }
    if cfg.slurm_partition:
        slurm["slurm_partition"] = cfg.slurm_partition
    runner = Runner(
        p,
        cells,
        lay,
        executor=cfg.executor,
        jobs=cfg.jobs,
        max_minutes=cfg.max_minutes,
        end_minutes=cfg.end_minutes,
        redo=cfg.redo,
        retries=cfg.retries,
        progress=cfg.progress,
        ray_address=cfg.ray_address,
        ray_retries=cfg.ray_retries,
        submitit_cluster=cfg.submitit_cluster,
        slurm=slurm if cfg.submitit_cluster == "slurm" else {"timeout_min": cfg.slurm_minutes},
        slurm_requeues=cfg.slurm_requeues,
        selects=" ".join(
            f"{k}={v}" for k, v in (("protocol", cfg.protocol), ("root", cfg.root), ("out", cfg.out)) if v
        ),
    )
    try:
        rc = runner.run(todo)
    except ProtocolError as err:
        cli.fail("reproduce.py", str(err))
    except KeyboardInterrupt:
        print("reproduce.py: stopped; the same command continues where it stopped", file=sys.stderr)
        return 130
    left = [c.name for c in cells if status(c, lay, cells) != "done"]
    print(
        f"reproduce.py: {len(cells) - len(left)} of {len(cells)} cells done"
        + (f"; not done: {', '.join(left[:10])}{' ...' if len(left) > 10 else ''}" if left else "")
    )
    return rc


if __name__ == "__main__":
    sys.exit(main())
