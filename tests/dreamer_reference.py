"""A recording of what the DreamerV3 code does, to compare code before and after a change that must not alter it
(issue 49: ``dreamer.py`` put in parts; issue 46: the update reworked for speed).

``record(out)`` writes, with fixed seeds and one torch thread:

* three seeded ``preset=debug`` training runs — ``algo=dreamer``, ``algo=dreamer_xs``, and ``algo=dreamer`` with
  every optional loss and replay path on (``aids``: consume and terminal shares, replayed critic loss, vector and
  prior-vector reconstruction terms, raw keys, reward scale, buffer in memory) — each a whole run directory:
  checkpoint (every weight, the three optimiser states, critic and slow critic, return normalisation, replay
  state, counters), final models, episodes/eval/train CSVs, open-loop pictures, the memory-mapped replay;
* acting trajectories of the trained ``algo=dreamer`` model loaded with ``load_policy`` (every key of every step,
  under both exploration types) and of a fresh seeded model through ``make_model`` / ``make_transforms`` /
  ``acting_policy`` (the training policy);
* the offline probes' results on that run (``ev_decoding_errors``, ``imagined_action_values``,
  ``eat_success_readout``, ``fit_world_model``).

``compare(a, b)`` lists every difference between two recordings (tensors with ``torch.equal``, CSV rows with their
wall-clock columns left out, pictures byte for byte).  The recording depends on the machine (CPU kernels), so it is
compared with one made on the same machine: record before a change, then run
``EVAAA_DREAMER_REFERENCE=<dir> pytest tests/test_dreamer_reference.py`` after it.

    python tests/dreamer_reference.py record /tmp/before
    python tests/dreamer_reference.py compare /tmp/before /tmp/after
"""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch

#: the runs recorded: name -> algo and extra overrides
RUNS = {
    "dreamer": ("dreamer", ()),
    # the reward it trained on before squared_death became its default
    "dreamer_xs": ("dreamer_xs", ("reward=squared",)),
    "aids": (
        "dreamer",
        (
            "algo.consume_share=0.25",
            "algo.terminal_share=0.25",
            "algo.critic.replay_scale=0.3",
            "algo.world_model.vector_scale=10",
            "algo.world_model.prior_vector_scale=1",
            "algo.world_model.raw_keys=[interoception]",
            "algo.reward_scale=2",
            "algo.buffer_on_disk=false",
        ),
    ),
}
TOTAL = 256
#: what differs between two identical runs: wall-clock and CPU time, and where the run lived
TIMING = {
    "seconds",
    "wall_seconds",
    "cpu_seconds",
    "time",
    "wall_time",
    "steps_per_second",
    "env_steps_per_second",
    "updates_per_second",
    "seconds_per_update",
    "cpu_minutes",
    "wall_minutes",
    "timestamp",
    "date",
    "update_seconds",
    "sps",
    "fps",
}
PLACES = {"on_disk", "run_dir", "dir", "path", "log_dir"}
#: the logger's record of env steps per second (the checkpoint's copy of logs/scalars/time/)
RATES = "time/"


def _cfg(algo: str, *overrides: str):
    from hydra import compose, initialize_config_dir

    from evaaa_baselines.paths import CONF_DIR

    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        return compose(
            "config",
            overrides=[
                f"algo={algo}",
                "preset=debug",
                "logger=csv",
                "progress=false",
                "threads=1",
                f"total_steps={TOTAL}",
                "seed=0",
                *overrides,
            ],
        )


def _trajectory(policy, env, steps: int) -> dict[str, torch.Tensor]:
    td = env.reset()
    frames = []
    for _ in range(steps):
        td = policy(td)
        frames.append(td.clone())
        _, td = env.step_and_maybe_reset(td)
    return torch.stack(frames).to_dict()


def record(out: Path) -> None:
    from tensordict.nn import InteractionType, set_interaction_type

    import evaaa
    from evaaa_baselines import load_policy
    from evaaa_baselines.config import register_levels
    from evaaa_baselines.training import train

    register_levels()
    torch.set_num_threads(1)
    out.mkdir(parents=True, exist_ok=True)
    for name, (algo, overrides) in RUNS.items():
        train(_cfg(algo, *overrides), out / name)

    run = out / "dreamer"
    loaded = load_policy(run / "model-0-1-1.pt", modalities=evaaa.MODALITIES)
    trajectories = {}
    for kind in (InteractionType.DETERMINISTIC, InteractionType.RANDOM):
        env = loaded.make_env(num_envs=2, seed=3)
        try:
            torch.manual_seed(7)
            with set_interaction_type(kind):
                trajectories[f"loaded_{kind.name.lower()}"] = _trajectory(loaded, env, 60)
        finally:
            env.close()
    trajectories["fresh_acting"] = _fresh_acting()
    torch.save(trajectories, out / "trajectories.pt")

    probes = _probes(run)
    (out / "probes.json").write_text(json.dumps(probes, indent=1, sort_keys=True))


def _fresh_acting() -> dict[str, torch.Tensor]:
    """A fresh seeded model acting through the training policy, in the env its transforms make."""
    import evaaa
    from evaaa_baselines.config import observation_keys
    from evaaa_baselines.dreamer import model as dreamer_model
    from evaaa_baselines.rollout import wrap_env

    cfg = _cfg("dreamer")
    keys = observation_keys(cfg)
    torch.manual_seed(11)
    base = evaaa.make_env("1-1", num_envs=2, seed=5, modalities=keys, episode={"max_steps": 48})
    shapes = {k: tuple(base.observation_spec[k].shape[1:]) for k in keys}
    model = dreamer_model.make_model(cfg.algo, shapes)
    env = wrap_env(base, dreamer_model.make_transforms(cfg.algo, keys, model))
    try:
        return _trajectory(dreamer_model.acting_policy(model), env, 40)
    finally:
        env.close()


def _probes(run: Path) -> dict[str, Any]:
    from evaaa_baselines.dreamer import probes

    torch.manual_seed(3)
    return {
        "ev_decoding_errors": probes.ev_decoding_errors(run, sequences=4),
        "imagined_action_values": probes.imagined_action_values(run, sequences=4, samples=2),
        "eat_success_readout": probes.eat_success_readout(run),
        # every row but its wall-clock seconds
        "fit_world_model": [
            {k: v for k, v in row.items() if k != "seconds"}
            for row in probes.fit_world_model(run, updates=4, every=2, overrides=["consume_share=0.5"], held_out=0.25)
        ],
    }


# ------------------------------------------------------------------------------------------------ comparison
def _same(a: Any, b: Any, where: str, out: list[str]) -> None:
    if isinstance(a, torch.Tensor) or isinstance(b, torch.Tensor):
        if not (
            isinstance(a, torch.Tensor)
            and isinstance(b, torch.Tensor)
            and a.dtype == b.dtype
            and a.shape == b.shape
            and torch.equal(a, b)
        ):
            out.append(f"{where}: tensors differ")
    elif isinstance(a, np.ndarray) or isinstance(b, np.ndarray):  # generator states kept by the checkpoint
        if not (
            isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.dtype == b.dtype and np.array_equal(a, b)
        ):
            out.append(f"{where}: arrays differ")
    elif hasattr(a, "to_dict") and hasattr(b, "to_dict"):  # tensordicts
        _same(a.to_dict(), b.to_dict(), where, out)
    elif isinstance(a, dict) and isinstance(b, dict):
        if a.keys() != b.keys():
            out.append(f"{where}: keys differ: {sorted(map(str, a.keys() ^ b.keys()))}")
        for k in a.keys() & b.keys():
            if k in TIMING or k in PLACES or (isinstance(k, str) and k.startswith(RATES)):
                continue
            _same(a[k], b[k], f"{where}.{k}", out)
    elif isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        if len(a) != len(b):
            out.append(f"{where}: lengths differ ({len(a)}, {len(b)})")
        for i, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{where}[{i}]", out)
    elif a != b and not (a != a and b != b):  # NaN equals NaN here
        out.append(f"{where}: {a!r} != {b!r}")


def _csv(path: Path) -> list[list[str]]:
    """The rows of a CSV file without its wall-clock columns (named in its header, if it has one)."""
    with path.open() as f:
        rows = list(csv.reader(f))
    keep = [i for i, name in enumerate(rows[0] if rows else []) if name not in TIMING]
    return [[row[i] for i in keep if i < len(row)] for row in rows]


def compare(a: Path, b: Path) -> list[str]:
    """Every difference between the recordings ``a`` and ``b`` (empty: identical)."""
    from tensordict import TensorDict

    from evaaa_baselines.checkpoint import load_checkpoint

    out: list[str] = []
    for name in RUNS:
        ra, rb = a / name, b / name
        files_a = sorted(p.relative_to(ra) for p in ra.rglob("*") if p.is_file())
        files_b = sorted(p.relative_to(rb) for p in rb.rglob("*") if p.is_file())
        if files_a != files_b:
            out.append(f"{name}: files differ: {sorted(set(map(str, files_a)) ^ set(map(str, files_b)))}")
        for rel in files_a:
            fa, fb = ra / rel, rb / rel
            if not fb.exists():
                continue
            where = f"{name}/{rel}"
            if fa.suffix == ".pt":
                _same(load_checkpoint(fa), load_checkpoint(fb), where, out)
            elif fa.suffix == ".csv" and "time" not in rel.parts:  # logs/scalars/time/: env steps per second
                if _csv(fa) != _csv(fb):
                    out.append(f"{where}: rows differ")
            elif fa.suffix == ".png":
                if fa.read_bytes() != fb.read_bytes():
                    out.append(f"{where}: pictures differ")
        if (ra / "replay").is_dir():
            for stage in sorted(p for p in (ra / "replay").iterdir() if p.is_dir()):
                _same(
                    TensorDict.load_memmap(stage).to_dict(),
                    TensorDict.load_memmap(rb / "replay" / stage.name).to_dict(),
                    f"{name}/replay/{stage.name}",
                    out,
                )
    _same(
        torch.load(a / "trajectories.pt", weights_only=True),
        torch.load(b / "trajectories.pt", weights_only=True),
        "trajectories",
        out,
    )
    _same(json.loads((a / "probes.json").read_text()), json.loads((b / "probes.json").read_text()), "probes", out)
    return out


def main(argv: list[str]) -> int:
    if argv[:1] == ["record"] and len(argv) == 2:
        record(Path(argv[1]))
        return 0
    if argv[:1] == ["compare"] and len(argv) == 3:
        differences = compare(Path(argv[1]), Path(argv[2]))
        print("\n".join(differences) or "identical")
        return 1 if differences else 0
    print(__doc__.rsplit("\n\n", 1)[-1], file=sys.stderr)
    return 2


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
