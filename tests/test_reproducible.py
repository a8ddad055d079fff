"""Reproducible figures: a learned policy's actions are the same bits whatever torch's threads
and CPU kernels (tendon2r_gym.policies.inference), and a benchmark rerun gives the same rows."""

import hashlib
import math
import os
import subprocess
import sys

import numpy as np
import pytest
import torch
from stable_baselines3 import PPO

from tendon2r_gym.artifacts.bundle import bundled_model
from tendon2r_gym.policies import inference
from tests.reading import rows_of

#: A plain MlpPolicy (three commands, residual) and a SplitViewPolicy (masked actor input).
BUNDLES = ("pull_only", "real_arm")


def _observations(model: PPO, n: int = 500) -> np.ndarray:
    rng = np.random.default_rng(0)
    shape = (n, *model.policy.observation_space.shape)
    return rng.normal(size=shape) * rng.choice([0.01, 1.0, 5.0], size=(n, 1))


@pytest.mark.parametrize("bundle", BUNDLES)
def test_the_exact_actor_is_sb3s_deterministic_predict_to_float32_rounding(bundle):
    model = PPO.load(bundled_model(bundle), device="cpu")
    obs = _observations(model)
    ours, state = inference.predict(model, obs, "state", None, True)
    theirs, _ = model.predict(obs, deterministic=True)
    assert state == "state" and ours.dtype == theirs.dtype and ours.shape == theirs.shape
    np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-6)
    assert not np.array_equal(ours, theirs), "float64, not SB3's float32 path"
    one, _ = inference.predict(model, obs[0])  # one observation: one action, as SB3's
    np.testing.assert_allclose(one, theirs[0], rtol=0, atol=1e-6)
    assert one.shape == model.action_space.shape
    sampled, _ = inference.predict(model, obs[:3], deterministic=False)  # SB3's own draw
    assert sampled.shape == theirs[:3].shape


def test_every_model_the_benchmark_runs_has_an_exact_actor():
    from tendon2r_gym.app import benchmark
    from tendon2r_gym.artifacts import registry
    from tendon2r_gym.artifacts.bundle import bundle_meta

    names = set(registry.names("preset") + registry.names("references") + registry.names("realism"))
    assert {m.parent.parent.name for ms in benchmark.preset_models().values() for m in
            sum(ms.values(), [])} <= names  # fmt: skip
    for name in sorted(names):
        for seed in bundle_meta(name)["seeds"]:
            policy = PPO.load(bundled_model(name, seed), device="cpu").policy
            assert inference.actor_layers(policy) is not None, (name, seed)


def test_the_exact_actor_follows_weights_changed_in_place():
    """Training evaluates its live model: an optimizer step (in place) changes the actions."""
    model = PPO.load(bundled_model("pull_only"), device="cpu")
    obs = _observations(model, 5)
    before, _ = inference.predict(model, obs)
    with torch.no_grad():
        model.policy.action_net.bias.add_(0.25)
    after, _ = inference.predict(model, obs)
    np.testing.assert_allclose(after, model.predict(obs, deterministic=True)[0], atol=1e-6)
    assert not np.allclose(after, before)


def test_a_layer_sums_in_one_order_whatever_its_chunks(monkeypatch):
    rng = np.random.default_rng(0)
    x, weight, bias = rng.normal(size=(16, 60)), rng.normal(size=(256, 60)), rng.normal(size=256)
    whole = inference.linear(x, weight, bias)
    np.testing.assert_allclose(whole, x @ weight.T + bias, rtol=0, atol=1e-12)
    monkeypatch.setattr(inference, "CHUNK", 1)  # one output at a time
    assert np.array_equal(inference.linear(x, weight, bias), whole)


def test_exp_and_tanh_are_accurate_to_float64_rounding():
    x = np.concatenate([np.linspace(-30, 30, 20001), [0.0, -0.0, 1e-300, -1e-12, 700.0]])
    tanh = inference.tanh(x)
    assert np.max(np.abs(tanh - np.array([math.tanh(v) for v in x]))) < 1e-15
    assert np.signbit(inference.tanh(np.array([-0.0])))[0], "odd, to the sign of zero"
    y = np.linspace(-700, 700, 20001)
    rel = np.abs(inference.exp(y) / np.array([math.exp(v) for v in y]) - 1)
    assert np.max(rel) < 4 * 2.0**-52


def _digest(bundle: str) -> str:
    model = PPO.load(bundled_model(bundle), device="cpu")
    return hashlib.sha256(inference.predict(model, _observations(model))[0].tobytes()).hexdigest()


#: A short benchmark: the residual trained on the ideal pull-only arm, on the same arm with
#: real cables, motors and sensors (where its figures move most with its last bits), three
#: episodes (SB3 batches them: a batch of three).
SHORT_ARM = {"preset": "real_arm", "episode_duration": 0.2}
SHORT_BUNDLE = "pull_only"
SHORT_SEEDS = [0, 1, 2]


def _short_rows(learned_only: bool = False) -> list[dict]:
    from tendon2r_gym.app import benchmark

    kwargs = SHORT_ARM
    model = bundled_model(SHORT_BUNDLE)
    if learned_only:
        row = benchmark.policy_row("short", "ppo residual", "ppo", kwargs, SHORT_SEEDS, model, None)
        rows = [row]
    else:
        rows = benchmark.compare("short", kwargs, {"ppo residual": [model]}, SHORT_SEEDS, None)
    return [{k: v for k, v in r.items() if k != "eval_s"} for r in rows]  # eval_s: wall time


def _fingerprint() -> str:
    """The actors' actions on fixed observations and the short benchmark's learned row."""
    return repr(([_digest(b) for b in BUNDLES], _short_rows(learned_only=True)))


#: What another machine changes in torch: its CPU kernels (ATen's and MKL's instruction set,
#: MKL's code branch) and its threads.
MACHINES = {
    "ATEN_CPU_CAPABILITY": "default",
    "MKL_ENABLE_INSTRUCTIONS": "SSE4_2",
    "MKL_CBWR": "COMPATIBLE",
    "OMP_NUM_THREADS": "1",
}


def test_a_rerun_gives_the_same_bits_on_other_kernels_and_threads():
    """The actors' actions and the benchmark's rows do not depend on torch's threads nor on
    the kernels another CPU would run (simulated with torch's and MKL's dispatch variables
    in a fresh process; MKL_CBWR alone changes SB3's float32 actions here)."""
    here = _fingerprint()
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(1 if threads > 1 else 2)
        assert _fingerprint() == here
    finally:
        torch.set_num_threads(threads)
    code = "import test_reproducible as t; f = t._fingerprint(); print(); print(f)"
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    path = os.pathsep.join([root, os.path.join(root, "tests")])
    env = {**os.environ, **MACHINES, "PYTHONPATH": path}
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=root, env=env, capture_output=True, text=True, check=True
    )
    assert out.stdout.strip().splitlines()[-1] == here


def test_a_figure_within_its_tolerance_keeps_its_printed_digits_on_other_arithmetic(
    monkeypatch,
):
    """The rows' tolerances are measured by the run itself; where a row's is below the
    printed precision, SB3's float32 network (another machine's arithmetic, in the last
    float32 bits) prints the same figures."""
    from tendon2r_gym.app.report import PRINTED
    from tendon2r_gym.app.report import fmt as _fmt
    from tendon2r_gym.evaluation.evaluator import REPRO_RUNS

    ours = _short_rows()
    assert REPRO_RUNS >= 1 and all(len(r["rms_deg_jittered"]) == REPRO_RUNS for r in ours)
    for r in ours:
        change = np.max(np.abs(np.subtract(r["rms_deg_jittered"], r["rms_deg"])), axis=0)
        assert r["reproducible_to"] == change.tolist()
    monkeypatch.setattr(inference, "predict", lambda m, *a: m.predict(*a))
    theirs = _short_rows()
    assert [r["policy"] for r in theirs] == [r["policy"] for r in ours]
    learned = [(a, b) for a, b in zip(ours, theirs, strict=True) if "model" in a]
    assert learned and all(a["rms_deg"] != b["rms_deg"] for a, b in learned), "float32"
    for a, b in zip(ours, theirs, strict=True):
        if max(a["reproducible_to"]) < PRINTED:
            assert _fmt(a["rms_deg"]) == _fmt(b["rms_deg"]), a["policy"]


def test_the_tables_print_each_rows_tolerance_beside_it():
    from tendon2r_gym.app.report import table

    row = {"env": "e", "policy": "pd", "rms_deg": [0.1, 0.2], "max_deg": [0.3, 0.4]}
    lines = table([{**row, "reproducible_to": [0.0, 3.2e-9]}])
    assert lines[0].split(" | ")[3] == "reproducible to (deg)"
    assert rows_of("\n".join(lines)) == [
        ["e", "pd", "0.1000 / 0.2000", "0 / 3.2e-09", "0.300 / 0.400"]
    ]


def test_a_rerun_is_compared_row_by_row_within_its_tolerance():
    """report.differences: the committed record against itself reproduces; a row whose error
    moves by more than its tolerance, or a missing row, is named; one within it is not."""
    import copy
    import json
    from pathlib import Path

    from tendon2r_gym.app.report import differences

    ours = json.loads((Path(__file__).parents[1] / "results" / "benchmark.json").read_text())
    assert differences(ours, copy.deepcopy(ours)) == []
    theirs = copy.deepcopy(ours)
    row = next(r for r in theirs["rows"] if "model" in r)
    row["rms_deg"] = [row["rms_deg"][0] + 2 * max(row["reproducible_to"]) + 1e-12,
                      row["rms_deg"][1]]  # fmt: skip
    (found,) = differences(ours, theirs)
    assert found.startswith(f"{row['env']}, {row['policy']}: RMS")
    row["rms_deg"][0] = next(r for r in ours["rows"] if r["policy"] == row["policy"]
                             and r["env"] == row["env"])["rms_deg"][0]  # fmt: skip
    assert differences(ours, theirs) == []
    theirs["rows"].pop()
    assert differences(ours, theirs)[0].endswith("only in one record")
