"""Real tendons and motors: the state they start from and the tension they carry.

The realism fields of `Mechanism` (all off by default;
then the
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

The nominal model's errors, which the controllers' model (`Mechanism.ideal`) leaves out
while the simulation has them: ``density_scale`` (the real links' and pulleys' density over
``density``: every mass and inertia scales with it; printed parts' infill, screws and glue
put a CAD mass off by tens of percent) and ``extra_joint_damping`` (N m s/rad, both joints:
bearings and cable bending; typical 1e-6 to 1e-5 for miniature ball bearings).

What the controller measures is set in the env config: ``observation_noise`` (Gaussian std on
each joint's angle, rad, and speed, rad/s; typical encoders 1e-4 rad, speeds from differences
1e-2 rad/s) and ``observation_delay`` (s, whole control steps; typical 1 to 5 ms):
`Sensors`.  The reward and ``info`` stay on the true state.

`Drive` puts an arm at rest for a reset: every spool where its cable holds the rest
tension (`Mechanism.rest_tension`), every motor's lag at the rest command, so that an
episode starts as it would on the bench.  Both envs use it (the vector env copies the state of
its scratch MjData into the batch).  `CommandDelay` holds the commands back: the envs
apply it, not MuJoCo (MuJoCo 4's actuator ``delay`` mixes samples across RK4's stages:
measured, a 2 ms delay moved the trajectory by neither 1 nor 2 steps).
"""

from __future__ import annotations

from collections import deque
from typing import Any

import mujoco
import numpy as np

from tendon2r_gym.simulation.actuation import MomentArms
from tendon2r_gym.simulation.mechanism import Mechanism
from tendon2r_gym.simulation.model import spool_name
from tendon2r_gym.validation import invalid


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
        #: The spools' degrees of freedom, contiguous (the model adds them after the arm's).
        self.spools = slice(2, 2 + n) if mech.elastic else slice(0, 0)
        if mech.elastic and self.spool_dof.tolist() != list(range(2, 2 + n)):
            raise RuntimeError(f"spool dofs {self.spool_dof.tolist()} are not 2..{n + 1}")

    def settle(
        self, data: mujoco.MjData, q: np.ndarray, dq: np.ndarray, tension: Any = None
    ) -> None:
        """Sets a freshly reset ``data`` (time 0) to the joint state (q, dq), every cable at its
        rest tension (or at ``tension``, N, one per cable) and still, every lag at the rest
        command; then runs mj_forward."""
        m, mech = self.model, self.mech
        data.qpos[:2], data.qvel[:2] = q, dq
        if mech.elastic:
            spools, dofs = self.spool_qpos, self.spool_dof
            data.qpos[spools] = 0.0
            mujoco.mj_fwdPosition(m, data)
            # The spool-anchor segment shortens as the spool moves to the wall (+x), so the
            # length is L(q, 0) - s, and the cable is still when ds/dt = J_arm dq.
            length = data.ten_length[: self.n].copy()
            stretch = self.stretch
            if tension is not None:  # a pull-only cable carries no push
                tension = np.asarray(tension, dtype=float)
                stretch = (np.maximum(tension, 0.0) if mech.pull_only else tension) / (
                    mech.tendon_elasticity
                )
            data.qpos[spools] = length - self.rest_length - stretch
            J = MomentArms(m, data).dense()  # the motors' tendons over the arm's joints
            data.qvel[dofs] = J @ np.asarray(dq, dtype=float)
        data.ctrl[:] = self.ctrl
        if mech.motor_tau > 0:
            data.act[:] = self.ctrl
        mujoco.mj_forward(m, data)

    @property
    def cable(self) -> tuple[Any, ...]:
        """Returns (stiffness, damping, rest length, slack length) of the cables: the
        arguments of `cable_tensions` after length and speed."""
        mech = self.mech
        return mech.tendon_elasticity, mech.tendon_damping, self.rest_length, self.slack_length

    def tension_view(self, qfrc_passive: np.ndarray) -> np.ndarray:
        """Returns a view of the cables' tensions (N, positive pulling) in ``qfrc_passive``
        (one MjData's, or the batch's N rows): the passive force of each cable on its spool's
        slide, which is its stretch's spring and damping force (`cable_tensions`: the
        same to within rounding, tests/test_realism.py).  Only for elastic cables."""
        return qfrc_passive[..., self.spools]


def cable_tensions(
    length: np.ndarray, velocity: np.ndarray, k: Any, c: Any, rest: np.ndarray, slack: np.ndarray
) -> np.ndarray:
    """Returns each elastic cable's tension (N, positive pulling) from the tendon lengths and
    speeds (the first n_tendons entries of ``ten_length`` and ``ten_velocity``, one row or N
    rows): stiffness k times the stretch past the rest length (below the slack length for
    push-pull cables, which push), plus the cable's damping c times its speed: the model of
    the cable that the compiled tendon spring implements.  The envs read MuJoCo's force
    (Drive.tension_view); the tests check the two against each other."""
    stretch = np.maximum(length - rest, 0.0) + np.minimum(length - slack, 0.0)
    return k * stretch + c * velocity


class LagRing:
    """The last capacity + 1 rows of N arms that step together, each arm read back its own
    number of steps late (0 to ``capacity``): what CommandDelay and Sensors hold.  One arm
    (the single env) steps through `push_one` instead: a deque of Python rows with the
    same lag, a fraction of the cost of a numpy row write."""

    def __init__(self, capacity: int, n_arms: int, width: int, what: str) -> None:
        self.steps = np.full(n_arms, capacity, dtype=np.int64)
        self.rows = np.zeros((capacity + 1, n_arms, width))
        self._what, self._cols, self._i = what, np.arange(n_arms), 0
        self._lag: int | None = capacity  # every arm's steps, when they are all equal
        self._line: deque[list[float]] = deque()  # one arm: its last ``steps`` rows

    def set_steps(self, arm: int, steps: int) -> None:
        """Arm ``arm`` is read ``steps`` steps late (at most the capacity)."""
        if not 0 <= steps < len(self.rows):
            raise invalid(f"{self._what} (control steps)", steps, f"0 to {len(self.rows) - 1}")
        self.steps[arm] = steps
        first = int(self.steps[0])
        self._lag = first if bool(np.all(self.steps == first)) else None

    def fill(self, arms: Any, row: Any) -> None:
        """Every slot of ``arms`` (indices or a slice) holds ``row``: their state at a reset."""
        self.rows[:, arms] = row
        if self.rows.shape[1] == 1:
            self._line = deque([self.rows[0, 0].tolist()] * int(self.steps[0]))

    def push_one(self, row: list[float]) -> list[float]:
        """One arm, after `fill`: stores ``row`` and returns the row of ``steps`` steps
        ago (``row`` itself for 0), as `lagged` would."""
        line = self._line
        if not line:
            return row
        line.append(row)
        return line.popleft()

    @property
    def slot(self) -> np.ndarray:
        """Returns the row (n_arms, width) this step writes."""
        return self.rows[self._i]

    def advance(self) -> None:
        """Closes the step: the slot just written becomes the newest row."""
        self._i = (self._i + 1) % len(self.rows)

    def lagged(self) -> np.ndarray:
        """Returns each arm's row of its ``steps`` steps before the newest (a view when every
        arm's steps agree: one slot for all)."""
        n = len(self.rows)
        if self._lag is not None:
            return self.rows[(self._i - 1 - self._lag) % n]
        return self.rows[(self._i - 1 - self.steps) % n, self._cols]


class CommandDelay:
    """Holds each motor command back by its arm's number of control steps (0 to
    ``capacity``), for N arms that step together (a LagRing), each arm's ring filled with its
    rest command at its reset.  Random arms set each arm's steps and rest command
    (`set_arm`)."""

    def __init__(self, capacity: int, n_arms: int, n_motors: int) -> None:
        self.ring = LagRing(capacity, n_arms, n_motors, "motor delay")
        #: The rest command of each arm's motors (n_arms, n_motors).
        self.rest = np.zeros((n_arms, n_motors))

    def set_arm(self, arm: int, steps: int, rest: Any) -> None:
        """Arm ``arm`` holds its commands ``steps`` steps (at most the capacity); ``rest`` is
        the command of its motors at rest."""
        self.ring.set_steps(arm, steps)
        self.rest[arm] = rest

    def reset(self, arms: np.ndarray | slice) -> None:
        """Fills the ring of ``arms`` with their rest command (the motors were at rest)."""
        self.ring.fill(arms, self.rest[arms])

    def __call__(self, ctrl: np.ndarray, arms: np.ndarray | slice = slice(None)) -> np.ndarray:
        """Stores ``ctrl`` (n_arms, n_motors) of the arms that step now (the others keep their
        ring) and returns each arm's command of its ``steps`` steps ago."""
        self.ring.slot[arms] = ctrl[arms]
        self.ring.advance()
        return self.ring.lagged().copy()

    def one(self, ctrl: list[float]) -> list[float]:
        """The single env's call (one arm, ``ctrl`` its n_motors floats, after `reset`):
        returns the command of its ``steps`` steps ago, the same as `__call__`'s."""
        return self.ring.push_one(ctrl)


#: Noise rows (q_A, q_B, dq_A, dq_B) that Sensors draws from an arm's generator at once: one
#: call per block instead of one per step.
NOISE_BLOCK = 256


class Sensors:
    """What the controller measures of N arms that step together: (q_A, q_B, dq_A, dq_B),
    each arm's number of control steps late (0 to ``capacity``, a LagRing), with Gaussian
    noise of its std (rad, rad/s).  Each arm's noise comes from its own generator in blocks
    of NOISE_BLOCK standard normal rows, drawn when the arm's block runs out; a reset
    discards the block, so that an episode depends on its own seed only.  Each measurement
    is taken when the state is (every step, and at a reset, which fills the arm's ring), so
    that reading draws nothing; a ``noisy`` env draws for every arm, even one of zero std,
    so that every arm's generator advances alike.  Random arms set each arm's delay and noise
    (`set_arm`).  The measurement is x + noise * std in Python floats, one arm at a
    time, in both envs (the same bits)."""

    def __init__(self, capacity: int, n_arms: int, noisy: bool) -> None:
        self.ring = LagRing(capacity, n_arms, 4, "observation delay")
        self._std = [[0.0] * 4 for _ in range(n_arms)]  # q_A, q_B, dq_A, dq_B, per arm
        self._blocks: list[list[list[float]]] = [[] for _ in range(n_arms)]
        self._noisy = noisy

    def set_arm(self, arm: int, steps: int, noise: tuple[float, float]) -> None:
        """Arm ``arm``'s measurements are ``steps`` control steps late (at most the capacity),
        with noise std ``noise`` = (rad, rad/s)."""
        self.ring.set_steps(arm, steps)
        angle, speed = float(noise[0]), float(noise[1])
        self._std[arm] = [angle, angle, speed, speed]

    def _measure(self, arm: int, state: list[float], rng: np.random.Generator) -> list[float]:
        """Returns the measurement of arm ``arm``'s true ``state`` (4 floats)."""
        if not self._noisy:
            return state
        block = self._blocks[arm]
        if not block:  # noise * std (the same bits as in floats), popped in drawing order
            rows = rng.standard_normal((NOISE_BLOCK, 4)) * np.array(self._std[arm])
            block.extend(reversed(rows.tolist()))
        n1, n2, n3, n4 = block.pop()
        x1, x2, x3, x4 = state
        return [x1 + n1, x2 + n2, x3 + n3, x4 + n4]

    def one(self, state: list[float], rng: np.random.Generator) -> list[float]:
        """The single env's step (arm 0, ``state`` its 4 floats, after `reset`):
        `store`, then `read`'s row, as floats."""
        return self.ring.push_one(self._measure(0, state, rng))

    def reset(self, arm: int, state: list[float], rng: np.random.Generator) -> None:
        """Arm ``arm`` starts at ``state`` (4 floats): its noise block is discarded, and
        every slot of its ring holds one measurement."""
        self._blocks[arm].clear()
        self.ring.fill(arm, self._measure(arm, state, rng))

    def store(self, states: np.ndarray, rngs: list[np.random.Generator], arms) -> None:
        """Measures the arms ``arms`` (indices) in ``states`` (n_arms, 4), then advances."""
        slot = self.ring.slot
        for i in arms:
            slot[i] = self._measure(i, states[i].tolist(), rngs[i])
        self.ring.advance()

    def read(self) -> np.ndarray:
        """Returns the measurements (n_arms, 4) the controller has now: each arm's of its
        ``steps`` steps ago (the last stored is one step back)."""
        return self.ring.lagged()


#: The Mechanism fields the envs apply between their steps, in Python, not in the compiled
#: model, each with what it does: tendon2r-export lists those a config sets beside its XML.
STEP_FIELDS = {"motor_delay": "each command held back whole control steps"}
#: Ranges of the seeded perturbed arms (the real-arm study, research.studies.realism) and of the
#: randomized training (``mechanism_ranges: real_arm``, tendon2r_gym.task.arms.MechanismRanges):
#: each value drawn uniformly and independently, in this order; delays are rounded to whole
#: control steps.  They span the catalog-typical values of the ``real_arm`` preset from about
#: half to twice (the model errors: a mass from half to twice the nominal one, and unmodeled
#: joint damping up to 1e-5 N m s/rad, a time constant of 0.2 s on the real_arm's joint B,
#: whose compiled inertia is 1.8e-6 kg m^2); friction and lag never vanish (a real cable rubs,
#: a real driver lags, and a zero would change the model's layout).
PERTURBATIONS: dict[str, tuple[float, float]] = {
    "tendon_elasticity": (2500.0, 8000.0),  # N/m
    "tendon_damping": (1.0, 4.0),  # N s/m
    "motor_mass": (0.002, 0.004),  # kg
    "tendon_friction": (0.001, 0.01),  # N
    "motor_tau": (0.0005, 0.004),  # s
    "motor_delay": (0.0, 0.002),  # s
    "observation_noise_angle": (0.0, 2e-4),  # rad
    "observation_noise_speed": (0.0, 0.1),  # rad/s
    "observation_delay": (0.0, 0.002),  # s
    "density_scale": (0.5, 2.0),  # the nominal model's mass error
    "extra_joint_damping": (0.0, 1e-5),  # N m s/rad
}
