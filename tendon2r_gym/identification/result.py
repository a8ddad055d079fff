"""What identification finds: each field's estimate, and the identified arm's changes to the
nominal experiment file (tendon2r_gym.identification.identify makes them)."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any

from tendon2r_gym.identification.fit import PIECE_S

#: The fields a fit can change: unit, and what a user cannot measure with a ruler.
FIELDS: dict[str, tuple[str, str]] = {
    "tendon_elasticity": ("N/m", "cable stiffness EA / L"),
    "tendon_damping": ("N s/m", "cable damping"),
    "tendon_friction": ("N", "cable friction on the pulleys"),
    "motor_tau": ("s", "motor lag"),
    "motor_mass": ("kg", "motor and spool mass along the cable"),
    "density_scale": ("1", "link mass scale"),
    "extra_joint_damping": ("N m s/rad", "extra joint damping"),
    "motor_delay": ("s", "motor delay"),
    "observation_delay": ("s", "sensor delay"),
}


@dataclass
class Estimate:
    """One field's result (SI units)."""

    field: str
    nominal: float
    value: float
    half_width: float  # of the 95% interval
    identified: bool
    why: str = ""  # why it is not identified
    #: The identified arm takes the value: identified, or its interval excludes the nominal
    #: value (then the fit is the better guess, though too uncertain to identify the field).
    used: bool = False

    @property
    def unit(self) -> str:
        return FIELDS[self.field][0]

    @property
    def interval(self) -> tuple[float, float]:
        return self.value - self.half_width, self.value + self.half_width


@dataclass
class Identification:
    """What tendon2r_gym.identification.identify.identify found, and the identified arm's
    changes to the nominal experiment file."""

    estimates: list[Estimate]
    loop_delay_s: float  # the best-fitting one, which the fields are fitted at
    delay_identified: bool
    #: What the identified arm changes in the nominal experiment file: ``mechanism`` fields
    #: and ``observation_delay``.
    changes: dict[str, Any]
    skipped: dict[str, str]  # asked-for fields the nominal arm's model cannot vary, and why
    #: The sensors' noise std (rad, rad/s) at the fit: of the angles from the residual, of
    #: the speeds from the measured ones (None if the recordings hold none).
    noise: tuple[float, float | None]
    pieces: int
    residual_rms_rad: tuple[float, float]  # before and after the fit (projected)
    seconds: float
    sources: list[str] = field(default_factory=list)
    #: The loop delays (s) not told apart from the best one, (least, most).
    delay_range_s: tuple[float, float] = (0.0, 0.0)
    #: Each loop delay not told apart (s): the fields' fit there, on the subset's pieces.
    delay_fits: dict[float, dict[str, float]] = field(default_factory=dict)
    #: The folds' residual (RMS, rad) on the pieces they were fitted on, and on those they
    #: held out (tendon2r_gym.identification.holdout); None without a continuous field.
    holdout_rms_rad: tuple[float, float] | None = None
    extras: dict[str, Any] = field(default_factory=dict, repr=False)  # for the report

    def experiment(self, nominal: str | os.PathLike) -> dict[str, Any]:
        """Returns the identified arm's experiment file: the nominal one (a preset name or
        file) with `changes`."""
        from tendon2r_gym.presets import load_yaml, merge_env_kwargs, preset_path

        return merge_env_kwargs(load_yaml(preset_path(nominal)), self.changes)

    def lines(self) -> list[str]:
        """The printed table."""
        out = [f"{'field':<20} {'nominal':>11} {'identified':>11} {'95% interval':>27}  unit"]
        for e in self.estimates:
            lo, hi = e.interval
            shown, ci = f"{e.value:11.4g}", f"[{lo:.4g}, {hi:.4g}]"
            if not e.identified:
                shown = f"{'-':>11}"
                ci = f"not identifiable ({e.why})"
                if e.used:  # too wide, yet it rules the nominal value out
                    shown, ci = f"{e.value:11.4g}", f"[{lo:.4g}, {hi:.4g}] too wide, nominal out"
            out.append(f"{e.field:<20} {e.nominal:11.4g} {shown} {ci:>27}  {e.unit}")
        angle, speed = self.noise
        shown = "not recorded" if speed is None else f"{speed:.3g} rad/s"
        out.append(f"{'sensor noise':<20} {'':>11} {angle:11.3g} rad (angles); speeds: {shown}")
        lo, hi = (v * 1e3 for v in self.delay_range_s)
        status = "identified" if self.delay_identified else f"not told from {lo:g}-{hi:g} ms"
        out.append(
            f"{'loop delay':<20} {'':>11} {self.loop_delay_s * 1e3:11.4g} {status:>27}  ms "
            "(motor_delay + observation_delay: only their sum shows)"
        )
        if len(self.delay_fits) > 1:
            for delay, fits in self.delay_fits.items():
                shown = ", ".join(f"{k} {v:.4g}" for k, v in fits.items())
                out.append(f"{'  at ' + format(delay * 1e3, 'g') + ' ms':<20} {shown}")
        if self.holdout_rms_rad is not None:
            inside, held = self.holdout_rms_rad
            out.append(
                f"{'held-out pieces':<20} residual {held:.3g} rad RMS, in-sample {inside:.3g} "
                f"({held / max(inside, 1e-300):.2g}x)"
            )
        for name, why in self.skipped.items():
            out.append(f"{name:<20} skipped: {why}")
        before, after = self.residual_rms_rad
        out.append(
            f"{self.pieces} pieces of {PIECE_S} s; angle residual {before:.3g} -> {after:.3g} rad "
            f"RMS; {self.seconds:.1f} s"
        )
        return out
