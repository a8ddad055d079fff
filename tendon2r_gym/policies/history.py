"""The observation history a learned policy sees: its last ``n`` normalized observations taken
every ``stride`` control steps, oldest first, zeros before an episode's first.

With stride 1 this is SB3's VecFrameStack (rl_zoo3's ``frame_stack``), which training keeps
using then; a stride spreads the same ``n`` frames over ``(n - 1) * stride + 1`` steps, a
window long enough to tell the arm's response (e.g. a hidden mass error) from a few inputs.
`FrameHistory` is the one buffer: the training wrapper
(tendon2r_gym.training.frame_stack.StridedFrameStack) and the deployed policy
(tendon2r_gym.policies.learned.PPOPolicy) both stack through it."""

from __future__ import annotations

from typing import Any

import numpy as np


class FrameHistory:
    """The last ``(n - 1) * stride + 1`` frames of one observation or a batch of them."""

    def __init__(self, n: int, stride: int = 1) -> None:
        self.n, self.stride = n, stride
        self.span = (n - 1) * stride + 1
        self._frames: np.ndarray | None = None  # (*batch, span, d), newest last

    def clear(self) -> None:
        """Starts every history anew (the next frame is the first of its episode)."""
        self._frames = None

    def push(self, frame: np.ndarray, start: Any = None) -> np.ndarray:
        """Adds ``frame`` (shape (*batch, d)) as the newest; where ``start`` (a bool per batch
        row, as SB3's ``episode_start``) the history is emptied first.  Returns the stack."""
        frame = np.asarray(frame)
        if self._frames is None or self._frames.shape[:-2] != frame.shape[:-1]:
            self._frames = np.zeros((*frame.shape[:-1], self.span, frame.shape[-1]), frame.dtype)
        else:
            if start is not None:
                mask = np.broadcast_to(np.asarray(start, dtype=bool), frame.shape[:-1])
                self._frames[mask] = 0.0
            self._frames = np.roll(self._frames, -1, axis=-2)
        self._frames[..., -1, :] = frame
        return self.stack(self._frames)

    def peek(self, row: int, frame: np.ndarray) -> np.ndarray:
        """Returns batch row ``row``'s stack with ``frame`` pushed, leaving the history as it
        is (the stacked terminal observation of an episode that just ended)."""
        assert self._frames is not None
        frames = np.roll(self._frames[row], -1, axis=0)
        frames[-1] = frame
        return self.stack(frames)

    def stack(self, frames: np.ndarray) -> np.ndarray:
        """Returns the ``n`` frames every ``stride``-th of ``frames``, flattened oldest first (a
        new array: the history's buffer changes in place)."""
        picked = frames[..., :: self.stride, :]
        return picked.reshape(*picked.shape[:-2], -1).copy()
