"""Training throughput of each baseline: env steps and gradient steps per second of the whole training loop, and
the memory it took.

    python scripts/bench_train.py                                 # ppo, ppo_lstm, dqn, dreamer_xs: 3 minutes each
    python scripts/bench_train.py algos=[ppo,dqn] minutes=2 threads=1
    python scripts/bench_train.py algos=[dreamer] minutes=10      # DreamerV3 size S: ~10 s per gradient step here
    python scripts/bench_train.py "runs=[runs/acceptance/*/seed0]"  # the same figures for runs already made
    python scripts/bench_train.py algos=[ppo] device=cuda "overrides=[bf16=true,compile=true]"  # options, as train.py's

Each algorithm trains with its defaults (``scripts/train.py algo=<name> level=<level>``, ``env.num_envs=8``, all
modalities) for ``minutes`` of wall time in a scratch run directory, one after another, so that the runs do not
share the machine.  The figures come from the run's own log (``logs/scalars/time/env_steps_per_s.csv``: env steps
per second of the session so far, written every ``log_every`` env steps — or its rows in a packed record's
``logs/scalars.csv`` — and the gradient-step counter where the
algorithm logs one; a resumed run's sessions, found in its ``train.log``, are added up):

* **whole run**: env steps / wall time from the start of training to the last log row (warm-up, evaluations and
  checkpoints included);
* **steady**: the rate between the log row closest to ``skip`` of the run's time and the last row, i.e. after
  warm-up (DreamerV3 collects its first 1,024 steps with a random policy, much faster than it trains).

Evaluations and checkpoints are pushed beyond the budget (``eval.every=0``, ``checkpoint.every`` larger than any run)
so that both rates measure training alone; the final evaluation and model of the stage are not timed.

Arguments are ``key=value`` (lists as ``[a,b]``), the keys of :class:`BenchConfig`; ``--help`` lists them.

Memory: **peak RSS** is the training process's maximum resident set (``wait4``'s ``ru_maxrss``: memory-mapped
replay pages it touched count too); **GPU memory** the peak of ``torch.cuda.max_memory_allocated`` the run logged
(``time/gpu_memory_peak_gb``, CUDA only).  **First gradient step**: seconds from launching the process to the end
of its first gradient step (DreamerV3, from its ``train.log``).
"""

from __future__ import annotations

import concurrent.futures
import glob
import itertools
import json
import math
import os
import platform
import queue
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, replace
from datetime import datetime
from pathlib import Path

import pandas as pd
from omegaconf import OmegaConf

import evaaa  # noqa: E402
from evaaa_baselines import cli  # noqa: E402
from evaaa_baselines.algos import names as algo_names  # noqa: E402
from evaaa_baselines.cli import option  # noqa: E402
from evaaa_baselines.logs import has_scalar, read_scalar, scalar_csv  # noqa: E402
from evaaa_baselines.machine import processor  # noqa: E402
from evaaa_baselines.stage import PHASES  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_ALGOS = ("ppo", "ppo_lstm", "dqn", "dreamer_xs")


@dataclass
class Throughput:
    algo: str
    env_steps: int
    seconds: float
    env_steps_per_s: float
    steady_env_steps_per_s: float
    gradient_steps: int | None
    steady_gradient_steps_per_s: float | None
    device: str | None = None
    peak_rss_gb: float | None = None
    gpu_memory_gb: float | None = None
    first_gradient_step_s: float | None = None
    #: CPU seconds per phase of the loop (evaaa_baselines.stage), ``other`` and ``total``, at the last log row
    cpu_split: dict[str, float] | None = None


def read_split(run_dir: Path) -> dict[str, float] | None:
    """CPU seconds per phase of the loop at the run's last log row (``time/cpu/*``, :mod:`evaaa_baselines.stage`;
    a resumed run's last session), with ``other`` (what no phase covers) and ``total``; None for a run that logged
    no split."""
    if not has_scalar(run_dir, "time/cpu/total"):
        return None
    last = {tag: float(read_scalar(run_dir, f"time/cpu/{tag}")[-1][1]) for tag in (*PHASES, "total")}
    total = last.pop("total")
    return {p: last[p] for p in PHASES} | {"other": max(0.0, total - sum(last.values())), "total": total}


def read_throughput(run_dir: Path, algo: str, skip: float = 0.25) -> Throughput:
    """The rates of a finished run from its CSV log (see the module docstring); ``skip``: share of the run's
    wall time left out of the steady rates."""
    rate_file = run_dir / "logs" / "scalars" / "time" / "env_steps_per_s.csv"  # or its rows in logs/scalars.csv
    if not has_scalar(run_dir, "time/env_steps_per_s") and (session := session_totals(run_dir, algo)) is not None:
        return session
    if not has_scalar(run_dir, "time/env_steps_per_s"):
        raise SystemExit(
            f"bench_train.py: {algo}: no {rate_file.relative_to(run_dir)} in {run_dir} (the run logged "
            "nothing: give it more minutes=, or see its train.log)"
        )
    rates = pd.read_csv(scalar_csv(run_dir, "time/env_steps_per_s"), header=None, names=["step", "rate"])
    rates = rates.drop_duplicates("step", keep="last")
    rates = rates[rates["rate"] > 0]
    if len(rates) < 2:
        session = session_totals(run_dir, algo)
        if session is not None:  # too slow to log twice (e.g. DreamerV3 S on a CPU): the whole run's figures only
            return session
        raise SystemExit(
            f"bench_train.py: {algo}: fewer than two log rows in {rate_file}; give it more minutes= "
            "or a smaller log_every"
        )
    # each row's rate is (step - the session's first step) / the session's seconds so far; a resumed run has a
    # session per resume (train.log: "resuming ... env step N"), laid end to end on one wall-time axis
    starts = resume_steps(run_dir)
    start = rates["step"].map(lambda step: max([0] + [s for s in starts if s < step]))
    rates = rates.assign(start=start, session_s=(rates["step"] - start) / rates["rate"])
    offset = rates.groupby("start")["session_s"].max().cumsum().shift(fill_value=0.0)
    rates = rates.assign(seconds=rates["session_s"] + rates["start"].map(offset))
    last = rates.iloc[-1]
    first = rates.iloc[(rates["seconds"] - skip * last["seconds"]).abs().argmin()]
    if first["step"] == last["step"]:
        first = rates.iloc[-2]
    span = last["seconds"] - first["seconds"]
    steady = (last["step"] - first["step"]) / span
    grad_steps = grad_rate = None
    if has_scalar(run_dir, "train/updates"):
        updates = pd.read_csv(scalar_csv(run_dir, "train/updates"), header=None, names=["step", "updates"])
        updates = updates.drop_duplicates("step", keep="last")
        by_step = updates.set_index("step")["updates"]
        if first["step"] in by_step.index and last["step"] in by_step.index:
            grad_steps = int(by_step[last["step"]])
            grad_rate = (by_step[last["step"]] - by_step[first["step"]]) / span
    gpu = "time/gpu_memory_peak_gb"
    gpu_gb = (
        float(pd.read_csv(scalar_csv(run_dir, gpu), header=None, names=["step", "gb"])["gb"].max())
        if has_scalar(run_dir, gpu)
        else None
    )
    return Throughput(
        algo,
        int(last["step"]),
        float(last["seconds"]),
        float(last["step"] / last["seconds"]),
        float(steady),
        grad_steps,
        None if grad_rate is None else float(grad_rate),
        device=run_device(run_dir),
        gpu_memory_gb=gpu_gb,
        cpu_split=read_split(run_dir),
    )


def session_totals(run_dir: Path, algo: str) -> Throughput | None:
    """The whole-run figures from the last session line of ``train.log`` (env steps, env steps/s, gradient steps),
    for a run that logged fewer than two rows; no steady rates."""
    log = run_dir / "train.log"
    found = (
        re.findall(
            r"on \S+: (\d+) env steps, ([\d.e+-]+) env steps/s this session, (\d+) gradient steps", log.read_text()
        )
        if log.exists()
        else []
    )
    if not found:
        return None
    steps, rate, updates = int(found[-1][0]), float(found[-1][1]), int(found[-1][2])
    return Throughput(algo, steps, steps / rate, rate, float("nan"), updates, None, device=run_device(run_dir))


def run_device(run_dir: Path) -> str | None:
    """The device the run trained on, from the first line of its ``train.log`` that names it."""
    log = run_dir / "train.log"
    match = re.search(r"parameters on (\S+) \(", log.read_text()) if log.exists() else None
    return match.group(1) if match else None


def first_gradient_step(run_dir: Path, launched: float) -> float | None:
    """Seconds from ``launched`` (a ``time.time()``) to the log line of the run's first gradient step, if any."""
    log = run_dir / "train.log"
    if not log.exists():
        return None
    match = re.search(r"^\[(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d+)\].* - first gradient step at", log.read_text(), re.M)
    if match is None:
        return None
    return datetime.strptime(match.group(1), "%Y-%m-%d %H:%M:%S,%f").timestamp() - launched


# Runs the command given after it and prints its exit status and peak resident set (ru_maxrss, kB). A process
# started by fork or vfork and exec counts its parent's resident high-water mark into its own ru_maxrss, so the
# command is started from this small interpreter rather than from a caller that may already hold gigabytes (a
# test worker, a notebook).
_MEASURE = """
import os, subprocess, sys
with open(sys.argv[1], "w") as out:
    child = subprocess.Popen(sys.argv[2:], stdout=out, stderr=subprocess.STDOUT)
    _, status, usage = os.wait4(child.pid, 0)
print(os.waitstatus_to_exitcode(status), usage.ru_maxrss)
"""


def run_measured(cmd: list[str], out_path: Path) -> tuple[int, int]:
    """Run ``cmd`` with its output in ``out_path``; returns its exit status and peak resident memory in bytes (its
    own: the command is started from a small measuring process, ``_MEASURE``)."""
    done = subprocess.run(
        [sys.executable, "-c", _MEASURE, str(out_path), *cmd],
        cwd=ROOT,
        env=os.environ.copy(),
        stdout=subprocess.PIPE,
        text=True,
        check=True,
    )
    status, kilobytes = done.stdout.split()
    return int(status), int(kilobytes) * 1024  # kilobytes on Linux


def resume_steps(run_dir: Path) -> list[int]:
    """The env steps at which the run was resumed (from its ``train.log``; none for a run of one session)."""
    log = run_dir / "train.log"
    if not log.exists():
        return []
    return [int(m.group(1)) for m in re.finditer(r"resuming .* env step (\d+)", log.read_text())]


def run_algo(run_dir: Path) -> str:
    """The algorithm of a run directory, from the configuration it saved."""
    config = run_dir / ".hydra" / "config.yaml"
    if not config.exists():
        raise SystemExit(
            f"bench_train.py: {run_dir} is not a run directory of scripts/train.py (no .hydra/config.yaml)"
        )
    return str(OmegaConf.load(config).algo.name)


def train_overrides(
    algo: str,
    level: str,
    minutes: float,
    threads: int | None,
    root: Path,
    extra: list[str],
    device: str = "auto",
    progress: bool = False,
) -> list[str]:
    """The ``scripts/train.py`` arguments of one algorithm's run."""
    overrides = [
        f"algo={algo}",
        f"level={level}",
        "total_steps=1000000000",
        f"max_minutes={minutes}",
        "eval.every=0",
        "checkpoint.every=1000000000",
        "eval.episodes=1",
        "logger=csv",
        f"progress={str(progress).lower()}",
        f"device={device}",
        f"run.root={root}",
        f"run.name={algo}",
        *extra,
    ]
    return overrides + ([f"threads={threads}"] if threads is not None else [])


def check_runs(args: BenchConfig, device: str) -> None:
    """Refuse, in one line and before any run starts, a training command that ``train.py`` would refuse (a bad
    value in ``overrides``)."""
    from hydra import initialize_config_dir

    from evaaa_baselines.cli.training import check_overrides
    from evaaa_baselines.config import ConfigError, register_levels
    from evaaa_baselines.paths import CONF_DIR

    register_levels()
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        for algo in args.algos:
            try:
                check_overrides(
                    train_overrides(
                        algo,
                        args.level,
                        args.minutes,
                        args.threads,
                        Path("runs"),
                        args.overrides,
                        device,
                        args.progress,
                    ),
                    multirun=False,
                )
            except ConfigError as err:
                cli.fail("bench_train.py", f"the run of {algo}: {err}")


def run_one(
    algo: str,
    level: str,
    minutes: float,
    threads: int | None,
    root: Path,
    extra: list[str],
    device: str = "auto",
    skip: float = 0.25,
    progress: bool = False,
) -> Throughput:
    """Train ``algo`` for ``minutes`` in ``root/<algo>`` on ``device``; returns its figures (``progress``: the run
    draws its progress bar into ``root/<algo>.out``)."""
    run_dir = root / algo
    cmd = [
        sys.executable,
        str(ROOT / "scripts" / "train.py"),
        *train_overrides(algo, level, minutes, threads, root, extra, device, progress),
    ]
    log = root / f"{algo}.out"
    launched = time.time()
    code, peak_rss = run_measured(cmd, log)
    if code:
        tail = "\n".join(log.read_text().splitlines()[-40:])
        raise SystemExit(f"bench_train.py: {algo} failed (exit {code}); the end of its output:\n{tail}")
    return replace(
        read_throughput(run_dir, algo, skip),
        peak_rss_gb=peak_rss / 1e9,
        first_gradient_step_s=first_gradient_step(run_dir, launched),
    )


def table(rows: list[Throughput]) -> str:
    def fmt(value: float | None, spec: str) -> str:
        return "–" if value is None else format(value, spec)

    head = (
        f"{'algo':<12}{'device':>8}{'env steps':>11}{'minutes':>9}{'env steps/s':>13}{'steady':>9}"
        f"{'grad steps/s':>14}{'grad steps':>12}{'1st grad s':>12}{'peak RSS GB':>13}{'GPU GB':>8}"
    )
    lines = [head]
    for r in rows:
        steady = None if r.steady_env_steps_per_s != r.steady_env_steps_per_s else r.steady_env_steps_per_s  # nan
        lines.append(
            f"{r.algo:<12}{r.device or '?':>8}{r.env_steps:>11,}{r.seconds / 60:>9.1f}"
            f"{r.env_steps_per_s:>13.1f}{fmt(steady, '.1f'):>9}"
            f"{fmt(r.steady_gradient_steps_per_s, '.3g'):>14}{fmt(r.gradient_steps, ','):>12}"
            f"{fmt(r.first_gradient_step_s, '.0f'):>12}{fmt(r.peak_rss_gb, '.2f'):>13}"
            f"{fmt(r.gpu_memory_gb, '.2f'):>8}"
        )
    return "\n".join(lines)


def split_table(rows: list[Throughput]) -> str:
    """Where each run's CPU time went: every phase's share of the process's CPU seconds (all threads)."""
    rows = [r for r in rows if r.cpu_split]
    if not rows:
        return ""
    columns = [p for p in (*PHASES, "other") if any(r.cpu_split[p] > 0 for r in rows)]
    lines = [f"{'CPU time split':<14}" + "".join(f"{c:>11}" for c in columns) + f"{'CPU s':>9}"]
    for r in rows:
        total = r.cpu_split["total"]
        lines.append(f"{r.algo:<14}" + "".join(f"{r.cpu_split[c] / total:>11.1%}" for c in columns) + f"{total:>9.0f}")
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------------ learning speed
#: the in-training validation evaluation that decides "learned": sampled actions, this many episodes
LEARN_EPISODES = 8


@dataclass
class Learning:
    """How fast one run learned: the training CPU time (evaluations left out) at which its validation evaluation
    first reached ``bar`` decisions of mean survival, and whether every later one stayed there."""

    algo: str
    preset: str
    seed: int
    bar: float
    evaluations: list[dict]
    cpu_minutes_to_learn: float | None
    env_steps_to_learn: int | None
    stays: bool | None
    final_survival: float | None
    final_learned: bool | None
    train_cpu_minutes: float
    env_steps: int
    acting: str = "sample"  # the acting mode of the evaluations read (a greedy DQN's: mode)
    eval_cpu_left_out: bool = True  # False: a run older than the eval/cpu_seconds log, its evaluations counted


def standstill_survival(run_dir: Path) -> float:
    """Mean survival of standing still on the validation worlds the run evaluated on: its level with its level
    overrides (reward, ``env.overrides``), ``eval.episodes`` worlds seeded as ``Run.evaluate`` seeds them."""
    import torch

    from evaaa_baselines.config import env_overrides
    from evaaa_baselines.rollout import EVALUATION_INFO, evaluate

    cfg = OmegaConf.load(run_dir / ".hydra" / "config.yaml")
    env = evaaa.make_env(
        cfg.level.name,
        num_envs=cfg.eval.episodes,
        modalities=["interoception"],
        info=EVALUATION_INFO,
        worlds="validation",
        **env_overrides(cfg),
    )
    try:
        env.set_seed(cfg.seed, static_seed=True)

        def still(td):
            return td.set("action", torch.zeros(td.batch_size, dtype=torch.long))

        return evaluate(env, still).survival_mean
    finally:
        env.close(raise_if_closed=False)


def eval_acting(run_dir: Path, algo: str) -> str:
    """How the in-training evaluations of a run whose ``eval.csv`` has no ``acting`` column acted, as
    baselines/reports/load.py reads such files: sampled where the run's ``eval.sample`` was true (DQN, which has no
    action distribution, took its most likely action whatever it said), the most likely action otherwise."""
    sample = bool((OmegaConf.load(run_dir / ".hydra" / "config.yaml").get("eval") or {}).get("sample", False))
    return "sample" if sample and algo != "dqn" else "mode"


def learning(run_dir: Path, algo: str, preset: str, seed: int, bar: float) -> Learning:
    """The learning speed of a run from its ``eval.csv`` (mean survival and the stage's CPU seconds per evaluation)
    and the CPU seconds each evaluation took (``eval/cpu_seconds`` in its log), which are left out."""
    evals = pd.read_csv(run_dir / "eval.csv")
    if "acting" not in evals:  # written before eval.csv named its acting mode: as the run's eval.sample said
        evals["acting"] = eval_acting(run_dir, algo)
    # eval.both_modes: rows of both modes; the sampled ones are the measure (DQN evaluates greedily only)
    acting = "sample" if (evals["acting"] == "sample").any() else "mode"
    evals = evals[(evals["acting"] == acting) & (evals["stage"] == evals["stage"].min())]
    if evals.empty:
        raise SystemExit(f"bench_train.py: {run_dir}/eval.csv holds no evaluation")
    per = evals.groupby("env_steps").agg(survival=("steps", "mean"), cpu_seconds=("cpu_seconds", "max")).reset_index()
    # the evaluations' own CPU seconds, logged since issue 61 (an older run's are counted as training)
    logged = read_scalar(run_dir, "eval/cpu_seconds") if has_scalar(run_dir, "eval/cpu_seconds") else []
    spent = {int(step): float(v) for step, v in logged}
    per["eval_cpu"] = per["env_steps"].map(lambda step: spent.get(int(step), 0.0)).cumsum()
    per["train_cpu_minutes"] = (per["cpu_seconds"] - per["eval_cpu"]) / 60
    above = per["survival"] >= bar
    first = int(above.to_numpy().argmax()) if above.any() else None
    rows = [
        {
            "env_steps": int(r.env_steps),
            "train_cpu_minutes": round(float(r.train_cpu_minutes), 3),
            "survival": float(r.survival),
        }
        for r in per.itertuples()
    ]
    last = per.iloc[-1]
    return Learning(
        algo=algo,
        preset=preset,
        seed=seed,
        bar=bar,
        evaluations=rows,
        cpu_minutes_to_learn=None if first is None else float(per["train_cpu_minutes"].iloc[first]),
        env_steps_to_learn=None if first is None else int(per["env_steps"].iloc[first]),
        stays=None if first is None else bool(above.iloc[first:].all()),
        final_survival=float(last["survival"]),
        final_learned=bool(last["survival"] >= bar),
        train_cpu_minutes=float(last["train_cpu_minutes"]),
        env_steps=int(last["env_steps"]),
        acting=acting,
        eval_cpu_left_out=bool(logged),
    )


def learn_overrides(algo: str, preset: str, seed: int, args: BenchConfig, root: Path) -> list[str]:
    """The ``scripts/train.py`` arguments of one learning-speed run: the algorithm's settings under ``preset``, a
    CPU-time budget, and validation evaluations every ``eval_every`` env steps, sampled, 8 episodes."""
    return [
        f"algo={algo}",
        f"preset={preset}",
        f"level={args.level}",
        f"seed={seed}",
        "total_steps=1000000000",
        f"max_cpu_minutes={args.cpu_minutes}",
        f"eval.every={args.eval_every}",
        f"eval.episodes={LEARN_EPISODES}",
        "eval.sample=true",
        f"checkpoint.every={args.eval_every}",
        "logger=csv",
        "progress=false",
        "threads=1",
        "device=cpu",
        f"run.root={root}",
        f"run.name={preset}/{algo}/seed{seed}",
        *args.overrides,
    ]


def run_learning(job: tuple[str, str, int], args: BenchConfig, root: Path, core: int | None) -> Path:
    """Train one learning-speed run to its CPU budget (resuming it where a checkpoint is left; nothing to do
    where its final model is written), on one thread pinned to ``core``; returns its run directory."""
    algo, preset, seed = job
    run_dir = root / preset / algo / f"seed{seed}"
    if (run_dir / f"model-0-{args.level}.pt").is_file():
        return run_dir
    resume = ["resume=true"] if (run_dir / "checkpoint.pt").is_file() else []
    cmd = [
        sys.executable,
        str(ROOT / "scripts" / "train.py"),
        *learn_overrides(algo, preset, seed, args, root),
        *resume,
    ]
    if core is not None and shutil.which("taskset"):
        cmd = ["taskset", "-c", str(core), *cmd]
    run_dir.parent.mkdir(parents=True, exist_ok=True)
    log = run_dir.parent / f"seed{seed}.out"
    env = os.environ | {"EVAAA_THREADS": "1", "OMP_NUM_THREADS": "1"}
    with open(log, "a") as out:
        code = subprocess.run(cmd, cwd=ROOT, env=env, stdout=out, stderr=subprocess.STDOUT).returncode
    if code:
        tail = "\n".join(log.read_text().splitlines()[-30:])
        raise SystemExit(f"bench_train.py: {preset}/{algo}/seed{seed} failed (exit {code}); the end of {log}:\n{tail}")
    return run_dir


def learning_summary(runs: list[Learning]) -> list[dict]:
    """Per preset and algorithm: the median CPU-minutes to learn over seeds (a seed that never learned counts as
    more than any that did; the median is None when half or more never learned) and how many learned."""
    out = []
    for (preset, algo), group in itertools.groupby(
        sorted(runs, key=lambda r: (r.preset, r.algo)), key=lambda r: (r.preset, r.algo)
    ):
        group = list(group)
        minutes = [r.cpu_minutes_to_learn if r.cpu_minutes_to_learn is not None else math.inf for r in group]
        median = float(statistics.median(minutes))
        out.append(
            {
                "preset": preset,
                "algo": algo,
                "seeds": len(group),
                "learned": sum(r.cpu_minutes_to_learn is not None for r in group),
                "stayed": sum(bool(r.stays) for r in group),
                "final_learned": sum(bool(r.final_learned) for r in group),
                "median_cpu_minutes_to_learn": median if math.isfinite(median) else None,
                "cpu_minutes_to_learn": [r.cpu_minutes_to_learn for r in group],
                "final_survival": [r.final_survival for r in group],
            }
        )
    return out


def learning_table(summary: list[dict], budget: float) -> str:
    lines = [f"{'preset':<24}{'algo':<12}{'learned':>9}{'stayed':>8}{'final':>7}{'median CPU-min':>16}  per seed"]
    for row in summary:
        median = row["median_cpu_minutes_to_learn"]
        seeds = ", ".join("–" if m is None else f"{m:.1f}" for m in row["cpu_minutes_to_learn"])
        lines.append(
            f"{row['preset']:<24}{row['algo']:<12}{row['learned']:>5}/{row['seeds']:<3}{row['stayed']:>8}"
            f"{row['final_learned']:>7}{(f'{median:.1f}' if median is not None else f'> {budget:g}'):>16}  {seeds}"
        )
    return "\n".join(lines)


def finished_learning(dirs: list[str], bar: float) -> list[Learning]:
    """``learn=true runs=[...]``: the learning speed of runs already made (a protocol's record, say), each labelled
    by its folder (``<label>/seed<s>``) and measured against ``bar`` x stand-still on its own validation worlds."""
    runs = []
    for d in map(Path, dirs):
        cfg = OmegaConf.load(d / ".hydra" / "config.yaml")
        label = "/".join(d.parts[-3:-1]) if d.name.startswith("seed") else d.name
        runs.append(learning(d, str(cfg.algo.name), label, int(cfg.seed), bar * standstill_survival(d)))
    return runs


def main_learn(args: BenchConfig) -> int:
    """``learn=true``: CPU-minutes to learn, per preset, algorithm and seed (module docstring)."""
    if args.runs:
        runs = finished_learning(args.runs, args.bar)
        print(f"evaaa bench_train learn: {len(runs)} existing runs; {processor()}")
        summary = learning_summary(runs)
        print(learning_table(summary, max(r.train_cpu_minutes for r in runs)))
        if args.json:
            write_json(
                args.json,
                {"processor": processor(), "runs_read": args.runs, "bar_times_standstill": args.bar}
                | {"summary": summary}
                | {"runs": [asdict(r) for r in runs]},
            )
        return 0
    jobs = [(algo, preset, seed) for preset in args.presets for algo in args.algos for seed in args.seeds]
    root = Path(args.keep or "runs/bench-learn").resolve()
    print(
        f"evaaa bench_train learn: level {args.level}, {len(jobs)} runs (presets {', '.join(args.presets)}; "
        f"{', '.join(args.algos)}; seeds {args.seeds}), one core each, {args.jobs} at a time, in {root}; "
        f"{processor()}",
        flush=True,
    )
    cores = args.cores or list(range(os.cpu_count() or 1))
    with concurrent.futures.ThreadPoolExecutor(args.jobs) as pool:
        slots = queue.Queue()
        for i in range(args.jobs):
            slots.put(cores[i % len(cores)] if args.jobs <= len(cores) else None)

        def one(job):
            core = slots.get()
            try:
                print(f"  {job[1]}/{job[0]}/seed{job[2]} on core {core} ...", flush=True)
                return run_learning(job, args, root, core)
            finally:
                slots.put(core)

        dirs = list(pool.map(one, jobs))
    load = os.getloadavg()  # other work on the machine slows a run's CPU seconds too (shared caches): said with them
    # the bar of each run: stand-still's survival on the validation worlds it evaluated on, with its level settings
    bars = {str(d): args.bar * standstill_survival(d) for d in dirs}
    print(f"  the bar: {args.bar:g} x stand-still on each run's validation worlds = {sorted(set(bars.values()))}")
    runs = [learning(d, algo, preset, seed, bars[str(d)]) for d, (algo, preset, seed) in zip(dirs, jobs)]
    summary = learning_summary(runs)
    print(learning_table(summary, args.cpu_minutes))
    if args.json:
        write_json(
            args.json,
            {
                "processor": processor(),
                "cores": os.cpu_count(),
                "load_average_at_end": [round(x, 2) for x in load],
                "level": args.level,
                "bar": {
                    "times_standstill": args.bar,
                    "by_run": {str(Path(d).relative_to(root)): b for d, b in bars.items()},
                },
                "evaluation": f"validation worlds, sampled actions, {LEARN_EPISODES} episodes every {args.eval_every} env steps",
                "cpu_minutes_budget": args.cpu_minutes,
                "overrides": args.overrides,
                "summary": summary,
                "runs": [asdict(r) for r in runs],
            },
        )
    return 0


@dataclass
class BenchConfig:
    algos: list[str] = option(list(DEFAULT_ALGOS), "algorithms to train, one after another", choices=algo_names)
    level: str = option(
        "1-1", "level or testbed trained on", choices=lambda: [*evaaa.LEVELS, *evaaa.TESTBEDS, "curriculum"]
    )
    minutes: float = option(3.0, "wall-clock training time per algorithm", check=(lambda v: v > 0, "a positive number"))
    threads: int | None = option(
        None, "torch threads (null: torch's default)", check=(lambda v: v >= 1, "a positive integer")
    )
    skip: float = option(
        0.25,
        "share of each run left out of the steady rates (warm-up)",
        check=(lambda v: 0 <= v < 1, "a number in [0, 1)"),
    )
    keep: str | None = option(None, "keep the run directories under this folder (null: a temporary one)")
    json: str | None = option(None, "also write the figures to this file")
    runs: list[str] | None = option(
        None,
        "report these finished run directories (glob patterns allowed) instead of training (learn=true: how fast "
        "they learned)",
    )
    device: str = option(
        "auto",
        "where the networks train: auto (CUDA when available), cpu, cuda or cuda:N",
        check=(lambda v: re.fullmatch(r"auto|cpu|cuda(:\d+)?", v) is not None, "auto, cpu, cuda or cuda:N"),
    )
    progress: bool = option(False, "keep each run's progress bar (in <keep>/<algo>.out)")
    overrides: list[str] = option([], "more train.py overrides for every run, e.g. [env.num_envs=16,preset=debug]")
    learn: bool = option(
        False, "measure CPU-minutes to learn instead: every preset x algorithm x seed to its CPU budget (docstring)"
    )
    presets: list[str] = option(["none"], "learn=true: the settings compared (train.py's preset=; none: the defaults)")
    seeds: list[int] = option([0], "learn=true: seeds of every preset and algorithm")
    cpu_minutes: float = option(
        40.0, "learn=true: CPU-minutes of training per run (max_cpu_minutes)", check=(lambda v: v > 0, "positive")
    )
    eval_every: int = option(
        10_000, "learn=true: env steps between validation evaluations", check=(lambda v: v > 0, "a positive integer")
    )
    bar: float = option(2.0, "learn=true: learned = mean survival at least this many times stand-still's")
    jobs: int = option(
        1, "learn=true: runs at a time, each on a core of its own", check=(lambda v: v >= 1, "at least 1")
    )
    cores: list[int] | None = option(
        None,
        "learn=true: the cores the runs are pinned to, one run each (null: 0, 1, ...), e.g. [1] beside other work",
        check=(lambda c: 0 <= c < (os.cpu_count() or 1), f"a core number below {os.cpu_count()}"),
    )


def main(argv: list[str] | None = None) -> int:
    args = cli.parse(
        BenchConfig,
        argv,
        prog="bench_train.py",
        description=__doc__.split("\n\n")[0],
        examples=["algos=[ppo,dqn] minutes=2 threads=1", '"runs=[runs/acceptance/*/seed0]"'],
    )
    algos = args.algos
    if args.runs is not None:  # patterns are expanded here, so that they may be quoted on the command line
        args.runs = [d for pattern in args.runs for d in (sorted(glob.glob(pattern)) or [pattern])]
    for d in args.runs or ():
        if not (Path(d) / ".hydra" / "config.yaml").is_file():
            cli.fail("bench_train.py", f"runs: {d} is not a run directory of scripts/train.py (no .hydra/config.yaml)")
        if args.learn and not (Path(d) / "eval.csv").is_file():
            cli.fail("bench_train.py", f"runs: {d} has no eval.csv (learn=true reads its validation evaluations)")
    if args.learn:
        if args.level == "curriculum":
            cli.fail("bench_train.py", "level=curriculum: learn=true measures one level (name a level or testbed)")
        return main_learn(args)
    if not algos and args.runs is None:
        cli.fail("bench_train.py", f"algos=[]: name at least one of {', '.join(algo_names())}")
    if args.runs:
        rows = [read_throughput(Path(d), run_algo(Path(d)), args.skip) for d in args.runs]
        print(f"evaaa bench_train: {len(rows)} existing runs")
        for d, r in zip(args.runs, rows):
            print(f"  {r.algo}: {d}")
        print(table(rows))
        print(split_table(rows))
        if args.json:
            write_json(args.json, {"runs": args.runs, "rows": [asdict(r) for r in rows]})
        return 0
    from evaaa_baselines.devices import DeviceError, resolve_device

    try:
        device = resolve_device(args.device)
    except DeviceError as err:
        cli.fail("bench_train.py", str(err))
    check_runs(args, str(device))
    gpu = f", {torch_device_name(device)}" if device.type == "cuda" else ""
    print(
        f"evaaa bench_train: level {args.level}, {args.minutes:g} min per algorithm, device {device}{gpu}, threads "
        f"{args.threads or 'default'}, {platform.machine()}, {os.cpu_count()} cores",
        flush=True,
    )
    rows, failed = [], {}
    with tempfile.TemporaryDirectory(prefix="evaaa-bench-train-") as scratch:
        root = Path(args.keep) if args.keep else Path(scratch)
        root.mkdir(parents=True, exist_ok=True)
        for algo in algos:
            print(f"  {algo} ...", flush=True)
            try:
                rows.append(
                    run_one(
                        algo,
                        args.level,
                        args.minutes,
                        args.threads,
                        root.resolve(),
                        args.overrides,
                        str(device),
                        args.skip,
                        args.progress,
                    )
                )
            except SystemExit as err:  # one algorithm not measured: the others' figures still count
                failed[algo] = str(err.code)
                print(f"  {algo}: not measured: {err.code}", flush=True)
    print(table(rows))
    print(split_table(rows))
    if args.json:
        write_json(
            args.json,
            {
                "processor": processor(),
                "level": args.level,
                "minutes": args.minutes,
                "threads": args.threads,
                "device": str(device),
                "overrides": args.overrides,
                "cores": os.cpu_count(),
                "rows": [asdict(r) for r in rows],
                "not_measured": failed,
            },
        )
    return 1 if failed else 0


def torch_device_name(device) -> str:
    import torch

    return torch.cuda.get_device_name(device)


def write_json(path: str, data: dict) -> None:
    """``data`` as indented JSON at ``path``, creating its folder."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(data, indent=2) + "\n")


if __name__ == "__main__":
    sys.exit(main())
