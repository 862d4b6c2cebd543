"""A level of your own wherever a level is named (issue 64; ``evaaa.make_env(path)`` is tested with the hostile
files): ``train.py level=file level.file=path``, ``evaluate.py levels=[1-1,path]`` (the spelling train.py's closing
hint prints, with absolute paths so that it works from any folder), ``play.py level=path`` and ``level_dir=``, and
report.py's table of them; every refusal one line, exit 2, nothing written.  Also evaluate.py's other refusals
before it makes ``out``, and "did you mean" for keys and level names."""

from __future__ import annotations

import csv
import shlex
from pathlib import Path

import pytest
import torch
from helpers import load_script
from hydra import initialize_config_dir
from omegaconf import OmegaConf

import evaaa
from evaaa_baselines.config import ConfigError, compose_checked, register_levels
from evaaa_baselines.paper.report import build_report
from evaaa_baselines.paths import CONF_DIR
from evaaa_baselines.training import summary

register_levels()

ROOT = Path(__file__).resolve().parents[1]
HOT = 'extends: "1-1"\nepisode: {max_steps: 20}\n'


@pytest.fixture
def hot(tmp_path, monkeypatch) -> Path:
    """``hot.yaml``: level 1-1 with 20-decision episodes; registered names are forgotten after each test (a name is
    one file's in a process)."""
    monkeypatch.setattr(evaaa.level_files, "_USER_FILES", {})
    path = tmp_path / "mine" / "hot.yaml"
    path.parent.mkdir()
    path.write_text(HOT)
    return path


def run_main(module, args: list[str], capsys) -> tuple[int, str]:
    try:
        code = module.main(args)
    except SystemExit as exit_:
        code = exit_.code
    return code, capsys.readouterr().err


def test_evaluate_plays_a_level_file_from_another_folder(hot, tmp_path, monkeypatch, capsys):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    out = tmp_path / "eval"
    args = ["policy=[still]", f"levels=[{hot}]", "episodes=2", "num_envs=2", f"out={out}"]
    assert load_script("evaluate").main(args) == 0
    with open(out / "episodes.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["level"] for r in rows] == ["hot", "hot"] and all(r["steps"] == "20" for r in rows)
    text = (out / "summary.md").read_text()
    assert "| hot | 20.0" in text and f"Level hot: the file {hot}." in text
    assert (out / "survival.png").is_file()  # no success rule: drawn with the training levels
    # report.py shows it, although the paper's sections know only the packaged levels
    report = build_report([], [out], tmp_path / "report")
    md = report.markdown.read_text()
    assert "## Levels of your own" in md and "| hot | 20.0" in md


@pytest.mark.parametrize(
    "level, message",
    [
        ("missing.yaml", "levels={}: the file cannot be read: no such file"),
        ("bad.yaml", "levels={}: the level is invalid"),
        ("1_1", "'1_1' is not allowed (did you mean 1-1?); allowed: 1-1"),
        ("my.yml.txt", "or the path of a .yaml level file of your own, e.g. levels=[1-1,path/to/my.yaml]"),
    ],
)
def test_evaluate_refuses_a_level_in_one_line_and_writes_nothing(level, message, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "bad.yaml").write_text("agent: {move_sped: 3}\n")
    out = tmp_path / "eval"
    code, err = run_main(load_script("evaluate"), ["policy=[still]", f"levels=[{level}]", f"out={out}"], capsys)
    assert code == 2 and err.startswith("evaluate.py: error: ") and err.count("\n") == 1, err
    assert message.format(level) in err, err
    assert not out.exists()


@pytest.mark.skipif(torch.cuda.is_available(), reason="a machine without CUDA")
def test_evaluate_refuses_a_device_this_machine_lacks_before_making_out(tmp_path, capsys):
    out = tmp_path / "eval"
    code, err = run_main(load_script("evaluate"), ["policy=[still]", "device=cuda", f"out={out}"], capsys)
    assert code == 2 and err.count("\n") == 1 and "device=cuda: no CUDA device is available here" in err, err
    assert not out.exists()


def test_evaluate_refuses_an_unusable_checkpoint_before_making_out(tmp_path, capsys):
    fake = tmp_path / "model.pt"
    fake.write_bytes(b"not a checkpoint")
    out = tmp_path / "eval"
    code, err = run_main(load_script("evaluate"), [f"policy=[{fake}]", "levels=[1-1]", f"out={out}"], capsys)
    assert code == 2 and err.count("\n") == 1, err
    assert not out.exists()


@pytest.mark.parametrize(
    "script, arg, hint",
    [
        ("evaluate", "episode=3", "unknown key 'episode' (did you mean episodes?)"),
        ("report", "eval=[x]", "unknown key 'eval' (did you mean evals?)"),
        ("render_levels", "level=[1-1]", "unknown key 'level' (did you mean levels?)"),
        ("demo", "level=1_1", "'1_1' is not allowed (did you mean 1-1?)"),
    ],
)
def test_a_typo_of_a_key_or_a_choice_names_the_closest(script, arg, hint, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    code, err = run_main(load_script(script), [arg], capsys)
    assert code == 2 and err.count("\n") == 1 and hint in err, err
    assert not list(tmp_path.iterdir())


def test_train_names_the_closest_key():
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        with pytest.raises(ConfigError, match=r"unknown key 'total_step' \(did you mean total_steps\?\)"):
            compose_checked(["algo=ppo", "total_step=5"])
        with pytest.raises(ConfigError, match=r"unknown key 'eval.evry' \(did you mean eval.every\?\)"):
            compose_checked(["algo=ppo", "eval.evry=5"])


def test_train_s_closing_hint_evaluates_the_level_file_from_any_folder(hot, tmp_path, monkeypatch):
    run_dir = tmp_path / "runs" / "hot" / "ppo" / "all-squared" / "seed0"
    run_dir.mkdir(parents=True)
    (run_dir / "model-0-hot.pt").write_bytes(b"m")
    fields = ["env_steps", "stage", "level", "steps", "end_type", "worlds", "acting"]
    with open(run_dir / "eval.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=fields)
        writer.writeheader()
        writer.writerow(dict(zip(fields, ["64", "0", "hot", "20", "MaxStepReached", "validation", "mode"])))
    monkeypatch.chdir(tmp_path)
    cfg = OmegaConf.create({"level": {"name": "hot", "file": str(hot.relative_to(tmp_path))}})
    hint = summary(cfg, Path("runs/hot/ppo/all-squared/seed0")).splitlines()[-1]
    command = shlex.split(hint.split("(", 1)[1].rsplit(" evaluates", 1)[0])
    assert command[:2] == ["python", str(ROOT / "scripts" / "evaluate.py")]
    assert command[2] == f"policy={(run_dir / 'model-0-hot.pt').resolve()}"
    assert command[3] == f"levels=[{hot.resolve()}]"
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    cfg = load_script("evaluate").parse(command[2:])
    assert cfg.levels == ["hot"]


def test_play_takes_a_level_file_by_its_path(hot):
    play = load_script("play")
    options = play.parse_args([f"level={hot}"])
    assert options.level == "hot"
    with pytest.raises(play.UsageError, match=r"^level=.*missing.yaml: the file cannot be read: no such file$"):
        play.parse_args([f"level={hot.parent / 'missing.yaml'}"])
