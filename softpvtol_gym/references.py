"""Compiled references of the built-in tasks, evaluated inside the step kernel (no NumPy round-trip).

A reference is (position, velocity, acceleration) of the body coordinates (x, z, theta) at episode
time t; its per-episode parameters are a row of ``N_REF_PARAMS`` numbers (the ``refp`` field of the
packed state), declared by :data:`REF_PARAMS`: the constant set-point (x, z, theta) in the ``setpoint``
columns; track_random: z0 in the set-point's z column (:data:`RP_Z0`) and three sinusoids
(a1, a2, a3, w1, w2, w3, phi1, phi2, phi3) for x and for z in ``x_sinusoids`` and ``z_sinusoids``. A task registered
from user code has no compiled reference (``REF_CUSTOM``): its Python ``reference(t)`` is called
once per step for the whole batch.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ._columns import Columns

_jit = njit(cache=True, fastmath=False, nogil=True, error_model="numpy")

#: columns of a reference parameter row (refp)
REF_PARAMS = Columns("reference_params", [("setpoint", 3), ("x_sinusoids", 9), ("z_sinusoids", 9)])
RP = REF_PARAMS.at
#: track_random's mean height z0 [m]: the set-point's z column
RP_Z0 = RP.setpoint + 1
N_REF_PARAMS = REF_PARAMS.size
REF_CUSTOM, REF_CONSTANT, REF_PAPER, REF_SINUSOIDS = -1, 0, 1, 2


@_jit
def _sinusoids(A, n, c, t):
    """sum_k a_k (sin(w_k t + phi_k) - sin phi_k) and its two time derivatives; (a, w, phi) x 3 in
    A[n, c:c + 9] as (a1, a2, a3, w1, w2, w3, phi1, phi2, phi3)."""
    p = v = a = 0.0
    for k in range(3):
        amp, w, ph = A[n, c + k], A[n, c + 3 + k], A[n, c + 6 + k]
        arg = w * t + ph
        s, co = math.sin(arg), math.cos(arg)
        p += amp * (s - math.sin(ph))
        v += amp * w * co
        a -= amp * w * w * s
    return p, v, a


@_jit
def paper_row(t):
    """The paper's eq. (traj_des) at time t [s]: x = 4 sin(t/2), z = 3 cos(-t/10) + 4 (theta = 0), as (x and its
    first four time derivatives, z and its first four). The derivatives are computed correctly: zdot = -0.3 sin(t/10)
    (the paper prints -0.3 sin(-t/10), a sign error; docs/model.md). The one definition of the trajectory: the
    step kernel reads its first three entries, :func:`softpvtol_gym.control.paper_reference` all five."""
    s, co = math.sin(0.5 * t), math.cos(0.5 * t)
    sz, cz = math.sin(0.1 * t), math.cos(0.1 * t)
    x = (4.0 * s, 2.0 * co, -s, -0.5 * co, 0.25 * s)
    z = (3.0 * math.cos(-0.1 * t) + 4.0, -0.3 * sz, -0.03 * cz, 0.003 * sz, 0.0003 * cz)
    return x, z


@njit(cache=True, nogil=True)
def paper_block(t, out):
    """out[n] = paper_row(t[n]) as (2, 5): row 0 x and its derivatives, row 1 z and its derivatives."""
    for n in range(t.shape[0]):
        x, z = paper_row(t[n])
        for k in range(5):
            out[n, 0, k] = x[k]
            out[n, 1, k] = z[k]


def paper_derivatives(t) -> np.ndarray:
    """:func:`paper_row` at times ``t`` [s] (any shape): (..., 2, 5), x and z with their first four derivatives."""
    t = np.asarray(t, dtype=np.float64)
    flat = np.ascontiguousarray(t.reshape(-1))
    out = np.empty((flat.shape[0], 2, 5))
    paper_block(flat, out)
    return out.reshape(t.shape + (2, 5))


@_jit
def reference_row(code, t, A, n, c):
    """((x, z, theta), their rates, their accelerations) at time t of a built-in reference ``code``
    whose parameters are A[n, c:c + N_REF_PARAMS]."""
    zero = (0.0, 0.0, 0.0)
    if code == REF_PAPER:
        x, z = paper_row(t)
        return (x[0], z[0], 0.0), (x[1], z[1], 0.0), (x[2], z[2], 0.0)
    if code == REF_SINUSOIDS:
        x, xd, xdd = _sinusoids(A, n, c + RP.x_sinusoids, t)
        z, zd, zdd = _sinusoids(A, n, c + RP.z_sinusoids, t)
        return (x, A[n, c + RP_Z0] + z, 0.0), (xd, zd, 0.0), (xdd, zdd, 0.0)
    o = c + RP.setpoint  # (x, z, theta)
    return (A[n, o], A[n, o + 1], A[n, o + 2]), zero, zero


@njit(cache=True, nogil=True)
def batch_reference(code, t, refp, out):
    """out[n] = (position (3), velocity (3), acceleration (3)) of row n at time t[n]."""
    for n in range(t.shape[0]):
        pos, vel, acc = reference_row(code, t[n], refp, n, 0)
        for i in range(3):
            out[n, i] = pos[i]
            out[n, 3 + i] = vel[i]
            out[n, 6 + i] = acc[i]


def evaluate(code: int, t, refp) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(pos, vel, acc), each (N, 3), of a compiled reference at times t (N,) with parameters refp (N, 21)."""
    t = np.ascontiguousarray(t, dtype=np.float64).reshape(-1)
    # (a writeable copy even of one row broadcast: one compiled signature)
    refp = np.array(np.broadcast_to(refp, (t.shape[0], N_REF_PARAMS)), dtype=np.float64, order="C")
    out = reference_block(code, t, refp)
    return out[:, 0:3], out[:, 3:6], out[:, 6:9]


def reference_block(code: int, t: np.ndarray, refp: np.ndarray) -> np.ndarray:
    """:func:`evaluate` as one (N, 9) array (position, velocity, acceleration) from t (N,) and refp (N, 21),
    both C-contiguous float64 (unchecked: the env's reset, on arrays it made)."""
    out = np.empty((t.shape[0], 9))
    batch_reference(code, t, refp, out)
    return out
