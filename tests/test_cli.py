"""One command-line idiom: every script answers ``--help`` with each key's type, default and meaning (exit 0), and
refuses a malformed argument in one line that names the key (exit 2, no traceback) — train.py (Hydra) before it
writes anything.  The commands the README, docs/*.md and the scripts' docstrings show parse as written."""

from __future__ import annotations

import dataclasses
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import load_script
from hydra import initialize_config_dir
from hydra._internal.utils import get_args_parser

from evaaa_baselines import cli
from evaaa_baselines.cli.training import check_command_line, check_overrides, job_overrides
from evaaa_baselines.config import ConfigError, compose_checked, register_levels
from evaaa_baselines.paths import CONF_DIR

register_levels()

ROOT = Path(__file__).resolve().parents[1]
#: each script's config dataclass (train.py's config is Hydra's, composed from conf/)
SCHEMAS = {
    "evaluate": "EvalConfig",
    "report": "ReportConfig",
    "bench_env": "BenchConfig",
    "bench_train": "BenchConfig",
    "bench_gpu": "GpuBenchConfig",
    "demo": "DemoConfig",
    "profile_env": "ProfileConfig",
    "render_levels": "RenderConfig",
    "play": "PlaySettings",
    "wall_hits": "WallHitsConfig",
    "reproduce": "ReproduceConfig",
    "probe_dreamer": "ProbeConfig",
    "fit_world_model": "FitConfig",
    "pack_record": "PackConfig",
    "choose_acting": "ChooseConfig",
    "zoo": "ZooConfig",
    "record_trajectories": "RecordConfig",
    "record_runs": "RunsConfig",
}


def schema(name: str) -> type:
    return getattr(load_script(name), SCHEMAS[name])


def test_every_script_is_covered():
    assert {p.stem for p in (ROOT / "scripts").glob("*.py")} == {*SCHEMAS, "train"}


# ------------------------------------------------------------------------------------------------ --help
@pytest.mark.parametrize("name", sorted(SCHEMAS))
def test_help_lists_every_key_with_type_default_and_meaning(name, capsys):
    module = load_script(name)
    config = getattr(module, SCHEMAS[name])
    try:
        code = module.main(["--help"])
    except SystemExit as exit_:
        code = exit_.code
    assert code in (0, None)
    out = capsys.readouterr().out
    assert out.startswith(f"usage: python scripts/{name}.py [key=value ...]")
    hints = dataclasses.fields(config)
    for f in hints:
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
        line = next((ln for ln in out.splitlines() if ln.startswith(f"  {f.name}: ")), None)
        assert line is not None, f"--help of {name}.py does not list {f.name}"
        assert line.endswith(f" = {cli._show(default)}"), line
        assert f.metadata["meaning"].split()[0] in out  # its meaning follows


def test_train_help_lists_every_key_of_the_composed_config(capsys):
    with pytest.raises(SystemExit) as exit_:
        check_command_line(["--help"])
    assert exit_.value.code == 0
    out = capsys.readouterr().out
    for text in (
        "total_steps: int = 2000000",
        "env steps (decisions summed over the worlds)",
        "max_minutes: float or null = null",
        "eval.sample: bool = false",
        "algo.gamma: float = 0.99",
        "discount factor",
        "algo: dqn, dreamer, dreamer_xs, ppo, ppo_lstm (now ppo)",
    ):
        assert text in out, text
    with pytest.raises(SystemExit):
        check_command_line(["--help", "algo=dqn"])  # the keys of the options chosen
    out = capsys.readouterr().out
    assert "algo.eps_anneal_updates: int = 209000" in out and "algo.gae_lambda" not in out


# ------------------------------------------------------------------------------------------------ bad input
@pytest.mark.parametrize(
    "name, args, message",
    [
        ("bench_env", ["level=1-3"], "level=1-3: '1-3' is not allowed (did you mean 1-2 or 1-1?); allowed: 1-1, 1-2"),
        ("bench_env", ["steps=many"], "steps=many: expected an integer"),
        ("bench_train", ["minutes=0"], "minutes=0: expected a positive number"),
        ("demo", ["num_envs=1.5"], "num_envs=1.5: expected an integer"),
        ("render_levels", ["levels=[1-1,9-9]"], "levels=[1-1,9-9]: '9-9' is not allowed"),
        ("profile_env", ["--level", "4-2"], "'--level' is not of the form key=value"),
        ("evaluate", ["sample=maybe"], "sample=maybe: expected true or false"),
        ("evaluate", ["episodes=[1,2]"], "episodes=[1,2]: expected an integer"),
        ("report", ["window=2.5"], "window=2.5: expected an integer"),
        ("report", ["colour=red"], "unknown key 'colour'; keys: runs, evals, out, survival"),
    ],
)
def test_a_malformed_argument_is_one_line_naming_the_key(name, args, message, capsys):
    with pytest.raises(SystemExit) as exit_:
        load_script(name).main(args)
    err = capsys.readouterr().err
    assert exit_.value.code == 2
    assert err == f"{name}.py: error: {err.split(': error: ', 1)[1]}" and err.count("\n") == 1, err
    assert message in err, err


def test_a_string_key_keeps_its_text_and_a_single_value_is_a_list():
    cfg = cli.read(schema("evaluate"), ["levels=1-1", "out=007", "policy=random"])
    assert cfg.levels == ["1-1"] and cfg.out == "007" and cfg.policy == ["random"]
    title = cli.read(schema("report"), ["title=level 1-1: DreamerV3, 75 minutes"]).title
    assert title == "level 1-1: DreamerV3, 75 minutes"  # YAML would have read a mapping

    # shell patterns that begin with * are YAML aliases: a list of names still reads them as typed
    cells = cli.read(schema("reproduce"), ["cells=[*/ppo/matched-1-1/seed0, eval/dqn/*]"]).cells
    assert cells == ["*/ppo/matched-1-1/seed0", "eval/dqn/*"]
    assert cli.read(schema("reproduce"), ["cells=*/dqn/*"]).cells == ["*/dqn/*"]  # one, as a single value is
    with pytest.raises(cli.UsageError, match=r"counts=\[\*1\]: not a valid value"):
        cli.read(schema("bench_env"), ["counts=[*1]"])  # a list of numbers is not read as text


@pytest.mark.parametrize(
    "args, message",
    [
        (["total_steps=abc"], "total_steps=abc: expected an integer (default 2000000)"),
        (["eval.sample=maybe"], "eval.sample=maybe: expected true or false"),
        (["max_minutes=soon"], "max_minutes=soon: expected a number"),
        (["algo.encoder.cnn.channels=[a,b]"], "algo.encoder.cnn.channels=[a,b]: expected a list of integers"),
        (["totl_steps=5"], "unknown key 'totl_steps' (did you mean total_steps?); keys here: seed, total_steps"),
        (["+totl_steps=5"], "unknown key 'totl_steps'"),
        (["algo.lrr=1"], "unknown key 'algo.lrr' (did you mean algo.lr?); keys here: algo.name"),
        (["algo=a2c"], "algo=a2c: no option 'a2c' in algo; allowed: dqn, dreamer, dreamer_xs, ppo, ppo_lstm"),
        (["level=1-3"], "level=1-3: no option '1-3' in level (did you mean level=1-2?); allowed: 1-1, 1-2"),
        (["env.overrides.episode.max_steps=5"], "add it with ++env.overrides.episode.max_steps=5"),
        (["seed=0,1"], "seed=0,1: several values make a sweep: add -m"),
        (["-m", "seed=0,x"], "seed=x: expected an integer"),
        (["total_steps=[1"], "total_steps=[1"),
        # what YAML makes of a newcomer's typing, budgets of zero or less, values only a running job used to check
        (["level=3_2"], "level=3_2: no option '3_2' in level (did you mean level=3-2?); allowed: 1-1"),
        (["total_steps=-5"], "total_steps=-5: expected an integer >= 1 (default 2000000)"),
        (
            ["total_steps=1e3"],
            "total_steps=1e3: expected an integer (default 2000000); YAML reads it as 1000.0: write it "
            "as an integer, e.g. total_steps=1000 or total_steps=1_000",
        ),
        (["progress=on"], "progress=on: expected true or false"),
        (["run.name=3_2"], "run.name=3_2: expected a string"),
        (["level=curriculum", "level.stages=[1-1,3_2]"], "level.stages=[1-1,3_2]: '3_2' is not a level"),
        (["level=curriculum", "level.stage_steps=0"], "level.stage_steps=0: expected an integer >= 1"),
        (["env.num_envs=0"], "env.num_envs=0: expected an integer >= 1"),
        (["env.num_envs=3"], "algo.frames_per_batch=1024: expected a multiple of env.num_envs (3)"),
        (["max_minutes=-1"], "max_minutes=-1: expected a number > 0"),
        (["algo.lr=-1"], "algo.lr=-1: expected a number > 0"),
        (["device=on"], "device=on: not a device; allowed: auto, cpu, cuda, cuda:N"),
        (["protocol=smoke"], "protocol=smoke: protocol is not a key of train.py"),
    ],
)
def test_train_refuses_a_malformed_override_in_one_line(args, message, capsys):
    with pytest.raises(SystemExit) as exit_:
        check_command_line(args)
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.startswith("train.py: error: ") and err.count("\n") == 1, err
    assert message in err, err


def test_train_accepts_what_its_config_allows():
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        cfg = compose_checked(
            [
                "algo=ppo_lstm",
                "max_minutes=5",
                "algo.lr=1e-3",
                "threads=2",
                "++env.overrides.episode.max_steps=50",
                "level=curriculum",
                "level.stages=[1-1,1-2]",
                "hydra/launcher=basic",
            ]
        )
        assert (cfg.max_minutes, cfg.algo.lr, cfg.level.stages) == (5, 1e-3, ["1-1", "1-2"])
        with pytest.raises(ConfigError, match="level.stages"):
            compose_checked(["level=curriculum", "level.stages=1-1"])  # a list is written [a,b]
    jobs = job_overrides(["algo=dqn,ppo", "seed=0,1,2", "preset=debug"], multirun=True)
    assert (
        len(jobs) == 4
        and ["algo=ppo", "seed=0", "preset=debug"] in jobs
        and ["algo=dqn", "seed=2", "preset=debug"] in jobs
    )


def test_train_script_refuses_before_hydra_writes_anything(tmp_path):
    done = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "train.py"), "total_steps=-5"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        "train.py: error: total_steps=-5: expected an integer >= 1 (default 2000000)"
    ]
    assert not list(tmp_path.iterdir())  # no run directory, no .hydra: the corrected command finds nothing in its way


def test_dreamer_size_s_on_a_machine_without_a_gpu_stops_and_says_what_to_type(monkeypatch, capsys):
    monkeypatch.setattr("torch.cuda.is_available", lambda: False)
    with pytest.raises(SystemExit) as exit_:
        check_command_line(["algo=dreamer", "level=3-2"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.count("\n") == 1, err
    assert "algo=dreamer is DreamerV3 size S, a GPU size" in err and "algo=dreamer_xs" in err and "device=cpu" in err
    for asked in (["algo=dreamer", "device=cpu"], ["algo=dreamer_xs"], ["algo=dreamer", "preset=debug"]):
        check_command_line(asked)  # the paper's size by name, the CPU size, and the smoke-test networks go ahead
    with pytest.raises(SystemExit):
        check_command_line(["-m", "algo=ppo,dreamer"])  # each job of a sweep is checked


# ------------------------------------------------------------------------------------------------ documented commands
def documented_commands() -> list[tuple[str, str, list[str]]]:
    """``(where, script, arguments)`` of every ``python scripts/<name>.py ...`` in the README, docs/*.md and the
    scripts' docstrings; continuation lines joined, shell comments dropped; placeholders (``<a>``, ``...``) and
    command substitutions ``$(...)`` left out."""
    found = []
    sources = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), *sorted((ROOT / "scripts").glob("*.py"))]
    for path in sources:
        text = path.read_text().replace("\\\n", " ")
        snippets = re.findall(r"`(python scripts/[^`]+)`", text)  # inline, possibly over a line break
        snippets += re.findall(r"^\s*(?:\$ )?(python scripts/.+)$", text, re.M)
        for snippet in snippets:
            if "..." in snippet or "<" in snippet or "$(" in snippet:
                continue
            words = shlex.split(snippet, comments=True)
            name = Path(words[1]).stem
            if any(w in ("-h", "--help") for w in words):
                continue
            found.append((f"{path.name}: {snippet.strip()}", name, words[2:]))
    return found


def test_the_documentation_shows_commands_of_every_script():
    assert {name for _, name, _ in documented_commands()} >= {
        "train",
        "evaluate",
        "report",
        "bench_env",
        "bench_train",
        "demo",
        "render_levels",
        "play",
    }


def test_documented_commands_parse_as_written():
    problems = []
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        for where, name, args in documented_commands():
            try:
                if name == "train":
                    parsed = get_args_parser().parse_args(args)
                    # keys and types; a GPU named in an example need not be on this machine
                    check_overrides(parsed.overrides, parsed.multirun, values=False)
                else:  # keys and types; paths of runs that exist elsewhere are not looked for
                    cli.read(schema(name), args, checks=False)
            except (cli.UsageError, ConfigError) as err:
                problems.append(f"{where}\n    {err}")
    assert not problems, "\n".join(problems)


# ------------------------------------------------------------------------------------------------ refused before writing
#: for every script, values a newcomer types by mistake: YAML's readings (3_2 is the integer 32, 1e3 the float
#: 1000.0, on is true), budgets of zero or less, a device that is not one
BAD_VALUES = [
    ("bench_env", "level=3_2", "level=3_2: '3_2' is not allowed"),
    ("bench_env", "steps=-5", "steps=-5: expected"),
    ("bench_env", "steps=1e3", "steps=1e3: expected an integer (YAML reads 1e3 as 1000.0: write 1000)"),
    ("bench_env", "skip_parallel=on", "skip_parallel=on: expected true or false"),
    ("bench_gpu", "variants=[fast]", "'fast' is not allowed"),
    ("bench_gpu", "budget_s=0", "budget_s=0: expected a number > 0"),
    ("bench_gpu", "env_threads=[4]", "env_threads=[4]: give worlds= too, one value per env_threads value"),
    ("bench_gpu", "device=tpu", "device=tpu: expected"),
    ("bench_train", "level=3_2", "level=3_2: '3_2' is not allowed"),
    ("bench_train", "minutes=-5", "minutes=-5: expected a positive number"),
    ("bench_train", "threads=1e3", "threads=1e3: expected an integer"),
    ("bench_train", "overrides=[total_steps=-5]", "total_steps=-5: expected an integer >= 1"),
    ("bench_train", "device=on", "device=on: expected"),
    ("demo", "level=3_2", "level=3_2: '3_2' is not allowed"),
    ("demo", "steps=-5", "steps=-5: expected a positive integer"),
    ("demo", "steps=1e3", "steps=1e3: expected an integer"),
    ("demo", "seed=-1", "seed=-1: expected an integer >= 0"),
    ("demo", "policy=zoo:ppo-11", "policy=zoo:ppo-11: zoo:ppo-11 is not in the zoo; did you mean zoo:ppo-1-1?"),
    ("demo", "gif_scale=2", "gif_scale=2: expected in (0, 1]"),
    ("evaluate", "levels=[3_2]", "levels=[3_2]: '3_2' is not allowed"),
    ("evaluate", "episodes=-5", "episodes=-5: expected a positive integer"),
    ("evaluate", "episodes=1e3", "episodes=1e3: expected an integer"),
    ("evaluate", "sample=on", "sample=on: expected true or false"),
    ("evaluate", "seed=-1", "seed=-1: expected an integer >= 0"),
    ("evaluate", "policy=[random,zoo:pp-1-1]", "did you mean zoo:ppo-1-1?"),
    ("fit_world_model", "updates=-5", "updates=-5: expected >= 1"),
    ("fit_world_model", "updates=1e3", "updates=1e3: expected an integer"),
    ("fit_world_model", "keys=[3_2]", "keys=[3_2]: '3_2' is not allowed"),
    ("pack_record", "root=nowhere", "root=nowhere: not a folder"),
    ("pack_record", "root=", "root=: expected a string"),
    ("play", "level=3_2", "level=3_2: '3_2' is not allowed"),
    ("play", "port=1e3", "port=1e3: expected an integer"),
    ("play", "step_log=on", "step_log=on: expected true or false"),
    ("probe_dreamer", "sequences=-5", "sequences=-5: expected >= 1"),
    ("probe_dreamer", "samples=1e3", "samples=1e3: expected an integer"),
    ("profile_env", "level=3_2", "level=3_2: '3_2' is not allowed"),
    ("profile_env", "steps=-5", "steps=-5: expected a positive integer"),
    ("profile_env", "steps=1e3", "steps=1e3: expected an integer"),
    ("render_levels", "levels=[3_2]", "levels=[3_2]: '3_2' is not allowed"),
    ("render_levels", "seed=-1", "seed=-1: expected an integer >= 0"),
    ("choose_acting", "first=greedy", "first=greedy: 'greedy' is not allowed; allowed: sample, mode"),
    ("choose_acting", "epsilon=2", "epsilon=2: expected a number in [0, 1]"),
    ("choose_acting", "out=x.json", "runs: give the run directories, runs=[a,b]"),
    ("report", "window=-5", "window=-5: expected a positive integer"),
    ("report", "bins=1e3", "bins=1e3: expected an integer"),
    ("reproduce", "protocol=3_2", "protocol=3_2"),
    ("reproduce", "jobs=-5", "jobs=-5: expected"),
    ("reproduce", "jobs=1e3", "jobs=1e3: expected an integer"),
    ("reproduce", "max_minutes=-5", "max_minutes=-5: expected"),
    ("reproduce", "plan=on", "plan=on: expected true or false"),
    ("wall_hits", "angles=[-5]", "angles=[-5]: expected angles in [0, 90)"),
    ("wall_hits", "angles=on", "angles=on: expected"),
    ("record_trajectories", "levels=[3_2]", "levels=[3_2]: '3_2' is not allowed"),
    ("record_trajectories", "steps=-5", "steps=-5: expected a positive integer"),
    ("record_trajectories", "atol=-1", "atol=-1: expected a number >= 0"),
    ("record_trajectories", "atol=0.1", "atol= is for compare="),
    ("record_trajectories", "compare=nowhere", "compare=nowhere: no manifest.json there"),
    ("record_runs", "runs=[a2c]", "runs=[a2c]: 'a2c' is not allowed"),
    ("record_runs", "seed=-1", "seed=-1: expected an integer >= 0"),
    ("record_runs", "keep=kept", "keep= is for compare="),
    ("record_runs", "compare=nowhere", "compare=nowhere: no manifest.json there"),
    ("zoo", "replace=on", "replace=on: expected true or false"),
    ("zoo", "name=ppo-x", "name= and model= go together"),
    ("zoo", "model=nowhere.pt", "name= and model= go together"),
]


@pytest.mark.parametrize("name, arg, message", BAD_VALUES, ids=[f"{n}-{a}" for n, a, _ in BAD_VALUES])
def test_every_script_refuses_a_bad_value_in_one_line_and_writes_nothing(
    name, arg, message, tmp_path, monkeypatch, capsys
):
    monkeypatch.chdir(tmp_path)  # where each script's default output folder would go
    module = load_script(name)
    if hasattr(module, "serve"):  # play.py: a value let through would start a server that never returns
        monkeypatch.setattr(module, "serve", lambda *args: pytest.fail(f"{name}.py accepted {arg}"))
    try:
        code = module.main([arg])  # play.py returns its status, the others exit
    except SystemExit as exit_:
        code = exit_.code
    err = capsys.readouterr().err
    assert code == 2 and err.startswith(f"{name}.py: error: ") and err.count("\n") == 1, err
    assert message in err, err
    assert not list(tmp_path.iterdir())


def test_every_script_has_rows_of_bad_values():
    assert {name for name, _, _ in BAD_VALUES} == set(SCHEMAS)


def test_setup_sh_help_prints_help_and_sets_nothing_up():
    done = subprocess.run(
        ["bash", str(ROOT / "scripts" / "setup.sh"), "--help"], capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 0 and done.stdout.startswith("usage: bash scripts/setup.sh"), done.stderr
    assert "[setup]" not in done.stdout + done.stderr  # no step ran
    wrong = subprocess.run(
        ["bash", str(ROOT / "scripts" / "setup.sh"), "--bogus"], capture_output=True, text=True, timeout=60
    )
    assert wrong.returncode == 2 and wrong.stderr.strip() == "setup.sh: error: unknown argument --bogus (see --help)"


def test_train_help_loads_no_training_code():
    """``train.py --help`` (and the command line's checks) run before torch, TorchRL and the training code load:
    that is what keeps it fast (docs/training.md; about 1.5 s of CPU against 5 s when every import came first)."""
    probe = (
        "import runpy, sys\n"
        "sys.argv = ['scripts/train.py', '--help']\n"
        "try:\n"
        "    runpy.run_path('scripts/train.py', run_name='__main__')\n"
        "except SystemExit as e:\n"
        "    assert e.code == 0, e.code\n"
        "heavy = sorted(m for m in ('torch', 'torchrl', 'tensordict', 'evaaa.env', 'evaaa_baselines.run') if m in sys.modules)\n"
        "print('loaded:', heavy)\n"
    )
    out = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "total_steps: int" in out.stdout  # the help was printed
    assert out.stdout.rstrip().endswith("loaded: []"), out.stdout[-300:]


def test_train_help_lists_only_training_groups(capsys):
    with pytest.raises(SystemExit):
        check_command_line(["--help"])
    groups = capsys.readouterr().out.split("groups (")[1].split("\nkeys (")[0]
    assert "algo: dqn" in groups and "protocol" not in groups  # protocol=<name> is scripts/reproduce.py's key


HELP_PROBE = (
    "import runpy, sys\n"
    "sys.argv = [sys.argv[1], '--help']\n"
    "try:\n"
    "    runpy.run_path(sys.argv[0], run_name='__main__')\n"
    "except SystemExit as e:\n"
    "    assert e.code in (0, None), e.code\n"
    "print('loaded:', sorted(m for m in ('torch', 'torchrl', 'tensordict') if m in sys.modules))\n"
)


def test_the_report_s_help_loads_neither_pandas_nor_scipy_stats():
    # issue 64: report.py's --help took 3.2 s of CPU (over the 3 s asked), importing the report layer first
    probe = HELP_PROBE.replace("('torch', 'torchrl', 'tensordict')", "('pandas', 'scipy.stats')")
    out = subprocess.run(
        [sys.executable, "-c", probe, "scripts/report.py"], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0 and "usage: " in out.stdout, out.stderr[-2000:]
    assert out.stdout.rstrip().endswith("loaded: []"), out.stdout[-300:]


def test_the_demo_s_help_loads_neither_matplotlib_nor_scipy_spatial():
    # issue 64: demo.py's --help took 3.2 CPU-s beside a training run (over the 3 s asked): the pictures module (and
    # matplotlib) loaded before the arguments were read, and `import evaaa` loaded scipy.spatial for the patrol hull
    probe = HELP_PROBE.replace("('torch', 'torchrl', 'tensordict')", "('matplotlib', 'scipy.spatial')")
    out = subprocess.run(
        [sys.executable, "-c", probe, "scripts/demo.py"], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0 and "usage: " in out.stdout, out.stderr[-2000:]
    assert out.stdout.rstrip().endswith("loaded: []"), out.stdout[-300:]


@pytest.mark.parametrize("name", sorted({*SCHEMAS, "train"}))
def test_help_of_every_script_imports_no_torch(name):
    """``--help`` of every script prints before torch, TorchRL and TensorDict load (issue 64: evaluate's, demo's and
    reproduce's help imported torch first, 29-39 s under load against 9 s for train's): what keeps it within 3 s of
    CPU on a 2-core machine."""
    out = subprocess.run(
        [sys.executable, "-c", HELP_PROBE, f"scripts/{name}.py"], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert "usage: " in out.stdout  # the help was printed
    assert out.stdout.rstrip().endswith("loaded: []"), out.stdout[-300:]
