"""DreamerV3's replay: :class:`SequenceReplay` (every world's transitions in time order, sampled as sequences,
optionally around the rare steps that ate, drank or died), what each stored transition costs, and
:func:`make_replay`, which puts a stage's buffer on disk (memory-mapped under the run directory) or in memory after
checking that it fits.

The replay buffer (about 12.4 kB per transition with pixels, 12.4 GB for S's million) is memory-mapped under the run
directory by default (``algo.buffer_on_disk``): the checkpoint holds its cursor and the few rows the next checkpoint
interval could overwrite, not the rows again.  In memory (``buffer_on_disk=false``) it sits on the device, must fit
the memory there, and the checkpoint holds the rows written so far.  Either way ``resume=true`` continues exactly.
"""

from __future__ import annotations

import logging
import os
import shutil
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import LazyMemmapStorage, LazyTensorStorage, ReplayBuffer, SliceSampler

if TYPE_CHECKING:
    from ..run import Run

# the package's logger, not the module's: a run's train.log names DreamerV3's lines as before the package split
log = logging.getLogger(__package__)


class SequenceReplay:
    """Every world's transitions in time order, sampled as sequences.

    A torchrl ``ReplayBuffer`` on a two-dimensional storage (rows = time, one column per world; ``capacity``
    transitions in all) with a ``SliceSampler`` whose trajectories are the worlds' streams (``world``), so a sequence
    may run across an episode's end: ``is_init`` marks where the RSSM restarts, as in DreamerV3.

    The storage is a ``LazyMemmapStorage`` in ``directory`` (files of the full size, filled as the run goes; only the
    pages in use take memory) or, without a directory, a ``LazyTensorStorage`` on ``device``.  Sampled batches are
    moved to ``device`` (from pinned memory on a GPU).

    Checkpoint state: in memory, the rows written so far and the writer's cursor.  On disk, the rows are already
    there: the state is the cursor, the length, and a copy of the rows the next ``guard_rows`` writes would
    overwrite (none until the buffer is full and wraps), so that a run killed after its checkpoint, whose later
    writes have reached the files, resumes on exactly the rows it checkpointed.
    """

    def __init__(
        self,
        capacity: int,
        num_envs: int,
        sequence_length: int,
        batch_size: int,
        *,
        directory: Path | None = None,
        device: torch.device | str = "cpu",
        guard_rows: int = 0,
        consume_share: float = 0.0,
        terminal_share: float = 0.0,
    ):
        if capacity // num_envs < sequence_length:
            raise ValueError(
                f"algo.buffer_size ({capacity}) holds fewer than algo.sequence_length "
                f"({sequence_length}) steps of each of the {num_envs} worlds"
            )
        self.num_envs, self.sequence_length, self.batch_size = num_envs, sequence_length, batch_size
        self.directory, self.device, self.guard_rows = directory, torch.device(device), guard_rows
        for name, share in (("consume_share", consume_share), ("terminal_share", terminal_share)):
            if not 0.0 <= share <= 1.0:
                raise ValueError(f"algo.{name} must lie in [0, 1], got {share}")
        if consume_share + terminal_share > 1.0:
            raise ValueError(
                f"algo.consume_share + algo.terminal_share must be at most 1, got {consume_share} + {terminal_share}"
            )
        #: sequences of each training batch drawn around a step that ate or drank (the rest: uniformly)
        self.consume_sequences = round(consume_share * batch_size)
        #: sequences of each training batch drawn around a step that ended an episode (``terminated``)
        self.terminal_sequences = min(round(terminal_share * batch_size), batch_size - self.consume_sequences)
        self._sampled = torch.Generator().manual_seed(0)
        #: the uniform draws' generator: None (the global torch RNG) unless :meth:`use_own_generator`
        self._prefetch_rng: torch.Generator | None = None
        #: a batch drawn ahead (:meth:`prefetch`) and the generators' states from before its draw
        self._pending: TensorDictBase | None = None
        self._pending_states: dict[str, torch.Tensor] | None = None
        self.capacity = capacity - capacity % num_envs
        if directory is not None:
            storage = LazyMemmapStorage(self.capacity, scratch_dir=directory, ndim=2, existsok=True)
        else:
            storage = LazyTensorStorage(self.capacity, ndim=2, device=self.device)
        self.buffer = ReplayBuffer(
            storage=storage,
            sampler=SliceSampler(slice_len=sequence_length, traj_key="world", truncated_key=None),
            batch_size=batch_size * sequence_length,
        )

    @property
    def rows(self) -> int:
        """Steps stored per world."""
        return len(self.buffer) // self.num_envs

    @property
    def place(self) -> str:
        return f"memory-mapped in {self.directory}" if self.directory is not None else f"in memory on {self.device}"

    def extend(self, transition: TensorDictBase) -> None:
        """One step of every world (batch ``[num_envs]``)."""
        transition["world"] = torch.arange(self.num_envs, device=transition.device)
        self.buffer.extend(transition.unsqueeze(1))  # [world, time]; the storage keeps time first

    @property
    def pins(self) -> bool:
        """Whether sampled batches go to the device through pinned memory: memory-mapped rows are read on the host;
        a buffer in memory already lives on the device (its batches are there, nothing to pin)."""
        return self.device.type == "cuda" and self.directory is not None

    def _to_device(self, batch: TensorDictBase) -> TensorDictBase:
        if self.pins:
            return batch.pin_memory().to(self.device, non_blocking=True)
        return batch.to(self.device)

    def sample(self, sequences: int | None = None, length: int | None = None) -> TensorDictBase:
        """``[sequences, length]`` consecutive steps of random worlds (default: the training batch), on the device.

        The training batch is drawn on the global torch RNG, or on the replay's own generator once
        :meth:`use_own_generator` was called (``algo.update.prefetch``: the next batch is drawn while the current
        gradient step runs, so it must not take its draws from the stream the gradient step uses)."""
        if sequences is None and length is None:
            if self._pending is not None:
                batch, self._pending, self._pending_states = self._pending, None, None
                return batch
            generator = self._prefetch_rng
            around = [
                part
                for key, count in (
                    (("next", "terminated"), self.terminal_sequences),
                    (("next", "consumed"), self.consume_sequences),
                )
                if count and (part := self._around(key, count)) is not None
            ]
            uniform = self.batch_size - sum(len(part) for part in around)
            if uniform:
                around.insert(0, self._uniform(uniform, self.sequence_length, generator))
            return self._to_device(torch.cat(around, dim=0) if len(around) > 1 else around[0])
        return self._to_device(self._uniform(sequences, length))

    def _uniform(self, sequences: int, length: int, generator: torch.Generator | None = None) -> TensorDictBase:
        """``[sequences, length]`` consecutive steps, each sequence of a uniformly drawn world from a uniformly drawn
        start, in O(sequences x length): the same draws (the same RNG calls on the same stream) as torchrl's
        ``SliceSampler`` over the worlds' streams, which recomputes every world's trajectory bounds over the whole
        buffer at each sample.  A world's stream is its column: rows 0.. until the buffer is full, then from the
        writer's cursor (the oldest row) round to the newest, so no sequence crosses the cursor."""
        rows, storage_rows = self.rows, self.capacity // self.num_envs
        if rows < length:
            raise RuntimeError(f"the replay holds {rows} steps per world, fewer than a sequence's {length}")
        data = self.buffer.storage._storage
        device = data.device if data.device is not None else torch.device("cpu")
        first = int(self.buffer._writer._cursor) % storage_rows if rows == storage_rows else 0
        world = torch.randint(self.num_envs, (sequences,), device=device, generator=generator)
        windows = torch.full((sequences,), rows - length + 1, dtype=torch.long, device=device)
        start = (torch.rand(sequences, device=device, generator=generator) * windows).floor().long() + first
        time = (start[:, None] + torch.arange(length, device=device)) % storage_rows
        return data[time.reshape(-1), world.repeat_interleave(length)].reshape(sequences, length)

    def prefetch(self) -> None:
        """Draw the next training batch now and start its copy to the device (without waiting for it): the next
        :meth:`sample` returns it.  Called while a gradient step runs on the GPU, it takes the sampling off the
        critical path.  A checkpoint taken while a batch is pending keeps the generators' states from before its
        draw, so that the resumed run draws it again (the buffer does not change between the two)."""
        if self._prefetch_rng is None:
            raise RuntimeError("SequenceReplay.prefetch needs the replay's own generator (use_own_generator)")
        if self._pending is None:
            states = self._generator_states()
            self._pending = self.sample()
            self._pending_states = states

    def _generator_states(self) -> dict[str, torch.Tensor]:
        states = {"sampled": self._sampled.get_state()}
        if self._prefetch_rng is not None:
            states["prefetch"] = self._prefetch_rng.get_state()
        return states

    def use_own_generator(self, seed: int) -> None:
        """Draw the training batches' uniform sequences on a generator of their own, seeded with ``seed`` (and
        checkpointed), instead of the global torch RNG: for ``algo.update.prefetch``."""
        self._prefetch_rng = torch.Generator(device=self._sample_device).manual_seed(seed)

    @property
    def _sample_device(self) -> torch.device:
        return torch.device("cpu") if self.directory is not None else self.device

    def _around(self, key: tuple[str, str], count: int) -> TensorDictBase | None:
        """``count`` sequences, each holding a stored step whose ``key`` is set (``("next", "consumed")``: it ate or
        drank; ``("next", "terminated")``: it ended an episode) at a uniformly drawn position, or None while there is
        none (or too few rows).  A sequence never runs across the writer's cursor, where the newest rows meet the
        oldest."""
        rows, length = self.rows, self.sequence_length
        if rows < length:
            return None
        storage = self.buffer.storage
        eaten = storage._storage[key][:rows].reshape(rows, self.num_envs)
        where = eaten.nonzero()
        if not len(where):
            return None
        storage_rows = self.capacity // self.num_envs
        cursor = int(self.buffer._writer._cursor) % storage_rows
        full = rows == storage_rows
        picks = where[torch.randint(len(where), (4 * count,), generator=self._sampled)]
        offset = torch.randint(length, (len(picks),), generator=self._sampled)
        start = (picks[:, 0] - offset).clamp(0, rows - length)
        if full:  # the rows [start, start + length) must not hold the cursor's row unless it is the first
            crosses = (cursor > start) & (cursor < start + length)
            start, picks = start[~crosses], picks[~crosses]
        if len(start) < count:
            return None
        start, world = start[:count], picks[:count, 1]
        time = start[:, None] + torch.arange(length)
        return storage._storage[time, world[:, None]]

    def _overwritten_next(self) -> torch.Tensor:
        """Rows holding data now that the next ``guard_rows`` writes go to, in writing order."""
        storage_rows = self.capacity // self.num_envs
        cursor = int(self.buffer._writer._cursor) % storage_rows
        ahead = (cursor + torch.arange(min(self.guard_rows, storage_rows))) % storage_rows
        return ahead[ahead < self.rows]

    def state_dict(self) -> dict:
        storage = self.buffer.storage
        writer = self.buffer._writer.state_dict()
        # the sampling generators (kept only where they matter, so that a checkpoint of a run without them holds
        # what it always held): those of the shares' draws and of the prefetched batches
        generators = dict(self._pending_states or self._generator_states())
        if not (self.consume_sequences or self.terminal_sequences):
            generators.pop("sampled")
        extra = {"generators": generators} if generators else {}
        if self.directory is None:
            rows = storage._storage[: self.rows].clone() if self.rows else None
            return {"rows": rows, "writer": writer, **extra}
        guard = self._overwritten_next() if self.rows else torch.zeros(0, dtype=torch.long)
        self.flush()
        return {
            "on_disk": str(self.directory),
            "length": len(self.buffer),
            "writer": writer,
            "guard_index": guard,
            "guard_rows": storage._storage[guard].clone() if len(guard) else None,
            **extra,
        }

    def load_state_dict(self, state: Mapping) -> None:
        if ("on_disk" in state) != (self.directory is not None):
            raise ValueError(
                "the checkpoint's replay buffer was "
                + ("on disk" if "on_disk" in state else "in memory")
                + f"; this run's is {self.place}: resume with the algo.buffer_on_disk it was made with"
            )
        self.buffer.empty()
        self._pending, self._pending_states = None, None
        generators = state.get("generators", {})
        if "sampled" in generators:
            self._sampled.set_state(generators["sampled"])
        if "prefetch" in generators:
            if self._prefetch_rng is None:
                raise ValueError(
                    "the checkpoint's replay drew its batches ahead (algo.update.prefetch=true); resume with it"
                )
            self._prefetch_rng.set_state(generators["prefetch"])
        elif self._prefetch_rng is not None and ("rows" in state or state.get("length")):
            raise ValueError(
                "the checkpoint's replay drew its batches on the global RNG (algo.update.prefetch=false); resume "
                "with it"
            )
        if self.directory is None:
            if state["rows"] is not None:
                self.buffer.extend(state["rows"].transpose(0, 1))  # rows 0.. in storage order, as they were
            self.buffer._writer.load_state_dict(state["writer"])
            return
        if state["length"]:
            if not (self.directory / "meta.json").exists():
                raise FileNotFoundError(
                    f"the checkpoint's replay buffer is memory-mapped in {self.directory}, which "
                    "is missing: this run cannot resume exactly"
                )
            storage = self.buffer.storage
            storage._storage = TensorDict.load_memmap(self.directory, mode="r+")
            storage.initialized = True
            storage._len = state["length"]
            if state["guard_rows"] is not None:  # the rows the killed process overwrote after its checkpoint
                storage._storage[state["guard_index"]] = state["guard_rows"]
        self.buffer._writer.load_state_dict(state["writer"])

    def flush(self) -> None:
        """Write the memory-mapped rows to the disk (so a checkpoint never refers to rows only in the page cache)."""
        if self.directory is None or not self.directory.exists():
            return
        for path in self.directory.rglob("*.memmap"):
            fd = os.open(path, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)


def transition_bytes(env, stored: Sequence) -> int:
    """Bytes one world's transition takes in the replay buffer (what :func:`train` stores, plus the world index)."""
    fake = env.fake_tensordict().select(*stored, strict=False)  # ("next", "consumed") is added by train()
    per_world = sum(t.element_size() * t.numel() for t in fake.values(True, True)) // env.batch_size.numel()
    return per_world + torch.tensor(0).element_size() + int(("next", "consumed") in stored)  # a bool


def available_memory(device: torch.device) -> int | None:
    """Bytes free for a buffer on ``device``: the GPU's free memory, or the system's MemAvailable."""
    if device.type == "cuda":
        return torch.cuda.mem_get_info(device)[0]
    try:
        with open("/proc/meminfo") as f:
            info = dict(line.split(":", 1) for line in f)
        return int(info["MemAvailable"].split()[0]) * 1024
    except (OSError, KeyError, ValueError):
        return None


def gb_text(n: float) -> str:
    return f"{n / 1e9:.3g} GB"


def consumed(transition: TensorDictBase) -> torch.Tensor:
    """Whether each world ate or drank on this step (its food or water count grew): the replay keeps it as
    ``("next", "consumed")`` so that :func:`diagnostics` can tell the reward head's error on those rare steps."""
    before, after = transition["info"], transition["next", "info"]
    return (after["food_eaten"] + after["water_eaten"]) > (before["food_eaten"] + before["water_eaten"])


def replay_directory(run: Run) -> Path:
    """Where a stage's memory-mapped replay buffer lives: ``replay/<stage>-<level>/`` in the run directory."""
    return run.dir / "replay" / f"{run.stage.index}-{run.stage.level}"


def make_replay(run: Run, num_envs: int, row_bytes: int) -> SequenceReplay:
    """The stage's replay buffer, on disk or in memory (``algo.buffer_on_disk``), after checking that it fits."""
    cfg = run.cfg.algo
    full = cfg.buffer_size * row_bytes
    # a stage's rows are rewritten at most every checkpoint.every env steps: a checkpoint keeps a copy of those
    guard = -(-int(run.cfg.checkpoint.every) // num_envs) + 2
    if cfg.buffer_on_disk:
        directory = replay_directory(run)
        if run.resume_state is None and directory.exists():
            shutil.rmtree(directory)  # a stage started afresh: rows left by a run killed before its first checkpoint
        directory.mkdir(parents=True, exist_ok=True)
        for stale in sorted(directory.parent.glob("*-*")):  # stages before the previous one: no checkpoint needs them
            if stale != directory and int(stale.name.split("-", 1)[0]) < run.stage.index - 1:
                shutil.rmtree(stale)
        free = shutil.disk_usage(directory).free
        if full > free:
            log.warning(
                "replay: a full buffer (algo.buffer_size=%s, %s) needs more than the %s free on the disk of "
                "%s; lower algo.buffer_size before it fills",
                f"{cfg.buffer_size:,}",
                gb_text(full),
                gb_text(free),
                directory,
            )
        return SequenceReplay(
            cfg.buffer_size,
            num_envs,
            cfg.sequence_length,
            cfg.batch_size,
            directory=directory,
            device=run.device,
            guard_rows=guard,
            consume_share=cfg.get("consume_share", 0.0),
            terminal_share=cfg.get("terminal_share", 0.0),
        )
    free = available_memory(run.device)
    if free is not None and full > free:
        raise ValueError(
            f"algo.buffer_size={cfg.buffer_size:,} transitions need {gb_text(full)} when full, but "
            f"{run.device} has {gb_text(free)} available: use algo.buffer_on_disk=true (memory-mapped under "
            f"the run directory) or algo.buffer_size<={free // row_bytes:,}"
        )
    return SequenceReplay(
        cfg.buffer_size,
        num_envs,
        cfg.sequence_length,
        cfg.batch_size,
        device=run.device,
        consume_share=cfg.get("consume_share", 0.0),
        terminal_share=cfg.get("terminal_share", 0.0),
    )
