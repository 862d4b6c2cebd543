"""Pack a record's runs for committing: each run's logs/scalars/**/*.csv (one file per scalar) become one file,
logs/scalars.csv, and the paths in its Hydra files become relative to the folder it ran in.

    python scripts/pack_record.py root=docs/results/paper-cpu/record

A protocol's committed record (``scripts/reproduce.py``) keeps every run's CSV logs; the CSV logger writes some
twenty files a run, so a record of 64 runs held some 1,500 of them.  Packed, a run holds one, with every row as it
was (``tag,step,value``); ``scripts/bench_train.py`` and ``evaaa_baselines.logs.read_scalar`` read either
form, and ``scripts/report.py`` reads neither (it reads ``episodes.csv``, ``eval.csv`` and the evaluations).  Pack
a record once its protocol has finished: a run resumed later writes per-scalar files again, which readers take after
the packed rows, and packing again folds them in.  Run directories are those with ``.hydra/config.yaml``.

Hydra's own record of a run (``.hydra/hydra*.yaml``, which nothing here reads) names the folder the run was started
in (``hydra.runtime.cwd``: the repository root, where every cell runs) and paths under it; those become relative
to it (``cwd: .``, ``output_dir: docs/results/...``), so the record names no folder of the machine it was made on.
"""

from __future__ import annotations

import re
import sys
from dataclasses import dataclass
from pathlib import Path

import yaml

from evaaa_baselines import cli
from evaaa_baselines.cli import option
from evaaa_baselines.logs import pack

_CWD = re.compile(r"^\s*cwd: (/.*)$", re.M)


def relative_paths(run_dir: Path) -> int:
    """Make the paths of the run's ``.hydra/hydra*.yaml`` relative to the folder it ran in (their ``cwd``); returns
    how many files changed."""
    changed = 0
    for path in sorted((run_dir / ".hydra").glob("hydra*.yaml")):
        text = path.read_text()
        found = _CWD.search(text)
        if found is None:
            continue
        cwd = found.group(1).rstrip("/")
        new = re.sub(rf"(?<=: ){re.escape(cwd)}$", ".", text.replace(cwd + "/", ""), flags=re.M)
        if cwd in new:
            raise SystemExit(
                f"pack_record.py: {path} names {cwd} in a way this script does not rewrite; left as it was"
            )
        yaml.safe_load(new)  # still YAML
        if new != text:
            path.write_text(new)
            changed += 1
    return changed


@dataclass
class PackConfig:
    root: str = option("", "the folder whose run directories (at any depth) are packed, e.g. a protocol's record")


def main(argv: list[str] | None = None) -> int:
    cfg = cli.parse(
        PackConfig,
        argv,
        prog="pack_record.py",
        description=__doc__.split("\n\n")[0],
        examples=["root=docs/results/paper-cpu/record"],
    )
    root = Path(cfg.root)
    if not cfg.root or not root.is_dir():
        cli.fail(
            "pack_record.py",
            f"root={cfg.root}: not a folder; give the record's folder, e.g. root=docs/results/paper-cpu/record",
        )
    runs = sorted(p.parent.parent for p in root.rglob(".hydra/config.yaml"))
    files = hydra = 0
    for run in runs:
        files += pack(run)
        hydra += relative_paths(run)
    print(
        f"pack_record.py: {len(runs)} run directories under {root}; {files} scalar files packed into "
        f"logs/scalars.csv; {hydra} Hydra files given relative paths"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
