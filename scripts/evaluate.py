"""Evaluate policies on testbeds and training levels: episode records, a table and figures.

    python scripts/evaluate.py policy=[oracle,random,still] levels=testbeds episodes=20
    python scripts/evaluate.py policy=runs/ppo-1-1/checkpoint.pt levels=[1-1,two-resource-food] episodes=20
    python scripts/evaluate.py policy=[zoo:ppo-1-1,random,still] levels=[1-1] episodes=20   # a shipped network
    python scripts/evaluate.py policy=py:my_agent.py:policy levels=[1-1] episodes=20       # a policy of your own

Episodes are played on the test worlds of ``seed`` (evaaa/worlds.py: no training run of any seed steps them, and the
periodic evaluations during training use other worlds again, the validation worlds); ``worlds=validation`` plays
those instead, for choosing settings.  Published numbers come from test worlds.

A policy of your own is ``py:<module>:<name>`` or ``py:<file.py>:<name>``: a TorchRL module, a Stable-Baselines3
model or a callable (docs/evaluation.md, "Your own agent"); random and still play beside it unless ``references``
says otherwise.  Only such a ``policy=`` typed on the command line runs code: checkpoints, level files and episode
files are read as data.

Arguments are ``key=value`` (lists as ``[a,b]``), the keys of :class:`EvalConfig`; ``--help`` lists them with their
types, defaults and meanings.

Writes to ``out``, which must not hold an earlier evaluation (it is refused, changing nothing: each evaluation is a
complete result of its own; one stopped after its ``episodes.csv`` and before its ``summary.md``, which is written
last, is completed by the same command): ``episodes.csv`` (one row per episode, put in place once every episode is
done),
``summary.md`` (per testbed the success rate with its 95 % Wilson interval, per training level the interquartile
mean survival with its 95 % bootstrap interval beside mean ± standard error, one column per policy), ``success.png``,
``survival.png`` and ``outcomes.png`` (what the agent did: consumed the right or wrong resource, died of which
EV, ran out of time; mean collisions).  The episodes are played and written by :mod:`evaaa_baselines.evaluation`
(:func:`~evaaa_baselines.evaluation.write_evaluation`, which :func:`~evaaa_baselines.evaluation.score` also calls),
the summary and figures made by :mod:`evaaa_baselines.reports`.
"""

from __future__ import annotations

import re
import sys
from dataclasses import dataclass
from pathlib import Path

import evaaa
from evaaa_baselines import cli
from evaaa_baselines.cli import option

OWN_POLICY = "py:MODULE:NAME or py:FILE.py:NAME (a policy of your own)"


@dataclass
class EvalConfig:
    policy: list[str] = option(
        ["oracle", "random", "still"],
        "oracle, random, still (stands still), a checkpoint file of a baseline, zoo:NAME (a shipped network: "
        f"scripts/zoo.py lists them), or {OWN_POLICY}: a TorchRL module, a Stable-Baselines3 model or a callable, "
        "imported because this command names it; a list evaluates each",
        check=(
            lambda spec: cli.policy_ok(spec, own=True),
            f"oracle, random, still, zoo:NAME, an existing checkpoint file or {OWN_POLICY}",
        ),
    )
    references: list[str] | None = option(
        None,
        "reference agents played beside the policies, on the same worlds (null: random and still where policy names "
        "a policy of your own, none otherwise)",
        choices=("oracle", "random", "still"),
    )
    levels: list[str] = option(
        ["testbeds"],
        f"level and testbed names ({', '.join((*evaaa.LEVELS, *evaaa.TESTBEDS))}), the groups testbeds, training, "
        f"all, or {cli.OWN_LEVEL}; episodes.csv names a file's level by its stem, as train.py level=file does",
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
        "for checkpoints and policies of your own: the observation keys to evaluate with (default: those a "
        "checkpoint or SB3 model was trained on, every sense for other policies; a checkpoint trained on others is "
        "refused)",
        choices=lambda: evaaa.MODALITIES,
    )
    sample: bool = option(
        False,
        "for checkpoints, TorchRL modules and SB3 models: sample actions from the policy's distribution (PPO, "
        "DreamerV3) instead of taking the most likely one; said in summary.md",
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
        "policy=py:my_agent.py:policy levels=[1-1,two-resource-food] out=outputs/eval-mine",
    ],
}
if __name__ == "__main__":
    cli.help_first(EvalConfig, **HELP)  # before torch and the reports' libraries (pandas, matplotlib, scipy) load


#: the file each level of your own was read from, by its name
OWN_FILES: dict[str, Path] = {}


def parse(argv: list[str] | None = None) -> EvalConfig:
    """The config from ``key=value`` arguments (``--help`` lists the keys); level groups expanded, in order."""
    cfg = cli.parse(EvalConfig, argv, **HELP)
    # torch loads here, not for --help: a level file, and a device this machine lacks, are refused before out= is made
    from evaaa_baselines.devices import DeviceError, resolve_device
    from evaaa_baselines.evaluation import EvaluationError, expand_levels

    try:
        cfg.levels, files = expand_levels(cfg.levels, cli.given(sys.argv[1:] if argv is None else argv, "levels"))
    except EvaluationError as err:
        cli.fail("evaluate.py", str(err))
    OWN_FILES.update(files)
    try:
        resolve_device(cfg.device)
    except DeviceError as err:
        cli.fail("evaluate.py", str(err))
    return cfg


def references(cfg: EvalConfig) -> list[str]:
    """The reference agents played beside ``cfg.policy``: ``references`` as given, or (null) random and still where a
    policy of your own is evaluated; those the policy list names already are not played twice."""
    from evaaa_baselines.evaluation import SCORE_REFERENCES, is_own

    chosen = cfg.references
    if chosen is None:
        chosen = list(SCORE_REFERENCES) if any(is_own(p) for p in cfg.policy) else []
    return [r for r in dict.fromkeys(chosen) if r not in cfg.policy]


def main(argv: list[str] | None = None) -> int:
    cfg = parse(argv)
    from evaaa_baselines.evaluation import EvaluationError, OwnPolicy, earlier_evaluation, own_note, player

    try:
        completing = earlier_evaluation(cfg.out)
    except EvaluationError as err:
        raise SystemExit(f"evaluate.py: {err}") from None
    import torch

    if cfg.threads is not None:
        torch.set_num_threads(cfg.threads)
    extra = references(cfg)
    try:  # before out= is made: a policy refused leaves nothing behind
        players = [
            player(spec, cfg.seed, modalities=cfg.modalities, epsilon=cfg.epsilon, sample=cfg.sample, device=cfg.device)
            for spec in [*cfg.policy, *extra]
        ]
    except EvaluationError as err:
        cli.fail("evaluate.py", str(err))
    notes = [own_note(p, extra) for p in players if isinstance(p, OwnPolicy)]
    from evaaa_baselines.evaluation import write_evaluation

    try:
        result = write_evaluation(
            players,
            cfg.levels,
            cfg.out,
            episodes=cfg.episodes,
            num_envs=cfg.num_envs,
            seed=cfg.seed,
            worlds=cfg.worlds,
            include=cfg.include,
            step_log=cfg.step_log,
            level_files=OWN_FILES,
            sample=cfg.sample,
            epsilon=cfg.epsilon,
            notes=notes,
            completing=completing,
        )
    except EvaluationError as err:
        raise SystemExit(f"evaluate.py: {err}") from None
    print(result.table)
    print("\nwrote " + ", ".join(str(p) for p in result.files))
    return 0


if __name__ == "__main__":
    sys.exit(main())
