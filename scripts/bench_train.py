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

import glob
import json
import os
import platform
import re
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
from evaaa_baselines.scalar_log import has_scalar, scalar_csv  # noqa: E402

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
        None, "report these finished run directories (glob patterns allowed) instead of training"
    )
    device: str = option(
        "auto",
        "where the networks train: auto (CUDA when available), cpu, cuda or cuda:N",
        check=(lambda v: re.fullmatch(r"auto|cpu|cuda(:\d+)?", v) is not None, "auto, cpu, cuda or cuda:N"),
    )
    progress: bool = option(False, "keep each run's progress bar (in <keep>/<algo>.out)")
    overrides: list[str] = option([], "more train.py overrides for every run, e.g. [env.num_envs=16,preset=debug]")


def main(argv: list[str] | None = None) -> int:
    args = cli.parse(
        BenchConfig,
        argv,
        prog="bench_train.py",
        description=__doc__.split("\n\n")[0],
        examples=["algos=[ppo,dqn] minutes=2 threads=1", '"runs=[runs/acceptance/*/seed0]"'],
    )
    algos = args.algos
    if not algos and args.runs is None:
        cli.fail("bench_train.py", f"algos=[]: name at least one of {', '.join(algo_names())}")
    if args.runs is not None:  # patterns are expanded here, so that they may be quoted on the command line
        args.runs = [d for pattern in args.runs for d in (sorted(glob.glob(pattern)) or [pattern])]
    for d in args.runs or ():
        if not (Path(d) / ".hydra" / "config.yaml").is_file():
            cli.fail("bench_train.py", f"runs: {d} is not a run directory of scripts/train.py (no .hydra/config.yaml)")
    if args.runs:
        rows = [read_throughput(Path(d), run_algo(Path(d)), args.skip) for d in args.runs]
        print(f"evaaa bench_train: {len(rows)} existing runs")
        for d, r in zip(args.runs, rows):
            print(f"  {r.algo}: {d}")
        print(table(rows))
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
    rows = []
    with tempfile.TemporaryDirectory(prefix="evaaa-bench-train-") as scratch:
        root = Path(args.keep) if args.keep else Path(scratch)
        root.mkdir(parents=True, exist_ok=True)
        for algo in algos:
            print(f"  {algo} ...", flush=True)
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
    print(table(rows))
    if args.json:
        write_json(
            args.json,
            {
                "level": args.level,
                "minutes": args.minutes,
                "threads": args.threads,
                "device": str(device),
                "overrides": args.overrides,
                "cores": os.cpu_count(),
                "rows": [asdict(r) for r in rows],
            },
        )
    return 0


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
