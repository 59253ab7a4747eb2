"""The frame stack of a learned policy in evaluation: SB3's VecFrameStack semantics on a batch of sub-envs."""

from __future__ import annotations

import numpy as np


class ObservationStack:
    """The last ``k`` observations of each of a batch of sub-envs, oldest first, as SB3's VecFrameStack feeds a
    model in training: :meth:`push` shifts each sub-env's stack by one observation, empties it (zeros) where
    ``episode_start`` is true, and puts the new observation last. ``width`` is the model's input size
    (``k`` x the size of one observation); ``dtype`` the stack's."""

    def __init__(self, k: int, width: int, dtype=np.float32):
        if isinstance(k, bool) or not isinstance(k, int) or k < 1:
            raise ValueError(f"frame_stack must be an integer >= 1, got {k!r}")
        if width % k:
            raise ValueError(f"the model takes {width} numbers, not a multiple of frame_stack={k}")
        self.k, self.width, self.dtype = k, width, np.dtype(dtype)
        self._stack: np.ndarray | None = None

    def reset(self) -> None:
        """Forget the stacks (the next :meth:`push` starts every sub-env's stack afresh)."""
        self._stack = None

    def push(self, obs: np.ndarray, episode_start=None) -> np.ndarray:
        """The model's input (a new array) for observations ``obs`` (n_envs, width / k). ``episode_start``: n_envs
        bools (true: that sub-env's episode starts, its stack is emptied first), or None: every stack starts on
        the first call (and on a call with another number of sub-envs), later calls continue them."""
        starts = self.starts(obs, episode_start)
        dim = obs.shape[1]
        # VecFrameStack's update: shift by one observation, zeros where an episode starts, the new one last
        self._stack = np.roll(self._stack, -dim, axis=-1)
        self._stack[starts] = 0
        self._stack[:, -dim:] = obs
        return self._stack.copy()

    def starts(self, obs: np.ndarray, episode_start=None) -> np.ndarray:
        """The sub-envs whose stacks start with this call (n_envs bools), for observations ``obs`` (n_envs,
        width / k) and ``episode_start`` as :meth:`push` takes them; the stacks are allocated (zeros) on the first
        call. :meth:`push` then updates them; a compiled caller updates :attr:`rows` in place the same way."""
        if obs.ndim != 2:
            raise ValueError(f"a frame-stacked policy takes a batch of observations (n_envs, obs_dim), got an "
                             f"array of shape {obs.shape}")
        n, dim = obs.shape
        if dim * self.k != self.width:
            raise ValueError(f"the model takes {self.width} numbers ({self.k} stacked observations), "
                             f"got observations of {dim}")
        fresh = self._stack is None or self._stack.shape[0] != n
        if episode_start is None:
            starts = np.full(n, fresh)
        else:
            starts = np.asarray(episode_start, bool)
            if starts.size != n:
                raise ValueError(f"episode_start must hold one bool per sub-env ({n}), got shape {starts.shape}")
            starts = starts.reshape(n)
        if fresh:
            if not starts.all():
                raise ValueError(f"the frame stack holds {0 if self._stack is None else self._stack.shape[0]} "
                                 f"sub-envs, the call has {n}: pass episode_start all true to start new stacks")
            self._stack = np.zeros((n, self.width), dtype=self.dtype)
        return starts

    @property
    def rows(self) -> np.ndarray | None:
        """The stacks (n_envs, width), each sub-env's last k observations oldest first; None before the first call."""
        return self._stack


def frame_stack_wrapper(venv):
    """The VecFrameStack in a chain of SB3 VecEnv wrappers, or None."""
    from stable_baselines3.common.vec_env import VecEnvWrapper, VecFrameStack

    while isinstance(venv, VecEnvWrapper):
        if isinstance(venv, VecFrameStack):
            return venv
        venv = venv.venv
    return None
