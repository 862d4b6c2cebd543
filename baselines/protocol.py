"""The paper's experiments as a protocol: a YAML file (``conf/protocol/<name>.yaml``) read into a validated
:class:`Protocol`, expanded into named **cells** (one training run, the evaluations of one model, a reference agent's
evaluation, the report), each a subprocess of ``scripts/train.py``, ``scripts/evaluate.py`` or
``scripts/report.py``; and the scheduler that runs the cells not yet done, a few at a time, resumably
(``scripts/reproduce.py``; docs/reports.md, "The paper's protocol at CPU scale").

A cell is *done* only when its outputs are complete: a training run when the final model of its last stage exists
and the done-marker written after ``train.py`` exited 0 (``<root>/done/<cell>.done``); an evaluation when every
``out`` folder of it holds ``episodes.csv`` (evaluate.py writes it last); the report when its marker is newer than
every other cell's outputs and every other cell is done.  A training cell that was started and not finished is
continued with ``resume=true`` (started over, ``start_over=true``, where it holds no checkpoint); an evaluation's
``out`` folder without ``episodes.csv`` is moved aside (``<out>.partial-<UTC time>``, never deleted) and the
evaluation run again.

A protocol's ``root`` may lie inside the repository (paper_cpu's does): commands name the files there relative to
the repository root, the folder's ``.gitignore`` keeps checkpoints, models and logs out of git, and the rest (run
settings and CSV logs, evaluation episodes, done-markers) can be committed.  On a clone of it a finished training
run whose models are gone counts as done while every evaluation of it is; one with evaluations still to make is
trained again (``start_over=true``).
"""

from __future__ import annotations

import fnmatch
import json
import os
import shlex
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from functools import cache
from pathlib import Path
from typing import Any, Literal

import yaml
from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

import evaaa

from .algos import names as algorithm_names
from .paths import CONF_DIR
from .rollout import samples_actions

REPO = CONF_DIR.parent
PROTOCOL_DIR = CONF_DIR / "protocol"
MODALITIES = sorted(p.stem for p in (CONF_DIR / "modality").glob("*.yaml"))
REWARDS = sorted(p.stem for p in (CONF_DIR / "reward").glob("*.yaml"))
#: the level groups evaluate.py expands (scripts/evaluate.py GROUPS)
LEVEL_GROUPS = {"testbeds": evaaa.TESTBEDS, "training": evaaa.LEVELS, "all": evaaa.LEVELS + evaaa.TESTBEDS}
#: seconds a script takes to start (imports, first env) on the 2-core box, added to every cell's estimate
STARTUP_SECONDS = 10.0
#: a run's checkpoints (baselines/training.py), deleted once it is done where keep_checkpoints is false
CHECKPOINTS = ("checkpoint.pt", "checkpoint-previous.pt")


class ProtocolError(ValueError):
    """A protocol file that cannot be used; the message names the file, the field and what it accepts."""


# ------------------------------------------------------------------------------------------------ the file
class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


def _check_levels(names: Sequence[str], allowed: Sequence[str], what: str) -> list[str]:
    bad = [n for n in names if n not in allowed]
    if bad:
        raise ValueError(f"{bad[0]!r} is not {what}; allowed: {', '.join(allowed)}")
    return list(names)


class RateFrom(_Strict):
    """A measured rate: the steady env steps/s of ``algo``'s row in a JSON of scripts/bench_train.py (a path relative
    to the repository root; a file of several runs, ``{"runs": {...}}``, gives its first run's)."""

    file: str
    algo: str

    def rate(self) -> float:
        path = REPO / self.file
        try:
            data = json.loads(path.read_text())
        except (OSError, ValueError) as err:
            raise ValueError(f"rate_from.file: cannot read {self.file}: {err}") from None
        runs = list(data["runs"].values()) if isinstance(data, dict) and "runs" in data else [data]
        rows = [r for run in runs for r in run.get("rows", []) if r.get("algo") == self.algo]
        if not rows:
            have = sorted({r.get("algo") for run in runs for r in run.get("rows", [])})
            raise ValueError(f"rate_from.algo: {self.algo!r} has no row in {self.file}; allowed: {', '.join(have)}")
        return float(rows[0]["steady_env_steps_per_s"])


class AlgorithmSpec(_Strict):
    enabled: bool = True
    # measured env steps/s of one training run (estimates); or rate_from: the measurement it is read from
    steps_per_second: float | None = Field(default=None, gt=0)
    rate_from: RateFrom | None = None
    overrides: list[str] = []  # train.py overrides of this algorithm's runs (reward, hyperparameters)
    # false: once a run is done, its checkpoint.pt and checkpoint-previous.pt are deleted (a DQN checkpoint holds
    # its replay buffer, ~2.4 GB); the models, logs and records stay, but the run cannot be continued further
    keep_checkpoints: bool = True
    gpus: float = Field(default=0, ge=0)  # GPUs of one training run (a Ray task's num_gpus, a SLURM job's GPUs)

    @model_validator(mode="after")
    def _rate(self) -> AlgorithmSpec:
        if (self.steps_per_second is None) == (self.rate_from is None):
            raise ValueError("give steps_per_second or rate_from (one of them)")
        if self.rate_from is not None:
            self.steps_per_second = self.rate_from.rate()
        return self


class TrainingSpec(_Strict):
    overrides: list[str] = []  # train.py overrides of every training run
    curriculum: bool = True  # one run through all `levels` per algorithm and seed
    direct: bool = True  # one run per level per algorithm and seed
    algorithms: list[str] | None = None  # the algorithms of the curriculum and direct runs (null: every enabled one)
    direct_levels: list[str] | None = None  # the levels of the direct runs (null: every level of `levels`)
    # env steps of the direct run on the k-th level of `levels` (k from 0): `stage` gives every one S; `matched`
    # gives (k + 1) * S, what the curriculum had seen by the end of that stage (curriculum vs direct at equal steps)
    direct_steps: Literal["stage", "matched"] = "stage"

    @field_validator("direct_levels")
    @classmethod
    def _direct_levels(cls, v: list[str] | None) -> list[str] | None:
        return None if v is None else _check_levels(v, evaaa.LEVELS, "a training level")


class MatchedSpec(_Strict):
    """Every algorithm on one level for the same CPU minutes (``max_cpu_minutes``), whatever env steps that buys."""

    level: str
    cpu_minutes: float = Field(gt=0)
    algorithms: list[str] | None = None  # null: every enabled algorithm
    seeds: list[int] | None = None  # null: the protocol's seeds
    overrides: dict[str, list[str]] = {}  # per algorithm: train.py overrides of its matched runs (evaluation rate)

    @field_validator("level")
    @classmethod
    def _level(cls, v: str) -> str:
        return _check_levels([v], [*evaaa.LEVELS, *evaaa.TESTBEDS], "a level or testbed")[0]


class AblationSpec(_Strict):
    enabled: bool = True
    algorithm: str
    level: str
    modalities: list[str]  # `all` is the direct run of `algorithm` on `level` (trained once)
    seeds: list[int] | None = None  # null: the protocol's seeds

    @field_validator("level")
    @classmethod
    def _level(cls, v: str) -> str:
        return _check_levels([v], evaaa.LEVELS, "a training level")[0]

    @field_validator("modalities")
    @classmethod
    def _modalities(cls, v: list[str]) -> list[str]:
        return _check_levels(v, MODALITIES, "a modality option (conf/modality)")


def _any_levels(v: list[str]) -> list[str]:
    return _check_levels(v, [*LEVEL_GROUPS, *evaaa.LEVELS, *evaaa.TESTBEDS], "a level, testbed or group")


class EvalPart(_Strict):
    levels: list[str] = ["testbeds"]
    episodes: int = Field(ge=1)
    num_envs: int = Field(default=4, ge=1)

    _levels = field_validator("levels")(_any_levels)


class OwnLevelPart(_Strict):
    episodes: int = Field(ge=1)
    num_envs: int = Field(default=4, ge=1)


class EvaluationSpec(_Strict):
    seed: int = 0
    epsilon: float = Field(default=0.05, ge=0, le=1)
    sample: bool = False
    # several acting modes: every model is evaluated in each (its folders get a `-<mode>` suffix; an algorithm with no
    # action distribution, DQN, only in `mode`), and the report compares them in the first; null: as `sample` says
    modes: list[Literal["mode", "sample"]] | None = Field(default=None, min_length=1)
    worlds: Literal["test", "validation"] = "test"  # the evaluations' worlds (evaaa/worlds.py): published: test
    testbeds: EvalPart | None = None  # every evaluated model on these levels (null: none)
    own_level: OwnLevelPart | None = None  # every evaluated model on the level it was trained up to (null: none)
    steps_per_second: float = Field(gt=0, description="measured world steps/s of evaluate.py (estimates)")


class ReferenceSpec(_Strict):
    policies: list[Literal["oracle", "random", "still"]] = ["oracle", "random", "still"]
    levels: list[str] = ["all"]
    # a policy's own levels where they differ from `levels` (the oracle survives every training level to its step
    # limit: hours of CPU for a number known in advance)
    levels_of: dict[Literal["oracle", "random", "still"], list[str]] = {}
    episodes: int = Field(default=20, ge=1)
    num_envs: int = Field(default=10, ge=1)
    steps_per_second: float = Field(gt=0)

    _levels = field_validator("levels")(_any_levels)

    @field_validator("levels_of")
    @classmethod
    def _levels_of(cls, v: dict[str, list[str]]) -> dict[str, list[str]]:
        return {k: _any_levels(lv) for k, lv in v.items()}


class ReportSpec(_Strict):
    out: str | None = None  # relative paths: to the repository root; null: <root>/report
    survival: Literal["eval", "train"] = "eval"
    title: str | None = None


class Protocol(_Strict):
    name: str
    description: str = ""
    stage_steps: int = Field(gt=0)  # S: env steps of every curriculum stage and every direct run
    seeds: list[int] = Field(min_length=1)
    levels: list[str] | None = None  # curriculum stages and direct levels (null: every level of evaaa.LEVELS)
    threads: int = Field(default=1, ge=1)  # torch threads and EVAAA_THREADS of every training and evaluation
    budget_cpu_hours: float | None = Field(default=None, gt=0)  # plan=true says when the estimate exceeds it
    algorithms: dict[str, AlgorithmSpec]
    training: TrainingSpec = TrainingSpec()
    ablations: AblationSpec | None = None
    evaluation: EvaluationSpec
    references: ReferenceSpec | None = None
    matched: MatchedSpec | None = None  # the compute-matched comparison on one level
    # the order of the parts' cells, and so of the scheduler's work: the first ones answer something on their own
    order: list[Literal["references", "matched", "ablations", "curriculum", "direct"]] = [
        "references",
        "curriculum",
        "direct",
        "ablations",
        "matched",
    ]
    report: ReportSpec
    # where the runs, evaluations, logs and done-markers go (reproduce.py's root= overrides it); relative paths: to
    # the repository root. A folder inside the repository can be committed (its .gitignore keeps the checkpoints
    # and logs out): a cell whose outputs are committed is done on any clone, so a protocol longer than one
    # session continues on another machine
    root: str | None = None

    @field_validator("levels")
    @classmethod
    def _levels(cls, v: list[str] | None) -> list[str] | None:
        return None if v is None else _check_levels(v, evaaa.LEVELS, "a training level")

    @field_validator("algorithms")
    @classmethod
    def _algorithms(cls, v: dict[str, AlgorithmSpec]) -> dict[str, AlgorithmSpec]:
        _check_levels(list(v), algorithm_names(), "an algorithm")
        if not any(a.enabled for a in v.values()):
            raise ValueError("no algorithm is enabled")
        return v

    @model_validator(mode="after")
    def _part_algorithms(self) -> Protocol:
        enabled = [n for n, a in self.algorithms.items() if a.enabled]
        for where, names in (
            ("training.algorithms", self.training.algorithms),
            ("matched.algorithms", self.matched.algorithms if self.matched else None),
            ("matched.overrides", list(self.matched.overrides) if self.matched else None),
        ):
            bad = [n for n in names or () if n not in enabled]
            if bad:
                raise ValueError(
                    f"{where}: {bad[0]!r} is not an enabled algorithm of this protocol; allowed: {', '.join(enabled)}"
                )
        if sorted(self.order) != sorted(set(self.order)) or len(set(self.order)) != 5:
            raise ValueError("order: name each of references, matched, ablations, curriculum, direct once")
        return self

    @model_validator(mode="after")
    def _ablation_algorithm(self) -> Protocol:
        ab = self.ablations
        if ab is not None and ab.enabled:
            enabled = [n for n, a in self.algorithms.items() if a.enabled]
            if ab.algorithm not in enabled:
                raise ValueError(
                    f"ablations.algorithm: {ab.algorithm!r} is not an enabled algorithm of this "
                    f"protocol; allowed: {', '.join(enabled)}"
                )
        return self

    @property
    def stage_levels(self) -> list[str]:
        return list(self.levels or evaaa.LEVELS)


# integer arithmetic for settings derived from stage_steps in a protocol file: ${idiv:${stage_steps},2}
OmegaConf.register_new_resolver("idiv", lambda a, b: int(a) // int(b), replace=True)
OmegaConf.register_new_resolver("sub", lambda a, b: int(a) - int(b), replace=True)


def _field_path(loc: Sequence[Any]) -> str:
    return ".".join(str(p) for p in loc if p not in ("function-after", "function-before"))


def _fields_at(loc: Sequence[Any]) -> list[str] | None:
    """The fields allowed where ``loc`` points (for an unknown field's message)."""
    model: Any = Protocol
    for part in loc[:-1]:
        info = getattr(model, "model_fields", {}).get(part) if isinstance(part, str) else None
        if info is None:
            if model is Protocol and loc[0] == "algorithms":
                model = AlgorithmSpec
                continue
            return None
        tp = info.annotation
        args = [a for a in getattr(tp, "__args__", (tp,)) if isinstance(a, type) and issubclass(a, BaseModel)]
        model = args[0] if args else tp
    return list(getattr(model, "model_fields", {})) or None


def load_protocol(spec: str | Path) -> Protocol:
    """The protocol named ``spec`` (``conf/protocol/<spec>.yaml``) or in the YAML file ``spec``; interpolations
    (``${stage_steps}``, ``${idiv:${stage_steps},16}``) resolved.  Raises :class:`ProtocolError`."""
    path = Path(spec)
    if not path.suffix:
        path = PROTOCOL_DIR / f"{spec}.yaml"
    if not path.is_file():
        known = ", ".join(sorted(p.stem for p in PROTOCOL_DIR.glob("*.yaml")))
        raise ProtocolError(f"protocol={spec}: no such protocol; allowed: {known}, or a path to a .yaml file")
    try:
        raw = OmegaConf.to_container(OmegaConf.load(path), resolve=True)
    except (yaml.YAMLError, OmegaConfBaseException) as err:
        mark = getattr(err, "problem_mark", None)
        where = f" (line {mark.line + 1})" if mark is not None else ""
        raise ProtocolError(f"{path}: not a valid protocol file{where}: {' '.join(str(err).split())}") from None
    if not isinstance(raw, dict):
        raise ProtocolError(f"{path}: a protocol is a mapping of fields ({', '.join(Protocol.model_fields)})")
    try:
        return Protocol.model_validate(raw)
    except ValidationError as err:
        first = err.errors()[0]
        where = _field_path(first["loc"]) or "(top level)"
        msg = first["msg"].removeprefix("Value error, ")
        if first["type"] == "extra_forbidden":
            allowed = _fields_at(first["loc"])
            msg = "unknown field" + (f"; allowed: {', '.join(allowed)}" if allowed else "")
        elif first["type"] == "missing":
            msg = "required field missing"
        raise ProtocolError(f"{path}: field {where}: {msg}") from None


# ------------------------------------------------------------------------------------------------ cells
@dataclass
class Command:
    """One subprocess of a cell; ``out``: the evaluation folder it writes (None for training and the report)."""

    argv: list[str]
    out: Path | None = None

    def text(self, threads: int) -> str:
        return f"EVAAA_THREADS={threads} python " + " ".join(shlex.quote(a) for a in self.argv)


@dataclass
class Cell:
    """One experiment of the protocol: its name, what kind, its commands, the files it needs and makes."""

    name: str
    kind: Literal["train", "eval", "ref", "report"]
    commands: list[Command]
    minutes: float  # estimated CPU-minutes
    group: str  # the budget line it counts in (e.g. "ppo curriculum", "evaluation")
    run_dir: Path | None = None  # training: the run directory
    final_model: Path | None = None  # training: the last stage's model
    needs: list[Path] = field(default_factory=list)  # files that must exist before it starts (models)
    needs_cells: list[str] = field(default_factory=list)  # cells whose outputs those are
    keep_checkpoints: bool = True  # training: false deletes the run's checkpoints once it is done
    report_out: Path | None = None  # the report: its folder


def _safe(name: str) -> str:
    return name.replace("/", os.sep)


@cache
def max_steps(level: str) -> int:
    """A level's episode cap (decisions), for the estimates."""
    return int(evaaa.load_level(level).episode.max_steps)


def expand_levels(names: Sequence[str]) -> list[str]:
    out: list[str] = []
    for n in names:
        out += [x for x in LEVEL_GROUPS.get(n, (n,)) if x not in out]
    return out


class Layout:
    """Where a protocol's files go under ``root``."""

    def __init__(self, root: Path):
        self.root = root.resolve()
        self.runs = self.root / "runs"
        self.evals = self.root / "evals"
        self.logs = self.root / "logs"
        self.done = self.root / "done"

    def marker(self, cell: str) -> Path:
        return self.done / f"{_safe(cell)}.done"

    def log(self, cell: str) -> Path:
        return self.logs / f"{_safe(cell)}.log"

    def clock(self, cell: str) -> Path:
        """The wall and CPU seconds the cell's commands have run so far, over every session (JSON)."""
        return self.done / f"{_safe(cell)}.seconds"

    def took(self, cell: str, key: str = "cpu_seconds") -> float | None:
        """CPU seconds a done cell took (its marker), or None where it was not timed; ``key="seconds"``: the wall
        seconds of its commands."""
        marker = self.marker(cell)
        try:
            seconds = json.loads(marker.read_text()).get(key) if marker.exists() else None
        except (ValueError, AttributeError):
            return None
        return float(seconds) if isinstance(seconds, (int, float)) else None

    def wall(self, cell: str) -> float | None:
        """Wall seconds a done cell's commands ran (its marker), or None where it was not timed."""
        return self.took(cell, "seconds")


def read_clock(path: Path) -> dict[str, float]:
    """A cell's running account (:meth:`Layout.clock`); zeros where there is none or it cannot be read."""
    try:
        account = json.loads(path.read_text())
        return {k: float(account[k]) for k in ("seconds", "cpu_seconds")}
    except (OSError, ValueError, KeyError, TypeError):
        return {"seconds": 0.0, "cpu_seconds": 0.0}


def arg(path: Path) -> str:
    """``path`` as a command line names it: relative to the repository root (where every cell runs) when it lies
    inside it, so that the files a protocol writes there (evaluations name their checkpoints) hold on any clone."""
    try:
        return str(Path(path).resolve().relative_to(REPO.resolve()))
    except ValueError:
        return str(path)


#: what keep_out_of_git writes: a protocol's committed results are its settings, CSV logs, evaluation episodes and
#: done-markers, never its models, checkpoints, logs of text or per-evaluation figures (each report draws its own);
#: ``runs/``, which the repository's own .gitignore leaves out everywhere, is taken back in
GITIGNORE = """\
# written by scripts/reproduce.py: commit the results, not the models, checkpoints, text logs or figures
!/runs/
*.pt
*.log
/logs/
/evals/**/*.png
.reproduce.lock
*.seconds
*.partial-*/
*.old-*/
.*.replaced-*/
"""


def keep_out_of_git(lay: Layout) -> Path | None:
    """Inside the repository, give ``lay.root`` its ``.gitignore`` (:data:`GITIGNORE`; one already there is kept
    as it is); returns the file written, or None."""
    try:
        lay.root.resolve().relative_to(REPO.resolve())
    except ValueError:
        return None
    path = lay.root / ".gitignore"
    if path.exists():
        return None
    lay.root.mkdir(parents=True, exist_ok=True)
    path.write_text(GITIGNORE)
    return path


def build_cells(p: Protocol, root: Path, report_out: Path | None = None) -> list[Cell]:
    """Every cell of ``p`` with its files under ``root``, in the order the scheduler prefers: the parts in
    ``p.order`` (within a part, per algorithm each training run followed by the evaluations of its models; the
    matched comparison seed by seed), then the report."""
    lay = Layout(root)
    S, levels, th = p.stage_steps, p.stage_levels, p.threads
    ev = p.evaluation
    parts: dict[str, list[Cell]] = {part: [] for part in p.order}
    eval_outs: list[Path] = []
    modes = eval_modes(ev)

    def eval_cell(name: str, model: Path, own: str, train_cell: str, sps: float, algo: str) -> Cell:
        cmds, seconds = [], 0.0
        # an algorithm without an action distribution acts the same when asked to sample: evaluated once
        own_modes = [m for m in modes if m == "mode" or samples_actions(algo)] or modes
        for mode in own_modes:
            suffix = "" if len(modes) == 1 else f"-{mode}"
            common = [
                f"seed={ev.seed}",
                f"epsilon={ev.epsilon:g}",
                f"sample={str(mode == 'sample').lower()}",
                f"threads={th}",
                f"policy=[{arg(model)}]",
            ]
            if ev.worlds != "test":
                common.append(f"worlds={ev.worlds}")
            if ev.testbeds is not None:
                out = lay.evals / _safe(name.removeprefix("eval/")) / f"testbeds{suffix}"
                tb = expand_levels(ev.testbeds.levels)
                cmds.append(
                    Command(
                        [
                            "scripts/evaluate.py",
                            *common,
                            f"levels=[{','.join(ev.testbeds.levels)}]",
                            f"episodes={ev.testbeds.episodes}",
                            f"num_envs={ev.testbeds.num_envs}",
                            f"out={arg(out)}",
                        ],
                        out,
                    )
                )
                seconds += STARTUP_SECONDS + ev.testbeds.episodes * sum(max_steps(t) for t in tb) / sps
            if ev.own_level is not None:
                out = lay.evals / _safe(name.removeprefix("eval/")) / f"level{suffix}"
                cmds.append(
                    Command(
                        [
                            "scripts/evaluate.py",
                            *common,
                            f"levels=[{own}]",
                            f"episodes={ev.own_level.episodes}",
                            f"num_envs={ev.own_level.num_envs}",
                            f"out={arg(out)}",
                        ],
                        out,
                    )
                )
                seconds += STARTUP_SECONDS + ev.own_level.episodes * max_steps(own) / sps
        eval_outs.extend(c.out for c in cmds if c.out is not None)
        return Cell(name, "eval", cmds, seconds / 60, f"{algo} evaluation", needs=[model], needs_cells=[train_cell])

    if p.references is not None:
        ref = p.references
        for policy in ref.policies:
            names = ref.levels_of.get(policy, ref.levels)
            ref_levels = expand_levels(names)
            out = lay.evals / "ref" / policy
            cmd = Command(
                [
                    "scripts/evaluate.py",
                    f"policy=[{policy}]",
                    f"levels=[{','.join(names)}]",
                    f"episodes={ref.episodes}",
                    f"num_envs={ref.num_envs}",
                    f"seed={ev.seed}",
                    f"threads={th}",
                    *([f"worlds={ev.worlds}"] if ev.worlds != "test" else []),
                    f"out={arg(out)}",
                ],
                out,
            )
            seconds = STARTUP_SECONDS + ref.episodes * sum(max_steps(lv) for lv in ref_levels) / ref.steps_per_second
            parts["references"].append(Cell(f"ref/{policy}", "ref", [cmd], seconds / 60, "references"))
            eval_outs.append(out)

    def train_cell(
        part: str,
        algo: str,
        spec: AlgorithmSpec,
        setup: str,
        seed: int,
        level_args: list[str],
        stages: list[str],
        group: str,
        extra: Sequence[str] = (),
        steps: int | None = None,
        minutes: float | None = None,
    ) -> None:
        name = f"train/{algo}/{setup}/seed{seed}"
        run_name = f"{algo}/{setup}/seed{seed}"
        run_dir = lay.runs / _safe(run_name)
        argv = [
            "scripts/train.py",
            f"algo={algo}",
            *level_args,
            f"seed={seed}",
            f"threads={th}",
            *p.training.overrides,
            *spec.overrides,
            *extra,
            f"run.root={arg(lay.runs)}",
            f"run.name={run_name}",
        ]
        if minutes is None:
            minutes = (STARTUP_SECONDS + (steps or S * len(stages)) / spec.steps_per_second) / 60
        final = run_dir / f"model-{len(stages) - 1}-{stages[-1]}.pt"
        cells = parts[part]
        cells.append(
            Cell(
                name,
                "train",
                [Command(argv)],
                minutes,
                f"{algo} {group}",
                run_dir=run_dir,
                final_model=final,
                keep_checkpoints=spec.keep_checkpoints,
            )
        )
        if len(stages) > 1:
            for i, lv in enumerate(stages):
                cells.append(
                    eval_cell(
                        f"eval/{algo}/{setup}/seed{seed}/stage{i}-{lv}",
                        run_dir / f"model-{i}-{lv}.pt",
                        lv,
                        name,
                        ev.steps_per_second,
                        algo,
                    )
                )
        else:
            cells.append(
                eval_cell(f"eval/{algo}/{setup}/seed{seed}", final, stages[0], name, ev.steps_per_second, algo)
            )

    enabled = [a for a, spec in p.algorithms.items() if spec.enabled]
    trained = p.training.algorithms if p.training.algorithms is not None else enabled
    ab = p.ablations if p.ablations is not None and p.ablations.enabled else None
    for algo in enabled:
        spec = p.algorithms[algo]
        if algo in trained and p.training.curriculum:
            for seed in p.seeds:
                train_cell(
                    "curriculum",
                    algo,
                    spec,
                    "curriculum",
                    seed,
                    ["level=curriculum", f"level.stages=[{','.join(levels)}]", f"level.stage_steps={S}"],
                    levels,
                    "curriculum",
                )
        direct_levels = list(p.training.direct_levels or levels) if p.training.direct and algo in trained else []
        shares_all = ab is not None and ab.algorithm == algo and "all" in ab.modalities
        for lv in dict.fromkeys([*direct_levels, *([ab.level] if shares_all else [])]):
            # the ablation's `all` condition is the direct run on its level, trained once
            ablation_only = lv not in direct_levels
            seeds = (ab.seeds or p.seeds) if ablation_only else p.seeds
            if shares_all and lv == ab.level:
                seeds = list(dict.fromkeys([*seeds, *(ab.seeds or p.seeds)]))
            k = levels.index(lv) if lv in levels else 0
            steps = S * (k + 1) if p.training.direct_steps == "matched" and not ablation_only else S
            part = "ablations" if ablation_only or (shares_all and lv == ab.level and k == 0) else "direct"
            for seed in seeds:
                train_cell(
                    part,
                    algo,
                    spec,
                    f"direct-{lv}",
                    seed,
                    [f"level={lv}", f"total_steps={steps}"],
                    [lv],
                    "direct",
                    steps=steps,
                )
        if ab is not None and ab.algorithm == algo:
            for mod in ab.modalities:
                if mod == "all":
                    continue
                for seed in ab.seeds or p.seeds:
                    train_cell(
                        "ablations",
                        algo,
                        spec,
                        f"ablation-{mod}",
                        seed,
                        [f"level={ab.level}", f"total_steps={S}"],
                        [ab.level],
                        "ablations",
                        extra=[f"modality={mod}"],
                    )
    if p.matched is not None:
        m = p.matched
        for seed in m.seeds or p.seeds:
            for algo in m.algorithms or enabled:
                # a step budget no run reaches: the CPU minutes end every run
                train_cell(
                    "matched",
                    algo,
                    p.algorithms[algo],
                    f"matched-{m.level}",
                    seed,
                    [f"level={m.level}", f"total_steps={MATCHED_STEPS}", f"max_cpu_minutes={m.cpu_minutes:g}"],
                    [m.level],
                    "matched",
                    extra=m.overrides.get(algo, []),
                    minutes=m.cpu_minutes + STARTUP_SECONDS / 60,
                )
    cells = [c for part in p.order for c in parts[part]]

    out = (
        Path(report_out)
        if report_out is not None
        else lay.root / "report"
        if p.report.out is None
        else REPO / p.report.out
    )
    out = out.resolve()
    title = p.report.title or default_title(p)
    argv = [
        "scripts/report.py",
        f"runs=[{arg(lay.runs)}]",
        "evals=[" + ",".join(map(arg, eval_outs)) + "]",
        f"out={arg(out)}",
        f"survival={p.report.survival}",
        f"title={title}",
    ]
    if any(c.kind == "eval" for c in cells) and len(modes) == 1:
        # several modes: the report shows each, labelled, and its claims take the mode every agent has
        argv.append(f"acting={acting(ev)}")
    cells.append(
        Cell(
            "report",
            "report",
            [Command(argv, None)],
            1.0,
            "report",
            needs_cells=[c.name for c in cells],
            report_out=out,
        )
    )
    return cells


#: the env-step budget of a compute-matched run: more than any run reaches in its CPU minutes
MATCHED_STEPS = 1_000_000_000


def eval_modes(ev: EvaluationSpec) -> list[str]:
    """The acting modes every model is evaluated in, the report's first."""
    return list(ev.modes) if ev.modes is not None else ["sample" if ev.sample else "mode"]


def acting(ev: EvaluationSpec) -> str:
    """How evaluate.py names the acting mode of the protocol's checkpoint evaluations the report compares (its
    ``acting`` column; the first of several modes)."""
    return eval_modes(ev)[0] + (f"+epsilon={ev.epsilon:g}" if ev.epsilon else "")


def default_title(p: Protocol) -> str:
    algos = ", ".join(n for n, a in p.algorithms.items() if a.enabled)
    return (
        f"evaaa: the paper's protocol at CPU scale ({p.name}: {algos}; {p.stage_steps:,} env steps per "
        f"stage; seeds {', '.join(map(str, p.seeds))}; checkpoints act {acting_text(p.evaluation)})"
    )


def acting_text(ev: EvaluationSpec) -> str:
    """How the protocol's checkpoints act, in words that hold for every algorithm (DQN has no distribution)."""
    eps = f", epsilon {ev.epsilon:g}" if ev.epsilon else ""
    modes = eval_modes(ev)
    if modes == ["mode"]:
        return f"by their most likely action{eps}"
    if modes == ["sample"]:
        return f"by sampling (DQN: its greedy action){eps}"
    return f"by their most likely action, and by sampling where they have a distribution{eps}"


# ------------------------------------------------------------------------------------------------ status
def _newest(paths: Sequence[Path]) -> float:
    return max((q.stat().st_mtime for q in paths if q.exists()), default=0.0)


def outputs(cell: Cell, lay: Layout) -> list[Path]:
    """The files whose presence makes ``cell`` done."""
    if cell.kind == "train":
        return [cell.final_model, lay.marker(cell.name)]  # type: ignore[list-item]
    if cell.kind in ("eval", "ref"):
        return [c.out / "episodes.csv" for c in cell.commands if c.out is not None]
    return [cell.report_out / "report.md", lay.marker(cell.name)]  # type: ignore[operator]


def status(cell: Cell, lay: Layout, cells: Sequence[Cell] = ()) -> Literal["done", "partial", "todo"]:
    """done: every output complete; partial: started (a run directory, an ``out`` folder) but not complete; todo."""
    outs = outputs(cell, lay)
    lost = cell.kind == "train" and not cell.final_model.exists()  # type: ignore[union-attr]
    if lost and lay.marker(cell.name).exists():
        # finished, and its models are gone (a clone of committed results holds no checkpoints): done while every
        # evaluation of it is; otherwise it is trained again for the evaluations still to make
        dependents = [c for c in cells if c.kind == "eval" and cell.name in c.needs_cells]
        return "done" if all(status(c, lay) == "done" for c in dependents) else "partial"
    if all(o.exists() for o in outs):
        if cell.kind != "report":
            return "done"
        others = [c for c in cells if c.kind != "report"]
        if all(status(c, lay) == "done" for c in others) and lay.marker(cell.name).stat().st_mtime >= _newest(
            [o for c in others for o in outputs(c, lay)]
        ):
            return "done"
        return "partial"  # written before some cell was (re)done
    if cell.kind == "train":
        return (
            "partial" if cell.run_dir is not None and cell.run_dir.is_dir() and any(cell.run_dir.iterdir()) else "todo"
        )
    if cell.kind in ("eval", "ref"):
        return "partial" if any(c.out is not None and c.out.exists() for c in cell.commands) else "todo"
    return "partial" if any(o.exists() for o in outs) else "todo"


def command_now(cell: Cell, lay: Layout, redo: bool = False) -> list[Command]:
    """The commands that bring ``cell`` to done from where it stands: a started training run continues
    (``resume=true``; with ``redo``: ``start_over=true``); evaluations whose ``episodes.csv`` exists are skipped (all
    run again with ``redo``)."""
    if cell.kind == "train":
        (cmd,) = cell.commands
        if lay.marker(cell.name).exists() and not cell.final_model.exists():  # type: ignore[union-attr]
            # a finished run whose models are gone, with evaluations still to make: trained again from zero (the
            # old run directory is moved aside by train.py, never deleted)
            return [Command([*cmd.argv, "start_over=true"])]
        started = cell.run_dir is not None and cell.run_dir.is_dir() and any(cell.run_dir.iterdir())
        pruned = not any((cell.run_dir / n).exists() for n in CHECKPOINTS)  # type: ignore[operator]
        if started and not redo and cell.final_model.exists() and pruned:  # type: ignore[union-attr]
            return []  # finished, checkpoints deleted: only the done-marker is missing
        if started:
            # without a checkpoint (never reached, or a clone of committed files) there is nothing to resume
            return [Command([*cmd.argv, "start_over=true" if redo or pruned else "resume=true"])]
        return [cmd]
    if cell.kind in ("eval", "ref"):
        return [c for c in cell.commands if redo or not (c.out / "episodes.csv").exists()]  # type: ignore[operator]
    return list(cell.commands)


# ------------------------------------------------------------------------------------------------ plan
def budget(cells: Sequence[Cell]) -> dict[str, float]:
    """Estimated CPU-minutes per budget line, in order."""
    lines: dict[str, float] = {}
    for c in cells:
        lines[c.group] = lines.get(c.group, 0.0) + c.minutes
    return lines


def plan_text(p: Protocol, cells: Sequence[Cell], lay: Layout, threads: int) -> str:
    """The plan: every cell with its status and estimate, the budget split, the totals, each cell's command."""
    states = {c.name: status(c, lay, cells) for c in cells}
    width = max(len(c.name) for c in cells)
    lines = [
        f"protocol {p.name}: {len(cells)} cells under {lay.root}; S = {p.stage_steps:,} env steps per stage "
        f"(curriculum stage and direct run), seeds {p.seeds}; checkpoints act {acting_text(p.evaluation)}",
        "",
        f"{'cell':<{width}}  {'status':<7}  {'CPU-min':>8}  {'took':>8}",
    ]
    took = {c.name: lay.took(c.name) if states[c.name] == "done" else None for c in cells}
    for c in cells:
        t = took[c.name]
        lines.append(
            f"{c.name:<{width}}  {states[c.name]:<7}  {c.minutes:8.1f}  "
            f"{'' if t is None else f'{t / 60:8.1f}'}".rstrip()
        )
    total = sum(c.minutes for c in cells)
    left = sum(c.minutes for c in cells if states[c.name] != "done")
    counts = {s: sum(1 for v in states.values() if v == s) for s in ("done", "partial", "todo")}
    lines += [
        "",
        f"estimated CPU-hours (threads={p.threads} per cell, hours of one cell; rates in the protocol file; evaluation episodes "
        "taken to their step limit):",
    ]
    split = budget(cells)
    parts = (
        "curriculum",
        "direct",
        "ablations",
        *(("matched",) if any(g.endswith(" matched") for g in split) else ()),
        "evaluation",
    )
    algos = list(dict.fromkeys(g.split(" ")[0] for g in split if " " in g))
    lines.append(f"  {'':<12}" + "".join(f"{x:>12}" for x in (*parts, "all")))
    for a in algos:
        row = [split.get(f"{a} {x}", 0.0) / 60 for x in parts]
        lines.append(f"  {a:<12}" + "".join(f"{v:12.2f}" for v in (*row, sum(row))))
    for g in (g for g in split if " " not in g):
        lines.append(f"  {g:<12}" + " " * 12 * len(parts) + f"{split[g] / 60:12.2f}")
    lines.append(
        f"  {'total':<12}" + " " * 12 * len(parts) + f"{total / 60:12.2f}  ({len(cells)} cells: "
        f"{counts['done']} done, {counts['partial']} partial, {counts['todo']} todo; {left / 60:.2f} h left)"
    )
    timed = [c for c in cells if took[c.name] is not None]
    if timed:
        # the CPU time of each cell's processes, summed over the sessions that ran them
        spent = sum(took[c.name] for c in timed) / 3600  # type: ignore[misc]
        planned = sum(c.minutes for c in timed) / 60
        lines.append(
            f"  measured: the {len(timed)} timed done cells took {spent:.2f} CPU-hours, against "
            f"{planned:.2f} estimated for them"
        )
    if p.budget_cpu_hours is not None and total / 60 > p.budget_cpu_hours:
        lines.append(f"  WARNING: over the protocol's budget of {p.budget_cpu_hours:g} CPU-hours")
    lines += gpu_plan(p, cells)
    lines += ["", "commands (run from the repository root; a started training run gets resume=true):"]
    for c in cells:
        for cmd in command_now(c, lay) if states[c.name] != "done" else c.commands:
            lines.append(f"[{c.name}] {cmd.text(threads)}")
    return "\n".join(lines)


#: the cluster sizes plan=true gives the wall time for
GPU_COUNTS = (1, 8, 64)


def wall_hours(hours: Sequence[float], gpus: int) -> float:
    """The wall hours of runs of ``hours`` on ``gpus`` GPUs, one run per GPU, longest first onto the GPU free
    soonest (an estimate: the engine, not this, places the runs)."""
    free = [0.0] * gpus
    for h in sorted(hours, reverse=True):
        free[free.index(min(free))] += h
    return max(free, default=0.0)


def gpu_plan(p: Protocol, cells: Sequence[Cell]) -> list[str]:
    """The plan in GPU-hours per algorithm (training runs on ``gpus`` > 0 GPUs, at the algorithm's measured rate)
    and the wall time of the training runs on :data:`GPU_COUNTS` GPUs; empty for a protocol without GPUs."""
    train = [c for c in cells if c.kind == "train" and cell_resources(p, c)[1] > 0]
    if not train:
        return []
    hours = {c.name: c.minutes / 60 * cell_resources(p, c)[1] for c in train}
    lines = [
        "",
        "estimated GPU-hours (training runs at each algorithm's measured env steps/s, rate_from; "
        "evaluations and references run on the CPUs):",
        f"  {'':<12}{'runs':>6}{'steps/s':>10}{'GPU-hours':>12}{'GPU-days':>10}  rate",
    ]
    for algo, spec in p.algorithms.items():
        mine = [c for c in train if c.name.split("/")[1] == algo]
        if not mine:
            continue
        h = sum(hours[c.name] for c in mine)
        source = f"{spec.rate_from.file} ({spec.rate_from.algo})" if spec.rate_from else "steps_per_second"
        lines.append(f"  {algo:<12}{len(mine):>6}{spec.steps_per_second:>10.1f}{h:>12.1f}{h / 24:>10.1f}  {source}")
    total = sum(hours.values())
    longest = max(train, key=lambda c: hours[c.name])
    lines.append(f"  {'total':<12}{len(train):>6}{'':>10}{total:>12.1f}{total / 24:>10.1f}")
    lines.append(
        f"  wall time of the training runs (one GPU each; the longest run, {longest.name}, takes "
        f"{hours[longest.name]:.1f} h): "
        + "; ".join(
            f"{n} GPU{'s' if n > 1 else ''}: {wall_hours(list(hours.values()), n):.0f} h "
            f"({wall_hours(list(hours.values()), n) / 24:.1f} days)"
            for n in GPU_COUNTS
        )
    )
    return lines


def provenance(p: Protocol, cells: Sequence[Cell], lay: Layout, selects: str | None = None) -> list[str]:
    """The report's last section: the commands that re-run the protocol or one cell of it (``selects``: the
    reproduce.py arguments that name this protocol, root and report folder; default ``protocol=<name>``), and the CPU
    time its done cells took (their markers), per budget line, beside what the protocol file estimates for them."""
    states = {c.name: status(c, lay, cells) for c in cells}
    done = [c for c in cells if states[c.name] == "done" and c.kind != "report"]
    took = {c.name: lay.took(c.name) for c in done}
    timed = [c for c in done if took[c.name] is not None]
    selects = selects or f"protocol={p.name}"
    example = next((c.name for c in cells if c.kind == "train"), cells[0].name)
    lines = [
        "## How this report was made",
        "",
        f"The protocol `{p.name}`: S = {p.stage_steps:,} env steps per stage (curriculum "
        f"stage and direct run), seeds {', '.join(map(str, p.seeds))}, checkpoints act {acting_text(p.evaluation)}; "
        f"{len(cells)} cells, {len(done)} of them done (the report not counted) when this report was made. From "
        "the repository root:",
        "",
        "```bash",
        f"python scripts/reproduce.py {selects} plan=true   # every cell: status, command, CPU time",
        f"python scripts/reproduce.py {selects} jobs=2      # what is not done (killed: the same continues)",
        f'python scripts/reproduce.py {selects} "cells=[{example}]" redo=true   # one cell again',
        "```",
        "",
    ]
    if not timed:
        return lines + ["No done cell was timed.", ""]
    lines += [
        "CPU time each done cell's processes took (their own `rusage`, summed over the sessions that ran them; "
        "`threads=1`, one core each), per budget line, against the protocol file's estimate for the same cells:",
        "",
        "| budget line | timed cells | CPU-hours | estimated | wall hours of its commands |",
        "|---|---|---|---|---|",
    ]
    wall = {c.name: lay.wall(c.name) for c in timed}
    for group in dict.fromkeys(c.group for c in timed):
        part = [c for c in timed if c.group == group]
        lines.append(
            f"| {group} | {len(part)} | {sum(took[c.name] for c in part) / 3600:.2f} | "
            f"{sum(c.minutes for c in part) / 60:.2f} | {sum(wall[c.name] or 0.0 for c in part) / 3600:.2f} |"
        )
    spent = sum(took[c.name] for c in timed) / 3600  # type: ignore[misc]
    lines.append(
        f"| **all** | {len(timed)} | **{spent:.2f}** | {sum(c.minutes for c in timed) / 60:.2f} | "
        f"{sum(wall[c.name] or 0.0 for c in timed) / 3600:.2f} |"
    )
    untimed = [c for c in done if took[c.name] is None]
    if untimed:
        lines += [
            "",
            f"{len(untimed)} done cells were not timed (run before cells were): "
            f"{', '.join(c.name for c in untimed)}; the protocol file estimates them at "
            f"{sum(c.minutes for c in untimed) / 60:.2f} CPU-hours.",
        ]
    return lines + [""]


# ------------------------------------------------------------------------------------------------ running
def utc_stamp() -> str:
    return datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%SZ")


def _move_aside(out: Path, why: str) -> Path:
    """Rename an evaluation's folder to ``<out>.<why>-<UTC time>`` (kept, never deleted); returns the new path."""
    aside = out.with_name(f"{out.name}.{why}-{utc_stamp()}")
    out.rename(aside)
    return aside


def select(cells: Sequence[Cell], patterns: Sequence[str]) -> list[Cell]:
    """The cells named by ``patterns`` (names or shell patterns, ``eval/ppo/*``); an unmatched one is an error."""
    chosen: list[Cell] = []
    for pat in patterns:
        hits = [c for c in cells if fnmatch.fnmatchcase(c.name, pat)]
        if not hits:
            raise ProtocolError(f"cells: no cell named {pat!r} (plan=true lists them)")
        chosen += [c for c in hits if c not in chosen]
    return [c for c in cells if c in chosen]


#: how reproduce.py runs cells: a pool of subprocesses on this machine, Ray tasks, SLURM jobs through submitit
EXECUTORS = ("local", "ray", "slurm")
#: seconds a cell asked to stop (one SIGINT: a training writes its checkpoint) gets before it is killed
STOP_GRACE_SECONDS = 120.0


class CellFailed(RuntimeError):
    """A cell that did not finish (raised on the worker, or by the driver for a lost worker): ``rc`` its command's
    exit status (None: no status, e.g. lost with its worker); the driver tries it again ``retries`` times."""

    def __init__(self, message: str, rc: int | None = None):
        super().__init__(message, rc)
        self.message, self.rc = message, rc

    def __str__(self) -> str:
        return self.message


@dataclass
class CellTask:
    """Everything a worker needs to bring one cell to done, picklable (a Ray task's or a submitit job's argument).
    Every decision is taken on the worker from the files (:func:`status`, :func:`command_now`), so that a task run
    again — Ray retrying it after its worker was lost, the next reproduce.py — continues what the lost one began
    and never does a done cell again."""

    p: Protocol
    cells: list[Cell]  # all of the protocol's: a report's status and provenance need them
    name: str
    root: Path
    redo: bool = False
    selects: str | None = None
    python: str = sys.executable
    deadline: float | None = None  # time.time() after which the task starts nothing (max_minutes)

    @property
    def cell(self) -> Cell:
        return next(c for c in self.cells if c.name == self.name)


@dataclass
class CellResult:
    name: str
    ran: bool  # False: done already, or past the deadline
    late: bool = False  # past max_minutes' deadline: not started
    outdated: list[str] = field(default_factory=list)  # evaluations moved aside: to be made again
    messages: list[str] = field(default_factory=list)


#: set by the local executor's driver on Ctrl-C: its worker threads pass one SIGINT to their cell (a Ray task or a
#: submitit job gets a KeyboardInterrupt or SIGTERM in its own process instead)
STOP = threading.Event()


def _die_with_parent() -> None:
    """In the child, before exec: be killed when the worker that started it dies (Linux ``PR_SET_PDEATHSIG``), so
    that a cell lost with its Ray worker or SLURM job never runs on beside the retry that resumes it."""
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # 1: PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def run_cell(task: CellTask) -> CellResult:
    """Bring ``task``'s cell to done on this worker: its commands as subprocesses (one session each, a log per cell,
    CPU and wall time added to its account), then its done-marker. Raises :class:`CellFailed` on a non-zero exit;
    on KeyboardInterrupt or SIGTERM passes exactly one SIGINT to the running command (a second one would stop a
    training without its checkpoint), waits for it, and raises KeyboardInterrupt."""
    if threading.current_thread() is not threading.main_thread():
        return _run_cell(task)
    # scancel and a Ray worker's shutdown send SIGTERM: stopped like a Ctrl-C, the time so far kept
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        return _run_cell(task)
    finally:
        signal.signal(signal.SIGTERM, previous)


def _interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


def _run_cell(task: CellTask) -> CellResult:
    cell, lay = task.cell, Layout(task.root)
    result = CellResult(cell.name, ran=False)
    if not task.redo and status(cell, lay, task.cells) == "done":
        return result  # done by an earlier try whose report was lost with its worker: never done twice
    if task.deadline is not None and time.time() > task.deadline:
        result.late = True
        return result
    commands = command_now(cell, lay, task.redo)
    if task.redo:
        lay.marker(cell.name).unlink(missing_ok=True)  # not done until it is again
    if not commands:
        _finish(task, result)
        return result
    if task.redo or "start_over=true" in commands[0].argv or status(cell, lay) == "todo":
        lay.clock(cell.name).unlink(missing_ok=True)  # nothing of it is left: timed anew
    if "start_over=true" in commands[0].argv:
        # a training from zero makes new models: what was evaluated from the old ones no longer describes them
        # (training is not reproducible to the bit), so it is evaluated again
        result.outdated = _outdated_evaluations(task, result)
    result.ran = True
    env = {**os.environ, "EVAAA_THREADS": str(task.p.threads), "PYTHONUNBUFFERED": "1"}
    for cmd in commands:
        if cmd.out is not None and cmd.out.exists() and not (cmd.out / "episodes.csv").exists():
            aside = _move_aside(cmd.out, "partial")  # an interrupted evaluation: kept, out of the way
            result.messages.append(f"{cell.name}: moved the unfinished evaluation {cmd.out} to {aside}")
        if cmd.out is not None and task.redo and (cmd.out / "episodes.csv").exists():
            aside = _move_aside(cmd.out, "old")
            result.messages.append(f"{cell.name}: redo: moved the earlier evaluation {cmd.out} to {aside}")
        if cell.kind == "report":
            cmd = _report_command(cmd)
        rc = _run_command(cmd, cell, lay, env, task)
        if rc != 0:
            raise CellFailed(f"{cell.name}: FAILED (exit status {rc}); see {lay.log(cell.name)}", rc)
    _finish(task, result)
    return result


def _run_command(cmd: Command, cell: Cell, lay: Layout, env: dict[str, str], task: CellTask) -> int:
    """Run one command of ``cell`` to its end; its wall time and CPU time (its own ``rusage``: the CPU it used,
    however many processes shared the cores) are added to the cell's account (:meth:`Layout.clock`)."""
    log_path = lay.log(cell.name)
    log_path.parent.mkdir(parents=True, exist_ok=True)
    with open(log_path, "a") as log:
        log.write(f"\n== {utc_stamp()} {cmd.text(task.p.threads)}\n")
        log.flush()
        # a session of its own: a Ctrl-C at the terminal reaches reproduce.py only, which passes exactly one on
        proc = subprocess.Popen(
            [task.python, *cmd.argv],
            cwd=REPO,
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,
            preexec_fn=_die_with_parent,
        )
        began = time.monotonic()

        def reap(block: bool) -> int | None:
            pid, st, usage = os.wait4(proc.pid, 0 if block else os.WNOHANG)
            if pid == 0:
                return None
            proc.returncode = os.waitstatus_to_exitcode(st)
            path = lay.clock(cell.name)
            path.parent.mkdir(parents=True, exist_ok=True)
            account = read_clock(path)
            account["seconds"] += time.monotonic() - began
            account["cpu_seconds"] += usage.ru_utime + usage.ru_stime
            path.write_text(json.dumps({k: round(v, 2) for k, v in account.items()}) + "\n")
            return proc.returncode

        try:
            while (rc := reap(False)) is None:
                if STOP.is_set():
                    raise KeyboardInterrupt
                time.sleep(0.2)
            return rc
        except KeyboardInterrupt:
            proc.send_signal(signal.SIGINT)  # one: a training writes its checkpoint and stops
            deadline = time.monotonic() + STOP_GRACE_SECONDS
            while reap(False) is None and time.monotonic() < deadline:
                time.sleep(0.2)
            if proc.returncode is None:
                proc.kill()
                reap(True)
            raise


def _report_command(cmd: Command) -> Command:
    """The report over the evaluations that are complete (the others are not passed: report.py would refuse a
    folder without episodes.csv)."""
    argv = []
    for a in cmd.argv:
        if a.startswith("evals=["):
            done = [x for x in a[len("evals=[") : -1].split(",") if x and (REPO / x / "episodes.csv").exists()]
            a = "evals=[" + ",".join(done) + "]"
        argv.append(a)
    return Command(argv)


def _outdated_evaluations(task: CellTask, result: CellResult) -> list[str]:
    """The evaluation cells of the training ``task`` that have results, their folders moved aside
    (``<out>.old-<UTC time>``, never deleted) so that they are made again from the models about to be trained."""
    lay, outdated = Layout(task.root), []
    for dep in task.cells:
        if dep.kind != "eval" or task.name not in dep.needs_cells:
            continue
        moved = False
        for cmd in dep.commands:
            if cmd.out is not None and cmd.out.exists():
                aside = _move_aside(cmd.out, "old")
                result.messages.append(
                    f"{task.name} trains from zero: moved its earlier evaluation {cmd.out} to {aside}"
                )
                moved = True
        if moved:
            lay.clock(dep.name).unlink(missing_ok=True)
            outdated.append(dep.name)
    return outdated


def _finish(task: CellTask, result: CellResult) -> None:
    """Mark the cell done (every kind gets a marker with the wall and CPU seconds its commands took, over every
    session; only a training's and the report's marker count for :func:`status`)."""
    cell, lay = task.cell, Layout(task.root)
    if cell.kind == "train" and not cell.final_model.exists():  # type: ignore[union-attr]
        raise CellFailed(f"{cell.name}: train.py exited 0 but {cell.final_model} is missing; not marked done")
    clock = lay.clock(cell.name)
    account = read_clock(clock) if clock.exists() else {"seconds": None, "cpu_seconds": None}
    marker = lay.marker(cell.name)
    marker.parent.mkdir(parents=True, exist_ok=True)
    tmp = marker.with_name(f".{marker.name}.tmp")  # written whole or not at all: a lost worker leaves no half marker
    tmp.write_text(json.dumps({"finished": utc_stamp(), "protocol": task.p.name, **account}) + "\n")
    tmp.replace(marker)
    clock.unlink(missing_ok=True)
    if cell.kind == "report" and (cell.report_out / "report.md").exists():  # type: ignore[operator]
        with open(cell.report_out / "report.md", "a") as report:  # type: ignore[operator]
            report.write("\n" + "\n".join(provenance(task.p, task.cells, lay, task.selects)))
    if cell.kind == "train" and not cell.keep_checkpoints:
        for name in CHECKPOINTS:
            (cell.run_dir / name).unlink(missing_ok=True)  # type: ignore[operator]


def cell_resources(p: Protocol, cell: Cell) -> tuple[int, float]:
    """(CPUs, GPUs) one cell needs: ``threads`` cores each; a training run the GPUs its algorithm asks for."""
    gpus = 0.0
    if cell.kind == "train":
        algo = cell.name.split("/")[1]
        gpus = p.algorithms[algo].gpus if algo in p.algorithms else 0.0
    return p.threads, gpus


# ------------------------------------------------------------------------------------------------ engines
class _Engine:
    """One engine's submit, wait and stop; the engine queues, places, runs and (Ray) retries the cells."""

    def submit(self, tasks: list[CellTask]) -> list[Any]:
        raise NotImplementedError

    def wait(self, handles: list[Any], timeout: float) -> list[tuple[Any, CellResult | BaseException]]:
        raise NotImplementedError

    def stop(self, handles: list[Any]) -> None:
        raise NotImplementedError

    def close(self) -> None:
        pass


class LocalEngine(_Engine):
    """``jobs`` worker threads of a standard pool, each running one cell's subprocesses at a time."""

    def __init__(self, jobs: int):
        from concurrent.futures import ThreadPoolExecutor

        STOP.clear()
        self.pool = ThreadPoolExecutor(max_workers=jobs, thread_name_prefix="cell")

    def submit(self, tasks):
        return [self.pool.submit(run_cell, t) for t in tasks]

    def wait(self, handles, timeout):
        from concurrent.futures import FIRST_COMPLETED, wait

        done, _ = wait(handles, timeout=timeout, return_when=FIRST_COMPLETED)
        return [(f, f.exception() or f.result()) for f in done]

    def stop(self, handles):
        from concurrent.futures import wait

        for f in handles:
            f.cancel()  # queued: never starts
        STOP.set()  # running: one SIGINT each, then they end
        wait(handles)

    def close(self):
        self.pool.shutdown(wait=True, cancel_futures=True)


class RayEngine(_Engine):
    """Every cell a Ray task with the CPUs and GPUs it needs; a task whose worker (or node) is lost is run again by
    Ray (``max_retries``) and continues from the files the lost one left."""

    def __init__(self, p: Protocol, address: str | None, jobs: int, retries_on_loss: int):
        try:
            import ray
        except ImportError:
            raise ProtocolError("executor=ray needs Ray: pip install -e '.[cluster]'") from None
        self.ray, self.p = ray, p
        self.started = not ray.is_initialized()
        if self.started:
            # address=None: a Ray instance on this machine with `jobs` CPUs (so `jobs` cells of one core at once)
            kw: dict[str, Any] = {"address": address} if address else {"num_cpus": jobs * p.threads}
            ray.init(**kw, include_dashboard=False, log_to_driver=False, configure_logging=False)
        self.remote = ray.remote(max_retries=retries_on_loss, retry_exceptions=False)(run_cell)

    def submit(self, tasks):
        refs = []
        for t in tasks:
            cpus, gpus = cell_resources(self.p, t.cell)
            refs.append(self.remote.options(num_cpus=cpus, num_gpus=gpus, name=t.name).remote(t))
        return refs

    def wait(self, handles, timeout):
        ready, _ = self.ray.wait(handles, num_returns=1, timeout=timeout)
        out = []
        for ref in ready:
            try:
                out.append((ref, self.ray.get(ref)))
            except self.ray.exceptions.RayTaskError as err:  # the cell's own exception (CellFailed)
                out.append((ref, getattr(err, "cause", None) or err))
            except self.ray.exceptions.RayError as err:  # the worker lost more often than max_retries
                out.append((ref, CellFailed(f"lost with its Ray worker: {type(err).__name__}")))
        return out

    def stop(self, handles):
        for ref in handles:
            self.ray.cancel(ref)  # a KeyboardInterrupt in the task: one SIGINT to its command
        self.ray.wait(handles, num_returns=len(handles), timeout=STOP_GRACE_SECONDS + 10)

    def close(self):
        if self.started:
            self.ray.shutdown()


class SubmititEngine(_Engine):
    """Cells as SLURM jobs through submitit: those released together go as one job array per (CPUs, GPUs);
    ``cluster="local"``: submitit's local executor (subprocesses of this machine, the same code path)."""

    def __init__(self, p: Protocol, lay: Layout, cluster: str, slurm: dict[str, Any]):
        try:
            import submitit
        except ImportError:
            raise ProtocolError("executor=slurm needs submitit: pip install -e '.[cluster]'") from None
        self.submitit, self.p = submitit, p
        self.executor = submitit.AutoExecutor(folder=lay.root / "submitit" / "%j", cluster=cluster)
        self.executor.update_parameters(**slurm)

    def submit(self, tasks):
        groups: dict[tuple[int, float], list[CellTask]] = {}
        for t in tasks:
            groups.setdefault(cell_resources(self.p, t.cell), []).append(t)
        jobs: dict[str, Any] = {}
        for (cpus, gpus), group in groups.items():
            self.executor.update_parameters(cpus_per_task=cpus, gpus_per_node=int(gpus + 0.999))
            with self.executor.batch():  # one job array
                for t in group:
                    jobs[t.name] = self.executor.submit(run_cell, t)
        return [jobs[t.name] for t in tasks]

    def wait(self, handles, timeout):
        deadline = time.monotonic() + timeout
        while True:
            done = [j for j in handles if j.done()]
            if done or time.monotonic() >= deadline:
                break
            time.sleep(0.5)
        out = []
        for j in done:
            try:
                out.append((j, j.result()))
            except self.submitit.core.utils.FailedJobError as err:
                cause = str(err).strip().splitlines()
                out.append(
                    (
                        j,
                        CellFailed(
                            next(
                                (ln for ln in reversed(cause) if "CellFailed" in ln),
                                f"job {j.job_id} failed; see {j.paths.stderr}",
                            )
                        ),
                    )
                )
            except Exception as err:  # noqa: BLE001 - a job that vanished (cancelled, node lost): not done
                out.append((j, CellFailed(f"job {j.job_id}: {type(err).__name__}: {err}")))
        return out

    def stop(self, handles):
        for j in handles:
            if not j.done():
                j.cancel(check=False)  # scancel: SIGTERM, one SIGINT to the command
        deadline = time.monotonic() + STOP_GRACE_SECONDS + 10
        while any(not j.done() for j in handles) and time.monotonic() < deadline:
            time.sleep(0.5)


class Runner:
    """Runs cells on an engine (``executor``: local, ray or slurm). The runner only hands a cell to the engine once
    the files it needs exist — the engine queues, places, runs and retries it — and the done-markers the workers
    write are the only record of what is done."""

    def __init__(
        self,
        p: Protocol,
        cells: Sequence[Cell],
        lay: Layout,
        *,
        executor: str = "local",
        jobs: int = 1,
        max_minutes: float | None = None,
        redo: bool = False,
        retries: int = 0,
        python: str = sys.executable,
        progress: bool = True,
        echo: Callable[[str], None] = print,
        selects: str | None = None,
        ray_address: str | None = None,
        ray_retries: int = 3,
        submitit_cluster: str = "slurm",
        slurm: dict[str, Any] | None = None,
    ):
        if executor not in EXECUTORS:
            raise ProtocolError(f"executor={executor}: not an executor; allowed: {', '.join(EXECUTORS)}")
        self.p, self.cells, self.lay, self.jobs, self.retries = p, list(cells), lay, jobs, retries
        self.selects = selects  # reproduce.py's protocol=, root=, out= as given: the report's commands repeat them
        self.max_minutes, self.redo, self.python, self.progress, self.echo = max_minutes, redo, python, progress, echo
        self.executor, self.ray_address, self.ray_retries = executor, ray_address, ray_retries
        self.submitit_cluster, self.slurm = submitit_cluster, dict(slurm or {})

    def _engine(self) -> _Engine:
        if self.executor == "ray":
            return RayEngine(self.p, self.ray_address, self.jobs, self.ray_retries)
        if self.executor == "slurm":
            return SubmititEngine(self.p, self.lay, self.submitit_cluster, self.slurm)
        return LocalEngine(self.jobs)

    def _ready(self, cell: Cell, finished: set[str], failed: set[str], selected: set[str]) -> bool | None:
        """True: may start; False: wait; None: can never start in this session (a needed cell failed or is not
        being run and its files are missing)."""
        if cell.kind == "report":
            pending = [n for n in cell.needs_cells if n in selected and n not in finished]
            if any(n in failed for n in pending):
                return None
            return not pending
        if all(f.exists() for f in cell.needs):
            return True
        if any(n in failed or n in finished or n not in selected for n in cell.needs_cells):
            return None
        return False

    def run(self, todo: Sequence[Cell]) -> int:
        """Run ``todo`` (in its order, as their needs allow); returns 0 when every one finished, else 1."""
        selected = {c.name for c in todo}
        by_name = {c.name: c for c in self.cells}
        waiting = list(todo)
        running: dict[Any, str] = {}
        finished: set[str] = set()
        failed: set[str] = set()
        late: set[str] = set()
        blocked: list[str] = []
        tries: dict[str, int] = {}
        deadline = None if self.max_minutes is None else time.time() + 60 * self.max_minutes
        bar = None
        if self.progress:
            from tqdm import tqdm

            bar = tqdm(total=len(todo), desc="cells", unit="cell", dynamic_ncols=True)

        previous = signal.signal(signal.SIGTERM, _interrupt)
        engine = self._engine()
        try:
            while waiting or running:
                release = []
                for cell in list(waiting):
                    ready = self._ready(cell, finished, failed, selected)
                    if ready is None:
                        waiting.remove(cell)
                        blocked.append(cell.name)
                        failed.add(cell.name)
                        if bar is not None:
                            bar.update(1)
                    elif ready:
                        waiting.remove(cell)
                        # a retry continues what the first try began
                        release.append(
                            CellTask(
                                self.p,
                                self.cells,
                                cell.name,
                                self.lay.root,
                                self.redo and cell.name not in tries,
                                self.selects,
                                self.python,
                                deadline,
                            )
                        )
                if release:
                    running.update(zip(engine.submit(release), (t.name for t in release)))
                if not running:
                    if waiting:  # nothing runs and nothing could start: nothing ever will
                        blocked += [c.name for c in waiting]
                        failed.update(c.name for c in waiting)
                    break
                for handle, outcome in engine.wait(list(running), timeout=0.5):
                    name = running.pop(handle)
                    if isinstance(outcome, KeyboardInterrupt):
                        raise outcome
                    if isinstance(outcome, BaseException):
                        rc = getattr(outcome, "rc", None)
                        if tries.get(name, 0) < self.retries and rc not in (130, -signal.SIGINT):
                            # e.g. the renderer's crash: the same cell again, continuing from what it left
                            tries[name] = tries.get(name, 0) + 1
                            self.echo(
                                f"{name}: exit status {rc}; trying again ({tries[name]} of {self.retries}); "
                                f"see {self.lay.log(name)}"
                            )
                            waiting.insert(0, by_name[name])
                            continue
                        failed.add(name)
                        self.echo(str(outcome))
                    elif outcome.late:
                        late.add(name)
                    else:
                        for m in outcome.messages:
                            self.echo(m)
                        finished.add(name)
                        for dep in outcome.outdated:  # evaluations of old models: made again
                            if dep not in selected:
                                selected.add(dep)
                                waiting.append(by_name[dep])
                                if bar is not None:
                                    bar.total += 1
                    if bar is not None:
                        bar.update(1)
                if deadline is not None and time.time() > deadline and waiting:
                    self.echo(
                        f"max_minutes={self.max_minutes:g} reached: no new cell starts; the {len(running)} "
                        "running finish"
                    )
                    late.update(c.name for c in waiting)
                    waiting = []
                if bar is not None:
                    bar.set_postfix_str(", ".join(running.values())[:80])
        except KeyboardInterrupt:
            self.echo(
                f"reproduce: stopping: {len(running)} running cell(s) asked to stop (training writes a "
                "checkpoint; an evaluation stops and is run again next time)"
            )
            engine.stop(list(running))
            raise
        finally:
            engine.close()
            signal.signal(signal.SIGTERM, previous)
            if bar is not None:
                bar.close()
        if blocked:
            self.echo(
                "not started (a cell they need failed or was not selected, and its files are missing): "
                + ", ".join(blocked)
            )
        if late:
            self.echo(f"{len(late)} cell(s) not started (max_minutes); the same command continues")
        return 0 if len(finished) == len(selected) else 1
