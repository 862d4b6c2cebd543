"""Evaluate policies on testbeds and training levels: episode records, a table and figures.

    python scripts/evaluate.py policy=[oracle,random] levels=testbeds episodes=20
    python scripts/evaluate.py policy=runs/ppo-1-1/checkpoint.pt levels=[1-1,two-resource-food] episodes=20

Arguments (``key=value``, lists as ``[a,b]``):
    policy     oracle, random, or a checkpoint path of a baseline; a list evaluates each (default [oracle,random])
    levels     level and testbed names, or testbeds / training / all (default testbeds)
    episodes   episodes per level and policy (default 20)
    num_envs   worlds run together (default 4)
    seed       seed of the envs (and the random agent); the same for every policy, so they face the same draws
    out        output directory (default outputs/eval)
    include    episode CSV files to add to the report (e.g. human play records from scripts/play.py)
    modalities for checkpoints: observation keys to evaluate with; a checkpoint trained on others is refused
    sample     for checkpoints: act by sampling from the policy's action distribution (PPO, DreamerV3) instead of
               taking its most likely action (default false); said in summary.md
    epsilon    for checkpoints: chance of a uniformly random action at each step (default 0: the policy's
               deterministic action; 0.05 is DQN's customary evaluation epsilon); said in summary.md
    device     for checkpoints: where the networks run, auto (CUDA when available), cpu, cuda or cuda:N (default auto)

Writes to ``out``: ``episodes.csv`` (one row per episode, appended), ``summary.md`` (success rate ± standard
error per testbed, mean survival ± standard error per training level, one column per policy), ``success.png``,
``survival.png`` and ``outcomes.png`` (what the agent did: consumed the right or wrong resource, died of which
EV, ran out of time; mean collisions).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException
from tqdm import tqdm

import evaaa
from evaaa.agents import OracleAgent, RandomAgent
from evaaa.analysis import markdown_table, plot_bars, plot_outcomes, read_episodes, summarize
from evaaa.records import EpisodeTracker, append_rows

GROUPS = {"testbeds": evaaa.TESTBEDS, "training": evaaa.LEVELS, "all": evaaa.LEVELS + evaaa.TESTBEDS}


@dataclass
class EvalConfig:
    policy: list[str] = field(default_factory=lambda: ["oracle", "random"])
    levels: list[str] = field(default_factory=lambda: ["testbeds"])
    episodes: int = 20
    num_envs: int = 4
    seed: int = 0
    out: str = "outputs/eval"
    include: list[str] = field(default_factory=list)
    #: for checkpoints: the observation keys to evaluate with (default: those it was trained on)
    modalities: list[str] | None = None
    #: for checkpoints: sample actions from the policy's distribution instead of taking the most likely one
    sample: bool = False
    #: for checkpoints: chance of a uniformly random action at each step (0: deterministic)
    epsilon: float = 0.0
    #: for checkpoints: where the networks run (auto, cpu, cuda, cuda:N); the worlds stay on the CPU
    device: str = "auto"


def parse(argv: list[str]) -> EvalConfig:
    """``key=value`` arguments over the defaults; single values where lists are expected become lists."""
    schema = OmegaConf.structured(EvalConfig)
    given = OmegaConf.from_dotlist(argv)
    for key in ("policy", "levels", "include", "modalities"):
        if key in given and not OmegaConf.is_list(given[key]):
            given[key] = [given[key]]
    try:
        cfg = OmegaConf.to_object(OmegaConf.merge(schema, given))
    except OmegaConfBaseException as err:
        allowed = ", ".join(EvalConfig.__dataclass_fields__)
        raise SystemExit(f"evaluate.py: {err.msg if hasattr(err, 'msg') else err}\n  allowed keys: {allowed}")
    levels: list[str] = []
    for name in cfg.levels:
        for level in GROUPS.get(name, (name,)):
            if level not in evaaa.LEVELS + evaaa.TESTBEDS:
                raise SystemExit(f"evaluate.py: unknown level {level!r}; available: "
                                 f"{', '.join(evaaa.LEVELS + evaaa.TESTBEDS)} or {', '.join(GROUPS)}")
            if level not in levels:
                levels.append(level)
    cfg.levels = levels
    if cfg.episodes < 1 or cfg.num_envs < 1:
        raise SystemExit("evaluate.py: episodes and num_envs must be positive")
    if not 0.0 <= cfg.epsilon <= 1.0:
        raise SystemExit(f"evaluate.py: epsilon must be in [0, 1], got {cfg.epsilon}")
    for path in cfg.include:
        if not Path(path).is_file():
            raise SystemExit(f"evaluate.py: include file {path} does not exist")
    return cfg


class Policy:
    """One policy to evaluate: builds the env for a level and picks actions for a batch of worlds."""

    def __init__(self, spec: str, seed: int, modalities: list[str] | None = None, epsilon: float = 0.0,
                 sample: bool = False, device: str = "cpu"):
        self.spec = spec
        self.seed = seed
        self.epsilon = epsilon
        self.sample = sample
        self.rng = torch.Generator().manual_seed(seed)  # epsilon's draws: the same for every run of the command
        self.loaded = None
        if spec not in ("oracle", "random"):
            path = Path(spec)
            if not path.is_file():
                raise SystemExit(f"evaluate.py: policy {spec!r} is neither oracle, random nor a checkpoint file")
            from baselines.evaluation import load_policy

            try:
                self.loaded = load_policy(path, modalities=modalities, device=device)
            except ValueError as err:
                raise SystemExit(f"evaluate.py: {err}") from None
        # a checkpoint is named by its path: reports look the run's configuration up from it
        self.name = spec if self.loaded is None else str(path)
        # how it acts, recorded with every episode so that evaluations made in different ways stay apart
        self.acting = "" if self.loaded is None else (
            "sample" if sample else "mode") + (f"+epsilon={epsilon:g}" if epsilon else "")

    def make_env(self, level: str, num_envs: int, seed: int):
        if self.loaded is not None:
            try:
                return self.loaded.make_env(level, num_envs=num_envs, seed=seed, overrides={})
            except ValueError as err:
                raise SystemExit(f"evaluate.py: {err}") from None
        self.agent = OracleAgent() if self.spec == "oracle" else RandomAgent(seed)
        return evaaa.make_env(level, num_envs=num_envs, seed=seed, modalities=["interoception"])

    def act(self, env, td):
        if self.loaded is not None:
            action = self.loaded(td, deterministic=not self.sample)["action"]
            if self.epsilon > 0:  # epsilon-greedy evaluation: a uniformly random action instead, now and then
                explore = torch.rand(action.shape, generator=self.rng) < self.epsilon
                other = torch.randint(0, len(evaaa.ACTION_NAMES), action.shape, generator=self.rng)
                action = torch.where(explore, other, action)
            return action
        sim = env.sim if hasattr(env, "sim") else env.base_env.sim
        return torch.from_numpy(self.agent.act(sim))


def run_level(policy: Policy, level: str, cfg: EvalConfig, bar: tqdm) -> list[dict]:
    env = policy.make_env(level, cfg.num_envs, cfg.seed)
    torch.manual_seed(cfg.seed)  # sampled actions (sample=true) repeat from run to run
    n = cfg.num_envs
    quota = np.full(n, cfg.episodes // n) + (np.arange(n) < cfg.episodes % n)  # episodes each world runs
    tracker = EpisodeTracker(n, level, policy.name, seed=cfg.seed, acting=policy.acting)
    rows: list[dict] = []
    td = env.reset()
    done_count = np.zeros(n, dtype=int)
    while (done_count < quota).any():
        td["action"] = policy.act(env, td).reshape(env.action_spec.shape)
        step, td = env.step_and_maybe_reset(td)
        nxt = step["next"]
        info = {k: v.reshape(n, -1) for k, v in nxt["info"].items()}
        done = nxt["done"].reshape(n).numpy()
        finished = tracker.update(nxt["reward"].reshape(n).numpy(), info, done)
        for w, row in zip(np.flatnonzero(done), finished):  # rows come in the order of the finished worlds
            if done_count[w] < quota[w]:  # a world's episodes beyond its quota are not counted
                rows.append(row)
                bar.update(1)
            done_count[w] += 1
    env.close()
    for i, row in enumerate(rows):
        row["episode"] = i
    return rows


def main(argv: list[str] | None = None) -> int:
    cfg = parse(sys.argv[1:] if argv is None else argv)
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    policies = [Policy(spec, cfg.seed, cfg.modalities, cfg.epsilon, cfg.sample, cfg.device) for spec in cfg.policy]
    total = len(policies) * len(cfg.levels) * cfg.episodes
    with tqdm(total=total, desc="episodes", unit="ep", dynamic_ncols=True) as bar:
        for policy in policies:
            for level in cfg.levels:
                bar.set_postfix_str(f"{policy.name} on {level}")
                append_rows(out / "episodes.csv", run_level(policy, level, cfg, bar))
    rows = read_episodes([out / "episodes.csv", *cfg.include])
    rows = rows[rows["level"].isin(cfg.levels)]
    summary = summarize(rows)
    table = markdown_table(summary)
    (out / "summary.md").write_text(
        f"# Evaluation ({cfg.episodes} episodes per level and policy, seed {cfg.seed}"
        + ("; checkpoints sample their actions" if cfg.sample else "")
        + (f"; checkpoints act epsilon-greedily, epsilon {cfg.epsilon:g}" if cfg.epsilon else "") + ")\n\n"
        "Testbeds: success rate ± standard error; training levels: mean survival (decisions) ± standard error.\n\n"
        + table + "\n")
    written = [out / "episodes.csv", out / "summary.md"]
    tests = summary[summary["level"].isin(evaaa.TESTBEDS)]
    if len(tests):
        written.append(plot_bars(tests, "success_rate", "success_se", out / "success.png", scale=100,
                                 ylabel="success rate (%)", title="Success per testbed"))
    training = summary[summary["level"].isin(evaaa.LEVELS)]
    if len(training):
        written.append(plot_bars(training, "survival", "survival_se", out / "survival.png",
                                 ylabel="survival (decisions)", title="Survival per training level"))
    written.append(plot_outcomes(rows, out / "outcomes.png"))
    print(table)
    print("\nwrote " + ", ".join(str(p) for p in written))
    return 0


if __name__ == "__main__":
    sys.exit(main())
