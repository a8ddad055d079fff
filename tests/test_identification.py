"""Identify your arm: the recording format and its errors, the simulator's recorder and the
excitation, and the fit (tendon2r_gym.identification)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tendon2r_gym.app.excitation import MultiSine, record
from tendon2r_gym.envs.env_config import EnvConfig
from tendon2r_gym.identification import recording
from tendon2r_gym.identification.identify import identify, load_recordings
from tests.reading import figures

pytest.importorskip("mujoco.sysid.report")


@pytest.fixture(scope="module")
def arm() -> EnvConfig:
    return EnvConfig.make("default")


@pytest.fixture(scope="module")
def rec(arm):
    signal = MultiSine(amp_rad=(0.1, 0.08), bias_rad=(0.1, -0.2))
    return record(arm, "pd", 2.6, seed=0, signal=signal)


def _write(tmp_path, rec, edit=None):
    path = rec.save(tmp_path / "r.csv")
    if edit is not None:
        lines = [line for line in path.read_text().splitlines() if not line.startswith("#")]
        edit(lines)
        path.write_text("\n".join(lines) + "\n")
    return path


def _load(path, arm, **kw):
    mech = arm.mechanism
    return recording.load(
        path, mech.n_tendons, arm.ctrl_dt, float(mech.max_tendon_force), mech.pull_only, **kw
    )


def test_a_recording_reads_back_bit_for_bit(tmp_path, arm, rec):
    back = _load(_write(tmp_path, rec), arm)
    assert np.array_equal(back.time, rec.time)
    assert np.array_equal(back.command, rec.command)
    assert np.array_equal(back.q, rec.q)


def _set(row: int, column: str, value: str):
    def edit(lines):
        header = lines[0].split(",")
        cells = lines[row].split(",")
        cells[header.index(column)] = value
        lines[row] = ",".join(cells)

    return edit


def _rename(old: str, new: str):
    def edit(lines):
        lines[0] = ",".join(new if h == old else h for h in lines[0].split(","))

    return edit


def _drop(column: str):
    def edit(lines):
        i = lines[0].split(",").index(column)
        for k, line in enumerate(lines):
            cells = line.split(",")
            del cells[i]
            lines[k] = ",".join(cells)

    return edit


@pytest.mark.parametrize(
    "edit, column, row",
    [
        (_drop("q_B"), "q_B", None),  # missing
        (_rename("q_B", "q_C"), "q_C", None),  # unknown
        (_rename("q_B", "q_A"), "q_A", None),  # twice
        (_set(3, "q_A", "nan"), "q_A", 3),
        (_set(4, "command_2", "abc"), "command_2", 4),
        (_set(5, "time", "0.0"), "time", 5),  # decreasing
        (_set(6, "time", "0.0052"), "time", 6),  # not uniform
        (_set(7, "command_1", "1e6"), "command_1", 7),  # beyond the force limit
        (_set(8, "command_2", "-1e6"), "command_2", 8),
    ],
)
def test_a_bad_recording_names_its_column_and_row(tmp_path, arm, rec, edit, column, row):
    path = _write(tmp_path, rec, edit)
    with pytest.raises(ValueError) as e:
        _load(path, arm)
    message = str(e.value)
    assert str(path) in message and repr(column) in message
    if row is not None:
        assert f"row {row}" in message


def test_pull_only_commands_may_not_push(tmp_path):
    cfg = EnvConfig.make("pull_only")
    rec = record(cfg, "pd", 0.05)
    path = _write(tmp_path, rec, _set(2, "command_3", "-0.001"))
    mech = cfg.mechanism
    with pytest.raises(ValueError, match="row 2.*pull-only"):
        recording.load(path, 3, cfg.ctrl_dt, float(mech.max_tendon_force), True)


def test_a_partial_optional_block_and_a_short_recording_are_refused(tmp_path, arm, rec):
    path = _write(tmp_path, rec, _drop("dq_B"))
    with pytest.raises(ValueError, match="'dq_B'"):
        _load(path, arm)
    short = _write(tmp_path, rec, lambda lines: lines.__delitem__(slice(800, None)))  # 0.8 s
    with pytest.raises(ValueError, match=f"recording {short}: too short to fit 1 field;"):
        identify(load_recordings([short], arm), arm, ["density_scale"])


def test_the_recorder_is_deterministic_and_holds_the_commands_as_sent(arm):
    noisy = EnvConfig.make("real_arm")
    a, b = record(noisy, "pd", 0.2, seed=3), record(noisy, "pd", 0.2, seed=3)
    c = record(noisy, "pd", 0.2, seed=4)
    assert np.array_equal(a.q, b.q) and np.array_equal(a.command, b.command)
    assert not np.array_equal(a.q, c.q)  # the sensors' noise follows the seed
    force = float(noisy.mechanism.max_tendon_force)
    assert a.command.min() >= 0.0 and a.command.max() <= force


def test_the_multisine_starts_at_rest_and_its_speed_is_its_derivative():
    s = MultiSine(amp_rad=(0.2, 0.1), bias_rad=(0.1, -0.3))
    q0, dq0 = s.q(0.0)
    assert np.allclose(q0, s.bias_rad) and np.allclose(dq0, 0.0)
    h = 1e-6
    for t in (0.2, 1.3, 2.9):
        numeric = (s.q(t + h)[0] - s.q(t - h)[0]) / (2 * h)
        assert np.allclose(s.q(t)[1], numeric, rtol=1e-5, atol=1e-6)


def test_a_noise_free_ideal_arm_gives_back_its_nominal_values(arm, rec):
    ident = identify([rec], arm, ["density_scale", "extra_joint_damping"], threads=1)
    est = {e.field: e for e in ident.estimates}
    assert abs(est["density_scale"].value - 1.0) <= 0.01
    assert abs(est["extra_joint_damping"].value) <= 0.01 * 1e-5  # 1% of its scale


def test_the_fit_finds_a_hidden_mass_and_damping_within_its_interval(arm):
    true = EnvConfig.make("default", mechanism={"density_scale": 1.3, "extra_joint_damping": 4e-6})
    signal = MultiSine(amp_rad=(0.1, 0.08), bias_rad=(0.1, -0.2))
    rec = record(true, "pd", 2.6, seed=0, signal=signal)
    ident = identify([rec], arm, ["density_scale", "extra_joint_damping"], threads=1)
    for e in ident.estimates:
        truth = getattr(true.mechanism, e.field)
        assert e.identified and e.interval[0] <= truth <= e.interval[1], e
        assert math.isclose(e.value, truth, rel_tol=0.1)
    assert ident.changes["mechanism"]["density_scale"] == pytest.approx(1.3, rel=0.1)


def test_the_fit_refuses_a_field_the_nominal_arm_cannot_vary(arm, rec):
    with pytest.raises(ValueError, match="tendon_elasticity.*rigid"):
        identify([rec], arm, ["tendon_elasticity"])


def test_tendon2r_identify_writes_an_experiment_file_every_command_reads(tmp_path, arm, rec):
    from tendon2r_gym.app.identify import identify_main

    path = rec.save(tmp_path / "rec.csv")
    out = tmp_path / "id" / "arm.yaml"
    identify_main(["--recording", str(path), "--env-config", "default", "--out", str(out),
                   "--fit", "density_scale", "--threads", "1"])  # fmt: skip
    identified = EnvConfig.make(out)
    assert identified.mechanism.density_scale == pytest.approx(1.0, rel=0.01)
    assert out.with_suffix(".html").stat().st_size > 0


def test_a_field_the_recording_cannot_show_is_flagged_and_keeps_its_nominal_value(arm, rec):
    # The ideal arm has no friction: the fit ends on the bound 0, and no number is reported.
    ident = identify([rec], arm, ["density_scale", "tendon_friction"], threads=1)
    est = {e.field: e for e in ident.estimates}
    assert est["density_scale"].identified and not est["tendon_friction"].identified
    assert "tendon_friction" not in ident.changes["mechanism"] and not est["tendon_friction"].used
    (shown,) = [line.split() for line in ident.lines() if line.split()[0] == "tendon_friction"]
    assert shown[2] == "-", "its printed row reports no identified value"


def test_a_field_too_uncertain_to_identify_that_rules_its_nominal_value_out_is_taken(arm):
    # Noisy angles: the mass scale's interval is too wide to identify it, yet it excludes the
    # nominal 1, so the identified arm takes the fit, and says so.
    true = EnvConfig.make("default", mechanism={"density_scale": 1.5},
                          observation_noise=[0.05, 0.0])  # fmt: skip
    signal = MultiSine(amp_rad=(0.1, 0.08), bias_rad=(0.1, -0.2))
    ident = identify([record(true, "pd", 2.6, seed=0, signal=signal)], arm, ["density_scale"],
                     threads=1)  # fmt: skip
    (e,) = ident.estimates
    assert not e.identified and e.used and not e.interval[0] <= 1.0 <= e.interval[1], e
    assert e.interval[0] <= 1.5 <= e.interval[1]
    assert ident.changes["mechanism"]["density_scale"] == e.value
    (shown,) = [line for line in ident.lines() if line.split()[0] == "density_scale"]
    assert figures(shown)[:4] == pytest.approx([1.0, e.value, *e.interval], rel=1e-3)


def test_several_recordings_of_one_arm_are_fitted_together(arm):
    true = EnvConfig.make("default", mechanism={"density_scale": 0.8})
    recs = [
        record(true, "pd", 1.7, seed=s, signal=MultiSine(amp_rad=(0.1, 0.08), bias_rad=b))
        for s, b in ((0, (0.1, -0.2)), (1, (-0.3, 0.4)))
    ]
    one = identify(recs[:1], arm, ["density_scale"], threads=1)
    both = identify(recs, arm, ["density_scale"], threads=1)
    assert both.pieces > one.pieces
    assert both.estimates[0].value == pytest.approx(0.8, rel=0.01)


def test_tendon2r_excite_keeps_the_rehearsal_within_the_limits(tmp_path):
    from tendon2r_gym.app.excitation import FORCE_MARGIN, RANGE_MARGIN_DEG
    from tendon2r_gym.app.identify import excite_main, record_main

    excite_main(["--env-config", "default", "--out", str(tmp_path), "--duration", "1"])
    cfg = EnvConfig.make("default")
    mech = cfg.mechanism
    rehearsal = _load(tmp_path / "rehearsal.csv", cfg)
    assert np.abs(rehearsal.command).max() <= FORCE_MARGIN * mech.max_tendon_force
    lo, hi = (math.radians(x) for x in mech.joint_range_deg)
    margin = math.radians(RANGE_MARGIN_DEG)
    assert rehearsal.q.min() >= lo + margin and rehearsal.q.max() <= hi - margin
    plan = np.loadtxt(tmp_path / "plan.csv", delimiter=",", skiprows=1)
    assert plan.shape == (len(rehearsal.time), 5)
    out = record_main(["--env-config", "default", "--excitation", "default", "--duration", "1",
                       "--out", str(tmp_path / "rec.csv")])  # fmt: skip
    again = _load(out, cfg)  # the same arm, noise-free: the rehearsal itself
    assert np.array_equal(again.command, rehearsal.command)


def test_tendon2r_identify_fits_several_recordings_and_writes_their_report(tmp_path, arm):
    from tendon2r_gym.app.identify import identify_main

    true = EnvConfig.make("default", mechanism={"density_scale": 1.2})
    paths = []
    for s, b in ((0, (0.1, -0.2)), (1, (-0.3, 0.4))):
        signal = MultiSine(amp_rad=(0.1, 0.08), bias_rad=b)
        rec = record(true, "pd", 1.0, seed=s, signal=signal)
        paths.append(str(rec.save(tmp_path / f"{s}.csv")))
    out = tmp_path / "arm.yaml"
    identify_main(["--recording", *paths, "--env-config", "default", "--out", str(out),
                   "--fit", "density_scale", "--threads", "1"])  # fmt: skip
    assert EnvConfig.make(out).mechanism.density_scale == pytest.approx(1.2, rel=0.01)
    assert out.with_suffix(".html").stat().st_size > 0


@pytest.mark.parametrize(
    "fit, threads, match",
    [(["density_scale", "density_scale"], None, "distinct"), (["mass"], None, "fit = 'mass'"),
     (["density_scale"], 0, "threads = 0")],
)  # fmt: skip
def test_bad_fit_arguments_are_refused_by_name(arm, rec, fit, threads, match):
    with pytest.raises(ValueError, match=match):
        identify([rec], arm, fit, threads)


def test_the_fit_estimates_the_sensors_noise(arm):
    noisy = EnvConfig.make("default", observation_noise=[2e-4, 0.03])
    signal = MultiSine(amp_rad=(0.1, 0.08), bias_rad=(0.1, -0.2))
    rec = record(noisy, "pd", 2.6, seed=0, signal=signal)
    ident = identify([rec], arm, ["density_scale"], threads=1)
    angle, speed = ident.noise
    assert angle == pytest.approx(2e-4, rel=0.1) and speed == pytest.approx(0.03, rel=0.1)
    assert ident.changes["observation_noise"] == [angle, speed]


def test_a_poor_fit_does_not_inflate_the_noise_estimate(arm):
    # The fit may not vary the mass that the true arm changes: its replay misses smoothly,
    # and the noise estimate still holds only the sensors' noise.
    noisy = EnvConfig.make("default", observation_noise=[1e-4, 0.02],
                           mechanism={"density_scale": 1.5})  # fmt: skip
    signal = MultiSine(amp_rad=(0.1, 0.08), bias_rad=(0.1, -0.2))
    rec = record(noisy, "pd", 2.6, seed=0, signal=signal)
    ident = identify([rec], arm, ["extra_joint_damping"], threads=1)
    assert ident.residual_rms_rad[1] > 2e-4  # the fit is poor
    assert ident.noise[0] == pytest.approx(1e-4, rel=0.1)
    # The speeds' replay keeps some of the wrong mass's response to PD's noisy commands.
    assert ident.noise[1] == pytest.approx(0.02, rel=0.3)


def test_the_loop_delay_is_found_and_split_evenly(arm):
    true = EnvConfig.make("default", mechanism={"motor_delay": 0.002}, observation_delay=0.001)
    signal = MultiSine(amp_rad=(0.1, 0.08), bias_rad=(0.1, -0.2))
    rec = record(true, "pd", 2.6, seed=0, signal=signal)
    ident = identify([rec], arm, ["density_scale", "motor_delay", "observation_delay"], threads=1)
    assert ident.delay_identified and ident.loop_delay_s == pytest.approx(0.003)
    assert ident.delay_range_s == pytest.approx((0.003, 0.003))
    assert ident.changes["observation_delay"] == pytest.approx(0.001)
    assert ident.changes["mechanism"]["motor_delay"] == pytest.approx(0.002)


def test_a_delay_left_out_of_fit_keeps_its_nominal_value_and_the_other_takes_the_rest():
    # The sensor's 2 ms are known (a datasheet): the loop's 2 ms are all the sensor's, where
    # an even split would give each delay 1 ms.
    true = EnvConfig.make("default", observation_delay=0.002)
    signal = MultiSine(amp_rad=(0.1, 0.08), bias_rad=(0.1, -0.2))
    rec = record(true, "pd", 2.6, seed=0, signal=signal)
    nominal = EnvConfig.make("default", mechanism={"motor_delay": 0.003}, observation_delay=0.002)
    ident = identify([rec], nominal, ["density_scale", "motor_delay"], threads=1)
    assert ident.loop_delay_s == pytest.approx(0.002)
    assert ident.changes["observation_delay"] == pytest.approx(0.002)
    assert ident.changes["mechanism"]["motor_delay"] == pytest.approx(0.0)


def test_the_coarse_start_finds_a_mass_far_from_the_nominal_one(arm):
    # Twice the nominal mass: the grid's best point is there, and the nominal arm's residual
    # (before the fit) is reported.
    from tendon2r_gym.identification.identify import DEFAULT_FIT, _coarse_start, _fields
    from tendon2r_gym.identification.problem import Problem

    true = EnvConfig.make("default", mechanism={"density_scale": 2.0})
    signal = MultiSine(amp_rad=(0.1, 0.08), bias_rad=(0.1, -0.2))
    rec = record(true, "pd", 2.6, seed=0, signal=signal)
    names, box, _ = _fields(list(DEFAULT_FIT), arm.mechanism, False)
    start, before = _coarse_start(Problem([rec], arm, names, box, 1), 0)
    assert start[names.index("density_scale")] == 2.0
    assert before > 1e-3  # rad: the nominal arm misses the heavy one widely
