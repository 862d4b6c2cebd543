"""Checkpoint files and RNG states: what a checkpoint file holds, atomic writes with the previous file kept, safe and
verified loading, and the global generators a resumed run must restore.

A checkpoint is one ``torch.save`` file (``checkpoint.pt`` for the latest state of a run, ``model-*.pt`` for a
stage's final or best network) holding ``{"evaaa_checkpoint": FILE_FORMAT, "checksum": ..., "state": ...}``.  The
state is a dict whose ``format`` is :data:`CHECKPOINT_FORMAT`; ``baselines/run.py`` decides what goes in,
``baselines/policies.py`` reads the network back.

Only tensors and plain data are stored (dicts, lists, tuples, str, numbers, ``None``), so a file loads with
``torch.load(weights_only=True)``: a file from someone else cannot run code here.  Numpy arrays, tensordicts and
OmegaConf containers are converted to such data on save and back on load, so a resumed run gets back exactly the
objects it saved.  The checksum covers every tensor byte and every plain value: a file damaged on disk is refused,
naming it, instead of resuming with silently changed weights.  ``checkpoint.pt`` is written beside a copy of the
previous one (``checkpoint-previous.pt``), which :func:`load_latest` falls back to when the latest is damaged.
"""

from __future__ import annotations

import hashlib
import math
import os
import pickle
import random
import shutil
from collections import OrderedDict
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig, ListConfig, OmegaConf
from tensordict import TensorDict, TensorDictBase, is_non_tensor

from evaaa.records import disk_error

CHECKPOINT = "checkpoint.pt"
#: the checkpoint before the latest, kept so that a damaged latest one costs one checkpoint interval, not the run
PREVIOUS = "checkpoint-previous.pt"
#: what the ``state`` of a checkpoint holds (identity keys, ``model``, ...): baselines/run.py
CHECKPOINT_FORMAT = 2
#: the envelope around a state: checksum and plain-data encoding
FILE_FORMAT = 1
_TAG = "__evaaa_type__"  # marks a dict that stands for a converted object (numpy array, tensordict)


#: deepest nesting of containers in a checkpoint's state (run.py's states nest about ten deep): a crafted file
#: nested thousands deep would overflow the recursion of :func:`checksum` and :func:`from_plain`
MAX_NESTING = 100


class CheckpointError(ValueError):
    """A checkpoint file that cannot be used: unreadable, damaged, malformed, from elsewhere, or holding code."""


# ------------------------------------------------------------------------------------------------ plain data
def to_plain(obj: Any, where: str = "state") -> Any:
    """``obj`` with numpy arrays, tensordicts and OmegaConf containers replaced by tensors and plain containers.

    Raises ``TypeError`` naming where in the state an object of another kind sits (it could not be loaded back
    with ``weights_only=True``)."""
    if isinstance(obj, torch.Tensor):
        return obj.detach()
    if isinstance(obj, np.ndarray):
        if obj.dtype.hasobject:
            raise TypeError(f"{where}: a numpy array of Python objects cannot be stored in a checkpoint")
        raw = np.ascontiguousarray(obj).reshape(-1).view(np.uint8)  # any dtype (uint32, float16...) as its bytes
        return {
            _TAG: "ndarray",
            "dtype": obj.dtype.str,
            "shape": list(obj.shape),
            "bytes": torch.from_numpy(raw.copy()),
        }
    if isinstance(obj, np.generic):
        return {_TAG: "npscalar", "array": to_plain(np.asarray(obj), where)}
    if isinstance(obj, TensorDictBase):
        items = {}
        for key, value in obj.items():
            if is_non_tensor(value):
                items[key] = {_TAG: "nontensor", "data": to_plain(value.data, f"{where}.{key}")}
            else:
                items[key] = to_plain(value, f"{where}.{key}")
        return {
            _TAG: "tensordict",
            "batch_size": list(obj.batch_size),
            "device": None if obj.device is None else str(obj.device),
            "items": items,
        }
    if isinstance(obj, (DictConfig, ListConfig)):
        return OmegaConf.to_container(obj, resolve=True)
    if isinstance(obj, Mapping):
        if _TAG in obj:
            raise TypeError(f"{where}: the key {_TAG!r} is reserved")
        plain = {k: to_plain(v, f"{where}.{k}") for k, v in obj.items()}
        return _with_metadata(obj, plain, lambda m: to_plain(m, f"{where}._metadata"))
    if obj is None or isinstance(obj, (bool, int, float, str, bytes, torch.dtype, torch.device, torch.Size)):
        return obj  # (torch.Size before tuple: a tensordict's state_dict tells its batch size by the type)
    if isinstance(obj, list):
        return [to_plain(v, f"{where}[{i}]") for i, v in enumerate(obj)]
    if isinstance(obj, tuple):
        return tuple(to_plain(v, f"{where}[{i}]") for i, v in enumerate(obj))
    raise TypeError(
        f"{where}: a {type(obj).__module__}.{type(obj).__qualname__} cannot be stored in a checkpoint "
        "(only tensors, numpy arrays, tensordicts and plain data)"
    )


def from_plain(obj: Any) -> Any:
    """The inverse of :func:`to_plain`."""
    if isinstance(obj, Mapping):
        kind = obj.get(_TAG)
        if kind == "ndarray":
            return obj["bytes"].cpu().numpy().view(np.dtype(obj["dtype"])).reshape(obj["shape"]).copy()
        if kind == "npscalar":
            return from_plain(obj["array"])[()]
        if kind == "tensordict":
            td = TensorDict({}, batch_size=obj["batch_size"], device=obj["device"])
            for key, value in obj["items"].items():
                if isinstance(value, Mapping) and value.get(_TAG) == "nontensor":
                    td.set_non_tensor(key, from_plain(value["data"]))
                else:
                    td.set(key, from_plain(value))
            return td
        return _with_metadata(obj, {k: from_plain(v) for k, v in obj.items()}, from_plain)
    if isinstance(obj, list):
        return [from_plain(v) for v in obj]
    if isinstance(obj, tuple) and not isinstance(obj, torch.Size):
        return tuple(from_plain(v) for v in obj)
    return obj


def _with_metadata(source: Mapping, items: dict, convert) -> dict:
    """``items`` as the kind of mapping ``source`` is; a state_dict's ``_metadata`` attribute (module versions, a
    tensordict's batch size and device) comes along, as ``torch.load(weights_only=True)`` keeps it."""
    if not isinstance(source, OrderedDict):
        return items
    out = OrderedDict(items)
    if hasattr(source, "_metadata"):
        out._metadata = convert(source._metadata)
    return out


def checksum(plain: Any) -> str:
    """A BLAKE2b digest of a plain state: every tensor's dtype, shape and bytes, every key and value, in order."""
    h = hashlib.blake2b(digest_size=32)

    def visit(node: Any) -> None:
        if isinstance(node, torch.Tensor):
            t = node.detach().cpu().contiguous()
            h.update(f"T{t.dtype}{tuple(t.shape)}".encode())
            if t.numel():
                h.update(t.reshape(-1).view(torch.uint8).numpy())
        elif isinstance(node, Mapping):
            h.update(f"D{len(node)}".encode())
            for key, value in node.items():
                visit(key)
                visit(value)
            if hasattr(node, "_metadata"):
                h.update(b"M")
                visit(node._metadata)
        elif isinstance(node, (list, tuple)):
            h.update(f"{'L' if isinstance(node, list) else 'U'}{len(node)}".encode())
            for value in node:
                visit(value)
        else:
            h.update(f"{type(node).__name__}:{node!r};".encode())

    visit(plain)
    return "blake2b:" + h.hexdigest()


# ------------------------------------------------------------------------------------------------ files
def save_checkpoint(state: Mapping, path: str | Path, *, keep_previous: bool = False) -> None:
    """Write ``state`` to ``path`` so that no crash leaves a half-written file there: a temporary file in the same
    directory, fsync, rename.  With ``keep_previous``, the file being replaced stays as :data:`PREVIOUS`.

    A disk that refuses the write (full, read-only, no permission) raises :class:`~evaaa.records.DiskError` naming
    ``path`` and the cause; the files already there are left as they were and no temporary file stays behind."""
    path = Path(path)
    plain = to_plain(dict(state))
    envelope = {"evaaa_checkpoint": FILE_FORMAT, "checksum": checksum(plain), "state": plain}
    tmp = path.with_name(f".{path.name}.tmp")
    # a second name for the current file, so that at every moment of the swap a complete checkpoint is on disk
    spare = path.with_name(f".{PREVIOUS}.tmp")
    try:
        with open(tmp, "wb") as f:
            torch.save(envelope, f)
            f.flush()
            os.fsync(f.fileno())
        if keep_previous and path.exists():
            spare.unlink(missing_ok=True)
            try:
                os.link(path, spare)
            except OSError:  # a file system without hard links
                shutil.copyfile(path, spare)
            os.replace(spare, path.with_name(PREVIOUS))
        os.replace(tmp, path)
        dir_fd = os.open(path.parent, os.O_RDONLY)  # make the renames themselves durable
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)
    except BaseException as exc:
        for leftover in (tmp, spare):
            try:
                leftover.unlink(missing_ok=True)
            except OSError:
                pass  # a read-only disk, where it could not have been written either
        error = disk_error(path, exc) if isinstance(exc, (OSError, RuntimeError)) else None
        if error is None:
            raise
        raise error from None


def load_checkpoint(path: str | Path, map_location: str | torch.device | None = "cpu") -> dict:
    """The state saved in ``path``, its tensors on ``map_location``.

    Raises :class:`CheckpointError`, naming the file, when it is missing, unreadable (truncated), damaged (its
    checksum does not match), not an evaaa checkpoint, or holds anything but tensors and plain data (such a file
    is refused before any of its code could run)."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: no such checkpoint file")
    try:
        envelope = torch.load(path, map_location=map_location, weights_only=True)
    except pickle.UnpicklingError as err:
        lines = [line.strip() for line in str(err).splitlines() if "Unpickler error" in line] or [type(err).__name__]
        raise CheckpointError(
            f"{path} is refused: it holds objects other than tensors and plain data, which could "
            f"run code when loaded ({lines[0][:200]})"
        ) from None
    except Exception as err:  # noqa: BLE001 - truncated zip, bad magic number, ...: all mean "unreadable"
        raise CheckpointError(
            f"{path} is unreadable (truncated or damaged): {type(err).__name__}: "
            f"{str(err).strip().splitlines()[0][:200] if str(err).strip() else ''}"
        ) from None
    if not (
        isinstance(envelope, dict)
        and envelope.get("evaaa_checkpoint") == FILE_FORMAT
        and {"checksum", "state"} <= envelope.keys()
    ):
        raise CheckpointError(f"{path} is not an evaaa checkpoint (file format {FILE_FORMAT})")
    problem = _malformed(envelope["state"])  # before the checksum, whose walk recurses
    if problem is None and checksum(envelope["state"]) != envelope["checksum"]:
        raise CheckpointError(f"{path} is damaged: its contents do not match its checksum")
    if problem is None:
        try:
            state = from_plain(envelope["state"])
        except Exception as err:  # noqa: BLE001 - e.g. a tensordict whose items do not fit its batch size
            problem = f"{type(err).__name__}: {' '.join(str(err).split())[:200]}"
    if problem is not None:  # a valid checksum says only that the file is as written, not that save_checkpoint wrote it
        raise CheckpointError(f"{path} is malformed: {problem}")
    model = state.get("model") if isinstance(state, dict) else None
    for name, tensor in model.items() if isinstance(model, Mapping) else ():
        if isinstance(tensor, torch.Tensor) and tensor.is_floating_point() and not torch.isfinite(tensor).all():
            raise CheckpointError(
                f"{path} is unusable: its network's {name} holds NaN or infinite values (the training that wrote it "
                "diverged)"
            )
    return state


def _malformed(state: Any) -> str | None:
    """What makes a plain state one :func:`to_plain` cannot have made (too deep, a converted object whose fields
    contradict each other), or None.  Iterative, so no depth of nesting overflows it; nothing is allocated."""
    stack = [(state, 1)]
    while stack:
        node, depth = stack.pop()
        if depth > MAX_NESTING:
            return f"its state nests deeper than {MAX_NESTING} levels"
        if isinstance(node, Mapping):
            problem = _converted_problem(node) if _TAG in node else None
            if problem is not None:
                return problem
            children = [*node.keys(), *node.values(), *([node._metadata] if hasattr(node, "_metadata") else [])]
        elif isinstance(node, (list, tuple)):
            children = list(node)
        else:
            continue
        stack.extend((child, depth + 1) for child in children)
    return None


def _sizes(value: Any) -> bool:
    """Whether ``value`` is a list of non-negative integers (a shape or a batch size)."""
    return isinstance(value, (list, tuple)) and all(type(n) is int and n >= 0 for n in value)


def _converted_problem(node: Mapping) -> str | None:
    """What is wrong with a mapping standing for a converted object (see :func:`to_plain`), or None."""
    kind = node.get(_TAG)
    if kind == "ndarray":
        try:
            dtype = np.dtype(node["dtype"])
        except (KeyError, TypeError, ValueError):
            return f"an array has no valid dtype ({str(node.get('dtype'))[:40]!r})"
        if dtype.hasobject:
            return "an array of Python objects (only numbers are stored)"
        shape, data = node.get("shape"), node.get("bytes")
        if not _sizes(shape):
            return f"an array's shape {str(shape)[:60]} is not a list of non-negative integers"
        if not (
            isinstance(data, torch.Tensor)
            and data.dtype == torch.uint8
            and data.dim() == 1
            and data.numel() == math.prod(shape) * dtype.itemsize
        ):
            return f"an array's bytes do not fit its shape {shape} and dtype {dtype}"
    elif kind == "npscalar":
        array = node.get("array")
        if not (isinstance(array, Mapping) and array.get(_TAG) == "ndarray"):
            return "a numpy scalar holds no array"
    elif kind == "tensordict":
        if not _sizes(node.get("batch_size")):
            return (
                f"a tensordict's batch size {str(node.get('batch_size'))[:60]} is not a list of non-negative integers"
            )
        if not isinstance(node.get("items"), Mapping):
            return "a tensordict holds no items"
        device = node.get("device")
        try:
            if device is not None:
                torch.device(device)
        except (TypeError, RuntimeError):
            return f"a tensordict's device {str(device)[:40]!r} is no device"
    elif kind != "nontensor" or "data" not in node:
        return f"an unknown stored object {str(kind)[:40]!r}"
    return None


def load_latest(
    run_dir: str | Path, map_location: str | torch.device | None = "cpu"
) -> tuple[dict, Path, str | None] | None:
    """The newest usable checkpoint of a run directory: its state, its file, and a note naming the latest file when
    that one is missing or damaged and the previous one is used instead; ``None`` when the run has neither.

    Raises :class:`CheckpointError` when checkpoint files exist but none can be used."""
    run_dir = Path(run_dir)
    problems = []
    for path in (run_dir / CHECKPOINT, run_dir / PREVIOUS):
        if not path.exists():
            continue
        try:
            state = load_checkpoint(path, map_location)
        except CheckpointError as err:
            problems.append(str(err))
            continue
        note = None
        if path.name != CHECKPOINT:
            note = (
                f"{'; '.join(problems) or f'{run_dir / CHECKPOINT} is missing'}: using the previous checkpoint "
                f"{path} (env step {state.get('counters', {}).get('steps', '?')}) instead"
            )
        return state, path, note
    if problems:
        raise CheckpointError("no usable checkpoint: " + "; ".join(problems))
    return None


def remove_stale_temporaries(run_dir: str | Path) -> list[Path]:
    """Delete the temporary files a process killed while writing a checkpoint leaves (``.checkpoint.pt.tmp``...);
    they are never complete checkpoints that the run needs.  Returns what was removed."""
    removed = []
    for tmp in sorted(Path(run_dir).glob(".*.pt.tmp")):
        tmp.unlink(missing_ok=True)
        removed.append(tmp)
    return removed


# ------------------------------------------------------------------------------------------------ RNGs
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
