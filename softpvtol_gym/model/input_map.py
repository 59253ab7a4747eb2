"""Input maps tau = B(q) a: the generalized force of the actuators a = (T_l, T_r, tau_l, tau_r).

Two maps, selected by an integer code (a compile-time branch): ``INPUT_MAP_PAPER``, the paper's map as
printed, and ``INPUT_MAP_EXACT``, the virtual work of the thrusts at the rotated tips (docs/model.md).
:func:`held_force` is what every RK4 stage applies: the held command's force at that stage's
configuration plus an external force on the body (or, with ``HELD_TAU``, a held generalized force).
"""

from __future__ import annotations

import math

from ..params import P_EPS, P_LL, P_LR
from .jit import inline, jit
from .series import one_minus_cos_over_q2, sin_cos, sinc

INPUT_MAP_PAPER = 0
INPUT_MAP_EXACT = 1


@inline
def thrust_curvature_work(T, length, q):
    """Generalized force T l (1 - cos q)/q^2 of a thrust T on its own arm's curvature q (exact map)."""
    return T * length * one_minus_cos_over_q2(q)


@inline
def thrust_body_forces(st, ct, ql, qr, Tl, Tr, p, input_map):
    """The body rows (tau_x, tau_z, tau_theta) of :func:`generalized_forces` for thrusts (T_l, T_r) at
    curvatures (q_l, q_r), given st, ct = sin(theta), cos(theta)."""
    sl, cl = sin_cos(ql)
    sr, cr = sin_cos(qr)
    vx = Tl * sl - Tr * sr
    vz = Tl * cl + Tr * cr
    t0 = ct * vx - st * vz
    t1 = st * vx + ct * vz
    ll, lr, eps = p[P_LL], p[P_LR], p[P_EPS]
    if input_map == INPUT_MAP_PAPER:
        return t0, t1, lr * Tr * cr * sinc(qr) - ll * Tl * cl * sinc(ql)
    return t0, t1, Tr * (eps * cr + lr * sinc(qr)) - Tl * (eps * cl + ll * sinc(ql))


@inline
def generalized_forces_sc(st, ct, ql, qr, a, p, input_map):
    """:func:`generalized_forces` given st, ct = sin(theta), cos(theta) and the curvatures."""
    Tl, Tr = a[0], a[1]
    t0, t1, t2 = thrust_body_forces(st, ct, ql, qr, Tl, Tr, p, input_map)
    if input_map == INPUT_MAP_PAPER:
        return (t0, t1, t2, a[2], a[3])
    return (t0, t1, t2, a[2] + thrust_curvature_work(Tl, p[P_LL], ql), a[3] + thrust_curvature_work(Tr, p[P_LR], qr))


@inline
def generalized_forces(q, a, p, input_map):
    """tau = B(q) a for a = (T_l, T_r, tau_l, tau_r), as a 5-tuple (q, a: arrays or tuples).

    ``INPUT_MAP_PAPER``: the paper's map as printed (eq. 'control input in vector form').
    ``INPUT_MAP_EXACT``: virtual work of the thrusts applied at the (body-rotated) arm tips: adds
    the moment of the horizontal thrust components and of epsilon to tau_theta, and the work
    T_i l_i (1 - cos q_i)/q_i^2 of each thrust on its own curvature.
    """
    return generalized_forces_sc(math.sin(q[2]), math.cos(q[2]), q[3], q[4], a, p, input_map)


@jit
def generalized_forces_into(q, a, p, input_map, out):
    """:func:`generalized_forces` into the array ``out`` (5)."""
    t = generalized_forces(q, a, p, input_map)
    out[0] = t[0]
    out[1] = t[1]
    out[2] = t[2]
    out[3] = t[3]
    out[4] = t[4]



#: ``input_map`` code of :func:`held_force`: the held command is the generalized force tau itself
HELD_TAU = -1


@inline
def held_force(st, ct, q, u, ext, p, input_map):
    """Generalized force at the configuration q (st, ct = sin, cos of its theta) under a held command
    u, plus an external force ext = (f_x, f_z) on the body, as a 5-tuple.

    ``input_map`` ``INPUT_MAP_PAPER`` / ``INPUT_MAP_EXACT``: u = (T_l, T_r, tau_l, tau_r[, unused]) are
    the actuators and tau = B(q) u (:func:`generalized_forces`), so B is evaluated at q; ``HELD_TAU``:
    u is the generalized force (5) itself.
    """
    if input_map == HELD_TAU:
        t = (u[0], u[1], u[2], u[3], u[4])
    else:
        t = generalized_forces_sc(st, ct, q[3], q[4], u, p, input_map)
    return (t[0] + ext[0], t[1] + ext[1], t[2], t[3], t[4])
