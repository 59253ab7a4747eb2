"""Counter-based Gaussian noise: a value depends on (per-episode key, step counter, stream) only, so
the noise of an env does not depend on how many envs are stepped together or in which thread."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_jit = njit(cache=True, fastmath=False, nogil=True, error_model="numpy")

_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_GOLD = np.uint64(0x9E3779B97F4A7C15)
_N_STREAMS = np.uint64(16)
#: streams: 0-4 noise on q, 5-9 noise on qdot, 10-11 wind on x and z
STREAM_Q, STREAM_QD, STREAM_WIND = 0, 5, 10


@_jit
def _mix(z):
    """splitmix64's finaliser."""
    z = (z ^ (z >> np.uint64(30))) * _M1
    z = (z ^ (z >> np.uint64(27))) * _M2
    return z ^ (z >> np.uint64(31))


@_jit
def counter_normal(key, counter, stream):
    """Standard normal from (per-episode key, step counter, stream): splitmix64 hash + Box-Muller."""
    base = _mix(key ^ _mix(np.uint64(counter) * _N_STREAMS + np.uint64(stream) + _GOLD))
    h2 = _mix(base + _GOLD)
    u1 = (np.float64(base >> np.uint64(11)) + 1.0) * (1.0 / 9007199254740992.0)
    u2 = np.float64(h2 >> np.uint64(11)) * (1.0 / 9007199254740992.0)
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)
