#!/usr/bin/env bash
# Builds the wheel, installs it (not editable) into a fresh venv that borrows the test venv's
# dependencies, and runs gym.make, PDPolicy, the bundled PPO and a console command from a
# folder outside the checkout.
set -euo pipefail
cd "$(dirname "$0")/.."
repo=$(pwd)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
# setuptools' own build folder can hold modules that were moved or deleted since: start clean.
rm -rf build/lib build/bdist.*
.venv/bin/python -m build --wheel --no-isolation --outdir "$work/dist" . >/dev/null
python3 -m venv "$work/venv"
deps=$(.venv/bin/python -c "import sysconfig; print(sysconfig.get_paths()['purelib'])")
site=$("$work/venv/bin/python" -c "import sysconfig; print(sysconfig.get_paths()['purelib'])")
echo "$deps" > "$site/test_venv_deps.pth"  # dependencies only: .pth files there are not run
"$work/venv/bin/python" -m pip install --quiet --no-deps --no-index "$work"/dist/*.whl
cd "$work"

# The core install: the wheel's own requirements name no torch, Stable-Baselines3 or plotting
# package, and the env, PD and computed torque run with those packages made unimportable.
"$work/venv/bin/python" - <<'PY'
from importlib.metadata import requires

core = [r for r in requires("tendon2r_gym") if "extra ==" not in r]
heavy = ("torch", "stable-baselines3", "matplotlib", "tensorboard")
assert not [r for r in core if r.startswith(heavy)], core
print("core requirements:", core)
PY
MUJOCO_GL=egl "$work/venv/bin/python" - <<'PY'
import sys

BLOCKED = ("torch", "stable_baselines3", "matplotlib", "tensorboard", "triton")


class Block:  # what a core install lacks cannot be imported
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"No module named {name!r} (core install)", name=name)


sys.meta_path.insert(0, Block())
import gymnasium as gym

import tendon2r_gym  # noqa: F401
from tendon2r_gym.policies.baselines import ComputedTorquePolicy, PDPolicy

env = gym.make("Tendon2R-v0")
obs, _ = env.reset(seed=0)
for policy in (PDPolicy.from_env(env), ComputedTorquePolicy.from_env(env)):
    action, _ = policy.predict(obs)
    obs, *_ = env.step(action)
assert not [m for m in sys.modules if m.split(".")[0] in BLOCKED]
print("core install: gym.make, PD and CT work without", ", ".join(BLOCKED))
PY

MUJOCO_GL=egl "$work/venv/bin/python" - "$repo" <<'PY'
import sys
from pathlib import Path

import gymnasium as gym

import tendon2r_gym
from tendon2r_gym.artifacts.bundle import bundled_model
from tendon2r_gym.policies.learned import PPOPolicy
from tendon2r_gym.policies.baselines import PDPolicy

repo = Path(sys.argv[1])
assert repo not in Path(tendon2r_gym.__file__).parents, tendon2r_gym.__file__
env = gym.make("Tendon2R-v0")
obs, _ = env.reset(seed=0)
for policy in (PDPolicy.from_env(env), PPOPolicy.load(bundled_model("default"), env)):
    action, _ = policy.predict(obs)
    assert env.action_space.contains(action)
print("wheel smoke: gym.make, PDPolicy and bundled PPO work from", tendon2r_gym.__file__)
PY
MUJOCO_GL=egl "$work/venv/bin/tendon2r-evaluate" --policy ppo --episodes 1 --episode-duration 0.2
MUJOCO_GL=egl "$work/venv/bin/tendon2r-train" --help >/dev/null
echo "wheel smoke: OK"
