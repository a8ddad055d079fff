"""PD and computed-torque gains: closed-loop quantities that carry over between arms.

The package's defaults are ``data/pd.yaml``; an experiment file may set its own with a
``pd_gains`` section (EnvConfig.pd_gains), for example the one ``tendon2r-tune-pd`` finds for
a lagging arm (tendon2r_gym.tuning).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

from tendon2r_gym.actuation import FORCE_DAMPING
from tendon2r_gym.presets import PD_CONFIG, load_yaml
from tendon2r_gym.validation import check_keys, mapping, number


@dataclass(frozen=True)
class Gains:
    """Closed-loop gains that carry over between mechanisms and control rates.

    The joint error obeys e'' + 2 zeta w e' + w^2 e = 0 with w = 2 pi bandwidth_hz, because the
    feedback torque is scaled by the joint inertia M(q).  The bandwidth is capped at
    ``max_bandwidth_fraction`` of the control rate so that the sampled loop stays stable."""

    bandwidth_hz: float = 30.0  # closed-loop natural frequency (Hz)
    damping_ratio: float = 1.0
    max_bandwidth_fraction: float = 0.05  # of the control rate 1 / ctrl_dt
    force_damping: float = FORCE_DAMPING  # damped-inverse regularization, relative to |J|

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
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

    def natural_frequency(self, ctrl_dt: float) -> float:
        """Returns w (rad/s): the bandwidth, capped at the fraction of the control rate."""
        return 2 * math.pi * min(self.bandwidth_hz, self.max_bandwidth_fraction / ctrl_dt)


@lru_cache(maxsize=1)
def default_gains() -> Gains:
    """Returns the package's gains (data/pd.yaml)."""
    return Gains.from_dict(load_yaml(PD_CONFIG), str(PD_CONFIG), Gains())


def gains_of(value: Gains | Mapping[str, Any] | None) -> Gains:
    """Returns ``value`` as Gains (None: the package default)."""
    if value is None:
        return default_gains()
    return value if isinstance(value, Gains) else Gains.from_dict(value)
