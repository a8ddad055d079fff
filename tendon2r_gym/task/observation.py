"""The observation layout of the Tendon2R env: named slices, the one place that knows the order.

The env writes the observation in this order, and policies, info and tests read it by name.
The fixed entries come first, so their slices do not depend on ``preview_steps``; then the
preview of the reference, then the last action (one value per action dimension), which makes
the action-rate reward term a function of the observed state.  Then the optional entries a
user asks for with ``observe`` (EnvConfig), in OBSERVABLE's order: ``error_rate``, the
log-scaled rate of the tracking error (``error_rate_log``); ``feedforward``, the reference's
acceleration in normalized joint torques; ``force_limit``, the log of the arm's force limit
(``force_limit_log``); ``arm`` (random arms, ``mechanism_ranges``), the arm's drawn fields,
normalized over their ranges (``arm_feature_ranges`` if given: one fixed arm, seen as a
generalist saw it).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from tendon2r_gym.validation import boolean

#: What ``observe`` may list: the optional entries, in the observation's order.
OBSERVABLE = ("error_rate", "feedforward", "force_limit", "arm")
#: The flags that ``observe`` replaced (tendon2r_gym 0.3.0), as older experiment files and run
#: records hold them; read through `from_flags`.  (An entry added to OBSERVABLE later
#: has no flag.)
FLAGS = {
    "observe_error_rate": "error_rate",
    "observe_feedforward": "feedforward",
    "observe_force_limit": "force_limit",
    "observe_arm": "arm",
}


def from_flags(kwargs: Mapping[str, Any], start: Iterable[str] = ()) -> dict[str, Any]:
    """Returns env kwargs with the FLAGS of ``kwargs`` folded into ``observe`` (a flag that is
    true adds its entry, false removes it, null leaves it), over ``kwargs``' own ``observe``,
    else ``start`` (the observe list the kwargs override)."""
    if not any(flag in kwargs for flag in FLAGS):
        return dict(kwargs)
    out = {k: v for k, v in kwargs.items() if k not in FLAGS}
    observe = list(out.get("observe", start) or ())
    for flag, name in FLAGS.items():
        value = kwargs.get(flag)
        if value is not None:
            value = boolean(flag, value)
        if value is True and name not in observe:
            observe.append(name)
        elif value is False and name in observe:
            observe.remove(name)
    out["observe"] = [name for name in OBSERVABLE if name in observe] + [
        name
        for name in observe
        if name not in OBSERVABLE  # refused by EnvConfig, named
    ]
    return out


def as_flags(record: Mapping[str, Any]) -> dict[str, Any]:
    """Returns an env config record with ``observe`` as the FLAGS it replaced: the form the
    env ids' and shipped models' pinned contracts were hashed in (tendon2r_gym.envs.contract),
    so that a record of the same behaviour keeps its hash."""
    out = {k: v for k, v in record.items() if k != "observe"}
    observe = record.get("observe", ())
    if later := [name for name in observe if name not in FLAGS.values()]:
        out["observe"] = later  # entries that came after the flags, as themselves
    return {**out, **{flag: name in observe for flag, name in FLAGS.items()}}


#: (name, size, unit) of each fixed entry, in order.  Two values each: joint A, then joint B
#: (or x, then z for the effector).
FIXED: tuple[tuple[str, int, str], ...] = (
    ("q", 2, "rad"),  # joint angles
    ("dq", 2, "rad/s"),  # joint velocities
    ("q_des", 2, "rad"),  # reference q_des(t)
    ("dq_des", 2, "rad/s"),  # reference velocity
    ("error", 2, "rad"),  # tracking error e = q_des - q
    ("error_log", 2, "1"),  # sign(e) log(1 + |e| / ERROR_LOG_SCALE): fine near 0, bounded far
    ("effector_pos", 2, "m"),  # effector x, z
    ("effector_vel", 2, "m/s"),  # effector velocity
)


#: The error below which ``error_log`` is linear (rad): 1e-4 rad = 0.006 deg.  Observation
#: normalizers (VecNormalize) keep running statistics from the start of training, when errors
#: are large; a raw error would then stay a tiny input long after the policy tracks to 0.1 deg.
ERROR_LOG_SCALE = 1e-4

#: The optional entry of ``error_rate`` (name, size, unit): sign(de) log(1 + |de| /
#: ERROR_RATE_LOG_SCALE) of the error's rate de = dq_des - dq, joint A then B.  The policy sees
#: dq and dq_des, but each normalized over speeds of rad/s: their difference near 0, a PD's
#: derivative term, is then a tiny input, as the raw error is.
ERROR_RATE = ("error_rate_log", 2, "1")
#: The error rate below which ``error_rate_log`` is linear (rad/s).  Its slope at 0, 1 /
#: scale, is the most gain a policy gets on a small error rate: at 1e-3 and 1e-2 rad/s plain
#: PPO tracked as precisely, but its tensions chattered at the control rate.
ERROR_RATE_LOG_SCALE = 0.1
#: With ``error_units: action``, error_log and error_rate_log log-scale normalized joint
#: torques (EnvConfig.needs.rate_to_action): those that give the joints, in one control step, the
#: speed that closes the error in one more, and those that cancel the error's rate; linear
#: below this fraction of a full action.
ACTION_LOG_SCALE = 0.1

#: The optional entry of ``feedforward`` (name, size, unit): rate_to_action (ctrl_dt
#: ddq_des(t + ctrl_dt / 2)), the normalized joint torques that give the joints the
#: reference's acceleration over the next control step, at the middle of it, through the
#: arm's inertia at the reference's bias (EnvConfig.needs.rate_to_action; no velocity terms).  A
#: user computes it from the arm and the reference as the env does; a policy that sees it
#: needs not learn each arm's inertia to lead the reference.
FEEDFORWARD = ("feedforward", 2, "1")

#: The optional entry of ``force_limit`` (name, size, unit): ln(F / 1 N) of the arm's
#: force limit F = max_tendon_force (``auto``: sized per arm and reference, the reset info's
#: ``max_tendon_force_N``).  A normalized action is a fraction of F (tension) or of a torque
#: proportional to F (joint torque): a policy that does not see F cannot keep its gain in
#: newtons when F changes from arm to arm.
FORCE_LIMIT = ("force_limit_log", 1, "ln N")
#: The optional entries (name, size, unit), in their order after the last action, each with
#: the ``observe`` name that adds it (the drawn arm's ``arm`` slice closes the observation).
OPTIONAL: dict[tuple[str, int, str], str] = {
    ERROR_RATE: "error_rate",
    FEEDFORWARD: "feedforward",
    FORCE_LIMIT: "force_limit",
}


def _slices() -> dict[str, slice]:
    out, start = {}, 0
    for name, size, _ in FIXED:
        out[name] = slice(start, start + size)
        start += size
    return out


#: Slices of the fixed entries, by name.
SLICES: dict[str, slice] = _slices()
N_FIXED = sum(size for _, size, _ in FIXED)
Q, DQ, Q_DES, DQ_DES, ERROR, ERROR_LOG = (
    SLICES[k] for k in ("q", "dq", "q_des", "dq_des", "error", "error_log")
)
EFFECTOR_POS, EFFECTOR_VEL = SLICES["effector_pos"], SLICES["effector_vel"]
#: The two runs of entries that the joint state sets (Formulas.state_entries): (q, dq) and
#: (error, error_log, effector_pos, effector_vel); q_des and dq_des lie between them.
STATE = (slice(Q.start, DQ.stop), slice(ERROR.start, EFFECTOR_VEL.stop))


def preview_slice(preview_steps: int) -> slice:
    """Returns the slice of the previewed references q_des(t + k preview_dt), k = 1..P, stored
    A then B for each k."""
    return slice(N_FIXED, N_FIXED + 2 * preview_steps)


def last_action_slice(preview_steps: int, n_actions: int) -> slice:
    """Returns the slice of the last command the env applied (the clipped action, through the
    env's action filter if it has one; the rest command after a reset)."""
    start = preview_slice(preview_steps).stop
    return slice(start, start + n_actions)


def optional_slice(name: str, preview_steps: int, n_actions: int, observed: Iterable[str]) -> slice:
    """Returns the slice of the optional entry ``name`` (one of OPTIONAL) in an observation
    that holds the optional entries ``observed``: after the last action, in OPTIONAL's order."""
    observed, start = set(observed), last_action_slice(preview_steps, n_actions).stop
    for entry, n, _ in OPTIONAL:
        if entry == name:
            return slice(start, start + n)
        start += n if entry in observed else 0
    raise ValueError(f"optional entry {name!r} is invalid; allowed: {[e for e, *_ in OPTIONAL]}")


def error_rate_slice(preview_steps: int, n_actions: int) -> slice:
    """Returns the slice of ``error_rate_log`` (observe ``error_rate``), after the last
    action."""
    return optional_slice(ERROR_RATE[0], preview_steps, n_actions, ())


def arm_slice(
    preview_steps: int, n_actions: int, n_arm: int, observed: Iterable[str] = ()
) -> slice:
    """Returns the slice of the arm's features (observe ``arm``): each drawn Mechanism field,
    normalized over its range to [-1, 1], in the order of the ranges (EnvConfig.feature_ranges).
    ``observed``: the optional entries the observation holds (names of OPTIONAL)."""
    observed = set(observed)
    start = last_action_slice(preview_steps, n_actions).stop
    start += sum(n for name, n, _ in OPTIONAL if name in observed)
    return slice(start, start + n_arm)


def size(preview_steps: int, n_actions: int, n_arm: int = 0, observed: Iterable[str] = ()) -> int:
    """Returns the length of the observation."""
    return arm_slice(preview_steps, n_actions, n_arm, observed).stop


def layout(
    preview_steps: int, n_actions: int, n_arm: int = 0, observed: Iterable[str] = ()
) -> list[list]:
    """Returns the layout as [[name, size], ...] in order (run.json records it, so that a
    trained model meets only the observation it was trained on)."""
    observed = set(observed)
    out = [[name, n] for name, n, _ in FIXED]
    out += [["preview", 2 * preview_steps], ["last_action", n_actions]]
    out += [[name, n] for name, n, _ in OPTIONAL if name in observed]
    return out + [["arm", n_arm]] if n_arm else out


def table(preview_steps_name: str = "P") -> str:
    """Returns the docstring table of the layout (the env's docstring embeds it)."""
    rows = ["| index | observation | unit |", "|-------|-------------|------|"]
    for name, _, unit in FIXED:
        s = SLICES[name]
        rows.append(f"| {s.start}-{s.stop - 1} | {name} | {unit} |")
    rows.append(
        f"| {N_FIXED} to {N_FIXED - 1} + 2{preview_steps_name} | q_des(t + k preview_dt), "
        "k = 1..P, A then B | rad |"
    )
    rows.append(
        f"| {N_FIXED} + 2{preview_steps_name}, n_actions entries | the last applied command "
        "(the rest command after a reset), one per action dimension | 1 |"
    )
    rows.append(
        "| (observe ``error_rate``) the next 2 | the tracking error's rate dq_des - dq, "
        f"log-scaled as error_log (``{ERROR_RATE[0]}``, linear below "
        f"{ERROR_RATE_LOG_SCALE:g} rad/s; with error_units 'action', as error_log of the "
        "normalized joint torques that cancel it in one control step, rate_to_action "
        f"(dq_des - dq), linear below {ACTION_LOG_SCALE:g}) | {ERROR_RATE[2]} |"
    )
    rows.append(
        "| (observe ``feedforward``) the next 2 | the normalized joint torques that give the "
        "reference's acceleration over the next control step, rate_to_action (ctrl_dt "
        f"ddq_des(t + ctrl_dt / 2)) (``{FEEDFORWARD[0]}``) | {FEEDFORWARD[2]} |"
    )
    rows.append(
        f"| (observe ``force_limit``) the next 1 | ln of the arm's force limit "
        f"max_tendon_force / 1 N (``{FORCE_LIMIT[0]}``) | {FORCE_LIMIT[2]} |"
    )
    rows.append(
        "| (observe ``arm``) the last entries | the arm's drawn fields, normalized over "
        "mechanism_ranges (or arm_feature_ranges) to [-1, 1] | 1 |"
    )
    return "\n".join(rows)


def arm_entry(field: str) -> str:
    """Returns the name of one drawn field's entry of the ``arm`` slice, ``arm.<field>``:
    hide_from_actor takes it as well as a layout name (e.g. the model's errors for the critic
    only, the fields a user knows for both)."""
    return f"arm.{field}"


def entry_names(layout_: list[list], arm_fields: Iterable[str] = ()) -> list[str]:
    """Returns the names that `layout_mask` can blank: the layout's names, then one
    `arm_entry` per drawn field (``arm_fields``, in order) if the layout has an arm."""
    names = [name for name, _ in layout_]
    return names + [arm_entry(f) for f in arm_fields] if "arm" in names else names


def layout_mask(
    layout_: list[list], hidden: Iterable[str], arm_fields: Iterable[str] = ()
) -> np.ndarray:
    """Returns a multiplier over an observation of ``layout_`` ([[name, size], ...], from
    EnvConfig.observation.layout()) that blanks the entries named in ``hidden``
    (`entry_names`; ``arm_fields`` names the arm slice's entries, in order)."""
    hidden, out = set(hidden), []
    for name, n in layout_:
        if name == "arm" and name not in hidden:
            out += [0.0 if arm_entry(f) in hidden else 1.0 for f in arm_fields]
        else:
            out += [0.0 if name in hidden else 1.0] * n
    if len(out) != sum(n for _, n in layout_):
        raise ValueError(f"arm_fields {list(arm_fields)} do not match the layout {layout_}")
    return np.array(out)


@dataclass(frozen=True)
class Layout:
    """One env's observation (EnvConfig.observation): its preview steps, its action count, the
    OPTIONAL entries it holds (by name) and the fields of its arm slice (none: no slice)."""

    preview_steps: int
    n_actions: int
    optional: tuple[str, ...] = ()
    arm_fields: tuple[str, ...] = ()

    @property
    def size(self) -> int:
        """Returns the observation's length."""
        return size(self.preview_steps, self.n_actions, len(self.arm_fields), self.optional)

    def layout(self) -> list[list]:
        """Returns the named layout, [[name, size], ...] (`layout`)."""
        return layout(self.preview_steps, self.n_actions, len(self.arm_fields), self.optional)

    def mask(self, hidden: Iterable[str]) -> np.ndarray:
        """Returns the 0/1 multiplier that blanks the entries named in ``hidden`` (layout
        names, or ``arm.<field>``: `layout_mask`)."""
        return layout_mask(self.layout(), hidden, self.arm_fields)

    def entries(self) -> list[str]:
        """Returns the names `mask` accepts."""
        return entry_names(self.layout(), self.arm_fields)
