"""The paper's protocol (baselines/paper/, scripts/reproduce.py): the paper_cpu file expands into the cells the
issue asks for with the decisions it encodes; a bad field is refused naming it; the scheduler respects what each cell
needs, moves an unfinished evaluation aside, blocks what a failed cell would have fed, and runs again only what is
not done; a tiny real protocol runs end to end into a report and a second run does nothing."""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import pytest
import yaml
from helpers import load_script

import evaaa
from evaaa.records import append_rows
from evaaa_baselines.machine import processor
from evaaa_baselines.paper.cell_status import status
from evaaa_baselines.paper.cells import Cell, Command, Layout, build_cells
from evaaa_baselines.paper.choice import choice_text
from evaaa_baselines.paper.plan import plan_text, provenance
from evaaa_baselines.paper.protocol import ProtocolError, load_protocol
from evaaa_baselines.paper.running import Runner

reproduce = load_script("reproduce")


def names(cells) -> list[str]:
    return [c.name for c in cells]


# ------------------------------------------------------------------------------------------------ paper_cpu
def test_paper_cpu_expands_into_the_issue_cells(tmp_path):
    p = load_protocol("paper_cpu")
    cells = build_cells(p, tmp_path)
    got = names(cells)
    S = p.stage_steps
    assert len(got) == len(set(got))
    algos = [n for n, a in p.algorithms.items() if a.enabled]
    assert algos == ["ppo", "dqn", "ppo_lstm"]  # the paper's three on CPU; the counts below follow from the protocol
    levels = evaaa.LEVELS
    for a in algos:
        for seed in (0, 1):
            assert f"train/{a}/curriculum/seed{seed}" in got
            for i, lv in enumerate(levels):
                assert f"eval/{a}/curriculum/seed{seed}/stage{i}-{lv}" in got
                assert f"train/{a}/direct-{lv}/seed{seed}" in got and f"eval/{a}/direct-{lv}/seed{seed}" in got
    ablations = ("no_vision", "no_interoception", "no_olfaction", "no_thermoception", "no_collision")
    assert {n for n in got if "ablation" in n and n.startswith("train/")} == {
        f"train/ppo/ablation-{m}/seed{s}" for m in ablations for s in (0, 1)
    }
    assert not any("dreamer" in n for n in got)  # listed, not enabled
    assert {"ref/oracle", "ref/random"} <= set(got) and got[-1] == "report"
    refs = {c.name: " ".join(c.commands[0].argv) for c in cells if c.kind == "ref"}
    assert "levels=[testbeds]" in refs["ref/oracle"] and "levels=[all]" in refs["ref/random"]  # levels_of
    # algorithms x seeds x (1 curriculum + one direct per level) + the ablations' trainings, their evaluations (each
    # curriculum stage and each direct run), the references, the report
    trains = len(algos) * 2 * (1 + len(levels)) + len(ablations) * 2
    evals = len(algos) * 2 * (len(levels) + len(levels)) + len(ablations) * 2
    assert len(got) == trains + evals + 2 + 1
    by = {c.name: c for c in cells}
    cur = " ".join(by["train/dqn/curriculum/seed1"].commands[0].argv)
    assert f"level.stage_steps={S}" in cur and "reward=dqn" in cur and "threads=1" in cur
    # epsilon reaches its floor at half a stage: (S/2 - learning_starts) / 8 worlds updates
    assert f"algo.eps_anneal_updates={(S // 2 - 5000) // 8}" in cur and "algo.learning_starts=5000" in cur
    assert "algo.normalize_reward=true" in by["train/ppo_lstm/direct-3-1/seed0"].commands[0].argv
    assert f"total_steps={S}" in by["train/ppo_lstm/direct-3-1/seed0"].commands[0].argv
    assert "modality=no_olfaction" in by["train/ppo/ablation-no_olfaction/seed1"].commands[0].argv
    ev = by["eval/ppo/curriculum/seed0/stage3-2-2"].commands
    assert [c.argv[c.argv.index("epsilon=0.05")] for c in ev] == ["epsilon=0.05"] * 2
    assert "levels=[testbeds]" in ev[0].argv and "episodes=10" in ev[0].argv
    assert "levels=[2-2]" in ev[1].argv and "episodes=5" in ev[1].argv
    assert by["eval/ppo/curriculum/seed0/stage3-2-2"].needs == [tmp_path / "runs/ppo/curriculum/seed0/model-3-2-2.pt"]
    assert by["train/ppo/curriculum/seed0"].final_model.name == "model-7-4-2.pt"
    assert not by["train/dqn/direct-1-1/seed0"].keep_checkpoints and by["train/ppo/direct-1-1/seed0"].keep_checkpoints


def test_every_training_command_of_paper_cpu_composes_as_train_py_would(tmp_path):
    from hydra import initialize_config_dir

    from evaaa_baselines.config import compose_checked, register_levels
    from evaaa_baselines.paths import CONF_DIR

    register_levels()
    trains = [c for c in build_cells(load_protocol("paper_cpu"), tmp_path) if c.kind == "train"]
    # one of each set-up and algorithm (the seeds and levels vary nothing else)
    kinds = {(c.name.split("/")[1], c.name.split("/")[2].split("-")[0]): c for c in trains}
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        for cell in kinds.values():
            cfg = compose_checked(cell.commands[0].argv[1:])
            S = load_protocol("paper_cpu").stage_steps
            assert cfg.threads == 1 and cfg.eval.every == S and cfg.checkpoint.every == S // 2
            assert (cfg.level.stage_steps if cfg.level.name == "curriculum" else cfg.total_steps) == S
            assert cfg.reward.name == ("dqn" if cfg.algo.name == "dqn" else "original")
            if cfg.algo.name in ("ppo", "ppo_lstm"):
                assert cfg.algo.normalize_reward is True
            if cfg.algo.name == "dqn":
                assert cfg.algo.eps_anneal_updates * cfg.env.num_envs + cfg.algo.learning_starts == S // 2


def test_plan_lists_every_cell_its_status_estimate_total_and_command(tmp_path, capsys):
    # out=: the repository's own report (docs/results/paper-cpu) would make the report cell "partial"
    assert reproduce.main(["protocol=paper_cpu", "plan=true", f"root={tmp_path}", f"out={tmp_path / 'report'}"]) == 0
    out = capsys.readouterr().out
    cells = build_cells(load_protocol("paper_cpu"), tmp_path, tmp_path / "report")
    for c in cells:
        assert re.search(rf"^{re.escape(c.name)}\s+todo\s+\d+\.\d$", out, re.M), c.name
        assert f"[{c.name}] EVAAA_THREADS=1 python scripts/" in out
    total = float(re.search(r"^  total\s+(\d+\.\d+)", out, re.M).group(1))
    assert total == pytest.approx(sum(c.minutes for c in cells) / 60, abs=0.01)
    assert total <= load_protocol("paper_cpu").budget_cpu_hours  # the protocol's own budget
    for part in ("curriculum", "direct", "ablations", "evaluation"):
        assert part in out
    assert "WARNING" not in out
    # docs/reports.md quotes this plan: its budget table and S must be what the code prints
    docs = (Path(__file__).parents[1] / "docs/reports.md").read_text()
    assert f"| **total** | | | | | **{total:.2f}** |" in docs
    for algo in (n for n, a in load_protocol("paper_cpu").algorithms.items() if a.enabled):
        row = re.search(rf"^  {algo}\s+([\d. ]+)$", out, re.M).group(1).split()
        assert f"| {algo} | " + " | ".join("–" if v == "0.00" else v for v in row) + " |" in docs
    assert f"S = **{load_protocol('paper_cpu').stage_steps:,}** env steps" in docs


def test_the_report_cell_states_the_protocol_s_verdict_margins(tmp_path):
    # paper_learned's file says margin 0.1 and gain_margin 0.1; a changed file reaches report.py's arguments
    argv = build_cells(load_protocol("paper_learned"), tmp_path)[-1].commands[0].argv
    assert "margin=0.1" in argv and "gain_margin=0.1" in argv
    base = yaml.safe_load((Path(__file__).parents[1] / "conf/protocol/smoke.yaml").read_text())
    base["report"] = {**base.get("report", {}), "verdicts": {"margin": 0.2, "gain_margin": 0.05}}
    path = tmp_path / "margins.yaml"
    path.write_text(yaml.safe_dump(base))
    argv = build_cells(load_protocol(path), tmp_path)[-1].commands[0].argv
    assert "margin=0.2" in argv and "gain_margin=0.05" in argv


@pytest.mark.parametrize(
    "change, message",
    [
        ({"algorithms": {"ppo2": {"steps_per_second": 1}}}, "field algorithms: 'ppo2' is not an algorithm; allowed: "),
        ({"stage_steps": 0}, "field stage_steps: Input should be greater than 0"),
        ({"speed": 3}, "field speed: unknown field; allowed: name, description, stage_steps"),
        (
            {"ablations": {"algorithm": "ppo", "level": "1-1", "modalities": ["no_smell"]}},
            "field ablations.modalities: 'no_smell' is not a modality option (conf/modality); allowed: all, no_collision",
        ),
        (
            {"ablations": {"algorithm": "dqn", "level": "1-1", "modalities": ["all"]}},
            "'dqn' is not an enabled algorithm of this protocol; allowed: ppo",
        ),
        (
            {"evaluation": {"steps_per_second": 1, "testbeds": {"levels": ["maze"], "episodes": 1}}},
            "field evaluation.testbeds.levels: 'maze' is not a level, testbed or group",
        ),
        ({"report": {"out": "x", "survival": "best"}}, "field report.survival: Input should be 'eval' or 'train'"),
        (
            {"training": {"eval_steps_per_second": 0}},
            "field training.eval_steps_per_second: Input should be greater than 0",
        ),
        (
            {"report": {"verdicts": {"margin": 0.1, "gain_margin": 10}}},
            "field report.verdicts.gain_margin: Input should be less than 1",
        ),
        (
            {"report": {"verdicts": {"gains": 0.1}}},
            "field report.verdicts.gains: unknown field; allowed: margin, gain_margin",
        ),
        (
            {"references": {"steps_per_second": 1, "levels_of": {"oracle": ["maze"]}}},
            "field references.levels_of: 'maze' is not a level, testbed or group",
        ),
    ],
)
def test_a_bad_field_is_refused_naming_it(tmp_path, change, message):
    base = yaml.safe_load((Path(__file__).parents[1] / "conf/protocol/smoke.yaml").read_text())
    base.update(change)
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(base))
    with pytest.raises(ProtocolError) as err:
        load_protocol(path)
    assert message in str(err.value)
    assert str(path) in str(err.value)


def _smoke_with(tmp_path, **changes) -> Path:
    """conf/protocol/smoke.yaml with ``changes`` (``training__direct_seed_offset=1``: a field of a part) written to a
    file of its own."""
    base = yaml.safe_load((Path(__file__).parents[1] / "conf/protocol/smoke.yaml").read_text())
    for key, value in changes.items():
        *parts, last = key.split("__")
        where = base
        for part in parts:
            where = where[part]
        where[last] = value
    path = tmp_path / "changed.yaml"
    path.write_text(yaml.safe_dump(base))
    return path


def _load_error(path: Path) -> str:
    with pytest.raises(ProtocolError) as err:
        load_protocol(path)
    assert "\n" not in str(err.value)  # one line
    return str(err.value)


def world_seeds(cells) -> dict[str, set[int]]:
    """The seeds of the worlds each arm trains on, read from the planned training commands: a curriculum run of seed
    s trains stage i on those of s + i (baselines/run.py), a direct run on those of its seed."""
    arms: dict[str, set[int]] = {"curriculum": set(), "direct": set()}
    for c in cells:
        if c.kind != "train" or not ("/curriculum/" in c.name or "/direct-" in c.name):
            continue
        argv = c.commands[0].argv
        seed = int(next(a for a in argv if a.startswith("seed=")).removeprefix("seed="))
        stages = next((a for a in argv if a.startswith("level.stages=")), None)
        n = len(stages.removeprefix("level.stages=[").rstrip("]").split(",")) if stages else 1
        arms["curriculum" if stages else "direct"] |= {seed + i for i in range(n)}
    return arms


def test_direct_seeds_among_a_curriculum_s_seed_plus_stage_are_refused(tmp_path):
    # smoke: seed 0, stages 1-1 and 1-2, so the curriculum trains on the worlds of seeds 0 and 1; an offset of 1 puts
    # the direct runs on seed 1, curriculum stage 1's worlds
    message = _load_error(_smoke_with(tmp_path, training__direct_seed_offset=1))
    assert (
        "field training.direct_seed_offset: the direct runs' training worlds (seeds 1) are the curriculum's (seed + "
        "stage: 0-1), shared by the arms of the comparison; allowed: an offset that takes every direct seed out of "
        "them (the smallest: 2), or training.allow_shared_worlds: true"
    ) in message
    assert "direct_seed_offset" in _load_error(_smoke_with(tmp_path, training__direct_seed_offset=0))
    # said explicitly, the overlap loads (paper_learned's record ran so), and the plan names it
    shared = load_protocol(_smoke_with(tmp_path, training__direct_seed_offset=0, training__allow_shared_worlds=True))
    arms = world_seeds(build_cells(shared, tmp_path))
    assert arms == {"curriculum": {0, 1}, "direct": {0}}
    plan = plan_text(shared, build_cells(shared, tmp_path), Layout(tmp_path), 1)
    assert "the arms share the worlds of seeds 0 (training.allow_shared_worlds)" in plan
    learned = world_seeds(build_cells(load_protocol("paper_learned"), tmp_path))
    assert learned["curriculum"] & learned["direct"] == {0, 1, 2}


@pytest.mark.parametrize("name, offset", [("smoke", 2), ("paper_gpu", 10)])
def test_with_the_offset_the_arms_train_on_disjoint_worlds_and_the_plan_names_them(tmp_path, capsys, name, offset):
    p = load_protocol(name)
    assert p.training.direct_seed_offset == offset
    cells = build_cells(p, tmp_path)
    arms = world_seeds(cells)
    assert arms["curriculum"] == {s + i for s in p.seeds for i in range(len(p.stage_levels))}
    assert arms["direct"] == {s + offset for s in p.seeds}
    assert not arms["curriculum"] & arms["direct"]
    # the ablations' `all` is the direct run on their level: every ablation trains on the direct runs' seeds
    ablation_seeds = {int(c.name.rsplit("seed", 1)[1]) for c in cells if "/ablation-" in c.name and c.kind == "train"}
    assert ablation_seeds == arms["direct"]
    assert reproduce.main([f"protocol={name}", "plan=true", f"root={tmp_path}", f"out={tmp_path / 'r'}"]) == 0
    seeds = ", ".join(map(str, sorted(arms["direct"])))
    assert f"direct runs and ablations on seeds {seeds} (seed + direct_seed_offset {offset}); disjoint" in (
        capsys.readouterr().out
    )


@pytest.mark.parametrize(
    "changes, message",
    [
        (
            {"training__overrides": ["preset=debug", "eval.sample=false"]},
            "field evaluation.compare: validation chooses from in-training validation evaluations in both acting "
            "modes; training.overrides must include eval.both_modes=true (and no algorithm's overrides set it false); "
            "allowed: sample, mode, or validation with eval.both_modes=true",
        ),
        (
            {"algorithms__ppo__overrides": ["reward=original", "eval.both_modes=false"]},
            "field evaluation.compare: validation chooses from in-training validation evaluations in both acting modes",
        ),
        (
            {"evaluation__modes": ["sample"]},
            "field evaluation.compare: validation needs both acting modes evaluated (evaluation.modes: [sample, mode]; "
            "here ['sample']); allowed: sample, or validation with both modes",
        ),
        (
            {"evaluation__modes": ["sample"], "evaluation__compare": "mode"},
            "field evaluation.compare: 'mode' is not an evaluated acting mode (evaluation.modes: ['sample']); "
            "allowed: sample",
        ),
        ({"evaluation__compare": "best"}, "field evaluation.compare: Input should be 'sample', 'mode' or 'validation'"),
    ],
)
def test_a_compared_mode_that_cannot_be_chosen_is_refused_at_load(tmp_path, changes, message):
    assert message in _load_error(_smoke_with(tmp_path, **changes))


def test_compare_validation_makes_a_choice_cell_every_checkpoint_evaluation_waits_for(tmp_path):
    p = load_protocol("smoke")
    assert p.evaluation.compare == "validation"
    cells = build_cells(p, tmp_path)
    by = {c.name: c for c in cells}
    choose = by["choose/acting"]
    trains = [c.name for c in cells if c.kind == "train"]
    assert choose.needs_cells == trains and choose.needs == [Layout(tmp_path).marker(n) for n in trains]
    argv = choose.commands[0].argv
    assert argv[0] == "scripts/choose_acting.py" and f"out={tmp_path / 'compared_mode.json'}" in argv
    assert all(f"{by[n].run_dir}" in argv[1] for n in trains)
    for c in cells:
        if c.kind == "eval":
            assert "choose/acting" in c.needs_cells and tmp_path / "compared_mode.json" in c.needs
    report = by["report"].commands[0].argv
    assert f"compare_from={tmp_path / 'compared_mode.json'}" in report and not any(
        a.startswith("compare=") for a in report
    )
    # a fixed choice: no such cell, and the report compares it (mode, not the first of the modes)
    fixed = _smoke_with(tmp_path, evaluation__compare="mode")
    cells = build_cells(load_protocol(fixed), tmp_path)
    assert "choose/acting" not in names(cells) and all("choose/acting" not in c.needs_cells for c in cells)
    assert "compare=mode+epsilon=0.05" in cells[-1].commands[0].argv


def test_an_evaluation_waits_for_the_choice_and_runs_once_it_is_made(tmp_path):
    # train -> choose -> eval: with three slots the evaluation still waits for the choice after its model exists
    lay, (train, ev, rep) = _fake(tmp_path)
    choice = lay.root / "compared_mode.json"
    code = f"import pathlib, time; time.sleep(0.3); pathlib.Path({str(choice)!r}).write_text('{{}}')"
    choose = Cell(
        "choose/acting",
        "choose",
        [Command(_py(code))],
        1.0,
        "c",
        needs=[lay.marker("train/a")],
        needs_cells=["train/a"],
        choice=choice,
    )
    ev.needs, ev.needs_cells = [*ev.needs, choice], [*ev.needs_cells, "choose/acting"]
    ev.commands[0].argv[-1] = (
        ev.commands[0]
        .argv[-1]
        .replace("assert m.exists();", f"assert m.exists() and pathlib.Path({str(choice)!r}).exists();")
    )
    rep.needs_cells.append("choose/acting")
    cells = [train, choose, ev, rep]
    assert _scheduler(lay, cells, jobs=3).run(cells) == 0
    assert [status(c, lay, cells) for c in cells] == ["done"] * 4
    # the evaluation started once the choice was written (its done-marker may come a moment after the file: the
    # evaluation waits for the file, as reproduce.py's do)
    assert choice.stat().st_mtime <= (ev.commands[0].out / "episodes.csv").stat().st_mtime
    # a training done in an earlier session (not among the cells to run): its evaluation waits for the choice alone
    (ev.commands[0].out / "episodes.csv").unlink()
    choice.unlink()
    assert _scheduler(lay, cells, jobs=3).run([choose, ev]) == 0 and status(ev, lay) == "done"


def _eval_csv(run: Path, rows: list[tuple]) -> Path:
    """An eval.csv of (env_steps, stage, level, worlds, acting, steps) rows, one per episode."""
    run.mkdir(parents=True, exist_ok=True)
    lines = ["env_steps,stage,level,worlds,acting,episode,steps,return,end_type"]
    lines += [f"{e},{s},{lv},{w},{a},{i},{n},0,FoodOutOfRange" for i, (e, s, lv, w, a, n) in enumerate(rows)]
    (run / "eval.csv").write_text("\n".join(lines) + "\n")
    return run


def test_the_compared_mode_is_the_one_whose_last_validation_evaluations_survive_longer(tmp_path, capsys):
    from evaaa_baselines.paper.choice import ChoiceError, choose

    # a curriculum of two stages: each stage's last validation evaluation counts (stage 0's earlier one, where
    # sampling was far ahead, does not; nor does a row on other worlds)
    cur = _eval_csv(
        tmp_path / "runs/cur",
        [
            (64, 0, "1-1", "validation", "sample", 5000),
            (64, 0, "1-1", "validation", "mode", 10),
            (128, 0, "1-1", "validation", "sample", 100),
            (128, 0, "1-1", "validation", "sample", 300),
            (128, 0, "1-1", "validation", "mode", 400),
            (128, 0, "1-1", "validation", "mode", 600),
            (128, 0, "1-1", "test", "mode", 1),
            (256, 1, "1-2", "validation", "sample", 200),
            (256, 1, "1-2", "validation", "sample", 200),
            (256, 1, "1-2", "validation", "mode", 100),
            (256, 1, "1-2", "validation", "mode", 120),
        ],
    )
    direct = _eval_csv(
        tmp_path / "runs/direct",
        [(128, 0, "1-2", "validation", "sample", 1000), (128, 0, "1-2", "validation", "mode", 500)],
    )
    # DQN acts the same either way: its rows are `mode` only, and it is left out, named
    dqn = _eval_csv(tmp_path / "runs/dqn", [(128, 0, "1-1", "validation", "mode", 9000)])
    got = choose([cur, direct, dqn], first="sample", epsilon=0.05)
    # by hand: sample 100, 300, 200, 200, 1000 (mean 360); mode 400, 600, 100, 120, 500 (mean 344): sample
    assert got["chosen"] == "sample" and got["compare"] == "sample+epsilon=0.05"
    assert got["survival"]["sample"] == {"episodes": 5, "mean": 360.0, "iqm": 233.33}
    assert got["survival"]["mode"] == {"episodes": 5, "mean": 344.0, "iqm": 340.0}
    assert (got["networks"], got["runs"]) == (3, 2)
    assert got["left_out"] == [f"{dqn} stage 0 (1-1): one acting mode only (mode)"]
    assert [(n["stage"], n["sample"], n["mode"]) for n in got["per_network"]] == [
        (0, 200.0, 500.0),
        (1, 200.0, 110.0),
        (0, 1000.0, 500.0),
    ]
    # without the direct run `mode` survives longer (mean 305 against 200)
    assert choose([cur], first="sample")["chosen"] == "mode"
    # a tie goes to the protocol's first mode
    tie = _eval_csv(tmp_path / "runs/tie", [(8, 0, "1-1", "validation", m, 50) for m in ("sample", "mode")])
    assert choose([tie], first="mode")["chosen"] == "mode" and choose([tie], first="sample")["chosen"] == "sample"
    assert "`mode`, the protocol's first mode, both surviving as long — mean 50.0" in choice_text(choose([tie], "mode"))
    assert "`sample`, whose in-training validation evaluations survived longer — mean 360.0" in choice_text(got)
    with pytest.raises(ChoiceError, match="runs: no network has a validation evaluation in both acting modes"):
        choose([dqn])
    # the script: written once, never over the first; refused where a checkpoint's evaluation exists already
    script = load_script("choose_acting")
    out, evals = tmp_path / "compared_mode.json", tmp_path / "evals"
    append_rows(evals / "ref" / "random" / "episodes.csv", [{"policy": "random", "steps": 5}])
    args = [f"runs=[{cur},{direct},{dqn}]", "epsilon=0.05", f"evals={evals}", f"out={out}"]
    assert script.main(args) == 0
    assert json.loads(out.read_text())["chosen"] == "sample"
    assert "wrote " in capsys.readouterr().out
    for setup, message in (
        (lambda: None, "out: " + str(out) + " exists: the compared mode is chosen once; nothing was written"),
        (
            lambda: (out.unlink(), append_rows(evals / "ppo" / "x" / "episodes.csv", [{"policy": "m.pt", "steps": 1}])),
            f"evals: {evals / 'ppo' / 'x' / 'episodes.csv'} holds a checkpoint's evaluation: the compared mode is "
            "chosen before any (1 found); nothing was written",
        ),
    ):
        setup()
        with pytest.raises(SystemExit) as exit_:
            script.main(args)
        assert exit_.value.code == 2 and message in capsys.readouterr().err
    assert not out.exists()


def test_a_second_session_on_the_same_root_is_refused(tmp_path, capsys):
    import fcntl

    spec = tmp_path / "tiny.yaml"
    spec.write_text(TINY)
    root = tmp_path / "root"
    root.mkdir()
    with open(root / ".reproduce.lock", "a+") as held:
        fcntl.flock(held, fcntl.LOCK_EX | fcntl.LOCK_NB)
        held.write("4242")
        held.flush()
        with pytest.raises(SystemExit) as stop:
            reproduce.main([f"protocol={spec}", f"root={root}", "progress=false"])
    assert stop.value.code == 2
    assert f"another reproduce.py (pid 4242) is running on {root}; nothing was started" in capsys.readouterr().err
    assert sorted(p.name for p in root.iterdir()) == [".reproduce.lock"]


def test_an_unknown_protocol_name_and_a_bad_key_are_one_line_errors(capsys):
    with pytest.raises(SystemExit) as stop:
        reproduce.main(["protocol=paper_tpu", "plan=true"])
    assert stop.value.code == 2
    assert (
        "protocol=paper_tpu: no such protocol; allowed: paper_cpu, paper_gpu, paper_learned, paper_settle, "
        "paper_settle_pilot, smoke" in capsys.readouterr().err
    )
    with pytest.raises(SystemExit) as stop:
        reproduce.main(["protocol=smoke", "executor=kubernetes"])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and "executor=kubernetes" in err and "local, ray, slurm" in err
    with pytest.raises(SystemExit):
        reproduce.main(["protocol=smoke", "cells=[train/nothing]", "plan=true"])
    assert "no cell named 'train/nothing'" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------------ the scheduler
def _py(code: str) -> list[str]:
    return ["-c", code]


def _fake(tmp_path: Path, fail_train: bool = False):
    """A train cell that writes its final model, an eval cell that needs it and writes episodes.csv, a report."""
    lay = Layout(tmp_path)
    run_dir = lay.runs / "a"
    model = run_dir / "model-0-1-1.pt"
    out = lay.evals / "a"
    code = (
        f"import pathlib,time; d=pathlib.Path({str(run_dir)!r}); d.mkdir(parents=True, exist_ok=True); "
        f"time.sleep(0.3); (d/'model-0-1-1.pt').write_text('m')" + ("; raise SystemExit(3)" if fail_train else "")
    )
    train = Cell("train/a", "train", [Command(_py(code))], 1.0, "a", run_dir=run_dir, final_model=model)
    ev_code = (
        f"import pathlib; m=pathlib.Path({str(model)!r}); assert m.exists(); o=pathlib.Path({str(out)!r}); "
        "o.mkdir(parents=True, exist_ok=True); (o/'episodes.csv').write_text('x')"
    )
    ev = Cell("eval/a", "eval", [Command(_py(ev_code), out)], 1.0, "e", needs=[model], needs_cells=["train/a"])
    report_out = tmp_path / "report"
    rep_code = (
        f"import pathlib; o=pathlib.Path({str(report_out)!r}); o.mkdir(exist_ok=True); (o/'report.md').write_text('r')"
    )
    rep = Cell(
        "report", "report", [Command(_py(rep_code))], 1.0, "r", needs_cells=["train/a", "eval/a"], report_out=report_out
    )
    return lay, [train, ev, rep]


def _episodes(cell: Cell) -> Path:
    return cell.commands[0].out / "episodes.csv"


def _scheduler(lay, cells, **kw):
    p = load_protocol("smoke")
    return Runner(p, cells, lay, progress=False, echo=lambda s: None, **kw)


def test_cells_run_when_what_they_need_exists_and_a_second_run_has_nothing_to_do(tmp_path):
    lay, cells = _fake(tmp_path)
    assert [status(c, lay, cells) for c in cells] == ["todo"] * 3
    assert _scheduler(lay, cells, jobs=3).run(cells) == 0  # 3 at once: the eval still waits for the model
    assert [status(c, lay, cells) for c in cells] == ["done"] * 3
    assert lay.marker("train/a").is_file() and lay.marker("report").is_file()
    assert all(lay.log(c.name).read_text().count("\n== ") == 1 for c in cells)


def _stamp(lay: Layout, cell: str, finished: str) -> None:
    """Give ``cell``'s done-marker another finished time (its UTC stamp, as the runner writes it)."""
    marker = lay.marker(cell)
    marker.write_text(json.dumps({**json.loads(marker.read_text()), "finished": finished}) + "\n")


def test_a_report_made_after_every_cell_stays_done_whatever_order_a_clone_wrote_the_files_in(tmp_path):
    # git keeps no modification times: a clone writes the record's files in its own order, often the report's marker
    # before the evaluations' episodes.csv (issue 64: a fresh clone's plan said "102 done, 1 partial"); the markers'
    # finished stamps say which came first
    lay, cells = _fake(tmp_path)
    assert _scheduler(lay, cells).run(cells) == 0
    _stamp(lay, "train/a", "20261129T040000Z")
    _stamp(lay, "eval/a", "20261129T041000Z")
    _stamp(lay, "report", "20261207T142044Z")
    os.utime(lay.marker("report"), (1_000_000, 1_000_000))  # checked out first
    assert [status(c, lay, cells) for c in cells] == ["done"] * 3
    # an evaluation redone after the report (its marker's stamp later): the report is out of date again
    _stamp(lay, "eval/a", "20261208T000000Z")
    assert status(cells[2], lay, cells) == "partial"


def test_a_report_is_out_of_date_where_a_cell_without_a_marker_was_written_after_it(tmp_path):
    lay, cells = _fake(tmp_path)
    assert _scheduler(lay, cells).run(cells) == 0
    lay.marker("eval/a").unlink()  # an evaluation made by hand: done by its episodes.csv alone, dated by its file
    report_made = math.floor(time.time()) + 3600  # later than the training's own stamp
    _stamp(lay, "report", datetime.fromtimestamp(report_made, timezone.utc).strftime("%Y%m%dT%H%M%SZ"))
    os.utime(lay.marker("report"), (1_000_000, 1_000_000))
    for written, state in ((report_made + 2, "partial"), (report_made + 0.9, "done"), (report_made - 60, "done")):
        os.utime(_episodes(cells[1]), (written, written))  # the report's stamp is cut to its second
        assert status(cells[1], lay, cells) == "done" and status(cells[2], lay, cells) == state, written


def test_a_clone_dates_a_cell_without_a_marker_by_the_commit_of_its_files(tmp_path):
    # issue 64: on a fresh clone `reproduce.py plan=true` said "172 done, 1 partial": two evaluations of the committed
    # record have no done-marker, and the clone had written their episodes.csv after the report's marker
    lay, cells = _fake(tmp_path / "repo")
    assert _scheduler(lay, cells).run(cells) == 0
    lay.marker("eval/a").unlink()
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-C", str(tmp_path / "repo")]
    subprocess.run([*git, "init", "-q"], check=True)
    subprocess.run([*git, "add", "-A"], check=True)
    subprocess.run([*git, "commit", "-q", "-m", "record"], check=True)
    committed = float(subprocess.run([*git, "log", "-1", "--format=%ct"], capture_output=True, text=True).stdout)
    _stamp(lay, "report", datetime.fromtimestamp(committed + 60, timezone.utc).strftime("%Y%m%dT%H%M%SZ"))
    subprocess.run([*git, "commit", "-q", "-am", "report"], check=True)
    later = committed + 3600  # as a clone leaves it: checked out after the report's marker
    os.utime(_episodes(cells[1]), (later, later))
    assert status(cells[2], lay, cells) == "done"
    _episodes(cells[1]).write_text(
        _episodes(cells[1]).read_text() + "\n"
    )  # redone by hand since: newer than the report
    os.utime(_episodes(cells[1]), (later, later))
    assert status(cells[2], lay, cells) == "partial"


def test_an_evaluation_runs_as_soon_as_its_model_exists_before_later_trainings(tmp_path):
    # two trainings and their evaluations, one at a time: a, eval a, b, eval b (not a, b, eval a, eval b: the early
    # cells answer something on their own)
    lay, (train_a, eval_a, _) = _fake(tmp_path / "a")
    lay_b, (train_b, eval_b, _) = _fake(tmp_path / "b")
    order = tmp_path / "order.txt"
    for cell, name in ((train_a, "train/a"), (eval_a, "eval/a"), (train_b, "train/b"), (eval_b, "eval/b")):
        cell.name = name
        note = f"open({str(order)!r}, 'a').write({name!r} + chr(10)); "
        cell.commands = [Command([*c.argv[:-1], note + c.argv[-1]], c.out) for c in cell.commands]
    eval_b.needs_cells = ["train/b"]
    cells = [train_a, eval_a, train_b, eval_b]
    assert _scheduler(lay, cells, jobs=1).run(cells) == 0
    assert order.read_text().split() == ["train/a", "eval/a", "train/b", "eval/b"]


def test_every_finished_cell_records_the_wall_time_it_took_and_the_plan_sums_them(tmp_path):
    import json

    lay, cells = _fake(tmp_path)
    train = cells[0]
    # half a second of work, then half a second asleep, then the model
    code = (
        f"import pathlib,time; t=time.process_time(); exec('while time.process_time() - t < 0.5: pass'); "
        f"time.sleep(0.5); d=pathlib.Path({str(train.run_dir)!r}); d.mkdir(parents=True, exist_ok=True); "
        f"(d/'model-0-1-1.pt').write_text('m')"
    )
    train.commands = [Command(_py(code))]
    assert _scheduler(lay, cells).run(cells) == 0
    markers = {c.name: json.loads(lay.marker(c.name).read_text()) for c in cells}
    assert markers["train/a"]["seconds"] >= 1.0  # wall time: both halves
    assert 0.5 <= markers["train/a"]["cpu_seconds"] < markers["train/a"]["seconds"] - 0.3  # CPU time: the work
    assert all(0 <= m["cpu_seconds"] <= m["seconds"] + 0.1 for m in markers.values())
    assert not list(lay.done.rglob("*.seconds"))  # the running account is folded into the marker
    # and names the processor its CPU time was spent on (one here, so all of it)
    assert markers["train/a"]["processors"] == {processor(): markers["train/a"]["cpu_seconds"]}
    plan = plan_text(load_protocol("smoke"), cells, lay, 1)
    assert re.search(rf"^train/a\s+done\s+1\.0\s+{markers['train/a']['cpu_seconds'] / 60:.1f}$", plan, re.M)
    total = sum(m["cpu_seconds"] for m in markers.values()) / 3600
    assert f"measured: the 3 timed done cells took {total:.2f} CPU-hours, against 0.05" in plan


def test_a_failed_training_blocks_its_evaluation_and_the_report(tmp_path):
    lay, cells = _fake(tmp_path, fail_train=True)
    messages = []
    sched = Runner(load_protocol("smoke"), cells, lay, progress=False, echo=messages.append, jobs=2)
    assert sched.run(cells) == 1
    assert not lay.marker("train/a").exists()  # exited 3: not done, although its model file exists
    assert status(cells[0], lay, cells) == "partial"
    assert any("train/a: FAILED (exit status 3)" in m for m in messages)
    assert not (tmp_path / "report" / "report.md").exists()


def test_an_unfinished_evaluation_is_moved_aside_and_run_again(tmp_path):
    lay, cells = _fake(tmp_path)
    _scheduler(lay, cells).run(cells)
    out = lay.evals / "a"
    (out / "episodes.csv").rename(out / ".episodes.csv.partial")  # as evaluate.py leaves a killed evaluation
    assert status(cells[1], lay, cells) == "partial"
    assert status(cells[2], lay, cells) == "partial"  # a report is done only while every other cell is
    todo = [c for c in cells if status(c, lay, cells) != "done"]
    assert names(todo) == ["eval/a", "report"]
    _scheduler(lay, cells).run(todo)
    aside = list(lay.evals.glob("a.partial-*"))
    assert len(aside) == 1 and (aside[0] / ".episodes.csv.partial").is_file()  # kept, never deleted
    assert (out / "episodes.csv").is_file() and status(cells[1], lay, cells) == "done"
    assert status(cells[2], lay, cells) == "done"
    assert lay.log("train/a").read_text().count("\n== ") == 1  # the training did not run again
    assert lay.log("report").read_text().count("\n== ") == 2


def test_a_started_training_run_continues_with_resume_and_redo_starts_over(tmp_path):
    lay, cells = _fake(tmp_path)
    train = cells[0]
    from evaaa_baselines.paper.cell_status import command_now

    assert command_now(train, lay)[0].argv == train.commands[0].argv
    train.run_dir.mkdir(parents=True)
    (train.run_dir / "checkpoint.pt").write_text("c")
    assert status(train, lay) == "partial"
    assert command_now(train, lay)[0].argv[-1] == "resume=true"
    assert command_now(train, lay, redo=True)[0].argv[-1] == "start_over=true"
    # a started run without any checkpoint (a clone of committed results holds none): trained again from zero,
    # its old folder moved aside by train.py
    (train.run_dir / "checkpoint.pt").unlink()
    (train.run_dir / "episodes.csv").write_text("e")
    assert command_now(train, lay)[0].argv[-1] == "start_over=true"
    # a finished run whose checkpoints were deleted (keep_checkpoints: false) only lacks its marker
    train.final_model.write_text("m")
    assert command_now(train, lay) == []


def test_max_minutes_starts_nothing_new(tmp_path):
    lay, cells = _fake(tmp_path)
    sched = _scheduler(lay, cells, max_minutes=1e-9)
    import time

    time.sleep(0.01)
    assert sched.run(cells) == 1
    assert [status(c, lay, cells) for c in cells] == ["todo"] * 3


def test_end_minutes_starts_only_cells_whose_estimate_fits_and_leaves_what_needs_them(tmp_path):
    lay, cells = _fake(tmp_path)
    messages = []
    train, ev, rep = cells
    train.minutes = 30.0  # more than the 20 minutes left: neither it nor the cells that need its model start
    sched = Runner(load_protocol("smoke"), cells, lay, progress=False, echo=messages.append, end_minutes=20)
    assert sched.run(cells) == 1
    assert [status(c, lay, cells) for c in cells] == ["todo"] * 3
    assert not lay.log("train/a").exists()
    assert any(m.startswith("train/a: not started: its estimate (plan=true), 30 minutes") for m in messages), messages
    assert "3 cell(s) not started (max_minutes, end_minutes); the same command continues" in messages
    # an estimate just over the minutes left reads in tenths, not "20 minutes does not fit in the 20 minutes"
    train.minutes = 20.3
    messages.clear()
    assert sched.run(cells) == 1
    assert any("20.3 minutes, does not fit in the 20.0 minutes end_minutes=20 leaves" in m for m in messages), messages
    # and in hundredths where tenths would ("23.7 left, does not fit in the 23.7 minutes")
    train.minutes = 20.03
    messages.clear()
    assert sched.run(cells) == 1
    assert any(re.search(r"20\.03 minutes, does not fit in the (20\.00|19\.9\d) minutes", m) for m in messages), (
        messages
    )
    train.minutes = 30.0
    # the model is there (another session made it): the evaluation fits and runs; the report waits for train/a
    train.final_model.parent.mkdir(parents=True)
    train.final_model.write_text("m")
    messages.clear()
    assert sched.run(cells) == 1
    assert [status(c, lay, cells) for c in cells] == ["partial", "done", "todo"]  # a model, no marker yet
    assert "2 cell(s) not started (max_minutes, end_minutes); the same command continues" in messages
    # time enough: every cell runs
    train.minutes = 19.0
    assert _scheduler(lay, cells, end_minutes=20).run([c for c in cells if status(c, lay, cells) != "done"]) == 0
    assert [status(c, lay, cells) for c in cells] == ["done"] * 3


def test_end_minutes_says_when_a_cell_stopped_fitting_while_it_waited_for_a_slot(tmp_path):
    # one slot: b is ready at once and fits (2.4 s of the 3 s left) but a holds the slot for 1.5 s; b is left when its
    # estimate stops fitting, and the line says it waited (not "2.4 minutes does not fit in the 2.4 minutes")
    lay, (train_a, _, _) = _fake(tmp_path / "a")
    _, (train_b, _, _) = _fake(tmp_path / "b")
    train_b.name = "train/b"
    train_a.minutes, train_b.minutes = 0.01, 0.04
    train_a.commands = [
        Command([*c.argv[:-1], "import time; time.sleep(1.5); " + c.argv[-1]]) for c in train_a.commands
    ]
    messages = []
    sched = Runner(
        load_protocol("smoke"), [train_a, train_b], lay, progress=False, echo=messages.append, jobs=1, end_minutes=0.05
    )
    assert sched.run([train_a, train_b]) == 1
    assert status(train_a, lay) == "done" and status(train_b, lay) == "todo"
    assert (
        "train/b: not started: it waited for a free slot (jobs=1) until its estimate (plan=true), 0.04 minutes, "
        "no longer fit in the minutes end_minutes=0.05 leaves"
    ) in messages, messages


def test_end_minutes_counts_the_cpu_minutes_a_training_with_a_checkpoint_has_run(tmp_path):
    lay, cells = _fake(tmp_path)
    train = cells[0]
    train.minutes = 30.0
    messages = []
    sched = Runner(load_protocol("smoke"), cells, lay, progress=False, echo=messages.append, end_minutes=20)
    clock = lay.clock("train/a")
    clock.parent.mkdir(parents=True, exist_ok=True)
    clock.write_text(json.dumps({"seconds": 600.0, "cpu_seconds": 300.0}))
    # an account but no checkpoint (cut short before its first): it would start over, so the whole estimate counts
    assert sched.run([train]) == 1
    assert any(
        m.startswith("train/a: not started: its estimate (plan=true), 30 minutes, does not fit") for m in messages
    )
    # with its checkpoint, 5 CPU-minutes run: 25 left, still more than 20
    train.run_dir.mkdir(parents=True)
    (train.run_dir / "checkpoint.pt").write_text("c")
    messages.clear()
    assert sched.run([train]) == 1
    assert any("30 minutes, less the 5 CPU-minutes it has run, 25 left, does not fit" in m for m in messages), messages
    assert "0.45 h left, less what started trainings have run" in plan_text(load_protocol("smoke"), cells, lay, 1)
    # 15 CPU-minutes run: 15 left, it fits and runs, and its marker counts every session's CPU time
    clock.write_text(json.dumps({"seconds": 1800.0, "cpu_seconds": 900.0}))
    assert sched.run([train]) == 0
    assert status(train, lay, cells) == "done"
    assert lay.took("train/a") > 900.0


def test_only_the_selected_cells_run(tmp_path, capsys):
    lay, cells = _fake(tmp_path)
    _scheduler(lay, cells).run(cells[:1])
    assert status(cells[0], lay, cells) == "done" and status(cells[1], lay, cells) == "todo"


# ------------------------------------------------------------------------------------------------ end to end
TINY = """
name: tiny
stage_steps: 128
seeds: [0]
levels: [1-1]
training:
  overrides: [preset=debug, logger=csv, progress=false, eval.episodes=2]
  curriculum: false
algorithms:
  ppo: {steps_per_second: 30, overrides: [reward=original]}
evaluation:
  testbeds: {levels: [two-resource-temp], episodes: 1, num_envs: 1}
  steps_per_second: 300
report: {out: null}
"""


def test_the_report_ends_with_the_commands_that_remake_it_and_the_time_its_cells_took(tmp_path):
    import json

    lay, cells = _fake(tmp_path)
    train = cells[0]
    train.commands = [
        Command(
            _py(
                f"import pathlib,time; t=time.process_time(); "
                f"exec('while time.process_time() - t < 0.4: pass'); "
                f"d=pathlib.Path({str(train.run_dir)!r}); d.mkdir(parents=True, exist_ok=True); "
                f"(d/'model-0-1-1.pt').write_text('m')"
            )
        )
    ]
    assert _scheduler(lay, cells, selects="protocol=smoke root=/some/where").run(cells) == 0
    text = (tmp_path / "report" / "report.md").read_text()
    assert text.startswith("r\n## How this report was made")  # appended to what report.py wrote
    assert "2 cells besides the report, 2 of them done when this report was made" in text
    assert "python scripts/reproduce.py protocol=smoke root=/some/where plan=true" in text
    assert 'python scripts/reproduce.py protocol=smoke root=/some/where "cells=[train/a]" redo=true' in text
    marker = {c.name: json.loads(lay.marker(c.name).read_text()) for c in cells[:2]}
    row = re.search(r"^\| a \| 1 \| ([0-9.]+) \| ([0-9.]+) \| ([0-9.]+) \|$", text, re.M)
    assert row and float(row[1]) == round(marker["train/a"]["cpu_seconds"] / 3600, 2) and float(row[2]) == 0.02
    total = sum(m["cpu_seconds"] for m in marker.values()) / 3600
    assert f"| **all** | 2 | **{total:.2f}** | 0.03 |" in text
    assert "The processors that ran them (CPU-hours; " in text and f"): {processor()} {total:.2f}." in text
    # a marker from before processors were recorded counts as "not recorded"
    old = json.loads(lay.marker("train/a").read_text())
    lay.marker("train/a").write_text(json.dumps({k: v for k, v in old.items() if k != "processors"}))
    joined = "\n".join(provenance(load_protocol("smoke"), cells, lay))
    spent = marker["eval/a"]["cpu_seconds"] / 3600
    assert f"): {processor()} {spent:.2f}; not recorded {old['cpu_seconds'] / 3600:.2f} (not recorded: " in joined
    # a done cell without a time (run before cells were timed) is named, with its estimate
    lay.marker("eval/a").write_text(json.dumps({"finished": "x", "seconds": None, "cpu_seconds": None}))
    lines = provenance(load_protocol("smoke"), cells, lay)
    assert (
        "1 done cells were not timed (run before cells were): eval/a; the protocol file estimates them at 0.02"
        in "\n".join(lines)
        and "python scripts/reproduce.py protocol=smoke plan=true" in "\n".join(lines)
    )


def test_a_tiny_protocol_runs_end_to_end_and_a_second_run_does_nothing(tmp_path, capsys):
    spec = tmp_path / "tiny.yaml"
    spec.write_text(TINY.replace("steps_per_second: 30,", "steps_per_second: 30, keep_checkpoints: false,"))
    root = tmp_path / "root"
    args = [f"protocol={spec}", f"root={root}", "progress=false"]
    assert reproduce.main(args) == 0
    out = capsys.readouterr().out
    assert "3 of 3 cells to run" in out and "3 of 3 cells done" in out
    report = (root / "report" / "report.md").read_text()
    assert "## The paper's claims" in report and "(b) curriculum beats direct training" in report
    assert "mode+epsilon=0.05" in report
    assert (root / "runs/ppo/direct-1-1/seed0/model-0-1-1.pt").is_file()
    assert (root / "done/train/ppo/direct-1-1/seed0.done").is_file()
    assert (root / "evals/ppo/direct-1-1/seed0/testbeds/episodes.csv").is_file()
    # keep_checkpoints: false: the finished run's checkpoints are gone, the run is reported finished all the same
    assert not list((root / "runs/ppo/direct-1-1/seed0").glob("checkpoint*.pt"))
    assert re.search(
        r"\| \S*runs/ppo/direct-1-1/seed0 \| ppo \| all \| original \| 1-1 \| 0 \| 128 / 128 \| finished \|", report
    )
    log = (root / "logs/train/ppo/direct-1-1/seed0.log").read_text()
    assert "EVAAA_THREADS=1 python scripts/train.py algo=ppo level=1-1 total_steps=128 seed=0 threads=1" in log
    before = {p: p.stat().st_mtime for p in root.rglob("*") if p.is_file()}
    assert reproduce.main(args) == 0
    assert "nothing to do" in capsys.readouterr().out
    assert {p: p.stat().st_mtime for p in root.rglob("*") if p.is_file()} == before


@pytest.mark.slow
def test_a_killed_protocol_continues_only_what_is_not_done(tmp_path, capsys):
    spec = tmp_path / "tiny.yaml"
    spec.write_text(TINY)
    root = tmp_path / "root"
    args = [f"protocol={spec}", f"root={root}", "progress=false"]
    assert reproduce.main(args) == 0
    logs = {
        n: root / "logs" / f"{n}.log" for n in ("train/ppo/direct-1-1/seed0", "eval/ppo/direct-1-1/seed0", "report")
    }
    # a lost done-marker and an evaluation killed mid-way: both cells run again, and the report after them
    (root / "done/train/ppo/direct-1-1/seed0.done").unlink()
    out = root / "evals/ppo/direct-1-1/seed0/testbeds"
    (out / "episodes.csv").rename(out / ".episodes.csv.partial")
    capsys.readouterr()
    assert reproduce.main([*args, "plan=true"]) == 0
    plan = capsys.readouterr().out
    assert re.search(r"^train/ppo/direct-1-1/seed0\s+partial", plan, re.M)
    assert re.search(r"^eval/ppo/direct-1-1/seed0\s+partial", plan, re.M)
    assert "resume=true" in plan
    assert reproduce.main(args) == 0
    assert all(p.read_text().count("\n== ") == 2 for p in logs.values())
    assert "resuming" in logs["train/ppo/direct-1-1/seed0"].read_text()  # continued, not started again
    assert len(list(out.parent.glob("testbeds.partial-*"))) == 1 and (out / "episodes.csv").is_file()
    # cells=[...] runs just those, redo=true although done
    assert reproduce.main([*args, "cells=[eval/ppo/*]", "redo=true"]) == 0
    assert logs["eval/ppo/direct-1-1/seed0"].read_text().count("\n== ") == 3
    assert logs["train/ppo/direct-1-1/seed0"].read_text().count("\n== ") == 2
    assert len(list(out.parent.glob("testbeds.old-*"))) == 1


@pytest.mark.slow
def test_the_smoke_protocol_produces_every_kind_of_cell_and_the_report(tmp_path):
    root = tmp_path / "root"
    assert reproduce.main(["protocol=smoke", f"root={root}", "progress=false", "jobs=2"]) == 0
    lay = Layout(root)
    cells = build_cells(load_protocol("smoke"), root)
    assert {c.kind for c in cells} == {"train", "eval", "ref", "choose", "report"}
    assert all(status(c, lay, cells) == "done" for c in cells)
    report = (root / "report" / "report.md").read_text()
    # the compared mode was chosen from validation rows before the first checkpoint's test evaluation, and the
    # report compares it and says so with its numbers
    choice = json.loads((root / "compared_mode.json").read_text())
    first_test = min((root / "evals" / "ppo").rglob("episodes.csv"), key=lambda f: f.stat().st_mtime)
    assert (root / "compared_mode.json").stat().st_mtime <= first_test.stat().st_mtime
    assert choice["networks"] == 5 and choice["runs"] == 4  # the curriculum's two stages, three single-stage runs
    assert f"The compared mode was {choice_text(choice)}." in report
    assert f"The claims compare the checkpoints acting `{choice['compare']}`" in report
    # the direct runs trained on seed 2, worlds no curriculum stage (seeds 0, 1) trained on
    assert (root / "runs/ppo/direct-1-2/seed2/model-0-1-2.pt").is_file()
    assert "direct runs and ablations on seeds 2 (seed + direct_seed_offset 2); disjoint" in report
    # an evaluation cell's commands ran in one process (one == line each in its log); a command of it run alone
    # plays the same episodes
    cell = next(c for c in cells if c.name == "eval/ppo/direct-1-1/seed2")
    assert len(cell.commands) == 4 and lay.log(cell.name).read_text().count("\n== ") == 4
    alone = tmp_path / "alone"
    cmd = cell.commands[1]
    argv = [a for a in cmd.argv[1:] if not a.startswith("out=")] + [f"out={alone}"]
    assert load_script("evaluate").main(argv) == 0
    assert (alone / "episodes.csv").read_text() == (cmd.out / "episodes.csv").read_text()
    for heading in (
        "Fig. 4a, left",
        "Fig. 4a, right",
        "Fig. 4b, left",
        "Fig. 4b, right",
        "Fig. 26",
        "The paper's claims",
    ):
        assert heading in report


def test_consecutive_evaluations_of_a_cell_share_one_process_and_the_first_failure_ends_it(tmp_path):
    from evaaa_baselines.paper import evaluate_many
    from evaaa_baselines.paper.engines import _processes

    ev = [Command(["scripts/evaluate.py", f"levels=[{lv}]"], tmp_path / lv) for lv in ("1-1", "1-2")]
    train, report = Command(["scripts/train.py", "seed=0"]), Command(["scripts/report.py", "runs=[x]"])
    procs = _processes([*ev, train, ev[0], report], threads=1)
    assert (
        [(c.argv[:2], own) for c, own in procs]
        == [
            (["-m", "evaaa_baselines.paper.evaluate_many"], False),  # the two evaluations: their own == lines
            (train.argv[:2], True),
            (ev[0].argv[:2], True),  # one evaluation alone runs as itself
            (report.argv[:2], True),
        ]
    )
    assert json.loads(procs[0][0].argv[2]) == {"threads": 1, "commands": [c.argv for c in ev]}
    # a refused command ends the batch with evaluate.py's exit status; the next is not run
    bad = Command(["scripts/evaluate.py", "levels=[1-1]", "episode=3", f"out={tmp_path / 'a'}"])
    spec = evaluate_many.batch_command([bad, Command([*bad.argv[:2], f"out={tmp_path / 'b'}"])], 1).argv[2]
    run = subprocess.run(
        [sys.executable, "-m", "evaaa_baselines.paper.evaluate_many", spec], capture_output=True, text=True
    )
    assert run.returncode == 2 and run.stdout.count("\n== ") == 1 and "episode" in run.stderr
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_a_failed_cell_is_tried_again_once_and_continues(tmp_path):
    lay, cells = _fake(tmp_path)
    flag = tmp_path / "crashed"
    # the first try dies (as the renderer's crash does) after writing part of its run; the retry finishes it
    code = (
        f"import pathlib; d=pathlib.Path({str(cells[0].run_dir)!r}); d.mkdir(parents=True, exist_ok=True); "
        f"f=pathlib.Path({str(flag)!r}); (d/'checkpoint.pt').write_text('c')\n"
        "if not f.exists(): f.write_text('1'); raise SystemExit(-11)\n"
        "(d/'model-0-1-1.pt').write_text('m')"
    )
    cells[0].commands = [Command(_py(code))]
    messages = []
    sched = Runner(load_protocol("smoke"), cells, lay, progress=False, echo=messages.append, retries=1)
    assert sched.run(cells) == 0
    assert any("train/a: exit status 245; trying again (1 of 1)" in m for m in messages)
    log = lay.log("train/a").read_text()
    assert log.count("\n== ") == 2 and log.split("\n== ")[2].rstrip().endswith("resume=true")
    assert all(status(c, lay, cells) == "done" for c in cells)
    assert lay.took("train/a") > 0 and not lay.clock("train/a").exists()  # both tries timed, into the marker


# ------------------------------------------------------------------------------------------------ committed results
def test_a_finished_training_whose_models_are_gone_is_trained_again_only_for_evaluations_left(tmp_path):
    from evaaa_baselines.paper.cell_status import command_now

    lay, cells = _fake(tmp_path)
    train, ev, _ = cells
    assert _scheduler(lay, cells).run(cells) == 0
    train.final_model.unlink()  # a clone of the committed results: no models
    assert status(train, lay, cells) == "done" and command_now(train, lay) == [
        Command([*train.commands[0].argv, "start_over=true"])
    ]
    (ev.commands[0].out / "episodes.csv").unlink()  # an evaluation still to make needs the model again
    assert status(train, lay, cells) == "partial"
    todo = [c for c in cells if status(c, lay, cells) != "done"]
    assert names(todo) == ["train/a", "eval/a", "report"]
    assert _scheduler(lay, cells).run(todo) == 0
    assert lay.log("train/a").read_text().split("\n== ")[-1].rstrip().endswith("start_over=true")
    assert train.final_model.is_file() and all(status(c, lay, cells) == "done" for c in cells)


def test_a_training_from_zero_has_its_earlier_evaluations_made_again_from_the_new_models(tmp_path):
    # a curriculum: two stage evaluations of one training, one made before the models were lost, one still to make
    lay, (train, ev, rep) = _fake(tmp_path)
    out2 = lay.evals / "b"
    ev2_code = (
        f"import pathlib; m=pathlib.Path({str(train.final_model)!r}); assert m.exists(); "
        f"o=pathlib.Path({str(out2)!r}); o.mkdir(parents=True, exist_ok=True); "
        "(o/'episodes.csv').write_text('x')"
    )
    ev2 = Cell(
        "eval/b", "eval", [Command(_py(ev2_code), out2)], 1.0, "e", needs=[train.final_model], needs_cells=["train/a"]
    )
    rep.needs_cells.append("eval/b")
    cells = [train, ev, ev2, rep]
    assert _scheduler(lay, cells).run(cells) == 0
    first = ev.commands[0].out / "episodes.csv"
    first.write_text("from the first models")
    train.final_model.unlink()  # a clone of the committed results
    (out2 / "episodes.csv").unlink()  # and eval/b still to make: the training runs again, from zero
    todo = [c for c in cells if status(c, lay, cells) != "done"]
    assert names(todo) == ["train/a", "eval/b", "report"]  # eval/a looks done before the training restarts
    messages = []
    sched = Runner(load_protocol("smoke"), cells, lay, progress=False, echo=messages.append)
    assert sched.run(todo) == 0
    assert first.read_text() == "x"  # made again from the new model
    aside = list(lay.evals.glob("a.old-*"))
    assert len(aside) == 1 and (aside[0] / "episodes.csv").read_text() == "from the first models"  # kept
    assert any("train/a trains from zero: moved its earlier evaluation" in m for m in messages)
    assert lay.log("eval/a").read_text().count("\n== ") == 2
    assert all(status(c, lay, cells) == "done" for c in cells)
    # continued from its checkpoint (resume=true), a training leaves its evaluations alone
    lay.marker("train/a").unlink()
    train.final_model.unlink()
    (train.run_dir / "checkpoint.pt").write_text("c")
    first.write_text("kept")
    todo = [c for c in cells if status(c, lay, cells) != "done"]
    assert names(todo) == ["train/a", "report"]
    assert _scheduler(lay, cells).run(todo) == 0
    assert lay.log("train/a").read_text().split("\n== ")[-1].rstrip().endswith("resume=true")
    assert first.read_text() == "kept" and len(list(lay.evals.glob("a.old-*"))) == 1


def test_commands_name_files_inside_the_repository_relative_to_it(tmp_path):
    from evaaa_baselines.paper.protocol import REPO

    inside = REPO / "runs" / "protocol" / "named-relative"
    for root, prefix in ((inside, "runs/protocol/named-relative/"), (tmp_path, f"{tmp_path.resolve()}/")):
        cells = build_cells(load_protocol("smoke"), root, report_out=root / "report")
        argv = " ".join(a for c in cells for cmd in c.commands for a in cmd.argv)
        assert f"run.root={prefix}runs" in argv and f"policy=[{prefix}runs/ppo/" in argv
        assert f"out={prefix}evals/" in argv and f"runs=[{prefix}runs]" in argv and f"out={prefix}report" in argv
        assert all(c.run_dir.is_absolute() for c in cells if c.kind == "train")  # the runner checks absolute paths
    assert not inside.exists()  # expanding cells writes nothing


def test_a_root_inside_the_repository_keeps_models_and_logs_out_of_git(tmp_path):
    import shutil
    import subprocess

    from evaaa_baselines.paper.cells import GITIGNORE, keep_out_of_git
    from evaaa_baselines.paper.protocol import REPO

    assert keep_out_of_git(Layout(tmp_path / "outside")) is None and not (tmp_path / "outside").exists()
    inside = REPO / "runs" / "protocol" / "gitignore-test"
    try:
        written = keep_out_of_git(Layout(inside))
        assert written == inside / ".gitignore" and written.read_text() == GITIGNORE
        written.write_text("# mine\n")
        assert keep_out_of_git(Layout(inside)) is None and written.read_text() == "# mine\n"  # kept as it was
    finally:
        shutil.rmtree(inside, ignore_errors=True)
    repo = tmp_path / "repo"
    (repo / "record").mkdir(parents=True)
    subprocess.run(["git", "init", "-q", str(repo)], check=True)
    (repo / ".gitignore").write_text((REPO / ".gitignore").read_text())  # which leaves every runs/ folder out
    (repo / "record" / ".gitignore").write_text(GITIGNORE)
    run = "record/runs/ppo/curriculum/seed0"
    ignored = [
        f"{run}/model-0-1-1.pt",
        f"{run}/checkpoint.pt",
        f"{run}/train.log",
        "record/logs/train/ppo.log",
        "record/evals/ppo/a/testbeds/survival.png",
        "record/evals/ppo/a/testbeds.partial-20261125/episodes.csv",
        "record/evals/ppo/a/testbeds.old-20261125/episodes.csv",
        "record/.reproduce.lock",
        "record/done/train/ppo/curriculum/seed1.seconds",
        "record/runs/ppo/curriculum/.seed0.replaced-20261125-101010/eval.csv",
        # DreamerV3's replay buffer on disk (gigabytes of pixels) and its open-loop prediction images
        "record/runs/dreamer_xs/matched-1-1/seed0/replay/0-1-1/next/pixels.memmap",
        "record/runs/dreamer_xs/matched-1-1/seed0/replay/0-1-1/meta.json",
        "record/runs/dreamer_xs/matched-1-1/seed0/openloop/openloop-0-1-1-000032368.png",
    ]
    kept = [
        f"{run}/.hydra/config.yaml",
        f"{run}/episodes.csv",
        f"{run}/eval.csv",
        f"{run}/logs/scalars/train/lr.csv",
        "record/evals/ppo/a/testbeds/episodes.csv",
        "record/evals/ppo/a/testbeds/summary.md",
        "record/done/train/ppo/curriculum/seed0.done",
        "record/runs/dreamer_xs/matched-1-1/seed0/logs/scalars/train/replay_steps.csv",
    ]
    for path in ignored + kept:
        (repo / path).parent.mkdir(parents=True, exist_ok=True)
        (repo / path).write_text("x")
    check = subprocess.run(["git", "-C", str(repo), "check-ignore", *ignored, *kept], capture_output=True, text=True)
    assert sorted(check.stdout.split()) == sorted(ignored)


def test_a_stopped_protocol_passes_one_ctrl_c_to_each_cell_and_keeps_its_time(tmp_path):
    import json
    import os
    import signal
    import threading

    lay, cells = _fake(tmp_path)
    train = cells[0]
    code = (
        f"import pathlib,signal,sys,time; d=pathlib.Path({str(train.run_dir)!r}); d.mkdir(parents=True); "
        "signal.signal(signal.SIGINT, lambda *a: ((d/'stopped').write_text('1'), sys.exit(130))); "
        "(d/'ready').write_text('1'); time.sleep(60)"
    )
    train.commands = [Command(_py(code))]
    stopper = threading.Timer(1.5, os.kill, (os.getpid(), signal.SIGTERM))  # as `kill` of reproduce.py does
    stopper.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            _scheduler(lay, cells).run(cells)
    finally:
        stopper.cancel()
    assert (train.run_dir / "stopped").is_file()  # it got its Ctrl-C and stopped cleanly
    assert status(train, lay, cells) == "partial" and not lay.marker("train/a").exists()
    account = json.loads(lay.clock("train/a").read_text())  # the time so far, kept for the next session
    assert 1.0 <= account["seconds"] < 30 and 0 <= account["cpu_seconds"] < account["seconds"]
    # where nothing of the cell is left (a clone without the unfinished run), it is timed from zero again
    import shutil

    shutil.rmtree(train.run_dir)
    train.commands = [
        Command(
            _py(
                f"import pathlib; d=pathlib.Path({str(train.run_dir)!r}); d.mkdir(parents=True); "
                "(d/'model-0-1-1.pt').write_text('m')"
            )
        )
    ]
    assert _scheduler(lay, cells).run(cells) == 0
    assert json.loads(lay.marker("train/a").read_text())["seconds"] < 1.0


def test_paper_learned_compute_matches_1_1_and_gives_direct_runs_the_curriculum_s_steps(tmp_path):
    from hydra import initialize_config_dir

    from evaaa_baselines.config import compose_checked, register_levels
    from evaaa_baselines.paths import CONF_DIR

    p = load_protocol("paper_learned")
    cells = build_cells(p, tmp_path)
    by = {c.name: c for c in cells}
    S = p.stage_steps
    # the parts come in the protocol's order: references, ablations, matched, curriculum, direct
    first = [c.name for c in cells if c.kind == "train"]
    assert first[0] == "train/ppo/direct-1-1/seed0" and first[3].startswith("train/ppo/ablation-")
    matched = [n for n in first if "matched" in n]
    assert matched[:4] == [f"train/{a}/matched-1-1/seed0" for a in ("ppo", "dqn", "ppo_lstm", "dreamer_xs")]
    assert (
        first.index(matched[-1]) < first.index("train/ppo/curriculum/seed0") < first.index("train/ppo/direct-1-2/seed0")
    )
    # curriculum and direct runs are PPO's alone; direct runs at the env steps the curriculum had seen by then
    assert not [n for n in first if ("curriculum" in n or "direct" in n) and not n.startswith("train/ppo/")]
    register_levels()
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        for level, k in (("1-2", 1), ("2-1", 2)):
            cfg = compose_checked(by[f"train/ppo/direct-{level}/seed1"].commands[0].argv[1:])
            assert cfg.total_steps == (k + 1) * S
        for algo, every in (("ppo", 50000), ("dqn", 25000), ("ppo_lstm", 30000), ("dreamer_xs", 10000)):
            cell = by[f"train/{algo}/matched-1-1/seed2"]
            cfg = compose_checked(cell.commands[0].argv[1:])
            assert cfg.max_cpu_minutes == 110 and cfg.total_steps > 10**8 and cfg.eval.every == every
            assert cell.minutes == pytest.approx(110 + 0.5, abs=1)
    assert "train/ppo/direct-2-2/seed0" not in by
    # every model in both acting modes on test worlds, DQN in its one mode; the stand-still reference is there
    ppo_eval = [c.argv for c in by["eval/ppo/matched-1-1/seed0"].commands]
    assert sorted(a[3] for a in ppo_eval) == ["sample=false"] * 2 + ["sample=true"] * 2
    assert all("worlds=validation" not in a and "epsilon=0" in a for a in ppo_eval)
    assert [c.argv[3] for c in by["eval/dqn/matched-1-1/seed0"].commands] == ["sample=false"] * 2
    assert {"ref/random", "ref/still", "ref/oracle"} <= set(by)
    assert sum(c.minutes for c in cells) / 60 <= p.budget_cpu_hours


def test_docs_quote_the_paper_learned_plan(tmp_path, capsys):
    assert (
        reproduce.main(["protocol=paper_learned", "plan=true", f"root={tmp_path}", f"out={tmp_path / 'report'}"]) == 0
    )
    out = capsys.readouterr().out
    docs = (Path(__file__).parents[1] / "docs/reports.md").read_text()
    docs = docs[docs.index("## The paper's claims between agents that learned") :]
    total = float(re.search(r"^  total\s+(\d+\.\d+)", out, re.M).group(1))
    assert f"| **total** | | | | | | **{total:.2f}** |" in docs and "WARNING" not in out
    for algo in (n for n, a in load_protocol("paper_learned").algorithms.items() if a.enabled):
        row = re.search(rf"^  {algo}\s+([\d. ]+)$", out, re.M).group(1).split()
        assert f"| {algo} | " + " | ".join("–" if v == "0.00" else v for v in row) + " |" in docs
    assert f"**S = {load_protocol('paper_learned').stage_steps:,}** env steps" in docs


def test_paper_learned_compares_sampled_actions_and_its_done_evaluations_stay_done(tmp_path):
    # modes [sample, mode]: the report's claims compare `sample` (DQN with its greedy action), every mode in its
    # tables; the evaluation folders are those of [mode, sample], so evaluations made before stay done
    p = load_protocol("paper_learned")
    assert p.evaluation.modes == ["sample", "mode"]
    before = p.model_copy(update={"evaluation": p.evaluation.model_copy(update={"modes": ["mode", "sample"]})})
    one = p.model_copy(update={"evaluation": p.evaluation.model_copy(update={"modes": ["sample"]})})
    now, old = build_cells(p, tmp_path), build_cells(before, tmp_path)
    assert names(now) == names(old)
    outs = {c.name: sorted(str(m.out) for m in c.commands) for c in now}
    assert outs == {c.name: sorted(str(m.out) for m in c.commands) for c in old}
    assert [Path(o).name for o in outs["eval/ppo/direct-1-1/seed0"]] == [
        "level-mode",
        "level-sample",
        "testbeds-mode",
        "testbeds-sample",
    ]
    assert [Path(o).name for o in outs["eval/dqn/matched-1-1/seed1"]] == ["level-mode", "testbeds-mode"]
    lay = Layout(tmp_path)
    for cmd in next(c for c in old if c.name == "eval/ppo/direct-1-1/seed0").commands:
        cmd.out.mkdir(parents=True)
        (cmd.out / "episodes.csv").write_text("policy\n")
    assert status(next(c for c in now if c.name == "eval/ppo/direct-1-1/seed0"), lay) == "done"
    report = {
        tuple(m.modes): [a for a in c.commands[0].argv if a.startswith(("acting=", "compare="))]
        for m, cells in ((p.evaluation, now), (before.evaluation, old), (one.evaluation, build_cells(one, tmp_path)))
        for c in cells
        if c.kind == "report"
    }
    assert report == {
        ("sample", "mode"): ["compare=sample"],
        ("mode", "sample"): ["compare=mode"],
        ("sample",): ["acting=sample", "compare=sample"],
    }


def test_paper_gpu_s_cpu_bound_cells_request_no_gpu_and_its_gpu_plan_names_its_rate_and_card(tmp_path):
    from evaaa_baselines.paper.plan import cell_resources, gpu_plan

    p = load_protocol("paper_gpu")
    cells = build_cells(p, tmp_path)
    trainings = [c for c in cells if c.kind == "train"]
    for c in cells:
        cpus, gpus = cell_resources(p, c)
        algo = c.name.split("/")[1] if c.kind == "train" else None
        if algo == "dreamer":  # the one algorithm that trains on the GPU it requests
            assert gpus == 1 and {"device=cuda", "deterministic=false"} <= set(c.commands[0].argv), c.name
        else:  # PPO, PPO+LSTM, DQN, evaluations, references, the choice, the report: on the CPUs, no GPU reserved
            assert gpus == 0, c.name
            if c.kind == "train":
                assert "device=cpu" in c.commands[0].argv and "device=cuda" not in c.commands[0].argv, c.name
    assert {c.name.split("/")[1] for c in trainings} == {"dreamer", "ppo", "ppo_lstm", "dqn"}
    # the GPU plan: DreamerV3's runs alone, at the rate the protocol file names with its card
    plan = "\n".join(gpu_plan(p, cells))
    assert re.search(r"^  dreamer\s+42\s+4\.9\s", plan, re.M) and not re.search(r"^  (ppo|dqn)", plan, re.M)
    text = (Path(__file__).parents[1] / "conf/protocol/paper_gpu.yaml").read_text()
    assert "16-core" not in text
    assert "4.9 env steps/s on one NVIDIA H200 with non-deterministic kernels" in text and "2.59" in text
    assert json.loads((Path(__file__).parents[1] / "docs/bench_train.json").read_text())["cores"] == 2
    assert "2-core development machine (docs/bench_train.json" in text


@pytest.mark.parametrize(
    "gpus, device, message",
    [
        (0, "device=cuda", "field algorithms.ppo.gpus: 0, but its runs train with device=cuda: request the GPUs"),
        (1, "device=cpu", "field algorithms.ppo.gpus: 1, but its runs train with device=cpu: the GPUs they reserve"),
    ],
)
def test_an_algorithm_whose_device_and_gpus_disagree_is_refused(tmp_path, gpus, device, message):
    path = _smoke_with(tmp_path, algorithms={"ppo": {"steps_per_second": 30, "gpus": gpus, "overrides": [device]}})
    assert message in _load_error(path)


def test_the_plan_counts_in_training_evaluations_where_the_protocol_gives_their_rate(tmp_path):
    # smoke: S = 128, eval.every=128 and eval.episodes=2 in both acting modes; every level's step limit is 5,000.
    # Per stage one evaluation (at its end): 2 episodes x 2 modes x 5,000 world steps, at 400 world steps/s 50 s
    plain = {c.name: c for c in build_cells(load_protocol("smoke"), tmp_path)}
    counted = {
        c.name: c
        for c in build_cells(load_protocol(_smoke_with(tmp_path, training__eval_steps_per_second=400)), tmp_path)
    }
    assert set(plain) == set(counted)
    extra = {n: 60 * (counted[n].minutes - plain[n].minutes) for n in plain}
    assert extra["train/ppo/curriculum/seed0"] == pytest.approx(2 * 50)  # two stages
    assert extra["train/ppo/direct-1-2/seed2"] == pytest.approx(50)
    assert extra["train/ppo/ablation-no_vision/seed2"] == pytest.approx(50)
    assert all(v == 0 for n, v in extra.items() if not n.startswith("train/"))
    # without the rate the estimate is what it always was: steps / rate and the start-up
    assert plain["train/ppo/curriculum/seed0"].minutes == pytest.approx((10 + 2 * 128 / 30) / 60)
    # one mode where the runs record one; none where eval.every=0; the last override wins, as in train.py
    for overrides, seconds in (
        (["eval.every=128", "eval.episodes=2", "eval.both_modes=false"], 2 * 25),
        (["eval.every=64", "eval.episodes=2", "eval.both_modes=true"], 2 * 100),
        (["eval.every=128", "eval.every=0"], 0),
    ):
        path = _smoke_with(
            tmp_path,
            training__eval_steps_per_second=400,
            training__overrides=["preset=debug", *overrides],
            evaluation__compare="sample",  # validation needs eval.both_modes=true
        )
        cell = next(c for c in build_cells(load_protocol(path), tmp_path) if c.name == "train/ppo/curriculum/seed0")
        assert 60 * cell.minutes - (10 + 2 * 128 / 30) == pytest.approx(seconds)
    plan = plan_text(
        load_protocol(_smoke_with(tmp_path, training__eval_steps_per_second=400)),
        [*counted.values()],
        Layout(tmp_path),
        1,
    )
    assert "trainings with their in-training validation evaluations at 400 world steps/s" in plan
    assert "trainings with their" not in plan_text(load_protocol("smoke"), [*plain.values()], Layout(tmp_path), 1)


def test_paper_settle_s_pilot_chooses_on_validation_worlds_and_its_arms_train_on_disjoint_worlds(tmp_path):
    pilot, settle = load_protocol("paper_settle_pilot"), load_protocol("paper_settle")
    pilot_cells = build_cells(pilot, tmp_path / "pilot")
    cells = build_cells(settle, tmp_path / "settle")
    # the pilot: the curriculum to 3-1, nothing on test worlds (its evaluations and references on validation worlds)
    assert pilot.stage_levels == ["1-1", "1-2", "2-1", "2-2", "3-1"] and not pilot.training.direct
    checked = [cmd.argv for c in pilot_cells if c.kind in ("eval", "ref") for cmd in c.commands]
    assert checked and all("worlds=validation" in argv for argv in checked)
    # paper_settle: five seeds, PPO's default recipe (not the paper's sizes), the mode chosen from validation rows
    # recorded in both modes, direct runs at the curriculum's env steps on the levels (b) is judged on
    assert settle.seeds == [0, 1, 2, 3, 4] and settle.evaluation.compare == "validation"
    assert settle.evaluation.worlds == "test" and pilot.stage_steps < settle.stage_steps
    trains = [c for c in cells if c.kind == "train"]
    assert trains and all("preset=paper_sizes" not in c.commands[0].argv for c in trains)
    assert all(
        "eval.both_modes=true" in c.commands[0].argv for c in [*trains, *(c for c in pilot_cells if c.kind == "train")]
    )
    assert {c.name for c in trains if "/direct-" in c.name} == {
        f"train/ppo/direct-{lv}/seed{s + 20}" for lv in ("1-2", "2-1", "2-2", "3-1") for s in settle.seeds
    }
    # the arms' training worlds are disjoint, and neither arm trains on the pilot's worlds
    arms, piloted = world_seeds(cells), world_seeds(pilot_cells)
    assert arms["curriculum"] == set(range(12)) and arms["direct"] == set(range(20, 25))
    assert not arms["curriculum"] & arms["direct"]
    assert not (arms["curriculum"] | arms["direct"]) & piloted["curriculum"]
    # the two plans within the issue's 60 CPU-hours, each within its own budget
    hours = {p.name: sum(c.minutes for c in cs) / 60 for p, cs in ((pilot, pilot_cells), (settle, cells))}
    assert hours["paper_settle_pilot"] <= pilot.budget_cpu_hours and hours["paper_settle"] <= settle.budget_cpu_hours
    assert sum(hours.values()) <= 60
    docs = (Path(__file__).parents[1] / "docs/reports.md").read_text()
    docs = docs[docs.index("## The protocol that settles (a) and (b)") : docs.index("## Sweeps and launchers")]
    for name, h in hours.items():
        assert f"**{h:.2f}** |" in docs and f"protocol={name} plan=true" in docs
    assert f"Pilot and runs: {sum(hours.values()):.1f} CPU-hours planned" in docs
