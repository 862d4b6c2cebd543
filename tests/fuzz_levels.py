"""Level-override fuzzing shared by tests/test_fuzz_levels.py: random override sets drawn from the level schema.

Each case starts from a level or testbed, picks one to three of its fields (walking the validated level, so every
field of the schema that the level has can be hit) and gives each a value that is likely to break something:
NaN and infinities, zero, negative and huge numbers, wrong types, swapped intervals, the other choices of a
``Literal``, removed groups, a fixed start anywhere.

:func:`hostile_file` attacks the file itself rather than its values: nesting, alias chains, YAML tags, encodings
and sizes; :func:`audit_case` the families of issue 65's audit, some of them several files (links, FIFOs, chains).
"""

from __future__ import annotations

import functools
import math
import os
import random
import typing
from pathlib import Path
from typing import Any

from pydantic import BaseModel

import evaaa
from evaaa.level import Level
from evaaa.level_files import load_level
from evaaa.level_limits import MAX_INTEGER, MAX_MAGNITUDE
from evaaa.physiology import REWARDS

BASES = evaaa.LEVELS + evaaa.TESTBEDS


def _leaves(tree: Any, prefix: str = "") -> list[tuple[str, Any]]:
    """(dotted path, value) of every leaf field of a dumped level; tuples and lists are leaves."""
    out = []
    for key, value in tree.items():
        path = f"{prefix}{key}"
        if isinstance(value, dict) and value:
            out += _leaves(value, path + ".")
        else:
            out.append((path, value))
    return out


def _field(path: str) -> Any:
    """The schema's FieldInfo of the field at ``path`` (a part may name a dict entry), or None."""
    model: Any = Level
    field = None
    for part in path.split("."):
        if typing.get_origin(model) is dict:
            model = typing.get_args(model)[1]
            continue
        models = [m for m in (typing.get_args(model) or (model,)) if isinstance(m, type) and issubclass(m, BaseModel)]
        field = models[0].model_fields.get(part) if models else None
        if field is None:
            return None
        model = field.annotation
    return field


def _limits(path: str, integer: bool) -> tuple[float, float]:
    """The bounds the schema states for a number field (the general magnitude bound where it states none)."""
    lo, hi = (-MAX_INTEGER, MAX_INTEGER) if integer else (-MAX_MAGNITUDE, MAX_MAGNITUDE)
    field = _field(path)
    for item in getattr(field, "metadata", ()):
        lo = getattr(item, "ge", None) if getattr(item, "ge", None) is not None else lo
        lo = getattr(item, "gt", None) if getattr(item, "gt", None) is not None else lo
        hi = getattr(item, "le", None) if getattr(item, "le", None) is not None else hi
        hi = getattr(item, "lt", None) if getattr(item, "lt", None) is not None else hi
    return lo, hi


def _number(rng: random.Random, path: str, value: float) -> Any:
    lo, hi = _limits(path, integer=False)
    kind = rng.random()
    if kind < 0.35:  # plausible: near the current value
        return value * rng.uniform(0.0, 3.0) + rng.gauss(0.0, 1.0)
    if kind < 0.65:  # the edges of what the schema allows, and just past them
        return rng.choice([lo, hi, lo - abs(lo) * 0.5 - 1.0, hi + abs(hi) * 0.5 + 1.0, 0.0, -value])
    return rng.choice([math.nan, math.inf, -math.inf, 1e308, -1e308, value * 10.0 ** rng.randint(-6, 12), "abc", None])


def _integer(rng: random.Random, path: str, value: int) -> Any:
    lo, hi = _limits(path, integer=True)
    lo, hi = int(lo), int(hi)
    kind = rng.random()
    if kind < 0.35:
        return max(0, value + rng.randint(-3, 3)) if rng.random() < 0.5 else value * rng.randint(0, 4)
    if kind < 0.65:
        return rng.choice([lo, hi, lo - 1, hi + 1, 0, 1, -1])
    return rng.choice([10**18, 1e9, 0.5, math.nan, "many", None])


def mutate(rng: random.Random, path: str, value: Any) -> Any:
    """A value for the field at ``path`` (now ``value``) likely to break something."""
    field = _field(path)
    annotation = field.annotation if field is not None else None
    if typing.get_origin(annotation) is typing.Literal and rng.random() < 0.7:
        return rng.choice(typing.get_args(annotation))
    if path == "reward.name" and rng.random() < 0.7:  # a name of the reward registry, as its Literal was
        return rng.choice(REWARDS)
    if isinstance(value, bool):
        return rng.choice([not value, "maybe", 2])
    if isinstance(value, int):
        return _integer(rng, path, value)
    if isinstance(value, float):
        return _number(rng, path, value)
    if isinstance(value, str):
        return rng.choice(["", "bogus", 3])
    if isinstance(value, (tuple, list)) and value and all(isinstance(v, (tuple, list)) for v in value):
        if path.endswith("pattern"):  # landmark grid
            rows, cols = rng.randint(0, 4), rng.randint(1, 4)
            return [[rng.choice([0, 0, 1, 2, 11]) for _ in range(cols)] for _ in range(rows)]
        i = rng.randrange(len(value))
        out = [list(v) for v in value]
        out[i] = mutate(rng, path, tuple(value[i]))
        return out
    if isinstance(value, (tuple, list)) and value:
        kind = rng.random()
        if kind < 0.15:
            return list(reversed(value))
        if kind < 0.2:
            return list(value) + [1.0]
        out = list(value)
        i = rng.randrange(len(out))
        out[i] = _integer(rng, "", out[i]) if isinstance(out[i], int) else _number(rng, "", float(out[i]))
        return out
    if value is None and path == "landmarks":
        return {"pattern": [[rng.randint(0, 2) for _ in range(3)] for _ in range(3)]}
    return rng.choice([None, 0, "x", math.nan])


def _special(rng: random.Random, base: str, tree: dict[str, Any]) -> dict[str, Any]:
    """Cross-field combinations that single-field mutations rarely hit."""
    kind = rng.randrange(6)
    groups = [f"{section}.{name}" for section in ("resources", "obstacles", "predators") for name in tree[section]]
    if kind == 0:
        return {"agent.start": "fixed", "agent.start_position": [rng.uniform(-200, 200), rng.uniform(-200, 200)]}
    if kind == 1 and tree["resources"]:
        return {f"resources.{name}.count": 0 for name in tree["resources"]} | {"agent.start": "random"}
    if kind == 2 and groups:
        return {rng.choice(groups): None}
    if kind == 3:
        near = rng.choice([0.3, 5.0, 100.0, 1e6])
        return {"sensors.vision.near": near, "sensors.vision.far": near * rng.choice([0.1, 1.0, 2.0])}
    if kind == 4:
        return {
            "agent.collision_damage.rate": rng.choice([1.0, 5.0, 50.0]),
            "agent.collision_damage.offset": rng.choice([-1e3, 0.0, 60.0]),
        }
    return {"arena.size": [rng.choice([1.0, 2.0, 5.0, 1e4]), rng.choice([1.0, 3.0, 100.0])]}


@functools.cache
def _dumped(base: str) -> dict[str, Any]:
    return load_level(base).model_dump()


def draw_case(seed: int) -> tuple[str, dict[str, Any]]:
    """A base level and an override set, a pure function of ``seed``."""
    rng = random.Random(seed)
    base = rng.choice(BASES)
    tree = _dumped(base)
    leaves = [(p, v) for p, v in _leaves(tree) if p not in ("name", "kind")]
    overrides: dict[str, Any] = {}
    if rng.random() < 0.15:
        overrides.update(_special(rng, base, tree))
    for path, value in rng.sample(leaves, rng.randint(1, 3)):
        if any(path.startswith(p + ".") for p in overrides):
            continue
        overrides[path] = mutate(rng, path, value)
    return base, overrides


# ------------------------------------------------------------------------------------------------ hostile files
#: fields a hostile value is put in: text, a number, a flag, an interval, a section, a named group
_TARGETS = ("description", "agent.mass", "agent.auto_eat", "agent.spawn_x", "arena", "resources.food")
_TAGS = (
    "!!python/object/apply:os.system ['touch /tmp/evaaa-pwned']",
    "!!python/name:os.system",
    "!!binary Mw==",
    "!!set {1, 2}",
    "!!timestamp 2001-12-14",
    "!!omap [a: 1]",
    "!!pairs [a: 1]",
    "!custom 3",
    "!!str 3",
    "!!int '3'",
    "!!float 3",
    "!!bool yes",
    "!!null ''",
    "!<tag:example.com,2000:x> 1",
    "!!merge 3",
)


def _nest(field: str, value: str) -> str:
    """``value`` at a dotted ``field`` as block YAML."""
    parts = field.split(".")
    lines = [f"{'  ' * i}{key}:" for i, key in enumerate(parts[:-1])]
    return "\n".join([*lines, f"{'  ' * (len(parts) - 1)}{parts[-1]}: {value}"]) + "\n"


def _deep(rng: random.Random) -> str:
    depth = rng.choice([rng.randint(1, 40), rng.randint(30, 3000), rng.randint(3000, 120_000)])
    style = rng.randrange(4)
    if style == 0:
        return "description: " + "[" * depth + "1" + "]" * depth + "\n"
    if style == 1:
        return "description: " + "{a: " * depth + "1" + "}" * depth + "\n"
    if style == 2:  # block mappings, one level per line
        depth = min(depth, 3000)
        return (
            "description:\n"
            + "".join(f"{' ' * (2 * i + 2)}k{i}:\n" for i in range(depth))
            + " " * (2 * depth + 2)
            + "x\n"
        )
    return "description: " + "- " * min(depth, 5000) + "1\n"  # block sequences on one line


def _aliases(rng: random.Random) -> str:
    width, chain = rng.randint(1, 12), rng.randint(1, 12)
    lines = [f"a0: &a0 [{', '.join(['lol'] * width)}]"]
    lines += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * width)}]" for i in range(1, chain)]
    kind = rng.randrange(5)
    if kind == 0:
        lines.append("b: &b [1, *b]")  # an alias inside what it names
    elif kind == 1:
        lines.append("c: *nowhere")
    elif kind == 2:
        lines.append("d: &a0 1")  # an anchor defined twice
    elif kind == 3:  # merge keys through a chain of mappings
        lines += ["m0: &m0 {mass: 3}"] + [f"m{i}: &m{i} {{<<: *m{i - 1}, k{i}: {i}}}" for i in range(1, chain)]
        return "\n".join(lines) + "\n" + _nest("agent", f"{{<<: *m{chain - 1}}}")
    return "\n".join(lines) + "\n" + _nest(rng.choice(_TARGETS), f"*a{chain - 1}")


def _tags(rng: random.Random) -> str:
    return _nest(rng.choice(_TARGETS), rng.choice(_TAGS))


def _encoding(rng: random.Random) -> bytes:
    text = 'extends: "1-2"\ndescription: "caf\u00e9 \u2603 \U0001f600"\nagent: {mass: 12.5}\n'
    kind = rng.randrange(8)
    if kind == 0:
        return text.encode(rng.choice(["utf-16", "utf-16-le", "utf-32", "utf-32-be"]))
    if kind == 1:
        return text.encode("latin-1", errors="replace")
    if kind == 2:
        return b"\xef\xbb\xbf" + text.encode()  # UTF-8 with a byte-order mark: fine
    if kind == 3:
        data = bytearray(text.encode())
        data.insert(rng.randrange(len(data)), rng.choice([0, 1, 7, 27, 0x7F]))
        return bytes(data)
    if kind == 4:
        return text.encode()[: rng.randint(1, len(text.encode()))]  # cut anywhere, even inside a character
    if kind == 5:
        return bytes(rng.randrange(256) for _ in range(rng.randint(1, 400)))
    if kind == 6:
        return text.replace("\n", rng.choice(["\r\n", "\r", "\u2028", "\x85"])).encode()
    return text.encode()


def _sizes(rng: random.Random) -> str:
    # a count that is small, near the file size limit (64 KiB: parsing it takes about a second) or far over it
    def many(small: int, near: int, over: int) -> int:
        return rng.choices([rng.randint(1, small), near, over], weights=[0.5, 0.05, 0.45])[0]

    kind = rng.randrange(9)
    if kind == 0:
        return "description: '" + "x" * many(1000, 60_000, 300_000) + "'\n"
    if kind == 1:
        return "description: " + "x" * many(1000, 60_000, 200_000) + "\n"  # one long plain line
    if kind == 2:
        return "".join(f"k{i}: {i}\n" for i in range(many(300, 7_000, 20_000)))
    if kind == 3:
        return rng.choice(["", "# only a comment\n", "---\n", "...\n", "null\n", "~\n"])
    if kind == 4:
        return "description: a\n---\ndescription: b\n"  # two documents
    if kind == 5:
        return _nest(
            rng.choice(["agent.mass", "episode.max_steps", "resources.food.count"]),
            rng.choice(
                [
                    "1" + "0" * 400,
                    "-1" + "0" * 400,
                    ".inf",
                    "-.inf",
                    ".nan",
                    "0x7fffffffffffffff",
                    "1e400",
                    "0b101",
                    "0o17",
                    "1_000",
                    "12:30:00",
                    "+.5",
                    "1e-400",
                ]
            ),
        )
    if kind == 6:
        return _nest("agent.spawn_x", "[" + ", ".join(["1"] * many(300, 20_000, 90_000)) + "]")
    if kind == 7:
        return rng.choice(
            ["[1, 2]\n", "3\n", "'text'\n", "- a\n- b\n", "? [a, b]\n: 1\n", "{[1]: 2}\n", "a: {[1]: 2}\n"]
        )
    return "agent: {mass: 5, mass: 6}\n" if rng.random() < 0.5 else "agent: {mass: 5}\nagent: {mass: 6}\n"


def hostile_file(seed: int) -> tuple[str, bytes]:
    """What a hostile level file tries (depth, aliases, tags, encodings, sizes) and its bytes; a pure function of
    ``seed``.  Most start from a packaged level, so that what is not refused is a level."""
    rng = random.Random(seed)
    kind = rng.choice(["depth", "aliases", "tags", "encoding", "sizes"])
    if kind == "encoding":
        return kind, _encoding(rng)
    body = {"depth": _deep, "aliases": _aliases, "tags": _tags, "sizes": _sizes}[kind](rng)
    base = rng.choice(['extends: "1-1"\n', 'extends: "two-resource-food"\n', ""])
    return kind, (base + body).encode()


# ------------------------------------------------------------------------------------------------ round three
#: pieces of names that would end an XML attribute or element, or lead out of a folder (issue 65, item 1)
_NAME_PIECES = ('"', "'", "<", ">", "&", "/", "..", " ", "\\n", "\\t", "\\u0000", "é", "</mujoco>", "-", "_", ".")
_INCLUDE = '"><include file="{fifo}"/></mujoco><mujoco model="'
#: fields and values that YAML 1.1 reads otherwise than YAML 1.2, and some that read alike (issue 65, item 8)
_YAML11_FIELDS = ("resources.food.count", "agent.mass", "episode.max_steps", "arena.walls", "episode.single_trial")
_YAML11_VALUES = (
    *("010", "-010", "00", "0_10", "1:30", "1:00:00", "-1:30", "1:30.5", "0b101", "0o17", "1_000"),
    *("yes", "No", "ON", "off", "y", "0x1F", "'010'", "'1:30'", "10", "true", "2.5"),
)
#: of those, the forms the two versions read differently: a level file holding one must be refused
YAML11_ONLY = ("010", "-010", "00", "0_10", "1:30", "1:00:00", "-1:30", "1:30.5", "0b101", "yes", "No", "ON", "off")
AUDIT_FAMILIES = ("xml name", "yaml 1.1", "merge keys", "symlink loop", "fifo", "extends chain", "huge integer")


def _xml_name(rng: random.Random, folder: Path) -> str:
    fifo = folder / "pipe"
    os.mkfifo(fifo)  # what an <include> of the old MJCF would have hung on
    kind = rng.randrange(4)
    if kind == 0:
        name = "a" + _INCLUDE.format(fifo=fifo) + "b"
    elif kind == 1:
        name = "".join(rng.choice(_NAME_PIECES) for _ in range(rng.randint(1, 8)))
    elif kind == 2:  # a name that is fine, or one character too long
        name = "lvl-" + "x" * rng.choice([1, 59, 60, 61]) + rng.choice(["", ".1", "_a"])
    else:
        name = rng.choice(["../../x", "/etc/x", ".hidden", "-dash", "a" * 65, "", "a b", "x\\ny"])
    return f'extends: "1-1"\nname: "{name.replace(chr(34), chr(92) + chr(34))}"\n'


def _yaml11(rng: random.Random) -> str:
    field, value = rng.choice(_YAML11_FIELDS), rng.choice(_YAML11_VALUES)
    if rng.random() < 0.2:
        return f'extends: "1-1"\narena: {{size: [{value}, 20]}}\n'  # inside a list
    return 'extends: "1-1"\n' + _nest(field, value)


def _merge_keys(rng: random.Random) -> str:
    return rng.choice(
        [
            "<<: {description: a}\n<<: {description: b}\n",  # two at the top: the last would win
            'extends: "1-1"\nx: &x {mass: 3}\ny: &y {mass: 4}\nagent: {<<: *x, <<: *y}\n',
            'extends: "1-1"\nx: &x {mass: 3}\ny: &y {mass: 4}\nagent: {<<: [*x, *y]}\n',  # the way to merge several
            'extends: "1-1"\nagent: {<<: 3}\n',
            'extends: "1-1"\nagent: {<<: [1, 2]}\n',
            'extends: "1-1"\nagent: {<<: *nowhere}\n',
            'extends: "1-1"\n<<: {extends: "1-2"}\n',
        ]
    )


def audit_case(seed: int, folder: Path) -> tuple[str, Path]:
    """A level file of the audit's families (issue 65: XML-breaking names, YAML 1.1 forms, merge keys, symlink loops,
    FIFOs, long extends chains, huge integers) made in ``folder`` with what it needs beside it, and the family; a
    pure function of ``seed``.  The file may be a link, a FIFO or the head of a chain of files."""
    rng = random.Random(seed)
    family = AUDIT_FAMILIES[seed % len(AUDIT_FAMILIES)]  # every family as often as the others
    path = folder / "level.yaml"
    if family == "xml name":
        path.write_text(_xml_name(rng, folder))
    elif family == "yaml 1.1":
        path.write_text(_yaml11(rng))
    elif family == "merge keys":
        path.write_text(_merge_keys(rng))
    elif family == "symlink loop":
        kind = rng.randrange(4)
        if kind == 0:
            path.symlink_to(path)
        elif kind == 1:
            (folder / "b.yaml").symlink_to(path)
            path.symlink_to(folder / "b.yaml")
        elif kind == 2:  # a fine file that extends a loop
            (folder / "loop.yaml").symlink_to(folder / "loop.yaml")
            path.write_text("extends: loop.yaml\n")
        else:
            path.symlink_to(folder / "nowhere.yaml")
    elif family == "fifo":
        if rng.random() < 0.5:
            os.mkfifo(path)
        else:  # a file whose parent is a FIFO
            os.mkfifo(folder / "parent.yaml")
            path.write_text("extends: parent.yaml\n")
    elif family == "extends chain":
        length = rng.choice([rng.randint(1, 40), 1000])
        cycle = rng.random() < 0.2
        for i in range(length):
            (folder / f"c{i}.yaml").write_text(f"extends: c{i + 1}.yaml\n")
        (folder / f"c{length}.yaml").write_text("extends: c0.yaml\n" if cycle else 'extends: "1-1"\n')
        path = folder / "c0.yaml"
    else:
        digits = rng.choice([11, 100, 101, 4300, 4301, 20_000, 100_000])
        number = rng.choice(["", "-", "+"]) + "9" * digits
        where = rng.choice(["episode.max_steps", "agent.mass", "resources.food.count"])
        body = _nest(where, number) if rng.random() < 0.7 else f"arena: {{size: [{number}, 20]}}\n"
        path.write_text('extends: "1-1"\n' + body)
    return family, path
