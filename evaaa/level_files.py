"""Level files: reading a level's YAML within limits, ``extends:`` and merging, dotted overrides, and error text.

A level is data (``evaaa/levels/<name>.yaml``); this module owns how a file, the files it extends and the user's
overrides are merged and validated against :class:`~evaaa.level.Level`.  Every level starts from
``levels/_defaults.yaml`` (the values common to all levels), may ``extends:`` another level, and may be changed
by dotted-path overrides (``{"agent.move_speed": 10}``).  Any mistake raises :class:`~evaaa.level.LevelError`
naming the field and what it accepts.
"""

from __future__ import annotations

import functools
import math
import os
import re
import stat
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ValidationError

from .level import LEVEL_NAME, LEVEL_NAME_RULE, Level, LevelError, excerpt
from .level_limits import MAX_INTEGER

__all__ = [
    "LEVELS",
    "TESTBEDS",
    "load_level",
    "level_names",
    "register_level",
]

#: Largest level file read (bytes).  The packaged levels are 0.5-3.5 KB, and a landmark pattern of 100 x 100 cells
#: is 30 KB; PyYAML's pure-Python parser reads about 50-200 KB/s, so a file at the limit parses in about a second.
MAX_FILE_BYTES = 64 * 1024
#: Deepest nesting of a level file or an override value (the schema nests 7 deep).  Parsing, merging and the
#: error messages stay far from Python's recursion limit, and libyaml's loader, which crashed the process at
#: 100,000 levels, is never used.
MAX_DEPTH = 32
#: Most values (mappings, lists and scalars, counting each use of an alias as a copy of what it names) in one level
#: file: ten times the largest landmark pattern.  A 7 x 7 alias chain would expand to 8e5, a 9 x 9 one to 4e8.
MAX_NODES = 100_000
#: Longest ``extends:`` chain, the file itself included (the packaged levels' longest, 4-2's, is 9 files)
MAX_EXTENDS = 32
#: keys of a level file about the file itself, not the level: they are not inherited through ``extends:``
_FILE_KEYS = ("extends", "order")


#: Most digits of an integer in a level file: a level's integers lie within MAX_INTEGER (10 digits), and Python
#: refuses to read one of more than 4,300 digits (a raw ValueError) or takes quadratic time below that
MAX_INTEGER_DIGITS = 100
_INT = "tag:yaml.org,2002:int"


def _yaml11_form(node: yaml.ScalarNode) -> str | None:
    """What is wrong with a plain scalar PyYAML (YAML 1.1) resolved to a number or a flag that YAML 1.2, which the
    level files are written in, reads otherwise (octal 010, base-60 1:30, binary 0b1, yes/no/on/off), or with an
    integer too long to read; None when nothing is."""
    if node.style is not None:  # quoted or a block: text in both versions
        return None
    text, number = node.value, node.value.lstrip("+-").replace("_", "")
    if node.tag == _INT and len(number) > MAX_INTEGER_DIGITS:
        return (
            f"an integer of {len(number)} digits; a level's integers lie within [-{MAX_INTEGER:.0e}, {MAX_INTEGER:.0e}]"
        )
    if node.tag in (_INT, "tag:yaml.org,2002:float") and ":" in text:
        return (
            f"{excerpt(text)} is a base-60 number in YAML 1.1 ({yaml.safe_load(text)}) and text in YAML 1.2; "
            "write the number you mean"
        )
    if node.tag == _INT and number[:2].lower() == "0b":
        return f"{excerpt(text)} is binary in YAML 1.1 ({yaml.safe_load(text)}) and text in YAML 1.2; write the number you mean"
    if node.tag == _INT and len(number) > 1 and number[0] == "0" and number[1].lower() != "x":
        decimal = ("-" if text.startswith("-") else "") + (number.lstrip("0") or "0")
        return (
            f"{excerpt(text)} is octal in YAML 1.1 ({yaml.safe_load(text)}) and {decimal} in YAML 1.2; write the "
            "number you mean without a leading 0"
        )
    if node.tag == "tag:yaml.org,2002:bool" and text.lower() not in ("true", "false"):
        return f"{excerpt(text)} is {str(yaml.safe_load(text)).lower()} in YAML 1.1 and text in YAML 1.2; write true or false (or quote it)"
    return None


class _Refused(yaml.YAMLError):
    """A level file that breaks a limit of :class:`_LevelLoader` or uses YAML that is not level data."""

    def __init__(self, message: str, mark: yaml.Mark | None):
        super().__init__(message if mark is None else f"{message} (line {mark.line + 1}, column {mark.column + 1})")


class _LevelLoader(yaml.SafeLoader):
    """PyYAML's pure-Python safe loader, with limits: nesting depth, values after alias expansion, duplicate keys,
    plain data only (no sets, binary, ordered maps; dates stay text).

    The C loader is not used: its composer recurses in C, so deep nesting overflows the C stack.  The Python
    composer recurses too, but :meth:`compose_node` stops it at :data:`MAX_DEPTH`.  Aliases are counted as the
    values they stand for, so an alias chain is refused while it is read, before anything expands it.
    """

    def __init__(self, stream: str):
        super().__init__(stream)
        self._depth = 0  # of the node being composed (the document's root is 1)
        self._deepest = 0  # deepest level reached inside the anchored node being composed, aliases expanded
        self._nodes = 0
        self._anchored: dict[str, tuple[int, int]] = {}  # anchor -> (values it stands for, its height)
        self._checked: set[int] = set()  # lists whose scalars _check_scalars has checked

    def _count(self, nodes: int, deepest: int, mark: yaml.Mark) -> None:
        self._nodes += nodes
        self._deepest = max(self._deepest, deepest)
        if deepest > MAX_DEPTH:
            raise _Refused(f"nested deeper than {MAX_DEPTH} levels (the limit of a level file)", mark)
        if self._nodes > MAX_NODES:
            raise _Refused(
                f"more than {MAX_NODES} values, counting what each alias stands for (the limit of a level file)", mark
            )

    def compose_node(self, parent: yaml.Node | None, index: Any) -> yaml.Node:
        event = self.peek_event()
        if isinstance(event, yaml.AliasEvent):
            if event.anchor in self.anchors and event.anchor not in self._anchored:
                raise _Refused(
                    f"the alias *{excerpt(event.anchor)[1:-1]} lies inside the value it names: a level "
                    "cannot contain itself",
                    event.start_mark,
                )
            node = super().compose_node(parent, index)  # an undefined alias raises here
            nodes, height = self._anchored[event.anchor]
            self._count(nodes, self._depth + height, event.start_mark)
            return node
        self._depth += 1
        outer_deepest, self._deepest = self._deepest, self._depth
        start = self._nodes
        self._count(1, self._depth, event.start_mark)
        node = super().compose_node(parent, index)
        if event.anchor is not None:
            self._anchored[event.anchor] = (self._nodes - start, self._deepest - self._depth + 1)
        self._deepest = max(outer_deepest, self._deepest)
        self._depth -= 1
        return node

    def compose_mapping_node(self, anchor: str | None) -> yaml.MappingNode:
        node = super().compose_mapping_node(anchor)
        seen: set[tuple[str, str]] = set()
        for key, value in node.value:
            if isinstance(key, yaml.ScalarNode):
                if (key.tag, key.value) in seen:  # a later key would silently win over the earlier one
                    if key.tag == "tag:yaml.org,2002:merge":
                        raise _Refused(
                            "the merge key << is repeated (the last would silently win); merge several mappings "
                            "with one key: <<: [*a, *b]",
                            key.start_mark,
                        )
                    raise _Refused(f"the key {excerpt(key.value)} is repeated", key.start_mark)
                seen.add((key.tag, key.value))
            self._check_scalars(excerpt(key.value)[1:-1] if isinstance(key, yaml.ScalarNode) else "a key", value)
        return node

    def _check_scalars(self, where: str, node: yaml.Node) -> None:
        """Refuse a plain scalar in ``node`` (a mapping's value, or a list's items, named ``where``) that YAML 1.1
        reads otherwise than YAML 1.2 (:func:`_yaml11_form`) or whose integer Python would not read."""
        if isinstance(node, yaml.ScalarNode):
            problem = _yaml11_form(node)
            if problem:
                raise _Refused(f"{where}: {problem}", node.start_mark)
        elif isinstance(node, yaml.SequenceNode) and id(node) not in self._checked:
            self._checked.add(id(node))  # a list an alias repeats is checked once
            for i, item in enumerate(node.value):
                self._check_scalars(f"{where}[{i}]", item)

    def _not_level_data(self, node: yaml.Node) -> Any:
        raise _Refused(
            f"{node.tag.replace('tag:yaml.org,2002:', '!!')} is not level data (numbers, true/false, "
            "text, lists and mappings)",
            node.start_mark,
        )


def _construct_int(loader: _LevelLoader, node: yaml.ScalarNode) -> int:
    # a key is not checked by _check_scalars: an integer Python will not read (over 4,300 digits) is refused here
    if len(node.value) > MAX_INTEGER_DIGITS:
        raise _Refused(_yaml11_form(node) or "an integer too long to read", node.start_mark)
    return yaml.SafeLoader.construct_yaml_int(loader, node)


_LevelLoader.add_constructor(_INT, _construct_int)
for _tag in ("set", "binary", "omap", "pairs"):
    _LevelLoader.add_constructor(f"tag:yaml.org,2002:{_tag}", _LevelLoader._not_level_data)
# a date is text to a level (a description may start with one), not a datetime no field accepts
_LevelLoader.add_constructor("tag:yaml.org,2002:timestamp", yaml.SafeLoader.construct_yaml_str)
# YAML 1.2's numbers: PyYAML (YAML 1.1) reads 1e-3 and 1e6 as text, which strict fields would refuse
_LevelLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."),
)


def parse_level_text(data: bytes, label: str) -> dict[str, Any]:
    """The mapping in a level file's bytes, parsed within the limits above.  Raises :class:`LevelError`, one line
    naming ``label`` (the file) and what is wrong."""
    if len(data) > MAX_FILE_BYTES:
        raise LevelError(
            f"level file '{label}' is larger than {MAX_FILE_BYTES // 1024} KiB (the limit of a level file)"
        )
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise LevelError(
            f"level file '{label}' is not UTF-8 text: byte {err.object[err.start]:#04x} at offset "
            f"{err.start} ({err.reason})"
        ) from None
    try:
        loader = _LevelLoader(text)
    except yaml.reader.ReaderError as err:  # raised while checking the whole text, before any parsing
        raise LevelError(
            f"level file '{label}' is not valid YAML: character {err.character:#06x} at offset "
            f"{err.position} is not allowed"
        ) from None
    try:
        tree = loader.get_single_data()
    except _Refused as err:
        raise LevelError(f"level file '{label}': {err}") from None
    except yaml.YAMLError as err:
        raise LevelError(f"level file '{label}' is not valid YAML: {_yaml_problem(err)}") from None
    finally:
        loader.dispose()
    if tree is None:
        return {}
    if not isinstance(tree, dict):
        raise LevelError(f"level file '{label}' must hold a mapping at the top, not {type(tree).__name__}")
    return tree


def _yaml_problem(err: yaml.YAMLError) -> str:
    """A PyYAML error in one line of bounded length (its message can quote the file's text)."""
    problem = getattr(err, "problem", None) or str(err)
    mark = getattr(err, "problem_mark", None)
    where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
    text = " ".join(str(problem).split())
    return (text if len(text) <= 200 else text[:200] + "...") + where


#: the packaged level files, including the bases (``_defaults``, ``_testbed``): the only names ``extends:`` and
#: :func:`load_level` resolve inside the package
PACKAGED_FILES = tuple(
    sorted(entry.name[:-5] for entry in resources.files("evaaa.levels").iterdir() if entry.name.endswith(".yaml"))
)


def _is_path(name: str | os.PathLike) -> bool:
    """A level given as a file (``my.yaml``, ``levels/my.yml``, a ``Path``) rather than a packaged level's name."""
    return isinstance(name, os.PathLike) or str(name).endswith((".yaml", ".yml"))


def _read_file(source: str | Path) -> dict[str, Any]:
    """The mapping of a packaged level file (a name of :data:`PACKAGED_FILES`) or of a file the user named."""
    if isinstance(source, Path):
        try:
            if not source.is_file():  # a FIFO or a device would block or never end
                raise LevelError(
                    f"level file '{source}' cannot be read: "
                    + ("not a regular file" if source.exists() else "no such file")
                )
            # without blocking: a file swapped for a FIFO since the check above must not hang the open
            with open(os.open(source, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0)), "rb") as f:
                if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):
                    raise LevelError(f"level file '{source}' cannot be read: not a regular file")
                data = f.read(MAX_FILE_BYTES + 1)
        except OSError as err:
            raise LevelError(f"level file '{source}' cannot be read: {err.strerror or err}") from None
        return parse_level_text(data, str(source))
    return _packaged_file(source)


@functools.cache
def _packaged_file(name: str) -> dict[str, Any]:
    """A packaged file's mapping, parsed once (the pure-Python parser is 7x slower than libyaml's): shared, so
    never changed in place (:func:`_raw_level` copies its top, :func:`_set_dotted` what it changes)."""
    assert name in PACKAGED_FILES, name
    return parse_level_text(resources.files("evaaa.levels").joinpath(f"{name}.yaml").read_bytes(), f"{name}.yaml")


def _parent(parent: Any, child: str | Path, root: Path | None) -> str | Path:
    """Where ``extends: <parent>`` of ``child`` leads: a packaged file, or a file of the user's in ``root`` (the
    folder of the file the user named) or below it."""
    label = f"{child}" if isinstance(child, Path) else f"{child}.yaml"
    usage = (
        f"a packaged level ({', '.join(n for n in PACKAGED_FILES)}) or, in a file of your own, a .yaml file in "
        "its folder or below it"
    )
    if not isinstance(parent, str) or not parent:
        what = "null (leave extends out to start from _defaults)" if parent is None else excerpt(parent)
        raise LevelError(f"level file '{label}': extends must name {usage}; got {what}")
    if not _is_path(parent):
        if parent not in PACKAGED_FILES:
            raise LevelError(f"level file '{label}': extends: {excerpt(parent)} is not {usage}")
        return parent
    if not isinstance(child, Path) or root is None:
        raise LevelError(f"level file '{label}': a packaged level extends packaged levels only, not {excerpt(parent)}")
    path = child.parent / parent
    if not path.resolve().is_relative_to(root):  # '..', an absolute path or a link out of the folder
        raise LevelError(
            f"level file '{label}': extends: {excerpt(parent)} leads out of {root}; a level file "
            "extends files in its own folder or below it only"
        )
    return path


def _packaged_files() -> dict[str, dict[str, Any]]:
    """Every packaged level file that is a level (not a ``_base`` shared by others), by name."""
    return {name: _read_file(name) for name in PACKAGED_FILES if not name.startswith("_")}


def _listed_levels() -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The training levels and the testbeds, each in the ``order:`` their files give (then by name).

    A level's ``kind`` may come from the file it extends (the testbeds inherit it from ``_testbed``); ``order`` is
    the file's own."""
    files = _packaged_files()
    groups: dict[str, list[tuple[float, str]]] = {"training": [], "testbed": []}
    for name, data in files.items():
        kind = _raw_level(name).get("kind")
        if kind not in groups:
            raise LevelError(f"level file '{name}.yaml': kind must be training or testbed, got {kind!r}")
        groups[kind].append((data.get("order", math.inf), name))
    return tuple(n for _, n in sorted(groups["training"])), tuple(n for _, n in sorted(groups["testbed"]))


def _deep_merge(base: dict[str, Any], update: Mapping[str, Any]) -> dict[str, Any]:
    """``update`` merged into a shallow copy of ``base``; mappings merge key by key, ``None`` deletes a key.

    Nothing is deep-copied: both trees are freshly parsed and nested at most :data:`MAX_DEPTH` deep, and
    :func:`_set_dotted` copies what it changes."""
    out = dict(base)
    for key, value in update.items():
        if value is None:
            out.pop(key, None)
        elif isinstance(value, Mapping) and isinstance(out.get(key), dict):
            out[key] = _deep_merge(out[key], value)
        else:
            out[key] = value
    return out


def _raw_level(source: str | Path, _seen: tuple[str, ...] = (), root: Path | None = None) -> dict[str, Any]:
    """The merged tree of a level file and the files it extends (``root``: the folder a user's files stay in)."""
    key = str(source.resolve()) if isinstance(source, Path) else source
    if key in _seen:
        raise LevelError(f"level '{source}' extends itself through {' -> '.join(_seen + (key,))}")
    if len(_seen) >= MAX_EXTENDS:  # each file is a frame of this recursion, and up to 64 KiB read
        raise LevelError(
            f"level file '{_seen[0]}': its extends: chain is longer than {MAX_EXTENDS} files (the limit; the "
            f"packaged levels' longest is 9) at '{source}'"
        )
    data = dict(_read_file(source))
    if "extends" in data:
        parent = _parent(data.pop("extends"), source, root)
    else:
        parent = "_defaults" if source != "_defaults" else None
    for file_key in _FILE_KEYS:
        data.pop(file_key, None)
    if parent is None:
        return data
    return _deep_merge(_raw_level(parent, _seen + (key,), root), data)


def _set_dotted(tree: dict[str, Any], path: str, value: Any) -> None:
    keys = path.split(".")
    node = tree
    for i, key in enumerate(keys[:-1]):
        child = node.get(key)
        if not isinstance(child, dict):
            where = ".".join(keys[: i + 1])
            if child is None:
                allowed = ", ".join(sorted(node)) or "(none)"
                raise LevelError(f"override '{path}': '{where}' is not a field; allowed here: {allowed}")
            raise LevelError(f"override '{path}': '{where}' is a value ({excerpt(child)}), not a section")
        # a copy: the same mapping may sit elsewhere in the tree too (a YAML alias), which must not change with it
        node[key] = child = dict(child)
        node = child
    if value is None:  # as in level files, None removes an entry (e.g. a resource group)
        if keys[-1] not in node:
            raise LevelError(f"override '{path}': nothing to remove; present here: {', '.join(sorted(node))}")
        del node[keys[-1]]
    else:
        node[keys[-1]] = value


def _check_value(path: str, value: Any) -> None:
    """Refuse an override value nested deeper than a level file may be, or holding a cycle or a set (walked without
    recursion: the value may come from anywhere)."""
    stack, nodes = [(value, 1)], 0
    while stack:
        item, depth = stack.pop()
        nodes += 1
        if depth > MAX_DEPTH or nodes > MAX_NODES:
            raise LevelError(
                f"override '{path}': the value nests deeper than {MAX_DEPTH} levels or holds more than "
                f"{MAX_NODES} values (the limits of a level)"
            )
        if isinstance(item, (set, frozenset)):
            raise LevelError(f"override '{path}': expected a list, got a set {excerpt(item)}")
        if isinstance(item, Mapping):
            stack.extend((v, depth + 1) for v in item.values())
        elif isinstance(item, (list, tuple)):
            stack.extend((v, depth + 1) for v in item)


def _flatten_overrides(overrides: Mapping[str, Any], prefix: str = "", depth: int = 1) -> dict[str, Any]:
    """Accept both ``{"agent.move_speed": 10}`` and ``{"agent": {"move_speed": 10}}``; ``None`` removes an entry."""
    if depth > MAX_DEPTH:
        raise LevelError(f"override '{prefix[:200]}...' nests deeper than {MAX_DEPTH} levels")
    flat: dict[str, Any] = {}
    for key, value in overrides.items():
        if not isinstance(key, str) or not key:
            raise LevelError(f"override keys must be non-empty strings, got {excerpt(key)}")
        path = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(_flatten_overrides(value, path + ".", depth + 1))  # an empty mapping changes nothing
        else:
            _check_value(path, value)
            flat[path] = value
    return flat


def _model_at(loc: tuple[Any, ...]) -> type[BaseModel] | None:
    """The schema class that owns the field at ``loc`` (for listing allowed keys)."""
    model: Any = Level
    for part in loc:
        if isinstance(model, type) and issubclass(model, BaseModel):
            field = model.model_fields.get(str(part))
            if field is None:
                return None
            model = field.annotation
        elif getattr(model, "__origin__", None) is dict:
            model = model.__args__[1]
        else:
            return None
    if getattr(model, "__origin__", None) is dict:
        return None
    return model if isinstance(model, type) and issubclass(model, BaseModel) else None


def _format_errors(name: str, err: ValidationError) -> str:
    lines = []
    unknown: dict[tuple[Any, ...], list[str]] = {}  # a section's unknown fields, said on one line
    for e in err.errors():
        loc = tuple(e["loc"])
        where = ".".join(str(p) for p in loc)
        if e["type"] == "extra_forbidden":
            if loc[:-1] not in unknown:
                unknown[loc[:-1]] = []
                lines.append(loc[:-1])  # placeholder, filled in below
            unknown[loc[:-1]].append(where)
        elif e["type"] == "missing":
            lines.append(f"{where}: required field is missing")
        else:
            got = e.get("input")
            got_text = "" if isinstance(got, dict) else f" (got {excerpt(got)})"
            msg = e["msg"].removeprefix("Value error, ")
            # a rule across sections (loc empty) names its fields itself
            lines.append(f"{where}: {msg}{got_text}" if where else msg)
    for i, line in enumerate(lines):
        if isinstance(line, tuple):
            fields, owner = unknown[line], _model_at(line)
            named = ", ".join(excerpt(f)[1:-1] for f in fields[:5]) + (
                f" and {len(fields) - 5} more" if len(fields) > 5 else ""
            )
            lines[i] = (
                f"{named}: unknown field{'s' if len(fields) > 1 else ''}; allowed: "
                f"{', '.join(owner.model_fields) if owner else '?'}"
            )
    shown = lines[:10] + ([f"... and {len(lines) - 10} more"] if len(lines) > 10 else [])
    return f"invalid level '{name}':\n  " + "\n  ".join(shown)


def load_level(name: str | os.PathLike, overrides: Mapping[str, Any] | None = None) -> Level:
    """Load a level by name, or from the user's own YAML file (a path ending in ``.yaml``), apply dotted-path
    overrides and validate it.

    A file outside the package is read as the packaged ones are: it starts from ``_defaults.yaml`` and may
    ``extends:`` a packaged level by name (or another file in its own folder or below it).  Its level's name is the
    file's stem unless it says ``name:``.  Every file is parsed within limits (:data:`MAX_FILE_BYTES`,
    :data:`MAX_DEPTH`, :data:`MAX_NODES`), and only these files are read.

    >>> load_level("1-1", {"agent.move_speed": 10}).agent.move_speed
    10.0
    """
    root = None
    if isinstance(name, str) and name in _USER_FILES:
        source, label = _USER_FILES[name], name
    elif isinstance(name, (str, os.PathLike)) and _is_path(name):
        source, label = Path(name), Path(name).stem
    elif not isinstance(name, str) or name not in level_names():
        raise LevelError(
            f"unknown level {excerpt(name)}; available: {', '.join(level_names())}, or a path to a .yaml level file"
        )
    else:
        source = label = name
    if isinstance(source, Path):
        root = _resolved(source).parent
    raw = _raw_level(source, root=root)
    for path, value in _flatten_overrides(overrides or {}).items():
        if path in ("name", "kind"):
            raise LevelError(f"override '{path}' cannot change a level's identity")
        _set_dotted(raw, path, value)
    raw.setdefault("name", label)
    try:
        return Level.model_validate(raw)
    except ValidationError as err:
        raise LevelError(_format_errors(str(name), err)) from None


#: the packaged training levels and testbeds, in their files' ``order:``
LEVELS, TESTBEDS = _listed_levels()
#: levels from the user's own files that :func:`register_level` made loadable by name in this process
_USER_FILES: dict[str, Path] = {}


def _resolved(path: Path) -> Path:
    """``path`` made absolute, links followed; a loop of links is a LevelError (Path.resolve raises RuntimeError)."""
    try:
        return path.resolve()
    except RuntimeError:  # Python before 3.13: "Symlink loop from '<path>'", which would name the file twice
        raise LevelError(f"level file '{path}' cannot be read: Symlink loop (its links lead back to it)") from None
    except OSError as err:
        raise LevelError(f"level file '{path}' cannot be read: {err.strerror or err}") from None


def register_level(path: str | os.PathLike) -> str:
    """Make the level in the user's YAML file at ``path`` loadable by its name (the file's stem) in this process,
    e.g. for code that takes level names, and return the name.  The file is loaded (and so checked) at once."""
    path = _resolved(Path(path))
    if not _is_path(path):
        raise LevelError(f"a level file must end in .yaml or .yml, got '{path}'")
    name = path.stem
    if not LEVEL_NAME.fullmatch(name):  # it becomes a level name, and a run's folder (train.py level=file)
        raise LevelError(f"level file '{path}': its name {excerpt(name)} (the file's stem) must be {LEVEL_NAME_RULE}")
    if name in LEVELS + TESTBEDS or _USER_FILES.get(name, path) != path:
        taken = "a packaged level" if name in LEVELS + TESTBEDS else f"the file '{_USER_FILES[name]}'"
        raise LevelError(f"level file '{path}': its name '{name}' is already {taken}'s; rename the file")
    load_level(path)
    _USER_FILES[name] = path
    return name


def registered_levels() -> tuple[str, ...]:
    """The names :func:`register_level` made loadable in this process."""
    return tuple(_USER_FILES)


def level_names() -> tuple[str, ...]:
    """Every packaged level: the training levels, then the testbeds."""
    return LEVELS + TESTBEDS
