"""Reports: every figure is built from small run directories and evaluation files written here by hand, and the
numbers in the report's tables are computed here from those inputs (interquartile means, Wilson intervals, means and
standard errors across seeds; the bootstrap interval from evaaa_baselines.reports.stats, tested on its own, over
the strata assembled here); missing, partial
and orphaned inputs are listed; bad input gives clear errors; the launcher presets compose; a modality ablation
removes a key and nothing else."""

from __future__ import annotations

import csv
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from helpers import load_script
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

import evaaa
from evaaa.records import TRAINING_EPISODE_FIELDS, append_rows
from evaaa_baselines.config import observation_keys, register_levels
from evaaa_baselines.logs import EVAL_COLUMNS_BEFORE_CPU
from evaaa_baselines.paper.choice import ChoiceError
from evaaa_baselines.paper.report import build_report
from evaaa_baselines.paths import CONF_DIR
from evaaa_baselines.reports import ReportError
from evaaa_baselines.reports.stats import clustered_rate, interval

register_levels()

ROOT = Path(__file__).resolve().parents[1]
STAGES = ("1-1", "1-2")
BUDGET = 100  # env steps per stage
TESTBEDS = ("two-resource-food", "y-maze")
#: eval.csv as training runs wrote it before evaluations kept one row per episode: one mean per evaluation
OLD_EVAL_COLUMNS = (
    "env_steps",
    "stage",
    "level",
    "episodes",
    "survival_mean",
    "survival_min",
    "survival_max",
    "return_mean",
    "end_types",
    "wall_time",
)
FIGURES = (
    "fig4a_survival_per_level.png",
    "fig4a_curriculum_vs_direct.png",
    "fig4b_success_per_testbed.png",
    "fig4b_generalisation.png",
    "fig_training_curves.png",
    "fig_evaluation_curves.png",
    "fig25_ablation_curves.png",
    "fig26_ablation_success.png",
)


# ------------------------------------------------------------------------------------------------ inputs
def make_cfg(*overrides: str, hydra: bool = False):
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        return compose("config", overrides=list(overrides), return_hydra_config=hydra)


def write_csv(path: Path, columns, rows) -> None:
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(columns))
        writer.writeheader()
        writer.writerows(rows)


class Sim:
    """Writes run directories as scripts/train.py leaves them (the real composed config, CSVs, empty model files)
    and keeps the numbers it wrote, so the tests can compute what the report must say."""

    def __init__(self, root: Path, seed: int = 0):
        self.root, self.rng = root, np.random.default_rng(seed)
        self.runs: dict[Path, dict] = {}

    def run(
        self,
        algo: str,
        seed: int,
        *,
        level: str = "curriculum",
        modality: str = "all",
        finish: int = 2,
        partial_steps: int = 0,
        files: bool = True,
        overrides: tuple[str, ...] = (),
        budget: int = BUDGET,
    ) -> Path:
        """``finish``: stages finished (a curriculum has two, a direct run one); ``partial_steps``: env steps the
        next, unfinished stage got to; ``files``: False leaves the config alone (a run that never started);
        ``budget``: a direct run's env steps."""
        extra = (
            [f"level.stage_steps={BUDGET}", f"level.stages=[{','.join(STAGES)}]"]
            if level == "curriculum"
            else [f"total_steps={budget}"]
        )
        cfg = make_cfg(
            f"algo={algo}",
            f"seed={seed}",
            f"level={level}",
            f"modality={modality}",
            "preset=debug",
            "logger=csv",
            *extra,
            *overrides,
        )
        run_dir = self.root / OmegaConf.to_container(cfg, resolve=True)["run"]["name"]
        (run_dir / ".hydra").mkdir(parents=True)
        OmegaConf.save(cfg, run_dir / ".hydra" / "config.yaml")  # as Hydra saves it: interpolations kept
        stages = STAGES if level == "curriculum" else (level,)
        info = {
            "algo": algo,
            "seed": seed,
            "modality": modality,
            "level": level,
            "stages": stages,
            "final": {},
            "episodes": [],
        }
        self.runs[run_dir] = info
        if not files:
            return run_dir
        episodes, evals = [], []
        for index, name in enumerate(stages):
            if index > finish:
                break
            end = (BUDGET if level == "curriculum" else budget) if index < finish else partial_steps
            for step in np.linspace(end / 5, end, 5).astype(int)[: -1 if index == finish else None]:
                survival = int(self.rng.integers(10, 400))
                episodes.append(
                    {
                        "env_steps": step,
                        "stage": index,
                        "level": name,
                        "episode": len(episodes) + 1,
                        "world": 0,
                        "steps": survival,
                        "return": -1.5,
                        "end_type": "FoodOutOfRange",
                        "final_satiation": -15.1,
                        "final_hydration": 0.0,
                        "final_temperature": 0.0,
                        "final_damage": 0.0,
                        "wall_time": "2026-01-01T00:00:00",
                    }
                )
                info["episodes"].append((index * BUDGET + step, survival))
            for step in (end // 2, end):
                if step == 0:
                    continue
                value = round(float(self.rng.uniform(20, 300)), 2)
                evals.append(
                    {
                        "env_steps": step,
                        "stage": index,
                        "level": name,
                        "episodes": 2,
                        "survival_mean": value,
                        "survival_min": 1,
                        "survival_max": 400,
                        "return_mean": -1,
                        "end_types": "FoodOutOfRange;FoodOutOfRange",
                        "wall_time": "2026-01-01T00:00:00",
                    }
                )
                if index < finish and step == end:
                    info["final"][name] = value
            if index < finish:
                (run_dir / f"model-{index}-{name}.pt").touch()
        write_csv(run_dir / "episodes.csv", TRAINING_EPISODE_FIELDS, episodes)
        write_csv(run_dir / "eval.csv", OLD_EVAL_COLUMNS, evals)
        (run_dir / "checkpoint.pt").touch()
        return run_dir

    def evaluate(self, policy: str, level: str, episodes: int, *, participant: str = "") -> list[dict]:
        """Episode rows of evaluate.py's format with random outcomes (success on testbeds, steps elsewhere)."""
        rows = []
        for i in range(episodes):
            success = bool(self.rng.random() < 0.5) if level in evaaa.TESTBEDS else ""
            rows.append(
                {
                    "policy": policy,
                    "participant": participant,
                    "level": level,
                    "episode": i,
                    "seed": 0,
                    "steps": int(self.rng.integers(5, 300)),
                    "return": -1.0,
                    "end_type": "MaxStepReached",
                    "success": success,
                    "food_eaten": 0,
                    "water_eaten": 0,
                    "collisions": 0,
                    "damage_taken": 0.0,
                    "attacks": 0,
                    "final_satiation": 0.0,
                    "final_hydration": 0.0,
                    "final_temperature": 0.0,
                    "final_damage": 0.0,
                }
            )
        return rows


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """Curriculum runs (ppo, dqn; a ppo no_vision ablation), direct ppo runs on each level, a dqn run killed in
    its second stage, a run that never started; evaluations of checkpoints, oracle, random, humans and one
    checkpoint whose run is gone; and the report built from all of it."""
    base = tmp_path_factory.mktemp("report")
    sim = Sim(base / "runs")
    for seed in (0, 1, 2):
        sim.run("ppo", seed)
        sim.run("dqn", seed)
        sim.run("ppo", seed, modality="no_vision")
    partial = sim.run("dqn", 3, finish=1, partial_steps=40)
    for level in STAGES:
        for seed in (0, 1):
            sim.run("ppo", seed, level=level, finish=1)
    missing = sim.run("ppo", 0, modality="no_olfaction", files=False)

    rows, evaluated = [], {}
    for run_dir, info in sim.runs.items():
        if run_dir == missing:
            continue
        if info["level"] == "curriculum":
            ckpts = [run_dir / f"model-{i}-{lv}.pt" for i, lv in enumerate(STAGES)]
            if run_dir == partial:
                ckpts = [ckpts[0], run_dir / "checkpoint.pt"]  # the latest state, in stage 1 (1-2)
            levels = list(STAGES)
        else:
            ckpts, levels = [run_dir / "checkpoint.pt"], [info["level"]]
        for ckpt, trained_to in zip(ckpts, levels):
            for testbed in TESTBEDS:
                part = sim.evaluate(str(ckpt), testbed, 4)
                evaluated[(run_dir, trained_to, testbed)] = [r["success"] for r in part]
                rows += part
    for testbed in TESTBEDS:
        rows += sim.evaluate("oracle", testbed, 6) + sim.evaluate("random", testbed, 6)
    rows += sim.evaluate("random", "1-1", 5)
    gone = base / "runs" / "deleted" / "seed0" / "model-0-1-1.pt"
    rows += sim.evaluate(str(gone), "y-maze", 3)
    append_rows(base / "eval" / "episodes.csv", rows)
    human = sim.evaluate("human", "two-resource-food", 3, participant="p01") + sim.evaluate(
        "human", "two-resource-food", 2, participant="p02"
    )
    append_rows(base / "human.csv", human)

    report = build_report([base / "runs"], [base / "eval", base / "human.csv"], base / "out", bins=4)
    text = report.markdown.read_text()
    return {
        "sim": sim,
        "base": base,
        "report": report,
        "text": text,
        "partial": partial,
        "missing": missing,
        "evaluated": evaluated,
        "eval_rows": rows,
        "human": human,
        "gone": gone,
    }


def stats(values) -> tuple[float, float, int]:
    """Mean, standard error of the mean (ddof 1) and count, computed here from the inputs."""
    v = np.asarray(values, dtype=float)
    return v.mean(), (v.std(ddof=1) / np.sqrt(len(v)) if len(v) > 1 else float("nan")), len(v)


def hand_iqm(values) -> float:
    """Interquartile mean by its definition: sort, drop a quarter (rounded down) at each end, average the rest."""
    v = np.sort(np.asarray(values, dtype=float))
    cut = len(v) // 4
    return float(v[cut : len(v) - cut].mean())


def wilson(k: int, n: int, z: float = 1.959963984540054) -> tuple[float, float]:
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z / (1 + z * z / n) * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return centre - half, centre + half


def size(samples, unit: str, means_of: int | None = None) -> str:
    n, episodes = len(samples), sum(len(s) for s in samples)
    if unit == "episodes":
        return f"{episodes} ep."
    word = unit if n != 1 else unit[:-1]
    if means_of:
        return f"{n} {word} × mean of {means_of} ep."
    return f"{n} {word} × {episodes // n} ep." if episodes % n == 0 else f"{n} {word}, {episodes} ep."


def expect(samples, unit: str = "seeds", *, per_seed: int | None = None) -> str:
    """The survival cell for ``samples`` (one list of episode survivals per seed, or per participant; ``unit``
    ``episodes``: one list, a reference agent's episodes, each its own unit): ``IQM [95 % bootstrap]; mean ± se
    (n=…)`` from three units on, ``IQM; seeds a, b (n=…)`` under three.  ``per_seed``: each seed gave one number
    (an evaluation's mean) over this many episodes."""
    samples = [list(map(float, s)) for s in samples]
    pooled = [v for s in samples for v in s]
    units = [[v] for v in pooled] if unit == "episodes" else samples
    text = f"{hand_iqm(pooled):.1f}"
    if len(units) >= 3:
        est = interval(units, "iqm")
        m, se, _ = stats([np.mean(s) for s in units])
        text += f" [{est.low:.1f}, {est.high:.1f}]; {m:.1f} ± {se:.1f}"
    else:
        text += f"; {unit} " + ", ".join(f"{np.mean(s):.1f}" for s in units)
    return f"{text} (n={size(samples, unit, per_seed)})"


def expect_rate(samples, unit: str = "seeds") -> str:
    """The success cell for ``samples`` (one list of outcomes per seed or participant; ``unit`` ``episodes``: one
    list): the pooled share with its interval — Wilson's for a reference agent's episodes, seed-clustered Wilson
    (tested in test_stats.py) from three seeds on, none under three (the seeds' rates instead)."""
    samples = [list(map(float, s)) for s in samples]
    pooled = [v for s in samples for v in s]
    text = f"{100 * np.mean(pooled):.1f}%"
    if unit == "episodes":
        low, high = wilson(int(sum(pooled)), len(pooled))
        text += f" [{100 * low:.1f}, {100 * high:.1f}]"
    elif len(samples) >= 3:
        est = clustered_rate(samples)
        text += f" [{100 * est.low:.1f}, {100 * est.high:.1f}]"
    else:
        text += f"; {unit} " + ", ".join(f"{100 * np.mean(s):.1f}%" for s in samples)
    return f"{text} (n={size(samples, unit)})"


def table(text: str, heading: str) -> dict[str, dict[str, str]]:
    """The first Markdown table after ``heading`` as {row: {column: cell}}."""
    lines = text[text.index(heading) :].splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("|"))
    header = [c.strip() for c in lines[start].strip("|").split("|")]
    out = {}
    for line in lines[start + 2 :]:
        if not line.startswith("|"):
            break
        cells = [c.strip() for c in line.strip("|").split("|")]
        out[cells[0]] = dict(zip(header[1:], cells[1:]))
    return out


def runs_of(world, **match):
    return [
        (d, info)
        for d, info in world["sim"].runs.items()
        if all(info[k] == v for k, v in match.items()) and d != world["missing"]
    ]


# ------------------------------------------------------------------------------------------------ figures
def test_every_figure_is_written_as_a_png_and_linked(world):
    out = world["base"] / "out"
    for name in FIGURES:
        data = (out / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5_000, name
        assert f"]({name})" in world["text"], name
    assert sorted(p.name for p in world["report"].figures) == sorted(FIGURES)


# ------------------------------------------------------------------------------------------------ Fig. 4a
def test_survival_per_level_is_the_mean_and_se_across_seeds_of_each_stage_final_evaluation(world):
    got = table(world["text"], "## Survival per training level")
    for label, algo, modality in (
        ("ppo · curriculum", "ppo", "all"),
        ("dqn · curriculum", "dqn", "all"),
    ):
        for level in STAGES:
            values = [
                [info["final"][level]]
                for _, info in runs_of(world, algo=algo, modality=modality, level="curriculum")
                if level in info["final"]
            ]
            assert got[level][label] == expect(values, per_seed=2), (label, level)
    # the run killed in stage 2 counts for the level it finished, not for the one it did not
    assert "(n=4 seeds × mean of 2 ep.)" in got["1-1"]["dqn · curriculum"]
    assert "(n=3 seeds × mean of 2 ep.)" in got["1-2"]["dqn · curriculum"]
    section = world["text"][world["text"].index("## Survival per training level") :]
    assert "means only" in section[: section.index("| level |")]  # eval.csv of the older format: said so
    # Fig. 4a as the paper's: runs with every sense, a series per agent x curriculum/direct (the ablations: Figs. 25
    # and 26), with short labels whose other settings a table of series gives
    assert {"ppo · curriculum", "dqn · curriculum"} <= set(got["1-1"])
    assert not any("no_vision" in k for k in got["1-1"])
    assert "**Series.**" in section[: section.index("## With and without")]


def test_the_tables_say_how_the_in_training_evaluations_acted(world, tmp_path):
    def title(text: str) -> str:
        section = text[text.index("## Survival per training level") :]
        return section[: section.index("| level |")]

    assert "Acting: `mode`" in title(world["text"])  # eval.sample is false by default: the greedy action
    sim = Sim(tmp_path / "runs")
    sim.run("ppo", 0, level="1-1", finish=1, overrides=("eval.sample=true",))
    sampled = build_report([tmp_path / "runs"], [], tmp_path / "out").markdown.read_text()
    assert "Acting: `sample`" in title(sampled)
    sim.run("dqn", 0, level="1-1", finish=1, overrides=("eval.sample=true",))
    mixed = build_report([tmp_path / "runs"], [], tmp_path / "out2").markdown.read_text()
    # DQN has no action distribution: greedy whatever eval.sample says; two modes in one table are said to be so
    assert "`mode` (dqn); `sample` (ppo)" in title(mixed) and "Not one acting mode" in title(mixed)


def test_curriculum_vs_direct_compares_the_same_level(world):
    got = table(world["text"], "## With and without curriculum")
    for level in STAGES:
        curriculum = [[i["final"][level]] for _, i in runs_of(world, algo="ppo", modality="all", level="curriculum")]
        direct = [[i["final"][level]] for _, i in runs_of(world, algo="ppo", level=level)]
        assert len(direct) == 2 and got[level]["ppo · curriculum"] == expect(curriculum, per_seed=2)
        assert got[level]["ppo · direct"] == expect(direct, per_seed=2)


def test_survival_from_training_episodes_on_request(world, tmp_path):
    report = build_report([world["base"] / "runs"], [], tmp_path, survival="train", window=2)
    got = table(report.markdown.read_text(), "## Survival per training level")
    values = []
    for _, info in runs_of(world, algo="ppo", modality="all", level="curriculum"):
        stage0 = [s for step, s in info["episodes"] if step <= BUDGET]
        values.append(stage0[-2:])
    assert got["1-1"]["ppo · curriculum"] == expect(values)


# ------------------------------------------------------------------------------------------------ Fig. 4b
def success_labels():
    """(algo, modality, level) of the runs -> their label: what differs among the evaluated runs is named."""
    return {
        ("ppo", "all", "curriculum"): "ppo · all · curriculum",
        ("dqn", "all", "curriculum"): "dqn · all · curriculum",
        ("ppo", "no_vision", "curriculum"): "ppo · no_vision · curriculum",
        ("ppo", "all", "1-1"): "ppo · all · trained on 1-1",
        ("ppo", "all", "1-2"): "ppo · all · trained on 1-2",
    }


def test_success_per_testbed_uses_each_run_final_checkpoint_and_the_references(world):
    got = table(world["text"], "## Success per testbed")
    ev = world["evaluated"]
    for (algo, modality, level), label in success_labels().items():
        for testbed in TESTBEDS:
            outcomes = []
            for run_dir, info in runs_of(world, algo=algo, modality=modality, level=level):
                final = info["stages"][-1] if level == "curriculum" else level
                outcomes.append(ev[(run_dir, final, testbed)])
            assert got[testbed][label] == expect_rate(outcomes), (label, testbed)
    rows = world["eval_rows"]
    for policy in ("oracle", "random"):
        for testbed in TESTBEDS:
            values = [float(r["success"]) for r in rows if r["policy"] == policy and r["level"] == testbed]
            assert got[testbed][policy] == expect_rate([values], "episodes")
    # human: participants are the units, all their episodes pooled for the rate
    per_person = [[float(r["success"]) for r in world["human"] if r["participant"] == p] for p in ("p01", "p02")]
    assert got["two-resource-food"]["human"] == expect_rate(per_person, "participants")
    assert "(n=2 participants, 5 ep.)" in got["two-resource-food"]["human"]
    assert got["y-maze"]["human"] == "–"


def test_generalisation_averages_testbeds_per_checkpoint_then_seeds(world):
    got = table(world["text"], "## Generalisation by training level")
    ev = world["evaluated"]
    for (algo, modality, level), label in success_labels().items():
        for trained_to in STAGES:
            values = [
                [x for tb in TESTBEDS for x in ev[(d, trained_to, tb)]]
                for d, _ in runs_of(world, algo=algo, modality=modality, level=level)
                if (d, trained_to, TESTBEDS[0]) in ev
            ]
            expected = expect_rate(values) if values else "–"
            assert got[trained_to][label] == expected, (label, trained_to)


def test_training_level_evaluations_report_survival(world):
    got = table(world["text"], "## Evaluation on training levels")
    steps = [r["steps"] for r in world["eval_rows"] if r["policy"] == "random" and r["level"] == "1-1"]
    assert got["1-1"]["random"] == expect([steps], "episodes")


# ------------------------------------------------------------------------------------------------ Figs. 25-26
def test_ablation_curves_are_binned_means_across_seeds(world):
    import pandas as pd

    curves = pd.read_csv(world["base"] / "out" / "data" / "ablation_curves.csv")
    width = len(STAGES) * BUDGET / 4
    for modality in ("all", "no_vision"):
        per_seed, episodes = {b: [] for b in range(4)}, {b: [] for b in range(4)}
        for _, info in runs_of(world, algo="ppo", modality=modality, level="curriculum"):
            steps = np.array([s for s, _ in info["episodes"]])
            surv = np.array([v for _, v in info["episodes"]])
            bins = np.clip(np.ceil(steps / width).astype(int) - 1, 0, 3)
            for b in range(4):
                if (bins == b).any():
                    per_seed[b].append(surv[bins == b].mean())
                    episodes[b] += surv[bins == b].tolist()
        got = curves[(curves["group"] == "ppo · curriculum") & (curves["label"] == modality)].set_index("bin")
        for b, values in per_seed.items():
            m, se, n = stats(values)
            assert got.loc[b, "mean"] == pytest.approx(m) and got.loc[b, "n"] == n
            assert got.loc[b, "se"] == pytest.approx(se, nan_ok=True)
            assert got.loc[b, "steps"] == pytest.approx((b + 0.5) * width)
            assert got.loc[b, "value"] == pytest.approx(hand_iqm(episodes[b])) and got.loc[b, "statistic"] == "iqm"
            assert got.loc[b, "low"] <= got.loc[b, "value"] <= got.loc[b, "high"]
            assert got.loc[b, "episodes"] == len(episodes[b])


def test_training_curves_have_a_line_per_algorithm_and_settings_per_training_set_up(world):
    import pandas as pd

    curves = pd.read_csv(world["base"] / "out" / "data" / "training_curves.csv")
    ablation = pd.read_csv(world["base"] / "out" / "data" / "ablation_curves.csv")
    # the curriculum PPO runs with all modalities are the same binned means in both figures
    mine = curves[
        (curves["group"] == "trained on curriculum")
        & (curves["label"].str.startswith("ppo"))
        & ~curves["label"].str.contains("no_vision")
    ].set_index("bin")
    theirs = ablation[(ablation["group"] == "ppo · curriculum") & (ablation["label"] == "all")].set_index("bin")
    assert len(mine) and list(mine.index) == list(theirs.index)
    assert np.allclose(mine["mean"], theirs["mean"]) and (mine["n"] == theirs["n"]).all()
    assert set(curves["group"]) == {
        f"trained on {info['level']}" for d, info in world["sim"].runs.items() if d != world["missing"]
    }
    assert "## Training curves" in world["text"] and "fig_training_curves.png" in world["text"]


def test_ablation_final_survival_per_modality(world):
    got = table(world["text"], "## Modality ablations: training curves")
    for modality in ("all", "no_vision"):
        values = [[i["final"]["1-2"]] for _, i in runs_of(world, algo="ppo", modality=modality, level="curriculum")]
        assert got[modality]["ppo · curriculum"] == expect(values, per_seed=2)
    assert got["no_vision"]["dqn · curriculum"] == "–"


def test_ablation_success_per_modality(world):
    got = table(world["text"], "## Modality ablations: testbed success")
    ev = world["evaluated"]
    for modality in ("all", "no_vision"):
        for testbed in TESTBEDS:
            outcomes = [
                ev[(d, "1-2", testbed)] for d, _ in runs_of(world, algo="ppo", modality=modality, level="curriculum")
            ]
            assert got[testbed][f"ppo · curriculum · {modality}"] == expect_rate(outcomes)


# ------------------------------------------------------------------------------------------------ what is missing
def test_missing_partial_and_orphaned_inputs_are_listed(world):
    section = world["text"][world["text"].index("## Missing and partial runs") :]
    section = section[: section.index("\n## ", 5)]
    rel = lambda p: str(Path(p).resolve())  # noqa: E731  (tmp paths are outside the current directory)
    assert f"{rel(world['missing'])}: missing: no episodes.csv" in section
    assert f"{rel(world['partial'])}: partial: 140 of 200 env steps (unfinished: 1-2)" in section
    assert f"evaluation of {world['gone']}: its run directory is gone; left out (3 episodes on y-maze" in section
    runs = table(world["text"], "## Runs")
    assert runs[rel(world["partial"])]["status"] == "partial" and runs[rel(world["missing"])]["status"] == "missing"
    assert len(runs) == len(world["sim"].runs)


def test_the_testbed_figures_show_the_curriculum_agents_with_every_sense_and_the_tables_every_run(
    world, tmp_path, monkeypatch
):
    from evaaa_baselines.reports import testbeds

    drawn, original = {}, testbeds.plot_bars

    def spy(stats, path, **kw):
        drawn[path.name] = set(stats["label"])
        return original(stats, path, **kw)

    def spy_lines(stats, path, **kw):
        drawn[path.name] = set(stats["label"])
        return lines(stats, path, **kw)

    lines = testbeds.plot_lines
    monkeypatch.setattr(testbeds, "plot_bars", spy)
    monkeypatch.setattr(testbeds, "plot_lines", spy_lines)
    report = build_report([world["base"] / "runs"], [world["base"] / "eval"], tmp_path)
    shown = drawn["fig4b_success_per_testbed.png"]
    text = report.markdown.read_text()
    columns = set(next(iter(table(text, "## Success per testbed").values())))
    assert {"oracle", "random"} <= shown
    agents = shown - {"oracle", "random"}
    assert agents and all(label.endswith("curriculum") and "no_vision" not in label for label in agents)
    assert any("1-1" in c for c in columns) and any("no_vision" in c for c in columns)  # the table keeps them all
    assert columns - {"testbed"} > shown
    assert f"The figure shows the {len(agents)} curriculum-trained agents with every sense" in text
    assert drawn["fig4b_generalisation.png"] == agents  # the same agents, one line each across their stages
    assert set(next(iter(table(text, "## Generalisation by training level").values()))) > agents


def test_the_ablation_figures_have_a_panel_only_where_several_modality_sets_were_trained(world, tmp_path, monkeypatch):
    from evaaa_baselines.reports import ablations

    drawn, bars, lines = {}, ablations.plot_bars, ablations.plot_lines

    def spy(original):
        def draw(stats, path, **kw):
            drawn[path.name] = set(stats[kw["panel"]]) if kw.get("panel") else set()
            return original(stats, path, **kw)

        return draw

    monkeypatch.setattr(ablations, "plot_bars", spy(bars))
    monkeypatch.setattr(ablations, "plot_lines", spy(lines))
    report = build_report([world["base"] / "runs"], [world["base"] / "eval"], tmp_path)
    # ppo's curriculum has all and no_vision; dqn's curriculum and ppo's direct runs have every sense only
    assert drawn["fig25_ablation_curves.png"] == drawn["fig26_ablation_success.png"] == {"ppo · curriculum"}
    text = report.markdown.read_text()
    assert table(text, "## Modality ablations: training curves")["all"]["dqn · curriculum"] != "–"  # table: all


def test_an_evaluated_checkpoint_whose_file_is_gone_but_whose_run_is_there_still_counts(tmp_path):
    sim = Sim(tmp_path / "runs")
    run = sim.run("ppo", 0, level="1-1", finish=1)
    rows = sim.evaluate(str(run / "checkpoint.pt"), "y-maze", 4)
    append_rows(tmp_path / "eval" / "episodes.csv", rows)
    with_file = build_report([run], [tmp_path / "eval"], tmp_path / "out")
    (run / "checkpoint.pt").unlink()  # as in a committed record, which keeps no model files
    without = build_report([run], [tmp_path / "eval"], tmp_path / "out2")
    text = without.markdown.read_text()
    assert "1 of the 1 evaluated checkpoints are not on disk here" in text
    assert "not on disk" not in with_file.markdown.read_text()
    assert without.problems == with_file.problems == []  # not a problem: a record is meant to be so
    success = table(text, "## Success per testbed")
    assert success == table(with_file.markdown.read_text(), "## Success per testbed") and success["y-maze"]


def test_a_finished_set_of_runs_reports_nothing_missing(world, tmp_path):
    report = build_report([world["base"] / "runs" / "1-1"], [], tmp_path)
    assert "None: every run finished" in report.markdown.read_text() and report.problems == []
    # sections without data say what is missing instead of drawing an empty figure
    assert "No testbed evaluation given" in report.markdown.read_text()
    assert not (tmp_path / "fig4b_success_per_testbed.png").exists()


def test_a_run_ended_by_its_wall_clock_budget_reports_the_steps_it_reached(tmp_path):
    # max_minutes ended the stage at 70 of its 200 env steps: it is finished (model written, final evaluation at 70)
    sim = Sim(tmp_path)
    run = sim.run("ppo", 0, level="1-1", finish=0, partial_steps=70)
    (run / "model-0-1-1.pt").touch()
    report = build_report([run], [], tmp_path / "out")
    row = table(report.markdown.read_text(), "## Runs")[str(run.resolve())]
    assert row["status"] == "finished" and row["env steps"] == f"70 / {BUDGET:,}"
    assert report.problems == []


def test_a_checkpoint_evaluated_in_two_ways_is_reported_both_ways_labelled_never_pooled(world, tmp_path):
    sim = world["sim"]
    run = next(d for d, info in sim.runs.items() if info["level"] == "1-1" and info["seed"] == 0)
    ckpt = str(run / "checkpoint.pt")
    greedy = [r | {"acting": "mode", "steps": 100 + i} for i, r in enumerate(sim.evaluate(ckpt, "1-1", 3))]
    sampled = [r | {"acting": "sample", "steps": 900 + 2 * i} for i, r in enumerate(sim.evaluate(ckpt, "1-1", 3))]
    append_rows(tmp_path / "greedy" / "episodes.csv", greedy)
    append_rows(tmp_path / "sampled" / "episodes.csv", sampled)
    append_rows(tmp_path / "random.csv", sim.evaluate("random", "1-1", 4))
    evals = [tmp_path / "greedy", tmp_path / "sampled", tmp_path / "random.csv"]
    both = table(
        build_report([run], evals, tmp_path / "both").markdown.read_text(), "## Evaluation on training levels"
    )["1-1"]
    label = next(k for k in both if k.endswith("[mode]")).removesuffix(" [mode]")
    assert both[f"{label} [mode]"] == expect([[r["steps"] for r in greedy]])
    assert both[f"{label} [sample]"] == expect([[r["steps"] for r in sampled]])
    with pytest.raises(ReportError, match=r"no checkpoint was evaluated acting 'greedy'"):
        build_report([run], evals, tmp_path / "out", acting="greedy")
    for acting, rows in (("sample", sampled), ("mode", greedy)):
        report = build_report([run], evals, tmp_path / acting, acting=acting)
        text = report.markdown.read_text()
        got = table(text, "## Evaluation on training levels")["1-1"]
        checkpoint_cells = [v for k, v in got.items() if k not in ("level", "random")]
        assert checkpoint_cells == [expect([[r["steps"] for r in rows]])]
        assert f"Checkpoints acted: `{acting}`" in text and "random" in got


def test_a_mode_chosen_from_validation_rows_is_compared_and_stated_with_its_numbers(world, tmp_path, capsys):
    # report.py compare_from=: the protocol's compared_mode.json (scripts/choose_acting.py) decides what the claims
    # compare, here `mode` (the first of the evaluations' modes would be `sample`), and the report says why
    from evaaa_baselines.paper.choice import write_choice

    sim = world["sim"]
    run = next(d for d, info in sim.runs.items() if info["level"] == "1-1" and info["seed"] == 0)
    ckpt = str(run / "checkpoint.pt")
    for acting in ("sample", "mode"):
        append_rows(tmp_path / acting / "episodes.csv", [r | {"acting": acting} for r in sim.evaluate(ckpt, "1-1", 3)])
    choice = {
        "chosen": "mode",
        "compare": "mode",
        "survival": {
            "sample": {"episodes": 16, "mean": 1104.5, "iqm": 1090.25},
            "mode": {"episodes": 16, "mean": 2250.0, "iqm": 2301.75},
        },
        "networks": 8,
        "runs": 5,
        "left_out": ["runs/dqn/matched-1-1/seed0 stage 0 (1-1): one acting mode only (mode)"],
        "chosen_at": "20270101T000000Z",
    }
    path = write_choice(tmp_path / "compared_mode.json", choice)
    script = load_report()
    args = [f"runs=[{run}]", f"evals=[{tmp_path / 'sample'},{tmp_path / 'mode'}]", f"compare_from={path}"]
    assert script.main([*args, f"out={tmp_path / 'out'}"]) == 0
    text = (tmp_path / "out" / "report.md").read_text()
    assert "The claims compare the checkpoints acting `mode` (the most likely action)" in text
    assert (
        "The compared mode was chosen from validation rows before any test evaluation (compared_mode.json, "
        "20270101T000000Z): `mode`, whose in-training validation evaluations survived longer — mean 2,250.0 "
        "decisions (IQM 2,301.8, 16 episodes) against mean 1,104.5 decisions (IQM 1,090.2, 16 episodes) acting "
        "`sample`, the same episodes, at the last validation evaluation of 8 networks of 5 runs; 1 left out"
    ) in text
    # the choice is made once; the report takes one of compare and compare_from
    with pytest.raises(ChoiceError, match="exists: the compared mode is chosen once"):
        write_choice(path, choice | {"chosen": "sample"})
    assert json.loads(path.read_text())["chosen"] == "mode"
    capsys.readouterr()
    for extra, message in (
        ([args[2], "compare=sample"], "compare_from: give compare or compare_from, not both"),
        ([f"compare_from={tmp_path / 'none.json'}"], "compare_from: cannot read"),
    ):
        with pytest.raises(SystemExit):
            script.main([*args[:2], *extra, f"out={tmp_path / 'x'}"])
        assert message in capsys.readouterr().err
    assert not (tmp_path / "x").exists()  # refused before anything was written


def test_a_stage_best_model_is_tied_to_its_stage_and_the_final_model_is_preferred(world):
    from evaaa_baselines.reports import attach, final_checkpoints, load_run

    sim = world["sim"]
    run = next(d for d, info in sim.runs.items() if info["level"] == "curriculum")
    stage, level = 0, STAGES[0]  # not the stage the run ended in, which a checkpoint.pt would be tied to
    best, final = str(run / f"model-best-{stage}-{level}.pt"), str(run / f"model-{stage}-{level}.pt")
    rows = pd.DataFrame(sim.evaluate(best, "1-1", 2) + sim.evaluate(final, "1-1", 2)).assign(file="episodes.csv")
    ckpts = attach(rows, {run.resolve(): load_run(run)}).checkpoints
    assert set(zip(ckpts["policy"], ckpts["ckpt_stage"], ckpts["ckpt_level"])) == {
        (best, stage, level),
        (final, stage, level),
    }
    assert set(final_checkpoints(ckpts)["policy"]) == {final}
    only_best = ckpts[ckpts["policy"] == best]
    assert set(final_checkpoints(only_best)["policy"]) == {best}


def test_checkpoints_outside_the_given_runs_are_found_through_their_run_directory(world, tmp_path):
    report = build_report([], [world["base"] / "eval"], tmp_path)
    got = table(report.markdown.read_text(), "## Success per testbed")
    assert "ppo · all · curriculum" in got["y-maze"] and "oracle" in got["y-maze"]
    assert any("its run directory is gone" in p for p in report.problems)


# ------------------------------------------------------------------------------------------------ command line
def load_report():
    return load_script("report")


def test_command_line_writes_the_report(world, tmp_path, capsys):
    script = load_report()
    out = tmp_path / "cli"
    assert (
        script.main(
            [f"runs=[{world['base'] / 'runs'}]", f"evals={world['base'] / 'eval'}", f"out={out}", "title=Sweep"]
        )
        == 0
    )
    assert (out / "report.md").read_text().startswith("# Sweep\n")
    printed = capsys.readouterr().out
    assert "note: " in printed and "fig26_ablation_success.png" in printed


@pytest.mark.parametrize(
    "args, message",
    [
        ([], "nothing to report"),
        (["runs=[/no/such/dir]"], "is not a directory"),
        (["colour=red"], "unknown key 'colour'; keys: runs, evals, out"),
        (["runs"], "'runs' is not of the form key=value"),
        (["bins=many"], "bins=many: expected an integer"),
        (["survival=best", "evals=[EVAL]"], "survival=best: 'best' is not allowed; allowed: eval, train"),
        (["evals=[RUN_CSV]"], "is not an episode file"),
        (["runs=[EMPTY]"], "no run directory"),
    ],
)
def test_command_line_rejects_bad_input(world, tmp_path, args, message, capsys):
    script = load_report()
    (tmp_path / "empty").mkdir()
    run_csv = next((world["base"] / "runs").rglob("eval.csv"))
    subst = {"EVAL": str(world["base"] / "eval"), "RUN_CSV": str(run_csv), "EMPTY": str(tmp_path / "empty")}
    for placeholder, value in subst.items():
        args = [a.replace(placeholder, value) for a in args]
    with pytest.raises(SystemExit) as exit_:
        script.main([*args, f"out={tmp_path / 'out'}"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.startswith("report.py: error: ") and message in err, err


def test_how_a_run_was_started_does_not_split_its_group(tmp_path):
    from evaaa_baselines.reports import describe_extras, load_run

    sim = Sim(tmp_path / "runs")
    dirs = [sim.run("ppo", 0, level="1-1", finish=1), sim.run("ppo", 1, level="1-1", finish=1)]
    config = dirs[1] / ".hydra" / "config.yaml"
    config.write_text(
        config.read_text().replace("start_over: false", "start_over: true").replace("resume: false", "resume: true")
    )
    older = dirs[0] / ".hydra" / "config.yaml"  # a run made before the deterministic key existed
    older.write_text(
        "".join(line for line in older.read_text().splitlines(keepends=True) if not line.startswith("deterministic:"))
    )
    runs = [load_run(d) for d in dirs]
    assert runs[1].config["start_over"] and runs[1].config["resume"]
    assert runs[1].config["deterministic"] and "deterministic" not in runs[0].config  # a run made before the key
    describe_extras(runs)
    assert runs[0].extras == runs[1].extras == ()


def test_a_run_made_before_a_setting_existed_pools_with_runs_at_its_earlier_value(tmp_path):
    from evaaa_baselines.reports import describe_extras, load_run

    sim = Sim(tmp_path / "runs")
    dirs = [sim.run("ppo", seed, level="1-1", finish=1) for seed in (0, 1)]
    dirs.append(sim.run("ppo", 2, level="1-1", finish=1, overrides=("env.backend=warp",)))
    older = OmegaConf.load(dirs[0] / ".hydra" / "config.yaml")  # made before env.backend and mlp_default
    del older.env["backend"]
    del older.algo.encoder["mlp_default"]
    OmegaConf.save(older, dirs[0] / ".hydra" / "config.yaml")
    runs = [load_run(d) for d in dirs]
    assert "backend" not in runs[0].config["env"] and runs[1].config["env"]["backend"] == "cpu"
    describe_extras(runs)
    # read as the CPU backend (what came before) and the default MLP size: pooled with the run made since
    assert runs[0].extras == runs[1].extras == ("env.backend=cpu",)
    assert runs[2].extras == ("env.backend=warp",)  # another backend still splits
    describe_extras(runs[:2])
    assert runs[0].extras == runs[1].extras == ()


def test_a_number_spelled_two_ways_or_another_time_budget_does_not_split_a_group(tmp_path):
    from evaaa_baselines.reports import describe_extras, load_run
    from evaaa_baselines.reports.load import labels

    sim = Sim(tmp_path / "runs")
    dirs = [
        sim.run("ppo", 0, level="1-1", finish=1, overrides=("algo.value_coef=1", "max_minutes=75")),
        sim.run(
            "ppo", 1, level="1-1", finish=1, overrides=("algo.value_coef=1.0", "max_minutes=33", "max_cpu_minutes=110")
        ),
        sim.run("ppo", 2, level="1-1", finish=1, overrides=("algo.value_coef=0.25",)),
    ]
    runs = [load_run(d) for d in dirs]
    assert [r.config["algo"]["value_coef"] for r in runs] == [1, 1.0, 0.25]
    assert isinstance(runs[0].config["algo"]["value_coef"], int)
    describe_extras(runs)
    # max_minutes and max_cpu_minutes are budgets, not settings
    assert runs[0].extras == runs[1].extras == ("algo.value_coef=1",)
    assert runs[2].extras == ("algo.value_coef=0.25",)  # a setting that differs still splits
    names = labels(runs)
    assert names[dirs[0]] == names[dirs[1]] != names[dirs[2]]


def test_a_row_cut_short_at_the_end_of_a_csv_is_skipped_and_said(world, tmp_path):
    from evaaa_baselines.reports import load_evaluations, load_run

    source = next(d for d in world["sim"].runs if d != world["missing"])
    run_dir = tmp_path / "run"
    shutil.copytree(source, run_dir)
    rows = len(pd.read_csv(run_dir / "episodes.csv"))
    with open(run_dir / "episodes.csv", "a") as f:
        f.write("100,1,1-2,37,0,")  # a process killed while writing its row
    run = load_run(run_dir)
    assert len(run.episodes) == rows
    assert [n for n in run.notes if str(run_dir / "episodes.csv") in n and "skipped" in n]

    evals = tmp_path / "episodes.csv"
    shutil.copy(world["base"] / "eval" / "episodes.csv", evals)
    with open(evals, "a") as f:
        f.write("random,,two-resource-food,9,0,3")
    notes: list[str] = []
    assert len(load_evaluations([evals], notes)) == len(world["eval_rows"])
    assert len(notes) == 1 and str(evals) in notes[0]
    report = build_report([run_dir], [evals], tmp_path / "out")
    assert any(str(evals) in p and "skipped" in p for p in report.problems)
    assert str(evals) in report.markdown.read_text()


def test_an_empty_csv_is_refused_in_one_line(world, tmp_path, capsys):
    script = load_report()
    empty = tmp_path / "episodes.csv"
    empty.write_bytes(b"")
    with pytest.raises(SystemExit) as refused:
        script.main([f"evals=[{empty}]", f"out={tmp_path / 'out'}"])
    err = capsys.readouterr().err
    assert refused.value.code == 2 and err.startswith(f"report.py: error: {empty} is empty (0 bytes")
    assert err.count("\n") == 1
    run_dir = tmp_path / "run"
    shutil.copytree(next(d for d in world["sim"].runs if d != world["missing"]), run_dir)
    (run_dir / "eval.csv").write_bytes(b"")
    with pytest.raises(ReportError, match=re.escape(str(run_dir / "eval.csv")) + " is empty"):
        build_report([run_dir], [], tmp_path / "out2")


# ------------------------------------------------------------------------------------------------ launchers
def test_launcher_presets_compose_with_hydra_config():
    # sweeps run in parallel on this machine by default (joblib); basic runs them one after another
    local = make_cfg(hydra=True).hydra.launcher
    assert local._target_ == "hydra_plugins.hydra_joblib_launcher.joblib_launcher.JoblibLauncher"
    assert local.n_jobs == 2 and int(local.batch_size) == 1
    assert make_cfg("hydra/launcher=basic", hydra=True).hydra.launcher._target_.endswith("BasicLauncher")
    assert make_cfg("hydra/launcher=local", "hydra.launcher.n_jobs=8", hydra=True).hydra.launcher.n_jobs == 8
    slurm = make_cfg("hydra/launcher=slurm", "hydra.launcher.partition=cpu", hydra=True).hydra.launcher
    assert slurm._target_ == "hydra_plugins.evaaa_ray_launcher.submitit_launchers.SlurmLauncher"
    assert slurm.partition == "cpu" and slurm.cpus_per_task == 4 and slurm.max_num_timeout > 0
    assert "export MUJOCO_GL=egl" in slurm.setup
    # a SLURM sweep tried through submitit's local executor
    slurm_local = make_cfg("hydra/launcher=slurm_local", hydra=True).hydra.launcher
    assert slurm_local._target_ == "hydra_plugins.evaaa_ray_launcher.submitit_launchers.LocalLauncher"
    # Ray: evaaa's own launcher plugin (Hydra's, hydra-ray-launcher, does not install beside the pinned packages)
    ray = make_cfg("hydra/launcher=ray_cluster", "hydra.launcher.address=auto", hydra=True).hydra.launcher
    assert ray._target_ == "hydra_plugins.evaaa_ray_launcher.ray_launcher.RayLauncher"
    assert ray.address == "auto" and ray.num_cpus == 4 and ray.num_gpus == 0
    # the presets do not shadow the plugins' own options
    names = {p.stem for p in (CONF_DIR / "hydra" / "launcher").glob("*.yaml")}
    assert names == {"local", "slurm", "slurm_local", "ray_cluster"}
    assert not names & {"joblib", "submitit_local", "submitit_slurm", "ray", "ray_aws"}


def test_train_script_prints_the_launcher_config(tmp_path):
    cmd = [
        sys.executable,
        str(ROOT / "scripts" / "train.py"),
        "hydra.launcher.n_jobs=3",
        "--cfg",
        "hydra",
        "--package",
        "hydra.launcher",
    ]
    done = subprocess.run(
        cmd, cwd=tmp_path, capture_output=True, text=True, timeout=120, env={**os.environ, "HYDRA_FULL_ERROR": "1"}
    )
    assert done.returncode == 0, done.stderr[-2000:]
    printed = yaml.safe_load(done.stdout.split("\n", 1)[1])  # after the "# @package hydra.launcher" line
    assert printed["_target_"].endswith("JoblibLauncher") and printed["n_jobs"] == 3


# ------------------------------------------------------------------------------------------------ ablations
def test_each_ablation_is_a_small_override_that_drops_one_key():
    full = make_cfg("modality=all").modality.enabled
    assert all(full[k] for k in evaaa.MODALITIES)
    for path in sorted((CONF_DIR / "modality").glob("no_*.yaml")):
        raw = yaml.safe_load(path.read_text())
        assert raw["defaults"] == ["all"] and set(raw) == {"defaults", "name", "enabled"}
        (dropped,) = [k for k, v in raw["enabled"].items() if v is False]
        cfg = make_cfg(f"modality={path.stem}")
        assert cfg.modality.name == path.stem
        assert observation_keys(cfg) == tuple(k for k in evaaa.MODALITIES if k != dropped)


def test_an_ablation_removes_the_key_and_keeps_reward_and_termination():
    actions = [1, 2, 1, 4] * 15
    results = []
    for keys in (None, ("pixels", "olfaction", "thermoception", "collision")):
        env = evaaa.make_env("1-1", seed=3, modalities=keys, **{"episode.max_steps": 40})
        td = env.reset()
        assert ("interoception" in td.keys()) == (keys is None)
        rewards, ends = [], []
        for a in actions:
            td["action"] = env.action_spec.zero() + a
            out, td = env.step_and_maybe_reset(td)
            rewards.append(float(out["next", "reward"]))
            ends.append(bool(out["next", "terminated"]) or bool(out["next", "truncated"]))
        env.close()
        results.append((rewards, ends))
    assert results[0] == results[1] and any(results[0][1])  # same reward and episode ends, one episode ended


def test_known_scores_give_their_iqm_and_old_training_files_still_read(tmp_path):
    """Hand-made training episodes, written under the column names of runs from before training shared evaluation's
    episode fields (survival_steps, satiation, ...): the IQM of 10, 20, 30, 1000 (seed 0) and 40, 50, 60, 70 (seed 1)
    is the mean of 30, 40, 50, 60 = 45; the seeds' means are 265 and 55: 160 ± 105."""
    sim = Sim(tmp_path / "runs")
    old = [
        "env_steps",
        "stage",
        "level",
        "episode",
        "world",
        "survival_steps",
        "return",
        "end_type",
        "satiation",
        "hydration",
        "temperature",
        "damage",
        "wall_time",
    ]
    for seed, scores in ((0, (10, 20, 30, 1000)), (1, (40, 50, 60, 70))):
        run_dir = sim.run("ppo", seed, level="1-1", finish=1)
        rows = [
            dict(
                zip(
                    old,
                    (
                        10 * (i + 1),
                        0,
                        "1-1",
                        i + 1,
                        0,
                        v,
                        -1.0,
                        "FoodOutOfRange",
                        -15.0,
                        0,
                        0,
                        0,
                        "2026-01-01T00:00:00",
                    ),
                )
            )
            for i, v in enumerate(scores)
        ]
        write_csv(run_dir / "episodes.csv", old, rows)
    report = build_report([tmp_path / "runs"], [], tmp_path / "out", survival="train", window=4)
    got = table(report.markdown.read_text(), "## Survival per training level")["1-1"]["ppo · direct"]
    assert got == "45.0; seeds 265.0, 55.0 (n=2 seeds × 4 ep.)"  # two seeds: their values, no interval
    data = pd.read_csv(tmp_path / "out" / "data" / "survival_per_level.csv")
    assert data.loc[0, "value"] == pytest.approx(45.0) and data.loc[0, "episodes"] == 8
    assert np.isnan(data.loc[0, "low"]) and data.loc[0, "acting"] == "exploring (training)"


def test_training_writes_the_episode_fields_of_evaluations():
    """One episode format: training's episodes.csv columns are evaluation's episode fields (same names, same
    meanings) plus where in the run the episode ended; the columns of older files map onto them."""
    from evaaa.records import EPISODE_FIELDS, TRAINING_OLD_NAMES, TRAINING_ONLY_FIELDS

    shared = [f for f in TRAINING_EPISODE_FIELDS if f not in TRAINING_ONLY_FIELDS]
    assert shared and set(shared) <= set(EPISODE_FIELDS)
    assert shared == [f for f in EPISODE_FIELDS if f in shared]  # in evaluation's order
    assert {"steps", "return", "end_type", "final_satiation"} <= set(shared)
    assert set(TRAINING_OLD_NAMES.values()) <= set(shared) and not set(TRAINING_OLD_NAMES) & set(EPISODE_FIELDS)


# ------------------------------------------------------------------------------------------------ the claims
def test_the_claims_are_judged_on_the_numbers_of_the_report(world):
    from evaaa_baselines.paper import claims as rules
    from evaaa_baselines.paper.verdicts import claim_verdicts, read_inputs

    text = world["text"]
    claims = text[text.index("## The paper's claims") :]
    for letter in "abcde":
        assert f"- **({letter}) " in claims
    verdicts = {
        v.claim[:3]: v
        for v in claim_verdicts(
            read_inputs([world["base"] / "runs"], [world["base"] / "eval", world["base"] / "human.csv"])
        )
    }
    tables = world["report"].tables
    # the summary at the top: a row per claim, the verdicts of the claims section
    top = table(text[: text.index("## Runs")], "The paper's claims at a glance")
    assert list(top) == [v.claim for v in verdicts.values()]
    for v in verdicts.values():
        assert top[v.claim]["verdict"] == f"**{v.verdict}**" and f"- **{v.claim}: {v.verdict}.**" in claims
        assert top[v.claim]["its parts"] == ("; ".join(f"{p.claim}: *{p.verdict}*" for p in v.parts) or "–")

    def fmt(frame, **match):
        row = frame[np.logical_and.reduce([frame[k] == v for k, v in match.items()])].iloc[0]
        return rules._fmt(row)

    # (b) compares exactly the cells of Fig. 4a right, on the levels after the first
    cmp = tables["curriculum_vs_direct"]
    (ppo,) = [p for p in verdicts["(b)"].parts if p.claim == "ppo"]
    assert ppo.evidence[0].startswith(
        f"1-2: curriculum {fmt(cmp, label='ppo · curriculum', level='1-2')} vs direct "
        f"{fmt(cmp, label='ppo · direct', level='1-2')}; curriculum / direct = "
    )
    # (d) finds the human records
    assert verdicts["(d)"].parts[0].claim == "humans ≈ ceiling (the oracle)"
    # (e) compares each modality set with `all` among runs of one algorithm and set-up (here ppo's curricula)
    ablation = [v for k, v in verdicts.items() if k == "(e)"][0]
    assert ablation.claim.endswith("(ppo, trained on curriculum)")
    final = tables["ablation_final_survival"]
    part = next(p for p in ablation.parts if p.claim == "no_vision fails (survival)")
    # "fails" by the one definition: each cell against the bar of the level (2× the better of random, stand-still)
    assert part.evidence[0].startswith(f"no_vision {fmt(final, label='no_vision', group='ppo · curriculum')}")
    assert part.evidence[1].startswith(f"all {fmt(final, label='all', group='ppo · curriculum')}")


# ------------------------------------------------------------------------------------------------ issue 42
def test_survival_cells_come_from_per_episode_evaluations_where_there_are_any(tmp_path):
    # three direct runs whose final models were evaluated on their level: the cell is over those episodes (seeds
    # redrawn, then episodes within seeds), not over the means of eval.csv
    sim = Sim(tmp_path / "runs")
    per_seed, rows = [], []
    for seed in (0, 1, 2):
        run = sim.run("ppo", seed, level="1-1", finish=1)
        part = [r | {"acting": "mode", "worlds": "test"} for r in sim.evaluate(str(run / "model-0-1-1.pt"), "1-1", 4)]
        per_seed.append([r["steps"] for r in part])
        rows += part
    append_rows(tmp_path / "eval" / "episodes.csv", rows)
    text = build_report([tmp_path / "runs"], [tmp_path / "eval"], tmp_path / "out").markdown.read_text()
    assert table(text, "## Survival per training level")["1-1"]["ppo · direct"] == expect(per_seed)
    section = text[text.index("## Survival per training level") :]
    assert "**Survival per training level (decisions).** Acting: `mode`. Worlds: test." in section
    assert "evaluated by evaluate.py on its level" in section.split("\n\n")[1]


def markdown_tables(text: str) -> list[tuple[str, str]]:
    """(title line, header line) of every Markdown table of ``text``: the title is the last non-empty line
    before it."""
    lines = text.splitlines()
    out = []
    for i, line in enumerate(lines):
        if line.startswith("|") and (i == 0 or not lines[i - 1].startswith("|")):
            out.append((next((x for x in reversed(lines[:i]) if x.strip()), ""), line))
    return out


def test_every_table_of_a_report_names_its_acting_mode_and_worlds(world):
    found = markdown_tables(world["text"])
    assert len(found) >= 10
    for title, header in found:
        assert "Acting:" in title and "Worlds:" in title, (header, title)
    assert "Worlds: seed-0 worlds, not held out." in world["text"]  # evaluations of files without a worlds column
    for path in (world["base"] / "out" / "data").glob("*.csv"):
        columns = set(pd.read_csv(path, nrows=0).columns)
        assert {"acting", "worlds"} <= columns, path.name


def png_width(path: Path) -> int:
    from PIL import Image

    with Image.open(path) as image:
        return image.size[0]


def test_figures_fit_a_page_width(world, tmp_path):
    from evaaa_baselines.reports import plot_bars, plot_lines, plot_outcomes

    for name in FIGURES:
        assert png_width(world["base"] / "out" / name) <= 1600, name
    # many agents on every level, many panels, many policies: wrapped into rows, never wider
    levels = list(evaaa.LEVELS)
    many = pd.DataFrame(
        [
            {
                "label": f"ppo · setting {i} · a long label",
                "level": lv,
                "value": 100.0 + i,
                "low": 90.0,
                "high": 120.0 + i,
                "statistic": "iqm",
                "n": 3,
                "unit": "seeds",
            }
            for i in range(30)
            for lv in levels
        ]
    )
    assert png_width(plot_bars(many, tmp_path / "bars.png", ylabel="survival", title="t")) <= 1600
    panels = many.assign(panel=many["label"].str[:14], steps=many["level"].map(levels.index) * 100.0)
    assert (
        png_width(
            plot_lines(
                panels, tmp_path / "lines.png", x="steps", panel="panel", ylabel="y", xlabel="x", title="t", band=True
            )
        )
        <= 1600
    )
    rows = pd.DataFrame(
        [
            {
                "policy": f"runs/{i}/seed0/model-0-1-1.pt",
                "acting": "mode",
                "level": lv,
                "success": np.nan,
                "end_type": "FoodOutOfRange",
                "food_eaten": 0,
                "collisions": 1,
            }
            for i in range(12)
            for lv in (*levels, *evaaa.TESTBEDS)
        ]
    )
    assert png_width(plot_outcomes(rows, tmp_path / "outcomes.png")) <= 1600


def test_one_colour_per_algorithm_and_per_modality_across_figures(world, tmp_path, monkeypatch):
    from matplotlib.axes import Axes

    from evaaa_baselines.reports.figures import styles

    drawn: list[tuple[str, str, object]] = []  # (figure kind, label, colour)
    bar, plot = Axes.bar, Axes.plot

    def spy_bar(self, *a, **kw):
        drawn.append(("bar", kw.get("label"), kw.get("color")))
        return bar(self, *a, **kw)

    def spy_plot(self, *a, **kw):
        drawn.append(("line", kw.get("label"), kw.get("color")))
        return plot(self, *a, **kw)

    monkeypatch.setattr(Axes, "bar", spy_bar)
    monkeypatch.setattr(Axes, "plot", spy_plot)
    build_report([world["base"] / "runs"], [world["base"] / "eval"], tmp_path)
    algos, modalities = {}, {}
    for _, label, colour in drawn:
        if not label or label.startswith("_"):
            continue
        if label in ("all", "no_vision"):  # Figs. 25 (lines) and 26 (bars) label their lines and bars by modality
            modalities.setdefault(label, set()).add(colour)
        else:
            algos.setdefault(label.split(" · ")[0], set()).add(colour)
    assert {"ppo", "dqn", "oracle", "random"} <= set(algos) and set(modalities) == {"all", "no_vision"}
    assert all(len(c) == 1 for c in (*algos.values(), *modalities.values())), (algos, modalities)
    assert len({next(iter(c)) for c in algos.values()}) == len(algos)  # and different algorithms differ
    assert modalities["all"] != modalities["no_vision"]
    # whatever else a figure shows, and in whatever order
    assert styles(["dqn · x", "ppo · y"])["ppo · y"][0] == styles(["ppo · z"])["ppo · z"][0]


def learned_rows(text: str) -> list[dict[str, str]]:
    lines = text[text.index("## What each agent learned") :].splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("| level"))
    header = [c.strip() for c in lines[start].strip("|").split("|")]
    rows = []
    for line in lines[start + 2 :]:
        if not line.startswith("|"):
            break
        rows.append(dict(zip(header, (c.strip() for c in line.strip("|").split("|")))))
    return rows


def test_what_it_learned_sets_every_agent_beside_random_and_stand_still(tmp_path):
    # ppo stands still (never eats, survives a little longer than stand-still); dqn eats two items an episode
    sim = Sim(tmp_path / "runs")
    rows = []
    for algo, steps, food in (("ppo", 1200, 0), ("dqn", 900, 2), ("ppo_lstm", 500, 0)):
        for seed in (0, 1, 2):
            run = sim.run(algo, seed, level="1-1", finish=1)
            rows += [
                r
                | {
                    "acting": "mode",
                    "worlds": "test",
                    "steps": steps + seed,
                    "food_eaten": food,
                    "end_type": "FoodOutOfRange",
                }
                for r in sim.evaluate(str(run / "model-0-1-1.pt"), "1-1", 4)
            ]
    rows += [
        r | {"worlds": "test", "steps": 1112, "end_type": "FoodOutOfRange"} for r in sim.evaluate("still", "1-1", 5)
    ]
    rows += [
        r | {"worlds": "test", "steps": 300, "food_eaten": 1, "collisions": 28, "end_type": "DamageTooHigh"}
        for r in sim.evaluate("random", "1-1", 5)
    ]
    append_rows(tmp_path / "eval" / "episodes.csv", rows)
    text = build_report([tmp_path / "runs"], [tmp_path / "eval"], tmp_path / "out").markdown.read_text()
    got = {r["agent"]: r for r in learned_rows(text)}
    assert set(got) == {"ppo", "dqn", "ppo_lstm", "still", "random"}
    assert got["ppo_lstm"]["reading"] == "neither eats more nor survives longer than random and stand-still"
    assert got["ppo"]["food / ep."] == "0.00" and got["ppo"]["vs better of random, stand-still"] == "1.08× still"
    assert got["ppo"]["reading"] == "survives longer than random and stand-still, eats no more"
    assert got["dqn"]["reading"] == "eats more than random and stand-still"  # 901 < 1112: not longer
    assert got["random"]["ends"] == "damaged 100 %" and got["random"]["collisions / ep."] == "28.0"
    assert got["dqn"]["n"] == "3 seeds × 4 ep."
    top = text.split("\n\n")[1]
    assert top.startswith("**What the agents learned**")
    assert (
        "\n- ppo ate more food and water per episode than random and stand-still on 0 of 1 levels and survived "
        "longer than the better of random and stand-still on 1 of 1\n"
    ) in top  # a line per agent
    assert (
        "dqn ate more food and water per episode than random and stand-still on 1 of 1 levels (1-1: 2.0) and "
        "survived longer than the better of random and stand-still on 0 of 1"
    ) in top
    assert (
        "ppo_lstm ate more food and water per episode than random and stand-still on 0 of 1 levels and "
        "survived longer than the better of random and stand-still on 0 of 1" in top
    )
    assert "Stand-still survives 1112 decisions on 1-1" in top


def test_what_they_learned_counts_levels_per_acting_mode(tmp_path):
    # one network evaluated sampling (it eats) and taking its most likely action (it stands still): two readings of
    # one level each, not one agent on "2 levels"
    sim = Sim(tmp_path / "runs")
    rows = []
    for seed in (0, 1, 2):
        run = sim.run("ppo", seed, level="1-1", finish=1)
        for acting, steps, food in (("sample", 3000, 4), ("mode", 1100, 0)):
            rows += [
                r | {"acting": acting, "worlds": "test", "steps": steps + seed, "food_eaten": food}
                for r in sim.evaluate(str(run / "model-0-1-1.pt"), "1-1", 4)
            ]
    rows += [r | {"worlds": "test", "steps": 1112} for r in sim.evaluate("still", "1-1", 5)]
    rows += [r | {"worlds": "test", "steps": 300, "food_eaten": 1} for r in sim.evaluate("random", "1-1", 5)]
    append_rows(tmp_path / "eval" / "episodes.csv", rows)
    text = build_report([tmp_path / "runs"], [tmp_path / "eval"], tmp_path / "out", compare="sample").markdown
    top = text.read_text().split("\n\n")[1]
    assert (
        "ppo [sample] ate more food and water per episode than random and stand-still on 1 of 1 levels (1-1: 4.0) "
        "and survived longer than the better of random and stand-still on 1 of 1"
    ) in top
    assert (
        "ppo [mode] ate more food and water per episode than random and stand-still on 0 of 1 levels and survived "
        "longer than the better of random and stand-still on 0 of 1"
    ) in top


def test_what_they_learned_shows_a_few_cubes_in_many_episodes_as_more_than_none(tmp_path):
    # one cube in twelve episodes is more than the references' none: the line must not print it as "0.0"
    sim = Sim(tmp_path / "runs")
    rows = []
    for seed in (0, 1, 2):
        run = sim.run("ppo", seed, level="1-1", finish=1)
        rows += [
            r | {"acting": "sample", "worlds": "test", "steps": 1500, "food_eaten": int(seed == 1 and i == 0)}
            for i, r in enumerate(sim.evaluate(str(run / "model-0-1-1.pt"), "1-1", 4))
        ]
    rows += [r | {"worlds": "test", "steps": 1112} for r in sim.evaluate("still", "1-1", 5)]
    rows += [r | {"worlds": "test", "steps": 300} for r in sim.evaluate("random", "1-1", 5)]
    append_rows(tmp_path / "eval" / "episodes.csv", rows)
    text = build_report([tmp_path / "runs"], [tmp_path / "eval"], tmp_path / "out", compare="sample").markdown
    top = text.read_text().split("\n\n")[1]
    assert "ate more food and water per episode than random and stand-still on 1 of 1 levels (1-1: 0.083)" in top


def test_curriculum_and_direct_are_shown_with_the_env_steps_each_has_seen(world, tmp_path):
    section = world["text"][world["text"].index("## With and without curriculum") :]
    section = section[: section.index("\n## ")]
    assert f"1-2: curriculum {2 * BUDGET:,}; direct {BUDGET:,}" in section  # stage 2 has seen both stages
    assert f"no direct run here has as many env steps as the curriculum stage on 1-2 ({2 * BUDGET:,})" in section
    # direct runs of the curriculum stage's total on 1-2: the matched view, and claim (b) on it
    sim = Sim(tmp_path / "runs")
    cur = [sim.run("ppo", seed) for seed in (0, 1, 2)]
    direct = [sim.run("ppo", seed, level="1-2", finish=1, budget=2 * BUDGET) for seed in (0, 1, 2)]
    other = Sim(tmp_path / "runs" / "short", seed=1)  # run directories are named without their budget
    short = [other.run("ppo", seed, level="1-2", finish=1) for seed in (0, 1, 2)]
    text = build_report([tmp_path / "runs"], [], tmp_path / "out").markdown.read_text()
    matched = table(text, "Curriculum vs direct at matched total env steps")
    want = [[sim.runs[d]["final"]["1-2"]] for d in direct]
    assert matched["1-2"]["ppo · direct"] == expect(want, per_seed=2)
    assert matched["1-2"]["ppo · curriculum"] == expect([[sim.runs[d]["final"]["1-2"]] for d in cur], per_seed=2)
    # each view holds the direct runs of its own budget only
    equal = table(text, "Curriculum vs direct at equal env steps per stage")
    assert equal["1-2"]["ppo · direct"] == expect([[other.runs[d]["final"]["1-2"]] for d in short], per_seed=2)
    from evaaa_baselines.paper import claims as rules
    from evaaa_baselines.paper.verdicts import claim_verdicts, read_inputs

    (b,) = [v for v in claim_verdicts(read_inputs([tmp_path / "runs"], [])) if v.claim.startswith("(b)")]
    matched_stats = pd.read_csv(tmp_path / "out" / "data" / "curriculum_vs_direct_matched.csv")
    row = matched_stats[(matched_stats["label"] == "ppo · direct") & (matched_stats["level"] == "1-2")].iloc[0]
    assert f"vs direct {rules._fmt(row)}" in b.parts[0].evidence[0]


def test_direct_runs_at_matched_steps_alone_are_not_shown_as_equal_per_stage(tmp_path):
    # paper_learned's direct runs: level k of the curriculum gets (k + 1) stages' env steps, none has a stage's own
    sim = Sim(tmp_path / "runs")
    cur = [sim.run("ppo", seed) for seed in (0, 1, 2)]
    first = [sim.run("ppo", seed, level="1-1", finish=1) for seed in (0, 1, 2)]
    second = [sim.run("ppo", seed, level="1-2", finish=1, budget=2 * BUDGET) for seed in (0, 1, 2)]
    odd = Sim(tmp_path / "runs" / "odd", seed=2)
    for seed in (0, 1, 2):
        odd.run("ppo", seed, level="1-2", finish=1, budget=3 * BUDGET)
    report = build_report([tmp_path / "runs"], [], tmp_path / "out")
    text = report.markdown.read_text()
    assert "Curriculum vs direct at equal env steps per stage" not in text
    assert "curriculum_vs_direct" not in report.tables and "fig4a_curriculum_vs_direct.png" in text
    matched = table(text, "Curriculum vs direct at matched total env steps")
    assert matched["1-1"]["ppo · direct"] == expect([[sim.runs[d]["final"]["1-1"]] for d in first], per_seed=2)
    assert matched["1-2"]["ppo · direct"] == expect([[sim.runs[d]["final"]["1-2"]] for d in second], per_seed=2)
    assert matched["1-2"]["ppo · curriculum"] == expect([[sim.runs[d]["final"]["1-2"]] for d in cur], per_seed=2)
    assert f"Direct runs of neither budget, in no view: 1-2 ({3 * BUDGET:,} env steps)." in text
    assert "no direct run here has as many env steps" not in text


def test_a_dqn_checkpoint_evaluated_with_sample_is_shown_acting_greedily(tmp_path):
    # DQN has no action distribution: older evaluate.py files label its epsilon-greedy episodes `sample+epsilon`
    sim = Sim(tmp_path / "runs")
    run = sim.run("dqn", 0, level="1-1", finish=1)
    rows = [r | {"acting": "sample+epsilon=0.05"} for r in sim.evaluate(str(run / "model-0-1-1.pt"), "1-1", 3)]
    append_rows(tmp_path / "eval" / "episodes.csv", rows)
    for acting in (None, "sample+epsilon=0.05", "mode+epsilon=0.05"):  # what was asked for, or what it did
        text = build_report([run], [tmp_path / "eval"], tmp_path / str(acting), acting=acting).markdown.read_text()
        assert "Checkpoints acted: `mode+epsilon=0.05`" in text
        assert "Acting: `mode+epsilon=0.05`" in text and "Acting: `sample" not in text


#: eval.csv with one row per episode of each periodic evaluation (as runs wrote it before cpu_seconds)
EVAL_EPISODE_COLUMNS = EVAL_COLUMNS_BEFORE_CPU


def test_per_episode_in_training_evaluations_give_cells_and_curves_over_episodes(tmp_path):
    # three runs whose eval.csv has one row per episode (validation worlds): the stage's last evaluation is a
    # survival cell over those episodes, and each evaluation a point of the curve over the seeds' episodes
    sim = Sim(tmp_path / "runs")
    last, first = [], []
    for seed in (0, 1, 2):
        run = sim.run("ppo", seed, level="1-1", finish=1)
        rows = []
        for steps in (BUDGET // 2, BUDGET):
            survival = [int(v) for v in sim.rng.integers(10, 400, 4)]
            (last if steps == BUDGET else first).append(survival)
            rows += [
                dict(
                    zip(
                        EVAL_EPISODE_COLUMNS,
                        (
                            steps,
                            0,
                            "1-1",
                            "validation",
                            "mode",
                            i,
                            v,
                            -1.0,
                            "FoodOutOfRange",
                            0,
                            0,
                            0,
                            0.0,
                            "2026-01-01T00:00:00",
                        ),
                    )
                )
                for i, v in enumerate(survival)
            ]
        write_csv(run / "eval.csv", EVAL_EPISODE_COLUMNS, rows)
    text = build_report([tmp_path / "runs"], [], tmp_path / "out").markdown.read_text()
    assert table(text, "## Survival per training level")["1-1"]["ppo · direct"] == expect(last)
    assert "Acting: `mode`. Worlds: validation." in text and "Means only:" not in text
    curve = pd.read_csv(tmp_path / "out" / "data" / "evaluation_curves.csv").set_index("steps")
    assert curve.loc[BUDGET // 2, "value"] == pytest.approx(hand_iqm([v for s in first for v in s]))
    assert curve.loc[BUDGET // 2, "n"] == 3 and curve.loc[BUDGET // 2, "episodes"] == 12
    assert table(text, "## In-training evaluations")["trained on 1-1"]["ppo"] == expect(last)


def test_a_folder_of_evaluations_is_searched_for_their_episode_files(world, tmp_path):
    # a protocol's evals folder: one evaluate.py output per cell, an evaluation moved aside that must not count
    rows = pd.read_csv(world["base"] / "eval" / "episodes.csv", dtype=str, keep_default_na=False)
    half = len(rows) // 2
    for name, part in (
        ("a/testbeds", rows.iloc[:half]),
        ("b/level", rows.iloc[half:]),
        ("b/level.old-20260101T000000Z", rows.iloc[:3]),
    ):
        (tmp_path / "evals" / name).mkdir(parents=True)
        part.to_csv(tmp_path / "evals" / name / "episodes.csv", index=False)
    whole = build_report([world["base"] / "runs"], [world["base"] / "eval"], tmp_path / "one")
    found = build_report([world["base"] / "runs"], [tmp_path / "evals"], tmp_path / "many")
    assert table(found.markdown.read_text(), "## Success per testbed") == table(
        whole.markdown.read_text(), "## Success per testbed"
    )
    (tmp_path / "empty").mkdir()
    with pytest.raises(ReportError, match="holds no episodes.csv"):
        build_report([], [tmp_path / "empty"], tmp_path / "none")


def test_the_claims_compare_agents_in_the_acting_mode_they_all_have():
    from evaaa_baselines.reports.document import one_mode

    rows = pd.DataFrame(
        {
            "run": ["ppo0", "ppo0", "dqn0", "ppo1", "ppo1"],
            "acting": ["mode", "sample", "mode", "sample", "mode"],
            "steps": [1, 2, 3, 4, 5],
        }
    )
    assert one_mode(rows)["acting"].tolist() == ["mode"] * 3  # the deterministic action: every agent has it
    apart = pd.DataFrame(
        {"run": ["a", "a", "b", "c", "c", "c"], "acting": ["sample", "sample", "mode", "sample", "mode", "mode"]}
    )
    # no mode shared by every run: each run's most frequent (such agents are then not compared)
    assert one_mode(apart)["acting"].tolist() == ["sample", "sample", "mode", "mode", "mode"]


def _learned_only_when_sampling(tmp_path: Path) -> tuple[list[Path], Path]:
    """Three PPO runs on 1-1 whose final network stands still acting `mode` (about stand-still's 1,112 decisions)
    and forages when sampling (3,000-4,000), and three DQN runs (no action distribution: `mode` alone, about
    2,000), each evaluated on 1-1 (test worlds) as the protocol's cells write it."""
    sim = Sim(tmp_path / "runs")
    runs = []
    for seed in (0, 1, 2):
        for algo, ways in (("ppo", {"mode": (1100, 1125), "sample": (3000, 4000)}), ("dqn", {"mode": (1900, 2100)})):
            run = sim.run(algo, seed, level="1-1", finish=1)
            runs.append(run)
            for acting, (low, high) in ways.items():
                rows = [
                    r | {"acting": acting, "worlds": "test", "steps": int(sim.rng.integers(low, high))}
                    for r in sim.evaluate(str(run / "model-0-1-1.pt"), "1-1", 6)
                ]
                append_rows(tmp_path / "evals" / f"{algo}{seed}" / f"level-{acting}" / "episodes.csv", rows)
    return runs, tmp_path / "evals"


def _dqn_vs_ppo(inp):
    from evaaa_baselines.paper.verdicts import claim_verdicts

    (c,) = [v for v in claim_verdicts(inp) if v.claim.startswith("(c)")]
    return next(p for p in c.parts if p.claim == "dqn > ppo in survival")


def test_a_sample_comparison_takes_each_agent_s_sampled_rows_and_dqn_s_greedy_ones(tmp_path):
    # PPO learned only when sampling, DQN is greedy: compared in `sample`, PPO's sampled rows face DQN's greedy ones
    # (labelled so) and DQN is below; compared in `mode` (or as before, without `compare`), PPO's standing still
    from evaaa_baselines.paper.verdicts import read_inputs

    runs, evals = _learned_only_when_sampling(tmp_path)
    sampled = read_inputs(runs, [evals], compare="sample")
    v = _dqn_vs_ppo(sampled)
    assert v.verdict == "contradicted", v.evidence
    assert "dqn `sample (greedy: no action distribution)`, ppo `sample`" in v.evidence[-1]
    for compare in (None, "mode"):
        v = _dqn_vs_ppo(read_inputs(runs, [evals], compare=compare))
        assert v.verdict == "reproduced" and "acting modes differ" not in " ".join(v.evidence)
    # the report names the compared acting in its tables and keeps PPO's other mode there, labelled
    text = build_report(runs, [evals], tmp_path / "out", compare="sample").markdown.read_text()
    survival = table(text, "## Survival per training level")["1-1"]
    assert {"ppo · direct [mode]", "ppo · direct [sample]", "dqn · direct"} <= set(survival)
    mode, sample = (float(survival[f"ppo · direct [{m}]"].split()[0]) for m in ("mode", "sample"))
    assert mode < 1125 < 3000 <= sample
    said = "The claims compare `sample` (sampled actions; dqn: `mode`, greedy: it has no action distribution)"
    assert text.count(said) >= 2 and "**Compared acting.**" in text
    from evaaa_baselines.reports.figures import how_measured

    stats = pd.read_csv(tmp_path / "out" / "data" / "survival_per_level.csv")
    assert how_measured(stats, sampled.compared).endswith(
        "\nthe claims compare sample (sampled actions; dqn: mode, greedy: it has no action distribution)"
    )
    with pytest.raises(ReportError, match=r"compare: 'greedy' is no acting mode; allowed: mode, sample"):
        read_inputs(runs, [evals], compare="greedy")
    with pytest.raises(ReportError, match="compare: no checkpoint was evaluated acting 'sample"):
        read_inputs(runs, [evals], compare="sample+epsilon=0.05")


def test_acting_sample_keeps_a_dqn_checkpoint_s_greedy_episodes_as_evaluate_py_writes_them_now(tmp_path):
    # evaluate.py sample=true records DQN's episodes as `mode…` (it has no distribution): `acting=sample…` keeps
    # them (its greedy action is how it acts when asked to sample) and drops PPO's `mode…` ones
    sim = Sim(tmp_path / "runs")
    dqn, ppo = (sim.run(a, 0, level="1-1", finish=1) for a in ("dqn", "ppo"))
    for run, acting in ((dqn, "mode+epsilon=0.05"), (ppo, "sample+epsilon=0.05"), (ppo, "mode+epsilon=0.05")):
        rows = [r | {"acting": acting} for r in sim.evaluate(str(run / "model-0-1-1.pt"), "1-1", 3)]
        append_rows(tmp_path / "eval" / f"{run.name}-{acting}" / "episodes.csv", rows)
    text = build_report([dqn, ppo], [tmp_path / "eval"], tmp_path / "out", acting="sample+epsilon=0.05")
    got = table(text.markdown.read_text(), "## Evaluation on training levels")["1-1"]
    assert sorted(k for k in got if k != "level") == ["dqn", "ppo"]
    assert "Acting: `mode+epsilon=0.05` (dqn); `sample+epsilon=0.05` (ppo)" in text.markdown.read_text()
