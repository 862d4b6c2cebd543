"""Evaluate policies on testbeds and training levels: episode records, a table and figures.

    python scripts/evaluate.py policy=[oracle,random,still] levels=testbeds episodes=20
    python scripts/evaluate.py policy=runs/ppo-1-1/checkpoint.pt levels=[1-1,two-resource-food] episodes=20
    python scripts/evaluate.py policy=[zoo:ppo-1-1,random,still] levels=[1-1] episodes=20   # a shipped network

Episodes are played on the test worlds of ``seed`` (evaaa/worlds.py: no training run of any seed steps them, and the
periodic evaluations during training use other worlds again, the validation worlds); ``worlds=validation`` plays
those instead, for choosing settings.  Published numbers come from test worlds.

Arguments are ``key=value`` (lists as ``[a,b]``), the keys of :class:`EvalConfig`; ``--help`` lists them with their
types, defaults and meanings.

Writes to ``out``, which must not hold an earlier evaluation (it is refused, changing nothing: each evaluation is a
complete result of its own; one stopped after its ``episodes.csv`` and before its ``summary.md``, which is written
last, is completed by the same command): ``episodes.csv`` (one row per episode, put in place once every episode is
done),
``summary.md`` (per testbed the success rate with its 95 % Wilson interval, per training level the interquartile
mean survival with its 95 % bootstrap interval beside mean ± standard error, one column per policy), ``success.png``,
``survival.png`` and ``outcomes.png`` (what the agent did: consumed the right or wrong resource, died of which
EV, ran out of time; mean collisions).  The episodes are run by :mod:`evaaa_baselines.evaluation`
(:class:`~evaaa_baselines.evaluation.EvaluatedPolicy`), the summary and figures made by :mod:`evaaa_baselines.reports`.
"""

from __future__ import annotations

import os
import re
import sys
import tempfile
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from tqdm import tqdm

import evaaa
from evaaa.records import DISK_ERRNOS, DiskError, StepLog, append_rows, disk_error, new_log_path, read_rows
from evaaa_baselines import cli
from evaaa_baselines.cli import option

if TYPE_CHECKING:  # torch and TorchRL load once --help and the command line have passed
    from evaaa_baselines.evaluation import EvaluatedPolicy

GROUPS = {"testbeds": evaaa.TESTBEDS, "training": evaaa.LEVELS, "all": evaaa.LEVELS + evaaa.TESTBEDS}
#: what an evaluation writes to ``out``: any of them there means ``out`` already holds one
OUTPUTS = ("episodes.csv", "summary.md", "success.png", "survival.png", "outcomes.png")
#: how a level of your own is named in ``levels`` (docs/levels.md, "A level of your own")
OWN_LEVEL = "the path of a .yaml level file of your own, e.g. levels=[1-1,path/to/my.yaml]"


@dataclass
class EvalConfig:
    policy: list[str] = option(
        ["oracle", "random", "still"],
        "oracle, random, still (stands still), a checkpoint file of a baseline, or zoo:NAME (a shipped network: "
        "scripts/zoo.py lists them); a list evaluates each",
        check=(cli.policy_ok, "oracle, random, still, zoo:NAME or an existing checkpoint file"),
    )
    levels: list[str] = option(
        ["testbeds"],
        f"level and testbed names ({', '.join((*evaaa.LEVELS, *evaaa.TESTBEDS))}), the groups testbeds, training, "
        f"all, or {OWN_LEVEL}; episodes.csv names a file's level by its stem, as train.py level=file does",
    )
    episodes: int = option(20, "episodes per level and policy", check=(lambda v: v >= 1, "a positive integer"))
    num_envs: int = option(4, "worlds run together", check=(lambda v: v >= 1, "a positive integer"))
    seed: int = option(
        0,
        "seed of the envs (and the random agent); the same for every policy, so they face the same draws",
        check=cli.SEED,
    )
    worlds: str = option(
        "test",
        "which of the seed's worlds: test (held out: every published number) or validation "
        "(the ones to choose settings on); never training worlds (evaaa/worlds.py)",
        choices=lambda: ["test", "validation"],
    )
    out: str = option("outputs/eval", "output directory")
    include: list[str] = option(
        [],
        "episode CSV files to add to the report (e.g. human play records of scripts/play.py)",
        check=(lambda p: Path(p).is_file(), "existing files"),
    )
    modalities: list[str] | None = option(
        None,
        "for checkpoints: the observation keys to evaluate with (default: "
        "those it was trained on; a checkpoint trained on others is refused)",
        choices=lambda: evaaa.MODALITIES,
    )
    sample: bool = option(
        False,
        "for checkpoints: sample actions from the policy's distribution (PPO, DreamerV3) "
        "instead of taking the most likely one; said in summary.md",
    )
    epsilon: float = option(
        0.0,
        "for checkpoints: chance of a uniformly random action at each step (0: the "
        "policy's own action; 0.05 is DQN's customary evaluation epsilon); said in "
        "summary.md",
        check=(lambda v: 0.0 <= v <= 1.0, "a number in [0, 1]"),
    )
    step_log: bool = option(
        False,
        "also write a per-step behaviour log, out/steps-<UTC time>.csv (one row per "
        "world and decision: evaaa.records.STEP_FIELDS)",
    )
    threads: int | None = option(
        None,
        "torch intra-op threads (null: torch's default), as train.py's threads=",
        check=(lambda v: v >= 1, "a positive integer"),
    )
    device: str = option(
        "auto",
        "for checkpoints: where the networks run: auto (CUDA when available), cpu, cuda or "
        "cuda:N; the worlds stay on the CPU",
        check=(lambda v: re.fullmatch(r"auto|cpu|cuda(:\d+)?", v) is not None, "auto, cpu, cuda or cuda:N"),
    )


HELP = {
    "prog": "evaluate.py",
    "description": __doc__.split("\n\n")[0],
    "examples": [
        "policy=[oracle,random] levels=testbeds episodes=20",
        "policy=[runs/1-1/ppo/all-squared/seed0/model-0-1-1.pt,random] levels=[1-1] sample=true",
    ],
}
if __name__ == "__main__":
    cli.help_first(EvalConfig, **HELP)  # before the reports' libraries (pandas, matplotlib, scipy) load

from evaaa_baselines.reports import (  # noqa: E402
    SUMMARY_NOTE,
    markdown_table,
    plot_outcomes,
    plot_summary,
    read_episodes,
    summarize,
)


def parse(argv: list[str] | None = None) -> EvalConfig:
    """The config from ``key=value`` arguments (``--help`` lists the keys); level groups expanded, in order."""
    cfg = cli.parse(EvalConfig, argv, **HELP)
    given = cli.given(sys.argv[1:] if argv is None else argv, "levels")
    levels: list[str] = []
    for name in cfg.levels:
        levels += [level for level in _levels(name, given) if level not in levels]
    cfg.levels = levels
    # a device this machine lacks is refused now, before out= is made (torch loads here, not for --help)
    from evaaa_baselines.devices import DeviceError, resolve_device

    try:
        resolve_device(cfg.device)
    except DeviceError as err:
        cli.fail("evaluate.py", str(err))
    return cfg


#: the file each level of your own was read from, by its name
OWN_FILES: dict[str, Path] = {}


def _levels(name: str, given: str) -> tuple[str, ...]:
    """The levels ``name`` of ``levels=`` stands for: a group's, a packaged level, or the level of a file of your own
    (registered, so that its name loads; checked now, before anything is written).  A name that is none of them
    exits 2 in one line, naming the closest names."""
    if name in GROUPS:
        return tuple(GROUPS[name])
    if name in (*evaaa.LEVELS, *evaaa.TESTBEDS):
        return (name,)
    if name.endswith((".yaml", ".yml")):
        from evaaa_baselines.config import ConfigError, level_file

        try:
            level = level_file(name, "levels")
        except ConfigError as err:
            cli.fail("evaluate.py", str(err))
        OWN_FILES[level] = Path(name).resolve()
        return (level,)
    names = [*evaaa.LEVELS, *evaaa.TESTBEDS, *GROUPS]
    cli.fail(
        "evaluate.py",
        f"levels={given}: '{name}' is not allowed{cli.did_you_mean(name, names)}; allowed: {', '.join(names)}, "
        f"or {OWN_LEVEL}",
    )


def episodes(summary) -> str:
    """How many episodes each bar of a figure stands for, for its title."""
    counts = sorted(set(summary["episodes"]))
    return f"{counts[0]} episodes per bar" if len(counts) == 1 else f"{counts[0]}–{counts[-1]} episodes per bar"


def _writable(out: Path) -> None:
    """Fail now, not after the episodes, where ``out`` cannot take files: a real write of 64 KiB made durable
    (root passes permission checks yet cannot write a read-only mount, and a full disk still creates empty files)."""
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=out, prefix=".write-test-") as probe:
            probe.write(bytes(64 * 1024))
            probe.flush()
            os.fsync(probe.fileno())
    except OSError as exc:
        raise DiskError(out, exc) from None


def _check_episodes(path: Path, policies: list[EvaluatedPolicy], cfg: EvalConfig) -> None:
    """Refuse (SystemExit) an ``episodes.csv`` that is not every episode this command asks for."""
    rows = read_rows(path)
    counts = Counter((r["policy"], r["acting"], r["level"], r["seed"], r.get("worlds")) for r in rows)
    wanted = {
        (p.name, p.acting, level, str(cfg.seed), cfg.worlds): cfg.episodes for p in policies for level in cfg.levels
    }
    if counts != wanted:
        missing = [f"{key[0]} on {key[2]}" for key, n in wanted.items() if counts.get(key) != n]
        raise SystemExit(
            f"evaluate.py: {path} holds other episodes than this command's ({len(rows)} rows; "
            f"not as asked: {', '.join(missing[:3]) or 'episodes of other policies or levels'}); "
            "nothing was changed: choose another out=, or repeat the command that made it"
        )


def _atomic(path: Path, write) -> Path:
    """``write(tmp)`` then rename ``tmp`` to ``path``: a full disk leaves no half-written file under its name."""
    tmp = path.with_name(f".{path.stem}.partial{path.suffix}")
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException as exc:
        tmp.unlink(missing_ok=True)
        error = disk_error(path, exc) if isinstance(exc, OSError) else None
        if error is None:
            raise
        raise error from None
    return path


def main(argv: list[str] | None = None) -> int:
    cfg = parse(argv)
    out = Path(cfg.out)
    earlier = [name for name in OUTPUTS if (out / name).exists()]
    # episodes.csv without summary.md: killed while the summary was written; the same command completes it
    completing = bool(earlier) and "episodes.csv" in earlier and "summary.md" not in earlier
    if earlier and not completing:
        # appending would pool two evaluations (n doubles, the standard error shrinks); replacing would lose one
        raise SystemExit(
            f"evaluate.py: {out} already holds an evaluation ({', '.join(earlier)}); nothing was "
            "changed: choose another out=, or move those files away first"
        )
    import torch

    from evaaa_baselines.evaluation import EvaluatedPolicy, EvaluationError

    if cfg.threads is not None:
        torch.set_num_threads(cfg.threads)
    try:  # before out= is made: a policy refused leaves nothing behind
        policies = [
            EvaluatedPolicy(spec, cfg.seed, cfg.modalities, cfg.epsilon, cfg.sample, cfg.device) for spec in cfg.policy
        ]
    except EvaluationError as err:
        cli.fail("evaluate.py", str(err))
    made = not out.exists()
    try:
        _writable(out)
    except DiskError as err:
        if made and out.is_dir() and not any(out.iterdir()):
            out.rmdir()
        raise SystemExit(f"evaluate.py: {err}; nothing was written, no episode was played") from None
    if completing:
        _check_episodes(out / "episodes.csv", policies, cfg)
        print(f"{out / 'episodes.csv'} holds every episode of this evaluation: writing its summary and figures")
    else:
        try:
            _run_episodes(cfg, policies, out)
        except DiskError as err:
            raise SystemExit(
                f"evaluate.py: {err}; no episodes.csv was written (run the command again once the disk takes writes)"
            ) from None
        except SystemExit:  # an episode refused (EvaluationError): a folder this command made stays only if used
            if made and out.is_dir() and not any(out.iterdir()):
                out.rmdir()
            raise
    try:
        written, table = _summarize(cfg, out)
    except OSError as err:
        if err.errno not in DISK_ERRNOS:
            raise
        raise SystemExit(
            f"evaluate.py: {disk_error(err.filename or out, err)}; episodes.csv is complete: the same "
            "command writes the summary and figures once the disk takes writes"
        ) from None
    print(table)
    print("\nwrote " + ", ".join(str(p) for p in written))
    return 0


def _run_episodes(cfg: EvalConfig, policies: list[EvaluatedPolicy], out: Path) -> None:
    from evaaa_baselines.evaluation import EvaluationError, episode_records

    total = len(policies) * len(cfg.levels) * cfg.episodes
    # episodes go to a hidden file until the last one is done: an interrupted evaluation leaves no episodes.csv
    partial = out / ".episodes.csv.partial"
    partial.unlink(missing_ok=True)  # an earlier interrupted evaluation's
    step_log = StepLog(new_log_path(out)) if cfg.step_log else None
    try:
        with tqdm(total=total, desc="episodes", unit="ep", dynamic_ncols=True) as bar:
            for policy in policies:
                for level in cfg.levels:
                    bar.set_postfix_str(f"{policy.name} on {level}")
                    try:
                        rows = episode_records(
                            policy,
                            level,
                            episodes=cfg.episodes,
                            num_envs=cfg.num_envs,
                            seed=cfg.seed,
                            worlds=cfg.worlds,
                            step_log=step_log,
                            on_episode=lambda: bar.update(1),
                        )
                    except EvaluationError as err:
                        raise SystemExit(f"evaluate.py: {err}") from None
                    append_rows(partial, rows)
        os.replace(partial, out / "episodes.csv")
    except DiskError:
        partial.unlink(missing_ok=True)
        raise
    finally:
        if step_log is not None:
            step_log.close()
    if step_log is not None:
        print(f"step log: {step_log.path}")


def _summarize(cfg: EvalConfig, out: Path) -> tuple[list[Path], str]:
    """summary.md and the figures from ``out/episodes.csv``; summary.md last, so that it marks a complete
    evaluation."""
    rows = read_episodes([out / "episodes.csv", *cfg.include])
    rows = rows[rows["level"].isin(cfg.levels)]
    summary = summarize(rows)
    table = markdown_table(summary)
    written = [out / "episodes.csv"]
    # a level of your own is drawn with the testbeds where it has a success rule, else with the training levels
    own, judged = ~summary["level"].isin((*evaaa.LEVELS, *evaaa.TESTBEDS)), summary["success_rate"].notna()
    tests = summary[summary["level"].isin(evaaa.TESTBEDS) | (own & judged)]
    if len(tests):
        written.append(
            _atomic(
                out / "success.png",
                lambda p: plot_summary(tests, p, success=True, title=f"Success per testbed ({episodes(tests)})"),
            )
        )
    training = summary[summary["level"].isin(evaaa.LEVELS) | (own & ~judged)]
    if len(training):
        written.append(
            _atomic(
                out / "survival.png",
                lambda p: plot_summary(
                    training, p, success=False, title=f"Survival per training level ({episodes(training)})"
                ),
            )
        )
    written.append(_atomic(out / "outcomes.png", lambda p: plot_outcomes(rows, p)))
    text = (
        f"# Evaluation ({cfg.episodes} episodes per level and policy, {cfg.worlds} worlds of seed {cfg.seed}"
        + ("; checkpoints sample their actions (DQN's act greedily: it has no distribution)" if cfg.sample else "")
        + (f"; checkpoints act epsilon-greedily, epsilon {cfg.epsilon:g}" if cfg.epsilon else "")
        + ")\n\n"
        + "".join(f"Level {name}: the file {OWN_FILES[name]}.\n\n" for name in cfg.levels if name in OWN_FILES)
        + SUMMARY_NOTE
        + "\n\n"
        + table
        + "\n"
    )
    written.insert(1, _atomic(out / "summary.md", lambda p: p.write_text(text)))
    return written, table


if __name__ == "__main__":
    sys.exit(main())
