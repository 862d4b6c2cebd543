"""Pack the scalar logs of a record's runs: each run's logs/scalars/**/*.csv (one file per scalar) become one file,
logs/scalars.csv.

    python scripts/pack_record.py root=docs/results/paper-cpu/record

A protocol's committed record (``scripts/reproduce.py``) keeps every run's CSV logs; the CSV logger writes some
twenty files a run, so a record of 64 runs held some 1,500 of them.  Packed, a run holds one, with every row as it
was (``tag,step,value``); ``scripts/bench_train.py`` and ``evaaa_baselines.scalar_log.read_scalar`` read either
form, and ``scripts/report.py`` reads neither (it reads ``episodes.csv``, ``eval.csv`` and the evaluations).  Pack
a record once its protocol has finished: a run resumed later writes per-scalar files again, which readers take after
the packed rows, and packing again folds them in.  Run directories are those with ``.hydra/config.yaml``.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

from evaaa_baselines import cli
from evaaa_baselines.cli import option
from evaaa_baselines.scalar_log import pack


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
            f"root={cfg.root!r}: not a folder; give the record's folder, e.g. root=docs/results/paper-cpu/record",
        )
    runs = sorted(p.parent.parent for p in root.rglob(".hydra/config.yaml"))
    files = 0
    for run in runs:
        files += pack(run)
    print(
        f"pack_record.py: {len(runs)} run directories under {root}; {files} scalar files packed into logs/scalars.csv"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
