"""Human play in the browser: a person plays a level or testbed with the keyboard, recorded like an agent.

This script is the command line of the play server (:mod:`evaaa.play`: the simulator, the JSON API, the page, the
records).  Every episode that ends is appended to ``<out>/episodes.csv`` with ``policy="human"``, the participant id
and the level: the rows the evaluation tool writes for agents, so a report can put people beside them.

    python scripts/play.py level=1-1 participant=p01                 # then open http://127.0.0.1:8000/
    python scripts/play.py level=1-2 participant=p02 rate=5 seed=3 port=8080 out=outputs/human
    python scripts/play.py level=1-1 overrides.episode.max_steps=200 # any level field, by its dotted path
    python scripts/play.py level_dir=my-levels level=maze           # my-levels/maze.yaml (the page offers them all)
    python scripts/play.py level=path/to/my.yaml                    # one level file of your own

Keys: up = forward, left/right = turn, space = eat, period = do nothing, Enter = new episode once one ended.
Steps advance on each key press; with ``rate=R`` they advance R times a second instead, a second without a
key doing nothing (action 0).  The server answers only this machine's own page (see :mod:`evaaa.play`).
"""

from __future__ import annotations

import sys
from collections.abc import Mapping
from dataclasses import replace
from typing import Any

from evaaa.level import LevelError
from evaaa.level_files import load_level
from evaaa.play import PlaySettings, register_level_dir, serve
from evaaa_baselines import cli


class UsageError(ValueError):
    """A command-line argument is invalid; the message says which and what is allowed."""


DESCRIPTION = "Serve a page where a person plays an evaaa level with the keyboard; every finished episode is recorded."


def usage() -> str:
    return cli.usage(
        PlaySettings,
        "play.py",
        DESCRIPTION,
        ["level=1-1 participant=p01 rate=5", "level=1-1 overrides.episode.max_steps=200"],
    )


def _dotted(overrides: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested overrides as ``{"a.b": value}``, the form make_env and load_level document."""
    flat: dict[str, Any] = {}
    for key, value in overrides.items():
        if isinstance(value, Mapping) and value:
            flat.update(_dotted(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def parse_args(argv: list[str]) -> PlaySettings:
    """The settings from ``key=value`` arguments.  Raises :class:`UsageError` (one line naming the key)."""
    try:
        # the levels of level_dir are registered before the values are checked: level= may name one of them
        first = cli.read(PlaySettings, argv, checks=False)
        if first.level_dir is not None:
            register_level_dir(first.level_dir)
        if first.level.endswith((".yaml", ".yml")):  # a level file of your own, by its path: played by its name
            from evaaa_baselines.config import ConfigError, level_file

            try:
                name = level_file(first.level, "level")
            except ConfigError as exc:
                raise UsageError(str(exc)) from None
            argv = [f"level={name}" if a.partition("=")[0].lstrip("+") == "level" else a for a in argv]
        options = cli.read(PlaySettings, argv)
    except cli.UsageError as exc:
        raise UsageError(str(exc)) from None
    except LevelError as exc:
        raise UsageError("level_dir: " + " ".join(str(exc).split())) from None
    options = replace(options, overrides=_dotted(options.overrides))
    try:  # fail here, before a port is taken, on a bad override
        load_level(options.level, options.overrides)
    except LevelError as exc:
        raise UsageError("overrides: " + " ".join(str(exc).split())) from None
    return options


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if any(a in ("-h", "--help") for a in argv):
        print(usage())
        return 0
    try:
        options = parse_args(argv)
    except UsageError as exc:
        print(f"play.py: error: {exc}", file=sys.stderr)
        return 2
    return serve(options, "play.py")


if __name__ == "__main__":
    sys.exit(main())
