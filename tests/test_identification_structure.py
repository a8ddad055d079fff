"""tendon2r_gym.identification reads like the rest of the package: short functions, ruff's
layout throughout, no chains of conditional expressions."""

from __future__ import annotations

import ast
from pathlib import Path

import tendon2r_gym

IDENTIFICATION = Path(tendon2r_gym.__file__).resolve().parent / "identification"
#: The most lines a function may span, from ``def`` to its last line (docstring included).
MAX_FUNCTION_LINES = 60


def _sources() -> dict[str, str]:
    sources = {p.name: p.read_text() for p in sorted(IDENTIFICATION.glob("*.py"))}
    assert "identify.py" in sources and "recording.py" in sources, "the package is read"
    return sources


def _functions(source: str) -> list[ast.FunctionDef | ast.AsyncFunctionDef]:
    nodes = ast.walk(ast.parse(source))
    return [n for n in nodes if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))]


def test_no_function_is_longer_than_the_limit():
    long = {
        f"{name}:{f.lineno} {f.name}": f.end_lineno - f.lineno + 1
        for name, source in _sources().items()
        for f in _functions(source)
        if f.end_lineno - f.lineno + 1 > MAX_FUNCTION_LINES
    }
    assert not long, long


def test_the_formatter_lays_out_every_line():
    skipped = [
        f"{name}:{i}"
        for name, source in _sources().items()
        for i, line in enumerate(source.splitlines(), start=1)
        if "fmt: skip" in line or "fmt: off" in line
    ]
    assert not skipped, skipped


def test_no_conditional_expression_holds_another():
    nested = [
        f"{name}:{node.lineno}"
        for name, source in _sources().items()
        for node in ast.walk(ast.parse(source))
        if isinstance(node, ast.IfExp)
        and any(isinstance(inner, ast.IfExp) for inner in ast.walk(node) if inner is not node)
    ]
    assert not nested, nested


def test_the_length_is_counted_from_def_to_the_last_line():
    source = 'def f():\n    """Doc."""\n\n    return 1\n'
    (f,) = _functions(source)
    assert f.end_lineno - f.lineno + 1 == 4
