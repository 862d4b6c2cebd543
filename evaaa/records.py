"""Episode records: one row per finished episode, the common format of evaluations, human play and reports.

``EpisodeTracker`` follows a batch of worlds step by step (from the simulator's or the env's ``info``) and
returns a row for every episode that ends; ``append_rows`` adds rows to a CSV file, writing the header when the
file is new and syncing to disk so that a killed run loses nothing it reported.
"""

from __future__ import annotations

import csv
import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .physiology import END_TYPES

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
#: Per-episode event counters: column -> the ``info`` flag summed over the episode.
EVENT_FIELDS: dict[str, str] = {"trigger_crossed": "trigger_crossed", "steps_near_heat": "near_heat"}


def _scalar(value) -> Any:
    value = np.asarray(value).reshape(-1)[0]
    return value.item() if hasattr(value, "item") else value


class EpisodeTracker:
    """Accumulates per-world episode statistics and emits a row when a world's episode ends."""

    def __init__(self, num_worlds: int, level: str, policy: str, participant: str = "", seed: int | None = None,
                 judged: bool | None = None, acting: str = ""):
        """``judged``: whether the level has a success rule (default: looked up from the level's name);
        ``acting``: how a checkpoint picks its actions (see :data:`EPISODE_FIELDS`)."""
        self.n = num_worlds
        self.level, self.policy, self.participant, self.seed = level, policy, participant, seed
        self.acting = acting
        if judged is None:
            from .spec import load_level

            judged = load_level(level).episode.success.rule != "none"
        self.judged = judged
        self.episodes = 0
        self._clear(np.ones(num_worlds, dtype=bool))

    def _clear(self, worlds: np.ndarray) -> None:
        if not hasattr(self, "_sums"):
            self._sums = {k: np.zeros(self.n) for k in ("return", "food_eaten", "water_eaten", "collisions",
                                                        "damage_taken", "attacks", *EVENT_FIELDS)}
        for values in self._sums.values():
            values[worlds] = 0.0

    def update(self, reward, info: Mapping[str, Any], done) -> list[dict[str, Any]]:
        """Account one decision of every world; return the rows of the episodes that ended with it.

        ``reward`` and ``done`` are (N,) or (N, 1); ``info`` maps the env's info keys to (N, ...) arrays or
        tensors.
        """
        info = {k: np.asarray(v).reshape(self.n, -1) for k, v in info.items()}
        reward = np.asarray(reward, dtype=np.float64).reshape(self.n)
        done = np.asarray(done, dtype=bool).reshape(self.n)
        sums = self._sums
        sums["return"] += reward
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
            rows.append(row)
            self.episodes += 1
        self._clear(done)
        return rows


def append_rows(path: str | os.PathLike, rows: Iterable[Mapping[str, Any]]) -> None:
    """Append episode rows to a CSV file (header written once), flushed and synced to disk."""
    rows = list(rows)
    if not rows:
        return
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fields = list(EPISODE_FIELDS) + [k for k in EVENT_FIELDS if any(k in r for r in rows)]
    # a tool's own columns (human play: session, ended_at) follow, in the order its rows give them
    fields += [k for k in dict.fromkeys(k for r in rows for k in r) if k not in fields]
    new = not path.exists() or path.stat().st_size == 0
    if not new:
        with path.open(newline="") as f:
            existing = next(csv.reader(f), [])
        fields = existing + [k for k in fields if k not in existing]
        if fields != existing:
            raise ValueError(f"{path} has columns {existing}; these rows need {fields}")
    with path.open("a", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=fields, extrasaction="raise")
        if new:
            writer.writeheader()
        writer.writerows(rows)
        f.flush()
        os.fsync(f.fileno())


def read_rows(path: str | os.PathLike) -> list[dict[str, str]]:
    with Path(path).open(newline="") as f:
        return list(csv.DictReader(f))
