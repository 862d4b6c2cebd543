"""Checkpoint files and RNG states: atomic writes, loading, and the global generators a resumed run must restore.

A checkpoint is one ``torch.save`` file (``checkpoint.pt`` for the latest state of a run, ``model-*.pt`` for a
stage's final network) holding a dict whose ``format`` is :data:`CHECKPOINT_FORMAT`; ``baselines/runtime.py``
decides what goes in, ``baselines/evaluation.py`` reads the network back.
"""

from __future__ import annotations

import os
import random
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

CHECKPOINT = "checkpoint.pt"
CHECKPOINT_FORMAT = 1


def save_atomic(obj: Any, path: Path) -> None:
    """``torch.save`` that never leaves a half-written file: temp file in the same directory, fsync, rename."""
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as f:
        torch.save(obj, f)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    dir_fd = os.open(path.parent, os.O_RDONLY)  # make the rename itself durable
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)


def load_checkpoint(path: str | Path, map_location: str | torch.device = "cpu") -> dict:
    # checkpoints hold tensordicts, numpy arrays and RNG states, not only tensors: they are this project's own files
    return torch.load(path, map_location=map_location, weights_only=False)


def seed_everything(seed: int) -> None:
    torch.manual_seed(seed)
    np.random.seed(seed % 2**32)
    random.seed(seed)


def rng_state() -> dict:
    state = {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate()}
    if torch.cuda.is_initialized():  # updates on a GPU draw from its generators
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_rng_state(state: Mapping) -> None:
    torch.set_rng_state(state["torch"])
    np.random.set_state(state["numpy"])
    random.setstate(state["python"])
    if "cuda" in state and torch.cuda.is_available() and len(state["cuda"]) == torch.cuda.device_count():
        torch.cuda.set_rng_state_all([s.cpu() for s in state["cuda"]])
