"""Reproducible figures: a learned policy's actions are the same bits whatever torch's threads
and CPU kernels (tendon2r_gym.inference)."""

import hashlib
import math
import os
import subprocess
import sys

import numpy as np
import pytest
import torch
from stable_baselines3 import PPO

from tendon2r_gym import inference
from tendon2r_gym.bundle import bundled_model

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
    from tendon2r_gym import benchmark
    from tendon2r_gym.bundle import bundle_meta

    names = {p + s for p in benchmark.PRESETS for s, _ in benchmark.LEARNED.values()}
    names |= {"random_reference", benchmark.REALISM_BUNDLE, benchmark.RANDOMIZED_BUNDLE}
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


#: What another machine changes in torch: its CPU kernels (ATen's and MKL's instruction set,
#: MKL's code branch) and its threads.
MACHINES = {
    "ATEN_CPU_CAPABILITY": "default",
    "MKL_ENABLE_INSTRUCTIONS": "SSE4_2",
    "MKL_CBWR": "COMPATIBLE",
    "OMP_NUM_THREADS": "1",
}


def test_the_exact_actor_is_the_same_bits_on_other_kernels_and_threads():
    """The actions' bits do not depend on torch's threads nor on the kernels another CPU
    would run (simulated with torch's and MKL's dispatch variables in a fresh process; MKL_CBWR
    alone changes SB3's float32 actions here)."""
    here = [_digest(b) for b in BUNDLES]
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(1 if threads > 1 else 2)
        assert [_digest(b) for b in BUNDLES] == here
    finally:
        torch.set_num_threads(threads)
    code = "import test_reproducible as t; print(*(t._digest(b) for b in t.BUNDLES))"
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    path = os.pathsep.join([root, os.path.join(root, "tests")])
    env = {**os.environ, **MACHINES, "PYTHONPATH": path}
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=root, env=env, capture_output=True, text=True, check=True
    )
    assert out.stdout.split()[-len(BUNDLES) :] == here
