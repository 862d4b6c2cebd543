"""The processor a measurement ran on, named for benchmark files and the protocol's CPU-time account.

CPU-minutes bought different numbers of env steps on the processors a session may draw, so a compute-matched run
and a benchmark name theirs. Linux reports ``model name`` from ``/proc/cpuinfo``; where that is a family's name only
(``AMD EPYC``), its family and model numbers tell the generations apart."""

from __future__ import annotations

import platform
from pathlib import Path


def processor(cpuinfo: Path = Path("/proc/cpuinfo")) -> str:
    """``model name (family F, model M)`` of the first CPU in ``cpuinfo``; Python's own name for the processor where
    that file cannot be read (not Linux)."""
    fields: dict[str, str] = {}
    try:
        for line in cpuinfo.read_text().splitlines():
            if not line.strip():
                break  # the first CPU's block ends
            key, _, value = line.partition(":")
            fields.setdefault(key.strip(), value.strip())
    except OSError:
        pass
    name = fields.get("model name")
    if not name:
        return platform.processor() or platform.machine()
    if "cpu family" in fields and "model" in fields:
        return f"{name} (family {fields['cpu family']}, model {fields['model']})"
    return name
