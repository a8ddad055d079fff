"""The repository speaks of itself only: no tracked file names a path outside it, or narrates
the history of its own making (working sessions, closing notes, trial entries left
uncommitted); the wheel's package holds no study."""

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
