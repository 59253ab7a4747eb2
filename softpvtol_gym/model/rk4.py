"""The classical RK4 step with the command held (zero-order hold), of the paper's and the consistent
model, on tuples (inlined into lane loops) and on arrays."""

from __future__ import annotations

import math

from ..params import P_EPS, P_G, P_I, P_IL, P_IR, P_LL, P_LR, P_M, P_ML, P_MR
from .consistent import consistent_qddot
from .input_map import held_force
from .jit import accessor, inline, jit
from .paper import qddot
from .series import rotate


@accessor
def _axpy5(x, c, v):
    """x + c v for 5-tuples."""
    return (x[0] + c * v[0], x[1] + c * v[1], x[2] + c * v[2], x[3] + c * v[3], x[4] + c * v[4])


@accessor
def _rk4_combine(x, v, a1, a2, a3, a4, h, dt, c):
    """RK4 update of one coordinate from its four stage accelerations."""
    # position slopes of the four stages: v, v + h a1, v + h a2, v + dt a3
    dq = v + 2.0 * (v + h * a1) + 2.0 * (v + h * a2) + (v + dt * a3)
    dv = a1 + 2.0 * a2 + 2.0 * a3 + a4
    return x + c * dq, v + c * dv


@accessor
def _rk4_update(q, qd, k1, k2, k3, k4, h, dt):
    """(q_next, qdot_next) as 5-tuples from the four stages' accelerations k1 .. k4 (h = dt / 2)."""
    c = dt / 6.0
    x0, w0 = _rk4_combine(q[0], qd[0], k1[0], k2[0], k3[0], k4[0], h, dt, c)
    x1, w1 = _rk4_combine(q[1], qd[1], k1[1], k2[1], k3[1], k4[1], h, dt, c)
    x2, w2 = _rk4_combine(q[2], qd[2], k1[2], k2[2], k3[2], k4[2], h, dt, c)
    x3, w3 = _rk4_combine(q[3], qd[3], k1[3], k2[3], k3[3], k4[3], h, dt, c)
    x4, w4 = _rk4_combine(q[4], qd[4], k1[4], k2[4], k3[4], k4[4], h, dt, c)
    return (x0, x1, x2, x3, x4), (w0, w1, w2, w3, w4)


@accessor
def _arguments(q, qd, u, ext, p):
    """The arrays of the ``*_into`` wrappers as the tuples the steps take (p: the 10 parameters they read)."""
    return ((q[0], q[1], q[2], q[3], q[4]), (qd[0], qd[1], qd[2], qd[3], qd[4]), (u[0], u[1], u[2], u[3], u[4]),
            (ext[0], ext[1]), (p[P_M], p[P_ML], p[P_MR], p[P_I], p[P_IL], p[P_IR], p[P_LL], p[P_LR], p[P_G], p[P_EPS]))


@inline
def rk4_step_sc(q, qd, s0, c0, u, ext, p, dt, input_map):
    r"""One classical RK4 step of (q, qdot) with the command u and the external force ext held
    (zero-order hold): at every stage the generalized force is :func:`held_force` at that stage's
    configuration, so held actuators see B(q) move with the state; with ``HELD_TAU`` the
    generalized force itself is held. (s0, c0) = (sin, cos) of q's theta; a stage's are
    :func:`rotate`\ d from them by its theta increment.

    q, qd, u (5), ext (2) and p (10) are arrays or tuples; returns (q_next, qdot_next) as 5-tuples.
    Stages: (q, v), (q + h v, v + h k1), (q + h v2, v + h k2), (q + dt v3, v + dt k3), h = dt / 2.
    """
    h = 0.5 * dt
    v1 = (qd[0], qd[1], qd[2], qd[3], qd[4])
    k1 = qddot(q[3], q[4], v1[3], v1[4], held_force(s0, c0, q, u, ext, p, input_map), p)
    q2, v2 = _axpy5(q, h, v1), _axpy5(v1, h, k1)
    s2, c2 = rotate(s0, c0, h * v1[2])
    k2 = qddot(q2[3], q2[4], v2[3], v2[4], held_force(s2, c2, q2, u, ext, p, input_map), p)
    q3, v3 = _axpy5(q, h, v2), _axpy5(v1, h, k2)
    s3, c3 = rotate(s0, c0, h * v2[2])
    k3 = qddot(q3[3], q3[4], v3[3], v3[4], held_force(s3, c3, q3, u, ext, p, input_map), p)
    q4, v4 = _axpy5(q, dt, v3), _axpy5(v1, dt, k3)
    s4, c4 = rotate(s0, c0, dt * v3[2])
    k4 = qddot(q4[3], q4[4], v4[3], v4[4], held_force(s4, c4, q4, u, ext, p, input_map), p)
    return _rk4_update(q, qd, k1, k2, k3, k4, h, dt)


@inline
def rk4_step(q, qd, u, ext, p, dt, input_map):
    """:func:`rk4_step_sc` from q alone (sin, cos of its theta by libm)."""
    return rk4_step_sc(q, qd, math.sin(q[2]), math.cos(q[2]), u, ext, p, dt, input_map)


@jit
def rk4_step_tuple(q, qd, u, ext, p, dt, input_map):
    """:func:`rk4_step` as a compiled call (tuples in and out): the one non-inlined copy of the step,
    shared by the array wrapper and partial lane blocks (inlining costs compile time)."""
    return rk4_step(q, qd, u, ext, p, dt, input_map)


@jit
def rk4_step_into(q, qd, u, ext, p, dt, input_map, q_out, qd_out):
    """:func:`rk4_step` on arrays. Allocation-free; ``q_out``/``qd_out`` may alias ``q``/``qd``."""
    qt, vt, ut, et, pt = _arguments(q, qd, u, ext, p)
    qn, vn = rk4_step_tuple(qt, vt, ut, et, pt, dt, input_map)
    q_out[0], q_out[1], q_out[2], q_out[3], q_out[4] = qn
    qd_out[0], qd_out[1], qd_out[2], qd_out[3], qd_out[4] = vn


@jit
def consistent_stage(st, ct, q, qd, u, ext, p, held):
    """qddot of the consistent model at one RK4 stage under the held command (:func:`held_force`);
    one compiled copy shared by the four stages."""
    return consistent_qddot(st, ct, q, qd, held_force(st, ct, q, u, ext, p, held), p)


@inline
def consistent_rk4_step(q, qd, u, ext, p, dt, held):
    """:func:`rk4_step` of the consistent model: the same classical RK4 stages with the command held
    (``held``: ``HELD_TAU``, or ``INPUT_MAP_EXACT``, the consistent model's own input map: the virtual
    work of the thrusts at the rotated tips); each stage's attitude by libm sin/cos (not SIMD code)."""
    h = 0.5 * dt
    v1 = (qd[0], qd[1], qd[2], qd[3], qd[4])
    s1, c1 = math.sin(q[2]), math.cos(q[2])
    k1 = consistent_stage(s1, c1, q, v1, u, ext, p, held)
    q2, v2 = _axpy5(q, h, v1), _axpy5(v1, h, k1)
    s2, c2 = math.sin(q2[2]), math.cos(q2[2])
    k2 = consistent_stage(s2, c2, q2, v2, u, ext, p, held)
    q3, v3 = _axpy5(q, h, v2), _axpy5(v1, h, k2)
    s3, c3 = math.sin(q3[2]), math.cos(q3[2])
    k3 = consistent_stage(s3, c3, q3, v3, u, ext, p, held)
    q4, v4 = _axpy5(q, dt, v3), _axpy5(v1, dt, k3)
    s4, c4 = math.sin(q4[2]), math.cos(q4[2])
    k4 = consistent_stage(s4, c4, q4, v4, u, ext, p, held)
    return _rk4_update(q, qd, k1, k2, k3, k4, h, dt)


@jit
def consistent_rk4_step_tuple(q, qd, u, ext, p, dt, held):
    """:func:`consistent_rk4_step` as a compiled call (tuples in and out)."""
    return consistent_rk4_step(q, qd, u, ext, p, dt, held)


@jit
def consistent_rk4_step_into(q, qd, u, ext, p, dt, held, q_out, qd_out):
    """:func:`consistent_rk4_step` on arrays (see :func:`rk4_step_into`)."""
    qt, vt, ut, et, pt = _arguments(q, qd, u, ext, p)
    qn, vn = consistent_rk4_step_tuple(qt, vt, ut, et, pt, dt, held)
    q_out[0], q_out[1], q_out[2], q_out[3], q_out[4] = qn
    qd_out[0], qd_out[1], qd_out[2], qd_out[3], qd_out[4] = vn
