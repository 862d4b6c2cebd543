"""Record what every level does on this code, step by step, and compare a later code with the recording.

    python scripts/record_trajectories.py out=../recordings/main-ce12fe5/trajectories
    python scripts/record_trajectories.py compare=../recordings/main-ce12fe5/trajectories

For every level and testbed (``levels``): ``num_envs`` worlds on the CPU backend, seeded with ``seed``, all senses
on and every ``info`` field, episodes capped at ``max_steps`` (so that truncations and partial resets happen within
the recording), step through ``steps`` decisions with ``threads`` threads.  The decisions are a seeded mix per world:
stretches of the oracle (which walks to food and water and eats: eating, regrowth, triggers, single-trial ends),
of random actions, of Forward runs (wall hits: contact damage) and of Eat; the oracle decides every step, its action
is taken where the schedule says so.  Every key of every step's tensordict (observations before and after, the
action, reward, done/terminated/truncated, ``info``; pixels in full) is written to ``<level>.npz`` with the worlds'
snapshot at step ``snapshot_at`` (``<level>.snapshot.pt``) and ``manifest.json`` (commit, settings, times).  After
the run, the snapshot is restored and the recorded actions from ``snapshot_at`` on are replayed: the steps must be
the same (checked while recording and while comparing; a later code must restore today's snapshot).

``compare=`` replays the recording's settings on this code and prints one line per level: ``identical`` or the first
step and key that differ (world and index, recorded and new value); exit status 1 when a level differs.  Integers,
booleans and pixels compare exactly; floats bit for bit unless ``atol`` is given.  Recordings are large (about 2 MB a
level): ``out`` is refused inside the repository; without ``out``, they go to
``$EVAAA_RECORDINGS/<commit>/trajectories`` (``~/.cache/evaaa/recordings`` when unset).
"""

from __future__ import annotations

import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

import evaaa
from evaaa_baselines import cli
from evaaa_baselines.cli import option
from evaaa_baselines.recordings import (
    RecordingError,
    check_out,
    check_recording,
    default_out,
    first_difference,
    write_manifest,
)

EXAMPLES = [
    "out=../recordings/main-ce12fe5/trajectories",
    "compare=../recordings/main-ce12fe5/trajectories levels=[4-2] atol=1e-6",
]
PROG = "record_trajectories.py"
TOOL = "record_trajectories"
#: the keys whose values a comparison takes from the recording's manifest, not from the command line
SETTINGS = ("steps", "num_envs", "seed", "max_steps", "threads", "snapshot_at")
#: the schedule of decisions: kind -> (share of the stretches, shortest and longest stretch); Forward runs are long
#: enough to cross half of a 100 m arena (1.9 m a decision) and hit its wall
STRETCHES = {"oracle": (0.5, 5, 40), "random": (0.2, 5, 30), "forward": (0.2, 15, 60), "eat": (0.1, 3, 10)}


@dataclass
class RecordConfig:
    levels: list[str] = option(
        [*evaaa.LEVELS, *evaaa.TESTBEDS],
        "levels and testbeds to record (compare: those of the recording to replay, default all it holds)",
        choices=lambda: [*evaaa.LEVELS, *evaaa.TESTBEDS],
    )
    out: str | None = option(None, "folder to record into (new or empty; outside the repository)")
    compare: str | None = option(None, "a recording's folder: replay its settings here and report the differences")
    atol: float = option(
        0.0, "compare: floats may differ by this much (0: bit for bit)", check=(lambda v: v >= 0, "a number >= 0")
    )
    steps: int = option(300, "decisions recorded per level", check=(lambda v: v >= 1, "a positive integer"))
    num_envs: int = option(2, "worlds stepped together", check=(lambda v: v >= 1, "a positive integer"))
    seed: int = option(0, "seed of the worlds and of the decisions' schedule", check=cli.SEED)
    max_steps: int | None = option(
        120, "episode.max_steps of every level (null: the level's own)", check=(lambda v: v >= 1, "a positive integer")
    )
    threads: int = option(1, "the env's threads (1: all in the calling thread)", check=(lambda v: v >= 1, "at least 1"))
    snapshot_at: int | None = option(
        150, "step whose snapshot is kept and replayed from (null: none)", check=(lambda v: v >= 0, "an integer >= 0")
    )


def check(cfg: RecordConfig, argv: list[str]) -> RecordConfig:
    """The settings to record or compare with, or one line and exit 2."""
    if cfg.compare is not None:
        if cfg.out is not None:
            cli.fail(PROG, "give out= (record) or compare= (replay a recording), not both")
        typed = [k for k in SETTINGS if cli.given(argv, k)]
        if typed:
            cli.fail(PROG, f"{typed[0]}=: compare= replays the recording's own {', '.join(SETTINGS)}")
        try:
            manifest = check_recording(Path(cfg.compare), TOOL)
        except RecordingError as err:
            cli.fail(PROG, str(err))
        recorded = list(manifest["levels"])
        asked = cfg.levels if cli.given(argv, "levels") else recorded
        missing = [name for name in asked if name not in recorded]
        if missing:
            cli.fail(PROG, f"levels={cli.given(argv, 'levels')}: '{missing[0]}' is not in the recording")
        return RecordConfig(**{**asdict(cfg), **manifest["settings"], "levels": asked})
    if cfg.atol:
        cli.fail(PROG, "atol= is for compare=")
    if cfg.snapshot_at is not None and cfg.snapshot_at >= cfg.steps:
        cli.fail(PROG, f"snapshot_at={cfg.snapshot_at}: expected a step below steps ({cfg.steps}), or null")
    try:
        cfg.out = str(check_out(Path(cfg.out) if cfg.out is not None else default_out("trajectories")))
    except RecordingError as err:
        cli.fail(PROG, str(err))
    return cfg


# ------------------------------------------------------------------------------------------------- recording
def schedule(steps: int, num_envs: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``(actions, oracle)``, both ``(steps, num_envs)``: the scripted action of each decision, and whether the
    oracle's action is taken instead.  A pure function of its arguments (its own generator)."""
    from evaaa.sim import EAT, FORWARD, NUM_ACTIONS

    rng = np.random.default_rng([seed, 20261207])
    kinds = list(STRETCHES)
    shares = [STRETCHES[k][0] for k in kinds]
    actions = np.zeros((steps, num_envs), np.int64)
    oracle = np.zeros((steps, num_envs), bool)
    for w in range(num_envs):
        t = 0
        while t < steps:
            kind = kinds[rng.choice(len(kinds), p=shares)]
            end = min(steps, t + int(rng.integers(STRETCHES[kind][1], STRETCHES[kind][2] + 1)))
            oracle[t:end, w] = kind == "oracle"
            actions[t:end, w] = {"forward": FORWARD, "eat": EAT}.get(kind, 0)
            if kind == "random":
                actions[t:end, w] = rng.integers(0, NUM_ACTIONS, end - t)
            t = end
    return actions, oracle


def make(level: str, cfg: RecordConfig):
    overrides = {} if cfg.max_steps is None else {"episode.max_steps": cfg.max_steps}
    return evaaa.make_env(
        level, num_envs=cfg.num_envs, seed=cfg.seed, threads=cfg.threads, info=True, backend="cpu", **overrides
    )


def flat(td) -> dict[str, np.ndarray]:
    """Every leaf of a tensordict as a numpy array, under its key path joined by ``/``."""
    return {"/".join((k,) if isinstance(k, str) else k): v.numpy() for k, v in td.items(True, True)}


def play(level: str, cfg: RecordConfig) -> tuple[dict[str, np.ndarray], dict | None]:
    """Every step's tensordict stacked over the steps, and the snapshot taken before step ``snapshot_at``."""
    import torch

    from evaaa.agents import OracleAgent

    scripted, use_oracle = schedule(cfg.steps, cfg.num_envs, cfg.seed)
    env = make(level, cfg)
    oracle = OracleAgent()
    snapshot, steps = None, []
    try:
        td = env.reset()
        for t in range(cfg.steps):
            if t == cfg.snapshot_at:
                snapshot = env.snapshot()
            planned = oracle.act(env.sim)  # every decision: the oracle plans each new episode as it starts
            td["action"] = torch.from_numpy(np.where(use_oracle[t], planned, scripted[t]))
            step, td = env.step_and_maybe_reset(td)
            steps.append(step.clone())
    finally:
        env.close()
    return flat(torch.stack(steps)), snapshot


def replay(level: str, cfg: RecordConfig, snapshot: dict, actions: np.ndarray) -> dict[str, np.ndarray]:
    """The steps from ``snapshot_at`` on, from the restored snapshot with the recorded actions: the ``next`` keys
    (the first step's observations before the action are those of the reset before the restore)."""
    import torch

    env = make(level, cfg)
    steps = []
    try:
        td = env.reset()
        env.restore(snapshot)
        for t in range(cfg.snapshot_at, cfg.steps):
            td["action"] = torch.from_numpy(actions[t])
            step, td = env.step_and_maybe_reset(td)
            steps.append(step["next"].clone())
    finally:
        env.close()
    return {f"next/{k}": v for k, v in flat(torch.stack(steps)).items()}


def difference(recorded: dict[str, np.ndarray], now: dict[str, np.ndarray], atol: float, first: int = 0) -> str | None:
    """The earliest step at which any key differs, as ``step T, key K, world W[, at I]: recorded X, now Y``
    (``first``: the step the arrays start at), or None where every key is the same."""
    if set(recorded) != set(now):
        gone, new = sorted(set(recorded) - set(now)), sorted(set(now) - set(recorded))
        return f"keys differ: {'recorded only ' + ', '.join(gone) if gone else ''}{'; ' if gone and new else ''}" + (
            f"new {', '.join(new)}" if new else ""
        )
    found = []
    for key in sorted(recorded):
        diff = first_difference(recorded[key], now[key], atol)
        if diff is None:
            continue
        if not diff.index:  # a dtype or shape
            return f"key {key}: {diff}"
        step, world, *rest = diff.index
        where = f", at {rest}" if rest else ""
        found.append(
            (
                step,
                key,
                f"step {first + step}, key {key}, world {world}{where}: recorded {diff.recorded!r}, now {diff.now!r}",
            )
        )
    return min(found)[2] if found else None


def coverage(steps: dict[str, np.ndarray]) -> dict[str, float]:
    """What a recording went through, summed over its steps and worlds (the manifest keeps it per level)."""
    info = {k.removeprefix("next/info/"): v for k, v in steps.items() if k.startswith("next/info/")}
    counts = {k: int(info[k].sum()) for k in ("food_eaten", "water_eaten", "collision", "attacked", "trigger_crossed")}
    return counts | {
        "damage_taken": round(float(info["damage_taken"].sum()), 3),
        "terminated": int(steps["next/terminated"].sum()),
        "truncated": int(steps["next/truncated"].sum()),
    }


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    cfg = check(cli.parse(RecordConfig, argv, prog=PROG, description=__doc__.split("\n\n")[0], examples=EXAMPLES), argv)

    from tqdm import tqdm

    from evaaa_baselines.checkpoint import load_checkpoint, save_checkpoint

    comparing = cfg.compare is not None
    folder = Path(cfg.compare if comparing else cfg.out)
    if not comparing:
        folder.mkdir(parents=True, exist_ok=True)
    lines, took, failed = [], {}, False
    began = time.process_time()
    for level in tqdm(cfg.levels, desc="compare" if comparing else "record", unit="level", dynamic_ncols=True):
        start = time.process_time()
        now, snapshot = play(level, cfg)
        if comparing:
            with np.load(folder / f"{level}.npz") as data:
                recorded = dict(data)
            problem = difference(recorded, now, cfg.atol)
        else:
            np.savez_compressed(folder / f"{level}.npz", **now)
            recorded, problem = now, None
        if problem is None and cfg.snapshot_at is not None:
            if comparing:  # today's snapshot, restored by this code
                snapshot = load_checkpoint(folder / f"{level}.snapshot.pt")["snapshot"]
            else:
                save_checkpoint({"snapshot": snapshot}, folder / f"{level}.snapshot.pt")
            again = replay(level, cfg, snapshot, recorded["action"])
            part = {k: v[cfg.snapshot_at :] for k, v in recorded.items() if k in again}
            problem = difference(part, again, cfg.atol, first=cfg.snapshot_at)
            problem = problem and f"restored from the snapshot at step {cfg.snapshot_at}: {problem}"
        took[level] = {"cpu_seconds": round(time.process_time() - start, 1), **coverage(now)}
        failed |= problem is not None
        size = f"{cfg.steps} steps x {cfg.num_envs} worlds, {len(now)} keys"
        if not comparing:
            size += ", " + ", ".join(f"{k} {v}" for k, v in took[level].items() if k != "cpu_seconds")
        lines.append(
            f"{level}: {'identical' if comparing else 'recorded'} ({size})"
            if problem is None
            else f"{level}: {problem}"
        )
    if not comparing:
        write_manifest(
            folder,
            TOOL,
            {k: getattr(cfg, k) for k in SETTINGS},
            levels=took,
            cpu_seconds=round(time.process_time() - began, 1),
        )
    print("\n".join(lines))
    print(f"{'compared with' if comparing else 'recorded in'} {folder} in {time.process_time() - began:.0f} s of CPU")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
