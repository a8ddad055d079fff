"""The policy's observation history (tendon2r_gym.policies.history): SB3's VecFrameStack at stride
1,
every stride-th frame otherwise, emptied at each episode start, terminal observations too."""

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv, VecFrameStack

from tendon2r_gym.policies.history import FrameHistory
from tendon2r_gym.training.frame_stack import StridedFrameStack, stacked

KWARGS = {"preset": "default", "episode_duration": 0.012}  # 12 steps: episodes end


def _venv(n=2):
    venv = DummyVecEnv([lambda: gym.make("Tendon2R-v0", **KWARGS) for _ in range(n)])
    venv.seed(3)
    return venv


def _run(venv, steps=30):
    """Returns every observation and every terminal observation of ``steps`` random steps."""
    rng = np.random.default_rng(0)
    out, terminal = [venv.reset()], []
    for _ in range(steps):
        action = rng.uniform(-1, 1, (venv.num_envs, *venv.action_space.shape))
        obs, _, dones, infos = venv.step(action.astype(np.float32))
        out.append(obs)
        terminal += [infos[i]["terminal_observation"] for i in np.flatnonzero(dones)]
    return out, terminal


def test_stride_one_is_sb3_vec_frame_stack():
    ours, ours_terminal = _run(StridedFrameStack(_venv(), 4, 1))
    sb3, sb3_terminal = _run(VecFrameStack(_venv(), 4))
    assert len(ours_terminal) >= 2
    np.testing.assert_array_equal(np.array(ours), np.array(sb3))
    np.testing.assert_array_equal(np.array(ours_terminal), np.array(sb3_terminal))


def test_a_stride_picks_every_strideth_frame_of_the_episode_and_zeros_before_it():
    n, stride = 3, 4
    raw, raw_terminal = _run(_venv(1))
    ours, ours_terminal = _run(StridedFrameStack(_venv(1), n, stride))
    d = raw[0].shape[-1]
    starts = [0] + [t + 1 for t in range(len(raw) - 1) if t % 12 == 11]  # episode starts

    def expected(t, frames, start=None):
        start = max(s for s in starts if s <= t) if start is None else start
        want = np.zeros(n * d)
        for k in range(n):  # frame k of n, oldest first: t - (n - 1 - k) * stride
            past = t - (n - 1 - k) * stride
            if past >= start:
                want[k * d : (k + 1) * d] = frames[past][0]
        return want

    for t in range(len(raw)):
        np.testing.assert_array_equal(ours[t][0], expected(t, raw))
    # the first episode's terminal observation: at step 12, on that episode's frames
    terminal_frames = raw[:12] + [raw_terminal[0][None]]
    np.testing.assert_array_equal(ours_terminal[0], expected(12, terminal_frames, start=0))


def test_frame_history_empties_the_rows_that_start_only():
    history = FrameHistory(2, 2)
    for value in (1.0, 2.0, 3.0):
        out = history.push(np.full((2, 1), value))
    np.testing.assert_array_equal(out, [[1.0, 3.0], [1.0, 3.0]])
    out = history.push(np.full((2, 1), 4.0), start=[True, False])
    np.testing.assert_array_equal(out, [[0.0, 4.0], [2.0, 4.0]])


def test_stacked_keeps_sb3_wrappers_where_rl_zoo3_has_them():
    venv = _venv()
    assert stacked(venv, 1, 5) is venv
    assert isinstance(stacked(venv, 3), VecFrameStack)
    assert isinstance(stacked(venv, 3, 2), StridedFrameStack)


def test_a_stride_is_validated_and_refused_by_the_zoo_export():
    from tendon2r_gym.training import Hyperparams
    from tendon2r_gym.training.zoo import zoo_entry

    with pytest.raises(ValueError, match="frame_stride = 0"):
        Hyperparams.from_entry("default").replace(frame_stride=0)
    with pytest.raises(ValueError, match="frame_stride = 3 .* 1 when frame_stack is 1"):
        Hyperparams.from_entry("default").replace(frame_stride=3)
    with pytest.raises(ValueError, match="frame_stride = 2"):
        zoo_entry(Hyperparams.from_entry("default").replace(frame_stack=4, frame_stride=2))
