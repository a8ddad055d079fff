"""Results that carry their uncertainty (tendon2r_gym.evaluation.statistics): the IQM and its
stratified bootstrap interval, the probability of beating PD, performance profiles, and the
errors on bad input."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy import stats

from tendon2r_gym.evaluation import statistics
from tendon2r_gym.evaluation.statistics import (
    beat_probability,
    few_runs_note,
    iqm,
    iqm_interval,
    performance_profile,
    summary,
    wilson,
    worst_ratios,
)
from tests.reading import figures


def test_the_iqm_is_the_mean_of_the_middle_half():
    """8 runs: the mean of the middle 4.  The convention (scipy.stats.trim_mean(x, 0.25), the
    paper's): n // 4 runs dropped at each end, so 10 runs keep their middle 6 and 3 runs their
    mean."""
    rng = np.random.default_rng(0)
    runs = np.stack([rng.permutation(np.arange(1.0, 9.0)), rng.permutation(np.arange(11.0, 19.0))],
                    axis=1)  # fmt: skip
    assert iqm(runs).tolist() == [4.5, 14.5]
    assert iqm(np.arange(1.0, 11.0)) == np.mean(np.arange(3.0, 9.0))
    assert iqm([1.0, 2.0, 9.0]) == 4.0
    for n in range(1, 14):
        x = rng.lognormal(size=(n, 2))
        np.testing.assert_allclose(iqm(x), stats.trim_mean(x, 0.25, axis=0), rtol=1e-12)


def test_the_interval_is_reproducible_from_its_seed_and_stratified():
    rng = np.random.default_rng(1)
    runs = {"arm a": rng.lognormal(size=(6, 2)).tolist(), "arm b": rng.lognormal(size=(4, 2))}
    first = iqm_interval(runs, seed=7, n_resamples=999)
    assert iqm_interval(runs, seed=7, n_resamples=999) == first
    assert iqm_interval(runs, seed=8, n_resamples=999) != first
    pooled = np.concatenate([runs["arm a"], runs["arm b"]])
    assert first.value == iqm(pooled).tolist()
    for lo, v, hi in zip(first.low, first.value, first.high, strict=True):
        assert lo < v < hi
    # each stratum resampled within itself: a stratum of equal runs adds no spread
    flat = {"arm a": runs["arm a"], "arm b": [[1.0, 1.0]] * 4}
    unstratified = iqm_interval([*runs["arm a"], *[[1.0, 1.0]] * 4], seed=7, n_resamples=999)
    stratified = iqm_interval(flat, seed=7, n_resamples=999)
    width = lambda e: np.subtract(e.high, e.low)  # noqa: E731
    assert np.all(width(stratified) < width(unstratified))


def _true_iqm(locs: np.ndarray, sigma: float, points: int = 20_000) -> float:
    """The IQM of an equal mixture of lognormals (log-means ``locs``, log-sd ``sigma``), from
    each one's quantiles at (i + 0.5) / points."""
    u = (np.arange(points) + 0.5) / points
    pooled = np.concatenate([stats.lognorm.ppf(u, sigma, scale=np.exp(m)) for m in locs])
    return float(iqm(pooled))


@settings(max_examples=6, deadline=None, derandomize=True,
          suppress_health_check=list(HealthCheck))  # fmt: skip
@given(
    n_strata=st.integers(1, 3),
    per_stratum=st.integers(8, 12),
    sigma=st.floats(0.1, 1.0),
    spread=st.floats(0.0, 2.0),
    seed=st.integers(0, 2**32 - 1),
)
def test_the_interval_covers_the_true_iqm_at_about_its_nominal_rate(
    n_strata, per_stratum, sigma, spread, seed
):
    """Over 200 synthetic studies (strata of seeds, each stratum's RMS lognormal; joint B
    twice joint A's scale), the 95% interval covers the true IQM of the strata's mixture in
    [0.80, 0.99] of them, per joint.  A percentile bootstrap covers less than its nominal rate
    on few runs (8 per stratum here: about 0.84 to 0.96 measured); an interval that is wrong
    (too narrow, or around another statistic) covers far less."""
    locs = np.linspace(0.0, spread, n_strata)
    truth = _true_iqm(locs, sigma) * np.array([1.0, 2.0])
    rng = np.random.default_rng(seed)
    covered = np.zeros(2)
    datasets = 200
    for i in range(datasets):
        runs = {f"arm {k}": rng.lognormal(m, sigma, (per_stratum, 2)) * [1.0, 2.0]
                for k, m in enumerate(locs)}  # fmt: skip
        e = iqm_interval(runs, seed=i, n_resamples=999)
        covered += (np.array(e.low) <= truth) & (truth <= np.array(e.high))
    assert np.all((0.80 <= covered / datasets) & (covered / datasets <= 0.99)), covered


def test_the_probability_of_beating_pd_on_hand_made_pairs():
    """Arm a (PD 1, 1): one run better on both joints, one worse on joint B, one equal
    (counts: <= on both); arm b (PD 2, 2): one worse on joint A, one better.  3 of 5 pairs,
    with the Wilson interval of 3 / 5."""
    runs = {"a": [[0.5, 0.9], [0.5, 1.1], [1.0, 1.0]], "b": [[3.0, 1.0], [1.0, 1.0]]}
    out = beat_probability(runs, {"a": [1.0, 1.0], "b": [2.0, 2.0]})
    assert (out["wins"], out["pairs"], out["share"]) == (3, 5, 0.6)
    assert out["interval"] == "wilson"
    assert out["low"] == pytest.approx(0.2307, abs=1e-4)
    assert out["high"] == pytest.approx(0.8824, abs=1e-4)
    assert wilson(0, 3) == (0.0, pytest.approx(0.5615, abs=1e-4))
    assert wilson(3, 3) == (pytest.approx(0.4385, abs=1e-4), 1.0)
    one_pd = beat_probability(runs["a"], [1.0, 1.0])
    assert (one_pd["wins"], one_pd["pairs"]) == (2, 3)
    assert worst_ratios(runs, {"a": [1.0, 1.0], "b": [2.0, 2.0]}) == {
        "a": [0.9, 1.1, 1.0], "b": [1.5, 0.5]
    }  # fmt: skip


def test_the_performance_profile_is_monotone_and_reaches_one():
    rng = np.random.default_rng(3)
    ratios = {
        "ppo residual": {"arm a": rng.lognormal(-0.3, 0.4, 6), "arm b": rng.lognormal(0, 0.4, 5)},
        "ppo scratch": rng.lognormal(0.5, 0.6, 8).tolist(),
        "pd": [1.0, 1.0, 1.0],
    }
    profile = performance_profile(ratios, seed=0, n_resamples=999)
    tau = np.array(profile["tau"])
    assert np.all(np.diff(tau) > 0) and 1.0 in profile["tau"]
    for policy, curve in profile["curves"].items():
        for key in ("fraction", "low", "high"):
            values = np.array(curve[key])
            assert np.all(np.diff(values) >= 0), (policy, key)
            assert values[-1] == 1.0, (policy, key)
        assert np.all(np.array(curve["low"]) <= curve["high"])
    assert profile["curves"]["ppo scratch"]["runs"] == 8
    pd = profile["curves"]["pd"]["fraction"]
    assert all(f == (1.0 if t >= 1.0 else 0.0) for t, f in zip(tau, pd, strict=True))
    fixed = performance_profile({"x": [0.5, 2.0]}, taus=[0.25, 0.5, 1.0, 2.0], n_resamples=99)
    assert fixed["curves"]["x"]["fraction"] == [0.0, 0.5, 0.5, 1.0]
    assert performance_profile(ratios, seed=0, n_resamples=999) == profile


def test_the_profile_figure_is_deterministic(tmp_path):
    from tendon2r_gym.app.plots import plot_performance_profile

    profile = performance_profile({"ppo": [0.4, 0.8, 1.3, 0.9], "pd": [1.0, 1.0]},
                                  n_resamples=99)  # fmt: skip
    a = plot_performance_profile(profile, tmp_path / "a" / "profile.png")
    b = plot_performance_profile(profile, tmp_path / "b.png")
    assert a.read_bytes() == b.read_bytes() and a.stat().st_size > 1000


def test_summary_and_the_note_on_few_runs():
    runs = [[1.0, 2.0], [2.0, 3.0], [4.0, 1.0]]
    out = summary(runs, [2.5, 2.5], seed=0, n_resamples=999)
    assert out["runs"] == 3 and out["strata"] == 1 and out["iqm"] == [7 / 3, 2.0]
    assert out["mean"] == [7 / 3, 2.0] and out["std"] == np.std(runs, axis=0).tolist()
    assert len(out["iqm_ci"]) == 2 and all(lo <= hi for lo, hi in out["iqm_ci"])
    assert out["beats_baseline"]["wins"] == 1 and out["worst_ratio"] == [0.8, 1.2, 1.6]
    assert out["note"] == few_runs_note(3)
    assert few_runs_note(3).startswith("3 runs: the interval is wide")
    assert figures(few_runs_note(1))[0] == 1 and statistics.MIN_RUNS in figures(few_runs_note(1))
    assert few_runs_note(statistics.MIN_RUNS) is None


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: iqm_interval([]), r"^runs = \[\] is invalid; allowed: a non-empty list of runs"),
        (
            lambda: iqm_interval([[1.0, float("nan")], [1.0, 2.0]]),
            r"^runs\[0\]\[1\] = nan is invalid; allowed: a finite number",
        ),
        (
            lambda: iqm_interval([[1.0, 2.0], [1.0]]),
            r"^runs\[1\] = \[1.0\] is invalid; allowed: 2 per-joint scores",
        ),
        (
            lambda: iqm_interval({"a": [[1.0, 2.0]], "b": [[1.0, 2.0], [2.0, 1.0]]}),
            r"^runs\['a'\] = \[\[1.0, 2.0\]\] is invalid; allowed: 2 or more runs",
        ),
        (lambda: iqm_interval({}), r"^runs = \{\} is invalid"),
        (lambda: iqm_interval([[1.0], [2.0]], seed=-1), r"^seed = -1 is invalid"),
        (lambda: iqm_interval([[1.0], [2.0]], confidence=1.0), r"^confidence = 1.0 is invalid"),
        (
            lambda: beat_probability([[1.0, 2.0]], [1.0]),
            r"^baseline = \[1.0\] is invalid; allowed: 2 per-joint scores, each > 0",
        ),
        (lambda: beat_probability({"a": [[1.0]]}, {"b": [1.0]}), r"^baseline = \['b'\]"),
        (lambda: performance_profile({"ppo": [1.0]}), r"^ratios\['ppo'\] = \[1.0\] is invalid"),
        (
            lambda: performance_profile({"ppo": [1.0, -2.0]}),
            r"^ratios\['ppo'\]\[1\] = -2.0 is invalid; allowed: a finite number in \(0",
        ),
        (lambda: performance_profile({"ppo": [1.0, 2.0]}, taus=[2.0, 1.0]), r"^taus = \[2.0, 1.0"),
        (lambda: performance_profile({}), r"^ratios = \{\} is invalid"),
    ],
)
def test_bad_input_names_the_field_the_value_and_what_is_allowed(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def test_the_report_shows_each_multi_seed_row_s_iqm_interval_and_share_as_recorded():
    """The benchmark's table over training seeds is its rows' ``statistics``, cell for cell:
    the IQM and its interval per joint, the share beating PD with its interval, each seed's
    worst-joint ratio; a row without statistics (one seed, a baseline) has no line."""
    from tendon2r_gym.app import markdown, report
    from tendon2r_gym.app.benchmark import uncertainty

    pd = [0.10, 0.07]
    rms = [[0.02, 0.01], [0.03, 0.02], [0.12, 0.01], [0.025, 0.015]]
    learned = {"env": "default", "policy": "ppo residual (4 seeds)", "rms_deg": pd,
               "statistics": uncertainty(rms, pd)}  # fmt: skip
    rows = [{"env": "default", "policy": "pd", "rms_deg": pd}, learned]
    lines = report.seeds_table(rows)
    body = [line for line in lines if line.startswith("| default")]
    assert len(body) == 1
    cells = [c.strip() for c in body[0].strip("|").split("|")]
    s = learned["statistics"]
    low, high = zip(*s["rms_deg_iqm_ci"], strict=True)
    assert cells[2:5] == [str(len(rms)), markdown.pair(s["rms_deg_iqm"], ".4f"),
                          f"{report.fmt(list(low))} – {report.fmt(list(high))}"]  # fmt: skip
    assert (
        cells[5].startswith(f"{s['beats_pd']['wins']} of {len(rms)} ")
        and s["beats_pd"]["wins"] == 3
    )
    assert cells[6] == ", ".join(f"{max(r[0] / pd[0], r[1] / pd[1]):.2f}" for r in rms)
    assert s["note"] is not None  # 4 runs: fewer than statistics.MIN_RUNS
    assert report.seeds_table(rows[:1]) == []
