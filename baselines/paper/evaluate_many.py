"""Several ``scripts/evaluate.py`` commands of one cell in one Python process, so that torch, TorchRL and MuJoCo
are imported once per cell rather than once per command (about 7 of the 12 CPU-seconds of a one-episode
evaluation on the 2-core AMD EPYC box).

    python -m evaaa_baselines.paper.evaluate_many '{"threads": 1, "commands": [["scripts/evaluate.py", ...], ...]}'

Each command runs as ``evaluate.py``'s own ``main`` with its own arguments, after a ``== <UTC time> <command>`` line
in the output (the same line the runner writes before a command of its own), in order; the first that fails ends
the batch with its exit status.  An evaluation seeds what it draws (the worlds, the sampled actions, epsilon's
draws) from its ``seed``, so a command gives the same episodes here as run alone."""

from __future__ import annotations

import importlib.util
import json
import sys
from types import ModuleType

from .cell_status import utc_stamp
from .cells import Command
from .protocol import REPO

SCRIPT = "scripts/evaluate.py"


def batchable(cmd: Command) -> bool:
    """A command this module can run: an evaluate.py command."""
    return bool(cmd.argv) and cmd.argv[0] == SCRIPT


def batch_command(commands: list[Command], threads: int) -> Command:
    """One command that runs ``commands`` (each :func:`batchable`) in one process."""
    spec = {"threads": threads, "commands": [c.argv for c in commands]}
    return Command(["-m", __name__, json.dumps(spec)])


def _evaluate_script() -> ModuleType:
    spec = importlib.util.spec_from_file_location("evaaa_evaluate_script", REPO / SCRIPT)
    module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    sys.modules[spec.name] = module  # type: ignore[union-attr]  # its dataclasses look their module up there
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module


def _exit_status(err: SystemExit) -> int:
    if err.code is None or isinstance(err.code, int):
        return err.code or 0
    print(err.code, file=sys.stderr)  # a message, as the interpreter prints one at exit
    return 1


def main(argv: list[str]) -> int:
    spec = json.loads(argv[0])
    script = _evaluate_script()
    for args in spec["commands"]:
        if not batchable(Command(args)):
            raise SystemExit(f"evaluate_many: not an evaluate.py command: {args!r}")
        print(f"\n== {utc_stamp()} {Command(args).text(spec['threads'])}", flush=True)
        try:
            rc = script.main(args[1:])
        except SystemExit as err:
            rc = _exit_status(err)
        sys.stdout.flush()
        sys.stderr.flush()
        if rc:
            return rc
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
