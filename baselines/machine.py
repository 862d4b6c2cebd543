"""The machine a process runs on: the processor a measurement ran on, and how the process uses its memory.

The processor is named for benchmark files and the protocol's CPU-time account.

CPU-minutes bought different numbers of env steps on the processors a session may draw, so a compute-matched run
and a benchmark name theirs. Linux reports ``model name`` from ``/proc/cpuinfo``; where that is a family's name only
(``AMD EPYC``), its family and model numbers tell the generations apart."""

from __future__ import annotations

import ctypes
import ctypes.util
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


#: glibc's ``mallopt`` parameters (malloc.h)
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
#: blocks up to this size come from the heap and are reused once freed: a batch of stacked frames (50 MB for PPO's
#: 1,024 transitions) and every float copy of it otherwise cost a fresh mmap and a page fault per 4 KiB each time
REUSED_BLOCK_BYTES = 1 << 30


def keep_freed_memory() -> bool:
    """Make glibc's malloc keep freed blocks of up to 1 GiB for reuse instead of returning them to the system.

    A training loop allocates and frees the same large tensors every iteration (uint8 frames to float, minibatch
    copies, activations); by default glibc serves each one over 32 MiB (and, as its threshold adapts, many smaller
    ones) by a fresh ``mmap``, so every use page-faults its memory in again: measured on an AMD EPYC (family 25,
    model 1), converting 256 stacked 64x64x12 frames to float took 50 ms instead of 25, copying them 55 ms instead
    of 11 (scripts/bench_train.py's time split shows the effect on a whole loop).  The price is a resident size
    that stays at its high-water mark.  Returns whether the setting took (False where the C library is not glibc).
    """
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, REUSED_BLOCK_BYTES) and mallopt(_M_TRIM_THRESHOLD, 2**31 - 1))
