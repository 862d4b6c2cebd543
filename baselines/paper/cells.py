"""A protocol's cells (training runs, evaluations, references, the report), each a few subprocess commands, and
where their files go; :mod:`.cell_status` reads where each stands, :mod:`.plan` what they cost."""

from __future__ import annotations

import json
import math
import os
import shlex
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Literal

from omegaconf import OmegaConf

import evaaa

from ..config import COMPUTE_BOUND_STEPS
from ..paths import CONF_DIR
from .protocol import (
    LEVEL_GROUPS,
    REPO,
    STARTUP_SECONDS,
    EvaluationSpec,
    Protocol,
    seed_span,
)


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
    kind: Literal["train", "eval", "ref", "choose", "report"]
    commands: list[Command]
    minutes: float  # estimated CPU-minutes
    group: str  # the budget line it counts in (e.g. "ppo curriculum", "evaluation")
    run_dir: Path | None = None  # training: the run directory
    final_model: Path | None = None  # training: the last stage's model
    needs: list[Path] = field(default_factory=list)  # files that must exist before it starts (models)
    needs_cells: list[str] = field(default_factory=list)  # cells whose outputs those are
    keep_checkpoints: bool = True  # training: false deletes the run's checkpoints once it is done
    report_out: Path | None = None  # the report: its folder
    choice: Path | None = None  # the choice of the compared acting mode: the file it writes


def _safe(name: str) -> str:
    return name.replace("/", os.sep)


@cache
def max_steps(level: str) -> int:
    """A level's episode cap (decisions), for the estimates."""
    return int(evaaa.load_level(level).episode.max_steps)


@cache
def _eval_defaults() -> dict:
    """train.py's ``eval`` settings where no override names them (conf/config.yaml)."""
    return dict(OmegaConf.to_container(OmegaConf.load(CONF_DIR / "config.yaml").eval))


def override(argv: Sequence[str], key: str, default: object) -> str:
    """The value the last ``key=value`` of ``argv`` gives (train.py: the last override wins), else ``default``."""
    said = [a.split("=", 1)[1] for a in argv if a.replace(" ", "").lstrip("+").split("=", 1)[0] == key]
    return said[-1].strip() if said else str(default)


def validation_seconds(
    argv: Sequence[str], algo: str, stages: Sequence[str], budgets: Sequence[int], steps_per_second: float
) -> float:
    """Seconds a training run of ``argv`` spends in its in-training validation evaluations, each episode taken to its
    level's step limit (an upper bound): per stage one every ``eval.every`` env steps (the last at the stage's end),
    ``eval.episodes`` episodes, played twice where ``eval.both_modes=true`` and ``algo`` can sample; the settings as
    ``argv``'s overrides give them, else conf/config.yaml's (a preset's own ``eval`` settings are not read)."""
    from ..rollout import samples_actions  # the algorithms' modules load torch: only plans that count evaluations

    defaults = _eval_defaults()
    every = int(override(argv, "eval.every", defaults["every"]).replace("_", ""))
    if every <= 0:
        return 0.0
    episodes = int(override(argv, "eval.episodes", defaults["episodes"]))
    both = override(argv, "eval.both_modes", defaults["both_modes"]).lower() == "true"
    modes = 2 if both and samples_actions(algo) else 1
    evaluations = sum(math.ceil(b / every) * max_steps(lv) for lv, b in zip(stages, budgets))
    return evaluations * episodes * modes / steps_per_second


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
        # evaluation.compare: validation: the acting mode the claims compare, chosen before any test evaluation
        self.choice = self.root / "compared_mode.json"

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

    def processors(self, cell: str) -> dict[str, float]:
        """CPU seconds a done cell's commands took per processor that ran them (its marker); empty where that was
        not recorded (cells finished before it was)."""
        try:
            return _by_processor(json.loads(self.marker(cell).read_text()).get("processors"))
        except (OSError, ValueError, AttributeError):
            return {}


def read_clock(path: Path) -> dict:
    """A cell's running account (:meth:`Layout.clock`): wall and CPU seconds, and the CPU seconds per processor
    (:func:`~evaaa_baselines.machine.processor`) that ran its commands; zeros where there is none or it cannot be
    read."""
    try:
        account = json.loads(path.read_text())
        out: dict = {k: float(account[k]) for k in ("seconds", "cpu_seconds")}
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return {"seconds": 0.0, "cpu_seconds": 0.0, "processors": {}}
    out["processors"] = _by_processor(account.get("processors"))
    return out


def _by_processor(spent: object) -> dict[str, float]:
    """A marker's or clock's ``processors`` (name: CPU seconds) as read from JSON; empty where it is not one."""
    if not isinstance(spent, dict):
        return {}
    return {str(k): float(v) for k, v in spent.items() if isinstance(v, (int, float))}


def rounded(account: dict) -> dict:
    """``account`` (:func:`read_clock`) with its seconds to hundredths, as the clock and the markers keep them."""
    return {k: rounded(v) if isinstance(v, dict) else round(v, 2) for k, v in account.items()}


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
# written by scripts/reproduce.py: commit the results, not the models, checkpoints, replay buffers, text logs or figures
!/runs/
*.pt
*.log
/logs/
/evals/**/*.png
/runs/**/replay/
/runs/**/openloop/
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
    return _Builder(p, Layout(root)).build(report_out)


class _Builder:
    """The cells of one protocol, part by part (:func:`build_cells`)."""

    def __init__(self, p: Protocol, lay: Layout):
        self.p, self.lay, self.ev = p, lay, p.evaluation
        self.parts: dict[str, list[Cell]] = {part: [] for part in p.order}
        self.eval_outs: list[Path] = []  # every evaluation folder, in order: the report reads them
        self.modes = eval_modes(self.ev)

    def build(self, report_out: Path | None) -> list[Cell]:
        p = self.p
        self.references()
        enabled = [a for a, spec in p.algorithms.items() if spec.enabled]
        for algo in enabled:
            self.algorithm(algo, enabled)
        self.matched(enabled)
        cells = [c for part in p.order for c in self.parts[part]]
        trains = [c for c in cells if c.kind == "train"]
        if self.ev.compare == "validation" and trains:
            # after the last training, before the evaluations that wait for it
            cells.insert(cells.index(trains[-1]) + 1, self.choose(trains))
        cells.append(self.report(cells, report_out))
        return cells

    # ------------------------------------------------------------------------------------------ evaluations
    def eval_cell(self, name: str, model: Path, own: str, train_cell: str, sps: float, algo: str) -> Cell:
        """The evaluations of one model: on the testbeds and on its own level, in each acting mode."""
        from ..rollout import samples_actions  # torch: not for reproduce.py --help

        ev, lay, modes = self.ev, self.lay, self.modes
        cmds, seconds = [], 0.0
        # an algorithm without an action distribution acts the same when asked to sample: evaluated once
        own_modes = [m for m in modes if m == "mode" or samples_actions(algo)] or modes
        for mode in own_modes:
            suffix = "" if len(modes) == 1 else f"-{mode}"
            common = [
                f"seed={ev.seed}",
                f"epsilon={ev.epsilon:g}",
                f"sample={str(mode == 'sample').lower()}",
                f"threads={self.p.threads}",
                f"policy=[{arg(model)}]",
            ]
            if ev.worlds != "test":
                common.append(f"worlds={ev.worlds}")
            folder = lay.evals / _safe(name.removeprefix("eval/"))
            if ev.testbeds is not None:
                tb = expand_levels(ev.testbeds.levels)
                cmds.append(_evaluation(common, ev.testbeds.levels, ev.testbeds, folder / f"testbeds{suffix}"))
                seconds += STARTUP_SECONDS + ev.testbeds.episodes * sum(max_steps(t) for t in tb) / sps
            if ev.own_level is not None:
                cmds.append(_evaluation(common, [own], ev.own_level, folder / f"level{suffix}"))
                seconds += STARTUP_SECONDS + ev.own_level.episodes * max_steps(own) / sps
        self.eval_outs.extend(c.out for c in cmds if c.out is not None)
        needs, needs_cells = [model], [train_cell]
        if ev.compare == "validation":
            # no checkpoint meets a test world before the compared mode is chosen from validation rows
            needs, needs_cells = [model, lay.choice], [train_cell, CHOOSE]
        return Cell(name, "eval", cmds, seconds / 60, f"{algo} evaluation", needs=needs, needs_cells=needs_cells)

    def references(self) -> None:
        """The reference policies' evaluations (random, stand-still, the oracle), one cell each."""
        ref, ev, lay = self.p.references, self.ev, self.lay
        if ref is None:
            return
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
                    f"threads={self.p.threads}",
                    *([f"worlds={ev.worlds}"] if ev.worlds != "test" else []),
                    f"out={arg(out)}",
                ],
                out,
            )
            seconds = STARTUP_SECONDS + ref.episodes * sum(max_steps(lv) for lv in ref_levels) / ref.steps_per_second
            self.parts["references"].append(Cell(f"ref/{policy}", "ref", [cmd], seconds / 60, "references"))
            self.eval_outs.append(out)

    # ------------------------------------------------------------------------------------------ trainings
    def train_cell(
        self,
        part: str,
        algo: str,
        setup: str,
        seed: int,
        level_args: list[str],
        stages: list[str],
        group: str,
        extra: Sequence[str] = (),
        steps: int | None = None,
        minutes: float | None = None,
    ) -> None:
        """One training run and the evaluations of its models (each stage's, for a curriculum)."""
        p, lay, spec = self.p, self.lay, self.p.algorithms[algo]
        name = f"train/{algo}/{setup}/seed{seed}"
        run_name = f"{algo}/{setup}/seed{seed}"
        run_dir = lay.runs / _safe(run_name)
        argv = [
            "scripts/train.py",
            f"algo={algo}",
            *level_args,
            f"seed={seed}",
            f"threads={p.threads}",
            *p.training.overrides,
            *spec.overrides,
            *extra,
            f"run.root={arg(lay.runs)}",
            f"run.name={run_name}",
        ]
        if minutes is None:
            S = p.stage_steps
            minutes = (STARTUP_SECONDS + (steps or S * len(stages)) / spec.steps_per_second) / 60
            if p.training.eval_steps_per_second is not None:
                budgets = [steps or S] * len(stages)
                minutes += validation_seconds(argv, algo, stages, budgets, p.training.eval_steps_per_second) / 60
        final = run_dir / f"model-{len(stages) - 1}-{stages[-1]}.pt"
        cells = self.parts[part]
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
        sps = self.ev.steps_per_second
        if len(stages) > 1:
            for i, lv in enumerate(stages):
                model = run_dir / f"model-{i}-{lv}.pt"
                cells.append(
                    self.eval_cell(f"eval/{algo}/{setup}/seed{seed}/stage{i}-{lv}", model, lv, name, sps, algo)
                )
        else:
            cells.append(self.eval_cell(f"eval/{algo}/{setup}/seed{seed}", final, stages[0], name, sps, algo))

    def algorithm(self, algo: str, enabled: list[str]) -> None:
        """An algorithm's curriculum runs, direct runs and ablations."""
        p, S, levels = self.p, self.p.stage_steps, self.p.stage_levels
        trained = p.training.algorithms if p.training.algorithms is not None else enabled
        ab = p.ablations if p.ablations is not None and p.ablations.enabled else None
        if algo in trained and p.training.curriculum:
            curriculum = ["level=curriculum", f"level.stages=[{','.join(levels)}]", f"level.stage_steps={S}"]
            for seed in p.seeds:
                self.train_cell("curriculum", algo, "curriculum", seed, curriculum, levels, "curriculum")
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
                # worlds apart from the curriculum's (training.direct_seed_offset)
                level_args = [f"level={lv}", f"total_steps={steps}"]
                self.train_cell(
                    part, algo, f"direct-{lv}", p.direct_seed(seed), level_args, [lv], "direct", steps=steps
                )
        if ab is not None and ab.algorithm == algo:
            for mod in (m for m in ab.modalities if m != "all"):
                for seed in ab.seeds or p.seeds:
                    self.train_cell(
                        "ablations",
                        algo,
                        f"ablation-{mod}",
                        p.direct_seed(seed),  # the seeds of the `all` condition, the direct run on the level
                        [f"level={ab.level}", f"total_steps={S}"],
                        [ab.level],
                        "ablations",
                        extra=[f"modality={mod}"],
                    )

    def matched(self, enabled: list[str]) -> None:
        """The compute-matched runs, seed by seed: a step budget no run reaches, the CPU minutes end every run."""
        m = self.p.matched
        if m is None:
            return
        for seed in m.seeds or self.p.seeds:
            for algo in m.algorithms or enabled:
                self.train_cell(
                    "matched",
                    algo,
                    f"matched-{m.level}",
                    seed,
                    [f"level={m.level}", f"total_steps={MATCHED_STEPS}", f"max_cpu_minutes={m.cpu_minutes:g}"],
                    [m.level],
                    "matched",
                    extra=m.overrides.get(algo, []),
                    minutes=m.cpu_minutes + STARTUP_SECONDS / 60,
                )

    # ------------------------------------------------------------------------------------------ choice, report
    def choose(self, trains: list[Cell]) -> Cell:
        """The cell that chooses the compared acting mode from every run's validation rows."""
        ev, lay = self.ev, self.lay
        argv = [
            "scripts/choose_acting.py",
            "runs=[" + ",".join(arg(c.run_dir) for c in trains) + "]",  # type: ignore[arg-type]
            f"first={eval_modes(ev)[0]}",
            f"epsilon={ev.epsilon:g}",
            f"evals={arg(lay.evals)}",
            f"out={arg(lay.choice)}",
        ]
        return Cell(
            CHOOSE,
            "choose",
            [Command(argv)],
            STARTUP_SECONDS / 60,
            "choice",
            # every training's done-marker: the choice pools every network's last validation evaluation
            needs=[lay.marker(c.name) for c in trains],
            needs_cells=[c.name for c in trains],
            choice=lay.choice,
        )

    def report(self, cells: list[Cell], report_out: Path | None) -> Cell:
        """The report over every evaluation, written last."""
        p, ev, lay = self.p, self.ev, self.lay
        if report_out is not None:
            out = Path(report_out)
        else:
            out = lay.root / "report" if p.report.out is None else REPO / p.report.out
        out = out.resolve()
        argv = [
            "scripts/report.py",
            f"runs=[{arg(lay.runs)}]",
            "evals=[" + ",".join(map(arg, self.eval_outs)) + "]",
            f"out={arg(out)}",
            f"survival={p.report.survival}",
            f"title={p.report.title or default_title(p)}",
        ]
        if any(c.kind == "eval" for c in cells):
            # one mode: the report reports it alone; several: it shows each, labelled. Its claims compare the first
            # (an algorithm without an action distribution, DQN, with its greedy action in a `sample` comparison)
            argv += [f"acting={acting(ev)}"] * (len(self.modes) == 1)
            # compare: validation: the mode choose/acting wrote before any test evaluation, read by the report
            argv.append(f"compare_from={arg(lay.choice)}" if ev.compare == "validation" else f"compare={acting(ev)}")
        if p.report.learned is not None:
            argv.append(f"learned={p.report.learned:g}")
        # the verdict rules' margins, stated in the protocol file before its runs (docs/reports.md, "The verdict rules")
        argv += [f"margin={p.report.verdicts.margin:g}", f"gain_margin={p.report.verdicts.gain_margin:g}"]
        needs = [c.name for c in cells]
        return Cell("report", "report", [Command(argv, None)], 1.0, "report", needs_cells=needs, report_out=out)


def _evaluation(common: list[str], levels: Sequence[str], spec, out: Path) -> Command:
    """One evaluate.py command: ``common`` arguments, ``levels`` at ``spec``'s episodes and batch, into ``out``."""
    argv = [
        "scripts/evaluate.py",
        *common,
        f"levels=[{','.join(levels)}]",
        f"episodes={spec.episodes}",
        f"num_envs={spec.num_envs}",
        f"out={arg(out)}",
    ]
    return Command(argv, out)


#: the env-step budget of a compute-matched run: more than any run reaches in its CPU minutes
MATCHED_STEPS = COMPUTE_BOUND_STEPS
#: the cell that chooses the compared acting mode from validation rows (evaluation.compare: validation)
CHOOSE = "choose/acting"


def eval_modes(ev: EvaluationSpec) -> list[str]:
    """The acting modes every model is evaluated in, the report's first."""
    return list(ev.modes) if ev.modes is not None else ["sample" if ev.sample else "mode"]


def acting(ev: EvaluationSpec) -> str:
    """How evaluate.py names the acting mode of the protocol's checkpoint evaluations the report compares (its
    ``acting`` column; ``evaluation.compare`` where it names one, else the first of several modes; with
    ``compare: validation`` the first, which the report replaces by the mode chosen)."""
    mode = ev.compare if ev.compare in ("sample", "mode") else eval_modes(ev)[0]
    return mode + (f"+epsilon={ev.epsilon:g}" if ev.epsilon else "")


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
    said = {"mode": "by their most likely action", "sample": "by sampling (DQN: its greedy action)"}
    if len(modes) == 1:
        return said[modes[0]] + eps
    if ev.compare == "validation":
        return (
            " and ".join(said[m] for m in modes) + f"{eps}; the claims compare the mode whose in-training validation "
            "evaluations survived longer, chosen before any test evaluation (compared_mode.json)"
        )
    if ev.compare in modes:
        modes = [ev.compare, *(m for m in modes if m != ev.compare)]
    if modes[0] == "mode":
        said["sample"] = "by sampling where they have a distribution"
    return f"{said[modes[0]]}{eps}, the mode the claims compare, and " + " and ".join(said[m] for m in modes[1:])


def world_seeds_text(p: Protocol) -> str:
    """Which seeds' worlds the curriculum and the direct runs train on, and whether they are disjoint (the plan's and
    the report's words)."""
    t = p.training
    cur, direct = p.curriculum_world_seeds, p.direct_seeds
    parts = []
    if cur:
        parts.append(
            f"curriculum seeds {', '.join(map(str, p.seeds))} train stage i on the worlds of seed + i "
            f"({seed_span(cur)})"
        )
    if direct:
        off = f" (seed + direct_seed_offset {t.direct_seed_offset})" if t.direct_seed_offset else ""
        parts.append(f"direct runs and ablations on seeds {', '.join(map(str, sorted(direct)))}{off}")
    if cur and direct:
        shared = sorted(cur & direct)
        parts.append(
            f"the arms share the worlds of seeds {seed_span(set(shared))} (training.allow_shared_worlds)"
            if shared
            else "disjoint"
        )
    return "training worlds: " + "; ".join(parts) if parts else ""
