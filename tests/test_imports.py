"""The project's import graph has no cycle, counting imports inside functions too.

Every ``import`` in ``evaaa/`` and ``baselines/`` (installed as ``evaaa_baselines``) is read from the source with
:mod:`ast`, wherever it stands (module level, a function, a method), except under ``if TYPE_CHECKING:`` (annotations
only, never run).  An edge goes from the importing module to the project module it names; a package's
``__init__`` is the node of the package itself.  The implicit import of a parent package (Python runs
``evaaa/__init__.py`` before ``evaaa.env``) is not an edge, so a package may re-export its modules.
"""

from __future__ import annotations

import ast
import graphlib
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
#: the project's packages: import name -> folder
PACKAGES = {"evaaa": REPO / "evaaa", "evaaa_baselines": REPO / "baselines"}


def modules(packages: dict[str, Path] = PACKAGES) -> dict[str, Path]:
    """Every module of ``packages`` by its dotted name (a package by its own name)."""
    found = {}
    for name, root in packages.items():
        for path in sorted(root.rglob("*.py")):
            parts = [name, *path.relative_to(root).with_suffix("").parts]
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join(parts)] = path
    return found


def _type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _imports(tree: ast.AST):
    """Every Import / ImportFrom node, skipping ``if TYPE_CHECKING:`` bodies (their ``else`` still counts)."""
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, ast.If) and _type_checking(node):
            for child in node.orelse:
                yield from _imports(ast.Module(body=[child], type_ignores=[]))
            continue
        if isinstance(node, ast.Import | ast.ImportFrom):
            yield node
        yield from _imports(node)


def imported(module: str, path: Path, known: set[str]) -> set[str]:
    """The project modules ``module`` imports."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    targets = set()

    def nearest(name: str) -> str | None:  # the longest known prefix: a.b.C (a class) -> a.b
        while name and name not in known:
            name = name.rpartition(".")[0]
        return name or None

    for node in _imports(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names = [
                alias.name.replace("baselines", "evaaa_baselines", 1)
                if alias.name.startswith("baselines")
                else alias.name
                for alias in node.names
            ]
            targets.update(filter(None, map(nearest, names)))
            continue
        base = node.module or ""
        if node.level:
            anchor = package
            for _ in range(node.level - 1):
                anchor = anchor.rpartition(".")[0]
            base = f"{anchor}.{base}" if base else anchor
        for alias in node.names:  # `from pkg import mod` names a module; `from mod import thing` the module
            full = f"{base}.{alias.name}"
            target = full if full in known else nearest(base)
            if target:
                targets.add(target)
    targets.discard(module)
    return targets


def import_graph(packages: dict[str, Path] = PACKAGES) -> dict[str, set[str]]:
    mods = modules(packages)
    known = set(mods)
    return {name: imported(name, path, known) for name, path in mods.items()}


def test_the_graph_sees_the_imports_that_matter():
    graph = import_graph()
    # module level, relative
    assert "evaaa_baselines.checkpoint" in graph["evaaa_baselines.run"]
    # `from . import x` names the module x; `from evaaa import make_env` the package
    assert "evaaa" in graph["evaaa_baselines.evaluation"]
    # an import inside a function counts
    source = (REPO / "baselines" / "config.py").read_text()
    assert "    from .algos import algorithm" in source
    assert "evaaa_baselines.algos" in graph["evaaa_baselines.config"]


def test_type_checking_imports_are_not_edges():
    tree = ast.parse(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .a import A\nelse:\n    from .b import B\n"
    )
    assert [n.module for n in _imports(tree) if isinstance(n, ast.ImportFrom)] == ["typing", "b"]


def cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle of ``graph`` (its modules in order, the first repeated last), or None."""
    try:
        graphlib.TopologicalSorter(graph).prepare()
    except graphlib.CycleError as err:
        return list(reversed(err.args[1]))
    return None


def test_a_cycle_through_a_function_level_import_is_found(tmp_path):
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("from .a import A\n")
    (pkg / "a.py").write_text("from .b import B\n\nclass A: ...\n")
    (pkg / "b.py").write_text("def B():\n    from .a import A  # at call time only\n    return A\n")
    (pkg / "c.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .a import A\n")
    graph = import_graph({"pkg": pkg})
    assert graph == {"pkg": {"pkg.a"}, "pkg.a": {"pkg.b"}, "pkg.b": {"pkg.a"}, "pkg.c": set()}
    found = cycle(graph)
    assert found is not None and set(found) == {"pkg.a", "pkg.b"}
    (pkg / "b.py").write_text("def B():\n    return 1\n")
    assert cycle(import_graph({"pkg": pkg})) is None


def test_no_import_cycle():
    found = cycle(import_graph())
    assert found is None, "import cycle: " + " -> ".join(found or [])


def private_reads(path: Path, owner: str = "run") -> list[str]:
    """``owner._name`` attribute reads in a module's source (a Run's own names, read from outside it)."""
    tree = ast.parse(path.read_text(), str(path))
    return [
        f"{path.name}:{node.lineno}: {owner}.{node.attr}"
        for node in ast.walk(tree)
        if isinstance(node, ast.Attribute)
        and isinstance(node.value, ast.Name)
        and node.value.id == owner
        and node.attr.startswith("_")
    ]


def test_algorithms_use_only_the_public_run_contract(tmp_path):
    bad = tmp_path / "algo.py"
    bad.write_text("def train(run):\n    return run.steps, run._session\n")
    assert private_reads(bad) == ["algo.py:2: run._session"]
    # every module an algorithm is made of (baselines/*.py and subpackages, the Run's own module aside)
    sources = [p for p in (REPO / "baselines").rglob("*.py") if p.name != "run.py"]
    assert any(p.name == "ppo.py" for p in sources)
    assert [hit for path in sources for hit in private_reads(path)] == []
