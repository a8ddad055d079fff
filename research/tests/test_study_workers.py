"""The studies and tendon2r-tune-pd on two local worker processes (--workers 2): the same
results file as in one process (timings aside), each arm (or grid point) one job."""

import functools
import json

import pytest

from tendon2r_gym.training import executors
from tests.conftest import shortened


def _shorten() -> None:
    """In a worker: every vector env runs the tests' short episodes (tests/conftest.py's
    short_episodes, which a spawned worker does not inherit) and each figure gets one
    jittered rerun."""
    from tendon2r_gym.envs import vector_env
    from tendon2r_gym.evaluation import evaluator

    evaluator.REPRO_RUNS = 1
    base = vector_env.Tendon2RVectorEnv
    if not getattr(base, "shortened", False):
        vector_env.Tendon2RVectorEnv = shortened(base)


def _short_job(fn, job):
    """A job in a worker with the tests' short episodes."""
    _shorten()
    return fn(job)


class _Shortened:
    """An executor whose jobs run with the tests' short episodes in their worker."""

    def __init__(self, inner):
        self.inner, self.remote = inner, inner.remote

    def map(self, fn, jobs, labels=None, done=None):
        return self.inner.map(functools.partial(_short_job, fn), jobs, labels, done)


@pytest.fixture
def short_workers(monkeypatch, short_episodes):
    """Short episodes and one jittered rerun, in this process (the in-process run) and in
    each local worker (make_executor's local workers wrapped)."""
    from tendon2r_gym.evaluation import evaluator

    monkeypatch.setattr(evaluator, "REPRO_RUNS", 1)
    make = executors.make_executor

    def wrapped(workers=1, cluster=None, cpus=1):
        ex = make(workers, cluster, cpus)
        return ex if isinstance(ex, executors.InProcess) else _Shortened(ex)

    monkeypatch.setattr(executors, "make_executor", wrapped)


def _without(data, keys):
    """``data`` with every dict's ``keys`` dropped (timings), at any depth."""
    if isinstance(data, dict):
        return {k: _without(v, keys) for k, v in data.items() if k not in keys}
    if isinstance(data, list):
        return [_without(v, keys) for v in data]
    return data


def test_the_executor_flags_are_not_part_of_the_recorded_command():
    argv = ["--arms", "2", "--workers", "2", "--cluster=auto", "--out", "x", "--cluster", "a:1"]
    assert executors.without_executor_flags(argv) == ["--arms", "2", "--out", "x"]


def test_tune_pd_on_two_workers_scans_as_one_process(tmp_path):
    """Each grid point is one job: the same scan, and the same command result."""
    import yaml

    from tendon2r_gym.app.cli import tune_pd_main
    from tendon2r_gym.presets import load_yaml, preset_path

    arm = tmp_path / "arm.yaml"  # a lagging real arm (tests/test_tuning.py), short episodes
    data = load_yaml(preset_path("real_arm"))
    data["mechanism"] = {**data.get("mechanism", {}), "motor_delay": 0.002, "motor_tau": 0.004}
    arm.write_text(yaml.safe_dump({**data, "episode_duration": 0.2}))
    argv = ["--env-config", str(arm), "--episodes", "1"]
    assert tune_pd_main([*argv, "--workers", "2"]) == tune_pd_main(argv)
    with pytest.raises(ValueError, match=r"^--workers = 0 is invalid.*\[1, 256\]"):
        tune_pd_main([*argv, "--workers", "0"])
    with pytest.raises(ValueError, match=r"^--workers = 2 is invalid.*1 with --cluster"):
        tune_pd_main([*argv, "--workers", "2", "--cluster", "auto"])


def test_realism_on_two_workers_writes_the_same_results(tmp_path, monkeypatch, short_workers):
    from research.studies import realism

    arms = realism.realism_arms()[1:3]
    monkeypatch.setattr(realism, "realism_arms", lambda: arms)
    argv = ["--episodes", "1", "--out", str(tmp_path / "out")]
    one = realism.main(argv)
    (tmp_path / "out").rename(tmp_path / "one")  # the same --out: the same command recorded
    two = realism.main([*argv, "--workers", "2"])
    assert [r["arm"] for r in two["rows"]] == [name for name, _ in arms]
    for name in ("realism.json", "realism.md"):
        assert (tmp_path / "out" / name).read_text() == (tmp_path / "one" / name).read_text()
    assert two == one


def test_envelope_generalists_on_two_workers_writes_the_same_results(tmp_path, short_workers):
    """Every arm a job (its partial file written as each ends); --resume then keeps them."""
    from research.studies import envelope_generalists as study

    argv = ["--arms", "1", "--one-geometry", "1", "--episodes", "1", "--kinds", "real",
            "one_geometry", "--out", str(tmp_path / "out")]  # fmt: skip
    study.main(argv)
    (tmp_path / "out").rename(tmp_path / "one")  # the same --out: the same command recorded
    two = study.main([*argv, "--workers", "2"])
    assert list(two["arms"]) == ["real_0", "one_geometry_0"]
    for name in ("envelope_generalists.json", "envelope_generalists.md"):
        assert (tmp_path / "out" / name).read_text() == (tmp_path / "one" / name).read_text()
    partial = json.loads((tmp_path / "out" / "envelope_generalists.partial.json").read_text())
    assert partial == json.loads(json.dumps(two["arms"]))
    assert study.main([*argv, "--workers", "2", "--resume"])["arms"] == two["arms"]


@pytest.mark.slow  # four fits: minutes (make slow-test)
def test_identification_on_two_workers_writes_the_same_results(tmp_path, monkeypatch,
                                                                short_workers):  # fmt: skip
    """Two true arms, a 5 s recording each: the same rows (the fit's seconds aside), in arm
    order in the partial file; --resume runs only the arms missing from it."""
    from research.studies import identification as study

    monkeypatch.setattr(study, "DURATION", 5.0)  # the fit needs about 4.5 s
    # the ideal arm's check, a fit in this process after the arms' jobs: not the executors'
    monkeypatch.setattr(study, "ideal_check", lambda *a: {"fields": {}, "loop_delay_ms": 0.0})
    argv = ["--arms", "2", "--threads", "1"]
    one = study.main([*argv, "--out", str(tmp_path / "one")])
    two = study.main([*argv, "--out", str(tmp_path / "two"), "--workers", "2"])
    assert [r["arm"] for r in two["rows"]] == [0, 1]
    files = {d: json.loads((tmp_path / d / "identification.json").read_text())
             for d in ("one", "two")}  # fmt: skip
    assert _without(files["two"], {"seconds"}) == _without(files["one"], {"seconds"})
    partial = json.loads((tmp_path / "two" / "identification.partial.json").read_text())
    assert [r["arm"] for r in partial] == [0, 1]
    # --resume with arm 0 lost from the partial file runs that arm alone (here a stand-in
    # for its fit: the one process's row) and keeps arm 1 where it belongs
    (tmp_path / "two" / "identification.partial.json").write_text(json.dumps(partial[1:]))
    jobs = []
    monkeypatch.setattr(study, "arm_job", lambda job: jobs.append(job.index) or one["rows"][0])
    again = study.main([*argv, "--out", str(tmp_path / "two"), "--resume"])
    assert jobs == [0]
    assert _without(again, {"seconds"}) == _without(two, {"seconds"})
