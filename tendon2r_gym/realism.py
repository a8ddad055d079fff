"""Real tendons and motors: the state they start from and the tension they carry.

The realism fields of :class:`~tendon2r_gym.mechanism.Mechanism` (all off by default; then the
model is the ideal one, bit for bit) and what each one means physically:

- ``tendon_elasticity``: series stiffness EA / L of each cable (N/m); a stretched cable pulls,
  a slack pull-only one does not push, and each motor drives a spool of mass ``motor_mass``.
  Typical: 1e3 to 2e4 (a 0.3-0.5 mm braided line, 0.3 m long).
- ``motor_mass``: motor and spool inertia felt along the cable, J / r_spool^2 (kg).  Typical:
  0.01 to 0.2 for a low-geared motor.
- ``tendon_friction``: dry friction of a cable sliding on its pulleys (N).  Typical: 1 to 5% of
  the working tension.
- ``motor_tau``: first-order lag of the motor force (s): current loop and driver.  Typical: 1
  to 10 ms.
- ``motor_delay``: dead time between a command and the motor (s), whole control steps: bus and
  driver.  Typical: 1 to 5 ms.

What the controller measures is set in the env config: ``observation_noise`` (Gaussian std on
each joint's angle, rad, and speed, rad/s; typical encoders 1e-4 rad, speeds from differences
1e-2 rad/s) and ``observation_delay`` (s, whole control steps; typical 1 to 5 ms):
:class:`Sensors`.  The reward and ``info`` stay on the true state.

:class:`Drive` puts an arm at rest for a reset: every spool where its cable holds the rest
tension (:attr:`Mechanism.rest_tension`), every motor's lag at the rest command, so that an
episode starts as it would on the bench.  Both envs use it (the vector env copies the state of
its scratch MjData into the batch).  :class:`CommandDelay` holds the commands back: the envs
apply it, not MuJoCo (MuJoCo 4's actuator ``delay`` mixes samples across RK4's stages:
measured, a 2 ms delay moved the trajectory by neither 1 nor 2 steps).
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

from tendon2r_gym.actuation import MomentArms
from tendon2r_gym.mechanism import Mechanism
from tendon2r_gym.model import spool_name


class Drive:
    """The motors and cables of one compiled model (see the module docstring)."""

    def __init__(self, model: mujoco.MjModel, mech: Mechanism) -> None:
        self.model, self.mech = model, mech
        n = self.n = mech.n_tendons
        self.ctrl = mech.rest_ctrl
        #: Whether a reset has more to set than (q, dq): spools or lags.
        self.has_state = mech.elastic or mech.motor_tau > 0
        spools = [model.joint(spool_name(i)) for i in range(n)] if mech.elastic else []
        self.spool_qpos = np.array([j.qposadr[0] for j in spools], dtype=int)
        self.spool_dof = np.array([j.dofadr[0] for j in spools], dtype=int)
        self.stretch = mech.rest_tension / mech.tendon_elasticity if mech.elastic else 0.0
        spring = model.tendon_lengthspring[:n]
        self.slack_length, self.rest_length = spring[:, 0].copy(), spring[:, 1].copy()

    def settle(self, data: mujoco.MjData, q: np.ndarray, dq: np.ndarray) -> None:
        """Sets a freshly reset ``data`` (time 0) to the joint state (q, dq), every cable at its
        rest tension and still, every lag at the rest command; then runs mj_forward."""
        m, mech = self.model, self.mech
        data.qpos[:2], data.qvel[:2] = q, dq
        if mech.elastic:
            spools, dofs = self.spool_qpos, self.spool_dof
            data.qpos[spools] = 0.0
            mujoco.mj_fwdPosition(m, data)
            # The spool-anchor segment shortens as the spool moves to the wall (+x), so the
            # length is L(q, 0) - s, and the cable is still when ds/dt = J_arm dq.
            length = data.ten_length[: self.n].copy()
            data.qpos[spools] = length - self.rest_length - self.stretch
            J = MomentArms(m, data).dense()  # the motors' tendons over the arm's joints
            data.qvel[dofs] = J @ np.asarray(dq, dtype=float)
        data.ctrl[:] = self.ctrl
        if mech.motor_tau > 0:
            data.act[:] = self.ctrl
        mujoco.mj_forward(m, data)

    @property
    def cable(self) -> tuple[Any, ...]:
        """Returns (stiffness, damping, rest length, slack length) of the cables: what
        :func:`cable_tensions` needs (the vector env stacks one row per arm)."""
        mech = self.mech
        return mech.tendon_elasticity, mech.tendon_damping, self.rest_length, self.slack_length

    def cable_tensions(self, length: np.ndarray, velocity: np.ndarray) -> np.ndarray:
        """Returns :func:`cable_tensions` of this model's cables."""
        return cable_tensions(length, velocity, *self.cable)


def cable_tensions(
    length: np.ndarray, velocity: np.ndarray, k: Any, c: Any, rest: np.ndarray, slack: np.ndarray
) -> np.ndarray:
    """Returns each elastic cable's tension (N, positive pulling) from the tendon lengths and
    speeds (the first n_tendons entries of ``ten_length`` and ``ten_velocity``, one row or N
    rows): stiffness k times the stretch past the rest length (below the slack length for
    push-pull cables, which push), plus the cable's damping c times its speed."""
    stretch = np.maximum(length - rest, 0.0)
    stretch += np.minimum(length - slack, 0.0)
    return k * stretch + c * velocity


class CommandDelay:
    """Holds each motor command back by ``steps`` control steps, for N arms that step together:
    a ring of the last ``steps`` commands, each arm's filled with its rest command (``rest``:
    one for all, or one per arm) at its reset."""

    def __init__(self, steps: int, n_arms: int, n_motors: int, rest: Any) -> None:
        #: The rest command of each arm's motors (n_arms, n_motors); random arms update it.
        self.rest = np.broadcast_to(np.reshape(rest, (-1, 1)), (n_arms, n_motors)).copy()
        self._ring = np.repeat(self.rest[None], steps, axis=0)
        self._i = 0

    def reset(self, arms: np.ndarray | slice) -> None:
        """Fills the ring of ``arms`` with their rest command (the motors were at rest)."""
        self._ring[:, arms] = self.rest[arms]

    def __call__(self, ctrl: np.ndarray, arms: np.ndarray | slice = slice(None)) -> np.ndarray:
        """Returns the commands (n_arms, n_motors) sent ``steps`` steps ago, and stores
        ``ctrl`` of the arms that step now (the others keep their ring)."""
        out = self._ring[self._i].copy()
        self._ring[self._i, arms] = ctrl[arms]
        self._i = (self._i + 1) % len(self._ring)
        return out


class Sensors:
    """What the controller measures of N arms that step together: (q_A, q_B, dq_A, dq_B),
    ``steps`` control steps late, with Gaussian noise of std ``noise`` = (rad, rad/s).  Each
    measurement draws its noise once, from its arm's generator, when it is taken (every
    step, and at a reset, which fills the arm's ring), so that reading it draws nothing."""

    def __init__(self, steps: int, n_arms: int, noise: tuple[float, float]) -> None:
        self.std = np.repeat(np.asarray(noise, dtype=float), 2)  # q_A, q_B, dq_A, dq_B
        self._noisy = bool(np.any(self.std > 0))
        self._ring = np.zeros((steps + 1, n_arms, 4))
        self._i = 0

    def _measure(self, state: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        return state + rng.standard_normal(4) * self.std if self._noisy else state

    def reset(self, arm: int, state: np.ndarray, rng: np.random.Generator) -> None:
        """Arm ``arm`` starts at ``state`` (4,): every slot of its ring holds one measurement."""
        self._ring[:, arm] = self._measure(state, rng)

    def store(self, states: np.ndarray, rngs: list[np.random.Generator], arms) -> None:
        """Measures the arms ``arms`` (indices) in ``states`` (n_arms, 4), then advances."""
        slot = self._ring[self._i]
        for i in arms:
            slot[i] = self._measure(states[i], rngs[i])
        self._i = (self._i + 1) % len(self._ring)

    def read(self) -> np.ndarray:
        """Returns the measurements (n_arms, 4) the controller has now: the oldest kept."""
        return self._ring[self._i]


#: Ranges of the seeded perturbed arms (the realism section of ``make benchmark``) and of the
#: randomized training (``mechanism_ranges: real_arm``, tendon2r_gym.arms.MechanismRanges, the
#: ``mechanism`` part): each value drawn uniformly and independently; delays are rounded to
#: whole control steps.  They span the catalog-typical values of the ``real_arm`` preset from
#: about half to twice; friction and lag never vanish (a real cable rubs, a real driver lags,
#: and a zero would change the model's layout).
PERTURBATIONS: dict[str, Any] = {
    "mechanism": {
        "tendon_elasticity": (2500.0, 8000.0),  # N/m
        "tendon_damping": (1.0, 4.0),  # N s/m
        "motor_mass": (0.002, 0.004),  # kg
        "tendon_friction": (0.001, 0.01),  # N
        "motor_tau": (0.0005, 0.004),  # s
    },
    "motor_delay": (0.0, 0.002),  # s
    "observation_noise": ((0.0, 2e-4), (0.0, 0.1)),  # rad, rad/s
    "observation_delay": (0.0, 0.002),  # s
}


def perturbed_arms(preset: str, n: int, seed: int, ctrl_dt: float) -> list[dict[str, Any]]:
    """Returns the env kwargs of ``n`` arms: ``preset`` (control period ``ctrl_dt``, to which
    delays are rounded) with every PERTURBATIONS value drawn from
    ``np.random.default_rng(seed)``, in PERTURBATIONS' order."""
    rng = np.random.default_rng(seed)
    draw = lambda lo_hi: float(rng.uniform(*lo_hi))  # noqa: E731
    steps = lambda s: round(s / ctrl_dt) * ctrl_dt  # noqa: E731
    arms = []
    for _ in range(n):
        mech = {k: draw(r) for k, r in PERTURBATIONS["mechanism"].items()}
        mech["motor_delay"] = steps(draw(PERTURBATIONS["motor_delay"]))
        arms.append(
            {
                "preset": preset,
                "mechanism": mech,
                "observation_noise": [draw(r) for r in PERTURBATIONS["observation_noise"]],
                "observation_delay": steps(draw(PERTURBATIONS["observation_delay"])),
            }
        )
    return arms
