"""The observation: measured state (with noise in the noise tiers) relative to the reference."""

from __future__ import annotations

import math

from numba import njit

from .._columns import Columns
from .noise import STREAM_Q, STREAM_QD, counter_normal
from .packed_state import SC, SI, S

_jit = njit(cache=True, fastmath=False, nogil=True, error_model="numpy")

OBS_CLIP = 1.0e6
#: the observation's entries, declared once (the env writes them, PassivityPolicy reads them back)
OBSERVATION = Columns("observation", [
    ("e_pos", 2),  # x - x_ref, z - z_ref [m]
    ("e_theta", 1),  # theta - theta_ref, wrapped to [-pi, pi) [rad]
    ("sin_cos", 2),  # sin theta, cos theta
    ("arms", 2),  # q_l, q_r [rad]
    ("qd", 5),  # xdot, zdot [m/s], thetadot, q_l dot, q_r dot [rad/s]
    ("ref_vel", 3),  # xdot_ref, zdot_ref [m/s], thetadot_ref [rad/s]
    ("ref_acc", 3),  # xddot_ref, zddot_ref [m/s^2], thetaddot_ref [rad/s^2]
])
O = OBSERVATION.at
OBS_DIM = OBSERVATION.size
OBS_NAMES = (
    "x - x_ref", "z - z_ref", "theta - theta_ref", "sin theta", "cos theta", "q_l", "q_r",
    "xdot", "zdot", "thetadot", "q_l dot", "q_r dot",
    "xdot_ref", "zdot_ref", "thetadot_ref", "xddot_ref", "zddot_ref", "thetaddot_ref",
)

#: ``observe_error_integral=True``: the entries after OBS_DIM, the integrals of entries 0-2 over the episode
ERROR_INTEGRAL_NAMES = ("int (x - x_ref) dt", "int (z - z_ref) dt", "int (theta - theta_ref) dt")
N_ERROR_INTEGRALS = len(ERROR_INTEGRAL_NAMES)


@_jit
def wrap(a):
    """Angle wrapped to [-pi, pi): (a + pi) % 2 pi - pi, Python's float modulo. For a + pi already in
    [0, 2 pi) the modulo returns it unchanged (fmod is exact), so that case skips the modulo call
    (bit for bit the same result)."""
    x = a + math.pi
    if not (0.0 <= x < 2.0 * math.pi):
        x = x % (2.0 * math.pi)
    return x - math.pi


@_jit
def _clip(v):
    return min(max(v, -OBS_CLIP), OBS_CLIP)


@_jit
def observe_range(lo, hi, state, keys, istate, consts, obs):
    """Measured state (noise tiers: + Gaussian noise) into state's qm/qdm and the observation obs[n] of
    envs lo .. hi - 1."""
    noise = consts[SC.noise_on] > 0.0
    for n in range(lo, hi):
        counter = istate[n, SI.counter]
        for i in range(5):
            a = state[n, S.q + i]
            b = state[n, S.qd + i]
            if noise:
                a = a + consts[SC.noise_q + i] * counter_normal(keys[n], counter, STREAM_Q + i)
                b = b + consts[SC.noise_qd + i] * counter_normal(keys[n], counter, STREAM_QD + i)
            state[n, S.qm + i] = a
            state[n, S.qdm + i] = b
        obs[n, O.e_pos] = _clip(state[n, S.qm] - state[n, S.qr])
        obs[n, O.e_pos + 1] = _clip(state[n, S.qm + 1] - state[n, S.qr + 1])
        obs[n, O.e_theta] = _clip(wrap(state[n, S.qm + 2] - state[n, S.qr + 2]))
        th = state[n, S.qm + 2]
        s_th, c_th = math.sin(th), math.cos(th)  # side by side: one sincos call
        obs[n, O.sin_cos] = _clip(s_th)
        obs[n, O.sin_cos + 1] = _clip(c_th)
        obs[n, O.arms] = _clip(state[n, S.qm + 3])
        obs[n, O.arms + 1] = _clip(state[n, S.qm + 4])
        for i in range(5):
            obs[n, O.qd + i] = _clip(state[n, S.qdm + i])
        for i in range(3):
            obs[n, O.ref_vel + i] = _clip(state[n, S.qdr + i])
            obs[n, O.ref_acc + i] = _clip(state[n, S.qddr + i])
