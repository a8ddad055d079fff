"""How many library files each kind of change touches, measured by making one.

    python -m research.studies.change_costs                       # results/change_costs.*
    python -m research.studies.change_costs --kinds reward preset # some kinds only

For each kind of docs/extending.md, the study adds a temporary detached git worktree of HEAD
(removed afterwards, even on error), regenerates the docs there as HEAD's code writes them,
then makes a small but real example of the change with text edits at anchors in the source
(``KINDS``; an anchor that is missing, or found twice, stops the study naming the file),
regenerates the docs again and records what changed (``git status``, untracked files
included), split into library files (``tendon2r_gym/`` but its models), data files
(``tendon2r_gym/data/`` but its models), bundle folders, generated docs (what
``scripts/gen_docs.py`` wrote, if the change altered it) and others.

A fresh process on the edited copy (research/studies/change_probes.py) then uses the change
as a user would, and compares what an off-by-default change must keep with the same process
on HEAD: the registered env's single-env and vector-env rollouts, the compiled models of
two presets, and every registered id's contract against its pinned one, which it may grow
but not change (tests/test_contract.py).  ruff checks the edited Python files.

A kind meets its target when the example works, keeps the pinned contracts, and touches at
most its target's number of library and data files (a promoted model: no library file, one
added line of tendon2r_gym/data/shipped.yaml, its bundle folder and regenerated docs).
"""

from __future__ import annotations

import contextlib
import difflib
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

from research.studies import save_json
from tendon2r_gym.app.args import arg, parse
from tendon2r_gym.artifacts.runs import command_line

PROBES = Path(__file__).resolve().with_name("change_probes.py")
#: Where a change's files go, in the order of ``classify``'s answer.
CATEGORIES = ("library", "data", "bundle", "generated", "other")
LIBRARY, DATA, MODELS = "tendon2r_gym/", "tendon2r_gym/data/", "tendon2r_gym/data/models/"
REGISTRY = "tendon2r_gym/data/shipped.yaml"
#: The check that the registered env's behaviour is HEAD's.
UNCHANGED = "the registered env's rollouts are unchanged (single and vector env)"
#: What tests/test_contract.py asks of a changed contract.
NEW_VERSION = ("tendon2r_gym/__init__.py", "tendon2r_gym/data/contracts.yaml", "CHANGELOG.md")


@dataclass(frozen=True)
class Edit:
    """In ``path``, ``new`` goes ``how`` (after, before or instead of) ``anchor``, which must
    occur exactly once.  With ``source``, ``path`` is a new file: a copy of ``source`` with
    the edit."""

    path: str
    anchor: str
    new: str
    how: Literal["after", "before", "replace"] = "after"
    source: str | None = None


@dataclass(frozen=True)
class Kind:
    """One kind of change: its example's edits (after copying ``copies``, (folder, new
    folder) pairs), its target (most library + data files; None: a promoted model's rule)
    and the names of its existing members (the files that name them all are reported)."""

    example: str
    target: int | None
    edits: tuple[Edit, ...]
    members: tuple[str, ...]
    copies: tuple[tuple[str, str], ...] = ()


OBS, TASK = "tendon2r_gym/task/observation.py", "tendon2r_gym/envs/formulas.py"
MECH, MODEL = "tendon2r_gym/simulation/mechanism.py", "tendon2r_gym/simulation/model.py"
REALISM = "tendon2r_gym/simulation/realism.py"
ENV, VECTOR = "tendon2r_gym/envs/env.py", "tendon2r_gym/envs/vector_env.py"
#: The bundle the promotion copies, and its copy.
BUNDLE = (f"{MODELS}random_reference", f"{MODELS}random_reference_copy")

KINDS: dict[str, Kind] = {
    "observation": Kind(
        "observe `reference_acceleration`: the reference's acceleration ddq_des (2 entries)",
        2,
        (
            Edit(OBS, "acceleration in normalized joint torques; ",
                 "``reference_acceleration``, the\nreference's acceleration in rad/s^2 "
                 "(``ddq_des``); "),
            Edit(OBS, '"feedforward", "force_limit", "arm")',
                 '"feedforward", "reference_acceleration", "force_limit", "arm")', "replace"),
            Edit(OBS, "#: The optional entries (name, size, unit), in their order after",
                 "#: The optional entry of ``reference_acceleration`` (name, size, unit): the\n"
                 "#: reference's acceleration ddq_des(t), joint A then B.\n"
                 'REFERENCE_ACCELERATION = ("ddq_des", 2, "rad/s^2")\n', "before"),
            Edit(OBS, '    FEEDFORWARD: "feedforward",\n',
                 '    REFERENCE_ACCELERATION: "reference_acceleration",\n'),
            Edit(OBS, '    rows.append(\n        f"| (observe ``force_limit``)',
                 "    rows.append(\n"
                 '        "| (observe ``reference_acceleration``) the next 2 | the reference\'s '
                 'acceleration "\n'
                 '        f"ddq_des(t), A then B (``{REFERENCE_ACCELERATION[0]}``) | '
                 '{REFERENCE_ACCELERATION[2]} |"\n'
                 "    )\n", "before"),
            Edit(TASK, "error_rate_log, feedforward, force_limit_log and arm",
                 "error_rate_log, feedforward, ddq_des, force_limit_log and arm", "replace"),
            Edit(TASK, "            joints += self.feedforward_entries(ops, t, ref, arm)\n",
                 '        if "reference_acceleration" in self.config.observe:\n'
                 "            joints += [-amp1 * om1 * om1 * sin(arg1), "
                 "-amp2 * om2 * om2 * sin(arg2)]\n"),
        ),
        ("error_rate", "feedforward", "force_limit"),
    ),
    "reward": Kind(
        "reward term `tracking_abs`: -sum(|e|) in deg, weight 0",
        3,
        (
            Edit("tendon2r_gym/task/rewards.py", '    "ctrl": (\n        0.001,',
                 '    "tracking_abs": (\n        0.0,\n'
                 '        "``-sum(|e|)`` with the errors e in deg: the absolute '
                 'error\'s own weighting, "\n'
                 '        "between the quadratic\'s and the kernels\'",\n    ),\n',
                 "before"),
            Edit(TASK, '            "tracking_quadratic": quadratic,\n',
                 '            "tracking_abs": -(abs(e1) + abs(e2)),\n'),
        ),
        ("tracking_quadratic", "action_rate_need"),
    ),
    "baseline": Kind(
        "baseline `pdv`: PD without the reference-velocity feed-forward",
        3,
        (
            Edit("tendon2r_gym/policies/baselines.py",
                 "class ComputedTorquePolicy(_TendonController):\n",
                 "class PDVPolicy(_TendonController):\n"
                 '    """Joint-space PD without the reference-velocity feed-forward, scaled by '
                 "the joint\n    inertia: tau = M(q) (kp (q_des - q) - kd dq).\"\"\"\n\n"
                 "    def _torque(self, obs: np.ndarray, M: np.ndarray) -> np.ndarray:\n"
                 "        acc = self.kp * (obs[:, Q_DES] - obs[:, Q]) - self.kd * obs[:, DQ]\n"
                 '        return np.einsum("nij,nj->ni", M, acc)\n\n\n', "before"),
            Edit("tendon2r_gym/evaluation/evaluator.py", "ComputedTorquePolicy, PDPolicy\n",
                 "ComputedTorquePolicy, PDPolicy, PDVPolicy\n", "replace"),
            Edit("tendon2r_gym/evaluation/evaluator.py",
                 '    "ct": PolicyEntry("CT", BASELINE, lambda env, _: '
                 "ComputedTorquePolicy.from_env(env)),\n",
                 '    "pdv": PolicyEntry("PD-v", BASELINE, lambda env, _: '
                 "PDVPolicy.from_env(env)),\n"),
        ),
        ("PDPolicy", "ComputedTorquePolicy"),
    ),
    "mechanism": Kind(
        "Mechanism field `tip_mass`: a payload at the effector (kg)",
        3,
        (
            Edit(MECH, "    joint_damping: float = 0.0  # (N m s / rad)\n",
                 "    tip_mass: float = 0.0  # a payload at the effector, a small sphere (kg)\n"),
            Edit(MECH, '"tendon_damping", "pretension"):\n'
                 '            set_(name, number(f"Mechanism.{name}", getattr(self, name), 0.0))\n',
                 '        set_("tip_mass", number("Mechanism.tip_mass", self.tip_mass, 0.0, '
                 "10.0))\n"),
            Edit(MODEL, '    site(link_b, "effector", (b, 0.0), size=0.003, '
                 "rgba=(0.9, 0.9, 0.9, 1.0))\n",
                 "    if mech.tip_mass > 0:  # a payload at the effector: a small sphere of "
                 "that mass\n"
                 "        sphere = mujoco.mjtGeom.mjGEOM_SPHERE\n"
                 '        payload = geom(link_b, "payload", sphere, [rl, 0, 0], _RGBA["site"], '
                 "pos=[b, 0, 0])\n"
                 "        payload.mass = mech.tip_mass\n"),
        ),
        ("joint_damping", "tendon_stiffness", "tendon_damping"),
    ),
    "routing": Kind(
        "routing `n_plus_1_mirrored`: n_plus_1 with every side flipped",
        3,
        (
            Edit("tendon2r_gym/simulation/routing.py",
                 '    "n_plus_1": ((+1, +1), (+1, -1), (-1, 0)),\n',
                 "    # n_plus_1 with every side flipped: moment arms (r1, r2), (r1, -r2) and "
                 "(-r1, 0),\n    # the same null vector (1, 1, 2).\n"
                 '    "n_plus_1_mirrored": ((-1, -1), (-1, +1), (+1, 0)),\n'),
        ),
        ("asymmetric", "crossed", "n_plus_1"),
    ),
    "preset": Kind(
        "preset `slow_reference`: the default arm on a 1 Hz / 1.2 Hz reference",
        3,
        tuple(
            Edit("tendon2r_gym/data/presets/slow_reference.yaml", old, new, "replace",
                 "tendon2r_gym/data/presets/default.yaml")
            for old, new in (
                ("# Mechanism of reports 000/001, reference of report 001, asymmetric routing.",
                 "# The default arm on a slower reference (1 Hz and 1.2 Hz)."),
                ("  # max_tendon_force is not set: \"auto\" sizes it from the reference (2 x the "
                 "0.19 N that\n  # inverse dynamics needs = 0.385 N), and a mechanism override "
                 "through gym.make re-sizes it.\n",
                 "  # max_tendon_force is not set: \"auto\" sizes it from this reference.\n"),
                ("  freq_hz: [2.37, 2.71]\n", "  freq_hz: [1.0, 1.2]\n"),
            )
        ),  # fmt: skip
        ("report_002", "pull_only"),
    ),
    "realism_model": Kind(
        "realism field `joint_friction`: the joints' dry friction (N m), in the compiled model",
        4,
        (
            Edit(MECH, '    "tendon_friction": 1e3,  # N\n',
                 '    "joint_friction": 10.0,  # N m\n'),
            Edit(MECH, "    tendon_friction: float = 0.0  # dry friction of each cable sliding "
                 "on its pulleys (N)\n",
                 "    joint_friction: float = 0.0  # dry friction of each joint's bearings "
                 "(N m)\n"),
            Edit(REALISM, "  the working tension.\n",
                 "- ``joint_friction``: dry friction of each joint's bearings (N m), MuJoCo's "
                 "joint\n  frictionloss.  Typical: 1e-5 to 1e-4 for miniature ball bearings.\n"),
            Edit(MODEL, "            damping=mech.true_joint_damping,\n",
                 "            frictionloss=mech.joint_friction,\n"),
        ),
        ("tendon_elasticity", "tendon_friction", "motor_tau"),
    ),
    "realism_step": Kind(
        "realism field `motor_offset`: the drivers' zero error, added to every command "
        "between the action and ctrl",
        4,
        (
            Edit(MECH, "    motor_delay: float = 0.0  # dead time between a command and the "
                 "motor (s), whole ctrl_dt\n",
                 "    motor_offset: float = 0.0  # the drivers' zero error, added to every "
                 "command\n"),
            Edit(MECH, '            set_(name, number(f"Mechanism.{name}", getattr(self, name), '
                 "0.0, hi))\n",
                 '        set_("motor_offset", number("Mechanism.motor_offset", '
                 "self.motor_offset, -1.0, 1.0))\n"),
            Edit(MECH, "        return any(getattr(self, k) > 0 for k in REALISM_LIMITS) or any(\n"
                 "            getattr(self, k) != exact for k, exact in MODEL_ERRORS.items()\n"
                 "        )\n",
                 "        return (\n"
                 "            any(getattr(self, k) > 0 for k in REALISM_LIMITS)\n"
                 "            or self.motor_offset != 0.0\n"
                 "            or any(getattr(self, k) != exact for k, exact in "
                 "MODEL_ERRORS.items())\n"
                 "        )\n", "replace"),
            Edit(MECH, "off = dict.fromkeys(REALISM_LIMITS, 0.0)",
                 'off = dict.fromkeys((*REALISM_LIMITS, "motor_offset"), 0.0)', "replace"),
            Edit(REALISM, "  driver.  Typical: 1 to 5 ms.\n",
                 "- ``motor_offset``: the drivers' zero error, added to every normalized "
                 "command before\n  it reaches the motor (the envs add it, not MuJoCo), in "
                 "[-1, 1].  Typical: within +-0.01.\n"),
            Edit(ENV, "        self.drive = Drive(self.model, self.mechanism)\n",
                 "        self._offset = self.mechanism.motor_offset  # the drivers' zero error\n"),
            Edit(ENV, "        self._ctrl[:] = u\n",
                 "        if self._offset:  # Mechanism.motor_offset, on every command\n"
                 "            u = [x + self._offset for x in u]\n", "before"),
            Edit(VECTOR, "        self.drive = Drive(self.model, cfg.mechanism)\n",
                 "        self._offset = cfg.mechanism.motor_offset  # the drivers' zero error\n"),
            Edit(VECTOR, "        self._ctrl[active] = u[active]\n",
                 "        if self._offset:  # Mechanism.motor_offset, on every command\n"
                 "            u = u + self._offset\n", "before"),
            Edit(REALISM, 'STEP_FIELDS = {"motor_delay": "each command held back whole control '
                 'steps"}',
                 'STEP_FIELDS = {\n    "motor_delay": "each command held back whole control '
                 'steps",\n    "motor_offset": "added to every command",\n}', "replace"),
        ),
        ("motor_delay", "observation_delay"),
    ),
    "promote": Kind(
        "promoting a model: a copy of the `random_reference` bundle as "
        "`random_reference_copy`",
        None,
        (
            Edit(f"{BUNDLE[1]}/bundle.json", '"name": "random_reference",',
                 '"name": "random_reference_copy",', "replace"),
            Edit(REGISTRY, "group: references}\n",
                 'random_reference_copy: {role: "residual PPO on random references, default '
                 'arm (a copy of random_reference)", entry: random_reference, env: default, '
                 "seeds: [0], contract: 'f6bab26b7bf5', group: references}\n"),
        ),
        ("random_reference", "generalist_scratch"),
        copies=(BUNDLE,),
    ),
}  # fmt: skip
KindName = Literal[tuple(KINDS)]  # type: ignore[valid-type]


# -- edits ---------------------------------------------------------------------------------------
def apply(edits: tuple[Edit, ...], read: Callable[[str], str | None]) -> dict[str, str]:
    """Returns the text of every file ``edits`` change, by path, after them (``read``: a
    file's text before, None if it does not exist); raises a ValueError naming the file for
    an anchor found other than once, a missing file, or a new file that exists."""
    out: dict[str, str] = {}
    for e in edits:
        if e.path not in out:
            new_file = e.source is not None
            if new_file and read(e.path) is not None:
                raise ValueError(f"{e.path} exists: the study adds it; remove it or rename")
            text = read(e.source if new_file else e.path)
            if text is None:
                raise ValueError(f"{e.source or e.path} is missing: the code moved; update "
                                 "research/studies/change_costs.py")  # fmt: skip
            out[e.path] = text
        text = out[e.path]
        if (n := text.count(e.anchor)) != 1:
            raise ValueError(
                f"{e.path}: anchor {e.anchor!r} found {n} times, not once: the code moved; "
                "update research/studies/change_costs.py"
            )
        new = {"after": e.anchor + e.new, "before": e.new + e.anchor, "replace": e.new}[e.how]
        out[e.path] = text.replace(e.anchor, new)
    return out


def reader(root: Path, copies: tuple[tuple[str, str], ...] = ()) -> Callable[[str], str | None]:
    """Returns a reader of ``root``'s files by relative path, where a file under a copy's
    new folder is its original's (the copies not made)."""

    def read(path: str) -> str | None:
        for old, new in copies:
            if path.startswith(new + "/"):
                path = old + path[len(new) :]
        file = root / path
        return file.read_text() if file.is_file() else None

    return read


def make_change(kind: Kind, root: Path) -> None:
    """Makes ``kind``'s example in the tree at ``root``: its copies, then its edits."""
    import shutil

    for old, new in kind.copies:
        if (root / new).exists():
            raise ValueError(f"{new} exists: the study adds it; remove it or rename")
        shutil.copytree(root / old, root / new)
    for path, text in apply(kind.edits, reader(root)).items():
        (root / path).write_text(text)


# -- what changed ------------------------------------------------------------------------------
def classify(path: str, generated: set[str]) -> str:
    """Returns the category (CATEGORIES) of a changed file's repository path."""
    if path in generated:
        return "generated"
    if path.startswith(MODELS):
        return "bundle"
    if path.startswith(DATA):
        return "data"
    return "library" if path.startswith(LIBRARY) else "other"


def git(root: Path, *args: str) -> str:
    """Returns git's output in ``root``, or raises with its error."""
    proc = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"git {' '.join(args)} failed: {proc.stderr.strip()}")
    return proc.stdout


def dirty(root: Path) -> dict[str, bytes | None]:
    """Returns every file that ``git status`` lists (changed, added, deleted or untracked),
    with its content (None: deleted)."""
    out: dict[str, bytes | None] = {}
    for entry in git(root, "status", "--porcelain", "-uall", "-z").split("\0"):
        if entry:
            path = entry[3:]
            out[path] = (root / path).read_bytes() if (root / path).is_file() else None
    return out


def changed(root: Path, before: Mapping[str, bytes | None]) -> list[str]:
    """Returns the files that differ from ``before`` (``dirty``), sorted."""
    return sorted(p for p, data in dirty(root).items() if p not in before or before[p] != data)


@contextlib.contextmanager
def worktree(repo: Path) -> Iterator[Path]:
    """Yields a temporary detached worktree of ``repo``'s HEAD; removes it afterwards."""
    with tempfile.TemporaryDirectory(prefix="change_costs-") as tmp:
        root = Path(tmp) / "tree"
        git(repo, "worktree", "add", "--detach", "--quiet", str(root), "HEAD")
        try:
            yield root
        finally:
            git(repo, "worktree", "remove", "--force", str(root))


def _env(root: Path) -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(root), "MUJOCO_GL": "egl"}


def gen_docs(root: Path) -> set[str]:
    """Runs scripts/gen_docs.py in ``root``; returns the files it wrote (relative)."""
    proc = subprocess.run([sys.executable, "scripts/gen_docs.py"], cwd=root, env=_env(root),
                          capture_output=True, text=True)  # fmt: skip
    if proc.returncode != 0:
        raise RuntimeError(f"scripts/gen_docs.py failed: {proc.stderr[-2000:]}")
    wrote = [line.removeprefix("wrote ") for line in proc.stdout.splitlines()]
    return {Path(p).resolve().relative_to(root.resolve()).as_posix() for p in wrote if p}


def probe(root: Path, names: list[str]) -> dict[str, Any]:
    """Runs change_probes.py on ``root`` in a fresh process (``names``: what to run)."""
    proc = subprocess.run([sys.executable, str(PROBES), str(root), *names], cwd=root,
                          env=_env(root), capture_output=True, text=True)  # fmt: skip
    if proc.stderr.strip():
        print(proc.stderr[-3000:], file=sys.stderr)
    if proc.returncode != 0:
        raise RuntimeError(f"change_probes.py {' '.join(names)} failed: {proc.stderr[-2000:]}")
    return json.loads(proc.stdout)


def ruff(root: Path, files: list[str]) -> dict[str, Any]:
    """Returns {"check", "ok", "detail"}: ruff check and ruff format --check on ``files``."""
    if not files:
        return {"check": "ruff is clean on the edited files", "ok": True, "detail": "none"}
    out = []
    for cmd in (["check", "--quiet"], ["format", "--check", "--quiet"]):
        proc = subprocess.run([sys.executable, "-m", "ruff", *cmd, *files], cwd=root,
                              capture_output=True, text=True)  # fmt: skip
        if proc.returncode != 0:
            out.append(f"ruff {cmd[0]}: {(proc.stdout + proc.stderr).strip()[:500]}")
    return {"check": "ruff is clean on the edited files", "ok": not out, "detail": "; ".join(out)}


def line_counts(root: Path, files: list[str], before: Mapping[str, bytes | None]) -> dict:
    """Returns [lines added, lines removed] of each changed text file against its content
    before the change: ``before`` (``dirty``) if it holds it, else HEAD's (none for a
    new file)."""
    out = {}
    for path in files:
        if path in before:
            old = before[path]
        else:
            show = subprocess.run(["git", "-C", str(root), "show", f"HEAD:{path}"],
                                  capture_output=True)  # fmt: skip
            old = show.stdout if show.returncode == 0 else None
        new = (root / path).read_bytes() if (root / path).is_file() else None
        try:
            a, b = ((x or b"").decode().splitlines() for x in (old, new))
        except UnicodeDecodeError:  # a binary file
            continue
        diff = list(difflib.unified_diff(a, b, lineterm="", n=0))[2:]
        out[path] = [sum(d[0] == s for d in diff if not d.startswith("@@")) for s in "+-"]
    return out


def named_elsewhere(root: Path, members: tuple[str, ...], touched: list[str]) -> list[str]:
    """Returns the library and data files (not touched) that name every one of ``members``:
    lists of a kind's members that the change left as they were."""
    words = [re.compile(rf"\b{re.escape(m)}\b") for m in members]
    out = []
    for file in sorted((root / "tendon2r_gym").rglob("*")):
        path = file.relative_to(root).as_posix()
        if file.suffix not in (".py", ".yaml") or path.startswith(MODELS) or path in touched:
            continue
        text = file.read_text()
        if all(w.search(text) for w in words):
            out.append(path)
    return out


# -- one kind ------------------------------------------------------------------------------------
def measure(name: str, repo: Path) -> dict[str, Any]:
    """Makes kind ``name``'s example in a temporary worktree of ``repo``'s HEAD and returns
    what it touched, its checks and its verdict."""
    kind, start = KINDS[name], time.perf_counter()
    with worktree(repo) as root:
        gen_docs(root)  # HEAD's code's pages: the change's own effect is measured from here
        stale = dirty(root)
        before = probe(root, ["fingerprint"])["fingerprint"]
        make_change(kind, root)
        generated = gen_docs(root)
        touched = changed(root, stale)
        after = probe(root, ["fingerprint", name])
        files = {c: [p for p in touched if classify(p, generated) == c] for c in CATEGORIES}
        lines = line_counts(root, touched, stale)
        lint = ruff(root, [p for p in files["library"] if p.endswith(".py")])
        elsewhere = named_elsewhere(root, kind.members, touched)
    checks = [*after["checks"], *kept(before, after["fingerprint"]), lint]
    contracts = contract_changes(before, after["fingerprint"])
    met, why = verdict(kind, files, lines, checks, contracts)
    return {
        "kind": name,
        "example": kind.example,
        "members": list(kind.members),
        "target": kind.target,
        "files": files,
        "lines": lines,
        "count": len(files["library"]) + len(files["data"]),
        "checks": checks,
        "contracts_changed": contracts,
        "named_elsewhere": elsewhere,
        "met": met,
        "why": why,
        "wall_s": round(time.perf_counter() - start, 1),
    }


def kept(before: dict[str, Any], after: dict[str, Any]) -> list[dict[str, Any]]:
    """Returns the checks that an off-by-default change keeps HEAD's behaviour."""
    return [
        {"check": UNCHANGED,
         "ok": before["single"] == after["single"] and before["vector"] == after["vector"],
         "detail": f"{after['single']} {after['vector']}"},
        {"check": "the presets' compiled models are unchanged, bit for bit",
         "ok": before["models"] == after["models"], "detail": json.dumps(after["models"])},
    ]  # fmt: skip


def contract_changes(before: dict[str, Any], after: dict[str, Any]) -> list[str]:
    """Returns the ids whose contract lost or changed a pinned value (a contract may grow:
    tendon2r_gym.envs.contract.changes); raises if one had at HEAD already (the study then
    cannot tell the change's effect)."""
    if broken := [i for i, paths in before["contracts"].items() if paths]:
        raise RuntimeError(f"HEAD's contracts of {broken} are not the pinned ones")
    return [i for i, paths in after["contracts"].items() if paths]


def verdict(
    kind: Kind,
    files: dict[str, list[str]],
    lines: dict[str, list[int]],
    checks: list[dict[str, Any]],
    contracts: list[str],
) -> tuple[bool, list[str]]:
    """Returns whether the kind met its target, and why not (module docstring)."""
    failed = [c for c in checks if not c["ok"]]
    why = [f"check failed: {c['check']} ({c['detail']})" for c in failed]
    if contracts:
        same = not any(c["check"] == UNCHANGED for c in failed)
        why.append(
            f"changes the pinned contracts of {', '.join(contracts)}"
            + (" (the registered env behaves as before)" if same else "")
            + f": tests/test_contract.py fails until a new env version ({', '.join(NEW_VERSION)})"
            " or a contract that leaves out a field at its off value (as it leaves out an "
            "observe entry added later: tendon2r_gym.task.observation.as_flags)"
        )
    count = len(files["library"]) + len(files["data"])
    if kind.target is not None and count > kind.target:
        why.append(f"{count} library and data files, target at most {kind.target}")
    if kind.target is None:  # a promoted model
        if files["library"] or files["data"] != [REGISTRY] or lines.get(REGISTRY) != [1, 0]:
            why.append(f"touches more than one added line of {REGISTRY} beside its bundle")
        new = [new for _, new in kind.copies]
        if any(not any(p.startswith(n + "/") for n in new) for p in files["bundle"]):
            why.append("touches another bundle folder")
    if files["other"]:
        why.append(f"touches files outside the package: {', '.join(files['other'])}")
    return not why, why


# -- results ---------------------------------------------------------------------------------------
def shown(row: dict[str, Any]) -> tuple[str, str]:
    """Returns a row's library and data files, and what else it touched, as the table
    shows them."""
    files = row["files"]
    which = ", ".join(f"`{p}`" for p in files["library"] + files["data"]) or "none"
    also = []
    for folder in sorted({"/".join(p.split("/")[:4]) for p in files["bundle"]}):
        n = sum(p.startswith(folder + "/") for p in files["bundle"])
        also.append(f"`{folder}/` ({n} files)")
    also += [f"`{p}`" for p in files["generated"] + files["other"]]
    return which, ", ".join(also) or "none"


def target_text(target: int | None) -> str:
    """Returns a kind's target as the table shows it."""
    if target is None:
        return f"a bundle folder, one line of `{REGISTRY}`, regenerated docs"
    return f"at most {target}"


def write(result: dict[str, Any], out: Path) -> None:
    """Writes change_costs.json and change_costs.md."""
    save_json(out, "change_costs", result)
    lines = [
        "# The cost of each kind of change",
        "",
        f"Produced by `{result['command']}` on commit `{result['commit']}`: each kind's "
        "example made in a temporary worktree of that commit (the edits: "
        "`research/studies/change_costs.py`), the docs regenerated before and after it, "
        "and the change used in a fresh process (`research/studies/change_probes.py`). "
        "Files touched: library files (`tendon2r_gym/` but its models) and data files "
        "(`tendon2r_gym/data/` but its models); bundle folders and the pages "
        "`scripts/gen_docs.py` rewrote are listed beside them, tests are not written. Met: "
        "the example works, keeps every registered id's pinned contract and touches at "
        "most its target's files.",
        "",
        "| kind | example | files (library + data) | which files | also touched | target | met |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in result["kinds"]:
        which, also = shown(row)
        lines.append(
            f"| {row['kind']} | {row['example']} | {row['count']} | {which} | {also} | "
            f"{target_text(row['target'])} | {'yes' if row['met'] else '**no**'} |"
        )
    lines += ["", "## Why a target was missed", ""]
    missed = [row for row in result["kinds"] if not row["met"]]
    lines += [f"- {row['kind']}: {'; '.join(row['why'])}." for row in missed] or ["None."]
    lines += ["", "## Checks", ""]
    for row in result["kinds"]:
        ok = sum(c["ok"] for c in row["checks"])
        names = "; ".join(c["check"] for c in row["checks"])
        changed = ", ".join(row["contracts_changed"]) or "none"
        lines.append(
            f"- {row['kind']} ({ok} of {len(row['checks'])} passed): {names}. Pinned "
            f"contracts changed: {changed}."
        )
    lines += [
        "",
        "## Lists left as they were",
        "",
        "Library and data files, not touched by the example, that name every existing member "
        "the study looks for (a list a reader may expect to grow with the new one):",
        "",
    ]
    for row in result["kinds"]:
        files = ", ".join(f"`{p}`" for p in row["named_elsewhere"]) or "none"
        lines.append(f"- {row['kind']} ({', '.join(row['members'])}): {files}.")
    (out / "change_costs.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


@dataclass
class Args:
    """The study's arguments (module docstring)."""

    kinds: Annotated[list[KindName], arg("kinds of change to measure")] = field(
        default_factory=lambda: list(KINDS)
    )
    out: Annotated[str, arg("folder for change_costs.md and .json")] = "research/results"


def main(argv: list[str] | None = None) -> dict[str, Any]:
    args = parse(Args, argv, __doc__)
    repo = Path(git(Path.cwd(), "rev-parse", "--show-toplevel").strip())
    result: dict[str, Any] = {
        "command": command_line(argv, "python -m research.studies.change_costs"),
        "commit": git(repo, "rev-parse", "--short", "HEAD").strip(),
        "kinds": [],
    }
    for name in args.kinds:
        row = measure(name, repo)
        result["kinds"].append(row)
        print(f"{name}: {row['count']} files, met {row['met']} ({row['wall_s']} s)", flush=True)
    write(result, Path(args.out))
    return result


if __name__ == "__main__":
    main()
