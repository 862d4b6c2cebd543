"""The learners' speed on a GPU box, every variant in one call of at most ten minutes, written as JSON.

DreamerV3 (sizes S and XS), for each way a gradient step can run (``algo.update``): ``eager``, ``graphs`` (the three
phases replayed as CUDA graphs), ``compile`` (each phase compiled) and ``graphs_compile``; for each, milliseconds
per gradient step and gradient steps per second (on batches already on the device), the first steps' seconds
(capture or compilation), the CUDA kernels one gradient step launches (``torch.profiler``; on a CPU the aten
operations it dispatches instead), peak GPU memory; the replay's time split on a memory-mapped buffer of
``transitions`` steps: drawing a batch (the O(batch) sampler, and torchrl's ``SliceSampler`` it replaced), moving
it to the device, and a whole step (draw + move + update) with and without the next batch drawn ahead
(``algo.update.prefetch``).  Then PPO and DQN trained for ``loop_seconds`` each, with ``env.num_envs`` worlds
stepped in one process on ``EVAAA_THREADS`` threads (``worlds`` and ``env_threads``, paired; default 8 worlds on
2 threads, and on a box of more than 4 cores twice as many worlds as cores on half as many threads as cores):
whole-loop env steps per second.

The compiled variants come last (compiling S takes minutes): whatever ``budget_s`` leaves is theirs, and a variant
not started in time is recorded as skipped.  The JSON is rewritten after every measurement, so a call stopped
from outside keeps what was measured.

    python scripts/bench_gpu.py out=docs/bench/gpu-h100.json           # on a GPU box (about 9 minutes)
    python scripts/bench_gpu.py device=cpu tiny=true out=/tmp/gpu.json  # the same code at tiny sizes, on a CPU

Arguments are ``key=value``, the keys of :class:`GpuBenchConfig`; ``--help`` lists them.
"""

from __future__ import annotations

import json
import os
import platform
import re
import resource
import sys
import tempfile
import time
import traceback
from dataclasses import asdict, dataclass
from pathlib import Path

import evaaa
from evaaa_baselines import cli
from evaaa_baselines.cli import option
from evaaa_baselines.machine import processor

ROOT = Path(__file__).resolve().parents[1]
VARIANTS = {
    "eager": {"graphs": False, "compile": False},
    "graphs": {"graphs": True, "compile": False},
    "compile": {"graphs": False, "compile": True},
    "graphs_compile": {"graphs": True, "compile": True},
}
SIZES = {"S": "dreamer", "XS": "dreamer_xs"}


@dataclass
class GpuBenchConfig:
    out: str | None = option(None, "write the figures to this JSON file (rewritten after every measurement)")
    device: str = option(
        "auto",
        "where the networks train: auto (CUDA when available), cpu, cuda or cuda:N",
        check=(lambda v: re.fullmatch(r"auto|cpu|cuda(:\d+)?", v) is not None, "auto, cpu, cuda or cuda:N"),
    )
    tiny: bool = option(
        False, "the debug preset's tiny networks, a buffer of at most 256 steps: checks the script itself, on a CPU"
    )
    sizes: list[str] = option(["S", "XS"], "DreamerV3 sizes measured", choices=list(SIZES))
    variants: list[str] = option(list(VARIANTS), "ways a DreamerV3 gradient step runs", choices=list(VARIANTS))
    updates: int = option(30, "timed gradient steps per variant", check=(lambda v: v >= 1, "an integer >= 1"))
    transitions: int = option(
        32_768, "steps in the memory-mapped replay the sampling is timed on", check=(lambda v: v >= 1, ">= 1")
    )
    algos: list[str] = option(["ppo", "dqn"], "algorithms whose whole training loop is timed", choices=["ppo", "dqn"])
    worlds: list[int] = option(
        [], "env.num_envs of those runs (empty: 8, and twice the usable cores when there are more than 4)"
    )
    env_threads: list[int] = option(
        [], "EVAAA_THREADS of each of those runs, paired with worlds (empty: 2, and half the usable cores)"
    )
    loop_seconds: float = option(30.0, "seconds of each whole-loop run", check=(lambda v: v > 0, "a number > 0"))
    budget_s: float = option(
        540.0, "no measurement starts after this many seconds", check=(lambda v: v > 0, "a number > 0")
    )
    level: str = option("1-1", "level the PPO and DQN runs train on", choices=lambda: list(evaaa.LEVELS))
    deterministic: bool = option(True, "deterministic CUDA kernels, as training's default deterministic=true")


HELP = {
    "prog": "bench_gpu.py",
    "description": __doc__.split("\n\n")[0],
    "examples": ["out=docs/bench/gpu-h100.json", "device=cpu tiny=true out=/tmp/gpu.json"],
}
if __name__ == "__main__":
    cli.help_first(GpuBenchConfig, **HELP)  # before torch loads

import torch  # noqa: E402


class Bench:
    """The figures so far, written to ``out`` after each measurement."""

    def __init__(self, args: GpuBenchConfig, device: torch.device):
        self.args, self.device, self.began = args, device, time.perf_counter()
        self.data: dict = {
            "machine": machine(device),
            "arguments": asdict(args),
            "dreamer": {},
            "replay": {},
            "loops": [],
            "skipped": [],
        }

    def left(self) -> float:
        return self.args.budget_s - (time.perf_counter() - self.began)

    def save(self) -> None:
        self.data["seconds"] = round(time.perf_counter() - self.began, 1)
        if self.args.out:
            out = Path(self.args.out)
            out.parent.mkdir(parents=True, exist_ok=True)
            out.write_text(json.dumps(self.data, indent=2) + "\n")


def machine(device: torch.device) -> dict:
    info = {
        "device": str(device),
        "cpu": processor(),
        "cores": os.cpu_count(),
        "usable_cores": len(os.sched_getaffinity(0)),
        "python": platform.python_version(),
        "torch": torch.__version__,
    }
    if device.type == "cuda":
        info["gpu"] = torch.cuda.get_device_name(device)
        info["gpu_memory_gb"] = round(torch.cuda.get_device_properties(device).total_memory / 1e9, 1)
    return info


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def peak_memory_gb(device: torch.device) -> float:
    if device.type == "cuda":
        return torch.cuda.max_memory_allocated(device) / 1e9
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6  # the process's peak RSS (kB -> GB)


# ------------------------------------------------------------------------------------------------ DreamerV3
def compose_cfg(algo: str, tiny: bool, *extra: str):
    from hydra import compose, initialize_config_dir

    from evaaa_baselines.paths import CONF_DIR

    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        return compose("config", overrides=[f"algo={algo}", *(["preset=debug"] if tiny else []), *extra])


def obs_shapes(cfg, level: str) -> dict[str, tuple[int, ...]]:
    from evaaa_baselines.config import observation_keys

    keys = observation_keys(cfg)
    env = evaaa.make_env(level, num_envs=1, seed=0, modalities=keys)
    try:
        return {k: tuple(env.observation_spec[k].shape[1:]) for k in keys}
    finally:
        env.close()


def filled_replay(cfg, shapes: dict, num_envs: int, rows: int, directory: Path, device: torch.device):
    """A memory-mapped replay of ``rows`` random steps in each of ``num_envs`` worlds, as training stores them."""
    from tensordict import TensorDict

    from evaaa_baselines.dreamer.model import NUM_ACTIONS
    from evaaa_baselines.dreamer.replay import SequenceReplay

    replay = SequenceReplay(
        num_envs * rows, num_envs, cfg.sequence_length, cfg.batch_size, directory=directory, device=device
    )
    g = torch.Generator().manual_seed(0)
    for _ in range(rows):
        nxt = {
            k: torch.randint(0, 256, (num_envs, *s), dtype=torch.uint8, generator=g)
            if k == "pixels"
            else torch.randn(num_envs, *s, generator=g)
            for k, s in shapes.items()
        }
        terminated = torch.rand(num_envs, 1, generator=g) < 0.01
        nxt |= {"reward": torch.randn(num_envs, 1, generator=g), "terminated": terminated, "done": terminated}
        nxt["consumed"] = torch.rand(num_envs, generator=g) < 0.01
        replay.extend(
            TensorDict(
                {
                    "action": torch.randint(NUM_ACTIONS, (num_envs,), generator=g),
                    "is_init": torch.rand(num_envs, 1, generator=g) < 0.01,
                    "next": nxt,
                },
                [num_envs],
            )
        )
    return replay


def timed(fn, repeats: int, device: torch.device) -> float:
    """Mean seconds of ``fn()`` over ``repeats`` calls, the device's queue drained before and after."""
    sync(device)
    began = time.perf_counter()
    for _ in range(repeats):
        fn()
    sync(device)
    return (time.perf_counter() - began) / repeats


def replay_split(bench: Bench, size: str, replay, device: torch.device) -> None:
    """Drawing a batch (new sampler, torchrl's SliceSampler), moving it to the device."""
    repeats = 3 if bench.args.tiny else 10
    batch = replay._uniform(replay.batch_size, replay.sequence_length)
    bench.data["replay"][size] = {
        "transitions": len(replay.buffer),
        "batch": [replay.batch_size, replay.sequence_length],
        "draw_ms": 1e3 * timed(lambda: replay._uniform(replay.batch_size, replay.sequence_length), repeats, device),
        "draw_slice_sampler_ms": 1e3 * timed(lambda: replay.buffer.sample(), repeats, device),
        "to_device_ms": 1e3 * timed(lambda: replay._to_device(batch), repeats, device),
        "batch_mb": sum(t.numel() * t.element_size() for t in batch.values(True, True)) / 1e6,
    }


def count_launches(learner, batch, device: torch.device) -> dict:
    """What one gradient step launches: CUDA kernels (and graph launches) on a GPU, aten operations on a CPU."""
    from torch.profiler import ProfilerActivity, profile

    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device.type == "cuda" else [])
    sync(device)
    with profile(activities=activities) as prof:
        learner.update(batch)
        sync(device)
    events = prof.events()
    names = [e.name for e in events]
    out = {"aten_ops": sum(n.startswith("aten::") for n in names)}
    if device.type == "cuda":
        out["kernels"] = sum(1 for e in events if str(e.device_type).endswith("CUDA"))
        out["kernel_launch_calls"] = sum(
            n in ("cudaLaunchKernel", "cudaLaunchKernelExC", "cuLaunchKernel", "cuLaunchKernelEx") for n in names
        )
        out["graph_launches"] = sum(n == "cudaGraphLaunch" for n in names)
    return out


def dreamer_variant(bench: Bench, size: str, variant: str, replay, shapes: dict) -> None:
    from evaaa_baselines.dreamer.model import make_model
    from evaaa_baselines.dreamer.update import Learner

    args, device = bench.args, bench.device
    cfg = compose_cfg(SIZES[size], args.tiny)
    options = {**VARIANTS[variant], "prefetch": False}
    row: dict = {"size": size, "variant": variant}
    bench.data["dreamer"].setdefault(size, {})[variant] = row
    if options["graphs"] and device.type != "cuda":
        row["skipped"] = "CUDA graphs need a CUDA device"
        return
    if device.type == "cuda":
        torch.cuda.empty_cache()
        torch.cuda.reset_peak_memory_stats(device)
    torch.manual_seed(0)
    model = make_model(cfg.algo, shapes).to(device)
    learner = Learner(cfg.algo, model, device, options=options)
    batches = [replay.sample() for _ in range(4)]
    began = time.perf_counter()
    warmup = 5 if options["graphs"] else 2  # graphs: three eager steps, the capture, one replay
    for i in range(warmup):
        learner.update(batches[i % len(batches)])
    sync(device)
    row["warmup_s"] = time.perf_counter() - began
    row["warmup_steps"] = warmup
    n = args.updates
    counter = iter(range(10**9))
    seconds = timed(lambda: learner.update(batches[next(counter) % len(batches)]), n, device)
    row |= {"ms_per_update": 1e3 * seconds, "updates_per_s": 1 / seconds, "timed_updates": n}
    metrics = learner.update(batches[0])
    row["finite_losses"] = all(bool(torch.isfinite(v).all()) for v in metrics.values())
    row |= count_launches(learner, batches[0], device)
    # whole gradient steps from the replay: draw + move + update, one after the other, then the next drawn ahead
    m = max(2, n // 3)
    row["step_from_replay_ms"] = 1e3 * timed(lambda: learner.update(replay.sample()), m, device)
    replay.use_own_generator(0)

    def prefetched():
        learner.update(replay.sample())
        replay.prefetch()

    row["step_from_replay_prefetch_ms"] = 1e3 * timed(prefetched, m, device)
    replay._pending, replay._pending_states, replay._prefetch_rng = None, None, None
    row["peak_memory_gb"] = peak_memory_gb(device)
    row["peak_memory_kind"] = "GPU allocated" if device.type == "cuda" else "process RSS"


def dreamer_section(bench: Bench, variants: list[str], scratch: Path) -> None:
    args = bench.args
    for variant in variants:
        for size in args.sizes:
            if bench.left() < (60 if "compile" in variant and not args.tiny else 5):
                bench.data["skipped"].append(f"DreamerV3-{size} {variant}: budget_s spent")
                bench.save()
                continue
            print(f"  DreamerV3-{size} {variant} ...", flush=True)
            try:
                cfg = compose_cfg(SIZES[size], args.tiny)
                key = (size,)
                if key not in bench.replays:
                    shapes = obs_shapes(cfg, args.level)
                    num_envs = 2 if args.tiny else 8
                    transitions = min(args.transitions, 256) if args.tiny else args.transitions
                    rows = max(transitions // num_envs, cfg.algo.sequence_length)
                    directory = scratch / f"replay-{size}"
                    replay = filled_replay(cfg.algo, shapes, num_envs, rows, directory, bench.device)
                    bench.replays[key] = (replay, shapes)
                    replay_split(bench, size, replay, bench.device)
                replay, shapes = bench.replays[key]
                dreamer_variant(bench, size, variant, replay, shapes)
            except Exception as err:  # a variant that fails (e.g. a capture) is recorded, the others go on
                bench.data["dreamer"].setdefault(size, {})[variant] = {
                    "size": size,
                    "variant": variant,
                    "error": f"{type(err).__name__}: {err}"[:2000],
                    "traceback": traceback.format_exc()[-4000:],
                }
                print(f"    failed: {type(err).__name__}: {str(err)[:300]}", flush=True)
            row = bench.data["dreamer"].get(size, {}).get(variant, {})
            if "ms_per_update" in row:
                print(
                    f"    {row['ms_per_update']:.1f} ms per gradient step ({row['updates_per_s']:.2f}/s), "
                    f"warm-up {row['warmup_s']:.1f} s, {row.get('kernels', row['aten_ops'])} "
                    f"{'kernels' if 'kernels' in row else 'aten ops'}",
                    flush=True,
                )
            bench.save()


# ------------------------------------------------------------------------------------------------ PPO, DQN
def loops_section(bench: Bench, scratch: Path) -> None:
    from hydra import compose, initialize_config_dir

    from evaaa_baselines.paths import CONF_DIR
    from evaaa_baselines.training import train

    args = bench.args
    bench_train = load_bench_train()
    cores = len(os.sched_getaffinity(0))
    worlds = args.worlds or ([2] if args.tiny else [8, 2 * cores] if cores > 4 else [8])
    threads = args.env_threads or [2, max(2, cores // 2)][: len(worlds)]
    threads += [2] * (len(worlds) - len(threads))  # worlds given alone: 2 env threads each
    for algo in args.algos:
        for n, env_threads in zip(worlds, threads):
            if bench.left() < args.loop_seconds + 20:
                bench.data["skipped"].append(f"{algo} with {n} worlds: budget_s spent")
                bench.save()
                continue
            span = f"{n * 64} env steps of the debug preset" if args.tiny else f"{args.loop_seconds:g} s"
            print(f"  {algo}, {n} worlds on {env_threads} env threads, {span} ...", flush=True)
            run_dir = scratch / f"{algo}-{n}-{env_threads}"
            overrides = [
                f"algo={algo}",
                f"level={args.level}",
                f"env.num_envs={n}",
                f"device={bench.device}",
                f"deterministic={str(args.deterministic).lower()}",
                "eval.every=0",
                "checkpoint.every=1000000000",
                "logger=csv",
                "progress=false",
                # tiny: a few batches of the debug preset, whatever they take; else loop_seconds of the real thing
                *(
                    ["preset=debug", f"total_steps={n * 64}", "log_every=16"]
                    if args.tiny
                    else ["total_steps=1000000000", f"max_minutes={args.loop_seconds / 60}", f"log_every={n * 64}"]
                ),
            ]
            if algo == "ppo":
                overrides.append(f"algo.frames_per_batch={n * (16 if args.tiny else 128)}")
            row: dict = {"algo": algo, "num_envs": n, "env_threads": env_threads, "overrides": overrides}
            previous = os.environ.get("EVAAA_THREADS")
            os.environ["EVAAA_THREADS"] = str(env_threads)  # read when the run makes its env
            try:
                with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
                    cfg = compose("config", overrides=overrides)
                began = time.perf_counter()
                train(cfg, run_dir)
                row["wall_s"] = time.perf_counter() - began
                figures = bench_train.read_throughput(run_dir, algo)
                row |= {
                    "env_steps": figures.env_steps,
                    "env_steps_per_s": figures.env_steps_per_s,
                    "steady_env_steps_per_s": figures.steady_env_steps_per_s,
                    "gradient_steps": figures.gradient_steps,
                    "steady_gradient_steps_per_s": figures.steady_gradient_steps_per_s,
                }
                print(f"    {figures.steady_env_steps_per_s:.0f} env steps/s (steady)", flush=True)
            except (Exception, SystemExit) as err:
                row["error"] = f"{type(err).__name__}: {err}"[:2000]
                print(f"    failed: {row['error'][:300]}", flush=True)
            finally:
                if previous is None:
                    os.environ.pop("EVAAA_THREADS", None)
                else:
                    os.environ["EVAAA_THREADS"] = previous
            bench.data["loops"].append(row)
            bench.save()


def load_bench_train():
    import importlib.util

    spec = importlib.util.spec_from_file_location("evaaa_scripts_bench_train", ROOT / "scripts" / "bench_train.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


# ------------------------------------------------------------------------------------------------ main
def main(argv: list[str] | None = None) -> int:
    args = cli.parse(GpuBenchConfig, argv, **HELP)
    if args.env_threads and len(args.env_threads) != len(args.worlds):
        cli.fail(
            "bench_gpu.py",
            f"env_threads={cli._show(args.env_threads)}: give worlds= too, one value per env_threads value",
        )
    from evaaa_baselines.config import register_levels
    from evaaa_baselines.devices import DeviceError, resolve_device

    try:
        device = resolve_device(args.device)
    except DeviceError as err:
        cli.fail("bench_gpu.py", str(err))
    register_levels()
    from evaaa_baselines.devices import deterministic_kernels

    deterministic_kernels(args.deterministic, device)  # as a training run of the same setting
    bench = Bench(args, device)
    bench.replays = {}
    info = bench.data["machine"]
    print(
        f"evaaa bench_gpu: device {device}{' (' + info['gpu'] + ')' if 'gpu' in info else ''}, {info['cpu']}, "
        f"{info['usable_cores']} usable cores, budget {args.budget_s:g} s{', tiny sizes' if args.tiny else ''}",
        flush=True,
    )
    plain = [v for v in args.variants if "compile" not in v]
    compiled = [v for v in args.variants if "compile" in v]
    with tempfile.TemporaryDirectory(prefix="evaaa-bench-gpu-") as scratch:
        dreamer_section(bench, plain, Path(scratch))
        loops_section(bench, Path(scratch))
        dreamer_section(bench, compiled, Path(scratch))  # last: compiling takes what the budget leaves
        bench.replays.clear()
    bench.save()
    print(f"done in {bench.data['seconds']:.0f} s" + (f": {args.out}" if args.out else ""), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
