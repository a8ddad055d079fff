"""The task: per-joint sinusoidal references q_des(t) = amp * sin(omega * t + phase) + bias.

``freq_hz`` (reports 001/002: sin(2 pi f t)) or ``omega_rad_s`` (the course text: sin(FREQ t)
with FREQ in rad/s) gives the frequency: exactly one of the two.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from tendon2r_gym.simulation.mechanism import Mechanism
from tendon2r_gym.validation import check_keys, invalid, mapping, pair

_FIELDS = ("amp_deg", "bias_deg", "freq_hz", "omega_rad_s", "phase_deg")


def _pair(name: str, value: Any, lo: float, hi: float) -> tuple[float, float]:
    return pair(f"reference.{name}", value, lo, hi)


@dataclass(frozen=True)
class Reference:
    """Sinusoidal joint references.  Angles in degrees, frequencies in Hz or rad/s."""

    amp_deg: tuple[float, float]
    bias_deg: tuple[float, float]
    freq_hz: tuple[float, float] | None = None
    omega_rad_s: tuple[float, float] | None = None
    phase_deg: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        if (self.freq_hz is None) == (self.omega_rad_s is None):
            raise invalid(
                "reference frequency",
                {"freq_hz": self.freq_hz, "omega_rad_s": self.omega_rad_s},
                "exactly one of freq_hz (Hz, sin(2 pi f t)) and omega_rad_s (rad/s, sin(w t))",
            )
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731
        set_("amp_deg", _pair("amp_deg", self.amp_deg, 0.0, 180.0))
        set_("bias_deg", _pair("bias_deg", self.bias_deg, -180.0, 180.0))
        set_("phase_deg", _pair("phase_deg", self.phase_deg, -360.0, 360.0))
        if self.freq_hz is not None:
            set_("freq_hz", _pair("freq_hz", self.freq_hz, 0.0, 100.0))
        else:
            set_("omega_rad_s", _pair("omega_rad_s", self.omega_rad_s, 0.0, 200 * math.pi))
        # Cached arrays for the hot path (rad, rad/s).
        set_("_amp", np.radians(self.amp_deg))
        set_("_bias", np.radians(self.bias_deg))
        set_("_phase", np.radians(self.phase_deg))
        set_("_omega", np.asarray(self.omega, dtype=float))

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> Reference:
        """Builds a Reference from a mapping with the same keys as the fields."""
        values = mapping("reference", values)
        check_keys("reference", values, _FIELDS)
        if "amp_deg" not in values or "bias_deg" not in values:
            raise ValueError(
                f"reference = {values!r} is invalid; allowed: a mapping with amp_deg, bias_deg "
                "and one of freq_hz / omega_rad_s (an experiment file needs a reference section)"
            )
        return cls(**values)

    def to_dict(self) -> dict[str, list[float]]:
        return {k: list(getattr(self, k)) for k in _FIELDS if getattr(self, k) is not None}

    # -- the reference in SI units (cached arrays, joint A then B; do not modify) ------------------
    @property
    def amp_rad(self) -> np.ndarray:
        """Returns the amplitudes (rad)."""
        return self._amp

    @property
    def bias_rad(self) -> np.ndarray:
        """Returns the biases (rad)."""
        return self._bias

    @property
    def phase_rad(self) -> np.ndarray:
        """Returns the phases (rad)."""
        return self._phase

    @property
    def omega_array(self) -> np.ndarray:
        """Returns the angular frequencies (rad/s) as an array."""
        return self._omega

    @property
    def omega(self) -> tuple[float, float]:
        """Returns the angular frequency of each joint (rad/s)."""
        if self.omega_rad_s is not None:
            return self.omega_rad_s
        return (2 * math.pi * self.freq_hz[0], 2 * math.pi * self.freq_hz[1])

    def q(self, t: float | np.ndarray) -> np.ndarray:
        """Returns q_des(t) (rad), shape (..., 2)."""
        arg = np.multiply.outer(t, self._omega) + self._phase
        return self._amp * np.sin(arg) + self._bias

    def qdot(self, t: float | np.ndarray) -> np.ndarray:
        """Returns dq_des/dt (rad/s), shape (..., 2)."""
        arg = np.multiply.outer(t, self._omega) + self._phase
        return self._amp * self._omega * np.cos(arg)

    def qddot(self, t: float | np.ndarray) -> np.ndarray:
        """Returns d2q_des/dt2 (rad/s^2), shape (..., 2)."""
        arg = np.multiply.outer(t, self._omega) + self._phase
        return -self._amp * self._omega**2 * np.sin(arg)

    # -- workspace -----------------------------------------------------------------------------
    def workspace_violations(self, mech: Mechanism) -> list[str]:
        """Returns what is wrong with this reference on ``mech`` (empty if it fits).

        Checked conservatively over the whole box bias +- amp of both joints (any phase, any
        duration): each joint stays in the joint range, and joint B and the effector stay in
        front of the wall (x > 0)."""
        problems = []
        lo, hi = mech.joint_range_deg
        for j, name in enumerate("AB"):
            qmin = self.bias_deg[j] - self.amp_deg[j]
            qmax = self.bias_deg[j] + self.amp_deg[j]
            if qmin < lo or qmax > hi:
                problems.append(
                    f"joint {name} spans [{qmin:.2f}, {qmax:.2f}] deg, outside the joint range "
                    f"[{lo}, {hi}] deg"
                )
        grid = _box_grid(self.bias_deg, self.amp_deg)
        x_min = float(
            min(mech.forward_kinematics(grid)[:, 0].min(), mech.joint_b_position(grid)[:, 0].min())
        )
        if x_min <= 0.0:
            problems.append(f"the arm reaches x = {x_min:.4f} m, into the wall (x must stay > 0)")
        return problems

    def fit_to_workspace(self, mech: Mechanism, warn: bool = True) -> Reference:
        """Returns this reference with the amplitudes decreased until it fits ``mech`` (the
        course's rule: decrease the amplitude; the bias is left to the user)."""
        if not self.workspace_violations(mech):
            return self
        at_bias = dataclasses.replace(self, amp_deg=(0.0, 0.0))
        if at_bias.workspace_violations(mech):
            raise invalid(
                "reference.bias_deg",
                self.bias_deg,
                "a bias that fits the workspace at zero amplitude, but: "
                + "; ".join(at_bias.workspace_violations(mech)),
            )
        lo_k, hi_k = 0.0, 1.0
        for _ in range(40):
            k = 0.5 * (lo_k + hi_k)
            trial = dataclasses.replace(self, amp_deg=(k * self.amp_deg[0], k * self.amp_deg[1]))
            lo_k, hi_k = (lo_k, k) if trial.workspace_violations(mech) else (k, hi_k)
        fitted = dataclasses.replace(self, amp_deg=(lo_k * self.amp_deg[0], lo_k * self.amp_deg[1]))
        if warn:
            warnings.warn(
                f"fit_to_workspace: amplitudes scaled by {lo_k:.4f}, from {self.amp_deg} to "
                f"{tuple(round(a, 4) for a in fitted.amp_deg)} deg",
                stacklevel=2,
            )
        return fitted


def _box_grid(bias: tuple[float, float], amp: tuple[float, float], n: int = 33) -> np.ndarray:
    q1 = np.radians(np.linspace(bias[0] - amp[0], bias[0] + amp[0], n))
    q2 = np.radians(np.linspace(bias[1] - amp[1], bias[1] + amp[1], n))
    return np.stack(np.meshgrid(q1, q2, indexing="ij"), -1).reshape(-1, 2)


@dataclass(frozen=True)
class ReferenceRanges:
    """Ranges [[lo_A, hi_A], [lo_B, hi_B]] to draw a random reference from, each episode."""

    amp_deg: tuple[tuple[float, float], tuple[float, float]]
    freq_hz: tuple[tuple[float, float], tuple[float, float]]
    bias_deg: tuple[tuple[float, float], tuple[float, float]]
    phase_deg: tuple[tuple[float, float], tuple[float, float]] = ((0.0, 360.0), (0.0, 360.0))

    def __post_init__(self) -> None:
        limits = {  # the same bounds as a Reference's fields
            "amp_deg": (0.0, 180.0),
            "freq_hz": (0.0, 100.0),
            "bias_deg": (-180.0, 180.0),
            "phase_deg": (-360.0, 360.0),
        }
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            lo, hi = limits[f.name]
            field = f"reference_ranges.{f.name}"
            allowed = f"[[lo_A, hi_A], [lo_B, hi_B]] with {lo:g} <= lo <= hi <= {hi:g}"
            if isinstance(value, (str, bytes, Mapping)) or not hasattr(value, "__len__"):
                raise invalid(field, value, allowed)
            if len(value) != 2:
                raise invalid(field, value, allowed)
            rows = tuple(pair(field, row, lo, hi) for row in value)
            if any(r[0] > r[1] for r in rows):
                raise invalid(field, value, allowed)
            object.__setattr__(self, f.name, rows)

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> ReferenceRanges:
        values = mapping("reference_ranges", values)
        names = [f.name for f in dataclasses.fields(cls)]
        check_keys("reference_ranges", values, names)
        missing = [n for n in ("amp_deg", "freq_hz", "bias_deg") if n not in values]
        if missing:
            raise invalid("reference_ranges", values, f"a mapping that also has {missing}")
        return cls(**values)

    def to_dict(self) -> dict[str, list[list[float]]]:
        """Returns the ranges as plain YAML-friendly lists."""
        return {f.name: [list(r) for r in getattr(self, f.name)] for f in dataclasses.fields(self)}

    def corner_violations(self, mech: Mechanism) -> list[str]:
        """Returns why some draw could fail on ``mech`` (empty if none can): every bias in the
        ranges must fit the workspace at zero amplitude, since a draw's amplitudes are scaled
        down to fit but its bias is kept."""
        (b1lo, b1hi), (b2lo, b2hi) = self.bias_deg
        box = Reference(
            amp_deg=((b1hi - b1lo) / 2, (b2hi - b2lo) / 2),
            bias_deg=((b1hi + b1lo) / 2, (b2hi + b2lo) / 2),
            freq_hz=(0.0, 0.0),
        )
        return [f"bias_deg range {self.bias_deg}: {p}" for p in box.workspace_violations(mech)]

    def corners(self) -> list[Reference]:
        """Returns the references at the largest amplitudes and frequencies, at each corner of
        the bias ranges (where the force need peaks; phases do not matter to it)."""
        amp = (self.amp_deg[0][1], self.amp_deg[1][1])
        freq = (self.freq_hz[0][1], self.freq_hz[1][1])
        return [
            Reference(amp_deg=amp, freq_hz=freq, bias_deg=(b1, b2))
            for b1 in self.bias_deg[0]
            for b2 in self.bias_deg[1]
        ]

    def violations(self, ref: Reference) -> list[str]:
        """Returns the fields of ``ref`` outside the ranges (empty if it is inside; amplitudes
        only above them, since a drawn reference's amplitudes are fitted down)."""
        out = []
        values = {"amp_deg": ref.amp_deg, "bias_deg": ref.bias_deg}
        if ref.freq_hz is not None:
            values["freq_hz"] = ref.freq_hz
        else:
            values["freq_hz"] = tuple(w / (2 * math.pi) for w in ref.omega_rad_s)
        for name, pair_ in values.items():
            for joint, x, (lo, hi) in zip("AB", pair_, getattr(self, name), strict=True):
                lo = 0.0 if name == "amp_deg" else lo
                if not lo - 1e-9 <= x <= hi + 1e-9:
                    out.append(
                        f"reference.{name} of joint {joint} = {x:g} outside [{lo:g}, {hi:g}]"
                    )
        return out

    def sample(self, rng: np.random.Generator, mech: Mechanism) -> Reference:
        """Draws a reference (uniform in each range), fitted to the workspace of ``mech``."""
        draw = {
            f.name: tuple(float(rng.uniform(lo, hi)) for lo, hi in getattr(self, f.name))
            for f in dataclasses.fields(self)
        }
        return Reference(**draw).fit_to_workspace(mech, warn=False)


def checked_reference(
    ref: Reference,
    ranges: ReferenceRanges | None,
    mech: Mechanism,
    ctrl_dt: float,
    fit_to_workspace: bool = False,
) -> Reference:
    """Returns the episode's reference ``ref`` on the arm ``mech`` (its amplitudes scaled down
    into the workspace if ``fit_to_workspace``), or raises naming what is wrong: a reference
    or a corner of ``ranges`` that leaves the workspace, or a frequency with fewer than 10
    control steps per period."""
    if fit_to_workspace:
        ref = ref.fit_to_workspace(mech)
    elif problems := ref.workspace_violations(mech):
        raise invalid(
            "reference",
            ref.to_dict(),
            f"a reference inside the workspace, but it leaves it: {'; '.join(problems)} "
            "(or pass fit_to_workspace=True to scale the amplitudes down)",
        )
    nyquist = 0.5 / ctrl_dt
    freqs = [max(ref.omega) / (2 * math.pi)]
    if ranges is not None:
        freqs.append(max(hi for _, hi in ranges.freq_hz))
        if problems := ranges.corner_violations(mech):
            raise invalid(
                "reference_ranges.bias_deg",
                ranges.bias_deg,
                "biases that fit the workspace, but a draw could leave it: " + "; ".join(problems),
            )
    if max(freqs) * ctrl_dt > 0.1:
        raise invalid(
            "reference frequency (Hz)",
            max(freqs),
            f"<= {0.1 / ctrl_dt:g} Hz: at least 10 control steps per period, a fifth "
            f"of the Nyquist limit 0.5 / ctrl_dt = {nyquist:g} Hz (use a smaller ctrl_dt)",
        )
    return ref
