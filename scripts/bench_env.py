"""Environment throughput against the raw MuJoCo limit of the same scene, measured in one run.

For each setting the env is stepped through TorchRL (``step_and_maybe_reset``, random actions); then the same
trajectory is replayed as raw MuJoCo work only: per world and decision, five ``mj_step`` calls and one 64x64
render of the same states, in one thread.  The ratio env/raw says how much of the possible speed the env keeps;
both numbers come from this run on this machine, so a busy machine moves both.

Each setting is measured with the env's defaults, which use two threads when the process may use two cores: a
batch in two shares at once (physics on the calling thread and a helper, frames on two render threads with a GL
context each), one world with its frame drawn on the calling thread while a helper advances the EVs and reads the
other senses.  Each is measured the other way too ("one thread" or "2 threads").
The raw side is always one thread.  ``cores`` is the env's CPU seconds per wall-clock second, and ``per core`` the
ratio divided by it: how much of one core's raw speed each CPU second the env uses keeps.

Also reported: what TorchRL's step path costs on its own (the same loop over an env of the same keys that simulates
nothing), and so the most any single env can keep of raw; one world as users step it: TorchRL's ``env.rollout``
(random actions, every step kept; once more with ``info=True``, the diagnostics' cost) and the gymnasium adapter
(``gymnasium.make("evaaa/<level>-v0")``); the cost of a reset in steps; resident memory over a long run.

The peer: MiniWorld's ``MiniWorld-CollectHealth-v0`` (a 3-D survival task with 64x64 egocentric pixels, one world
per process, its fastest setting ``LP_NUM_THREADS=0``) stepped the same way in the same run, so that evaaa's
single-world rates can be given as a ratio to it on any machine.  MiniWorld is installed on demand into a
virtual environment of its own (``peer_venv``, outside this project's); where it cannot be installed the peer is
skipped with the reason.

    python scripts/bench_env.py                      # level 1-1, all settings
    python scripts/bench_env.py level=1-2 steps=2000 json=bench.json

With ``backend=warp`` it measures the MuJoCo Warp backend instead (docs/backends.md): env steps/s at the level's
64x64 frames for each number of worlds in ``counts`` on each of ``levels``, beside the CPU backend (one process, its
default threads) at the counts up to ``cpu_max_worlds``, through the same TorchRL loop.  On a GPU:

    python scripts/bench_env.py backend=warp json=docs/bench/bench_env_warp_h100.json

and on a CPU, where Warp's CPU device is for development (tiny counts): ``backend=warp counts=[2,8]``.

With ``host_cost=true`` it measures the host CPU time per world-decision of the game logic alone, for the CPU
backend and for the Warp backend's host side, at each of ``worlds`` on each of ``levels`` (the issue's sizes: 1,024
and 4,096 worlds, levels 1-1 and 4-2), split by phase.  Stubbed: the physics (no ``mj_step``, no contact damage, no
per-world pose read-back: a stand-in moves each body by its commanded velocity, in arrays, clipped to the arena) and
the camera (every sense but pixels is read); on the Warp backend Warp itself (its device data is torch CPU tensors of
the device's shapes: the push and pull run for real against them; no kernel is compiled or launched).  Partial
resets are timed apart (``reset_us_per_world_decision``), outside the decision's figure:

    python scripts/bench_env.py host_cost=true json=docs/bench/host_cost.json

Arguments are ``key=value``, the keys of :class:`BenchConfig`; ``--help`` lists them.
"""

from __future__ import annotations

import gc
import json
import multiprocessing as mp
import os
import platform
import subprocess
import sys
import time
import venv
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import evaaa  # noqa: F401  (sets MUJOCO_GL before mujoco loads)
from evaaa_baselines import cli
from evaaa_baselines.cli import option


@dataclass
class BenchConfig:
    level: str = option(
        "1-1", "level or testbed whose scene is measured", choices=lambda: [*evaaa.LEVELS, *evaaa.TESTBEDS]
    )
    steps: int = option(
        3000,
        "decisions per setting (the first 50 warm up)",
        check=(lambda v: v > 60, "more than 60 (the first 50 decisions warm up)"),
    )
    num_envs: int = option(8, "worlds of the batched setting", check=(lambda v: v >= 1, "a positive integer"))
    resets: int = option(50, "resets timed for the cost of a reset", check=(lambda v: v >= 1, "a positive integer"))
    memory_steps: int = option(
        20000,
        "steps of the memory run (resident memory is sampled every 1000 steps)",
        check=(lambda v: v >= 2000, "at least 2000 (memory is sampled every 1000 steps)"),
    )
    skip_parallel: bool = option(False, "leave out the ParallelEnv settings")
    peer: bool = option(True, "also time MiniWorld-CollectHealth (installed on demand into peer_venv)")
    peer_venv: str = option("~/.cache/evaaa/bench-miniworld", "virtual environment the peer is installed into")
    json: str | None = option(None, "also write the figures to this file")
    backend: str = option(
        "cpu", "cpu: the settings above; warp: the MuJoCo Warp backend beside the CPU one", choices=("cpu", "warp")
    )
    levels: list[str] = option(
        ["1-1", "4-2"], "backend=warp and host_cost: levels measured", choices=lambda: [*evaaa.LEVELS, *evaaa.TESTBEDS]
    )
    counts: list[int] = option(
        [],
        "backend=warp: numbers of worlds ([]: 256, 1024, 4096, 8192 on a GPU, 2 and 8 on a CPU)",
        check=(lambda v: v >= 1, "positive integers"),
    )
    warp_steps: int = option(
        100,
        "backend=warp: decisions timed per setting (after a tenth of that, at least 3, warming up)",
        check=(lambda v: v >= 1, "a positive integer"),
    )
    cpu_max_worlds: int = option(
        64,
        "backend=warp: the CPU backend is measured at the counts up to this",
        check=(lambda v: v >= 0, "an integer >= 0"),
    )
    host_cost: bool = option(
        False, "host CPU time per world-decision of both backends' game logic, physics and camera stubbed"
    )
    worlds: list[int] = option(
        [1024, 4096], "host_cost: numbers of worlds", check=(lambda v: v >= 1, "positive integers")
    )
    host_steps: int = option(
        20,
        "host_cost: decisions timed per setting (after 3 warming up)",
        check=(lambda v: v >= 1, "a positive integer"),
    )


HELP = {
    "prog": "bench_env.py",
    "description": __doc__.split("\n\n")[0],
    "examples": [
        "",
        "level=4-2 steps=1500 skip_parallel=true json=docs/bench_env_4-2.json",
        "backend=warp json=docs/bench/bench_env_warp_h100.json",
        "host_cost=true json=docs/bench/host_cost.json",
    ],
}
if __name__ == "__main__":
    cli.help_first(BenchConfig, **HELP)  # before torch and the env load

# isort: split
import gymnasium  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from evaaa.env import EvaaaEnv, make_env  # noqa: E402
from evaaa.level_files import load_level  # noqa: E402
from evaaa.render import BatchRenderer  # noqa: E402
from evaaa.scene import GROUP_AGENT  # noqa: E402
from evaaa.sim import FORWARD, SUBSTEPS, Simulator, default_threads  # noqa: E402
from evaaa.worldgen import AGENT_HALF  # noqa: E402
from evaaa_baselines.machine import processor  # noqa: E402

torch.set_num_threads(1)


def rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


# ------------------------------------------------------------------------------------------------- env side
def random_actions(steps: int, n: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 5, size=(steps, n))


def time_env(env, actions: np.ndarray, warmup: int = 50) -> tuple[float, float]:
    """Steps per second (worlds x decisions) of a TorchRL loop over ``actions`` (T, N), and the CPU seconds per
    wall-clock second this process spent on it."""
    td = env.reset()
    acts = torch.from_numpy(actions).reshape(len(actions), *env.action_spec.shape)
    for t in range(warmup):
        td["action"] = acts[t]
        _, td = env.step_and_maybe_reset(td)
    start, cpu = time.perf_counter(), time.process_time()
    for t in range(warmup, len(actions)):
        td["action"] = acts[t]
        _, td = env.step_and_maybe_reset(td)
    elapsed = time.perf_counter() - start
    return (len(actions) - warmup) * actions.shape[1] / elapsed, (time.process_time() - cpu) / elapsed


def time_rollout(level: str, steps: int, warmup: int = 50, **kwargs) -> tuple[float, float]:
    """Steps per second of one world through ``env.rollout`` (TorchRL's own loop, random actions from the action
    spec, every step kept and stacked at the end: how a TorchRL user steps one world), and its CPU seconds per
    wall-clock second.  ``kwargs`` go to ``make_env``."""
    env = make_env(level, num_envs=1, seed=0, **kwargs)
    torch.manual_seed(0)
    env.rollout(warmup, break_when_any_done=False)
    start, cpu = time.perf_counter(), time.process_time()
    env.rollout(steps - warmup, break_when_any_done=False)
    elapsed = time.perf_counter() - start
    env.close()
    return (steps - warmup) / elapsed, (time.process_time() - cpu) / elapsed


class IdleEnv(EvaaaEnv):
    """The env's specs and keys with the simulation left out: every step hands TorchRL the last observation and
    info again (fresh tensors, as a real step does), with zero reward and no episode end.  Stepped like the env, it
    measures what TorchRL's step path and the handing over cost on their own."""

    def _step(self, tensordict):
        false = torch.zeros((self.num_envs, 1), dtype=torch.bool)
        return self._to_td(
            self.sim.last_obs,
            self.sim.last_info,
            {
                "reward": torch.zeros((self.num_envs, 1)),
                "done": false,
                "terminated": false.clone(),
                "truncated": false.clone(),
            },
        )


def time_gym(level: str, actions: np.ndarray, warmup: int = 50) -> tuple[float, float]:
    """Steps per second of one world through the gymnasium adapter over ``actions`` (T,), and its CPU seconds per
    wall-clock second."""
    env = gymnasium.make(f"evaaa/{level}-v0")
    env.reset(seed=0)

    def run(acts) -> None:
        for a in acts:
            _, _, terminated, truncated, _ = env.step(int(a))
            if terminated or truncated:
                env.reset()

    run(actions[:warmup])
    start, cpu = time.perf_counter(), time.process_time()
    run(actions[warmup:])
    elapsed = time.perf_counter() - start
    env.close()
    return (len(actions) - warmup) / elapsed, (time.process_time() - cpu) / elapsed


# the peer's loop, run by the peer's own interpreter: prints its steps/s and CPU seconds per second as JSON
PEER_LOOP = """
import json, sys, time
import pyglet
pyglet.options["headless"] = True
import gymnasium, miniworld, numpy as np
steps, warmup = int(sys.argv[1]), 50
env = gymnasium.make("MiniWorld-CollectHealth-v0", obs_width=64, obs_height=64)
env.reset(seed=0)
actions = np.random.default_rng(0).integers(0, env.action_space.n, steps)
def run(acts):
    for a in acts:
        _, _, terminated, truncated, _ = env.step(int(a))
        if terminated or truncated:
            env.reset()
run(actions[:warmup])
start, cpu = time.perf_counter(), time.process_time()
run(actions[warmup:])
elapsed = time.perf_counter() - start
print(json.dumps({"steps_per_s": (steps - warmup) / elapsed, "cores": (time.process_time() - cpu) / elapsed}))
"""


def peer_python(venv_dir: Path) -> tuple[Path | None, str]:
    """The interpreter of a virtual environment holding MiniWorld (made and installed on first use), or None and
    why it could not be."""
    python = venv_dir / "bin" / "python"
    try:
        if not python.exists():
            print(f"installing MiniWorld for the peer into {venv_dir} (once) ...", flush=True)
            venv.create(venv_dir, with_pip=True)
        check = subprocess.run([python, "-c", "import miniworld"], capture_output=True)
        if check.returncode != 0:
            install = subprocess.run(
                [python, "-m", "pip", "install", "-q", "miniworld"], capture_output=True, text=True, timeout=900
            )
            if install.returncode != 0:
                return None, f"pip install miniworld failed: {install.stderr.strip().splitlines()[-1:]}"
    except (OSError, subprocess.SubprocessError) as error:
        return None, f"could not make {venv_dir}: {error}"
    return python, ""


def time_peer(venv_dir: Path, steps: int) -> tuple[dict | None, str]:
    """MiniWorld-CollectHealth's steps/s at 64x64 with ``LP_NUM_THREADS=0``, or None and why not."""
    python, why = peer_python(venv_dir)
    if python is None:
        return None, why
    env = dict(os.environ, LP_NUM_THREADS="0")
    try:
        out = subprocess.run(
            [python, "-c", PEER_LOOP, str(steps)], capture_output=True, text=True, env=env, timeout=1800
        )
    except subprocess.SubprocessError as error:
        return None, f"the peer's loop failed: {error}"
    if out.returncode != 0:
        return None, f"the peer's loop failed: {out.stderr.strip().splitlines()[-1:]}"
    return json.loads(out.stdout.strip().splitlines()[-1]), ""


# ------------------------------------------------------------------------------------------------- raw side
def record_states(level: str, n: int, seed: int, actions: np.ndarray) -> list[np.ndarray]:
    """Per decision, the state (N, size) each world's physics starts from, as the env produces it."""
    sim = Simulator(load_level(level), n, modalities=["interoception"], seed=seed)
    sim.reset()
    states = []
    for t in range(len(actions)):
        sim.apply_actions(actions[t])
        states.append(sim.physics_states())
        _, _, term, trunc, _ = sim.advance(actions[t])
        done = term | trunc
        if done.any():
            sim.reset(done)
    sim.close()
    return states


def time_raw(level: str, states: list[np.ndarray], warmup: int = 50) -> float:
    """Steps per second of the raw MuJoCo work (5 x mj_step + one render per world) over recorded states."""
    spec = load_level(level)
    sim = Simulator(spec, states[0].shape[0], modalities=["interoception"], seed=0)
    model, datas = sim.model, sim.datas
    v = spec.sensors.vision
    renderer = BatchRenderer(model, v.height, v.width, hidden_groups=(GROUP_AGENT,))
    cam = sim.index.eye_camera
    what = mujoco.mjtState.mjSTATE_INTEGRATION
    out = np.empty((1, v.height, v.width, 3), dtype=np.uint8)
    elapsed = 0.0
    for t, frame in enumerate(states):
        for w, data in enumerate(datas):
            mujoco.mj_setState(model, data, frame[w], what)
            mujoco.mj_forward(model, data)
            start = time.perf_counter()
            for _ in range(5):
                mujoco.mj_step(model, data)
            renderer.render([data], cam, out=out)
            if t >= warmup:
                elapsed += time.perf_counter() - start
    renderer.close()
    sim.close()
    return (len(states) - warmup) * states[0].shape[0] / elapsed


def _raw_worker(level, states, queue):
    queue.put(time_raw(level, states))


def time_raw_parallel(level: str, per_worker_states: list[list[np.ndarray]]) -> float:
    """Raw throughput of several processes replaying at once (sum of their rates)."""
    ctx = mp.get_context("spawn")
    queue = ctx.Queue()
    procs = [ctx.Process(target=_raw_worker, args=(level, s, queue)) for s in per_worker_states]
    for p in procs:
        p.start()
    rates = [queue.get() for _ in procs]
    for p in procs:
        p.join()
    return float(sum(rates))


# ------------------------------------------------------------------------------------------------- report
def _zero(seconds: dict | None) -> None:
    for key in seconds or {}:
        seconds[key] = 0.0


def time_decisions(env, decisions: int, warmup: int, seed: int, on_start=lambda: None) -> float:
    """Env steps per second (worlds x decisions) of ``decisions`` random decisions through TorchRL after ``warmup``
    (waiting for the device at both ends; ``on_start()`` is called when the clock starts)."""
    n = env.num_envs
    acts = torch.from_numpy(random_actions(warmup + decisions, n, seed)).to(env.device)
    td = env.reset()
    for t in range(warmup):
        td["action"] = acts[t]
        _, td = env.step_and_maybe_reset(td)
    sync = torch.cuda.synchronize if env.device.type == "cuda" else (lambda: None)
    sync()
    on_start()
    start = time.perf_counter()
    for t in range(warmup, warmup + decisions):
        td["action"] = acts[t]
        _, td = env.step_and_maybe_reset(td)
    sync()
    return decisions * n / (time.perf_counter() - start)


def measure_backends(args) -> dict:
    """``backend=warp``: the Warp backend's env steps/s at each count of worlds, beside the CPU backend's."""
    from evaaa import mjwarp

    warp_device = mjwarp.default_device()
    env_device = "cuda" if warp_device.startswith("cuda") else "cpu"
    gpu = torch.cuda.get_device_name(0) if env_device == "cuda" else None
    counts = args.counts or ([256, 1024, 4096, 8192] if gpu else [2, 8])
    decisions = args.warp_steps
    results: dict = {
        "backend": "warp",
        "levels": list(args.levels),
        "counts": counts,
        "decisions": decisions,
        "frame": "64x64 RGB, every sense on",
        "warp_device": warp_device,
        "gpu": gpu,
        "processor": processor(),
        "machine": f"{platform.machine()}, {os.cpu_count()} cores",
        "versions": {"mujoco_warp": _version("mujoco-warp"), "warp": _version("warp-lang"), "torch": torch.__version__},
        "kernel_cache": str(mjwarp.kernel_cache_dir()).replace(str(Path.home()), "~", 1),  # no machine path in the JSON
        "rows": [],
    }
    print(f"evaaa bench_env backend=warp: Warp on {warp_device} ({gpu or results['processor']}), {decisions} decisions")
    print(f"{'level':<8}{'worlds':>8}{'backend':>9}{'env steps/s':>14}{'make s':>9}   per decision (warp)")
    for level in args.levels:
        for n in counts:
            for backend in ("warp", "cpu"):
                if backend == "cpu" and n > args.cpu_max_worlds:
                    continue
                start = time.perf_counter()
                device = env_device if backend == "warp" else "cpu"
                env = make_env(level, num_envs=n, seed=0, backend=backend, device=device)
                made = time.perf_counter() - start
                sim = env.sim
                if backend == "warp":
                    sim.wait_for_device = True
                # the first decisions compile (or load) the device's kernels: warm up past them
                warmup = max(3, decisions // 10)
                seconds = getattr(sim, "seconds", None)
                rate = time_decisions(env, decisions, warmup=warmup, seed=n, on_start=partial(_zero, seconds))
                row = {"level": level, "worlds": n, "backend": backend, "env_steps_per_s": rate, "make_seconds": made}
                if seconds is not None:  # where a decision's time went, per decision
                    row["seconds_per_decision"] = {k: v / decisions for k, v in seconds.items()}
                    row["seconds_per_decision"]["total"] = n / rate
                env.close()
                results["rows"].append(row)
                shares = ""
                if seconds is not None:
                    per = row["seconds_per_decision"]
                    shares = "   " + ", ".join(f"{k} {v * 1e3:.1f} ms" for k, v in per.items())
                print(f"{level:<8}{n:>8}{backend:>9}{rate:>14.0f}{made:>9.1f}{shares}", flush=True)
    return results


# ------------------------------------------------------------------------------------------------- host cost
HOST_STUBS = (
    "physics: no mj_step, no contact damage, no per-world pose read-back (mj_kinematics, mj_camlight); a stand-in "
    "moves each body by its commanded velocity for the decision (arrays over worlds, clipped to the arena, no "
    "collisions); camera: not drawn (every sense but pixels is read); Warp: no Warp call at all (the device data "
    "is torch CPU tensors of the device's shapes: the push and pull run for real against them, mjw.step, the "
    "contact forces, the overflow read and the render do not; Warp kernels are not compiled)"
)


class Phases:
    """CPU seconds of the process per phase of a decision, each phase's own (what it calls that is a phase too is
    counted there)."""

    def __init__(self):
        self.seconds: dict[str, float] = {}
        self._open: list[float] = []

    def wrap(self, name: str, fn):
        self.seconds.setdefault(name, 0.0)

        def timed(*args, **kwargs):
            self._open.append(0.0)
            start = time.process_time()
            try:
                return fn(*args, **kwargs)
            finally:
                spent = time.process_time() - start
                inner = self._open.pop()
                self.seconds[name] += spent - inner
                if self._open:
                    self._open[-1] += spent

        return timed


def _stand_in_move(sim, actions: np.ndarray, pos: np.ndarray) -> None:
    """The physics' stand-in: ``pos`` (N, 2) moved by each body's commanded velocity over a decision, in the arena."""
    seconds = SUBSTEPS * sim.model.opt.timestep
    speed = sim._move_speed * (actions == FORWARD) * seconds
    heading = sim.state.heading_rad
    step = np.stack([speed * np.sin(heading), speed * np.cos(heading)], axis=1)
    half = np.asarray(sim.level.arena.size) / 2 - AGENT_HALF
    pos[:] = np.clip(pos + step, -half, half)


def host_only_warp(level, n: int, modalities: list[str], seed: int):
    """A :class:`~evaaa.mjwarp.WarpSimulator` without Warp: its device data is torch CPU tensors of the device's
    shapes and its physics the stand-in, so that what it times is the backend's host-side Python."""
    from evaaa.mjwarp import WarpSimulator

    class HostOnlyWarp(WarpSimulator):
        def __init__(self):
            self.wp = self.mjw = None
            self.device = "cpu"
            self._dev = None
            self._moved = self._posed = None
            Simulator.__init__(self, level, n, modalities, seed=seed, threads=1)
            self._setup_device()
            self._track_writes()

        def _setup_device(self):
            if self._dev is not None:
                return
            m = self.model
            zeros = partial(torch.zeros, dtype=torch.float32)
            self._t = {
                "qpos": zeros((n, m.nq)),
                "qvel": zeros((n, m.nv)),
                "qacc_warmstart": zeros((n, m.nv)),
                "mocap_pos": zeros((n, m.nmocap, 3)),
                "mocap_quat": zeros((n, m.nmocap, 4)),
            }
            self.torch_device = torch.device("cpu")
            self._predator_mocap = torch.as_tensor(self.index.predator_mocap)
            self.seconds = {"sync": 0.0, "physics": 0.0, "camera": 0.0}
            self.wait_for_device = False
            self._dev = True

        def _physics(self, worlds, damage, collided):
            self._push(all_poses=True)
            qpos = self._t["qpos"]
            pos = qpos[:, :2].double().numpy()
            _stand_in_move(self, self._actions, pos)
            qpos[:, :2] = torch.from_numpy(pos)
            self._pull()

    return HostOnlyWarp()


def time_host(level: str, n: int, backend: str, decisions: int, warmup: int, seed: int) -> dict:
    """Host CPU microseconds per world-decision of one backend's game logic on ``level`` with ``n`` worlds (physics
    and camera stubbed: :data:`HOST_STUBS`), in all and per phase."""
    from evaaa.sensors import SENSORS

    spec = load_level(level)
    modalities = [k for k in SENSORS if k != "pixels"]
    start = time.perf_counter()
    if backend == "cpu":
        sim = Simulator(spec, n, modalities=modalities, seed=seed, threads=1)

        def stand_in(worlds, damage, collided):
            _stand_in_move(sim, sim._actions, sim.state.pos)

        sim._physics = stand_in
    else:
        sim = host_only_warp(spec, n, modalities, seed)
    sim.reset()
    made = time.perf_counter() - start
    phases = Phases()
    names = {"apply_actions": "apply actions", "_physics": "physics stand-in", "_eat": "eat"}
    names |= {"_predators_act": "predators", "_conclude": "physiology and senses"}
    if backend == "warp":
        names |= {"_push": "push", "_pull": "pull"}
    for attr, name in names.items():
        setattr(sim, attr, phases.wrap(name, getattr(sim, attr)))
    sim.triggers.cross = phases.wrap("triggers", sim.triggers.cross)
    sim.daynight.advance = phases.wrap("sun", sim.daynight.advance)
    reset = phases.wrap("reset", sim.reset)
    actions = random_actions(warmup + decisions, n, seed)
    total = 0.0
    for t in range(warmup + decisions):
        if t == warmup:
            for key in phases.seconds:
                phases.seconds[key] = 0.0
            total = 0.0
        sim._actions = actions[t]
        begin = time.process_time()
        sim.apply_actions(actions[t])
        _, _, terminated, truncated, _ = sim.advance(actions[t])
        total += time.process_time() - begin
        done = terminated | truncated
        if done.any():
            reset(done)
    sim.close()
    per = 1e6 / (decisions * n)
    split = {k: v * per for k, v in phases.seconds.items() if k != "reset"}
    split["other"] = total * per - sum(split.values())
    return {
        "level": level,
        "worlds": n,
        "backend": backend,
        "us_per_world_decision": total * per,
        "phases_us": split,
        "reset_us_per_world_decision": phases.seconds["reset"] * per,
        "make_seconds": made,
    }


def measure_host_cost(args) -> dict:
    """``host_cost=true``: the game logic's host CPU time per world-decision with the physics and camera stubbed."""
    results: dict = {
        "host_cost": True,
        "levels": list(args.levels),
        "worlds": list(args.worlds),
        "decisions": args.host_steps,
        "warmup": 3,
        "stubbed": HOST_STUBS,
        "clock": "process CPU time (time.process_time), one thread (torch 1 thread, Simulator threads=1)",
        "processor": processor(),
        "machine": f"{platform.machine()}, {os.cpu_count()} cores",
        "load_average": os.getloadavg(),
        "rows": [],
    }
    print(f"evaaa bench_env host_cost: {results['processor']}, {args.host_steps} decisions, load {os.getloadavg()}")
    print(f"stubbed: {HOST_STUBS}")
    print(f"{'level':<8}{'worlds':>8}{'backend':>9}{'us/world-decision':>19}   per phase (us)")
    for level in args.levels:
        for n in args.worlds:
            for backend in ("cpu", "warp"):
                row = time_host(level, n, backend, args.host_steps, warmup=3, seed=n)
                gc.collect()  # its wrapped methods held the simulator in cycles: free its worlds before the next
                results["rows"].append(row)
                split = ", ".join(f"{k} {v:.2f}" for k, v in row["phases_us"].items())
                print(f"{level:<8}{n:>8}{backend:>9}{row['us_per_world_decision']:>19.2f}   {split}", flush=True)
    results["load_average_after"] = os.getloadavg()
    return results


def _version(package: str) -> str | None:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(package)
    except PackageNotFoundError:
        return None


def measure(args) -> dict:
    from torchrl.envs import ParallelEnv

    level, steps = args.level, args.steps
    results: dict = {
        "level": level,
        "steps": steps,
        "machine": f"{platform.machine()}, {os.cpu_count()} cores",
        "settings": [],
    }

    def row(name, env_rate, raw_rate, target, cores=None, threads=None):
        ratio = env_rate / raw_rate
        per_core = ratio / cores if cores else None
        results["settings"].append(
            {
                "setting": name,
                "env_steps_per_s": env_rate,
                "raw_steps_per_s": raw_rate,
                "ratio": ratio,
                "target": target,
                "cores": cores,
                "ratio_per_core": per_core,
                "threads": threads,
            }
        )
        bound = f">= {target}" if target != "-" else "(report)"
        used = f"{cores:>7.2f}{per_core:>10.2f}" if cores is not None else f"{'':>17}"
        print(f"{name:<40}{env_rate:>12.0f}{raw_rate:>13.0f}{ratio:>8.2f}{used}   {bound}", flush=True)

    print(f"evaaa bench_env: level {level}, {steps} decisions per setting, {results['machine']}")
    print(f"{'setting':<40}{'env steps/s':>12}{'raw steps/s':>13}{'ratio':>8}{'cores':>7}{'per core':>10}   target")

    def env_rows(name: str, n: int, seed: int, target: float) -> None:
        acts = random_actions(steps, n, seed=seed)
        raw = time_raw(level, record_states(level, n, 0, acts))
        default = default_threads()
        variants = [(default, name, target)]  # the env's default, and the other way too
        variants.append((1, f"{name}, one thread", "-") if default > 1 else (2, f"{name}, 2 threads", "-"))
        for threads, label, bound in variants:
            env = EvaaaEnv(level, num_envs=n, seed=0, threads=threads)
            threads = env.sim.threads
            env_rate, cores = time_env(env, acts)
            env.close()
            row(label, env_rate, raw, bound, cores, threads)
        return raw

    raw_one = env_rows("1 env", 1, 1, 0.75)
    # TorchRL's share: the same step loop over an env that simulates nothing.  A single world's physics and frame
    # come one after the other, and the step path after them, so no env can keep more than raw / (raw + this).
    env = IdleEnv(level, num_envs=1, seed=0, threads=1)
    idle_rate, _ = time_env(env, random_actions(steps, 1, seed=1))
    env.close()
    ceiling = 1.0 / (1.0 + raw_one / idle_rate)
    results["torchrl_floor"] = {
        "seconds_per_step": 1.0 / idle_rate,
        "raw_seconds_per_step": 1.0 / raw_one,
        "ceiling_ratio_1_env": ceiling,
    }
    print(
        f"{'  TorchRL step path alone (1 env)':<40}{idle_rate:>12.0f}{'':>13}{'':>8}{'':>17}   "
        f"{1e6 / idle_rate:.0f} us/step: 1 env can keep at most {ceiling:.2f} of raw"
    )
    # one world as a user steps it: TorchRL's rollout (also with every info field asked for), gymnasium; the peer
    rollout_rate, rollout_cores = time_rollout(level, steps)
    info_rate, info_cores = time_rollout(level, steps, info=True)
    gym_rate, gym_cores = time_gym(level, random_actions(steps, 1, seed=1)[:, 0])
    results["rollout"] = {"steps_per_s": rollout_rate, "cores": rollout_cores}
    results["rollout_info"] = {"steps_per_s": info_rate, "cores": info_cores}
    results["gymnasium"] = {"steps_per_s": gym_rate, "cores": gym_cores}
    print(f"{'1 env through env.rollout':<40}{rollout_rate:>12.0f}{'':>13}{'':>8}{rollout_cores:>7.2f}")
    print(f"{'  the same, info=True':<40}{info_rate:>12.0f}{'':>13}{'':>8}{info_cores:>7.2f}")
    print(f"{'1 env through gymnasium':<40}{gym_rate:>12.0f}{'':>13}{'':>8}{gym_cores:>7.2f}")
    if args.peer:
        peer, why = time_peer(Path(args.peer_venv).expanduser(), steps)
        if peer is None:
            print(f"peer MiniWorld-CollectHealth skipped: {why}")
            results["peer"] = {"skipped": why}
        else:
            torchrl_x, gym_x = rollout_rate / peer["steps_per_s"], gym_rate / peer["steps_per_s"]
            results["peer"] = {
                "name": "MiniWorld-CollectHealth-v0, 64x64, LP_NUM_THREADS=0",
                **peer,
                "torchrl_ratio": torchrl_x,
                "gymnasium_ratio": gym_x,
            }
            print(
                f"{'peer: MiniWorld-CollectHealth 64x64':<40}{peer['steps_per_s']:>12.0f}{'':>13}{'':>8}"
                f"{peer['cores']:>7.2f}"
            )
            print(
                f"  1 env / peer: TorchRL (env.rollout) {torchrl_x:.2f}x, gymnasium {gym_x:.2f}x   "
                "(target >= 1.5x each)"
            )
    n = args.num_envs
    env_rows(f"num_envs={n} (1 process)", n, 2, 0.85)

    # two worker processes, one world each and a batch each
    for per_worker in () if args.skip_parallel else (1, n):
        acts = random_actions(steps, 2 * per_worker, seed=3)
        seeds = (10, 11)
        penv = ParallelEnv(
            2, [partial(make_env, level, num_envs=per_worker, seed=s) for s in seeds], mp_start_method="spawn"
        )
        env_rate, _ = time_env(penv, acts)  # the workers' CPU time is not this process's
        penv.close()
        states = [
            record_states(level, per_worker, s, acts[:, i * per_worker : (i + 1) * per_worker])
            for i, s in enumerate(seeds)
        ]
        name = "ParallelEnv(2)" if per_worker == 1 else f"ParallelEnv(2) x num_envs={per_worker}"
        row(name, env_rate, time_raw_parallel(level, states), "-")

    # reset cost
    env = make_env(level, num_envs=1, seed=0)
    step_rate, _ = time_env(env, random_actions(min(steps, 1000), 1, seed=4))
    start = time.perf_counter()
    for _ in range(args.resets):
        env.reset()
    reset_s = (time.perf_counter() - start) / args.resets
    reset_steps = reset_s * step_rate
    results["reset"] = {"seconds": reset_s, "in_steps": reset_steps, "target_steps": 20}
    print(f"reset (1 env): {reset_s * 1e3:.2f} ms = {reset_steps:.1f} steps   (target <= 20 steps)")

    # resident memory over a long run
    td = env.reset()
    acts = torch.from_numpy(random_actions(args.memory_steps, 1, seed=5))
    samples = []
    for t in range(args.memory_steps):
        td["action"] = acts[t]
        _, td = env.step_and_maybe_reset(td)
        if t % 1000 == 999:
            samples.append(rss_mb())
    env.close()
    base = samples[0]
    drift = max(abs(s - base) for s in samples)
    results["memory"] = {
        "steps": args.memory_steps,
        "rss_mb_first": base,
        "rss_mb_last": samples[-1],
        "max_drift_mb": drift,
        "samples_mb": samples,
    }
    print(
        f"memory over {args.memory_steps} steps: RSS {base:.1f} -> {samples[-1]:.1f} MB, "
        f"largest drift {drift:.1f} MB   (target within 10 MB)"
    )
    return results


def main(argv=None) -> int:
    args = cli.parse(BenchConfig, argv, **HELP)
    if args.host_cost:
        results = measure_host_cost(args)
    else:
        results = measure_backends(args) if args.backend == "warp" else measure(args)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        with open(args.json, "w") as f:
            json.dump(results, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
