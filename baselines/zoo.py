"""The zoo: trained networks shipped with ``evaaa_baselines``, loaded by name wherever a checkpoint file is taken.

``zoo:<name>`` stands for ``baselines/zoo/<name>.pt`` (package data, so an installed wheel has them too):

>>> from evaaa_baselines.policies import load_policy
>>> policy = load_policy("zoo:ppo-1-1")               # a LoadedPolicy, as from a run's model-*.pt

    python scripts/evaluate.py policy=[zoo:ppo-1-1,random] levels=[1-1]
    python scripts/demo.py policy=zoo:ppo-1-1 level=1-1 steps=600

``baselines/zoo/zoo.yaml`` is the manifest: for each network its file, the file's sha256, the algorithm, level,
seed and env steps its checkpoint records, the command that trained it, and what it survives on validation and test
worlds (``null`` until someone evaluates it).  A file whose sha256 differs from the manifest's is refused
(:class:`~baselines.checkpoint.CheckpointError`), so a network is never swapped silently.  ``scripts/zoo.py`` adds
or replaces an entry from a run's model file, reading these values from the checkpoint's own record.

Nothing here imports torch until a network is read, so that scripts check ``zoo:`` names before torch loads.
"""

from __future__ import annotations

import difflib
import hashlib
import re
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import yaml

#: what names a zoo network where a checkpoint path is taken
PREFIX = "zoo:"
#: where the shipped networks and their manifest lie
ZOO_DIR = Path(__file__).resolve().parent / "zoo"
MANIFEST = "zoo.yaml"
#: a network's name: a file name too, and typed on command lines
NAME = re.compile(r"^[a-z0-9][a-z0-9._-]*$")
_HEADER = """\
# The zoo: trained networks shipped with evaaa_baselines, loaded as policy=zoo:<name> (baselines/zoo.py).
# Written by scripts/zoo.py, which reads algo, level, seed and env_steps from the checkpoint's own record and the
# command from its run's .hydra/overrides.yaml; a file whose sha256 differs from the one here is refused.
# validation_survival / test_survival: the network's survival (decisions) on validation / test worlds, filled in
# from an evaluation (null: not yet): mean, se (standard error), iqm, episodes, acting (sample or mode), command.
"""


class ZooError(ValueError):
    """A ``zoo:`` name that names no network of the zoo, or a manifest that cannot be read."""


@dataclass(frozen=True)
class ZooEntry:
    """One network of the zoo, as the manifest records it."""

    name: str
    file: str
    sha256: str
    algo: str
    level: str
    seed: int | None
    env_steps: int | None
    source: str  # the model file it was copied from (model-<stage>-<level>.pt: final; model-best-...: best)
    trained_by: str  # the command that trained it
    validation_survival: Any = None
    test_survival: Any = None
    note: str = ""

    def path(self, folder: Path | None = None) -> Path:
        return (folder or ZOO_DIR) / self.file

    @staticmethod
    def survival_text(survival: Any) -> str:
        """``3482 ± 278 (20 episodes, sample)`` from a survival field; ``not measured`` where it is empty."""
        if not survival:
            return "not measured"
        if isinstance(survival, dict) and {"mean", "se", "episodes"} <= survival.keys():
            acting = f", {survival['acting']}" if survival.get("acting") else ""
            return f"{survival['mean']:.0f} ± {survival['se']:.0f} ({survival['episodes']} episodes{acting})"
        return str(survival)


def is_zoo(spec: Any) -> bool:
    """Whether ``spec`` (a policy or checkpoint argument) names a zoo network."""
    return isinstance(spec, str) and spec.startswith(PREFIX)


def entries(folder: Path | None = None) -> dict[str, ZooEntry]:
    """Every network of the zoo in ``folder`` (default the shipped one), by name."""
    manifest = (folder or ZOO_DIR) / MANIFEST
    if not manifest.is_file():
        return {}
    try:
        data = yaml.safe_load(manifest.read_text()) or {}
        return {name: ZooEntry(name=name, **fields) for name, fields in (data.get("networks") or {}).items()}
    except (yaml.YAMLError, TypeError, AttributeError) as err:
        raise ZooError(f"{manifest} is malformed: {' '.join(str(err).split())[:200]}") from None


def entry(spec: str, folder: Path | None = None) -> ZooEntry:
    """The manifest's entry for ``spec`` (``zoo:<name>`` or ``<name>``).  Raises :class:`ZooError` in one line naming
    the networks there are, with the closest one first when the name looks like a typo."""
    name = spec[len(PREFIX) :] if is_zoo(spec) else spec
    known = entries(folder)
    if name in known:
        return known[name]
    close = difflib.get_close_matches(name, known, n=1, cutoff=0.5)
    hint = f"did you mean {PREFIX}{close[0]}? " if close else ""
    names = ", ".join(PREFIX + n for n in sorted(known)) or "none"
    raise ZooError(f"{PREFIX}{name} is not in the zoo; {hint}networks: {names}")


def sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def resolve(spec: str, folder: Path | None = None) -> Path:
    """The checkpoint file of the zoo network ``spec`` (``zoo:<name>``), once its sha256 matches the manifest's.

    Raises :class:`ZooError` for a name the zoo does not hold and :class:`~baselines.checkpoint.CheckpointError`
    naming the file when it is missing or differs from the file the manifest recorded."""
    from .checkpoint import CheckpointError

    found = entry(spec, folder)
    path = found.path(folder)
    if not path.is_file():
        raise CheckpointError(f"{path} ({PREFIX}{found.name}): no such file; the zoo's manifest lists it")
    actual = sha256(path)
    if actual != found.sha256:
        raise CheckpointError(
            f"{path} ({PREFIX}{found.name}) is refused: its sha256 is {actual}, the zoo's manifest says "
            f"{found.sha256} (replace it with scripts/zoo.py, which records both)"
        )
    return path


def checkpoint_path(spec: str | Path) -> Path:
    """``spec`` as a checkpoint file: a zoo network's verified file for ``zoo:<name>``, else the path itself."""
    return resolve(spec) if is_zoo(spec) else Path(spec)


def trained_by(model: Path) -> str:
    """The training command of the run ``model`` lies in, from Hydra's record of it (``.hydra/overrides.yaml``;
    overrides whose value is an absolute path, such as ``run.root=``, name a folder of that machine, not the recipe,
    and are left out); empty when there is no record."""
    overrides = model.parent / ".hydra" / "overrides.yaml"
    if not overrides.is_file():
        return ""
    args = [str(a) for a in yaml.safe_load(overrides.read_text()) or []]
    return " ".join(["python scripts/train.py", *(a for a in args if not a.partition("=")[2].startswith("/"))])


def add(
    name: str,
    model: Path,
    *,
    algo: str,
    level: str,
    seed: int | None,
    env_steps: int | None,
    command: str,
    note: str = "",
    replace: bool = False,
    folder: Path | None = None,
) -> ZooEntry:
    """Copy the checkpoint ``model`` into the zoo as ``<name>.pt`` and record it in the manifest with its sha256 and
    the values given (``scripts/zoo.py`` reads them from the checkpoint's own record; ``command`` is how it was
    trained).  Survival fields start empty: they belong to the network measured, not to one it replaces.  Raises
    ``ValueError`` (nothing written) for a bad name, or an existing one without ``replace``."""
    folder = folder or ZOO_DIR
    if not NAME.match(name):
        raise ValueError(f"name={name!r}: expected lower-case letters, digits, '.', '_' or '-' (e.g. ppo-1-1)")
    known = entries(folder)
    if name in known and not replace:
        raise ValueError(f"name={name}: the zoo already holds {PREFIX}{name}; add replace=true to replace it")
    model = Path(model)
    new = ZooEntry(
        name=name,
        file=f"{name}.pt",
        sha256=sha256(model),
        algo=algo,
        level=level,
        seed=seed,
        env_steps=env_steps,
        source=model.name,
        trained_by=command or "unknown",
        note=note,
    )
    folder.mkdir(parents=True, exist_ok=True)
    target = new.path(folder)
    partial = target.with_name(target.name + ".partial")
    shutil.copyfile(model, partial)
    if sha256(partial) != new.sha256:
        partial.unlink()
        raise ValueError(f"{model}: its copy at {partial} differs from it (a disk error?); nothing was changed")
    partial.replace(target)
    known[name] = new
    _write_manifest(known, folder)
    return new


def _write_manifest(known: dict[str, ZooEntry], folder: Path) -> None:
    networks = {}
    for name in sorted(known):
        fields = asdict(known[name])
        del fields["name"]
        networks[name] = fields
    text = _HEADER + yaml.safe_dump({"networks": networks}, sort_keys=False, width=120, allow_unicode=True)
    tmp = folder / (MANIFEST + ".partial")
    tmp.write_text(text)
    tmp.replace(folder / MANIFEST)
