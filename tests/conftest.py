"""Test-suite ordering for CI's two workers (``make test``: ``-n auto --dist loadfile --no-loadscope-reorder``).

xdist hands whole files to its workers in collection order; a file that takes minutes and starts last keeps one
worker busy while the other waits.  The files below took the most time in CI's ``--durations`` report (slowest
first), so they are collected first and the short files fill in behind them.  The order changes nothing a test
does or asserts."""

from __future__ import annotations

from pathlib import Path

import pytest

#: the longest files of the suite in CI (seconds of their tests summed, largest first; measured on the 2-core box)
LONGEST_FIRST = (
    "test_protocol.py",
    "test_cluster.py",
    "test_launchers.py",
    "test_train.py",
    "test_dreamer.py",
    "test_fuzz_levels.py",
    "test_testbeds.py",
    "test_run_records.py",
    "test_cli.py",
    "test_dreamer_update.py",
    "test_bench_train.py",
    "test_packaging.py",
)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    # a stable sort: the listed files first in the listed order, every other file after them as collected
    items.sort(key=lambda item: rank.get(Path(str(item.fspath)).name, len(rank)))
