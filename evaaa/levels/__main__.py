"""Print a level as the env builds it: its file and every file it ``extends`` merged, the overrides applied, every
field present (defaults included) and validated.

    python -m evaaa.levels                       # the packaged levels and testbeds, by name
    python -m evaaa.levels 3-2                   # level 3-2, fully resolved, as YAML
    python -m evaaa.levels 3-2 episode.max_steps=2000 reward.name=drive_reduction
    python -m evaaa.levels path/to/my.yaml --json

An override is ``dotted.path=value``, the value read as YAML (``2000``, ``true``, ``[1, 2]``), as
``evaaa.load_level(name, {path: value})`` takes it.
"""

from __future__ import annotations

import argparse
import json
import sys

import yaml

from ..level import LevelError
from ..level_files import LEVELS, TESTBEDS, load_level, registered_levels


def _override(text: str) -> tuple[str, object]:
    path, sep, value = text.partition("=")
    if not sep or not path:
        raise argparse.ArgumentTypeError(f"an override is dotted.path=value, got {text!r}")
    try:
        return path, yaml.safe_load(value)
    except yaml.YAMLError as err:
        raise argparse.ArgumentTypeError(f"override {path!r}: {value!r} is not a YAML value ({err})") from None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m evaaa.levels",
        description="Print a level fully resolved: extends applied, overrides applied, every field present.",
    )
    parser.add_argument("level", nargs="?", help="a packaged level's name, or a path to a .yaml level file")
    parser.add_argument("overrides", nargs="*", type=_override, help="dotted.path=value level-field changes")
    parser.add_argument("--json", action="store_true", help="print JSON instead of YAML")
    args = parser.parse_args(argv)
    if args.level is None:
        print("training levels:", " ".join(LEVELS))
        print("testbeds:", " ".join(TESTBEDS))
        if registered_levels():
            print("registered:", " ".join(registered_levels()))
        return 0
    try:
        level = load_level(args.level, dict(args.overrides))
    except LevelError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    tree = level.model_dump(mode="json")
    if args.json:
        print(json.dumps(tree, indent=2))
    else:
        print(yaml.safe_dump(tree, sort_keys=False, default_flow_style=None, width=120), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
