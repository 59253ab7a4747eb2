"""Stand-ins for a teacher and a student in the distillation tests: policies whose actions are known."""

from __future__ import annotations

import numpy as np


class LinearTeacher:
    """A stateless teacher whose labels can be recomputed from the stored observations: a fixed linear map
    clipped to the action box (hover needs about -0.35 on the thrusts' normalised scale)."""

    def __init__(self):
        self.gain = np.zeros((4, 21))
        self.gain[0, 1] = self.gain[1, 1] = -0.3  # more thrust when below the reference
        self.gain[2, 2] = self.gain[3, 2] = 0.1
        self.calls = 0

    def label(self, obs):
        return np.clip(np.asarray(obs, float) @ self.gain.T - 0.35 * np.array([1, 1, 0, 0]), -1, 1)

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        self.calls += 1
        return self.label(obs).astype(np.float32), None


class ZeroStudent:
    """A student that applies the middle of every actuator's range, whatever it observes."""

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        return np.zeros((len(obs), 4), np.float32), None
