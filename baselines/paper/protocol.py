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

import json
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import yaml
from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

import evaaa

from ..algos import names as algorithm_names
from ..paths import CONF_DIR

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
    # the direct runs (and the ablations, whose `all` condition is the direct run on their level) train with seed +
    # direct_seed_offset: a curriculum run of seed s trains its stage i on the worlds of seed s + i (baselines/run.py),
    # so without an offset the direct run of seed s + i trains on the very worlds of curriculum s's stage i, and the
    # two arms of claim (b) are not independent. Curriculum and compute-matched runs keep the protocol's seeds
    direct_seed_offset: int = Field(default=0, ge=0)
    # true: the curriculum's and the direct runs' training-world seeds may overlap (a protocol that ran so before
    # the offset existed); false: such a protocol is refused at load
    allow_shared_worlds: bool = False
    # measured world steps/s of the runs' in-training validation evaluations: given, the plan counts them in every
    # training cell (each stage's evaluations every eval.every env steps, eval.episodes episodes, in both acting modes
    # where eval.both_modes=true and the algorithm samples, each taken to its level's step limit: an upper bound);
    # null: not counted, as the protocols before it were planned (a compute-matched run's CPU minutes hold them anyway)
    eval_steps_per_second: float | None = Field(default=None, gt=0)

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
    # action distribution, DQN, only in `mode`), and the report's claims compare them in the first (DQN with its
    # greedy action where that is `sample`), every mode in its tables; null: as `sample` says
    modes: list[Literal["mode", "sample"]] | None = Field(default=None, min_length=1)
    worlds: Literal["test", "validation"] = "test"  # the evaluations' worlds (evaaa/worlds.py): published: test
    testbeds: EvalPart | None = None  # every evaluated model on these levels (null: none)
    own_level: OwnLevelPart | None = None  # every evaluated model on the level it was trained up to (null: none)
    steps_per_second: float = Field(gt=0, description="measured world steps/s of evaluate.py (estimates)")
    # the acting mode the report's claims compare: `sample` or `mode` (one of `modes`), fixed in the file; or
    # `validation`: the one whose in-training validation evaluations (eval.csv rows, both modes recorded through
    # eval.both_modes=true) survived longer, pooled over the protocol's networks at their last evaluation, chosen by
    # the cell choose/acting once every training is done and before any checkpoint's test evaluation (which waits
    # for it), written to <root>/compared_mode.json; null: the first of `modes`
    compare: Literal["sample", "mode", "validation"] | None = None

    @model_validator(mode="after")
    def _compare(self) -> EvaluationSpec:
        evaluated = list(self.modes) if self.modes is not None else ["sample" if self.sample else "mode"]
        if self.compare == "validation" and sorted(set(evaluated)) != ["mode", "sample"]:
            # the chosen mode must be one the test evaluations made, whichever it turns out to be
            raise ValueError(
                f"evaluation.compare: validation needs both acting modes evaluated (evaluation.modes: [sample, "
                f"mode]; here {evaluated}); allowed: {', '.join(evaluated)}, or validation with both modes"
            )
        if self.compare in ("sample", "mode") and self.compare not in evaluated:
            allowed = evaluated + (["validation"] if len(set(evaluated)) == 2 else [])
            raise ValueError(
                f"evaluation.compare: {self.compare!r} is not an evaluated acting mode (evaluation.modes: "
                f"{evaluated}); allowed: {', '.join(allowed)}"
            )
        return self


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


class VerdictSpec(_Strict):
    """The margins of the verdict rules (baselines/paper/claims.py ``Rules``; docs/reports.md, "The verdict rules"),
    stated in the protocol file before its runs so that a verdict of equivalence cannot be tuned after them."""

    # 'A beats B' (survival IQMs, testbed success rates) is reproduced when the 95 % interval of A / B lies above
    # 1 + margin, contradicted when it lies at or under 1 + margin (equal within the margin, or worse)
    margin: float = Field(default=0.1, ge=0, lt=1)
    # claim (d)'s "no monotonic gain": the gain of mean testbed success (a share: 0.1 is 10 points) along the
    # least-squares line from the first training level to the last reproduces it when its 95 % interval lies at or
    # under +gain_margin (no gain beyond the margin), contradicts it when it lies above
    gain_margin: float = Field(default=0.1, gt=0, lt=1)


class ReportSpec(_Strict):
    out: str | None = None  # relative paths: to the repository root; null: <root>/report
    survival: Literal["eval", "train"] = "eval"
    title: str | None = None
    # report.py's learned=: the factor over the better of random and stand-still an agent's all-senses network must
    # reach on the first level to enter the claims' comparisons (null: every agent is compared)
    learned: float | None = Field(default=None, gt=0)
    verdicts: VerdictSpec = VerdictSpec()


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

    @model_validator(mode="after")
    def _disjoint_worlds(self) -> Protocol:
        t = self.training
        if not (t.curriculum and t.direct) or t.allow_shared_worlds:
            return self
        shared = sorted(self.direct_seeds & self.curriculum_world_seeds)
        if shared:
            fit = next(k for k in range(t.direct_seed_offset + 1, 10**6) if not self._collide(k))
            raise ValueError(
                f"training.direct_seed_offset: the direct runs' training worlds (seeds "
                f"{', '.join(map(str, sorted(self.direct_seeds)))}) are the curriculum's (seed + stage: "
                f"{seed_span(self.curriculum_world_seeds)}), shared by the arms of the comparison; allowed: an offset that "
                f"takes every direct seed out of them (the smallest: {fit}), or training.allow_shared_worlds: true"
            )
        return self

    @model_validator(mode="after")
    def _devices_match_gpus(self) -> Protocol:
        # a run that trains on a GPU must request one (Ray's num_gpus, SLURM's GPUs), and one that requests a GPU must
        # use it: a CPU-bound run reserving a whole GPU idles it (train.py: the last device= override wins)
        for name, spec in self.algorithms.items():
            said = [
                o.replace(" ", "").lstrip("+").lower().split("=", 1)[1]
                for o in [*self.training.overrides, *spec.overrides]
                if o.replace(" ", "").lstrip("+").lower().startswith("device=")
            ]
            device = said[-1] if said else "auto"
            if spec.gpus == 0 and device.startswith("cuda"):
                raise ValueError(
                    f"algorithms.{name}.gpus: 0, but its runs train with device={device}: request the GPUs they use "
                    f"(gpus: 1), or train them on the CPU (device=cpu)"
                )
            if spec.gpus > 0 and device == "cpu":
                raise ValueError(
                    f"algorithms.{name}.gpus: {spec.gpus:g}, but its runs train with device=cpu: the GPUs they reserve "
                    f"would idle; allowed: gpus: 0, or device=cuda (or auto) in its overrides"
                )
        return self

    def _collide(self, offset: int) -> bool:
        return bool({s + offset for s in self.seeds} & self.curriculum_world_seeds)

    @model_validator(mode="after")
    def _validation_rows(self) -> Protocol:
        if self.evaluation.compare != "validation":
            return self
        # the choice reads validation rows of both modes from every run: each run's overrides must ask for them, and
        # no algorithm's or matched run's own overrides may take them away (train.py: the last override wins)
        key = "eval.both_modes="

        def said(overrides: Sequence[str]) -> list[str]:
            plain = (o.replace(" ", "").lstrip("+").lower() for o in overrides)
            return [o for o in plain if o.startswith(key)]

        runs = said(self.training.overrides)
        later = said([o for spec in self.algorithms.values() for o in spec.overrides])
        later += said([o for extra in (self.matched.overrides.values() if self.matched else ()) for o in extra])
        if not runs or runs[-1] != key + "true" or any(o != key + "true" for o in later):
            raise ValueError(
                "evaluation.compare: validation chooses from in-training validation evaluations in both acting modes; "
                "training.overrides must include eval.both_modes=true (and no algorithm's overrides set it false); "
                "allowed: sample, mode, or validation with eval.both_modes=true"
            )
        return self

    @property
    def stage_levels(self) -> list[str]:
        return list(self.levels or evaaa.LEVELS)

    @property
    def curriculum_world_seeds(self) -> set[int]:
        """The seeds of the worlds the curriculum runs train on: seed s's stage i on those of s + i
        (baselines/run.py); empty without curriculum runs."""
        if not self.training.curriculum:
            return set()
        return {s + i for s in self.seeds for i in range(len(self.stage_levels))}

    @property
    def direct_seeds(self) -> set[int]:
        """The seeds the direct runs train with (their one stage's worlds): the protocol's, plus
        ``training.direct_seed_offset``; empty without direct runs."""
        if not self.training.direct:
            return set()
        return {s + self.training.direct_seed_offset for s in self.seeds}

    def direct_seed(self, seed: int) -> int:
        """The seed a direct (or ablation) run of the protocol's seed ``seed`` trains with."""
        return seed + self.training.direct_seed_offset


def seed_span(seeds: set[int]) -> str:
    """``{0, 1, 2, 3, 7}`` as ``0-3, 7``."""
    out: list[str] = []
    for s in sorted(seeds):
        if out and s == int(out[-1].split("-")[-1]) + 1:
            out[-1] = f"{out[-1].split('-')[0]}-{s}"
        else:
            out.append(str(s))
    return ", ".join(out)


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
        # a check across fields names the one to change first in its message (``training.direct_seed_offset: ...``)
        named = re.match(r"([a-z_]+(?:\.[a-z_]+)+): ", msg)
        if named and (where == "(top level)" or named.group(1).startswith(where + ".")):
            where, msg = named.group(1), msg[named.end() :]
        if first["type"] == "extra_forbidden":
            allowed = _fields_at(first["loc"])
            msg = "unknown field" + (f"; allowed: {', '.join(allowed)}" if allowed else "")
        elif first["type"] == "missing":
            msg = "required field missing"
        raise ProtocolError(f"{path}: field {where}: {msg}") from None
