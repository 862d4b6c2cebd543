"""Where the networks run: ``device=`` resolved to a ``torch.device`` (:func:`resolve_device`), CUDA's deterministic
kernels, bf16 autocast, and :class:`OnDevice`, a policy on the GPU acting on tensordicts of CPU worlds.

The worlds live on the CPU; the networks, losses, optimisers and replay live on ``device``.  Acting sends each step's
observations to the device and brings the policy's outputs back.
"""

from __future__ import annotations

import os
import re

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase


class DeviceError(ValueError):
    """``device=`` names a device this machine does not have, or is not a device at all."""


def resolve_device(spec: str | torch.device) -> torch.device:
    """``auto`` (CUDA when available, else the CPU), ``cpu``, ``cuda`` or ``cuda:N`` as a ``torch.device``;
    :class:`DeviceError` names the key and the allowed values, or says why this machine has no such device."""
    text = str(spec).strip().lower()
    if text == "auto":
        return torch.device("cuda") if torch.cuda.is_available() else torch.device("cpu")
    if text == "cpu":
        return torch.device("cpu")
    match = re.fullmatch(r"cuda(?::(\d+))?", text)
    if match is None:
        raise DeviceError(f"device={spec}: not a device; allowed: auto, cpu, cuda, cuda:N")
    if not torch.cuda.is_available():
        build = f"CUDA {torch.version.cuda}" if torch.version.cuda else "without CUDA"
        raise DeviceError(
            f"device={spec}: no CUDA device is available here (torch {torch.__version__}, built "
            f"{build}); use device=cpu or device=auto"
        )
    index, count = int(match.group(1) or 0), torch.cuda.device_count()
    if index >= count:
        raise DeviceError(f"device={spec}: this machine has {count} CUDA device(s): cuda:0 to cuda:{count - 1}")
    return torch.device("cuda", index)


def deterministic_kernels(on: bool, device: torch.device) -> None:
    """``deterministic=true`` on CUDA: cuDNN's deterministic convolutions and torch's deterministic algorithms (a
    warning names any operation that has none), so that a run repeats and a killed run resumes to the same
    weights as an uninterrupted one; ``false`` leaves torch's faster defaults.  The CPU's kernels repeat as they
    are: nothing changes there."""
    if device.type != "cuda":
        return
    if on:  # cuBLAS repeats its sums only with a fixed workspace (read when torch creates one)
        os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
        torch.backends.cudnn.benchmark = False
    torch.backends.cudnn.deterministic = on
    torch.use_deterministic_algorithms(on, warn_only=True)


def to_device(td: TensorDictBase, device: torch.device) -> TensorDictBase:
    """``td`` (on the CPU) on ``device``: on a GPU through pinned memory without blocking the host (later work on
    the device waits for the copy; the host may not write ``td`` meanwhile, and the loops here do not); elsewhere a
    plain ``to``."""
    if torch.device(device).type == "cuda" and (td.device is None or td.device.type == "cpu"):
        return td.pin_memory().to(device, non_blocking=True)
    return td.to(device)


class OnDevice(TensorDictModuleBase):
    """A policy whose networks live on ``device``, acting on tensordicts of CPU worlds: the observations go to the
    device, the policy's outputs come back (tensordict's ``to`` overlaps the copies and synchronises once).  On
    the CPU it is the policy itself, at no cost."""

    def __init__(self, policy: TensorDictModuleBase, device: torch.device):
        super().__init__()
        self.policy, self.device = policy, torch.device(device)
        self.in_keys, self.out_keys = policy.in_keys, policy.out_keys

    def forward(self, td: TensorDictBase) -> TensorDictBase:
        if self.device.type == "cpu":
            return self.policy(td)
        # the observations go through pinned memory, without blocking the host (page-locked copies are faster)
        acted = self.policy(to_device(td.select(*self.in_keys, strict=False), self.device))
        return td.update(acted.select(*self.out_keys, strict=False).to(td.device or "cpu"))


def autocast(device: torch.device, enabled: bool):
    """bf16 autocast of the networks' forward passes on ``device`` (``bf16=true``); a no-op when disabled."""
    return torch.autocast(device.type, dtype=torch.bfloat16, enabled=bool(enabled))
