"""Convert the VecNormalize statistics that earlier versions saved as a pickle
(``<name>_vecnormalize.pkl``) into the plain arrays tendon2r_gym reads without unpickling
(``<name>_vecnormalize.npz``), and check that nothing changed.

For each file: the statistics are equal, array for array, and so are the normalized
observations of a fixed set of observations, bit for bit; with the model zip beside it, the
policy built without pickle (tendon2r_gym.artifacts.files.load_policy) has the weights of SB3's
``PPO.load``, and on those normalized observations both give the same actions, bit for bit
(the exact actor of tendon2r_gym.policies.inference, and SB3's own float32 predict).

Unpickling runs whatever code the file holds: convert only files you made (the command needs
--trust-pickle).

    python scripts/convert_model_files.py --trust-pickle --folders runs/my_run
    python scripts/convert_model_files.py --trust-pickle --remove-pkl \\
        --folders tendon2r_gym/data/models
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated

import gymnasium as gym
import numpy as np

from tendon2r_gym.app.args import arg, parse
from tendon2r_gym.artifacts.files import TRUST_HELP, convert_stats, load_policy, read_stats
from tendon2r_gym.llvm import load_triton

#: Observations per check, and the scales they are drawn at (the largest are clipped).
N_OBS = 64
SCALES = (0.01, 1.0, 10.0, 1000.0)


@dataclass
class Args:
    """Convert earlier versions' pickled VecNormalize statistics to npz, checking each."""

    folders: Annotated[list[str], arg("run folders, bundles or a models root (searched)")] = field(
        default_factory=lambda: []
    )
    trust_pickle: Annotated[bool, arg(f"required: {TRUST_HELP}")] = False
    remove_pkl: Annotated[bool, arg("delete each pkl once its npz is checked")] = False


class _Blank(gym.Env):
    """An env of one observation shape, for a VecNormalize to wrap (it is never stepped)."""

    def __init__(self, shape: tuple[int, ...]) -> None:
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape, np.float64)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)


def observations(size: int, n: int = N_OBS) -> np.ndarray:
    """Returns ``n`` observations of ``size`` entries at the scales of ``SCALES``."""
    rng = np.random.default_rng(0)
    return rng.normal(size=(n, size)) * rng.choice(SCALES, size=(n, 1))


def check(pkl: Path, npz: Path) -> str:
    """Raises AssertionError if ``npz`` and the model zip beside it do not give the same
    normalized observations and actions as ``pkl`` with SB3's PPO.load; returns what was
    checked."""
    load_triton()  # before torch: tendon2r_gym.llvm
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv

    from tendon2r_gym.artifacts.files import _unpickled_vecnormalize
    from tendon2r_gym.policies import inference

    old = _unpickled_vecnormalize(pkl)  # the trust option is required by main
    stats = read_stats(npz)
    shape = stats.obs_shape
    new = stats.vecnormalize(DummyVecEnv([lambda: _Blank(shape)]))
    for name in ("mean", "var"):
        theirs, ours = getattr(old.obs_rms, name), getattr(new.obs_rms, name)
        assert theirs.dtype == ours.dtype and np.array_equal(theirs, ours), name
    for key in ("norm_obs", "norm_reward", "training", "clip_obs", "clip_reward", "gamma"):
        assert getattr(old, key) == getattr(new, key), key
    assert old.epsilon == new.epsilon and old.obs_rms.count == new.obs_rms.count
    assert (old.ret_rms.mean, old.ret_rms.var) == (new.ret_rms.mean, new.ret_rms.var)
    assert old.ret_rms.count == new.ret_rms.count
    frames = 1
    zip_path = pkl.with_name(pkl.name.replace("_vecnormalize", "")).with_suffix(".zip")
    if zip_path.is_file():
        frames = PPO.load(zip_path, device="cpu").observation_space.shape[0] // shape[0]
    raw = observations(shape[0], N_OBS * frames)
    theirs, ours = old.normalize_obs(raw), new.normalize_obs(raw)
    assert theirs.dtype == ours.dtype and np.array_equal(theirs, ours), "normalized observations"
    done = f"{N_OBS * frames} normalized observations"
    if not zip_path.is_file():
        return done
    before, after = PPO.load(zip_path, device="cpu"), load_policy(zip_path)
    state, rebuilt = before.policy.state_dict(), after.policy.state_dict()
    assert list(state) == list(rebuilt), "the policy's parameters"
    assert all(torch.equal(state[k], rebuilt[k]) for k in state), "the policy's weights"
    for space in ("observation_space", "action_space"):
        was, now = getattr(before, space), getattr(after, space)
        assert (was.shape, was.dtype) == (now.shape, now.dtype), space
        assert np.array_equal(was.low, now.low) and np.array_equal(was.high, now.high), space
    x = ours.reshape(N_OBS, -1)
    exact = [inference.predict(m, x)[0] for m in (before, after)]
    sb3 = [m.policy.predict(x, deterministic=True)[0] for m in (before, after)]
    for what, (a, b) in (("inference", exact), ("SB3", sb3)):
        assert a.dtype == b.dtype and np.array_equal(a, b), f"actions ({what})"
    return f"{done}, weights and {N_OBS} actions (inference and SB3)"


def pickles(folders: list[str]) -> list[Path]:
    """Returns the pickled statistics under ``folders``, sorted."""
    found: set[Path] = set()
    for folder in map(Path, folders):
        if folder.is_file():
            found.add(folder)
        found.update(folder.rglob("*_vecnormalize*.pkl"))
    return sorted(found)


def main(argv: list[str] | None = None) -> list[Path]:
    args = parse(Args, argv)
    if not args.trust_pickle:
        raise ValueError(f"--trust-pickle = False is invalid; allowed: True ({TRUST_HELP})")
    if not args.folders:
        raise ValueError("--folders = [] is invalid; allowed: one or more folders or pkl files")
    converted = []
    for pkl in pickles(args.folders):
        npz = pkl.with_suffix(".npz")
        new = not npz.is_file()
        if new:
            convert_stats(pkl, npz, trust_pickle=True)
        try:
            what = check(pkl, npz)
        except AssertionError as e:
            if new:
                npz.unlink()
            print(f"error: {npz} differs from {pkl} ({e}); the pkl is kept", file=sys.stderr)
            raise SystemExit(1) from None
        if args.remove_pkl:
            pkl.unlink()
        print(f"{pkl} -> {npz.name}: bit-identical ({what})", flush=True)
        converted.append(npz)
    print(f"{len(converted)} file(s) converted and checked", flush=True)
    return converted


if __name__ == "__main__":
    main()
