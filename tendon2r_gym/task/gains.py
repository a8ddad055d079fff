"""PD and computed-torque gains: closed-loop quantities that carry over between arms.

The package's defaults are ``data/pd.yaml``; an experiment file may set its own with a
``pd_gains`` section (EnvConfig.pd_gains), for example the one ``tendon2r-tune-pd`` finds for
a lagging arm (tendon2r_gym.evaluation.tuning).

A real arm's motor lag and delays (tendon2r_gym.simulation.realism) take phase out of the loop:
about
w tau at the closed loop's frequency w, for a loop delay tau (`loop_delay`).  With
``max_delay_phase`` the bandwidth is held to that phase on each arm, w <= max_delay_phase /
tau: a stiff PD where the delays are short, a soft one where they are long, on the arm's known
delays (gain scheduling; ``tendon2r-tune-pd --scan max_delay_phase`` tunes the phase).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from tendon2r_gym.presets import PD_CONFIG, load_yaml
from tendon2r_gym.simulation.actuation import FORCE_DAMPING
from tendon2r_gym.simulation.mechanism import Mechanism
from tendon2r_gym.validation import check_keys, mapping, number


@dataclass(frozen=True)
class Gains:
    """Closed-loop gains that carry over between mechanisms and control rates.

    The joint error obeys e'' + 2 zeta w e' + w^2 e = 0 with w = 2 pi bandwidth_hz, because the
    feedback torque is scaled by the joint inertia M(q).  The bandwidth is capped at
    ``max_bandwidth_fraction`` of the control rate so that the sampled loop stays stable, and
    with ``max_delay_phase`` at that phase over the arm's loop delay (module docstring)."""

    bandwidth_hz: float = 30.0  # closed-loop natural frequency (Hz)
    damping_ratio: float = 1.0
    max_bandwidth_fraction: float = 0.05  # of the control rate 1 / ctrl_dt
    force_damping: float = FORCE_DAMPING  # damped-inverse regularization, relative to |J|
    max_delay_phase: float | None = None  # rad the loop delay may take at w; None: no cap

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            if f.name == "max_delay_phase" and self.max_delay_phase is None:
                continue
            value = number(f"pd_gains.{f.name}", getattr(self, f.name), 0.0, lo_open=True)
            object.__setattr__(self, f.name, value)

    @classmethod
    def from_dict(cls, values: Any, where: str = "pd_gains", base: Gains | None = None) -> Gains:
        """Reads ``{field: value}``: the given fields, each validated, over ``base`` (default:
        the package's gains, data/pd.yaml)."""
        values = mapping(where, values)
        check_keys(where, values, [f.name for f in dataclasses.fields(cls)])
        return dataclasses.replace(base or default_gains(), **values)

    def to_dict(self) -> dict[str, float]:
        """Returns the gains as plain YAML-friendly numbers."""
        return dataclasses.asdict(self)

    def natural_frequency(self, ctrl_dt: float, delay: float | np.ndarray = 0.0) -> Any:
        """Returns w (rad/s): the bandwidth, capped at the fraction of the control rate and,
        with max_delay_phase, at max_delay_phase / ``delay`` (the loop delay in s, one per arm:
        `loop_delay`; then one w per arm)."""
        w = 2 * math.pi * min(self.bandwidth_hz, self.max_bandwidth_fraction / ctrl_dt)
        if self.max_delay_phase is None:
            return w
        return np.minimum(w, self.max_delay_phase / np.asarray(delay, dtype=float))


def loop_delay(mechanism: Mechanism, observation_delay: float, ctrl_dt: float) -> float:
    """Returns the loop delay of an arm (s): the age of its measurements, the dead time and lag
    of its motors, and half a control period for the command's zero-order hold.  Always > 0."""
    return observation_delay + mechanism.motor_delay + mechanism.motor_tau + 0.5 * ctrl_dt


def true_phase_per_hz(mechanism: Mechanism, observation_delay: float, ctrl_dt: float) -> float:
    """Returns the phase (rad) that the arm's loop delay takes in its true closed loop per Hz
    of PD's bandwidth: 2 pi tau / sqrt(density_scale).  PD scales its torque by the nominal
    inertia, so on an arm density_scale times heavier its loop runs at w /
    sqrt(density_scale).  Only a simulation knows density_scale; a user's tuning on the real
    arm sees its effect."""
    tau = loop_delay(mechanism, observation_delay, ctrl_dt)
    return 2 * math.pi * tau / math.sqrt(mechanism.density_scale)


def tuned_bandwidth(
    mechanism: Mechanism, observation_delay: float, ctrl_dt: float, phase: float
) -> float:
    """Returns the bandwidth (Hz) at which the arm's true loop delay takes ``phase`` rad
    (`true_phase_per_hz`): a model of what ``tendon2r-tune-pd`` picks on the arm, used
    to draw the gains a residual trains on (MechanismRanges' tuned_phase), not to deploy
    them."""
    return phase / true_phase_per_hz(mechanism, observation_delay, ctrl_dt)


@lru_cache(maxsize=1)
def default_gains() -> Gains:
    """Returns the package's gains (data/pd.yaml)."""
    return Gains.from_dict(load_yaml(PD_CONFIG), str(PD_CONFIG), Gains())


def gains_of(value: Gains | Mapping[str, Any] | None) -> Gains:
    """Returns ``value`` as Gains (None: the package default)."""
    if value is None:
        return default_gains()
    return value if isinstance(value, Gains) else Gains.from_dict(value)
