"""The repository speaks of itself only: no tracked file names a path outside it, or narrates
the history of its own making (working sessions, closing notes, trial entries left
uncommitted); the wheel's package holds no study."""

import ast
import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: Absolute paths of a machine: a file that needs another file names it relative to the repo.
OUTSIDE = re.compile(r"(?<![\w.])(/work/|/tmp/|/home/|/root/|/Users/|[A-Z]:\\\\)")
#: Words that narrate how the work went rather than what the project is.
NARRATION = re.compile(
    r"\b(sessions?|closing notes?|not committed|trial entry|trained under the name)\b", re.I
)


def _tracked_text() -> dict[str, str]:
    files = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True)
    if files.returncode != 0:  # not a git checkout (an sdist): nothing to check
        return {}
    out = {}
    for name in files.stdout.splitlines():
        path = ROOT / name
        if path.suffix in {".zip", ".pkl", ".png", ".gif", ".mp4"} or not path.is_file():
            continue
        try:
            out[name] = path.read_text()
        except UnicodeDecodeError:
            continue
    return out


def _matches(pattern: re.Pattern) -> list[str]:
    texts = _tracked_text()
    texts.pop("tests/test_repository.py", None)  # its own patterns
    return [f"{n}: {m.group(0)}" for n, t in texts.items() if (m := pattern.search(t))]


def test_no_tracked_file_names_a_path_outside_the_repository():
    assert not _matches(OUTSIDE)


def test_no_tracked_file_narrates_its_own_making():
    assert not _matches(NARRATION)


def test_the_package_holds_no_study():
    assert not (ROOT / "tendon2r_gym" / "studies").exists()
    assert (ROOT / "research" / "studies").is_dir()


#: A dotted pointer into the package, as docstrings, pages and results name code.
POINTER = re.compile(r"\btendon2r_gym(?:\.[A-Za-z_]\w*)+")
#: Files whose pointers are history: they name the code as it was when it changed.
HISTORY = ("CHANGELOG.md", "docs/changelog.md")


def _resolves(pointer: str) -> bool:
    """Whether ``a.b.c`` is a module, or an attribute path from the longest importable one."""
    import importlib

    parts = pointer.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for name in parts[i:]:
            if not hasattr(obj, name):
                return False
            obj = getattr(obj, name)
        return True
    return False


def test_every_code_pointer_in_the_repository_resolves():
    """A pointer such as ``tendon2r_gym.task.arms.draw_arms`` in any tracked text names a
    module or an attribute that exists (history aside), so none goes stale when code moves."""
    pointers: dict[str, set[str]] = {}
    for name, text in _tracked_text().items():
        if name not in HISTORY:
            for m in POINTER.finditer(text):
                pointers.setdefault(m.group(0).rstrip("."), set()).add(name)
    stale = {p: sorted(files)[:3] for p, files in pointers.items() if not _resolves(p)}
    assert pointers and not stale


# -- phrase assertions ---------------------------------------------------------------------------
#: The folders of tests.
TEST_FOLDERS = ("tests", "research/tests")
#: The mark of a deliberate snapshot, on an assert's line or the line above: a page that
#: must show one thing (its comment says why).
SNAPSHOT = "# snapshot:"
#: The most snapshots the tests may keep.
MAX_SNAPSHOTS = 10
#: String literals whose ``in`` tests a key, element or name of data (a dict, list or set
#: of data, not rendered text), by file.
DATA = {
    "tests/test_cli.py": {"rms_deg", "missing", "arm", "action_mode"},
    "tests/test_config.py": {"observe"},
    "tests/test_contract.py": {"new_term", "reward_terms.ctrl", "config.reward_scales.ctrl"},
    "tests/test_executors.py": {"error"},
    "tests/test_identification.py": {"tendon_friction"},
    "tests/test_identification_structure.py": {"identify.py", "recording.py"},
    "tests/test_random_arms.py": {"mechanism", "arm", "pd_gains"},
    "tests/test_structure.py": {"tendon2r_gym.envs.formulas"},
    "tests/test_vector_env.py": {"tracking_error_deg"},
    "tests/test_zoo.py": {"env_wrapper"},
    "research/tests/test_candidates.py": {"rms_deg"},
}
#: The key of a row's error message: the reason a command recorded in place of its figures.
MESSAGE_KEY = "missing"


def _caught(function: ast.AST) -> set[str]:
    """Returns the names in ``function`` that hold an error or its message: bound by
    ``pytest.raises(...) as e`` or ``except ... as e``, or assigned ``str(e)`` or
    ``str(e.value)`` of one."""
    names = set()
    for node in ast.walk(function):
        if isinstance(node, ast.ExceptHandler) and node.name:
            names.add(node.name)
        elif isinstance(node, ast.withitem) and isinstance(node.optional_vars, ast.Name):
            call = node.context_expr
            func = call.func if isinstance(call, ast.Call) else None
            if getattr(func, "attr", getattr(func, "id", None)) == "raises":
                names.add(node.optional_vars.id)
    for node in ast.walk(function):
        if isinstance(node, ast.Assign) and len(node.targets) == 1:
            target = node.targets[0]
            if isinstance(target, ast.Name) and _is_message(node.value, names):
                names.add(target.id)
    return names


def _is_message(node: ast.AST, caught: set[str]) -> bool:
    """Whether ``node`` reads an error's message: ``str(e)``, ``str(e.value)``, a name that
    holds one, or a row's ``missing``."""
    if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "str" and node.args:
        node = node.args[0]
        if isinstance(node, ast.Attribute) and node.attr == "value":
            node = node.value
    if isinstance(node, ast.Name):
        return node.id in caught
    return isinstance(node, ast.Subscript) and getattr(node.slice, "value", None) == MESSAGE_KEY


def _phrase_assertions() -> tuple[list[str], list[str]]:
    """Returns the tests' assertions that a string literal (or f-string) is ``in`` (or
    ``not in``) something, neither an error's message nor data of DATA, as ``file:line``:
    those not marked, and the snapshots (every assert marked SNAPSHOT)."""
    phrases, snapshots = [], []
    for folder in TEST_FOLDERS:
        for path in sorted((ROOT / folder).glob("*.py")):
            name = str(path.relative_to(ROOT))
            text = path.read_text()
            lines, tree = text.splitlines(), ast.parse(text)
            scopes = [n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)]
            caught = {id(a): _caught(f) for f in scopes for a in ast.walk(f)}
            for node in ast.walk(tree):
                if not isinstance(node, ast.Assert):
                    continue
                marked = any(SNAPSHOT in lines[i] for i in (node.lineno - 2, node.lineno - 1))
                if marked:
                    snapshots.append(f"{name}:{node.lineno}")
                    continue
                for cmp in ast.walk(node.test):
                    if not isinstance(cmp, ast.Compare) or not isinstance(
                        cmp.left, ast.Constant | ast.JoinedStr
                    ):
                        continue
                    literal = cmp.left.value if isinstance(cmp.left, ast.Constant) else None
                    if not isinstance(literal, str | None):
                        continue
                    for op, right in zip(cmp.ops, cmp.comparators, strict=True):
                        if not isinstance(op, ast.In | ast.NotIn):
                            continue
                        if _is_message(right, caught.get(id(node), set())):
                            continue  # an error names its field, value and range
                        if literal in DATA.get(name, ()):
                            continue
                        phrases.append(f"{name}:{node.lineno}: {ast.unparse(cmp)[:80]}")
    return phrases, snapshots


def test_the_tests_check_data_not_phrases_of_rendered_text():
    """A test of a page or a command's output compares the rows and figures it shows with
    the data it was made from (tests/reading.py reads them back), not a phrase of its
    wording, which breaks when the wording changes and passes when the data is wrong.  What
    a page must show word for word is a snapshot, marked, and there are few."""
    phrases, snapshots = _phrase_assertions()
    assert phrases == []
    assert 0 < len(snapshots) <= MAX_SNAPSHOTS, snapshots
