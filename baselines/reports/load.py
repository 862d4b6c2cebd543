"""A report's inputs: training run directories and evaluation episode files, read and tied together.

Inputs are what the other tools write: run directories of ``scripts/train.py`` (``.hydra/config.yaml``,
``episodes.csv``, ``eval.csv``, ``model-<stage>-<level>.pt``, ``checkpoint.pt``) and episode files of
``scripts/evaluate.py`` and ``scripts/play.py`` (one row per episode in the format of :mod:`evaaa.records`;
``policy`` is a checkpoint path, ``oracle``, ``random``, ``still`` or ``human``; ``acting`` how a checkpoint acted,
``worlds`` on which worlds — files without that column were measured on ``make_env(seed=s)``'s worlds, a seed-s
training run's own, and are labelled not held out).  An evaluated checkpoint is tied to its run
through the run directory it lies in, whose ``.hydra/config.yaml`` says what was trained (algorithm, modality,
reward, level or curriculum, seed, ...).  Nothing is dropped silently: what cannot be used says why.
"""

from __future__ import annotations

import io
import os
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from omegaconf import OmegaConf

import evaaa
from evaaa.records import TRAINING_OLD_NAMES

from ..config import COMPUTE_BOUND_STEPS
from ..config import stages as config_stages

REFERENCES = ("oracle", "random", "still", "human")
MODEL_FILE = re.compile(r"^model-(\d+)-(.+)\.pt$")
#: the network of a stage's best evaluation (run.Run.best_model_path)
BEST_MODEL_FILE = re.compile(r"^model-best-(\d+)-(.+)\.pt$")
#: Settings that do not change what is trained: runs differing only in these (and the seed) are pooled
#: (``deterministic`` picks CUDA kernels that repeat; runs made before it existed have no such key).
BOOKKEEPING = (
    "seed",
    "resume",
    "start_over",
    "threads",
    "progress",
    "progress_window",
    "log_every",
    "total_steps",
    "max_minutes",
    "max_cpu_minutes",
    "deterministic",
    "stages",
    "run.",
    "logger.",
    "checkpoint.",
    "eval.",
    "level.",
    "hydra.",
)
RUN_COLUMNS = ("env_steps", "stage", "level", "steps")
#: eval.csv: one row per episode (``steps``), or, in files written before, one row per evaluation (its mean)
EVAL_RUN_COLUMNS = ("env_steps", "stage", "level", "steps")
EVAL_RUN_MEAN_COLUMNS = ("env_steps", "stage", "level", "survival_mean")
#: worlds of evaluate.py episodes written before the ``worlds`` column: ``make_env(seed=s)``'s, the worlds a seed-s
#: training run starts on
OLD_WORLDS = "seed-{} worlds, not held out"
#: worlds of in-training evaluations written before the ``worlds`` column (the run's seed + ``eval.seed_offset``)
OLD_EVAL_WORLDS = "in-training evaluation worlds (run seed + {:,}), not held out"
EVAL_FILE_COLUMNS = ("policy", "level", "steps", "success", "episode")
LEVEL_ORDER = {name: i for i, name in enumerate((*evaaa.LEVELS, *evaaa.TESTBEDS))}


def level_sorted(names: Iterable[str]) -> list[str]:
    """``names`` without repeats, levels in curriculum order, then testbeds in theirs, then any others by name."""
    return sorted(dict.fromkeys(names), key=lambda n: (LEVEL_ORDER.get(n, len(LEVEL_ORDER)), n))


class ReportError(ValueError):
    """Bad input: a path that does not exist, a file of the wrong kind, nothing to report on."""


# ------------------------------------------------------------------------------------------------ runs
@dataclass
class RunRecord:
    """One training run directory as a report reads it: what it was configured to do and how far it got
    (the training loop's own view of a stage is :class:`evaaa_baselines.run.Run`)."""

    dir: Path
    config: dict = field(default_factory=dict)
    algo: str = "?"
    modality: str = "?"
    reward: str = "?"
    seed: int | None = None
    curriculum: bool = False
    stages: list[tuple[int, str, int]] = field(default_factory=list)  # (index, level, budget)
    episodes: pd.DataFrame | None = None
    #: eval.csv as written: one row per episode of the periodic evaluations (on validation worlds), or, in files of
    #: the older format (``eval_means_only``), one row per evaluation with its mean survival
    evals: pd.DataFrame | None = None
    eval_episodes: pd.DataFrame | None = None  # ``evals`` where it has one row per episode, else None
    complete: set[int] = field(default_factory=set)  # indices of finished stages
    steps: int = 0  # env steps reached, summed over stages
    problem: str | None = None  # why the run is missing or partial (None: finished)
    usable: bool = True  # False: nothing of it can be reported (no config or no episodes file)
    extras: tuple = ()  # other settings that tell this run's group apart (filled by describe_extras)
    eval_means_only: bool = False  # eval.csv of the format before per-episode rows: one mean per evaluation
    eval_acting: str = ""  # how its in-training evaluations acted, where eval.csv does not say
    eval_worlds: str = ""  # on which worlds, where eval.csv does not say
    notes: list[str] = field(default_factory=list)  # what was skipped while reading its files

    @property
    def total(self) -> int:
        return sum(b for _, _, b in self.stages)

    @property
    def training(self) -> str:
        return "curriculum" if self.curriculum else (self.stages[0][1] if self.stages else "?")

    @property
    def cpu_budget(self) -> float | None:
        """The CPU minutes a compute-bound run was given (``max_cpu_minutes`` with a step budget of
        :data:`~..config.COMPUTE_BOUND_STEPS` or more: the time ends it, as in a protocol's compute-matched runs),
        else None."""
        minutes = self.config.get("max_cpu_minutes")
        if minutes is None or not self.stages or min(b for _, _, b in self.stages) < COMPUTE_BOUND_STEPS:
            return None
        return float(minutes)

    @property
    def budget(self) -> str:
        """What a run was given, as labels show it: ``110 CPU-min`` (compute-bound) or ``150,000 env steps`` (per
        stage)."""
        if self.cpu_budget is not None:
            return f"{self.cpu_budget:g} CPU-min"
        return f"{self.stages[0][2]:,} env steps" if self.stages else "?"

    def offset(self, stage: int) -> int:
        """Env steps of the stages before ``stage``."""
        return sum(b for i, _, b in self.stages if i < stage)

    @property
    def latest_stage(self) -> int:
        """The stage the run is in (or ended in)."""
        seen = [int(s) for df in (self.episodes, self.evals) if df is not None and len(df) for s in df["stage"]]
        return max([*seen, *self.complete, 0])


def find_run_dirs(paths: Iterable[str | Path]) -> list[Path]:
    """Run directories at or under ``paths``: directories with ``.hydra/config.yaml`` or a training
    ``episodes.csv`` / ``eval.csv`` / checkpoint (hidden folders such as submitit's logs are skipped)."""
    found: list[Path] = []
    for root in paths:
        root = Path(root)
        if not root.is_dir():
            raise ReportError(f"runs: {root} is not a directory")
        before = len(found)
        for here, dirs, files in os.walk(root):
            dirs[:] = sorted(d for d in dirs if not d.startswith("."))
            here = Path(here)
            if (here / ".hydra" / "config.yaml").is_file() or _looks_like_run(here, files):
                found.append(here)
                dirs[:] = []  # a run directory holds no other run
        if len(found) == before:
            raise ReportError(f"runs: no run directory (.hydra/config.yaml, episodes.csv, eval.csv) under {root}")
    return list(dict.fromkeys(p.resolve() for p in found))


def _looks_like_run(here: Path, files: Sequence[str]) -> bool:
    if "checkpoint.pt" in files or any(MODEL_FILE.match(f) for f in files):
        return True
    for name in ("episodes.csv", "eval.csv"):
        if name in files:
            with open(here / name, newline="") as f:
                header = f.readline().strip().split(",")
            if {"env_steps", "stage"} <= set(header):  # training files, not evaluate.py's episodes.csv
                return True
    return False


def load_run(run_dir: str | Path) -> RunRecord:
    """A run directory as a :class:`RunRecord`; a run that cannot be used says why in ``problem``."""
    run = RunRecord(Path(run_dir).resolve())
    cfg_path = run.dir / ".hydra" / "config.yaml"
    if not cfg_path.is_file():
        run.problem, run.usable = "no .hydra/config.yaml: its settings are unknown, so it is left out", False
        return run
    try:
        cfg = OmegaConf.load(cfg_path)
        run.config = OmegaConf.to_container(cfg, resolve=True)
        run.algo, run.modality, run.reward = cfg.algo.name, cfg.modality.name, cfg.reward.name
        run.seed = int(cfg.seed)
        run.curriculum = "stages" in cfg.level
        run.stages = [(s.index, s.level, s.budget) for s in config_stages(cfg)]
    except Exception as err:  # noqa: BLE001 - any malformed config is reported, not fatal
        run.problem, run.usable = f"unreadable .hydra/config.yaml ({err}); left out", False
        return run
    run.episodes = _read_run_csv(run.dir / "episodes.csv", RUN_COLUMNS, run.notes)
    run.evals = _read_run_csv(run.dir / "eval.csv", EVAL_RUN_COLUMNS, run.notes, EVAL_RUN_MEAN_COLUMNS)
    if run.evals is not None:
        run.eval_means_only = "steps" not in run.evals.columns
        ev = run.config.get("eval") or {}
        # DQN has no action distribution: its in-training evaluations took the greedy action whatever eval.sample
        run.eval_acting = "sample" if ev.get("sample") and run.algo != "dqn" else "mode"
        run.eval_worlds = OLD_EVAL_WORLDS.format(int(ev.get("seed_offset", 0)))
        for column, default in (("acting", run.eval_acting), ("worlds", run.eval_worlds)):
            run.evals[column] = run.evals[column].fillna(default) if column in run.evals else default
        run.eval_episodes = None if run.eval_means_only else run.evals
    for index, level, budget in run.stages:
        later = any(df is not None and (df["stage"] > index).any() for df in (run.episodes, run.evals))
        evaluated_at_end = (
            run.evals is not None and ((run.evals["stage"] == index) & (run.evals["env_steps"] >= budget)).any()
        ) or _cpu_spent(run, index)
        if (run.dir / f"model-{index}-{level}.pt").is_file() or later or evaluated_at_end:
            run.complete.add(index)
    # env steps reached: the furthest logged step (a stage ended by `max_minutes` is complete short of its budget);
    # a complete stage that logged nothing counts its whole budget
    reached, logged = [], set()
    for df in (run.episodes, run.evals):
        if df is not None and len(df):
            reached += [run.offset(int(s)) + int(e) for s, e in zip(df["stage"], df["env_steps"])]
            logged |= {int(s) for s in df["stage"]}
    reached += [run.offset(i) + run.stages[i][2] for i in run.complete if i not in logged]
    run.steps = min(max(reached, default=0), run.total)
    if run.episodes is None:
        run.problem, run.usable = "missing: no episodes.csv (the run never started, or its files are gone)", False
    elif len(run.complete) < len(run.stages):
        unfinished = [level for i, level, _ in run.stages if i not in run.complete]
        run.problem = (
            f"partial: {run.steps:,} of {run.total:,} env steps (unfinished: {', '.join(unfinished)}); "
            "its curves are drawn, its unfinished stages are left out of the final-survival tables"
        )
    if run.episodes is not None and not len(run.episodes) and run.problem is None:
        run.problem = "no finished training episode (the budget is shorter than an episode)"
    return run


def _cpu_spent(run: RunRecord, stage: int) -> bool:
    """A compute-bound stage evaluated after its CPU minutes were spent: it ended (its last evaluation's
    ``cpu_seconds`` reached ``max_cpu_minutes``; a record keeps no model file to say so)."""
    minutes = run.cpu_budget
    ev = run.evals
    if minutes is None or ev is None or "cpu_seconds" not in ev.columns:
        return False
    spent = pd.to_numeric(ev.loc[ev["stage"] == stage, "cpu_seconds"], errors="coerce")
    return bool((spent >= 60.0 * minutes).any())


def csv_text(path: Path, notes: list[str]) -> io.StringIO:
    """A CSV file's text, less a last row cut short (every writer here ends its rows with a newline: a file that
    does not end with one was being written when its process stopped); ``notes`` gets a line saying so.

    Raises :class:`ReportError` for an empty file (it has not even a header)."""
    data = path.read_bytes()
    if not data.strip():
        raise ReportError(f"{path} is empty ({len(data)} bytes, not even a header line): remove it or write it again")
    text = data.decode("utf-8", errors="replace")
    if not text.endswith("\n") and "\n" in text.rstrip("\r"):
        text = text[: text.rindex("\n") + 1]
        notes.append(
            f"{path}: its last row was cut short (the file was being written when its process stopped); "
            "that row is skipped"
        )
    return io.StringIO(text)


def _read_run_csv(
    path: Path, needed: Sequence[str], notes: list[str], older: Sequence[str] = ()
) -> pd.DataFrame | None:
    """A training CSV with the columns ``needed`` (or, for files of an older format, ``older``)."""
    if not path.is_file():
        return None
    df = pd.read_csv(csv_text(path, notes))
    df = df.rename(columns={k: v for k, v in TRAINING_OLD_NAMES.items() if v not in df.columns})  # older runs
    missing = [c for c in needed if c not in df.columns]
    if missing and older and all(c in df.columns for c in older):
        return df
    if missing:
        raise ReportError(f"{path} is not a training {path.name} (no column {', '.join(missing)})")
    return df


#: a setting added to the configs after runs were made, whose absence from a run stands for whatever the runs made
#: since say (it changed nothing for the runs made before it)
AS_SINCE = object()
#: settings added to the configs after runs were made, with the value a run without the key is read as having (what
#: the versions before the key did), so that runs made before and after it pool where nothing else differs
ADDED_SETTINGS: dict[str, Any] = {
    "env.backend": "cpu",  # before backends, MuJoCo stepped every world on the CPU
    # before it, every vector sense had its own size in algo.encoder.mlp; the default sizes a sense it does not list
    "algo.encoder.mlp_default": AS_SINCE,
}


def describe_extras(runs: Sequence[RunRecord]) -> None:
    """Set each run's ``extras``: the settings (beyond algorithm, modality, reward and training levels) in which
    runs of the same algorithm differ, as ``key=value`` pairs, so that they land in separate groups.  A setting a
    run's config lacks because it was added later (:data:`ADDED_SETTINGS`) is read as its value from before."""
    flat = {id(r): _flatten(r.config) | {"budget": r.budget} for r in runs}
    by_algo: dict[str, list[RunRecord]] = {}
    for r in runs:
        by_algo.setdefault(r.algo, []).append(r)
    for same in by_algo.values():
        keys = sorted({k for r in same for k in flat[id(r)]})
        values: dict[str, dict[int, str]] = {}
        for k in keys:
            given = {id(r): _setting(flat[id(r)][k]) for r in same if k in flat[id(r)]}
            before = ADDED_SETTINGS.get(k, None)
            if before is AS_SINCE and len(set(given.values())) == 1:
                before = next(iter(given.values()))
            values[k] = {id(r): given.get(id(r), _setting(before)) for r in same}
        varying = [
            k
            for k in keys
            if not k.startswith(BOOKKEEPING)
            and k not in ("algo.name", "modality.name", "reward.name")
            and not k.startswith("modality.enabled")
            and len(set(values[k].values())) > 1
        ]
        for r in same:
            r.extras = tuple(f"{k}={values[k][id(r)]}" for k in varying)


def _setting(value: Any) -> str:
    """A setting's value as labels show and compare it: a whole number without its ``.0`` (``100`` given on the
    command line and ``100.0`` from a config file are one setting), anything else as written."""
    if isinstance(value, float) and value.is_integer() and abs(value) < 1e15:
        return str(int(value))
    return str(value)


def _flatten(node: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(node, dict):
        out: dict[str, Any] = {}
        for k, v in node.items():
            out |= _flatten(v, f"{prefix}{k}.")
        return out
    return {prefix[:-1]: node}


def labels(
    runs: Sequence[RunRecord], parts: Sequence[str] = ("algo", "modality", "reward", "extras", "condition")
) -> dict[Path, str]:
    """A label per run naming the algorithm and whichever of ``parts`` differ among ``runs`` (so runs that differ
    only in their seed share a label).  ``condition``: curriculum or direct; ``training``: curriculum or the level."""

    def part(r: RunRecord, name: str) -> str:
        if name == "condition":
            return "curriculum" if r.curriculum else "direct"
        if name == "training":
            return "curriculum" if r.curriculum else f"trained on {r.training}"
        if name == "extras":  # the budget by its value alone: "110 CPU-min", "150,000 env steps"
            return ", ".join(e.removeprefix("budget=") for e in r.extras)
        return str(getattr(r, name))

    shown = [p for p in parts if p == "algo" or len({part(r, p) for r in runs}) > 1]
    return {r.dir: " · ".join(x for x in (part(r, p) for p in shown) if x) for r in runs}


# ------------------------------------------------------------------------------------------------ episode files
def read_episodes(paths: Sequence[str | Path | io.StringIO]) -> pd.DataFrame:
    """Episode rows of several CSV files in one frame (``success`` as booleans, NaN where a level has none)."""
    frames = [pd.read_csv(p, dtype={"participant": str, "seed": str}, keep_default_na=False) for p in paths]
    if not frames:
        raise ValueError("no episode files given")
    rows = pd.concat(frames, ignore_index=True)
    # files written before the acting column existed: how their checkpoints acted is not known
    rows["acting"] = rows["acting"].fillna("") if "acting" in rows else ""
    rows["success"] = rows["success"].map({"True": True, "False": False, True: True, False: False, "": np.nan})
    # files written before the worlds column: evaluate.py built make_env(seed=s)'s worlds, a seed-s run's own
    old = (
        rows["seed"].fillna("").astype(str).map(lambda s: OLD_WORLDS.format(s or "?"))
        if "seed" in rows
        else OLD_WORLDS.format("?")
    )
    worlds = rows["worlds"].fillna("").astype(str) if "worlds" in rows else pd.Series("", index=rows.index)
    rows["worlds"] = worlds.where(worlds != "", old)
    return rows


def display_names(rows: pd.DataFrame) -> pd.Series:
    """The policy column as tables and figures show it: a checkpoint's path with how it acted, e.g.
    ``run/model-0-1-1.pt [sample]``, so that one checkpoint evaluated in two ways gives two entries."""
    if "acting" not in rows:
        return rows["policy"]
    acting = rows["acting"].fillna("").astype(str)
    return rows["policy"].where(acting == "", rows["policy"] + " [" + acting + "]")


# ------------------------------------------------------------------------------------------------ evaluations
def _episode_files(paths: Iterable[str | Path]) -> list[Path]:
    """The episode CSVs of ``paths``: a file itself; a directory's ``episodes.csv``; or, for a directory without
    one (a protocol's ``evals`` folder), every ``episodes.csv`` below it — hidden folders and evaluations moved
    aside (``.partial-``, ``.old-``) skipped, as they hold no finished evaluation of the models reported."""
    files: list[Path] = []
    for p in map(Path, paths):
        if p.is_file():
            files.append(p)
        elif (p / "episodes.csv").is_file():
            files.append(p / "episodes.csv")
        elif p.is_dir():
            found = []
            for here, dirs, names in os.walk(p):
                dirs[:] = sorted(d for d in dirs if not d.startswith(".") and ".partial-" not in d and ".old-" not in d)
                found += [Path(here) / "episodes.csv"] if "episodes.csv" in names else []
            if not found:
                raise ReportError(f"evals: {p} holds no episodes.csv, neither itself nor in a folder below it")
            files += found
        else:
            raise ReportError(f"evals: {p} is neither an episode CSV nor a directory holding episodes.csv")
    return files


def load_evaluations(paths: Iterable[str | Path], notes: list[str] | None = None) -> pd.DataFrame:
    """Episode rows of evaluation outputs (an ``out`` directory of evaluate.py, a folder of such directories
    searched recursively, or an episode CSV, e.g. human play records), in one frame with a ``file`` column.
    ``notes`` gets a line per skipped (cut short) row."""
    notes = [] if notes is None else notes
    frames = []
    for file in _episode_files(paths):
        text = csv_text(file, notes)
        columns = set(pd.read_csv(text, nrows=0).columns)
        missing = [c for c in EVAL_FILE_COLUMNS if c not in columns]
        if missing:
            raise ReportError(
                f"evals: {file} is not an episode file of scripts/evaluate.py or scripts/play.py "
                f"(no column {', '.join(missing)})"
            )
        text.seek(0)
        rows = read_episodes([text])
        frames.append(rows.assign(file=str(file)))
    if not frames:
        return pd.DataFrame(columns=[*EVAL_FILE_COLUMNS, "participant", "file"])
    return pd.concat(frames, ignore_index=True)


#: evaluate.py's ``acting`` values of checkpoints: how a report option names an acting mode
ACTING = re.compile(r"(mode|sample)(\+epsilon=[0-9.eE+-]+)?")


def check_acting(key: str, value: str | None) -> str | None:
    """``value`` if it names an acting mode (``mode``, ``sample``, with ``+epsilon=<e>``), else a
    :class:`ReportError` naming ``key`` and the allowed values."""
    if value is not None and not ACTING.fullmatch(str(value)):
        raise ReportError(
            f"{key}: {value!r} is no acting mode; allowed: mode, sample, and either with +epsilon=<e> "
            "(evaluate.py's acting column, e.g. mode+epsilon=0.05)"
        )
    return value


def can_sample(algo: str | None) -> bool:
    """Whether policies of ``algo`` have an action distribution to sample from (DQN's Q-values have none): such a
    checkpoint asked to sample takes its greedy action (``mode``).  An algorithm this package does not know: yes."""
    from ..rollout import samples_actions

    try:
        return samples_actions(str(algo))
    except ValueError:
        return True


#: how a checkpoint's greedy rows are labelled where they take part in a ``sample`` comparison (its algorithm has no
#: action distribution: :func:`stand_in`): ``sample (greedy: no action distribution)``
GREEDY_STAND_IN = " (greedy: no action distribution)"


def same_acting(a: str, b: str) -> bool:
    """Whether agents acting ``a`` and ``b`` (``/``-joined modes of several cells) may be compared: the same modes,
    a greedy stand-in (:data:`GREEDY_STAND_IN`) counting as the mode it stands in for."""
    return a.replace(GREEDY_STAND_IN, "") == b.replace(GREEDY_STAND_IN, "")


def stand_in(acting: str) -> str | None:
    """The acting mode a checkpoint without an action distribution shows in a comparison of ``acting``: its greedy
    action (``mode``, the same epsilon) for ``sample``; None where it acts as asked."""
    return "mode" + acting[len("sample") :] if acting.startswith("sample") else None


def select_acting(evals: pd.DataFrame, acting: str | None, runs: dict[Path, RunRecord] | None = None) -> pd.DataFrame:
    """Keep the checkpoints' episodes made acting ``acting`` (evaluate.py's ``acting`` column: ``mode``,
    ``sample``, ``mode+epsilon=0.05`` ...); reference agents' are always kept.  Without ``acting`` every way is
    kept: the report labels each checkpoint's cells with how it acted, so that greedy and sampled episodes are never
    pooled.  With ``runs`` (checkpoints tied to them: :func:`attach`), a run whose algorithm has no action
    distribution (DQN) and no episode asked to ``sample…`` keeps its greedy ones (:func:`stand_in`): evaluate.py
    records those as ``mode…`` even when asked to sample."""
    if not len(evals) or acting is None:
        return evals
    if acting == "unknown":  # episodes written before evaluate.py recorded how checkpoints acted
        acting = ""
    is_ckpt = ~evals["policy"].isin(REFERENCES) & evals["policy"].map(_is_checkpoint_path)
    modes = evals.loc[is_ckpt, "acting"].astype(str)
    # what the evaluation was asked for also selects (a DQN checkpoint's `sample` episodes, shown as `mode`)
    asked = evals["acting_recorded"].fillna(evals["acting"]).astype(str) if "acting_recorded" in evals else modes
    chosen = (evals["acting"].astype(str) == acting) | (asked.reindex(evals.index).astype(str) == acting)
    sub = stand_in(acting)
    if sub is not None and runs is not None and "run" in evals:
        greedy = is_ckpt & evals["run"].map(lambda d: d in runs and not can_sample(runs[d].algo))
        none_yet = ~chosen.groupby(evals["run"].astype(str)).transform("any")
        chosen |= greedy & none_yet & (evals["acting"].astype(str) == sub)
    if not chosen[is_ckpt].any() and is_ckpt.any():
        raise ReportError(
            f"acting: no checkpoint was evaluated acting {acting!r}; the evaluations hold "
            f"{', '.join(repr(m) for m in dict.fromkeys(modes))}"
        )
    return evals[~is_ckpt | chosen]


@dataclass
class Evaluations:
    """Evaluation episodes split into those of checkpoints tied to runs and those of reference agents."""

    checkpoints: pd.DataFrame  # + columns run (Path), ckpt_stage, ckpt_level, checkpoint
    references: pd.DataFrame
    orphans: list[str]  # problems: checkpoints whose run is gone or unreadable
    absent: list[str] = field(default_factory=list)  # checkpoints not on disk whose run is: their episodes count


def attach(evals: pd.DataFrame, runs: dict[Path, RunRecord]) -> Evaluations:
    """Tie every checkpoint's episodes to its run (the directory the checkpoint lies in; relative paths are taken
    from the current directory).  Runs found this way that were not among ``runs`` are loaded and added."""
    is_ref = evals["policy"].isin(REFERENCES) | ~evals["policy"].map(_is_checkpoint_path)
    refs, ckpts = evals[is_ref].copy(), evals[~is_ref].copy()
    orphans: list[str] = []
    absent: list[str] = []
    info: dict[str, tuple[Path | None, int, str]] = {}
    for policy, part in ckpts.groupby("policy", sort=False):
        where = (
            f"{len(part)} episodes on {', '.join(dict.fromkeys(part['level']))} "
            f"in {', '.join(dict.fromkeys(part['file']))}"
        )
        path = Path(policy)
        run_dir = path.parent.resolve()
        if run_dir not in runs:
            if (run_dir / ".hydra" / "config.yaml").is_file():
                runs[run_dir] = load_run(run_dir)
            else:
                gone = "is gone" if not run_dir.is_dir() else "has no .hydra/config.yaml"
                orphans.append(f"evaluation of {policy}: its run directory {gone}; left out ({where})")
                info[policy] = (None, -1, "")
                continue
        run = runs[run_dir]
        if not run.config:
            orphans.append(
                f"evaluation of {policy}: its run's settings are unknown ({run.problem}); left out ({where})"
            )
            info[policy] = (None, -1, "")
            continue
        match = MODEL_FILE.match(path.name) or BEST_MODEL_FILE.match(path.name)
        if match:
            stage, level = int(match.group(1)), match.group(2)
        else:  # checkpoint.pt (or a renamed file): the latest state, in the stage the run is in
            stage = run.latest_stage
            level = next((lv for i, lv, _ in run.stages if i == stage), run.training)
        if not path.is_file():  # a committed record keeps no model files: not a problem, its episodes count
            absent.append(policy)
        info[policy] = (run_dir, stage, level)
        if not can_sample(run.algo):  # DQN: evaluate.py's `sample` took the greedy action all the same
            relabel = (ckpts["policy"] == policy) & ckpts["acting"].astype(str).str.startswith("sample")
            ckpts.loc[relabel, "acting_recorded"] = ckpts.loc[relabel, "acting"]
            ckpts.loc[relabel, "acting"] = "mode" + ckpts.loc[relabel, "acting"].astype(str).str[len("sample") :]
    ckpts["run"] = ckpts["policy"].map(lambda p: info[p][0])
    if "acting_recorded" in ckpts:
        ckpts["acting_recorded"] = ckpts["acting_recorded"].fillna(ckpts["acting"])
    ckpts["ckpt_stage"] = ckpts["policy"].map(lambda p: info[p][1])
    ckpts["ckpt_level"] = ckpts["policy"].map(lambda p: info[p][2])
    ckpts = ckpts[ckpts["run"].notna()]
    return Evaluations(ckpts, refs, orphans, absent)


def _is_checkpoint_path(policy: str) -> bool:
    return policy.endswith(".pt") or "/" in policy or os.sep in policy


def final_checkpoints(ckpts: pd.DataFrame) -> pd.DataFrame:
    """Per run, the episodes of its furthest-trained evaluated checkpoint (a final ``model-*.pt`` before a
    ``model-best-*.pt`` or ``checkpoint.pt`` of the same stage)."""
    if not len(ckpts):
        return ckpts
    ckpts = ckpts.assign(_model=ckpts["policy"].map(lambda p: bool(MODEL_FILE.match(Path(p).name))))
    best = ckpts.sort_values(["ckpt_stage", "_model"], kind="stable").groupby("run", sort=False)["policy"].last()
    return ckpts[ckpts["policy"].isin(set(best))].drop(columns="_model")
