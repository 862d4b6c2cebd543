"""The zoo (baselines/zoo.py): trained networks shipped with the baselines, loaded by name (``zoo:<name>``) wherever
a checkpoint file is taken, each checked against its manifest's sha256; ``scripts/zoo.py`` adds one.  Nothing here
depends on the shipped network's bytes: it is replaced by the final one."""

from __future__ import annotations

import fnmatch
import re
import shutil
from pathlib import Path

import pytest
import tomllib
import yaml
from helpers import load_script

from evaaa_baselines import zoo
from evaaa_baselines.checkpoint import CheckpointError
from evaaa_baselines.policies import load_policy

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = "zoo:ppo-1-1"


@pytest.fixture
def own_zoo(tmp_path, monkeypatch) -> Path:
    """A copy of the shipped zoo that a test may change, standing in for it."""
    folder = tmp_path / "zoo"
    shutil.copytree(zoo.ZOO_DIR, folder)
    monkeypatch.setattr(zoo, "ZOO_DIR", folder)
    return folder


def test_the_shipped_zoo_records_each_network_and_its_file_matches():
    known = zoo.entries()
    assert "ppo-1-1" in known
    for name, e in known.items():
        assert (e.algo, e.file) == (("ppo", "ppo-1-1.pt") if name == "ppo-1-1" else (e.algo, f"{name}.pt"))
        stages = re.search(r"level\.stages=\[([^]]*)\]", e.trained_by)  # a curriculum's network: its last stage
        level = stages.group(1).split(",")[-1] if "level=curriculum" in e.trained_by else None
        assert e.trained_by.startswith("python scripts/train.py ") and level in (e.level, None)
        assert level is not None or f"level={e.level}" in e.trained_by
        assert isinstance(e.env_steps, int) and e.env_steps > 0 and e.seed is not None
        assert zoo.resolve(f"zoo:{name}") == zoo.ZOO_DIR / e.file
        assert zoo.sha256(zoo.ZOO_DIR / e.file) == e.sha256
    assert known["ppo-1-1"].level == "1-1"
    # the survival fields, filled in from an evaluation of each network on each kind of world by the command they name
    for name, fields in yaml.safe_load((zoo.ZOO_DIR / zoo.MANIFEST).read_text())["networks"].items():
        assert {"validation_survival", "test_survival", "trained_by", "sha256"} <= fields.keys()
        for worlds in ("validation", "test"):
            survival = fields[f"{worlds}_survival"]
            assert f"worlds={worlds}" in survival["command"] and f"policy=[zoo:{name}]" in survival["command"]
            assert f"levels=[{fields['level']}]" in survival["command"]
            assert survival["se"] < survival["mean"] <= 5000 and survival["episodes"] == 20


def test_a_survival_field_reads_as_mean_se_episodes_and_acting():
    text = zoo.ZooEntry.survival_text
    assert (
        text({"mean": 3481.96, "se": 278.04, "episodes": 20, "acting": "sample"}) == "3482 ± 278 (20 episodes, sample)"
    )
    assert text({"mean": 1112.0, "se": 0.0, "episodes": 8}) == "1112 ± 0 (8 episodes)"
    assert text(None) == "not measured"


def test_a_wheel_ships_the_zoo():
    data = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    patterns = data["evaaa_baselines.zoo"]  # the zoo folder is a data package of its own
    shipped = [p.name for p in (ROOT / "baselines" / "zoo").iterdir()]
    assert shipped and all(any(fnmatch.fnmatch(f, p) for p in patterns) for f in shipped), (shipped, patterns)


def test_load_policy_takes_a_zoo_name():
    policy = load_policy(SHIPPED)
    entry = zoo.entry(SHIPPED)
    assert (policy.algo, policy.level, policy.path) == (entry.algo, entry.level, zoo.ZOO_DIR / entry.file)


def test_a_wrong_name_is_one_line_with_the_names_and_the_closest():
    with pytest.raises(zoo.ZooError) as err:
        load_policy("zoo:ppo-11")
    message = str(err.value)
    assert "\n" not in message
    assert "zoo:ppo-11 is not in the zoo; did you mean zoo:ppo-1-1?" in message
    assert "networks: " in message and "zoo:ppo-1-1" in message.split("networks: ")[1]
    assert "did you mean" not in str(pytest.raises(zoo.ZooError, zoo.entry, "zoo:qqqqqqqqqqqqqq").value)


def test_a_file_that_differs_from_the_manifest_is_refused_naming_it(own_zoo):
    path = own_zoo / "ppo-1-1.pt"
    data = bytearray(path.read_bytes())
    data[-100] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(CheckpointError, match=r"ppo-1-1\.pt \(zoo:ppo-1-1\) is refused: its sha256 is [0-9a-f]{64}"):
        load_policy(SHIPPED)
    path.unlink()
    with pytest.raises(CheckpointError, match=r"ppo-1-1\.pt \(zoo:ppo-1-1\): no such file"):
        zoo.resolve(SHIPPED)


def test_the_zoo_script_adds_a_network_from_its_own_record(own_zoo, tmp_path, capsys):
    run = tmp_path / "runs" / "ppo" / "seed0"
    (run / ".hydra").mkdir(parents=True)
    model = run / "model-0-1-1.pt"
    shutil.copyfile(own_zoo / "ppo-1-1.pt", model)
    (run / ".hydra" / "overrides.yaml").write_text("- algo=ppo\n- level=1-1\n- seed=0\n- run.root=/somewhere/runs\n")
    script = load_script("zoo")
    assert script.main(["name=ppo-new", f"model={model}"]) == 0
    added = zoo.entries()["ppo-new"]
    record = load_policy(model)
    assert added.sha256 == zoo.sha256(model) and (own_zoo / "ppo-new.pt").read_bytes() == model.read_bytes()
    assert (added.algo, added.level, added.source) == (record.algo, record.level, "model-0-1-1.pt")
    assert added.seed == record.config["seed"] and added.env_steps > 0
    # the command that trained it, without the folder of the machine it ran on
    assert added.trained_by == "python scripts/train.py algo=ppo level=1-1 seed=0"
    assert added.validation_survival is None and added.test_survival is None
    assert load_policy("zoo:ppo-new").algo == record.algo
    # the name is taken: refused in one line, nothing changed, until replace=true
    before = (own_zoo / zoo.MANIFEST).read_text()
    with pytest.raises(SystemExit) as exc:
        script.main(["name=ppo-new", f"model={model}", "command=python scripts/train.py algo=ppo"])
    assert exc.value.code == 2 and "add replace=true" in capsys.readouterr().err
    assert (own_zoo / zoo.MANIFEST).read_text() == before
    assert script.main(["name=ppo-new", f"model={model}", "replace=true", "command=by hand"]) == 0
    assert zoo.entries()["ppo-new"].trained_by == "by hand"
    capsys.readouterr()
    assert script.main([]) == 0  # lists them, each file checked
    listed = capsys.readouterr().out
    assert "zoo:ppo-new  ppo on 1-1" in listed and "[ok]" in listed


@pytest.mark.parametrize("argv", [["name=x"], ["name=Bad Name", "model=MODEL"], ["name=x", "model=nowhere.pt"]])
def test_the_zoo_script_refuses_in_one_line(own_zoo, argv, capsys):
    argv = [a.replace("MODEL", str(own_zoo / "ppo-1-1.pt")) for a in argv]
    before = sorted(p.name for p in own_zoo.iterdir())
    with pytest.raises(SystemExit) as exc:
        load_script("zoo").main(argv)
    err = capsys.readouterr().err
    assert exc.value.code == 2 and err.count("\n") == 1 and err.startswith("zoo.py: error: "), err
    assert sorted(p.name for p in own_zoo.iterdir()) == before


def test_evaluate_takes_zoo_names_and_refuses_a_wrong_one_before_writing(tmp_path, capsys):
    evaluate = load_script("evaluate")
    assert evaluate.parse(["policy=[zoo:ppo-1-1,random]"]).policy == ["zoo:ppo-1-1", "random"]
    assert evaluate.parse(["policy=zoo:ppo-1-1"]).policy == ["zoo:ppo-1-1"]
    out = tmp_path / "eval"
    with pytest.raises(SystemExit) as exc:
        evaluate.main(["policy=[random,zoo:ppo-1-l]", "levels=[1-1]", f"out={out}"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and err.count("\n") == 1, err
    assert "policy=" in err and "did you mean zoo:ppo-1-1?" in err
    assert not out.exists()


def test_an_evaluated_zoo_network_is_named_by_its_zoo_name():
    from evaaa_baselines.evaluation import EvaluatedPolicy

    policy = EvaluatedPolicy(SHIPPED, seed=0)
    assert policy.name == SHIPPED and policy.loaded.algo == zoo.entry(SHIPPED).algo
    assert policy.acting == "mode"
