"""The command line of every script but ``train.py``: ``key=value`` arguments read into a typed dataclass.

The syntax is training's (Hydra): ``key=value``, lists as ``key=[a,b]``, a nested key dotted (``a.b=1``), values
read as YAML (``null``, ``true``, numbers).  A script declares its keys as a dataclass whose fields are made with
:func:`option` (default, meaning, and optionally the allowed values), and calls :func:`parse`:

* ``--help`` (or ``-h``) prints every key with its type, default and meaning, and exits with status 0;
* a malformed argument (not ``key=value``, an unknown key, a value of the wrong type or outside what is allowed)
  prints ONE line naming the key and what it accepts, and exits with status 2 — no traceback.

OmegaConf's structured configs do the typing; this module only adds the help, the messages, and two conveniences:
a single value where a list is expected is a list of one (``levels=1-1``), and a string key keeps its text as typed
(``participant=07`` stays ``"07"``, which YAML would read as the number 7).
"""

from __future__ import annotations

import copy
import dataclasses
import difflib
import os
import sys
import textwrap
import types
import typing
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TypeVar

import yaml
from omegaconf import OmegaConf
from omegaconf.errors import ConfigKeyError, OmegaConfBaseException

T = TypeVar("T")
HELP_FLAGS = ("-h", "--help")
SYNTAX = "key=value; lists as key=[a,b]; values read as YAML (null, true, 3, 0.5)"


def option(
    default: Any,
    meaning: str,
    *,
    choices: Sequence[Any] | Callable[[], Sequence[Any]] | None = None,
    check: tuple[Callable[[Any], bool], str] | None = None,
) -> Any:
    """A dataclass field of a script's config: its default, what it means (for ``--help``), and what is allowed.

    ``choices``: the allowed values (for a list: of each element), or a function giving them;
    ``check``: ``(predicate, what is allowed)`` for a value, e.g. ``(lambda v: v >= 1, "at least 1")``.
    """
    metadata = {"meaning": meaning, "choices": choices, "check": check}
    if isinstance(default, (list, dict)):
        return dataclasses.field(default_factory=lambda: copy.deepcopy(default), metadata=metadata)
    return dataclasses.field(default=default, metadata=metadata)


#: ``check=`` of a seed: numpy's generators take no negative seed
SEED = (lambda v: v >= 0, "an integer >= 0")
#: how a level of your own is named in ``levels`` (docs/levels.md, "A level of your own")
OWN_LEVEL = "the path of a .yaml level file of your own, e.g. levels=[1-1,path/to/my.yaml]"


class UsageError(ValueError):
    """A command-line argument is refused; the message names the key and what is allowed."""


# ------------------------------------------------------------------------------------------------- types
def _optional(tp: Any) -> tuple[Any, bool]:
    """``(T, True)`` for ``T | None``, ``(tp, False)`` otherwise."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1 and len(typing.get_args(tp)) == 2:
            return args[0], True
    return tp, False


def _is_list(tp: Any) -> bool:
    return typing.get_origin(_optional(tp)[0]) in (list, Sequence)


def _is_text(tp: Any) -> bool:
    return _optional(tp)[0] in (str, Path)


def _item(tp: Any) -> Any:
    """The element type of a list type."""
    return (typing.get_args(_optional(tp)[0]) or (Any,))[0]


def _bracketed(text: str) -> bool:
    """Whether ``text`` is written as a list, ``[...]``."""
    text = text.strip()
    return len(text) >= 2 and text[0] == "[" and text[-1] == "]"


def _as_typed(text: str, value: Any) -> Any:
    """``value`` (what YAML read from ``text``) with every scalar as the text typed: ``[3_2,07]`` -> ``["3_2", "07"]``;
    null stays null."""
    try:
        raw = yaml.load(text, Loader=yaml.BaseLoader)  # every scalar a string, as typed
    except yaml.YAMLError:
        return value
    if isinstance(value, list) and isinstance(raw, list) and len(raw) == len(value):
        return [v if v is None else r for v, r in zip(value, raw)]
    return raw if not isinstance(value, list) and isinstance(raw, str) else value


def type_name(tp: Any) -> str:
    """How ``--help`` and the errors name a field's type."""
    inner, optional = _optional(tp)
    origin = typing.get_origin(inner)
    if origin in (list, Sequence):
        (item,) = typing.get_args(inner) or (Any,)
        name = f"list of {type_name(item)}"
    elif origin is dict or inner is dict:
        name = "mapping"
    else:
        name = {int: "int", float: "float", bool: "bool", str: "str", Path: "path"}.get(inner, "any")
    return f"{name} or null" if optional else name


def _expected(tp: Any) -> str:
    inner, optional = _optional(tp)
    if typing.get_origin(inner) in (list, Sequence):
        (item,) = typing.get_args(inner) or (Any,)
        text = f"a list of {type_name(item)} values, e.g. [a,b]"
    else:
        text = {int: "an integer", float: "a number", bool: "true or false", str: "a string", Path: "a path"}.get(
            inner, f"a value of type {type_name(inner)}"
        )
    return text + (" (or null)" if optional else "")


def _show(value: Any) -> str:
    """A value as it is typed on the command line."""
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(_show(v) for v in value) + "]"
    if value is None:
        return "null"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_show(v)}" for k, v in value.items()) + "}"
    return str(value)


# ------------------------------------------------------------------------------------------------- help
def usage(schema: type, prog: str, description: str, examples: Sequence[str] = ()) -> str:
    """The ``--help`` text: what the script does, then every key with its type, default, meaning and choices."""
    hints = typing.get_type_hints(schema)
    lines = [f"usage: python scripts/{prog} [key=value ...]", ""]
    for paragraph in description.strip().split("\n\n"):
        lines += [*textwrap.wrap(" ".join(paragraph.split()), width=114, break_on_hyphens=False), ""]
    lines.append(f"keys ({SYNTAX}):")
    for f in dataclasses.fields(schema):
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
        lines.append(f"  {f.name}: {type_name(hints[f.name])} = {_show(default)}")
        meaning = f.metadata.get("meaning", "")
        choices = f.metadata.get("choices")
        if choices is not None:
            meaning += f" (allowed: {', '.join(map(str, _choices(choices)))})"
        lines += textwrap.wrap(
            meaning, width=114, initial_indent=" " * 6, subsequent_indent=" " * 6, break_on_hyphens=False
        )
    if examples:
        lines += ["", "examples:", *(f"  python scripts/{prog} {e}" for e in examples)]
    return "\n".join(lines)


def _choices(choices: Sequence[Any] | Callable[[], Sequence[Any]]) -> list[Any]:
    return list(choices() if callable(choices) else choices)


# ------------------------------------------------------------------------------------------------- parsing
def did_you_mean(word: Any, allowed: Sequence[Any]) -> str:
    """`` (did you mean X?)`` naming the allowed values closest to ``word`` (at most three, closest first), or
    nothing where none is close: for a typo of a key, a level or a choice.  A dotted key is compared by its last
    part where every allowed key shares the rest (``algo.lrr``: ``algo.lr``, not every ``algo.*``)."""
    word, allowed = str(word), [str(a) for a in allowed]
    parent = word.rpartition(".")[0]
    cut = len(parent) + 1 if parent and all(a.startswith(parent + ".") for a in allowed) else 0
    close = difflib.get_close_matches(word[cut:], [a[cut:] for a in allowed], n=3, cutoff=0.6)
    return f" (did you mean {' or '.join(word[:cut] + c for c in close)}?)" if close else ""


def read(schema: type[T], argv: Sequence[str], checks: bool = True) -> T:
    """``argv`` (``key=value`` strings) over ``schema``'s defaults.  Raises :class:`UsageError` with one line.
    ``checks=False`` checks keys and types only, not the allowed values (a documentation test of commands whose
    files do not exist here)."""
    hints = typing.get_type_hints(schema)
    fields = {f.name: f for f in dataclasses.fields(schema)}
    keys = ", ".join(fields)
    given = OmegaConf.create()
    for arg in argv:
        key, sep, text = arg.partition("=")
        key = key.lstrip("+")  # Hydra's "+key=value" and "++key=value" (add a key) mean the same here
        if not sep or not key:
            raise UsageError(f"'{arg}' is not of the form key=value; keys: {keys} (see --help)")
        top = key.split(".")[0]
        if top not in fields:
            raise UsageError(f"unknown key '{key}'{did_you_mean(top, list(fields))}; keys: {keys} (see --help)")
        tp = hints[top]
        try:
            value = OmegaConf.to_container(OmegaConf.from_dotlist([f"v={text}"]))["v"]
        except yaml.YAMLError:
            if key == top and _is_list(tp) and _is_text(_item(tp)):
                # a list of names YAML cannot read, such as shell patterns that begin with * (a YAML alias):
                # its items are the comma-separated texts, as typed ([a,b]), or the one text given
                items = text.strip()[1:-1].split(",") if _bracketed(text) else [text]
                OmegaConf.update(given, key, [i.strip() for i in items if i.strip()], force_add=True)
                continue
            if not (key == top and _is_text(tp)):
                raise UsageError(
                    f"{key}={text}: not a valid value (lists are written [a,b]); expected {_expected(tp)}"
                ) from None
            value = text
        if key == top and _is_text(tp) and value is not None and not isinstance(value, str):
            value = text  # a name like 07, or a title with a colon, stays as typed
        if key == top and _is_list(tp) and _is_text(_item(tp)) and value is not None:
            value = _as_typed(text, value)  # levels=[3_2] names '3_2', not the number 32 YAML reads
        if key == top and _is_list(tp) and not isinstance(value, list) and value is not None:
            value = [value]
        if (
            key == top
            and _optional(tp)[0] is bool
            and isinstance(value, bool)
            and text.strip().lower() not in ("true", "false")
        ):
            # YAML 1.1 reads on/off/yes/no as true/false: a typo of another key's value would pass unnoticed
            raise UsageError(f"{key}={text}: expected true or false")
        if key == top and _optional(tp)[0] is int and isinstance(value, float) and value.is_integer():
            # YAML reads 1e3 as the float 1000.0, which an integer key refuses: say what to write
            raise UsageError(
                f"{key}={text}: expected {_expected(tp)} (YAML reads {text} as {value!r}: write {int(value)})"
            )
        OmegaConf.update(given, key, value, force_add=True)
    try:
        cfg = OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(schema), given))
    except ConfigKeyError as err:
        raise UsageError(f"unknown key '{err.full_key}'; keys: {keys} (see --help)") from None  # a nested key
    except OmegaConfBaseException as err:
        top = str(err.full_key or "").split(".")[0].split("[")[0]
        if top not in fields:
            raise UsageError(f"{str(err).splitlines()[0]} (see --help)") from None
        raise UsageError(f"{top}={_given(argv, top)}: expected {_expected(hints[top])}") from None
    typed_keys = {a.partition("=")[0].lstrip("+").split(".")[0] for a in argv}
    # what was typed is checked first: its mistake is the one to report, not a required key left out
    ordered = sorted(dataclasses.fields(schema), key=lambda f: f.name not in typed_keys)
    for f in ordered if checks else ():
        value = getattr(cfg, f.name)
        items = value if isinstance(value, list) else [value]
        choices, check = f.metadata.get("choices"), f.metadata.get("check")
        if value is None:
            continue
        if choices is not None:
            allowed = _choices(choices)
            bad = [v for v in items if v not in allowed]
            if bad:
                raise UsageError(
                    f"{f.name}={_given(argv, f.name)}: '{_show(bad[0])}' is not allowed"
                    f"{did_you_mean(_show(bad[0]), allowed)}; allowed: {', '.join(map(str, allowed))}"
                )
        bad = [v for v in items if check is not None and not check[0](v)]
        if bad:
            got = f" (got {_show(bad[0])})" if isinstance(value, list) else ""
            raise UsageError(f"{f.name}={_given(argv, f.name)}: expected {check[1]}{got}")
    return cfg


def given(argv: Sequence[str], key: str) -> str:
    """The text the user gave for ``key`` on the command line (the last one), as messages quote it."""
    return _given(argv, key)


def _given(argv: Sequence[str], key: str) -> str:
    """The text the user gave for ``key`` (the last one, as OmegaConf keeps the last)."""
    texts = [a.partition("=")[2] for a in argv if a.partition("=")[0].lstrip("+") == key]
    return texts[-1] if texts else ""


def fail(prog: str, message: str) -> typing.NoReturn:
    """Print one line ``<prog>: error: <message>`` to stderr and exit with status 2 (as argparse does)."""
    print(f"{prog}: error: {message}", file=sys.stderr)
    raise SystemExit(2)


def help_first(schema: type, prog: str, description: str, examples: Sequence[str] = ()) -> None:
    """``--help`` before a script's slow imports (torch, the env): called under ``if __name__ == "__main__"`` ahead
    of them, it prints :func:`usage` and exits with status 0 when the command line asks for help."""
    if any(a in HELP_FLAGS for a in sys.argv[1:]):
        print(usage(schema, prog, description, examples))
        raise SystemExit(0)


def parse(
    schema: type[T], argv: Sequence[str] | None, *, prog: str, description: str, examples: Sequence[str] = ()
) -> T:
    """The script's config from ``argv`` (default ``sys.argv[1:]``): ``--help`` prints :func:`usage` and exits 0;
    a malformed argument exits 2 after one line naming the key (:func:`fail`)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if any(a in HELP_FLAGS for a in argv):
        print(usage(schema, prog, description, examples))
        raise SystemExit(0)
    try:
        return read(schema, argv)
    except UsageError as err:
        fail(prog, str(err))


#: the reference agents a ``policy`` argument may name
REFERENCE_AGENTS = ("oracle", "random", "still")
#: how a policy of your own is named on a command line: ``py:<module>:<name>`` or ``py:<file.py>:<name>``
OWN_PREFIX = "py:"


def is_own(spec: Any) -> bool:
    """Whether ``spec`` (a policy argument) names a policy of your own (``py:...``)."""
    return isinstance(spec, str) and spec.startswith(OWN_PREFIX)


def own_source(spec: str) -> tuple[str, str, bool]:
    """``(source, attribute, is_file)`` of ``py:<source>:<attribute>``."""
    source, _, attr = spec[len(OWN_PREFIX) :].rpartition(":")
    return source, attr, source.endswith(".py") or os.sep in source or "/" in source


def own_spec_problem(spec: str) -> str | None:
    """Why ``spec`` is not a well-formed ``py:`` policy (nothing is imported), or None."""
    source, attr, is_file = own_source(spec)
    form = "py:MODULE:NAME or py:FILE.py:NAME (e.g. py:my_agent.py:policy)"
    if not source or not attr or not all(part.isidentifier() for part in attr.split(".")):
        return f"policy={spec}: expected {form}"
    if is_file:
        if not Path(source).is_file():
            return f"policy={spec}: {source}: no such file"
    elif not all(part.isidentifier() for part in source.split(".")):
        return f"policy={spec}: '{source}' is neither a module name nor a .py file; expected {form}"
    return None


def policy_ok(spec: str, own: bool = False) -> bool:
    """``check=`` of a script's ``policy`` option: a reference agent, ``zoo:NAME`` (a wrong name is refused in one
    line with the zoo's names and the closest one) or an existing checkpoint file; with ``own``, also a policy of your
    own, ``py:MODULE:NAME`` or ``py:FILE.py:NAME``, whose form and file are checked here (nothing is imported: that
    happens once every argument has passed)."""
    from evaaa_baselines import zoo

    if zoo.is_zoo(spec):
        try:
            zoo.entry(spec)
        except zoo.ZooError as err:
            raise UsageError(f"policy={spec}: {err}") from None
        return True
    if own and is_own(spec):
        problem = own_spec_problem(spec)
        if problem is not None:
            raise UsageError(problem)
        return True
    return spec in REFERENCE_AGENTS or Path(spec).is_file()
