"""Each env argument's description, read from the one place it is written: the ``#:`` comment
above its EnvConfig field (tendon2r_gym/envs/env_config.py), and the Tendon2REnv docstring's
``Args:`` block for the env's own arguments (the preset and rendering).

The env card (scripts/docs_env.py) and the console commands' --help (tendon2r_gym.app.cli)
read them here.  The modules' sources are parsed, not imported.
"""

from __future__ import annotations

import ast
import functools
import re
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent
#: Where EnvConfig and Tendon2REnv are written.
ENV_CONFIG_SOURCE = PACKAGE / "envs" / "env_config.py"
ENV_SOURCE = PACKAGE / "envs" / "env.py"
#: A Google-style ``Args:`` block: the line ``Args:``, then its lines indented by 4 (or empty).
ARGS_BLOCK = re.compile(r"^Args:\n((?:(?: {4}.*)?\n)+?)(?=\S|\Z)", re.M)


def class_node(source: str, name: str) -> ast.ClassDef:
    """Returns the definition of the class ``name`` in a module's source."""
    tree = ast.parse(source)
    return next(n for n in ast.walk(tree) if isinstance(n, ast.ClassDef) and n.name == name)


def field_comments(path: Path = ENV_CONFIG_SOURCE, cls: str = "EnvConfig") -> dict[str, str]:
    """Returns each field's description: the ``#:`` comment lines right above it in the
    class's source, joined (Sphinx's convention)."""
    lines = path.read_text().splitlines()
    out = {}
    for item in class_node("\n".join(lines), cls).body:
        if isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name):
            above, k = [], item.lineno - 2
            while k >= 0 and lines[k].strip().startswith("#:"):
                above.insert(0, lines[k].strip()[2:].strip())
                k -= 1
            if above:
                out[item.target.id] = " ".join(above)
    return out


def docstring_args(doc: str) -> tuple[re.Match[str] | None, dict[str, str]]:
    """Returns a dedented docstring's ``Args:`` block (None if it has none) and each
    argument's description in it, continuation lines joined."""
    found = ARGS_BLOCK.search(doc)
    described: dict[str, str] = {}
    for line in found.group(1).splitlines() if found else ():
        if m := re.match(r" {4}(\w+): (.*)", line):
            described[m.group(1)] = m.group(2).strip()
        elif line.strip() and described:
            last = next(reversed(described))
            described[last] += " " + line.strip()
    return found, described


def env_docstring(path: Path = ENV_SOURCE, cls: str = "Tendon2REnv") -> str:
    """Returns the env class's docstring as its source writes it (before the tables are
    filled into it), dedented."""
    return ast.get_docstring(class_node(path.read_text(), cls), clean=True) or ""


@functools.cache
def argument_docs() -> dict[str, str]:
    """Returns every env argument's description: the env's own (its docstring's ``Args:``),
    then EnvConfig's fields' ``#:`` comments."""
    return {**docstring_args(env_docstring())[1], **field_comments()}


def plain(text: str) -> str:
    """Returns a description without its Markdown code marks, as a terminal shows it."""
    return re.sub(r"``?([^`]+?)``?", r"\1", text)


def env_help(name: str, note: str = "") -> str:
    """Returns a command flag's --help text for the env argument ``name`` (its one
    description), followed by what the command adds (``note``)."""
    text = plain(argument_docs()[name]).rstrip(".")
    return f"{text}; {note}" if note else text
