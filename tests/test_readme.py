"""The README's Python runs as written: every ```python block is executed as it stands, and an expression line
whose comment starts with a shape, ``data["next", "interoception"].shape  # (8, 1000, 4): ...``, must have that
shape; the one-line calls in its prose (``make_env("1-1", reward={"name": "drive_reduction"})``,
``gymnasium.make("evaaa/1-1-v0")``) are made too.  Commands of the scripts are checked in tests/test_cli.py."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
SHAPE_COMMENT = re.compile(r"^(?P<expr>[^#]+?)\s+#\s*\((?P<shape>\d+(?:,\s*\d+)*)\)")


def python_blocks() -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", README.read_text(), re.M | re.S)


def inline_calls() -> list[str]:
    """Inline code spans that are a single call of make_env or gymnasium.make (a signature is not a call)."""
    calls = []
    for span in re.findall(r"`([^`\n]+)`", README.read_text()):
        if not re.match(r"(evaaa\.)?make_env\(|gymnasium\.make\(", span):
            continue
        try:
            ast.parse(span, mode="eval")
        except SyntaxError:
            continue
        calls.append(span)
    return calls


def test_the_readme_has_examples():
    assert python_blocks() and len(inline_calls()) >= 3


@pytest.mark.parametrize("block", python_blocks(), ids=lambda b: b.splitlines()[0][:40])
def test_readme_python_block_runs_as_written_and_has_the_shapes_it_claims(block):
    namespace: dict = {}
    exec(compile(block, str(README), "exec"), namespace)
    claims = 0
    for line in block.splitlines():
        match = SHAPE_COMMENT.match(line)
        if match is None or "=" in match["expr"].replace("==", ""):
            continue
        value = eval(match["expr"], namespace)
        value = getattr(value, "shape", value)  # a tensor stands for its shape
        shape = tuple(int(n) for n in match["shape"].split(","))
        assert tuple(value) == shape, f"{match['expr']} is {tuple(value)}, the README says {shape}"
        claims += 1
    assert claims or "shape" not in block


@pytest.mark.parametrize("call", inline_calls())
def test_readme_inline_call_runs_as_written(call):
    import gymnasium

    import evaaa
    from evaaa import make_env

    env = eval(call, {"evaaa": evaaa, "make_env": make_env, "gymnasium": gymnasium})
    try:
        assert env.reset() is not None
    finally:
        env.close()
