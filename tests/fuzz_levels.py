"""Level-override fuzzing shared by tests/test_fuzz_levels.py: random override sets drawn from the level schema.

Each case starts from a level or testbed, picks one to three of its fields (walking the validated level, so every
field of the schema that the level has can be hit) and gives each a value that is likely to break something:
NaN and infinities, zero, negative and huge numbers, wrong types, swapped intervals, the other choices of a
``Literal``, removed groups, a fixed start anywhere.
"""

from __future__ import annotations

import functools
import math
import random
import typing
from typing import Any

from pydantic import BaseModel

import evaaa
from evaaa.spec import MAX_INTEGER, MAX_MAGNITUDE, Level, load_level

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
    return rng.choice([math.nan, math.inf, -math.inf, 1e308, -1e308, value * 10.0 ** rng.randint(-6, 12),
                       "abc", None])


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
        return {"agent.collision_damage.rate": rng.choice([1.0, 5.0, 50.0]),
                "agent.collision_damage.offset": rng.choice([-1e3, 0.0, 60.0])}
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
