"""A protocol's plan: the CPU- and GPU-hours of its cells against what they took, the wall time on a cluster, and the
provenance a record carries (``reproduce.py plan=true``, the report's \"How this report was made\")."""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence

from .cell_status import command_now, status
from .cells import Cell, Layout, acting_text, read_clock, world_seeds_text
from .protocol import (
    CHECKPOINTS,
    Protocol,
)


# ------------------------------------------------------------------------------------------------ plan
def budget(cells: Sequence[Cell]) -> dict[str, float]:
    """Estimated CPU-minutes per budget line, in order."""
    lines: dict[str, float] = {}
    for c in cells:
        lines[c.group] = lines.get(c.group, 0.0) + c.minutes
    return lines


def minutes_left(cell: Cell, lay: Layout) -> tuple[float, float]:
    """``cell``'s estimate less the CPU-minutes its account holds, and those minutes: a training that has a checkpoint
    continues from it (a run cut short in an earlier session, where this machine kept its files); any other cell
    counts in full."""
    if cell.kind != "train" or cell.run_dir is None or not (cell.run_dir / CHECKPOINTS[0]).exists():
        return cell.minutes, 0.0
    spent = read_clock(lay.clock(cell.name))["cpu_seconds"] / 60
    return max(cell.minutes - spent, 0.0), spent


def plan_text(p: Protocol, cells: Sequence[Cell], lay: Layout, threads: int) -> str:
    """The plan: every cell with its status and estimate, the budget split, the totals, each cell's command."""
    states = {c.name: status(c, lay, cells) for c in cells}
    width = max(len(c.name) for c in cells)
    lines = [
        f"protocol {p.name}: {len(cells)} cells under {lay.root}; S = {p.stage_steps:,} env steps per stage "
        f"(curriculum stage and direct run), seeds {p.seeds}; checkpoints act {acting_text(p.evaluation)}",
        *([world_seeds_text(p)] if world_seeds_text(p) else []),
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
    left = sum(minutes_left(c, lay)[0] for c in cells if states[c.name] != "done")
    counts = {s: sum(1 for v in states.values() if v == s) for s in ("done", "partial", "todo")}
    lines += [
        "",
        f"estimated CPU-hours (threads={p.threads} per cell, hours of one cell; rates in the protocol file; evaluation episodes "
        "taken to their step limit"
        + (
            f"; trainings with their in-training validation evaluations at {p.training.eval_steps_per_second:g} world "
            "steps/s"
            if p.training.eval_steps_per_second is not None
            else ""
        )
        + "):",
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
        f"{counts['done']} done, {counts['partial']} partial, {counts['todo']} todo; {left / 60:.2f} h left, "
        "less what started trainings have run)"
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
    on_cpus = [n for n, a in p.algorithms.items() if a.enabled and a.gpus == 0]
    cpu_trainings = f"the trainings of {', '.join(on_cpus)} (gpus: 0), " if on_cpus else ""
    lines = [
        "",
        "estimated GPU-hours (training runs at each algorithm's measured env steps/s, rate_from; "
        f"{cpu_trainings}evaluations and references run on the CPUs):",
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
    worlds = world_seeds_text(p)
    lines = [
        "## How this report was made",
        "",
        f"The protocol `{p.name}`: S = {p.stage_steps:,} env steps per stage (curriculum "
        f"stage and direct run), seeds {', '.join(map(str, p.seeds))}, checkpoints act {acting_text(p.evaluation)}; "
        + (f"{worlds}; " if worlds else "")
        + f"{sum(c.kind != 'report' for c in cells)} cells besides the report, {len(done)} of them done when this "
        "report was made. From "
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
    by_cell = {c.name: lay.processors(c.name) for c in timed}
    spent_on: Counter[str] = sum((Counter(v) for v in by_cell.values()), Counter())
    unknown = sum(took[n] or 0.0 for n, v in by_cell.items() if not v)
    parts = [f"{name} {seconds / 3600:.2f}" for name, seconds in sorted(spent_on.items())]
    if unknown:
        parts.append(f"not recorded {unknown / 3600:.2f}")
    lines += [
        "",
        "The processors that ran them (CPU-hours; a CPU-minute buys more env steps on a faster one, so a run's env "
        "steps reached depend on where it ran): "
        + "; ".join(parts)
        + (" (not recorded: cells done before the runner recorded it)." if unknown else "."),
    ]
    untimed = [c for c in done if took[c.name] is None]
    if untimed:
        lines += [
            "",
            f"{len(untimed)} done cells were not timed (run before cells were): "
            f"{', '.join(c.name for c in untimed)}; the protocol file estimates them at "
            f"{sum(c.minutes for c in untimed) / 60:.2f} CPU-hours.",
        ]
    return lines + [""]


def cell_resources(p: Protocol, cell: Cell) -> tuple[int, float]:
    """(CPUs, GPUs) one cell needs: ``threads`` cores each; a training run the GPUs its algorithm asks for."""
    gpus = 0.0
    if cell.kind == "train":
        algo = cell.name.split("/")[1]
        gpus = p.algorithms[algo].gpus if algo in p.algorithms else 0.0
    return p.threads, gpus
