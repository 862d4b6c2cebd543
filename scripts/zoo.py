"""List the zoo of trained networks (``policy=zoo:<name>``), or add one to it from a run's model file.

    python scripts/zoo.py                                                        # list, checking each file's sha256
    python scripts/zoo.py name=ppo-1-1 model=<run>/model-0-1-1.pt replace=true   # replace ppo-1-1

Adding copies the file to ``baselines/zoo/<name>.pt`` and records in ``baselines/zoo/zoo.yaml`` its sha256 and the
algorithm, level, seed and env steps of the checkpoint's own record; the command that trained it is read from the
run's ``.hydra/overrides.yaml`` (or given as ``command=``).  Its validation and test survival start empty
(``null``): fill them in from an evaluation of that network (``scripts/evaluate.py policy=[zoo:<name>]``).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

from evaaa_baselines import cli, zoo
from evaaa_baselines.cli import option

PROG = "zoo.py"


@dataclass
class ZooConfig:
    name: str | None = option(None, "the network's name (policy=zoo:<name>); with model=, adds it; e.g. ppo-1-1")
    model: str | None = option(None, "the checkpoint to add (a run's model-<stage>-<level>.pt)")
    command: str | None = option(
        None, "the command that trained it (default: read from the run's .hydra/overrides.yaml)"
    )
    note: str = option("", "a line on what the network is")
    replace: bool = option(False, "replace a network of that name (its survival fields are cleared)")


def main(argv: list[str] | None = None) -> int:
    cfg = cli.parse(
        ZooConfig,
        argv,
        prog=PROG,
        description=__doc__.split("\n\n")[0],
        examples=["name=ppo-1-1 model=runs/1-1/ppo/all-squared/seed0/model-0-1-1.pt replace=true"],
    )
    if (cfg.name is None) != (cfg.model is None):
        cli.fail(PROG, "name= and model= go together (both to add a network, neither to list the zoo)")
    if cfg.name is None:
        return _list()
    if not zoo.NAME.match(cfg.name):
        cli.fail(PROG, f"name={cfg.name}: expected lower-case letters, digits, '.', '_' or '-' (e.g. ppo-1-1)")
    if not Path(cfg.model).is_file():
        cli.fail(PROG, f"model={cfg.model}: no such file; give a checkpoint such as <run>/model-0-1-1.pt")
    model = Path(cfg.model)
    try:
        added = _add(cfg, model)
    except ValueError as err:  # CheckpointError included: the file does not load as a policy
        cli.fail(PROG, str(err))
    print(
        f"zoo:{added.name} <- {cfg.model}: {added.algo} on {added.level}, seed {added.seed}, "
        f"{added.env_steps} env steps, sha256 {added.sha256[:12]}...; trained by: {added.trained_by}"
    )
    print(f"wrote {added.path()} and {zoo.ZOO_DIR / zoo.MANIFEST}")
    return 0


def _add(cfg: ZooConfig, model: Path) -> zoo.ZooEntry:
    """Add ``model`` as ``cfg.name``, with the values of its own record, once it loads as a policy."""
    from evaaa_baselines.checkpoint import load_checkpoint
    from evaaa_baselines.policies import load_policy

    if cfg.name in zoo.entries() and not cfg.replace:  # before torch reads the file
        raise ValueError(f"name={cfg.name}: the zoo already holds zoo:{cfg.name}; add replace=true to replace it")
    loaded = load_policy(model)  # refuses (CheckpointError) what would not load back from the zoo
    state = load_checkpoint(model)
    return zoo.add(
        cfg.name,
        model,
        algo=loaded.algo,
        level=loaded.level,
        seed=(state.get("config") or {}).get("seed"),
        env_steps=None if state.get("env_steps") is None else int(state["env_steps"]),
        command=cfg.command if cfg.command is not None else zoo.trained_by(model),
        note=cfg.note,
        replace=cfg.replace,
    )


def _list() -> int:
    try:
        known = zoo.entries()
    except zoo.ZooError as err:
        cli.fail(PROG, str(err))
    bad = 0
    for name, e in known.items():
        path = e.path()
        state = "missing" if not path.is_file() else "ok" if zoo.sha256(path) == e.sha256 else "sha256 DIFFERS"
        bad += state != "ok"
        print(
            f"zoo:{name}  {e.algo} on {e.level}, seed {e.seed}, {e.env_steps} env steps  "
            f"validation {e.survival_text(e.validation_survival)}, test {e.survival_text(e.test_survival)}  "
            f"[{state}] {path}"
        )
    if not known:
        print(f"the zoo ({zoo.ZOO_DIR / zoo.MANIFEST}) holds no network")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
