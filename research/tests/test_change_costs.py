"""The change-cost study's machinery, without worktrees or subprocesses (the study itself runs
them): every kind's anchors are in today's sources, edits fail naming the file, and changed
files are found and classified."""

import ast
import subprocess
from pathlib import Path

import pytest

from research.studies import change_costs as cc
from research.studies.change_probes import PROBES
from tests.reading import figures

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("name", sorted(cc.KINDS))
def test_each_kinds_edits_apply_to_todays_sources(name):
    kind = cc.KINDS[name]
    read = cc.reader(ROOT, kind.copies)
    edited = cc.apply(kind.edits, read)
    assert set(edited) == {e.path for e in kind.edits}
    for path, text in edited.items():
        new_file = any(e.source is not None for e in kind.edits if e.path == path)
        assert (read(path) is None) == new_file, path
        assert text != read(path), path
        if path.endswith(".py"):
            ast.parse(text, path)  # the edited module still parses
    for old, _ in kind.copies:
        assert (ROOT / old).is_dir(), old
    assert name in PROBES, "each kind has its probe"


def test_an_anchor_found_other_than_once_names_the_file():
    read = {"a.py": "x = 1\nx = 1\n", "b.yaml": "k: v\n"}.get
    with pytest.raises(ValueError, match=r"a\.py: anchor 'x = 1\\n' found 2 times"):
        cc.apply((cc.Edit("a.py", "x = 1\n", "y = 2\n"),), read)
    with pytest.raises(ValueError, match=r"a\.py: anchor 'z' found 0 times"):
        cc.apply((cc.Edit("a.py", "z", ""),), read)
    with pytest.raises(ValueError, match=r"c\.py is missing"):
        cc.apply((cc.Edit("c.py", "z", ""),), read)
    with pytest.raises(ValueError, match=r"b\.yaml exists"):
        cc.apply((cc.Edit("b.yaml", "k", "j", "replace", source="a.py"),), read)
    edits = (cc.Edit("a.py", "x = 1\nx", "y", "replace"), cc.Edit("a.py", "y", "# z\n", "before"))
    assert cc.apply(edits, read) == {"a.py": "# z\ny = 1\n"}, "edits apply in order"


@pytest.mark.parametrize(
    ("path", "category"),
    [
        ("tendon2r_gym/envs/formulas.py", "library"),
        ("tendon2r_gym/data/shipped.yaml", "data"),
        ("tendon2r_gym/data/presets/x.yaml", "data"),
        ("tendon2r_gym/data/models/x/seed_0/run.json", "bundle"),
        ("docs/models.md", "generated"),
        ("docs/extending.md", "other"),
        ("CHANGELOG.md", "other"),
    ],
)
def test_classify(path, category):
    assert cc.classify(path, {"docs/models.md", "README.md"}) == category


def _files(**given):
    return {c: given.get(c, []) for c in cc.CATEGORIES}


def test_the_verdict_names_every_reason():
    kind, ok = cc.KINDS["reward"], {"check": "x", "ok": True, "detail": ""}
    two = _files(library=["tendon2r_gym/a.py", "tendon2r_gym/b.py"])
    assert cc.verdict(kind, two, {}, [ok], []) == (True, [])
    four = _files(library=["tendon2r_gym/a.py", "tendon2r_gym/b.py", "tendon2r_gym/c.py"],
                  data=["tendon2r_gym/data/d.yaml"])  # fmt: skip
    failed, contracts = {**ok, "ok": False}, ["Tendon2R-v1"]
    met, why = cc.verdict(kind, four, {}, [failed], contracts)
    assert not met and len(why) == 3  # each reason names what it is about
    assert failed["check"] in why[0].split() and contracts[0] in why[1]
    assert figures(why[2]) == [4, kind.target]  # the library and data files, the target


def test_a_promotion_is_a_bundle_and_one_registry_line():
    kind, ok = cc.KINDS["promote"], [{"check": "x", "ok": True, "detail": ""}]
    bundle = [f"{cc.BUNDLE[1]}/bundle.json"]
    files = _files(data=[cc.REGISTRY], bundle=bundle, generated=["docs/models.md"])
    assert cc.verdict(kind, files, {cc.REGISTRY: [1, 0]}, ok, [])[0]
    assert not cc.verdict(kind, files, {cc.REGISTRY: [2, 1]}, ok, [])[0]
    other = _files(data=[cc.REGISTRY], bundle=[f"{cc.MODELS}default/bundle.json"])
    assert not cc.verdict(kind, other, {cc.REGISTRY: [1, 0]}, ok, [])[0]
    library = _files(library=["tendon2r_gym/app/benchmark.py"], data=[cc.REGISTRY])
    assert not cc.verdict(kind, library, {cc.REGISTRY: [1, 0]}, ok, [])[0]


def _git(repo, *args):
    subprocess.run(["git", "-C", str(repo), "-c", "user.name=t", "-c", "user.email=t@t", *args],
                   check=True, capture_output=True)  # fmt: skip


def test_changes_are_found_against_a_snapshot_and_the_worktree_is_removed(tmp_path):
    repo = tmp_path / "repo"
    (repo / "docs").mkdir(parents=True)
    (repo / "a.py").write_text("x = 1\n")
    (repo / "docs" / "page.md").write_text("old\n")
    _git(repo, "init", "-q")
    _git(repo, "add", ".")
    _git(repo, "commit", "-qm", "start")
    with pytest.raises(RuntimeError, match="boom"), cc.worktree(repo) as root:
        (root / "docs" / "page.md").write_text("stale\n")  # as a regenerated stale page
        stale = cc.dirty(root)
        assert cc.changed(root, stale) == []
        (root / "a.py").write_text("x = 1\ny = 2\n")
        (root / "new").mkdir()
        (root / "new" / "b.txt").write_text("b\n")
        touched = cc.changed(root, stale)
        assert touched == ["a.py", "new/b.txt"]
        assert cc.line_counts(root, touched, stale) == {"a.py": [1, 0], "new/b.txt": [1, 0]}
        (root / "docs" / "page.md").write_text("new\n")
        assert cc.changed(root, stale) == ["a.py", "docs/page.md", "new/b.txt"]
        assert cc.line_counts(root, ["docs/page.md"], stale) == {"docs/page.md": [1, 1]}
        kept = root
        raise RuntimeError("boom")
    assert not kept.exists()
    listed = subprocess.run(["git", "-C", str(repo), "worktree", "list"], capture_output=True,
                            text=True).stdout.splitlines()  # fmt: skip
    assert len(listed) == 1, listed


def test_named_elsewhere_finds_the_untouched_files_that_name_every_member(tmp_path):
    package = tmp_path / "tendon2r_gym"
    (package / "data" / "models" / "m").mkdir(parents=True)
    (package / "lists.py").write_text("A = ('alpha', 'beta')\n")
    (package / "one.py").write_text("alpha = 1\n")
    (package / "touched.py").write_text("alpha, beta = 1, 2\n")
    (package / "data" / "x.yaml").write_text("alpha: beta\n")
    (package / "data" / "models" / "m" / "c.yaml").write_text("alpha: beta\n")
    found = cc.named_elsewhere(tmp_path, ("alpha", "beta"), ["tendon2r_gym/touched.py"])
    assert found == ["tendon2r_gym/data/x.yaml", "tendon2r_gym/lists.py"]
