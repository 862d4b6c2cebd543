"""Scoring a policy of your own (issue 64): ``evaaa_baselines.evaluation.score`` and ``evaluate.py policy=py:...`` play
a TorchRL module, a callable on the observation TensorDict, a callable on gymnasium's dict observation or a
Stable-Baselines3 model on test worlds, beside random and stand-still on the same worlds, and write what
``evaluate.py`` writes; code runs only where a command line names it; every refusal is one line, nothing written."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from helpers import load_script
from tensordict.nn import TensorDictModule

import evaaa
from evaaa_baselines.evaluation import EvaluationError, OwnPolicy, gym_policy, score

ROOT = Path(__file__).resolve().parents[1]
SHORT = 'extends: "1-1"\nepisode: {max_steps: 12}\n'
#: what the final EVs of an episode are: they depend on the world the episode was played in
FINAL = ("final_satiation", "final_hydration", "final_temperature", "final_damage")


@pytest.fixture
def short(tmp_path, monkeypatch) -> Path:
    """``short.yaml``: level 1-1 with 12-decision episodes (registered names are forgotten after each test)."""
    monkeypatch.setattr(evaaa.level_files, "_USER_FILES", {})
    path = tmp_path / "levels" / "short.yaml"
    path.parent.mkdir()
    path.write_text(SHORT)
    return path


def rows(out: Path) -> list[dict]:
    with open(out / "episodes.csv", newline="") as f:
        return list(csv.DictReader(f))


def by_policy(found: list[dict], policy: str) -> list[dict]:
    return sorted((r for r in found if r["policy"] == policy), key=lambda r: r["episode"])


def standing(td):
    """A callable on the TensorDict of every world: the "none" action everywhere; it never sees the diagnostics."""
    assert "info" not in td.keys() and td["pixels"].shape[-3:] == (64, 64, 3)
    return torch.zeros(td.batch_size, dtype=torch.long)


@gym_policy
def standing_gym(obs):
    """A callable on one world's gymnasium observation, as gymnasium.make("evaaa/1-1-v0") returns it."""
    assert set(obs) == set(evaaa.MODALITIES) and obs["pixels"].shape == (64, 64, 3)
    return 0


@pytest.mark.parametrize(
    "policy",
    [
        standing,
        standing_gym,
        TensorDictModule(lambda x: torch.zeros(x.shape[:-1], dtype=torch.long), ["interoception"], ["action"]),
    ],
    ids=["tensordict-callable", "gym-callable", "torchrl-module"],
)
def test_a_policy_of_your_own_plays_the_worlds_random_and_still_play(policy, short, tmp_path):
    out = tmp_path / "score"
    result = score(policy, levels=[str(short)], episodes=2, num_envs=2, out=out, name="mine")
    assert {p.name for p in result.files} == {"episodes.csv", "summary.md", "survival.png", "outcomes.png"}
    found = rows(out)
    assert [(r["policy"], r["level"]) for r in found] == [
        (p, "short") for p in ("mine", "random", "still") for _ in "ab"
    ]
    assert {r["worlds"] for r in found} == {"test"}
    mine, still = by_policy(found, "mine"), by_policy(found, "still")
    # standing still by its own hand: the stand-still agent's episodes, EV for EV, on the same worlds
    assert [[r[k] for k in ("level", "steps", *FINAL)] for r in mine] == [
        [r[k] for k in ("level", "steps", *FINAL)] for r in still
    ]
    assert all(float(r["none_pct"]) == 100.0 for r in mine)
    random_rows = by_policy(found, "random")
    assert any(float(r["forward_pct"]) > 0 for r in random_rows)  # the random reference did play its own actions
    summary = (out / "summary.md").read_text()
    # a TorchRL module acts by its distribution's mode, which its column says, as a checkpoint's does
    column = "mine [mode]" if isinstance(policy, TensorDictModule) else "mine"
    assert f"| {column} | random | still |" in summary and "Policy mine: " in summary and "random and still" in summary
    assert "test worlds of seed 0" in summary


def test_a_wrong_action_or_folder_is_refused_in_one_line_and_nothing_is_written(tmp_path):
    out = tmp_path / "score"
    with pytest.raises(EvaluationError, match=r"returned 2 values \[7,7\] for 2 worlds; expected one action per world"):
        score(lambda td: torch.full(td.batch_size, 7), levels=["1-1"], episodes=2, num_envs=2, out=out)
    assert not out.exists()
    with pytest.raises(EvaluationError, match="is not a policy"):
        score(42, levels=["1-1"], out=out)
    with pytest.raises(EvaluationError, match=r"levels=\[1-l\]: '1-l' is not allowed \(did you mean 1-2 or 1-1\?\)"):
        score(standing, levels=["1-l"], out=out)
    out.mkdir()
    (out / "summary.md").write_text("an earlier evaluation\n")
    with pytest.raises(EvaluationError, match="already holds an evaluation"):
        score(standing, levels=["1-1"], out=out)
    assert (out / "summary.md").read_text() == "an earlier evaluation\n"
    assert not OwnPolicy(standing_gym).acting and OwnPolicy(standing_gym).kind == "gym"


AGENT = """
import pathlib, torch
pathlib.Path(__file__).with_name("imported").write_text("yes")

def act(td):
    return torch.full(td.batch_size, 1)   # always forward
"""


def test_evaluate_py_scores_a_policy_named_on_the_command_line(short, tmp_path, capsys):
    agent = tmp_path / "agent.py"
    agent.write_text(AGENT)
    script = load_script("evaluate")
    out = tmp_path / "eval"
    args = [f"policy=py:{agent}:act", f"levels=[{short}]", "episodes=2", "num_envs=2", f"out={out}"]
    script.parse(args)  # checking the arguments runs none of the file
    assert not (tmp_path / "imported").exists()
    assert script.main(args) == 0
    assert (tmp_path / "imported").exists()
    found = rows(out)
    assert [r["policy"] for r in found] == [f"py:{agent}:act"] * 2 + ["random"] * 2 + ["still"] * 2
    assert all(float(r["forward_pct"]) == 100.0 for r in found[:2])
    # references=[] leaves them out; naming one in policy= does not play it twice
    out2 = tmp_path / "eval2"
    assert script.main([*args[:-1], "references=[]", f"out={out2}"]) == 0
    assert {r["policy"] for r in rows(out2)} == {f"py:{agent}:act"}
    out3 = tmp_path / "eval3"
    assert script.main([f"policy=[py:{agent}:act,still]", *args[1:-1], f"out={out3}"]) == 0
    assert [r["policy"] for r in rows(out3)].count("still") == 2


@pytest.mark.parametrize(
    "spec, message",
    [
        ("py:{dir}/missing.py:act", "missing.py: no such file"),
        ("py:{dir}/agent.py:act-now", "expected py:MODULE:NAME or py:FILE.py:NAME"),
        ("py:{dir}/agent.py:acts", "agent.py has no 'acts' (did you mean act?)"),
        ("py:{dir}/broken.py:act", "importing {dir}/broken.py raised ZeroDivisionError: division by zero"),
        ("py:no_such_module_here:act", "importing no_such_module_here raised ModuleNotFoundError"),
    ],
)
def test_a_policy_that_cannot_be_loaded_is_refused_in_one_line_and_nothing_is_written(spec, message, tmp_path):
    (tmp_path / "agent.py").write_text("def act(td):\n    return 0\n")
    (tmp_path / "broken.py").write_text("1 / 0\n")
    out = tmp_path / "eval"
    done = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "evaluate.py"), f"policy={spec.format(dir=tmp_path)}", f"out={out}"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert message.format(dir=tmp_path) in done.stderr
    assert not out.exists()


SB3_AGENT = """
from stable_baselines3 import PPO
model = PPO.load({path!r}, device="cpu")
"""


@pytest.mark.slow  # trains SB3's PPO for 128 steps on pixels (about a minute on a busy 2-core box)
def test_a_stable_baselines3_model_trains_on_the_gymnasium_id_and_is_scored(short, tmp_path):
    # docs/evaluation.md's example, as written there
    sb3 = pytest.importorskip("stable_baselines3")
    import gymnasium

    env = gymnasium.make("evaaa/1-1-v0", max_episode_steps=64)
    model = sb3.PPO("MultiInputPolicy", env, n_steps=64, batch_size=32, n_epochs=1, seed=0, device="cpu")
    model.learn(total_timesteps=128)
    model.save(tmp_path / "ppo-1-1")
    env.close()
    (tmp_path / "sb3_agent.py").write_text(SB3_AGENT.format(path=str(tmp_path / "ppo-1-1.zip")))
    out = tmp_path / "eval"
    done = subprocess.run(
        [
            sys.executable,
            str(ROOT / "scripts" / "evaluate.py"),
            f"policy=py:{tmp_path / 'sb3_agent.py'}:model",
            f"levels=[{short}]",
            "episodes=2",
            "num_envs=2",
            f"out={out}",
        ],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    found = rows(out)
    assert [r["policy"] for r in found][::2] == [f"py:{tmp_path / 'sb3_agent.py'}:model", "random", "still"]
    assert {r["acting"] for r in found[:2]} == {"mode"}  # predict(deterministic=True)
    assert "a Stable-Baselines3 model, its most likely actions" in (out / "summary.md").read_text()
