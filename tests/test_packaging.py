"""What `pip install -e .` puts on the import path: `evaaa` and `evaaa_baselines`, and no top-level `baselines`
(the name of OpenAI's package, installed in many RL environments); and the wheel `python -m build` makes, installed
into a fresh venv (not editable), away from the clone: the env steps, the levels and the zoo's networks are there."""

from __future__ import annotations

import shutil
import subprocess
import sys
import sysconfig
import textwrap
import venv
from pathlib import Path

import pytest
import tomllib

ROOT = Path(__file__).resolve().parents[1]
#: folders of data only (no __init__.py) that pyproject lists so that setuptools ships them without a warning
DATA_PACKAGES = {"evaaa_baselines.zoo"}
#: what the wheel is built from: what pyproject's packages and readme name
SOURCES = ("pyproject.toml", "README.md", "LICENSE", "evaaa", "baselines", "hydra_plugins")


def test_the_install_provides_evaaa_baselines_and_no_top_level_baselines(tmp_path):
    # from another directory, so that the checkout itself is not on the path
    code = (
        "import importlib.util, evaaa_baselines, evaaa_baselines.training, evaaa; "
        "print(importlib.util.find_spec('baselines') is None, evaaa_baselines.__file__)"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, check=True)
    no_baselines, where = out.stdout.split()
    assert no_baselines == "True"
    assert Path(where).resolve() == (ROOT / "baselines" / "__init__.py").resolve()


def test_every_package_folder_is_listed_in_pyproject():
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = set()
    # (hydra_plugins is a namespace shared with Hydra's launchers: only evaaa's plugin in it is evaaa's)
    for folder in ("evaaa", "baselines", "hydra_plugins"):
        found |= {
            ".".join(("evaaa_baselines", *parts[1:]) if parts[0] == "baselines" else parts)
            for parts in (i.parent.relative_to(ROOT).parts for i in (ROOT / folder).rglob("__init__.py"))
        }
    assert found | DATA_PACKAGES == listed
    assert not (ROOT / "hydra_plugins" / "__init__.py").exists()  # a namespace package, as Hydra's plugins need


#: run in the fresh venv, from a folder that is not the clone: what works without a clone
WITHOUT_A_CLONE = textwrap.dedent(
    """
    import sys
    from pathlib import Path

    import gymnasium

    import evaaa
    import evaaa_baselines
    from evaaa.level_files import load_level
    from evaaa_baselines import zoo

    here = Path(sys.argv[1]).resolve()
    for module in (evaaa, evaaa_baselines):  # the wheel's copy, not the clone's
        assert Path(module.__file__).resolve().is_relative_to(here), module.__file__
    levels = sorted(p.stem for p in (Path(evaaa.__file__).parent / "levels").glob("*.yaml") if p.stem[0] != "_")
    assert levels == sorted((*evaaa.LEVELS, *evaaa.TESTBEDS)), levels
    assert all(load_level(name).name == name for name in levels)
    env = evaaa.make_env("1-1", num_envs=2, seed=0)
    data = env.rollout(5, break_when_any_done=False)
    assert data["next", "pixels"].shape == (2, 5, 64, 64, 3) and data["next", "pixels"].float().std() > 0
    env.close()
    gym_env = gymnasium.make("evaaa/two-resource-food-v0")
    obs, _ = gym_env.reset(seed=0)
    gym_env.step(1)
    gym_env.close()
    assert zoo.resolve("zoo:ppo-1-1").is_relative_to(here)  # the network, its sha256 checked against the manifest
    # the baselines' Python API (the train extra's packages): a zoo network acts, and a policy of your own is scored
    from evaaa_baselines import load_policy
    from evaaa_baselines.evaluation import score

    policy = load_policy("zoo:ppo-1-1")
    env = policy.make_env("1-1", num_envs=1, seed=0)
    assert policy(env.reset())["action"].shape == (1,)
    env.close()
    (here / "tiny.yaml").write_text('extends: "1-1"\\nepisode: {max_steps: 5}\\n')
    result = score(lambda td: td["interoception"][:, 0] * 0, levels=[str(here / "tiny.yaml")], episodes=1,
                   num_envs=1, out=here / "score", name="mine")
    assert "| mine | random | still |" in result.table
    print("ok", len(levels), "levels")
    """
)


@pytest.mark.slow  # builds the wheel and a venv (about a minute on a busy 2-core box)
def test_the_wheel_installs_into_a_fresh_venv_and_works_without_the_clone(tmp_path):
    source = tmp_path / "source"
    source.mkdir()
    for name in SOURCES:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, source / name, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
        else:
            shutil.copy2(ROOT / name, source / name)
    # with this environment's setuptools (the dev extra), so that the build downloads nothing
    built = subprocess.run(
        [sys.executable, "-m", "build", "--wheel", "--no-isolation", "--outdir", str(tmp_path / "dist"), str(source)],
        capture_output=True,
        text=True,
    )
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr[-3000:]
    log = built.stdout + built.stderr
    assert "absent from the `packages` configuration" not in log and "Warning" not in log, log[-3000:]
    (wheel,) = (tmp_path / "dist").glob("evaaa-*.whl")
    fresh = tmp_path / "fresh"
    venv.create(fresh, with_pip=True)
    python = fresh / "bin" / "python"
    installed = subprocess.run(
        [str(python), "-m", "pip", "install", "--no-deps", "--no-index", "--quiet", str(wheel)],
        capture_output=True,
        text=True,
    )
    assert installed.returncode == 0, installed.stderr[-3000:]
    # its dependencies from this environment (a .pth line adds a folder, not its .pth files, so the clone's editable
    # install stays out): what pip would download, torch and MuJoCo, is not downloaded again
    purelib = Path(
        subprocess.check_output(
            [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], text=True
        ).strip()
    )
    (purelib / "zz-dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    done = subprocess.run(
        [str(python), "-c", WITHOUT_A_CLONE, str(fresh)], cwd=tmp_path, capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.split() == ["ok", str(len(evaaa_names())), "levels"]


def evaaa_names() -> list[str]:
    import evaaa

    return [*evaaa.LEVELS, *evaaa.TESTBEDS]
