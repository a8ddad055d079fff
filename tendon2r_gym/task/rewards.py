"""The reward's tables: its terms with their default weights and meanings, the tracking forms,
the error units, and their bounds.  tendon2r_gym.envs.formulas computes the terms; EnvConfig
validates ``reward_scales`` against these tables.
"""

from __future__ import annotations

#: Default weight of the action-rate term: plain PPO's tension rate within a few times PD's
#: (research/notes/2026-11-28-learning-and-reward.md).
ACTION_RATE_WEIGHT = 0.1

#: Reward terms: name -> (default weight, what the unscaled term is).  reward = sum of weight *
#: term; each scaled term is in ``info`` as ``reward_<name>``.
TERMS: dict[str, tuple[float, str]] = {
    "tracking": (
        1.0,
        'with ``tracking_form="multiscale"`` (default): the mean of "log" kernels at MULTISCALE '
        "x sigma (0.01 to 10 deg for sigma = ``tracking_sigma_deg`` = 1), in [-1, 0], whose "
        "gradient stays useful from 90 deg off down to 0.01 deg, so that plain and residual PPO "
        'both train on it.  ``"log"``: one kernel, flat below about sigma / 10 (the '
        'generalist\'s ablations).  ``"quadratic"``: the squared error in deg^2, the RMS metric, '
        "steep far off "
        "(the residual's reward before the multiscale one).  No form has a constant offset, "
        "so VecNormalize's reward scaling does not clip it",
    ),
    "tracking_quadratic": (
        0.0,
        "beside ``tracking``, the RMS metric's own weighting.  The "
        "multiscale kernels weigh a 0.03 deg error about 13 times a 0.001 deg one (sigma 0.1), "
        "the RMS 900 times, so that on them the few steps that close the reset's offset, most "
        "of a precise policy's RMS, are a few percent of its reward "
        "(research/results/transient.md)",
    ),
    "tracking_rate": (
        0.0,
        "the ``tracking`` form on e + ``tracking_horizon`` de, each joint's error "
        "``tracking_horizon`` s ahead at its rate de = dq_des - dq (deg): an action changes it "
        "on the next step, so that a learner with a short discount horizon (gamma 0.9 at 1 kHz "
        "looks 10 ms ahead) sees what its action did.  Driving it to 0 closes the error with "
        "time constant ``tracking_horizon``",
    ),
    "ctrl": (
        0.001,
        "f is the applied command as a fraction of the force limit: the tension (``(command + "
        "1) / 2`` for pull-only motors, whose -1 is slack) or the joint torque",
    ),
    "action_rate": (
        ACTION_RATE_WEIGHT,
        "the change of the applied command since the last step (observed, zeros after a "
        "reset): smooth commands that a motor can follow",
    ),
    "action_rate_need": (
        0.0,
        "s is, per joint, the largest change "
        "per control step of its torque command that the reference needs "
        "(EnvConfig.needs.torque_rate_need x ctrl_dt over TorqueToTension.max_torque): the "
        "action rate in multiples of the task's own, alike on every arm (``action_rate`` "
        "weighs a jitter alike whether the task moves a joint's command little or much); "
        "logarithmic, so that the step from rest after a reset costs little more than a steady 3x "
        "(joint-torque mode only)",
    ),
    "divergence": (
        100.0,
        "-1 on the step where the physics diverges, else 0: more than any discounted sum of "
        "tracking penalties it could end (at most 1 per step, 1 / (1 - gamma) = 100 for "
        "gamma 0.99), so that ending an episode never pays",
    ),
}
REWARD_SCALES: dict[str, float] = {name: weight for name, (weight, _) in TERMS.items()}
#: The largest weight a term may have: every unscaled term is at most about 1e5 in size
#: (``tracking_quadratic`` at 180 deg off on both joints is 6.5e4), so a weighted reward stays
#: far from float32's range (3.4e38) and from VecNormalize's variance overflowing.
MAX_REWARD_WEIGHT = 1e6
TRACKING_FORMS = ("quadratic", "log", "multiscale")
#: What ``error_log`` and ``error_rate_log`` log-scale (EnvConfig.error_units): "rad", the
#: tracking error (rad) and its rate (rad/s), linear below ERROR_LOG_SCALE and
#: ERROR_RATE_LOG_SCALE; "action", the normalized joint torques that, in one control step on
#: the episode's arm (EnvConfig.needs.rate_to_action), give the joints the speed that closes the
#: error in one more step, and cancel its rate; both linear below ACTION_LOG_SCALE.
ERROR_UNITS = ("rad", "action")
#: Error scales of the "multiscale" tracking reward, as multiples of tracking_sigma_deg: one
#: log kernel per decade, so that its gradient stays useful from tens of degrees down to
#: 0.01 deg (the "log" form alone is flat below about sigma / 10).
MULTISCALE = (0.01, 0.1, 1.0, 10.0)


def rewards_table() -> str:
    """Returns the docstring list of the reward terms (the env's docstring embeds it)."""
    return "\n".join(f"- ``{k}`` (weight {w:g}): {doc}." for k, (w, doc) in TERMS.items())
