"""Random course arms: the course's parameter ranges and a seeded sampler of valid arms.

The students' arms span pulley diameters of 0.011 to 0.047 m, links of 0.03 to 0.095 m,
amplitudes up to 53 deg, biases up to 44 deg and frequencies up to 3.9 Hz (NOTES.md).
:func:`draw_arm` draws uniformly in these ranges and keeps only arms that are valid:

- the mechanism passes ``Mechanism``'s checks (pulleys that fit on link c and clear the wall,
  a link radius below the pulleys);
- the reference's biases fit the workspace, and its amplitudes are fitted to it (the course's
  rule: decrease the amplitude);
- the force limit is ``auto``: sized from the arm's own inverse dynamics.

Each draw is an experiment file's content (``mechanism``, ``reference``,
``fit_to_workspace``), so ``tendon2r-benchmark --env-config`` runs it as a user's arm.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from tendon2r_gym.mechanism import Mechanism
from tendon2r_gym.reference import Reference
from tendon2r_gym.validation import invalid, pair

Range = tuple[float, float]


@dataclass(frozen=True)
class ArmRanges:
    """Uniform ranges [lo, hi] of a random arm (defaults: the course's)."""

    R1: Range = (0.011, 0.047)  # pulley diameter at joint A (m)
    R2: Range = (0.011, 0.047)  # pulley diameter at joint B (m)
    a: Range = (0.03, 0.095)  # m
    b: Range = (0.03, 0.095)
    c: Range = (0.03, 0.095)
    amp_deg: Range = (5.0, 53.0)  # per joint
    bias_deg: Range = (-44.0, 44.0)
    freq_hz: Range = (0.5, 3.9)

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            lo, hi = pair(f"arm_ranges.{f.name}", getattr(self, f.name))
            if lo > hi:
                raise invalid(f"arm_ranges.{f.name}", getattr(self, f.name), "[lo, hi], lo <= hi")
            object.__setattr__(self, f.name, (lo, hi))


COURSE = ArmRanges()
#: Draws tried before giving up (about 1 in 3 course draws is a valid arm).
MAX_TRIES = 1000


def draw_arm(
    rng: np.random.Generator,
    ranges: ArmRanges = COURSE,
    base: Mechanism | None = None,
) -> dict[str, Any]:
    """Returns a valid random arm as experiment-file content: ``mechanism`` (``base``'s fields,
    default Mechanism(), with the drawn geometry and ``max_tendon_force: auto``), ``reference``
    and ``fit_to_workspace: true``.  Raises if no valid arm is found in MAX_TRIES draws."""
    base = base or Mechanism()
    u = lambda r: float(rng.uniform(*r))  # noqa: E731
    for _ in range(MAX_TRIES):
        geometry = {k: round(u(getattr(ranges, k)), 4) for k in ("R1", "R2", "a", "b", "c")}
        try:
            mech = base.replace(**geometry, max_tendon_force="auto")
        except ValueError:
            continue
        ref = Reference(
            amp_deg=(round(u(ranges.amp_deg), 2), round(u(ranges.amp_deg), 2)),
            bias_deg=(round(u(ranges.bias_deg), 2), round(u(ranges.bias_deg), 2)),
            freq_hz=(round(u(ranges.freq_hz), 2), round(u(ranges.freq_hz), 2)),
        )
        try:
            ref.fit_to_workspace(mech, warn=False)  # its bias must fit at zero amplitude
        except ValueError:
            continue
        return {
            "mechanism": mech.to_dict(),
            "reference": ref.to_dict(),
            "fit_to_workspace": True,
        }
    raise invalid("arm_ranges", ranges, f"ranges where a valid arm is found in {MAX_TRIES} draws")


def draw_arms(seed: int, n: int, ranges: ArmRanges = COURSE, **kw: Any) -> list[dict[str, Any]]:
    """Returns ``n`` valid random arms drawn with ``seed`` (the same seed, the same arms)."""
    rng = np.random.default_rng(seed)
    return [draw_arm(rng, ranges, **kw) for _ in range(n)]
