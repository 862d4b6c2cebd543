"""What `pip install -e .` puts on the import path: `evaaa` and `evaaa_baselines`, and no top-level `baselines`
(the name of OpenAI's package, installed in many RL environments)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import tomllib

ROOT = Path(__file__).resolve().parents[1]


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
    assert found == listed
    assert not (ROOT / "hydra_plugins" / "__init__.py").exists()  # a namespace package, as Hydra's plugins need
