"""Reports from finished (or running) training runs and evaluations: the paper's figures and their tables.

Inputs are what the other tools write: run directories of ``scripts/train.py`` (``.hydra/config.yaml``,
``episodes.csv``, ``eval.csv``, ``model-<stage>-<level>.pt``, ``checkpoint.pt``) and episode files of
``scripts/evaluate.py`` (one row per episode; ``policy`` is a checkpoint path, ``oracle``, ``random`` or ``human``).
An evaluated checkpoint is tied to its run through the run directory it lies in, whose ``.hydra/config.yaml`` says
what was trained (algorithm, modality, reward, level or curriculum, seed, ...).

Statistics (:mod:`.stats`): a survival cell is the interquartile mean (IQM) of the episodes with its 95 % percentile
bootstrap interval (episodes redrawn within each seed: seeds are the strata), beside the mean over seeds of each
seed's value ± the standard error across seeds (no error with one seed); where a seed has only one number (the mean
of its last evaluation in ``eval.csv``) the IQM and its bootstrap are over the seeds' numbers.  A success rate is the
share of successful episodes of all seeds pooled, with its Wilson score interval.  Reference agents have no seeds:
their numbers are over episodes (oracle, random) or, for ``human`` rows with several participants, over participants
(the strata of the bootstrap, and the units of the standard error).  Every cell says how many seeds and episodes.

Runs that differ only in their seed (and in bookkeeping: logger, evaluation and checkpoint cadence, threads, run
directory) are pooled; anything else that differs (modality, reward, a hyperparameter, steps per stage, curriculum
or not) makes a separate group, and labels name what differs.  Nothing is dropped silently: runs without episodes,
unfinished runs and evaluations whose run directory is gone are listed in the report.
"""

from __future__ import annotations

import io
import os
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from omegaconf import OmegaConf

import evaaa
from evaaa.analysis import display_names, read_episodes, standard_error
from evaaa.records import TRAINING_OLD_NAMES

from .config import stages as config_stages
from .stats import binomial_interval, interval

#: Policies of evaluation files that are not checkpoints.
REFERENCES = ("oracle", "random", "human")
MODEL_FILE = re.compile(r"^model-(\d+)-(.+)\.pt$")
#: the network of a stage's best evaluation (runtime.Run.best_model_path)
BEST_MODEL_FILE = re.compile(r"^model-best-(\d+)-(.+)\.pt$")
#: Settings that do not change what is trained: runs differing only in these (and the seed) are pooled.
BOOKKEEPING = ("seed", "resume", "start_over", "threads", "progress", "progress_window", "log_every", "total_steps",
               "stages", "run.", "logger.", "checkpoint.", "eval.", "level.", "hydra.")
RUN_COLUMNS = ("env_steps", "stage", "level", "steps")
EVAL_RUN_COLUMNS = ("env_steps", "stage", "level", "survival_mean")
EVAL_FILE_COLUMNS = ("policy", "level", "steps", "success", "episode")
LEVEL_ORDER = {name: i for i, name in enumerate((*evaaa.LEVELS, *evaaa.TESTBEDS))}


class ReportError(ValueError):
    """Bad input: a path that does not exist, a file of the wrong kind, nothing to report on."""


# ------------------------------------------------------------------------------------------------ runs
@dataclass
class Run:
    """One training run directory, what it was configured to do and how far it got."""

    dir: Path
    config: dict = field(default_factory=dict)
    algo: str = "?"
    modality: str = "?"
    reward: str = "?"
    seed: int | None = None
    curriculum: bool = False
    stages: list[tuple[int, str, int]] = field(default_factory=list)  # (index, level, budget)
    episodes: pd.DataFrame | None = None
    evals: pd.DataFrame | None = None
    complete: set[int] = field(default_factory=set)  # indices of finished stages
    steps: int = 0  # env steps reached, summed over stages
    problem: str | None = None  # why the run is missing or partial (None: finished)
    usable: bool = True  # False: nothing of it can be reported (no config or no episodes file)
    extras: tuple = ()  # other settings that tell this run's group apart (filled by describe_extras)
    notes: list[str] = field(default_factory=list)  # what was skipped while reading its files

    @property
    def total(self) -> int:
        return sum(b for _, _, b in self.stages)

    @property
    def training(self) -> str:
        return "curriculum" if self.curriculum else (self.stages[0][1] if self.stages else "?")

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


def load_run(run_dir: str | Path) -> Run:
    """A run directory as a :class:`Run`; a run that cannot be used says why in ``problem``."""
    run = Run(Path(run_dir).resolve())
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
    run.evals = _read_run_csv(run.dir / "eval.csv", EVAL_RUN_COLUMNS, run.notes)
    for index, level, budget in run.stages:
        later = any(df is not None and (df["stage"] > index).any() for df in (run.episodes, run.evals))
        evaluated_at_end = run.evals is not None and ((run.evals["stage"] == index)
                                                      & (run.evals["env_steps"] >= budget)).any()
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
        run.problem = (f"partial: {run.steps:,} of {run.total:,} env steps (unfinished: {', '.join(unfinished)}); "
                       "its curves are drawn, its unfinished stages are left out of the final-survival tables")
    if run.episodes is not None and not len(run.episodes) and run.problem is None:
        run.problem = "no finished training episode (the budget is shorter than an episode)"
    return run


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
        notes.append(f"{path}: its last row was cut short (the file was being written when its process stopped); "
                     "that row is skipped")
    return io.StringIO(text)


def _read_run_csv(path: Path, needed: Sequence[str], notes: list[str]) -> pd.DataFrame | None:
    if not path.is_file():
        return None
    df = pd.read_csv(csv_text(path, notes))
    df = df.rename(columns={k: v for k, v in TRAINING_OLD_NAMES.items() if v not in df.columns})  # older runs
    missing = [c for c in needed if c not in df.columns]
    if missing:
        raise ReportError(f"{path} is not a training {path.name} (no column {', '.join(missing)})")
    return df


def describe_extras(runs: Sequence[Run]) -> None:
    """Set each run's ``extras``: the settings (beyond algorithm, modality, reward and training levels) in which
    runs of the same algorithm differ, as ``key=value`` pairs, so that they land in separate groups."""
    flat = {id(r): _flatten(r.config) | {"steps_per_stage": r.stages[0][2] if r.stages else None} for r in runs}
    by_algo: dict[str, list[Run]] = {}
    for r in runs:
        by_algo.setdefault(r.algo, []).append(r)
    for same in by_algo.values():
        keys = sorted({k for r in same for k in flat[id(r)]})
        varying = [k for k in keys if not k.startswith(BOOKKEEPING) and k not in ("algo.name", "modality.name",
                                                                                  "reward.name")
                   and not k.startswith("modality.enabled")
                   and len({repr(flat[id(r)].get(k)) for r in same}) > 1]
        for r in same:
            r.extras = tuple(f"{k}={flat[id(r)].get(k)}" for k in varying)


def _flatten(node: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(node, dict):
        out: dict[str, Any] = {}
        for k, v in node.items():
            out |= _flatten(v, f"{prefix}{k}.")
        return out
    return {prefix[:-1]: node}


def labels(runs: Sequence[Run], parts: Sequence[str] = ("algo", "modality", "reward", "extras", "condition")
           ) -> dict[Path, str]:
    """A label per run naming the algorithm and whichever of ``parts`` differ among ``runs`` (so runs that differ
    only in their seed share a label).  ``condition``: curriculum or direct; ``training``: curriculum or the level."""
    def part(r: Run, name: str) -> str:
        if name == "condition":
            return "curriculum" if r.curriculum else "direct"
        if name == "training":
            return "curriculum" if r.curriculum else f"trained on {r.training}"
        if name == "extras":
            return ", ".join(r.extras)
        return str(getattr(r, name))

    shown = [p for p in parts if p == "algo" or len({part(r, p) for r in runs}) > 1]
    return {r.dir: " · ".join(x for x in (part(r, p) for p in shown) if x) for r in runs}


# ------------------------------------------------------------------------------------------------ numbers
def mean_se(values: Iterable[float]) -> tuple[float, float, int]:
    """Mean, standard error of the mean (ddof 1; NaN for one value) and count of the non-NaN values."""
    s = pd.Series(list(values), dtype=float).dropna()
    return (float(s.mean()) if len(s) else float("nan")), standard_error(s), int(len(s))


def final_survival(runs: Sequence[Run], source: str = "eval", window: int = 20) -> pd.DataFrame:
    """One row per finished stage of every run: the survival the stage ended with.

    ``source="eval"``: the stage's last evaluation (``eval.csv``: deterministic episodes at the stage's end), or,
    in a stage without evaluations, the mean survival of its last ``window`` training episodes; ``"train"``: always
    the training episodes.  The ``source`` column says which.
    """
    rows = []
    for r in runs:
        if not r.usable:
            continue
        for index, level, _ in r.stages:
            if index not in r.complete:
                continue
            value, used, scores, episodes = float("nan"), "none", (), 0
            ev = r.evals[r.evals["stage"] == index] if r.evals is not None else None
            if source == "eval" and ev is not None and len(ev):
                last = ev.sort_values("env_steps", kind="stable").iloc[-1]
                value, used = float(last["survival_mean"]), "eval"
                # eval.csv keeps each evaluation's mean, not its episodes: the seed contributes that one number
                scores = (value,)
                episodes = int(last["episodes"]) if "episodes" in last and pd.notna(last["episodes"]) else 1
            else:
                eps = r.episodes[r.episodes["stage"] == index]
                if len(eps):
                    scores = tuple(float(v) for v in eps["steps"].iloc[-window:])
                    value, used, episodes = float(np.mean(scores)), "train", len(scores)
            rows.append({"run": r.dir, "stage": index, "level": level, "survival": value, "source": used,
                         "last": index == r.stages[-1][0], "scores": scores, "episodes": episodes})
    return pd.DataFrame(rows, columns=["run", "stage", "level", "survival", "source", "last", "scores", "episodes"])


def curves(runs: Sequence[Run], bins: int = 20) -> pd.DataFrame:
    """Training curves: survival of the training episodes against env steps (summed over stages), per run in
    ``bins`` equal bins of its group's longest budget (bin i holds episodes ending in (i·w, (i+1)·w]; the first
    also holds step 0); columns run, bin, steps (bin centre), survival (mean of the run's episodes in the bin),
    scores (those episodes' survival) and episodes (how many)."""
    rows = []
    for r in runs:
        if not r.usable or r.episodes is None or not len(r.episodes) or not r.total:
            continue
        x = np.array([r.offset(int(s)) + int(e) for s, e in zip(r.episodes["stage"], r.episodes["env_steps"])])
        width = r.total / bins
        b = np.clip(np.ceil(x / width).astype(int) - 1, 0, bins - 1)
        survival = r.episodes["steps"].to_numpy(dtype=float)
        for i in np.unique(b):
            scores = tuple(survival[b == i].tolist())
            rows.append({"run": r.dir, "bin": int(i), "steps": (i + 0.5) * width, "survival": float(np.mean(scores)),
                         "scores": scores, "episodes": len(scores)})
    return pd.DataFrame(rows, columns=["run", "bin", "steps", "survival", "scores", "episodes"])


#: Columns of the statistics frames (:func:`across_seeds`), after the grouping columns.  ``statistic`` says what
#: ``value`` and its interval ``low``..``high`` are: ``iqm`` (survival: interquartile mean, 95 % percentile
#: bootstrap interval) or ``rate`` (success: pooled share of episodes, 95 % Wilson interval); ``mean`` ± ``se``: the
#: mean over units (seeds, or episodes or participants for reference agents) and the standard error across them;
#: ``n``: units, ``episodes``: episodes behind the numbers.
STAT_COLUMNS = ("value", "low", "high", "statistic", "mean", "se", "n", "episodes", "unit")


def estimate(samples: Sequence[Sequence[float]], success: bool = False, seed: int = 0,
             episodes: int | None = None) -> dict[str, Any]:
    """The statistics of one table cell from ``samples``: one sequence of episode scores per unit (seed,
    participant; a success is 1.0, a failure 0.0).  Units that gave one number each (a seed's evaluation mean) are
    bootstrapped as one stratum: there is nothing to redraw within a unit.  ``episodes``: the episodes behind the
    scores, where a score is itself a mean (default: one per score)."""
    samples = [np.asarray(s, dtype=float).ravel() for s in samples]
    samples = [s for s in samples if s.size]
    scored = int(sum(s.size for s in samples))
    episodes = scored if episodes is None else int(episodes)
    m, se, n = mean_se(s.mean() for s in samples)
    if success:
        est = binomial_interval(int(round(sum(s.sum() for s in samples))), scored)
        return {"value": est.value, "low": est.low, "high": est.high, "statistic": "rate", "mean": m, "se": se,
                "n": n, "episodes": episodes}
    strata = [np.concatenate(samples)] if samples and all(s.size == 1 for s in samples) else samples
    est = interval(strata, "iqm", seed=seed)
    return {"value": est.value, "low": est.low, "high": est.high, "statistic": "iqm", "mean": m, "se": se, "n": n,
            "episodes": episodes}


def across_seeds(values: pd.DataFrame, by: Sequence[str], value: str, *, success: bool = False,
                 unit: str = "seeds") -> pd.DataFrame:
    """Per group of ``by``: the statistics of :data:`STAT_COLUMNS` over the group's rows (one row per seed, its
    episodes' scores in a ``scores`` column, or ``value`` alone where there is none)."""
    out = []
    for key, part in values.groupby(list(by), sort=False, dropna=False):
        if "scores" in part:
            samples = [s if len(s) else () for s in part["scores"]]
        else:
            samples = [(v,) for v in part[value].astype(float).dropna()]
        est = estimate(samples, success, episodes=int(part["episodes"].sum()) if "episodes" in part else None)
        out.append({**dict(zip(by, key if isinstance(key, tuple) else (key,))), **est, "unit": unit})
    return pd.DataFrame(out, columns=[*by, *STAT_COLUMNS])


# ------------------------------------------------------------------------------------------------ evaluations
def load_evaluations(paths: Iterable[str | Path], notes: list[str] | None = None) -> pd.DataFrame:
    """Episode rows of evaluation outputs (an ``out`` directory of evaluate.py or an episode CSV, e.g. human
    play records), in one frame with a ``file`` column.  ``notes`` gets a line per skipped (cut short) row."""
    notes = [] if notes is None else notes
    frames = []
    for p in paths:
        p = Path(p)
        file = p / "episodes.csv" if p.is_dir() else p
        if not file.is_file():
            raise ReportError(f"evals: {p} is neither an episode CSV nor a directory holding episodes.csv")
        text = csv_text(file, notes)
        columns = set(pd.read_csv(text, nrows=0).columns)
        missing = [c for c in EVAL_FILE_COLUMNS if c not in columns]
        if missing:
            raise ReportError(f"evals: {file} is not an episode file of scripts/evaluate.py or scripts/play.py "
                              f"(no column {', '.join(missing)})")
        text.seek(0)
        rows = read_episodes([text])  # type: ignore[list-item]  (pandas reads a text buffer like a path)
        frames.append(rows.assign(file=str(file)))
    if not frames:
        return pd.DataFrame(columns=[*EVAL_FILE_COLUMNS, "participant", "file"])
    return pd.concat(frames, ignore_index=True)


def select_acting(evals: pd.DataFrame, acting: str | None) -> pd.DataFrame:
    """Keep the checkpoints' episodes made acting ``acting`` (evaluate.py's ``acting`` column: ``mode``,
    ``sample``, ``mode+epsilon=0.05`` ...); reference agents' are always kept.  Without ``acting``, a checkpoint
    evaluated in more than one way is an error: pooling its greedy and sampled episodes would describe neither."""
    if not len(evals):
        return evals
    if acting == "unknown":  # episodes written before evaluate.py recorded how checkpoints acted
        acting = ""
    is_ckpt = ~evals["policy"].isin(REFERENCES) & evals["policy"].map(_is_checkpoint_path)
    modes = evals.loc[is_ckpt, "acting"].astype(str)
    if acting is not None:
        if not (modes == acting).any() and is_ckpt.any():
            raise ReportError(f"acting: no checkpoint was evaluated acting {acting!r}; the evaluations hold "
                              f"{', '.join(repr(m) for m in dict.fromkeys(modes))}")
        return evals[~is_ckpt | (evals["acting"].astype(str) == acting)]
    for policy, part in evals[is_ckpt].groupby("policy", sort=False):
        ways = list(dict.fromkeys(part["acting"].astype(str)))
        if len(ways) > 1:
            raise ReportError(f"evals: {policy} was evaluated in {len(ways)} ways ({', '.join(map(repr, ways))}); "
                              f"choose one with acting=<{'|'.join(w or 'unknown' for w in ways)}>")
    return evals


@dataclass
class Evaluations:
    """Evaluation episodes split into those of checkpoints tied to runs and those of reference agents."""

    checkpoints: pd.DataFrame  # + columns run (Path), ckpt_stage, ckpt_level, checkpoint
    references: pd.DataFrame
    orphans: list[str]  # problems: checkpoints whose run is gone or unreadable


def attach(evals: pd.DataFrame, runs: dict[Path, Run]) -> Evaluations:
    """Tie every checkpoint's episodes to its run (the directory the checkpoint lies in; relative paths are taken
    from the current directory).  Runs found this way that were not among ``runs`` are loaded and added."""
    is_ref = evals["policy"].isin(REFERENCES) | ~evals["policy"].map(_is_checkpoint_path)
    refs, ckpts = evals[is_ref].copy(), evals[~is_ref].copy()
    orphans: list[str] = []
    info: dict[str, tuple[Path | None, int, str]] = {}
    for policy, part in ckpts.groupby("policy", sort=False):
        where = (f"{len(part)} episodes on {', '.join(dict.fromkeys(part['level']))} "
                 f"in {', '.join(dict.fromkeys(part['file']))}")
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
            orphans.append(f"evaluation of {policy}: its run's settings are unknown ({run.problem}); left out "
                           f"({where})")
            info[policy] = (None, -1, "")
            continue
        match = MODEL_FILE.match(path.name) or BEST_MODEL_FILE.match(path.name)
        if match:
            stage, level = int(match.group(1)), match.group(2)
        else:  # checkpoint.pt (or a renamed file): the latest state, in the stage the run is in
            stage = run.latest_stage
            level = next((lv for i, lv, _ in run.stages if i == stage), run.training)
        if not path.is_file():
            orphans.append(f"evaluation of {policy}: the checkpoint file is gone but its run is there; its episodes "
                           f"are used ({where})")
        info[policy] = (run_dir, stage, level)
    ckpts["run"] = ckpts["policy"].map(lambda p: info[p][0])
    ckpts["ckpt_stage"] = ckpts["policy"].map(lambda p: info[p][1])
    ckpts["ckpt_level"] = ckpts["policy"].map(lambda p: info[p][2])
    ckpts = ckpts[ckpts["run"].notna()]
    return Evaluations(ckpts, refs, orphans)


def _is_checkpoint_path(policy: str) -> bool:
    return policy.endswith(".pt") or "/" in policy or os.sep in policy


def final_checkpoints(ckpts: pd.DataFrame) -> pd.DataFrame:
    """Per run, the episodes of its furthest-trained evaluated checkpoint (a final ``model-*.pt`` before a
    ``model-best-*.pt`` or ``checkpoint.pt`` of the same stage)."""
    if not len(ckpts):
        return ckpts
    ckpts = ckpts.assign(_model=ckpts["policy"].map(lambda p: bool(MODEL_FILE.match(Path(p).name))))
    best = (ckpts.sort_values(["ckpt_stage", "_model"], kind="stable").groupby("run", sort=False)["policy"].last())
    return ckpts[ckpts["policy"].isin(set(best))].drop(columns="_model")


def per_run(ckpts: pd.DataFrame, value: str, by: Sequence[str] = ("run", "level")) -> pd.DataFrame:
    """Each run's mean of ``value`` (success as 0/1, or steps) per ``by``: one value per seed, with its episodes'
    values in ``scores``."""
    grouped = ckpts.assign(_v=ckpts[value].astype(float)).groupby(list(by), sort=False)["_v"]
    return grouped.agg(**{value: "mean", "scores": lambda v: tuple(v.dropna())}).reset_index()


def reference_stats(refs: pd.DataFrame, value: str) -> pd.DataFrame:
    """Per (policy, level) the statistics (:data:`STAT_COLUMNS`) of ``value`` (``success`` or ``steps``) for
    reference agents: over episodes, or with participants as units for human rows of several participants."""
    out = []
    for (policy, level), part in refs.groupby(["policy", "level"], sort=False):
        vals, unit, samples = part[value].astype(float), "episodes", None
        if "participant" in part and part["participant"].astype(str).str.len().gt(0).all() \
                and part["participant"].nunique() > 1:
            unit = "participants"
            samples = [tuple(v.dropna()) for _, v in part.assign(_v=vals).groupby("participant")["_v"]]
        est = estimate(samples if samples is not None else [tuple(vals.dropna())], success=value == "success")
        if unit == "episodes":  # mean ± se over episodes, not over the one stratum
            est |= dict(zip(("mean", "se", "n"), mean_se(vals)))
        out.append({"label": policy, "level": level, **est, "unit": unit})
    return pd.DataFrame(out, columns=["label", "level", *STAT_COLUMNS])


# ------------------------------------------------------------------------------------------------ tables
def sample_size(n: int, episodes: int, unit: str = "seeds") -> str:
    """``2 seeds × 20 ep.`` (or ``2 seeds, 37 ep.`` when the seeds have unequal numbers of episodes); reference
    agents: ``20 ep.``, or ``3 participants, 30 ep.``."""
    if unit == "episodes":
        return f"{episodes} ep."
    word = unit if n != 1 else unit.rstrip("s")
    return f"{n} {word} × {episodes // n} ep." if n and episodes % n == 0 else f"{n} {word}, {episodes} ep."


def cell(row: Mapping[str, Any], percent: bool = False) -> str:
    """A table cell from a row of :data:`STAT_COLUMNS`: survival ``IQM [low, high]; mean ± se (n=…)``, success
    ``rate% [low, high] (n=…)`` (one decimal)."""
    if not row["n"] or np.isnan(row["value"]):
        return "–"
    k, pct = (100.0, "%") if percent else (1.0, "")
    text = f"{k * row['value']:.1f}{pct}"
    if not np.isnan(row["low"]):
        text += f" [{k * row['low']:.1f}, {k * row['high']:.1f}]"
    if row["statistic"] == "iqm":
        text += f"; {row['mean']:.1f}" + ("" if np.isnan(row["se"]) else f" ± {row['se']:.1f}")
    return f"{text} (n={sample_size(int(row['n']), int(row['episodes']), row.get('unit', 'seeds'))})"


def pivot_table(stats: pd.DataFrame, row: str, col: str, *, percent: bool = False, row_title: str = "level",
                rows: Sequence[str] | None = None, cols: Sequence[str] | None = None) -> str:
    """A Markdown table of ``stats`` (:data:`STAT_COLUMNS`) with one row per ``row`` value and one column per
    ``col`` value (cells: :func:`cell`)."""
    rows = list(rows if rows is not None else dict.fromkeys(stats[row]))
    cols = list(cols if cols is not None else dict.fromkeys(stats[col]))
    lines = [f"| {row_title} | " + " | ".join(cols) + " |", "|---|" + "---|" * len(cols)]
    for r in rows:
        cells = []
        for c in cols:
            hit = stats[(stats[row] == r) & (stats[col] == c)]
            cells.append(cell(hit.iloc[0], percent) if len(hit) else "–")
        lines.append(f"| {r} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _level_sorted(names: Iterable[str]) -> list[str]:
    return sorted(dict.fromkeys(names), key=lambda n: (LEVEL_ORDER.get(n, len(LEVEL_ORDER)), n))


# ------------------------------------------------------------------------------------------------ evaluate.py
#: What evaluate.py's summary table shows, for the text above it.
SUMMARY_NOTE = ("Testbeds: success rate `rate [low, high]`, the share of successful episodes with its 95 % Wilson "
                "score interval. Training levels: survival (decisions) `IQM [low, high]; mean ± se`, the "
                "interquartile mean of the episodes with its 95 % percentile bootstrap interval (2000 resamples, "
                "episodes redrawn within each seed; human play: within each participant), then the mean ± standard "
                "error over episodes. n: episodes (and participants or seeds where there are several).")


def summarize(rows: pd.DataFrame) -> pd.DataFrame:
    """evaluate.py's summary: one row per (level, policy and how it acted; ``policy`` holds
    :func:`evaaa.analysis.display_names`) with ``episodes``; the success rate with its Wilson interval
    (``success_rate``, ``success_low``, ``success_high``; NaN where the level has no success rule); survival as
    ``survival_iqm`` with its bootstrap interval (``survival_low``, ``survival_high``) and ``survival_mean`` ±
    ``survival_se`` over episodes; ``units`` and ``unit`` (the strata: participants of human play when several, else
    the evaluation seeds); mean ``collisions``."""
    rows = rows.assign(policy=display_names(rows))
    out = []
    for (level, policy), part in rows.groupby(["level", "policy"], sort=False):
        unit = "participants" if "participant" in part and part["participant"].astype(str).str.len().gt(0).all() \
            and part["participant"].nunique() > 1 else "seeds"
        key = "participant" if unit == "participants" else ("seed" if "seed" in part else None)
        strata = [g for _, g in part.groupby(key, sort=False)] if key else [part]
        steps = [tuple(g["steps"].astype(float)) for g in strata]
        surv = estimate(steps)
        mean, se, _ = mean_se(part["steps"].astype(float))
        judged = part["success"].notna()
        success = estimate([tuple(g.loc[judged.loc[g.index], "success"].astype(float)) for g in strata],
                           success=True) if judged.any() else {"value": np.nan, "low": np.nan, "high": np.nan}
        out.append({"level": level, "policy": policy, "episodes": len(part), "units": len(strata), "unit": unit,
                    "success_rate": success["value"], "success_low": success["low"], "success_high": success["high"],
                    "survival_iqm": surv["value"], "survival_low": surv["low"], "survival_high": surv["high"],
                    "survival_mean": mean, "survival_se": se, "collisions": float(part["collisions"].mean())})
    table = pd.DataFrame(out)
    return table.sort_values(by="level", key=lambda c: c.map(lambda n: LEVEL_ORDER.get(n, len(LEVEL_ORDER))),
                             kind="stable") if len(table) else table


def markdown_table(summary: pd.DataFrame) -> str:
    """evaluate.py's table: success rate (testbeds) or survival (training levels) per level, one column per policy
    (cells as :data:`SUMMARY_NOTE` says)."""
    policies = list(dict.fromkeys(summary["policy"]))
    lines = ["| level | " + " | ".join(policies) + " |", "|---|" + "---|" * len(policies)]
    for level, part in summary.groupby("level", sort=False):
        cells = []
        for policy in policies:
            hit = part[part["policy"] == policy]
            if hit.empty:
                cells.append("–")
                continue
            r = hit.iloc[0]
            n = f"{r['episodes']} ep." if r["units"] < 2 else sample_size(int(r["units"]), int(r["episodes"]),
                                                                          r["unit"])
            judged = not np.isnan(r["success_rate"])
            cells.append(cell({"value": r["success_rate"] if judged else r["survival_iqm"],
                               "low": r["success_low"] if judged else r["survival_low"],
                               "high": r["success_high"] if judged else r["survival_high"],
                               "statistic": "rate" if judged else "iqm", "mean": r["survival_mean"],
                               "se": r["survival_se"], "n": r["episodes"], "episodes": r["episodes"]},
                              percent=judged).rsplit(" (n=", 1)[0] + f" (n={n})")
        lines.append(f"| {level} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------------ figures
def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _finish(fig, axes, path: Path, title: str) -> Path:
    """Legends to the right of each panel (labels name algorithm, modality and more, so they are long), title,
    and the file, cropped to what was drawn."""
    for ax in axes:
        if ax.get_legend_handles_labels()[0]:
            ax.legend(frameon=False, fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
        ax.spines[["top", "right"]].set_visible(False)
    fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=120, bbox_inches="tight")
    _plt().close(fig)
    return Path(path)


def whiskers(stats: pd.DataFrame, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Bar heights (``value``) and their whiskers as matplotlib's (2, N) ``yerr``: the distance down to ``low`` and
    up to ``high`` (none where there is no interval)."""
    value = scale * stats["value"].to_numpy(dtype=float)
    low = np.nan_to_num(value - scale * stats["low"].to_numpy(dtype=float))
    high = np.nan_to_num(scale * stats["high"].to_numpy(dtype=float) - value)
    return value, np.clip(np.vstack([low, high]), 0, None)


def interval_note(stats: pd.DataFrame, drawn: str = "whiskers") -> str:
    """What the figure's bars or lines and their ``drawn`` (whiskers, band) show, for its caption."""
    kinds = set(stats["statistic"])
    parts = []
    if "iqm" in kinds:
        parts.append(f"interquartile mean, {drawn} 95 % bootstrap interval")
    if "rate" in kinds:
        parts.append(f"share of episodes, {drawn} 95 % Wilson interval")
    return "; ".join(parts)


def plot_bars(stats: pd.DataFrame, path: Path, *, ylabel: str, title: str, panel: str | None = None,
              scale: float = 1.0, levels: Sequence[str] | None = None, top: float | None = None) -> Path:
    """Grouped bars — one group per ``level``, one bar per ``label`` (``value``, its interval as whiskers) — in one
    panel per ``panel`` value (or a single panel); the y axis starts at 0 and ends at ``top`` if given."""
    plt = _plt()
    panels = list(dict.fromkeys(stats[panel])) if panel else [None]
    n_levels = stats["level"].nunique()
    fig, axes = plt.subplots(len(panels), 1, figsize=(max(4.5, 0.55 * len(stats) / len(panels) + 2.5, 1.2 * n_levels),
                                                      3.4 * len(panels)), squeeze=False)
    for ax, name in zip(axes[:, 0], panels):
        part = stats if name is None else stats[stats[panel] == name]
        order = [lv for lv in (levels or _level_sorted(part["level"])) if lv in set(part["level"])]
        names = list(dict.fromkeys(part["label"]))
        width = 0.8 / max(len(names), 1)
        for i, label in enumerate(names):
            one = part[part["label"] == label].set_index("level").reindex(order)
            heights, yerr = whiskers(one, scale)
            ax.bar(np.arange(len(order)) + (i - (len(names) - 1) / 2) * width, heights, width, yerr=yerr, capsize=3,
                   label=label)
        ax.set_xticks(range(len(order)), order, rotation=30 if len(order) > 2 else 0,
                      ha="right" if len(order) > 2 else "center")
        ax.set_ylabel(ylabel)
        ax.set_ylim(0, top)
        if name is not None:
            ax.set_title(str(name), fontsize=9)
    return _finish(fig, axes[:, 0], path, f"{title}\n({interval_note(stats)})")


def plot_lines(stats: pd.DataFrame, path: Path, *, x: str, panel: str | None, ylabel: str, xlabel: str,
               title: str, band: bool, scale: float = 1.0, order: Sequence[str] | None = None,
               hlines: pd.DataFrame | None = None, top: float | None = None) -> Path:
    """Lines of ``value`` per ``label`` (one panel per ``panel`` value), with its interval as a band or whiskers;
    ``order``: categorical x values in this order (labels drawn side by side, slightly apart, so that equal values
    stay visible); ``hlines``: (label, value) rows drawn as dashed lines; the y axis starts at 0, ends at ``top``."""
    plt = _plt()
    panels = list(dict.fromkeys(stats[panel])) if panel else [None]
    cols = min(len(panels), 2)
    nrows = -(-len(panels) // cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(6.5 * cols, 3.6 * nrows), squeeze=False)
    for ax in axes.flat[len(panels):]:
        ax.set_visible(False)
    for ax, name in zip(axes.flat, panels):
        part = stats if name is None else stats[stats[panel] == name]
        n_labels = part["label"].nunique()
        for k, (label, line) in enumerate(part.groupby("label", sort=False)):
            if order is not None:
                line = line.assign(_x=line[x].map({v: i for i, v in enumerate(order)})).sort_values("_x")
                xs = line["_x"].to_numpy(dtype=float) + 0.04 * (k - (n_labels - 1) / 2)
            else:
                line = line.sort_values(x)
                xs = line[x].to_numpy(dtype=float)
            m, yerr = whiskers(line, scale)
            if band:
                (drawn,) = ax.plot(xs, m, marker="." if len(xs) < 30 else None, label=label)
                ax.fill_between(xs, m - yerr[0], m + yerr[1], alpha=0.25, color=drawn.get_color(), linewidth=0)
            else:
                ax.errorbar(xs, m, yerr=yerr, marker="o", capsize=3, label=label)
        for style, (_, ref) in zip(("--", ":", "-.", (0, (5, 1))), (hlines if hlines is not None else
                                                                    pd.DataFrame()).iterrows()):
            ax.axhline(scale * ref["value"], linestyle=style, linewidth=1, color="0.35", label=ref["label"])
        if order is not None:
            ax.set_xticks(range(len(order)), order)
            ax.set_xlim(-0.3, len(order) - 0.7)
        else:  # env steps: 250k, 1.5M rather than six-digit labels that run into each other
            from matplotlib.ticker import EngFormatter

            ax.xaxis.set_major_formatter(EngFormatter(sep=""))
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.set_ylim(0, top)
        if name is not None:
            ax.set_title(str(name), fontsize=9)
    note = interval_note(stats, "band" if band else "whiskers")
    return _finish(fig, list(axes.flat[:len(panels)]), path, f"{title}\n({note})")


# ------------------------------------------------------------------------------------------------ the report
@dataclass
class Report:
    markdown: Path
    figures: list[Path]
    tables: dict[str, pd.DataFrame]
    problems: list[str]


def build_report(run_paths: Sequence[str | Path], eval_paths: Sequence[str | Path], out: str | Path, *,
                 survival: str = "eval", window: int = 20, bins: int = 20, title: str = "evaaa report",
                 acting: str | None = None) -> Report:
    """Read runs and evaluations, write ``out/report.md``, its PNG figures and ``out/data/*.csv`` (the tables'
    numbers); returns what was written.  ``acting``: which of the checkpoints' evaluation modes to report
    (:func:`select_acting`)."""
    if survival not in ("eval", "train"):
        raise ReportError(f"survival must be eval or train, not {survival!r}")
    if window < 1 or bins < 1:
        raise ReportError("window and bins must be positive")
    if not run_paths and not eval_paths:
        raise ReportError("nothing to report: give runs=[...] (run directories) and/or evals=[...] "
                          "(evaluate.py outputs)")
    runs = {d: load_run(d) for d in find_run_dirs(run_paths)}
    # attach may add the runs of evaluated checkpoints
    read_notes: list[str] = []
    evals = attach(select_acting(load_evaluations(eval_paths, read_notes), acting), runs)
    run_list = sorted(runs.values(), key=lambda r: str(r.dir))
    usable = [r for r in run_list if r.usable]
    describe_extras(usable)
    out = Path(out)
    (out / "data").mkdir(parents=True, exist_ok=True)
    md: list[str] = [f"# {title}", ""]
    figures: list[Path] = []
    tables: dict[str, pd.DataFrame] = {}
    cwd = Path.cwd()

    def rel(p: Path) -> str:
        try:
            return str(p.relative_to(cwd))
        except ValueError:
            return str(p)

    n_policies = evals.checkpoints["policy"].nunique() + evals.references["policy"].nunique()
    md += [f"{len(run_list)} run directories; {n_policies} evaluated policies "
           f"({len(evals.checkpoints) + len(evals.references)} evaluation episodes).", "",
           "**Statistics.** Survival cells: `IQM [low, high]; mean ± se (n=…)` — the interquartile mean (mean of "
           "the middle 50 %) of the episodes with its 95 % percentile bootstrap interval (2000 resamples; episodes "
           "redrawn within each seed, seeds as strata; where a seed gives one number, its last evaluation's mean, "
           "the seeds' numbers are redrawn), then the mean over seeds of each seed's value ± the standard error "
           "across seeds (none with one seed). Success cells: `rate [low, high] (n=…)` — the share of successful "
           "episodes of all seeds pooled, with its 95 % Wilson score interval (not degenerate at 0 % or 100 %). "
           "n: seeds × episodes per seed (`2 seeds, 37 ep.` when seeds have unequal episodes). Reference agents "
           "(oracle, random): over episodes; human: participants as the units when there are several. Figures: "
           "bars and lines show the IQM or rate, whiskers and bands its 95 % interval. "
           "Runs that differ only in their seed are pooled; labels name what else differs.", ""]
    ways = list(dict.fromkeys(evals.checkpoints["acting"].astype(str))) if len(evals.checkpoints) else []
    if ways:
        md += ["Checkpoints acted: " + ", ".join(f"`{w}`" if w else "not recorded" for w in ways)
               + " (evaluate.py: `mode` the most likely action, `sample` drawn from the policy, `+epsilon=e` a "
               "random action with chance e).", ""]

    # ---- runs and problems
    md += ["## Runs", "", "| run | algo | modality | reward | training | seed | env steps | status |",
           "|---|---|---|---|---|---|---|---|"]
    for r in run_list:
        status = "finished" if r.problem is None else r.problem.split(":")[0]
        md.append(f"| {rel(r.dir)} | {r.algo} | {r.modality} | {r.reward} | {r.training} | "
                  f"{'' if r.seed is None else r.seed} | {r.steps:,} / {r.total:,} | {status} |")
    problems = [f"{rel(r.dir)}: {r.problem}" for r in run_list if r.problem] + evals.orphans
    problems += [note for r in run_list for note in r.notes] + read_notes
    groups: dict[tuple, list[Run]] = {}
    for r in usable:
        groups.setdefault((r.algo, r.modality, r.reward, r.extras, r.training, r.seed), []).append(r)
    problems += [f"{', '.join(rel(r.dir) for r in same)}: same settings and seed; all are counted as seeds"
                 for same in groups.values() if len(same) > 1]
    md += ["", "## Missing and partial runs", ""]
    md += [f"- {p}" for p in problems] if problems else ["None: every run finished and every evaluated checkpoint "
                                                         "belongs to a run given here."]
    md.append("")

    def section(heading: str, note: str, figure: Path | None, table: str | None, empty: str) -> None:
        md.extend([f"## {heading}", ""])
        if figure is None:
            md.extend([empty, ""])
            return
        figures.append(figure)
        md.extend([note, "", f"![{heading}]({figure.name})", "", table or "", ""])

    # ---- Fig. 4a: survival per training level; with vs without curriculum
    final = final_survival(usable, survival, window)
    by_dir = {r.dir: r for r in usable}
    fallback = int((final["source"] == "train").sum()) if survival == "eval" else 0
    source_note = ("Survival: the last evaluation of each finished stage (`eval.csv`, deterministic episodes)"
                   if survival == "eval" else f"Survival: the mean of each finished stage's last {window} training "
                   "episodes")
    if fallback:
        source_note += f"; {fallback} value(s) from the last {window} training episodes (stages without evaluation)"
    source_note += "."
    curriculum_algos = {(r.algo, r.modality, r.reward, r.extras) for r in usable if r.curriculum}
    left_runs = [r for r in usable if r.curriculum or (r.algo, r.modality, r.reward, r.extras) not in curriculum_algos]
    table = figure = None
    if len(final):
        lab = labels(left_runs)
        f = final[final["run"].isin(list(lab))].assign(label=lambda d: d["run"].map(lab))
        stats = across_seeds(f, ["label", "level"], "survival")
        tables["survival_per_level"] = stats
        levels = _level_sorted(stats["level"])
        figure = plot_bars(stats, out / "fig4a_survival_per_level.png", levels=levels, ylabel="survival (decisions)",
                      title="Survival per training level")
        table = pivot_table(stats, "level", "label", rows=levels)
    section("Survival per training level (Fig. 4a, left)",
            source_note + " Curriculum runs where an algorithm has them, else its direct runs.", figure, table,
            "No finished stage in the runs given.")

    both = {k for k in curriculum_algos if any(not r.curriculum and (r.algo, r.modality, r.reward, r.extras) == k
                                               for r in usable)}
    cmp_runs = [r for r in usable if (r.algo, r.modality, r.reward, r.extras) in both]
    table = figure = None
    if cmp_runs and len(final):
        lab = {d: f"{v} · {'curriculum' if by_dir[d].curriculum else 'direct'}"
               for d, v in labels(cmp_runs, ("algo", "modality", "reward", "extras")).items()}
        f = final[final["run"].isin(list(lab))].assign(label=lambda d: d["run"].map(lab))
        f = f[f["level"].isin(set(f[f["label"].str.endswith("direct")]["level"]))]  # levels with direct runs
        stats = across_seeds(f, ["label", "level"], "survival").sort_values(
            "label", key=lambda s: s.str.endswith("direct"), kind="stable")
        tables["curriculum_vs_direct"] = stats
        levels = _level_sorted(stats["level"])
        if len(stats):
            figure = plot_bars(stats, out / "fig4a_curriculum_vs_direct.png", levels=levels,
                               ylabel="survival (decisions)", title="With and without curriculum")
            table = pivot_table(stats, "level", "label", rows=levels)
    section("With and without curriculum (Fig. 4a, right)",
            source_note + " Curriculum: the stage of that level after the levels before it; direct: a run trained "
            "on that level alone.", figure, table,
            "No algorithm has both curriculum runs (`level=curriculum`) and direct runs (`level=<level>`) here.")

    # ---- Fig. 4b: success per testbed; generalisation by training level
    ck = evals.checkpoints
    ck_runs = [runs[d] for d in dict.fromkeys(ck["run"])] if len(ck) else []
    ck_lab = labels(ck_runs, ("algo", "modality", "reward", "extras", "training"))
    refs = evals.references
    tests = ck[ck["level"].isin(evaaa.TESTBEDS)]
    best = final_checkpoints(tests)
    ref_tests = reference_stats(refs[refs["level"].isin(evaaa.TESTBEDS)], "success")
    table = figure = None
    if len(best) or len(ref_tests):
        stats = across_seeds(per_run(best, "success").assign(label=lambda d: d["run"].map(ck_lab)),
                             ["label", "level"], "success", success=True) if len(best) else ref_tests.iloc[:0]
        stats = pd.concat([stats.assign(unit="seeds"), ref_tests], ignore_index=True)
        tables["success_per_testbed"] = stats
        testbeds = _level_sorted(stats["level"])
        figure = plot_bars(stats, out / "fig4b_success_per_testbed.png", levels=testbeds, scale=100, top=105,
                           ylabel="success rate (%)", title="Success per testbed")
        table = pivot_table(stats, "level", "label", rows=testbeds, percent=True, row_title="testbed")
    section("Success per testbed (Fig. 4b, left)",
            "Each run's furthest-trained evaluated checkpoint; its episodes pooled over seeds (Wilson interval); n: "
            "seeds × episodes for trained agents, episodes (or human participants) for the others.", figure, table,
            "No testbed evaluation given (`evals=[...]`).")

    table = figure = None
    if len(tests):
        per_ckpt = per_run(tests, "success", ("run", "policy", "ckpt_stage", "ckpt_level", "level"))
        mean_tb = per_ckpt.groupby(["run", "policy", "ckpt_stage", "ckpt_level"], sort=False).agg(
            success=("success", "mean"), testbeds=("success", "size"),
            scores=("scores", lambda s: tuple(x for one in s for x in one))).reset_index()
        mean_tb = mean_tb.sort_values("policy", key=lambda p: p.map(lambda s: not MODEL_FILE.match(Path(s).name)),
                                      kind="stable").drop_duplicates(["run", "ckpt_stage"])
        stats = across_seeds(mean_tb.assign(label=lambda d: d["run"].map(ck_lab)), ["label", "ckpt_level"],
                             "success", success=True).rename(columns={"ckpt_level": "level"})
        tables["generalisation"] = stats
        order = _level_sorted(stats["level"])
        ref_tb = refs[refs["level"].isin(evaaa.TESTBEDS)]
        ref_mean = reference_stats(ref_tb.assign(level="testbeds"), "success") if len(ref_tb) else None
        figure = plot_lines(stats, out / "fig4b_generalisation.png", x="level", panel=None, order=order,
                            ylabel="mean testbed success (%)", xlabel="trained up to level", scale=100, top=105,
                            band=False, title="Generalisation by training level", hlines=ref_mean)
        tb_names = ", ".join(_level_sorted(tests["level"]))
        table = pivot_table(stats, "level", "label", rows=order, percent=True, row_title="trained up to")
        table += f"\n\nTestbeds averaged: {tb_names} (each checkpoint over the testbeds it was evaluated on)."
    section("Generalisation by training level (Fig. 4b, right)",
            "Success averaged over the testbeds, for checkpoints trained up to each level (`model-<stage>-<level>.pt` "
            "of curriculum runs; a direct run's checkpoint at its level); dashed: reference agents.",
            figure, table, "No testbed evaluation of a run's checkpoint given.")

    # ---- evaluations on training levels (survival), when there are any
    train_ck = final_checkpoints(ck[ck["level"].isin(evaaa.LEVELS)])
    ref_train = reference_stats(refs[refs["level"].isin(evaaa.LEVELS)], "steps")
    if len(train_ck) or len(ref_train):
        stats = across_seeds(per_run(train_ck, "steps").assign(label=lambda d: d["run"].map(ck_lab)),
                             ["label", "level"], "steps") if len(train_ck) else ref_train.iloc[:0]
        stats = pd.concat([stats.assign(unit="seeds"), ref_train], ignore_index=True)
        tables["evaluation_survival"] = stats
        md += ["## Evaluation on training levels", "", "Survival (decisions) in evaluate.py's episodes (cells as "
               "described under Statistics); checkpoints as above.", "",
               pivot_table(stats, "level", "label", rows=_level_sorted(stats["level"])), ""]

    # ---- training curves per training set-up, one line per algorithm (and settings)
    all_curves = curves(usable, bins)
    table = figure = None
    if len(all_curves):
        lab = labels(usable, ("algo", "modality", "reward", "extras"))
        by = all_curves.assign(group=lambda d: d["run"].map(lambda x: f"trained on {by_dir[x].training}"),
                               label=lambda d: d["run"].map(lab))
        stats = across_seeds(by, ["group", "label", "bin", "steps"], "survival")
        tables["training_curves"] = stats
        trained_on = {by_dir[d].training for d in by["run"]}
        hl = None
        if len(trained_on) == 1 and len(ref_train):
            hl = ref_train[ref_train["level"] == next(iter(trained_on))]
            hl = hl.assign(label=hl["label"] + " (evaluation)") if len(hl) else None
        figure = plot_lines(stats, out / "fig_training_curves.png", x="steps", panel="group", band=True,
                            ylabel="survival (decisions)", xlabel="env steps", title="Training curves",
                            hlines=hl)
        ends = stats.sort_values("bin").groupby(["group", "label"], sort=False).tail(1)
        table = pivot_table(ends.rename(columns={"group": "level"}), "level", "label", row_title="training")
        table += (f"\n\nCurves: survival of the training episodes (exploring policy) in {bins} bins of env steps, "
                  "IQM of the bin's episodes with its 95 % bootstrap interval (band); table: the last bin. "
                  "Dashed/dotted: reference agents' IQM survival in evaluate.py's episodes on that level, when given.")
    section("Training curves",
            "One panel per training set-up, one line per algorithm and settings.", figure, table,
            "No finished training episode in the runs given.")

    # ---- Figs. 25-26: modality ablations
    ab_lab = labels(usable, ("algo", "reward", "extras", "training"))
    curve_rows = all_curves
    table = figure = None
    if len(curve_rows):
        # one bin grid per group: a group's runs share a budget (steps per stage is part of the group)
        by = curve_rows.assign(group=lambda d: d["run"].map(ab_lab), label=lambda d: d["run"].map(
            lambda x: by_dir[x].modality))
        stats = across_seeds(by, ["group", "label", "bin", "steps"], "survival")
        tables["ablation_curves"] = stats
        figure = plot_lines(stats, out / "fig25_ablation_curves.png", x="steps", panel="group", band=True,
                            ylabel="survival (decisions)", xlabel="env steps", title="Training curves per modality")
        last = final[final["last"]].assign(group=lambda d: d["run"].map(ab_lab),
                                           label=lambda d: d["run"].map(lambda x: by_dir[x].modality))
        fstats = across_seeds(last, ["group", "label"], "survival")
        tables["ablation_final_survival"] = fstats
        table = pivot_table(fstats, "label", "group", row_title="modality",
                            rows=sorted(dict.fromkeys(fstats["label"]), key=_modality_key)) if len(fstats) else ""
        table += (f"\n\nCurves: survival of training episodes in {bins} bins of env steps, IQM with its 95 % "
                  "bootstrap interval (band). Table: survival at the end of each run (" +
                  ("last evaluation" if survival == "eval" else f"last {window} training episodes") + ").")
    section("Modality ablations: training curves (Fig. 25)",
            "One panel per algorithm (and training set-up), one line per modality set.", figure, table,
            "No finished training episode in the runs given.")

    table = figure = None
    if len(best):
        ab_ck = labels(ck_runs, ("algo", "reward", "extras", "training"))
        stats = across_seeds(per_run(best, "success").assign(group=lambda d: d["run"].map(ab_ck),
                                                             label=lambda d: d["run"].map(lambda x: runs[x].modality)),
                             ["group", "label", "level"], "success", success=True)
        order = {g: i for i, g in enumerate(dict.fromkeys(stats["group"]))}
        stats = stats.sort_values("label", key=lambda s: s.map(_modality_key), kind="stable").sort_values(
            "group", key=lambda s: s.map(order), kind="stable")
        tables["ablation_success"] = stats
        figure = plot_bars(stats, out / "fig26_ablation_success.png", panel="group", scale=100, top=105,
                           ylabel="success rate (%)", title="Testbed success per modality")
        stats = stats.assign(column=stats["group"] + " · " + stats["label"]) if stats["group"].nunique() > 1 \
            else stats.assign(column=stats["label"])
        table = pivot_table(stats, "level", "column", rows=_level_sorted(stats["level"]), percent=True,
                            row_title="testbed")
    section("Modality ablations: testbed success (Fig. 26)",
            "Each run's furthest-trained evaluated checkpoint, evaluated with the observation keys it was trained on.",
            figure, table, "No testbed evaluation of a run's checkpoint given.")

    for name, frame in tables.items():
        frame.to_csv(out / "data" / f"{name}.csv", index=False)
    if len(curve_rows):
        curve_rows.assign(run=curve_rows["run"].map(lambda d: rel(d))).to_csv(out / "data" / "curves_per_run.csv",
                                                                                index=False)
    path = out / "report.md"
    path.write_text("\n".join(md).rstrip() + "\n")
    return Report(path, figures, tables, problems)


def _modality_key(name: str) -> tuple[int, str]:
    return (0 if name == "all" else 1, name)
