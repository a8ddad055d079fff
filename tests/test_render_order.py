"""Rendering and loading a PPO model in one process, in either order, on every GL backend
installed here (tendon2r_gym.llvm: triton loaded after Mesa's LLVM segfaulted).

Each case runs in a fresh interpreter: this test process loaded triton before any GL context
(conftest), which hides the clash.
"""

import ctypes.util
import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

import tendon2r_gym
from tendon2r_gym import llvm

#: MuJoCo's headless backends and the library each needs (the package renders with EGL).
BACKENDS = {"egl": "EGL", "osmesa": "OSMesa"}

#: Steps a case runs in order: render with the env, render with a bare mujoco.Renderer, load
#: the bundled model and act once.
STEPS = """
import sys
import gymnasium as gym
import tendon2r_gym  # noqa: F401

def render():
    env = gym.make("Tendon2R-v1", render_mode="rgb_array", width=64, height=48)
    env.reset(seed=0)
    assert env.render().shape == (48, 64, 3)
    env.close()

def renderer():
    import mujoco
    from tendon2r_gym import Mechanism, build_model
    model = build_model(Mechanism())
    data = mujoco.MjData(model)
    with mujoco.Renderer(model, 48, 64) as r:
        r.update_scene(data)
        assert r.render().shape == (48, 64, 3)

def load():
    from tendon2r_gym.artifacts.bundle import bundled_model
    from tendon2r_gym.policies.learned import PPOPolicy
    from tendon2r_gym.artifacts.model_env import model_settings
    model = bundled_model("default")
    env = gym.make("Tendon2R-v1", **model_settings(model))
    PPOPolicy.load(model, env).predict(env.reset(seed=0)[0])

for step in sys.argv[1:]:
    globals()[step]()
    print(step, "done", flush=True)
"""

#: The orders a user meets: look at the arm then load a policy (with the env, or with a bare
#: mujoco.Renderer as tendon2r-view does), and the reverse.
ORDERS = (("render", "load"), ("renderer", "load"), ("load", "render"))


def _env(backend: str) -> dict[str, str]:
    root = str(Path(tendon2r_gym.__file__).resolve().parents[1])
    path = os.pathsep.join([root, *filter(None, [os.environ.get("PYTHONPATH")])])
    env = {**os.environ, "MUJOCO_GL": backend, "PYTHONPATH": path}
    env.pop("PYOPENGL_PLATFORM", None)  # mujoco sets it from MUJOCO_GL (this process: egl)
    return env


def _start(backend: str, code: str, *args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-X", "faulthandler", "-c", code, *args],
        env=_env(backend), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip


def _skip_without(backend: str) -> None:
    if ctypes.util.find_library(BACKENDS[backend]) is None:
        pytest.skip(f"MUJOCO_GL={backend} needs lib{BACKENDS[backend]}, not installed here")


@pytest.mark.parametrize("backend", list(BACKENDS))
def test_render_and_load_a_model_in_either_order(backend):
    _skip_without(backend)
    if importlib.util.find_spec("stable_baselines3") is None:
        pytest.skip("loading a PPO model needs stable_baselines3 (the [train] extra)")
    procs = {order: _start(backend, STEPS, *order) for order in ORDERS}  # concurrently
    for order, proc in procs.items():
        out = proc.communicate(timeout=300)[0]
        assert proc.returncode == 0, f"{' then '.join(order)} exit {proc.returncode}:\n{out}"
        done = [line for line in out.splitlines() if line.endswith(" done")]
        assert done == [f"{step} done" for step in order], out


@pytest.mark.parametrize("backend", list(BACKENDS))
def test_triton_is_loaded_only_where_a_gl_context_may_follow(backend):
    """An env without render_mode loads neither triton nor torch (gym.make stays fast); with
    one, libtriton is in the process before the first GL context (if triton is installed)."""
    _skip_without(backend)
    code = """
import sys
import gymnasium as gym
import tendon2r_gym  # noqa: F401

def triton_loaded():
    return any("libtriton" in line for line in open("/proc/self/maps"))

print(int(triton_loaded()), end=" ")
gym.make("Tendon2R-v2")
print(int(triton_loaded()), end=" ")
gym.make("Tendon2R-v2", render_mode="rgb_array")
print(int(triton_loaded()), int("torch" in sys.modules))
"""
    proc = _start(backend, code)
    out = proc.communicate(timeout=120)[0]
    assert proc.returncode == 0, out
    has_triton = importlib.util.find_spec("triton") is not None
    on_import = int(has_triton and backend == "osmesa")  # before mujoco, which loads OSMesa
    expected = f"{on_import} {on_import} {int(has_triton)} 0"
    assert expected in out.splitlines(), out


def test_load_triton_without_triton_does_nothing(monkeypatch):
    monkeypatch.setitem(sys.modules, "triton", None)  # find_spec then finds no triton
    assert llvm.load_triton.__wrapped__() is None
