"""The package's structure, checked on the source: no import cycle between its modules, no layer
importing a later one, no module past the size limit; and no module below training/ that needs
torch to import (checked in fresh interpreters)."""

import ast
from pathlib import Path

import tendon2r_gym

PACKAGE = Path(tendon2r_gym.__file__).resolve().parent


def _module(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(type_checking: bool = False) -> dict[str, set[str]]:
    """Module -> the package modules it imports at any level (lazy imports included; with
    ``type_checking``, also those for annotations only)."""
    modules = {_module(p): p for p in PACKAGE.rglob("*.py")}
    graph = {}
    for name, path in modules.items():
        found = set()
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree) if type_checking else _runtime_nodes(tree):
            if isinstance(node, ast.ImportFrom) and node.module:
                targets = [node.module, *(f"{node.module}.{a.name}" for a in node.names)]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                continue
            found |= {t for t in targets if t in modules and t != name}
        graph[name] = found - {"tendon2r_gym"}  # the package's __init__ re-exports only
    return graph


def _runtime_nodes(tree: ast.AST):
    """Every node except those under ``if TYPE_CHECKING:`` (imports for annotations only)."""
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            yield from (n for child in node.orelse for n in ast.walk(child))
            continue
        yield node
        yield from _runtime_nodes(node)


def test_the_import_graph_has_no_cycle():
    graph = _imports()
    assert "tendon2r_gym.envs.formulas" in graph["tendon2r_gym.envs.env"], "the graph is read"
    state: dict[str, int] = {}

    def visit(node, path):
        state[node] = 1
        for nxt in graph[node]:
            if state.get(nxt) == 1:
                raise AssertionError(" -> ".join([*path, node, nxt]))
            if nxt not in state:
                visit(nxt, [*path, node])
        state[node] = 2

    for node in graph:
        if node not in state:
            visit(node, [])


def test_no_two_modules_import_each_other_type_checking_included():
    graph = _imports(type_checking=True)
    pairs = sorted({tuple(sorted((a, b))) for a, deps in graph.items() for b in deps
                    if a in graph.get(b, ())})  # fmt: skip
    assert not pairs, pairs


#: The package's layers, in the order data flows (arm parameters -> model -> env -> policy ->
#: rollout -> metrics -> report); the top-level modules are shared helpers below them all.
LAYERS = (
    "", "simulation", "task", "envs", "identification", "artifacts", "policies", "evaluation",
    "training", "app",
)  # fmt: skip


def _layer(module: str) -> int:
    parts = module.split(".")
    return LAYERS.index(parts[1]) if len(parts) > 1 and parts[1] in LAYERS else 0


def test_every_module_lives_in_a_layer():
    assert {p.name for p in PACKAGE.iterdir() if p.is_dir() and (p / "__init__.py").exists()} == {
        *LAYERS[1:]
    }


def test_no_layer_imports_a_later_one_type_checking_included():
    upward = sorted(
        f"{a} -> {b}"
        for a, deps in _imports(type_checking=True).items()
        for b in deps
        # the package's __init__ re-exports; the shim keeps a path that a model file pickled
        if _layer(b) > _layer(a) and a not in ("tendon2r_gym", "tendon2r_gym.policies.split_view")
    )
    assert not upward, upward


#: The most code lines a library module may hold: past it, a module holds more than one job.
#: Code lines only: docstrings, comments and blank lines do not count, so that prose is never
#: cut to fit.
MAX_MODULE_LINES = 450


def code_lines(source: str) -> int:
    """Returns how many lines of ``source`` hold code: not blank, not only a comment, not
    part of a docstring (a string statement first in a module, class or function)."""
    import io
    import tokenize

    prose: set[int] = set()
    for node in ast.walk(ast.parse(source)):
        body = getattr(node, "body", None)
        if isinstance(body, list) and body and isinstance(body[0], ast.Expr):
            value = body[0].value
            if isinstance(value, ast.Constant) and isinstance(value.value, str):
                prose.update(range(body[0].lineno, body[0].end_lineno + 1))
    code: set[int] = set()
    skip = (tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT,
            tokenize.ENDMARKER)  # fmt: skip
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type not in skip:
            code.update(range(tok.start[0], tok.end[0] + 1))
    return len(code - prose)


def test_code_lines_count_neither_docstrings_nor_comments():
    source = 'def f():\n    """Doc.\n\n    More."""\n    # a comment\n    return 1  # two\n'
    assert code_lines(source) == 2


def test_no_library_module_is_longer_than_the_limit():
    long = {
        str(p.relative_to(PACKAGE)): n
        for p in PACKAGE.rglob("*.py")
        if (n := code_lines(p.read_text())) > MAX_MODULE_LINES
    }
    assert not long, long


#: Modules that import torch by design below training/: the shim at a path a shipped model file
#: pickled for its policy class (loading that class is loading torch).
TORCH_BY_DESIGN = ("tendon2r_gym.policies.split_view",)
#: What a fresh interpreter runs: torch and Stable-Baselines3 made unimportable, then each
#: module named on its command line; it prints each one that fails, and exits 1 if any does.
_WITHOUT_TORCH = """
import importlib, sys
sys.modules["torch"] = None
sys.modules["stable_baselines3"] = None
failed = []
for name in sys.argv[1:]:
    try:
        importlib.import_module(name)
    except ImportError as e:
        failed.append(f"{name}: {e}")
print("\\n".join(failed))
sys.exit(1 if failed else 0)
"""


def _below_training() -> list[str]:
    """Returns the library modules of the layers below training/ (the top-level helpers
    included), but `TORCH_BY_DESIGN`."""
    modules = (_module(p) for p in sorted(PACKAGE.rglob("*.py")))
    return [m for m in modules if _layer(m) < LAYERS.index("training") and m != "tendon2r_gym"
            and m not in TORCH_BY_DESIGN]  # fmt: skip


def test_no_module_below_training_needs_torch_to_import():
    """Torch and Stable-Baselines3 are imported only where a model is loaded or trained (inside
    the functions that do it): every module below training/ imports in a fresh interpreter in
    which neither can be imported (one interpreter: a module that needs either fails there,
    whichever came before it)."""
    import subprocess
    import sys

    modules = _below_training()
    done = subprocess.run(
        [sys.executable, "-c", _WITHOUT_TORCH, *modules], capture_output=True, text=True
    )
    assert len(modules) > 40 and done.returncode == 0, (done.stdout + done.stderr)[-2000:]


#: The test folders: tests/ checks the library, research/tests/ the studies.
TEST_DIRS = (PACKAGE.parent / "tests", PACKAGE.parent / "research" / "tests")
#: The top-level packages of code that is not the library: the tests' and the studies'.
TEST_ROOTS = ("tests", "research")


def private_reads(source: str) -> set[str]:
    """Returns each ``obj._name`` that ``source`` (a test file) reads from code other than its
    own: ``_name`` one underscore then a letter (no dunder), not a name the file defines
    (function, class, method, variable or attribute it sets), and ``obj`` not a module of the
    tests or the studies (``from research.studies import x``: x's helpers are its tests'
    subject)."""
    tree = ast.parse(source)
    own: set[str] = set()
    ours: set[str] = set()  # the modules of the tests and the studies it imports
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            own.add(node.name)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            own.add(node.id)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
            own.add(node.attr)
        elif isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] in TEST_ROOTS:
            ours.update(a.asname or a.name for a in node.names)
    return {
        ast.unparse(node)
        for node in ast.walk(tree)
        if isinstance(node, ast.Attribute)
        and node.attr[:1] == "_" and node.attr[1:2].isalpha()
        and node.attr not in own
        and not (isinstance(node.value, ast.Name) and node.value.id in ours)
    }  # fmt: skip


def test_private_reads_sees_a_library_attribute_only():
    source = (
        "from research.studies import study\nclass P(Base):\n    def _torque(self):\n"
        "        return super()._torque() + study._helper()\n"
        "def _mine():\n    env = make()\n    return env._state(), env.__class__, _mine()\n"
    )
    assert private_reads(source) == {"env._state"}


def test_no_test_reads_a_private_attribute_of_the_library():
    """A test checks what a user can reach: public names, or a public attribute documented as
    a test hook; never ``obj._name`` of the library."""
    found = {
        f"{path.relative_to(PACKAGE.parent)}: {read}"
        for folder in TEST_DIRS
        for path in sorted(folder.rglob("test_*.py"))
        for read in private_reads(path.read_text())
    }
    assert not found, sorted(found)
