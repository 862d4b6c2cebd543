"""Behaviour records: one row per finished episode (the common format of evaluations, human play and reports)
and, on request, one row per decision.

``EpisodeTracker`` follows a batch of worlds step by step (from the simulator's or the env's ``info``) and
returns a row for every episode that ends; ``append_rows`` adds rows to a CSV file, writing the header when the
file is new and syncing to disk so that a killed run loses nothing it reported.  ``StepLog`` writes the per-step
file the original's recorder wrote beside its per-episode one (pose, action, reward, distance, collision, events),
one file per run, for the paper's behavioural-event analyses.  A disk that refuses a write (full, read-only, no
permission) raises :class:`DiskError`, one line naming the file and the cause, with the file as it was before.
"""

from __future__ import annotations

import csv
import errno
import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .physiology import END_TYPES, EV_NAMES, ORIGINAL_END_TYPES
from .sim import ACTION_NAMES

#: Columns of an episode row, in order.
EPISODE_FIELDS: tuple[str, ...] = (
    "policy",  # what acted: a checkpoint path, "random", "oracle", "human"
    "acting",  # how a checkpoint chose its actions: "mode" or "sample", "+epsilon=<e>" when epsilon-greedy;
    #            empty for random, oracle and human
    "participant",  # who, for human play; empty otherwise
    "level",
    "episode",  # index of the episode within this run of the tool
    "seed",
    "steps",  # decisions survived
    "return",
    "end_type",  # name from evaaa.END_TYPES
    "success",  # the level's success criterion (testbeds); empty where a level has none
    "food_eaten",
    "water_eaten",
    "collisions",
    "damage_taken",
    "attacks",
    "final_satiation",
    "final_hydration",
    "final_temperature",
    "final_damage",
)
#: Columns of a training run's ``episodes.csv`` (scripts/train.py): the :data:`EPISODE_FIELDS` the training loop
#: knows of an episode without per-decision bookkeeping, under the same names and meanings (``episode`` counts a run's
#: episodes from 1), framed by :data:`TRAINING_ONLY_FIELDS`.  Positions are those of the files written before the
#: names were shared, so that a resumed old run appends rows that line up with its header.
TRAINING_EPISODE_FIELDS: tuple[str, ...] = (
    "env_steps",
    "stage",
    "level",
    "episode",
    "world",
    "steps",
    "return",
    "end_type",
    *(f"final_{name}" for name in EV_NAMES),
    "wall_time",
)
#: The training columns that are not episode fields: where in the run the episode ended.
TRAINING_ONLY_FIELDS: tuple[str, ...] = ("env_steps", "stage", "world", "wall_time")
#: Names of training columns in files written before they were shared with :data:`EPISODE_FIELDS`: old -> current.
TRAINING_OLD_NAMES: dict[str, str] = {"survival_steps": "steps", **{name: f"final_{name}" for name in EV_NAMES}}
#: Per-episode event counters: column -> the ``info`` flag summed over the episode.
EVENT_FIELDS: dict[str, str] = {"trigger_crossed": "trigger_crossed", "steps_near_heat": "near_heat"}
#: Per-episode reward statistics over the episode's decisions (the original's AvgReward, MaxReward, MinReward).
REWARD_FIELDS: tuple[str, ...] = ("mean_reward", "max_reward", "min_reward")
#: Per-episode share of each action in percent (the original's None% ... Eat%), when the actions are given.
ACTION_FIELDS: tuple[str, ...] = tuple(f"{name}_pct" for name in ACTION_NAMES)
#: Which of a seed's sets of worlds (evaaa.worlds: ``validation`` or ``test``) an evaluation's episode was played in;
#: absent in files written before the sets existed, whose evaluations played the worlds ``make_env(seed=s)`` gives
#: (the training worlds of seed ``s``).
WORLD_FIELDS: tuple[str, ...] = ("worlds",)
#: Columns a row may carry after :data:`EPISODE_FIELDS`, in this order.
OPTIONAL_FIELDS: tuple[str, ...] = (*EVENT_FIELDS, *REWARD_FIELDS, *ACTION_FIELDS, *WORLD_FIELDS)


#: what a disk answers when it will not take a write: no space, over quota, file too large, read-only, no permission
DISK_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.EACCES, errno.EPERM})


class DiskError(OSError):
    """A file could not be written (no space left, a read-only file system, no permission, ...).  Its message is one
    line naming the file and the cause; ``errno`` is the system's."""

    def __init__(self, path: str | os.PathLike, cause: OSError):
        super().__init__(cause.errno, cause.strerror or str(cause), str(path))

    def __str__(self) -> str:
        return f"cannot write {self.filename}: {self.strerror}"


def disk_error(path: str | os.PathLike, exc: BaseException) -> DiskError | None:
    """The :class:`DiskError` for writing ``path`` behind ``exc``: ``exc`` itself or the ``OSError`` it was raised
    from or while handling (``torch.save`` turns a failed write into a ``RuntimeError`` about zip positions).
    ``None`` when no ``OSError`` is behind it."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, DiskError):
            return exc
        if isinstance(exc, OSError):
            return DiskError(path, exc)
        exc = exc.__cause__ or exc.__context__
    return None


class EpisodeTracker:
    """Accumulates per-world episode statistics and emits a row when a world's episode ends."""

    def __init__(
        self,
        num_worlds: int,
        level: str,
        policy: str,
        participant: str = "",
        seed: int | None = None,
        judged: bool | None = None,
        acting: str = "",
        worlds: str | None = None,
    ):
        """``judged``: whether the level has a success rule (default: looked up from the level's name);
        ``acting``: how a checkpoint picks its actions (see :data:`EPISODE_FIELDS`); ``worlds``: the set of worlds
        played (:data:`WORLD_FIELDS`), a column of every row when given."""
        self.n = num_worlds
        self.level, self.policy, self.participant, self.seed = level, policy, participant, seed
        self.acting, self.worlds = acting, worlds
        if judged is None:
            from .level_files import load_level

            judged = load_level(level).episode.success.rule != "none"
        self.judged = judged
        self.episodes = 0
        self._clear(np.ones(num_worlds, dtype=bool))

    def _clear(self, worlds: np.ndarray) -> None:
        if not hasattr(self, "_sums"):
            self._sums = {
                k: np.zeros(self.n)
                for k in (
                    "return",
                    "food_eaten",
                    "water_eaten",
                    "collisions",
                    "damage_taken",
                    "attacks",
                    "decisions",
                    *EVENT_FIELDS,
                )
            }
            self._max_reward = np.full(self.n, -np.inf)
            self._min_reward = np.full(self.n, np.inf)
            self._actions = np.zeros((self.n, len(ACTION_NAMES)))
        for values in self._sums.values():
            values[worlds] = 0.0
        self._max_reward[worlds] = -np.inf
        self._min_reward[worlds] = np.inf
        self._actions[worlds] = 0.0

    def update(self, reward, info: Mapping[str, Any], done, actions=None) -> list[dict[str, Any]]:
        """Account one decision of every world; return the rows of the episodes that ended with it.

        ``reward`` and ``done`` are (N,) or (N, 1); ``info`` maps the env's info keys to (N, ...) arrays or
        tensors; ``actions`` (N,), when given, adds each action's share of the episode (:data:`ACTION_FIELDS`).
        """
        info = {k: np.asarray(v).reshape(self.n, -1) for k, v in info.items()}
        reward = np.asarray(reward, dtype=np.float64).reshape(self.n)
        done = np.asarray(done, dtype=bool).reshape(self.n)
        sums = self._sums
        sums["return"] += reward
        sums["decisions"] += 1
        np.maximum(self._max_reward, reward, out=self._max_reward)
        np.minimum(self._min_reward, reward, out=self._min_reward)
        if actions is not None:
            actions = np.asarray(actions).reshape(self.n).astype(np.int64)
            self._actions[np.arange(self.n), actions] += 1
        sums["food_eaten"] += info["food_eaten"][:, 0]
        sums["water_eaten"] += info["water_eaten"][:, 0]
        sums["collisions"] += info["collision"][:, 0]
        sums["damage_taken"] += info["damage_taken"][:, 0]
        if "attacked" in info:
            sums["attacks"] += info["attacked"][:, 0]
        for column, key in EVENT_FIELDS.items():
            if key in info:
                sums[column] += info[key][:, 0]
        rows = []
        for w in np.flatnonzero(done):
            row = {
                "policy": self.policy,
                "acting": self.acting,
                "participant": self.participant,
                "level": self.level,
                "episode": self.episodes,
                "seed": "" if self.seed is None else self.seed,
                "steps": int(info["step_count"][w, 0]),
                "return": float(sums["return"][w]),
                "end_type": END_TYPES[int(info["end_type"][w, 0])],
                "success": bool(info["success"][w, 0]) if self.judged and "success" in info else "",
                "food_eaten": int(sums["food_eaten"][w]),
                "water_eaten": int(sums["water_eaten"][w]),
                "collisions": int(sums["collisions"][w]),
                "damage_taken": float(sums["damage_taken"][w]),
                "attacks": int(sums["attacks"][w]),
                "final_satiation": float(info["satiation"][w, 0]),
                "final_hydration": float(info["hydration"][w, 0]),
                "final_temperature": float(info["temperature"][w, 0]),
                "final_damage": float(info["damage"][w, 0]),
            }
            for column, key in EVENT_FIELDS.items():
                if key in info:
                    row[column] = int(sums[column][w])
            if self.worlds is not None:
                row["worlds"] = self.worlds
            decisions = max(sums["decisions"][w], 1.0)
            row["mean_reward"] = float(sums["return"][w] / decisions)
            row["max_reward"] = float(self._max_reward[w])
            row["min_reward"] = float(self._min_reward[w])
            if actions is not None:
                for column, count in zip(ACTION_FIELDS, self._actions[w]):
                    row[column] = float(100.0 * count / decisions)
            rows.append(row)
            self.episodes += 1
        self._clear(done)
        return rows


def append_rows(path: str | os.PathLike, rows: Iterable[Mapping[str, Any]]) -> None:
    """Append episode rows to a CSV file (header written once), flushed and synced to disk.

    A file written before some optional columns existed (:data:`OPTIONAL_FIELDS`) is widened first: its header
    gains them and its earlier rows keep every value, with those cells empty (the file is rewritten beside itself
    and swapped in).  Any other column the file lacks is refused.
    """
    rows = list(rows)
    if not rows:
        return
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DiskError(path.parent, exc) from None
    fields = list(EPISODE_FIELDS) + [k for k in OPTIONAL_FIELDS if any(k in r for r in rows)]
    # a tool's own columns (human play: session, ended_at) follow, in the order its rows give them
    fields += [k for k in dict.fromkeys(k for r in rows for k in r) if k not in fields]
    new = not path.exists() or path.stat().st_size == 0
    if not new:
        with path.open(newline="") as f:
            existing = next(csv.reader(f), [])
        missing = [k for k in fields if k not in existing]
        if [k for k in missing if k not in OPTIONAL_FIELDS]:
            raise ValueError(f"{path} has columns {existing}; these rows need {existing + missing}")
        if missing:
            _widen(path, existing + missing)
        fields = existing + missing
    existed = path.exists()
    size = path.stat().st_size if existed else 0
    try:
        with path.open("a", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=fields, extrasaction="raise")
            if new:
                writer.writeheader()
            writer.writerows(rows)
            f.flush()
            os.fsync(f.fileno())
    except OSError as exc:
        _cut_back(path, size if existed else None)  # a row cut short by a full disk would read as a different episode
        raise DiskError(path, exc) from None


def _cut_back(path: Path, size: int | None) -> None:
    """Return ``path`` to its first ``size`` bytes (what it held before a failed append; ``None``: it did not exist),
    as far as the disk lets."""
    try:
        if size is None:
            path.unlink(missing_ok=True)
        elif path.exists() and path.stat().st_size > size:
            os.truncate(path, size)
    except OSError:
        pass  # a read-only file system: then nothing was appended either


def _widen(path: Path, fields: list[str]) -> None:
    """Rewrite a CSV file under a wider header (new cells empty), atomically."""
    old = read_rows(path)
    tmp = path.with_name(path.name + ".widening")
    try:
        with tmp.open("w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=fields)
            writer.writeheader()
            writer.writerows(old)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise DiskError(path, exc) from None


def read_rows(path: str | os.PathLike) -> list[dict[str, str]]:
    with Path(path).open(newline="") as f:
        return list(csv.DictReader(f))


# ------------------------------------------------------------------------------------------------ per-step log
#: Columns of the per-step log, in order (one row per world and decision).
STEP_FIELDS: tuple[str, ...] = (
    "policy",
    "acting",
    "participant",
    "level",
    "seed",
    "world",  # index of the world in its batch
    "episode",  # index of the episode within this world and level, in this run
    "global_step",  # decisions of this world in this run (all levels)
    "step",  # decision within the episode (1 for the first)
    "action",  # name from evaaa.ACTION_NAMES
    "reward",
    "x",
    "y",
    "z",
    "yaw",  # compass degrees
    "distance",  # metres travelled in this decision
    "satiation",
    "hydration",
    "temperature",
    "damage",
    "collision",  # a contact this decision counted as a collision
    "damage_taken",
    "consumed",  # food, water, food+water or empty
    "food_eaten",
    "water_eaten",
    "attacked",
    "event",  # trigger (an event trigger was crossed: the original's "resource" event) or empty
    "near_heat",
    "done",
    "end_type",  # on the episode's last decision: evaaa's name (evaaa.END_TYPES)
    "original_end_type",  # ... and the original's (evaaa.physiology.ORIGINAL_END_TYPES)
    "success",  # on a judged level's last decision
)


def new_log_path(directory: str | os.PathLike, stem: str = "steps") -> Path:
    """A file name in ``directory`` that no earlier run used: ``<stem>-<UTC time>.csv`` (``-2``, ``-3`` ... on a
    clash)."""
    import time

    directory = Path(directory)
    base = f"{stem}-{time.strftime('%Y%m%d-%H%M%S', time.gmtime())}"
    path, k = directory / f"{base}.csv", 1
    while path.exists():
        k += 1
        path = directory / f"{base}-{k}.csv"
    return path


class StepLog:
    """The per-step behaviour log of one run: a CSV file of :data:`STEP_FIELDS`, one row per world and decision.

    The file is new (an existing one is never overwritten) and each batch of rows is flushed as it is written.
    Call :meth:`start` when an env of a level starts (with the ``info`` of its reset), :meth:`update` after every
    step, and :meth:`close` at the end (or use it as a context manager).
    """

    def __init__(self, path: str | os.PathLike, *, policy: str = "", acting: str = "", participant: str = ""):
        self.path = Path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file = self.path.open("x", newline="")  # "x": refuse to overwrite what an earlier run wrote
            self._writer = csv.DictWriter(self._file, fieldnames=STEP_FIELDS, extrasaction="raise")
            self._writer.writeheader()
        except FileExistsError:
            raise
        except OSError as exc:
            raise DiskError(self.path, exc) from None
        self.policy, self.acting, self.participant = policy, acting, participant
        self.level, self.seed, self.judged = "", None, False
        self._global: dict[int, int] = {}
        self._episode = np.zeros(0, dtype=np.int64)
        self._previous = np.zeros((0, 3))

    def start(
        self,
        level: str,
        info: Mapping[str, Any],
        seed: int | None = None,
        judged: bool | None = None,
        policy: str | None = None,
        acting: str | None = None,
    ) -> None:
        """A level's env starts (or its worlds were all reset): ``info`` is the reset's (``position`` of every
        world); ``policy`` and ``acting``, when given, replace those the rows carry from here on."""
        position = np.asarray(info["position"], dtype=np.float64).reshape(-1, 3)
        self.policy = self.policy if policy is None else policy
        self.acting = self.acting if acting is None else acting
        if judged is None:
            from .level_files import load_level

            judged = load_level(level).episode.success.rule != "none"
        self.level, self.seed, self.judged = level, seed, judged
        self._episode = np.zeros(len(position), dtype=np.int64)
        self._previous = position.copy()

    def update(
        self, actions, reward, info: Mapping[str, Any], done, next_info: Mapping[str, Any] | None = None
    ) -> None:
        """Write one row per world for a decision: its ``actions`` (N,), ``reward`` and ``done`` (N,) or (N, 1)
        and ``info``.  ``next_info``: the info after worlds that ended were reset (where the next distance is
        measured from); without it a world's next episode starts where :meth:`start` or this step left it."""
        n = len(self._previous)
        info = {k: np.asarray(v).reshape(n, -1) for k, v in info.items()}
        actions = np.asarray(actions).reshape(n)
        reward = np.asarray(reward, dtype=np.float64).reshape(n)
        done = np.asarray(done, dtype=bool).reshape(n)
        position = info["position"].astype(np.float64)
        distance = np.linalg.norm(position - self._previous, axis=1)
        rows = []
        for w in range(n):
            self._global[w] = self._global.get(w, 0) + 1
            food, water = int(info["food_eaten"][w, 0]), int(info["water_eaten"][w, 0])
            end = END_TYPES[int(info["end_type"][w, 0])] if done[w] else ""
            rows.append(
                {
                    "policy": self.policy,
                    "acting": self.acting,
                    "participant": self.participant,
                    "level": self.level,
                    "seed": "" if self.seed is None else self.seed,
                    "world": w,
                    "episode": int(self._episode[w]),
                    "global_step": self._global[w],
                    "step": int(info["step_count"][w, 0]),
                    "action": ACTION_NAMES[int(actions[w])],
                    "reward": float(reward[w]),
                    "x": float(position[w, 0]),
                    "y": float(position[w, 1]),
                    "z": float(position[w, 2]),
                    "yaw": float(info["yaw"][w, 0]),
                    "distance": float(distance[w]),
                    "satiation": float(info["satiation"][w, 0]),
                    "hydration": float(info["hydration"][w, 0]),
                    "temperature": float(info["temperature"][w, 0]),
                    "damage": float(info["damage"][w, 0]),
                    "collision": bool(info["collision"][w, 0]),
                    "damage_taken": float(info["damage_taken"][w, 0]),
                    "consumed": "+".join(k for k, c in (("food", food), ("water", water)) if c),
                    "food_eaten": food,
                    "water_eaten": water,
                    "attacked": bool(info["attacked"][w, 0]) if "attacked" in info else False,
                    "event": "trigger" if "trigger_crossed" in info and info["trigger_crossed"][w, 0] else "",
                    "near_heat": bool(info["near_heat"][w, 0]) if "near_heat" in info else False,
                    "done": bool(done[w]),
                    "end_type": end,
                    "original_end_type": ORIGINAL_END_TYPES[end] if end else "",
                    "success": bool(info["success"][w, 0]) if done[w] and self.judged and "success" in info else "",
                }
            )
        try:
            self._writer.writerows(rows)
            self._file.flush()
        except OSError as exc:
            raise DiskError(self.path, exc) from None
        self._previous = position
        if next_info is not None:
            self._previous = np.asarray(next_info["position"], dtype=np.float64).reshape(n, 3).copy()
        self._episode += done

    def close(self) -> None:
        if not self._file.closed:
            try:
                self._file.flush()
                os.fsync(self._file.fileno())
            except OSError as exc:
                raise DiskError(self.path, exc) from None
            finally:
                try:
                    self._file.close()
                except OSError:  # the same failed flush again: reported above
                    pass

    def __enter__(self) -> StepLog:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
