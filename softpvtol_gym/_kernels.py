"""Compiled physics kernels: the single source of truth of the Soft-PVTOL model.

Everything physical (D, C, g, the input maps, forward dynamics, energies, tip positions, the RK4 step)
is written once here as numba-compiled functions of one state and the flat parameter vector
``p = SoftPVTOLParams.array``. The public batched API (:mod:`softpvtol_gym.dynamics`,
:mod:`softpvtol_gym.integrators`), the env, the vector env and the controller all call these.

Why numba: the model is a few dozen flops per state, so NumPy's per-call overhead (~1 us per ufunc on
tiny arrays) would dominate both the single env (hundreds of ufunc calls per RK4 step) and batched
rollouts (many temporaries). ``njit(cache=True)`` compiles the scalar code once per machine, keeps one
copy of the physics for single and batched use, and ``fastmath`` stays off so that results are bit for
bit identical between the single env and every sub-env of the vector env.

Two models: the paper's (the functions without prefix; its rotor masses on tips that do not rotate
with theta) and the consistent one (``consistent_*``: the same energy terms with the tips rotated by
theta; docs/model.md). The env's SIMD lane step is the paper model's; the consistent one runs lane by
lane (:func:`rk4_lanes_consistent`).

Conventions: q = (x, z, theta, q_l, q_r); p in ``PARAM_FIELDS`` order
(m, m_l, m_r, I, I_l, I_r, l_l, l_r, g, epsilon); actuators a = (T_l, T_r, tau_l, tau_r).

Speed (see ``benchmarks/``): the small, pure-arithmetic functions (series, D entries, qddot, the RK4
step, energies) are inlined into their callers (``inline="always"``) and take arrays *or* tuples, so a
loop over a block of ``LANES`` states stored structure-of-arrays (:func:`rk4_lanes`) compiles to SIMD
code. The series polynomial :func:`horner` is the exception: a plain compiled call that LLVM inlines
(numba's own inliner re-types and copies each of its few hundred inlined copies per kernel, which was
most of the cold compile time). Every lane performs exactly the scalar IEEE operations (no fastmath,
no FMA contraction), so the SIMD path is bit-identical to the scalar one; the tests check it. The
error model is numpy's (x/0 gives inf/nan instead of raising), which the vectoriser needs; no division
here has a zero denominator for valid parameters.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ._layout import Layout
from ._series import COEFFICIENTS

_S0 = COEFFICIENTS["S0"]
_C1 = COEFFICIENTS["C1"]
_A = COEFFICIENTS["A"]
_D1P = COEFFICIENTS["D1p"]
_D2 = COEFFICIENTS["D2"]
_D2PQ = COEFFICIENTS["D2pq"]

INPUT_MAP_PAPER = 0
INPUT_MAP_EXACT = 1

_jit = njit(cache=True, fastmath=False, nogil=True, error_model="numpy")
#: small pure functions: inlined into every caller (needed for the SIMD lane loops)
_inline = njit(cache=True, fastmath=False, nogil=True, error_model="numpy", inline="always")


#: coefficients of every series (``_series.N_TERMS``): :func:`horner` is written out for this many
HORNER_TERMS = 18
if any(len(c) != HORNER_TERMS for c in COEFFICIENTS.values()):  # pragma: no cover
    raise RuntimeError(f"_kernels.horner is written out for {HORNER_TERMS} coefficients; update it for "
                       f"{ {k: len(c) for k, c in COEFFICIENTS.items()} }")


@_jit
def horner(c, s):
    """c[0] + c[1] s + ... + c[17] s^17 by Horner's rule, from the highest coefficient down.

    The one small function here that numba does *not* inline: it is called a few hundred times per
    step kernel, and numba's inliner re-types and copies every inlined copy (most of the cold compile
    time). LLVM inlines the call (so lane loops stay SIMD); written out rather than looped, it is one
    straight block, the same operations in the same order as the loop."""
    acc = c[17]
    acc = acc * s + c[16]
    acc = acc * s + c[15]
    acc = acc * s + c[14]
    acc = acc * s + c[13]
    acc = acc * s + c[12]
    acc = acc * s + c[11]
    acc = acc * s + c[10]
    acc = acc * s + c[9]
    acc = acc * s + c[8]
    acc = acc * s + c[7]
    acc = acc * s + c[6]
    acc = acc * s + c[5]
    acc = acc * s + c[4]
    acc = acc * s + c[3]
    acc = acc * s + c[2]
    acc = acc * s + c[1]
    acc = acc * s + c[0]
    return acc


@_inline
def arm_basis(q):
    """(D1, D2, dD1/dq, dD2/dq) of one arm's curvature q: branch-free power series."""
    s = q * q
    return q * horner(_A, s), horner(_D2, s), horner(_D1P, s), q * horner(_D2PQ, s)


@_inline
def sinc(q):
    return horner(_S0, q * q)


@_inline
def one_minus_cos_over_q2(q):
    return horner(_C1, q * q)


@_inline
def sin_cos(q):
    """(sin q, cos q) = (q sinc q, 1 - q^2 (1 - cos q)/q^2) from the same series as the rest of the
    model (a few ulps for |q| <= 1.2 pi, 3e-14 at 2 pi): polynomial arithmetic only, so that a lane
    loop that evaluates the input map stays SIMD code. Used for the arm curvatures."""
    s = q * q
    return q * horner(_S0, s), 1.0 - s * horner(_C1, s)


TWO_PI = 2.0 * math.pi


@_inline
def rotate(s0, c0, d):
    """(sin, cos) of theta + d from (s0, c0) = (sin theta, cos theta), d reduced to [-pi, pi] and
    evaluated by the series (branch-free, SIMD): the attitude at an RK4 stage from the step's start."""
    d = d - TWO_PI * math.floor(d / TWO_PI + 0.5)
    sd, cd = sin_cos(d)
    return s0 * cd + c0 * sd, c0 * cd - s0 * sd


# --------------------------------------------------------------------------------------- model terms
@_inline
def mass_entries(ql, qr, p):
    """The nonzero entries of D(q): (M, I, D03, D13, D04, D14, D33, D44), D symmetric.

    Only the curvatures enter; D = [[M, 0, 0, D03, D04], [0, M, 0, D13, D14], [0, 0, I, 0, 0], ...].
    """
    return mass_entries_basis(arm_basis(ql), arm_basis(qr), p)


@_inline
def mass_entries_basis(bl, br, p):
    """:func:`mass_entries` from the arms' :func:`arm_basis` (bl, br): a caller that needs D, C and g
    evaluates each arm's series once (the same values; one inlined copy instead of three, which keeps
    the cold compile short)."""
    ml, mr, ll, lr = p[1], p[2], p[6], p[7]
    d1l, d2l = bl[0], bl[1]
    d1r, d2r = br[0], br[1]
    M = p[0] + p[1] + p[2]
    return (
        M,
        p[3],
        ml * ll * d1l,
        ml * ll * d2l,
        -mr * lr * d1r,
        mr * lr * d2r,
        ml * ll * ll * (d1l * d1l + d2l * d2l) + p[4],
        mr * lr * lr * (d1r * d1r + d2r * d2r) + p[5],
    )


@_jit
def mass_matrix_into(q, p, out):
    """D(q) (5x5) into ``out``. Only q_l, q_r enter: theta decouples (paper eq. (inertia))."""
    M, inertia, d03, d13, d04, d14, d33, d44 = mass_entries(q[3], q[4], p)
    for i in range(5):
        for j in range(5):
            out[i, j] = 0.0
    out[0, 0] = M
    out[1, 1] = M
    out[2, 2] = inertia
    out[0, 3] = out[3, 0] = d03
    out[1, 3] = out[3, 1] = d13
    out[0, 4] = out[4, 0] = d04
    out[1, 4] = out[4, 1] = d14
    out[3, 3] = d33
    out[4, 4] = d44


@_inline
def coriolis_entries(ql, qr, vl, vr, p):
    """The nonzero entries of C(q, qdot): (C03, C13, C04, C14, C33, C44) (Christoffel symbols of the
    first kind, so that Ddot - 2C is skew); only the curvatures and their rates enter."""
    return coriolis_entries_basis(arm_basis(ql), arm_basis(qr), vl, vr, p)


@_inline
def coriolis_entries_basis(bl, br, vl, vr, p):
    """:func:`coriolis_entries` from the arms' :func:`arm_basis` (see :func:`mass_entries_basis`)."""
    ml, mr, ll, lr = p[1], p[2], p[6], p[7]
    d1l, d2l, d1pl, d2pl = bl
    d1r, d2r, d1pr, d2pr = br
    return (
        ml * ll * d1pl * vl,
        ml * ll * d2pl * vl,
        -mr * lr * d1pr * vr,
        mr * lr * d2pr * vr,
        ml * ll * ll * (d1l * d1pl + d2l * d2pl) * vl,
        mr * lr * lr * (d1r * d1pr + d2r * d2pr) * vr,
    )


@_jit
def coriolis_matrix_into(q, qd, p, out):
    """C(q, qdot) (5x5) into ``out``: :func:`coriolis_entries`, zeros elsewhere."""
    c03, c13, c04, c14, c33, c44 = coriolis_entries(q[3], q[4], qd[3], qd[4], p)
    for i in range(5):
        for j in range(5):
            out[i, j] = 0.0
    out[0, 3] = c03
    out[1, 3] = c13
    out[0, 4] = c04
    out[1, 4] = c14
    out[3, 3] = c33
    out[4, 4] = c44


@_inline
def gravity_entries(ql, qr, p):
    """The nonzero entries of g(q) = dP/dq: (g1, g3, g4) (g0 = g2 = 0)."""
    return gravity_entries_basis(arm_basis(ql), arm_basis(qr), p)


@_inline
def gravity_entries_basis(bl, br, p):
    """:func:`gravity_entries` from the arms' :func:`arm_basis` (see :func:`mass_entries_basis`)."""
    d2l, d2r = bl[1], br[1]
    return p[8] * (p[0] + p[1] + p[2]), p[8] * p[1] * p[6] * d2l, p[8] * p[2] * p[7] * d2r


@_jit
def gravity_vector_into(q, p, out):
    """g(q) = dP/dq."""
    g1, g3, g4 = gravity_entries(q[3], q[4], p)
    out[0] = 0.0
    out[1] = g1
    out[2] = 0.0
    out[3] = g3
    out[4] = g4


@_inline
def thrust_curvature_work(T, length, q):
    """Generalized force T l (1 - cos q)/q^2 of a thrust T on its own arm's curvature q (exact map)."""
    return T * length * one_minus_cos_over_q2(q)


@_inline
def thrust_body_forces(st, ct, ql, qr, Tl, Tr, p, input_map):
    """The body rows (tau_x, tau_z, tau_theta) of :func:`generalized_forces` for thrusts (T_l, T_r) at
    curvatures (q_l, q_r), given st, ct = sin(theta), cos(theta)."""
    sl, cl = sin_cos(ql)
    sr, cr = sin_cos(qr)
    vx = Tl * sl - Tr * sr
    vz = Tl * cl + Tr * cr
    t0 = ct * vx - st * vz
    t1 = st * vx + ct * vz
    ll, lr, eps = p[6], p[7], p[9]
    if input_map == INPUT_MAP_PAPER:
        return t0, t1, lr * Tr * cr * sinc(qr) - ll * Tl * cl * sinc(ql)
    return t0, t1, Tr * (eps * cr + lr * sinc(qr)) - Tl * (eps * cl + ll * sinc(ql))


@_inline
def generalized_forces_sc(st, ct, ql, qr, a, p, input_map):
    """:func:`generalized_forces` given st, ct = sin(theta), cos(theta) and the curvatures."""
    Tl, Tr = a[0], a[1]
    t0, t1, t2 = thrust_body_forces(st, ct, ql, qr, Tl, Tr, p, input_map)
    if input_map == INPUT_MAP_PAPER:
        return (t0, t1, t2, a[2], a[3])
    return (t0, t1, t2, a[2] + thrust_curvature_work(Tl, p[6], ql), a[3] + thrust_curvature_work(Tr, p[7], qr))


@_inline
def generalized_forces(q, a, p, input_map):
    """tau = B(q) a for a = (T_l, T_r, tau_l, tau_r), as a 5-tuple (q, a: arrays or tuples).

    ``INPUT_MAP_PAPER``: the paper's map as printed (eq. 'control input in vector form').
    ``INPUT_MAP_EXACT``: virtual work of the thrusts applied at the (body-rotated) arm tips: adds
    the moment of the horizontal thrust components and of epsilon to tau_theta, and the work
    T_i l_i (1 - cos q_i)/q_i^2 of each thrust on its own curvature.
    """
    return generalized_forces_sc(math.sin(q[2]), math.cos(q[2]), q[3], q[4], a, p, input_map)


@_jit
def generalized_forces_into(q, a, p, input_map, out):
    """:func:`generalized_forces` into the array ``out`` (5)."""
    t = generalized_forces(q, a, p, input_map)
    out[0] = t[0]
    out[1] = t[1]
    out[2] = t[2]
    out[3] = t[3]
    out[4] = t[4]


@_inline
def qddot(ql, qr, vl, vr, tau, p):
    """qddot = D^-1 (tau - C qdot - g) as a 5-tuple.

    D, C and g (their entries: :func:`mass_entries`, :func:`coriolis_entries`, :func:`gravity_entries`)
    depend only on the curvatures and their rates, so only (q_l, q_r, q_l', q_r') enter. The solve uses
    the block structure of D: theta decouples, and the body block M*I2 is eliminated by a Schur
    complement, leaving a 2x2 system for the arms. Allocation-free (scalars only).
    """
    bl, br = arm_basis(ql), arm_basis(qr)
    M, inertia, a0, a1, b0, b1, dll, drr = mass_entries_basis(bl, br, p)
    c03, c13, c04, c14, c33, c44 = coriolis_entries_basis(bl, br, vl, vr, p)
    g1, g3, g4 = gravity_entries_basis(bl, br, p)
    # right-hand side tau - C qdot - g (C qdot: rows 0, 1 from both arms, rows 3, 4 from their own)
    r0 = tau[0] - (c03 * vl + c04 * vr)
    r1 = tau[1] - (c13 * vl + c14 * vr) - g1
    r3 = tau[3] - c33 * vl - g3
    r4 = tau[4] - c44 * vr - g4
    # Schur complement of the body block M*I2; a = D[0:2, 3], b = D[0:2, 4]
    s11 = dll - (a0 * a0 + a1 * a1) / M
    s22 = drr - (b0 * b0 + b1 * b1) / M
    s12 = -(a0 * b0 + a1 * b1) / M
    h3 = r3 - (a0 * r0 + a1 * r1) / M
    h4 = r4 - (b0 * r0 + b1 * r1) / M
    det = s11 * s22 - s12 * s12
    qdd_l = (s22 * h3 - s12 * h4) / det
    qdd_r = (s11 * h4 - s12 * h3) / det
    return (
        (r0 - a0 * qdd_l - b0 * qdd_r) / M,
        (r1 - a1 * qdd_l - b1 * qdd_r) / M,
        tau[2] / inertia,
        qdd_l,
        qdd_r,
    )


@_jit
def forward_dynamics_into(q, qd, tau, p, out):
    a = qddot(q[3], q[4], qd[3], qd[4], tau, p)
    for i in range(5):
        out[i] = a[i]


@_inline
def kinetic_energy(q, qd, p):
    """T = 1/2 qdot^T D(q) qdot from D's entries (:func:`mass_entries`)."""
    M, inertia, d03, d13, d04, d14, d33, d44 = mass_entries(q[3], q[4], p)
    vx, vz, w, vl, vr = qd[0], qd[1], qd[2], qd[3], qd[4]
    e = M * (vx * vx + vz * vz) + inertia * w * w
    e += 2.0 * vl * (d03 * vx + d13 * vz) + 2.0 * vr * (d04 * vx + d14 * vz)
    e += d33 * vl * vl + d44 * vr * vr
    return 0.5 * e


@_inline
def potential_energy(q, p):
    """P = g (M z + m_l z_l^tip + m_r z_r^tip), tip heights l q (1 - cos q)/q^2 above the body."""
    zl = p[6] * q[3] * one_minus_cos_over_q2(q[3])
    zr = p[7] * q[4] * one_minus_cos_over_q2(q[4])
    return p[8] * ((p[0] + p[1] + p[2]) * q[1] + p[1] * zl + p[2] * zr)


@_jit
def arm_offset(q_arm, length, eps, side):
    """Body-frame (x, z) of the tip of an arm of curvature q_arm; side = -1 left, +1 right."""
    return side * (eps + length * sinc(q_arm)), length * q_arm * one_minus_cos_over_q2(q_arm)


@_jit
def tip_positions_into(q, p, out):
    """World (x, z) of the left (out[0]) and right (out[1]) tips: p_v + R(theta) r_i(q_i)."""
    ct, st = math.cos(q[2]), math.sin(q[2])
    for i in range(2):
        side = -1.0 if i == 0 else 1.0
        rx, rz = arm_offset(q[3 + i], p[6 + i], p[9], side)
        out[i, 0] = q[0] + ct * rx - st * rz
        out[i, 1] = q[1] + st * rx + ct * rz


# --------------------------------------------------------------------------- the consistent model
# The paper's energy terms with the rotor masses at the *rotated* tips p_i = p_v + R(theta) r_i(q_i)
# (``docs/model.md``, "The consistent model"). In body-frame vectors (R orthogonal; J = [[0, -1], [1, 0]]
# the 90-degree rotation, dR/dtheta = R J): r_i the tip offset, e_i = dr_i/dq_i, e'_i = de_i/dq_i. The
# Jacobian of p_i has the columns (1, 0), (0, 1), R J r_i (theta) and R e_i (its own curvature), so
#   D = sum_i m_i J_i^T J_i + diag(m, m, I, I_l, I_r),   C = sum_i m_i J_i^T Jdot_i,
# (for point masses the Christoffel C is exactly sum m J^T Jdot), g = dP/dq, P = g (M z + sum m_i z_i).
MODEL_PAPER = 0
MODEL_CONSISTENT = 1


@_inline
def consistent_arm(q_arm, length, eps, side):
    """Body-frame (r, e, e') of one arm, side = -1 left, +1 right: the tip offset r = (side (eps + l S0),
    l q C1), e = dr/dq = (-side l D1, l D2) and e' = de/dq = (-side l D1', l D2'), as a 6-tuple
    (r_x, r_z, e_x, e_z, e'_x, e'_z). Series only: smooth at q = 0."""
    d1, d2, d1p, d2p = arm_basis(q_arm)
    return (side * (eps + length * sinc(q_arm)), length * q_arm * one_minus_cos_over_q2(q_arm),
            -side * length * d1, length * d2, -side * length * d1p, length * d2p)


@_inline
def consistent_arms(ql, qr, p):
    """:func:`consistent_arm` of the left and the right arm."""
    return consistent_arm(ql, p[6], p[9], -1.0), consistent_arm(qr, p[7], p[9], 1.0)


@_inline
def consistent_mass_entries(st, ct, al, ar, p):
    """The upper-triangle entries of the consistent D: (M, D02, D12, D03, D13, D04, D14, D22, D23, D24,
    D33, D44) (D01 = D34 = 0), given st, ct = sin, cos of theta and the arms' :func:`consistent_arm`."""
    ml, mr = p[1], p[2]
    M = p[0] + ml + mr
    # first moment s = sum m_i r_i; column theta of the tips' Jacobians summed: R J s
    sx = ml * al[0] + mr * ar[0]
    sz = ml * al[1] + mr * ar[1]
    return (
        M,
        -ct * sz - st * sx,
        -st * sz + ct * sx,
        ml * (ct * al[2] - st * al[3]),
        ml * (st * al[2] + ct * al[3]),
        mr * (ct * ar[2] - st * ar[3]),
        mr * (st * ar[2] + ct * ar[3]),
        p[3] + ml * (al[0] * al[0] + al[1] * al[1]) + mr * (ar[0] * ar[0] + ar[1] * ar[1]),
        ml * (al[0] * al[3] - al[1] * al[2]),
        mr * (ar[0] * ar[3] - ar[1] * ar[2]),
        p[4] + ml * (al[2] * al[2] + al[3] * al[3]),
        p[5] + mr * (ar[2] * ar[2] + ar[3] * ar[3]),
    )


@_jit
def consistent_mass_matrix_into(q, p, out):
    """The consistent D(q) (5x5) into ``out``: depends on theta and the curvatures."""
    al, ar = consistent_arms(q[3], q[4], p)
    M, d02, d12, d03, d13, d04, d14, d22, d23, d24, d33, d44 = consistent_mass_entries(
        math.sin(q[2]), math.cos(q[2]), al, ar, p)
    for i in range(5):
        for j in range(5):
            out[i, j] = 0.0
    out[0, 0] = M
    out[1, 1] = M
    out[0, 2] = out[2, 0] = d02
    out[1, 2] = out[2, 1] = d12
    out[0, 3] = out[3, 0] = d03
    out[1, 3] = out[3, 1] = d13
    out[0, 4] = out[4, 0] = d04
    out[1, 4] = out[4, 1] = d14
    out[2, 2] = d22
    out[2, 3] = out[3, 2] = d23
    out[2, 4] = out[4, 2] = d24
    out[3, 3] = d33
    out[4, 4] = d44


@_jit
def consistent_coriolis_matrix_into(q, qd, p, out):
    """The consistent C(q, qdot) = sum_i m_i J_i^T Jdot_i (the Christoffel form) into ``out``.

    Per arm i (its curvature column a): Jdot_i's theta column is R u2, u2 = -thetadot r + qdot_i J e,
    and its column a is R ua, ua = thetadot J e + qdot_i e'; the rows of J_i^T are (1, 0), (0, 1),
    R J r and R e, so the entries are m_i times the body-frame dot products below."""
    st, ct = math.sin(q[2]), math.cos(q[2])
    w = qd[2]
    for i in range(5):
        for j in range(5):
            out[i, j] = 0.0
    for i in range(2):
        side = -1.0 if i == 0 else 1.0
        a = 3 + i
        mi = p[1 + i]
        rx, rz, ex, ez, epx, epz = consistent_arm(q[a], p[6 + i], p[9], side)
        v = qd[a]
        u2x, u2z = -w * rx - v * ez, -w * rz + v * ex
        uax, uaz = -w * ez + v * epx, w * ex + v * epz
        out[0, 2] += mi * (ct * u2x - st * u2z)
        out[1, 2] += mi * (st * u2x + ct * u2z)
        out[0, a] = mi * (ct * uax - st * uaz)
        out[1, a] = mi * (st * uax + ct * uaz)
        # J r = (-rz, rx)
        out[2, 2] += mi * (-rz * u2x + rx * u2z)
        out[2, a] = mi * (-rz * uax + rx * uaz)
        out[a, 2] = mi * (ex * u2x + ez * u2z)
        out[a, a] = mi * (ex * uax + ez * uaz)


@_inline
def consistent_gravity_entries(st, ct, al, ar, p):
    """(g1, g2, g3, g4) of the consistent g = dP/dq (g0 = 0): g_j = g (sum_i m_i dp_i/dq_j)_z."""
    ml, mr, grav = p[1], p[2], p[8]
    sx = ml * al[0] + mr * ar[0]
    sz = ml * al[1] + mr * ar[1]
    return (grav * (p[0] + ml + mr), grav * (ct * sx - st * sz),
            grav * ml * (st * al[2] + ct * al[3]), grav * mr * (st * ar[2] + ct * ar[3]))


@_jit
def consistent_gravity_vector_into(q, p, out):
    al, ar = consistent_arms(q[3], q[4], p)
    g1, g2, g3, g4 = consistent_gravity_entries(math.sin(q[2]), math.cos(q[2]), al, ar, p)
    out[0] = 0.0
    out[1] = g1
    out[2] = g2
    out[3] = g3
    out[4] = g4


@_inline
def consistent_bias_arm(w, v, arm, mi):
    """m_i J_i^T Jdot_i qdot of one arm in body-frame terms: returns (the body-frame force f = m_i beta
    on the body (x, z), its theta moment, its curvature row), beta = -w^2 r + 2 w v J e + v^2 e'
    (w = thetadot, v = the arm's curvature rate)."""
    rx, rz, ex, ez, epx, epz = arm
    bx = -w * w * rx - 2.0 * w * v * ez + v * v * epx
    bz = -w * w * rz + 2.0 * w * v * ex + v * v * epz
    return mi * bx, mi * bz, mi * (-rz * bx + rx * bz), mi * (ex * bx + ez * bz)


@_jit
def consistent_qddot(st, ct, q, qd, tau, p):
    """qddot = D^-1 (tau - C qdot - g) of the consistent model as a 5-tuple (st, ct = sin, cos of theta).

    D = [[M I2, B], [B^T, E]] with B = D[0:2, 2:5]: the body block M I2 is eliminated (Schur complement
    S = E - B^T B / M, 3x3 SPD), S is solved by a written-out Cholesky factorisation, then the body rows.
    Allocation-free (scalars only). A compiled call, not inlined: the consistent model does not run in
    the SIMD lane loops, and one copy instead of one per RK4 stage keeps the env's cold compile short."""
    al, ar = consistent_arms(q[3], q[4], p)
    M, b0, b1, c0, c1, d0, d1, e22, e23, e24, e33, e44 = consistent_mass_entries(st, ct, al, ar, p)
    g1, g2, g3, g4 = consistent_gravity_entries(st, ct, al, ar, p)
    w = qd[2]
    flx, flz, flt, fla = consistent_bias_arm(w, qd[3], al, p[1])
    frx, frz, frt, fra = consistent_bias_arm(w, qd[4], ar, p[2])
    hx, hz = flx + frx, flz + frz
    # right-hand side tau - C qdot - g (the body rows of C qdot rotated to the world frame)
    r0 = tau[0] - (ct * hx - st * hz)
    r1 = tau[1] - (st * hx + ct * hz) - g1
    r2 = tau[2] - (flt + frt) - g2
    r3 = tau[3] - fla - g3
    r4 = tau[4] - fra - g4
    # B's columns: (b0, b1) theta, (c0, c1) q_l, (d0, d1) q_r
    s22 = e22 - (b0 * b0 + b1 * b1) / M
    s23 = e23 - (b0 * c0 + b1 * c1) / M
    s24 = e24 - (b0 * d0 + b1 * d1) / M
    s33 = e33 - (c0 * c0 + c1 * c1) / M
    s34 = -(c0 * d0 + c1 * d1) / M
    s44 = e44 - (d0 * d0 + d1 * d1) / M
    h2 = r2 - (b0 * r0 + b1 * r1) / M
    h3 = r3 - (c0 * r0 + c1 * r1) / M
    h4 = r4 - (d0 * r0 + d1 * r1) / M
    # Cholesky S = L L^T
    l22 = math.sqrt(s22)
    l32 = s23 / l22
    l42 = s24 / l22
    l33 = math.sqrt(s33 - l32 * l32)
    l43 = (s34 - l42 * l32) / l33
    l44 = math.sqrt(s44 - l42 * l42 - l43 * l43)
    y2 = h2 / l22
    y3 = (h3 - l32 * y2) / l33
    y4 = (h4 - l42 * y2 - l43 * y3) / l44
    a4 = y4 / l44
    a3 = (y3 - l43 * a4) / l33
    a2 = (y2 - l32 * a3 - l42 * a4) / l22
    return ((r0 - b0 * a2 - c0 * a3 - d0 * a4) / M, (r1 - b1 * a2 - c1 * a3 - d1 * a4) / M, a2, a3, a4)


@_jit
def consistent_forward_dynamics_into(q, qd, tau, p, out):
    a = consistent_qddot(math.sin(q[2]), math.cos(q[2]), q, qd, tau, p)
    for i in range(5):
        out[i] = a[i]


@_inline
def consistent_kinetic_energy(q, qd, p):
    """T = 1/2 qdot^T D(q) qdot of the consistent model."""
    al, ar = consistent_arms(q[3], q[4], p)
    M, d02, d12, d03, d13, d04, d14, d22, d23, d24, d33, d44 = consistent_mass_entries(
        math.sin(q[2]), math.cos(q[2]), al, ar, p)
    vx, vz, w, vl, vr = qd[0], qd[1], qd[2], qd[3], qd[4]
    e = M * (vx * vx + vz * vz) + d22 * w * w + d33 * vl * vl + d44 * vr * vr
    e += 2.0 * w * (d02 * vx + d12 * vz + d23 * vl + d24 * vr)
    e += 2.0 * vl * (d03 * vx + d13 * vz) + 2.0 * vr * (d04 * vx + d14 * vz)
    return 0.5 * e


@_inline
def consistent_potential_energy(q, p):
    """P = g (M z + m_l z_l + m_r z_r), z_i = (R(theta) r_i)_z the rotated tips' heights above the body."""
    al, ar = consistent_arms(q[3], q[4], p)
    st, ct = math.sin(q[2]), math.cos(q[2])
    sx = p[1] * al[0] + p[2] * ar[0]
    sz = p[1] * al[1] + p[2] * ar[1]
    return p[8] * ((p[0] + p[1] + p[2]) * q[1] + st * sx + ct * sz)


@_jit
def consistent_energies(q, qd, p):
    """(kinetic, potential) of the consistent model (a compiled call)."""
    return consistent_kinetic_energy(q, qd, p), consistent_potential_energy(q, p)


@_jit
def paper_tip_positions_into(q, p, out):
    """World (x, z) of the left (out[0]) and right (out[1]) rotor masses of the paper's Lagrangian:
    p_v + r_i(q_i), not rotated by theta (the paper's eq. (coords))."""
    for i in range(2):
        side = -1.0 if i == 0 else 1.0
        rx, rz = arm_offset(q[3 + i], p[6 + i], p[9], side)
        out[i, 0] = q[0] + rx
        out[i, 1] = q[1] + rz


#: ``input_map`` code of :func:`held_force`: the held command is the generalized force tau itself
HELD_TAU = -1


@_inline
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


@_inline
def _axpy5(x, c, v):
    """x + c v for 5-tuples."""
    return (x[0] + c * v[0], x[1] + c * v[1], x[2] + c * v[2], x[3] + c * v[3], x[4] + c * v[4])


@_inline
def _rk4_combine(x, v, a1, a2, a3, a4, h, dt, c):
    """RK4 update of one coordinate from its four stage accelerations."""
    # position slopes of the four stages: v, v + h a1, v + h a2, v + dt a3
    dq = v + 2.0 * (v + h * a1) + 2.0 * (v + h * a2) + (v + dt * a3)
    dv = a1 + 2.0 * a2 + 2.0 * a3 + a4
    return x + c * dq, v + c * dv


@_inline
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
    c = dt / 6.0
    x0, w0 = _rk4_combine(q[0], qd[0], k1[0], k2[0], k3[0], k4[0], h, dt, c)
    x1, w1 = _rk4_combine(q[1], qd[1], k1[1], k2[1], k3[1], k4[1], h, dt, c)
    x2, w2 = _rk4_combine(q[2], qd[2], k1[2], k2[2], k3[2], k4[2], h, dt, c)
    x3, w3 = _rk4_combine(q[3], qd[3], k1[3], k2[3], k3[3], k4[3], h, dt, c)
    x4, w4 = _rk4_combine(q[4], qd[4], k1[4], k2[4], k3[4], k4[4], h, dt, c)
    return (x0, x1, x2, x3, x4), (w0, w1, w2, w3, w4)


@_inline
def rk4_step(q, qd, u, ext, p, dt, input_map):
    """:func:`rk4_step_sc` from q alone (sin, cos of its theta by libm)."""
    return rk4_step_sc(q, qd, math.sin(q[2]), math.cos(q[2]), u, ext, p, dt, input_map)


@_jit
def rk4_step_tuple(q, qd, u, ext, p, dt, input_map):
    """:func:`rk4_step` as a compiled call (tuples in and out): the one non-inlined copy of the step,
    shared by the array wrapper and partial lane blocks (inlining costs compile time)."""
    return rk4_step(q, qd, u, ext, p, dt, input_map)


@_jit
def rk4_step_into(q, qd, u, ext, p, dt, input_map, q_out, qd_out):
    """:func:`rk4_step` on arrays. Allocation-free; ``q_out``/``qd_out`` may alias ``q``/``qd``."""
    qn, vn = rk4_step_tuple(
        (q[0], q[1], q[2], q[3], q[4]),
        (qd[0], qd[1], qd[2], qd[3], qd[4]),
        (u[0], u[1], u[2], u[3], u[4]),
        (ext[0], ext[1]),
        (p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8], p[9]),
        dt,
        input_map,
    )
    q_out[0], q_out[1], q_out[2], q_out[3], q_out[4] = qn
    qd_out[0], qd_out[1], qd_out[2], qd_out[3], qd_out[4] = vn


@_jit
def consistent_stage(st, ct, q, qd, u, ext, p, held):
    """qddot of the consistent model at one RK4 stage under the held command (:func:`held_force`);
    one compiled copy shared by the four stages."""
    return consistent_qddot(st, ct, q, qd, held_force(st, ct, q, u, ext, p, held), p)


@_inline
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
    c = dt / 6.0
    x0, w0 = _rk4_combine(q[0], qd[0], k1[0], k2[0], k3[0], k4[0], h, dt, c)
    x1, w1 = _rk4_combine(q[1], qd[1], k1[1], k2[1], k3[1], k4[1], h, dt, c)
    x2, w2 = _rk4_combine(q[2], qd[2], k1[2], k2[2], k3[2], k4[2], h, dt, c)
    x3, w3 = _rk4_combine(q[3], qd[3], k1[3], k2[3], k3[3], k4[3], h, dt, c)
    x4, w4 = _rk4_combine(q[4], qd[4], k1[4], k2[4], k3[4], k4[4], h, dt, c)
    return (x0, x1, x2, x3, x4), (w0, w1, w2, w3, w4)


@_jit
def consistent_rk4_step_tuple(q, qd, u, ext, p, dt, held):
    """:func:`consistent_rk4_step` as a compiled call (tuples in and out)."""
    return consistent_rk4_step(q, qd, u, ext, p, dt, held)


@_jit
def consistent_rk4_step_into(q, qd, u, ext, p, dt, held, q_out, qd_out):
    """:func:`consistent_rk4_step` on arrays (see :func:`rk4_step_into`)."""
    qn, vn = consistent_rk4_step_tuple(
        (q[0], q[1], q[2], q[3], q[4]),
        (qd[0], qd[1], qd[2], qd[3], qd[4]),
        (u[0], u[1], u[2], u[3], u[4]),
        (ext[0], ext[1]),
        (p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8], p[9]),
        dt,
        held,
    )
    q_out[0], q_out[1], q_out[2], q_out[3], q_out[4] = qn
    qd_out[0], qd_out[1], qd_out[2], qd_out[3], qd_out[4] = vn


# ------------------------------------------------------------------------------------ SIMD lanes
#: width of a lane block: W holds LANES states structure-of-arrays, W[row * LANES + lane]
LANES = 64
#: lane rows of :func:`rk4_lanes`: q, qdot, held command u, external force (f_x, f_z), params
RK4_LANES = Layout("rk4_lanes", [("q", 5), ("qd", 5), ("u", 5), ("ext", 2), ("p", 10), ("sc", 2)])
LANE_Q, LANE_QD, LANE_U, LANE_EXT, LANE_P, LANE_SC = RK4_LANES.at
LANE_ROWS_RK4 = RK4_LANES.size


@_inline
def _lane_load(W, j):
    L = LANES
    q = (W[j], W[L + j], W[2 * L + j], W[3 * L + j], W[4 * L + j])
    o = LANE_QD * L + j
    qd = (W[o], W[o + L], W[o + 2 * L], W[o + 3 * L], W[o + 4 * L])
    o = LANE_U * L + j
    u = (W[o], W[o + L], W[o + 2 * L], W[o + 3 * L], W[o + 4 * L])
    o = LANE_EXT * L + j
    ext = (W[o], W[o + L])
    o = LANE_P * L + j
    p = (W[o], W[o + L], W[o + 2 * L], W[o + 3 * L], W[o + 4 * L],
         W[o + 5 * L], W[o + 6 * L], W[o + 7 * L], W[o + 8 * L], W[o + 9 * L])
    return q, qd, u, ext, p


@_inline
def _lane_store(W, j, qn, vn):
    L = LANES
    W[j], W[L + j], W[2 * L + j], W[3 * L + j], W[4 * L + j] = qn
    o = LANE_QD * L + j
    W[o], W[o + L], W[o + 2 * L], W[o + 3 * L], W[o + 4 * L] = vn


@_jit
def rk4_lanes(W, dt, m, input_map):
    """:func:`rk4_step` in place on the first m lanes of a lane block W (rows ``LANE_*``).

    sin and cos of each lane's theta (libm, as in the scalar step) go into the rows ``LANE_SC`` first;
    the step itself is then polynomial arithmetic only: a full block (m == LANES) runs a loop of
    constant trip count over the inlined step, which LLVM vectorises (the lanes are independent); a
    partial block calls the same step lane by lane.
    """
    L = LANES
    for j in range(m):
        th = W[(LANE_Q + 2) * L + j]
        W[LANE_SC * L + j] = math.sin(th)
        W[(LANE_SC + 1) * L + j] = math.cos(th)
    if m == LANES:
        for j in range(LANES):
            q, qd, u, ext, p = _lane_load(W, j)
            qn, vn = rk4_step_sc(q, qd, W[LANE_SC * L + j], W[(LANE_SC + 1) * L + j], u, ext, p, dt, input_map)
            _lane_store(W, j, qn, vn)
    else:
        rk4_lanes_partial(W, dt, m, input_map)


@_jit
def rk4_lanes_partial(W, dt, m, input_map):
    """The lane-by-lane path of :func:`rk4_lanes` (any m <= LANES): :func:`rk4_step_tuple` per lane.
    A batch of fewer than LANES states needs only this (the env's small-batch step kernels call it
    directly: no SIMD copy of the step to compile)."""
    for j in range(m):
        q, qd, u, ext, p = _lane_load(W, j)
        qn, vn = rk4_step_tuple(q, qd, u, ext, p, dt, input_map)
        _lane_store(W, j, qn, vn)


@_jit
def rk4_lanes_consistent(W, dt, m, held):
    """:func:`rk4_lanes` of the consistent model (first m lanes of W, lane by lane: the env's plant
    under ``model="consistent"``); ``held`` as in :func:`consistent_rk4_step`."""
    for j in range(m):
        q, qd, u, ext, p = _lane_load(W, j)
        qn, vn = consistent_rk4_step_tuple(q, qd, u, ext, p, dt, held)
        _lane_store(W, j, qn, vn)


# ------------------------------------------------------------------------------- batched wrappers
# Each takes contiguous (N, ...) float64 arrays and a parameter matrix P of shape (N, 10) or (1, 10).
# They run in one thread and release the GIL: the public API splits large batches over threads
# (softpvtol_gym._parallel.run_rows); results do not depend on the split.
_batch = njit(cache=True, nogil=True)


@_batch
def batch_mass_matrix(q, P, model, out):
    ps = np.int64(P.shape[0] > 1)
    for n in range(q.shape[0]):
        if model == MODEL_CONSISTENT:
            consistent_mass_matrix_into(q[n], P[n * ps], out[n])
        else:
            mass_matrix_into(q[n], P[n * ps], out[n])


@_batch
def batch_coriolis_matrix(q, qd, P, model, out):
    ps = np.int64(P.shape[0] > 1)
    for n in range(q.shape[0]):
        if model == MODEL_CONSISTENT:
            consistent_coriolis_matrix_into(q[n], qd[n], P[n * ps], out[n])
        else:
            coriolis_matrix_into(q[n], qd[n], P[n * ps], out[n])


@_batch
def batch_gravity_vector(q, P, model, out):
    ps = np.int64(P.shape[0] > 1)
    for n in range(q.shape[0]):
        if model == MODEL_CONSISTENT:
            consistent_gravity_vector_into(q[n], P[n * ps], out[n])
        else:
            gravity_vector_into(q[n], P[n * ps], out[n])


@_batch
def batch_generalized_forces(q, a, P, input_map, out):
    """(The consistent model's input map is ``INPUT_MAP_EXACT``: no model argument needed.)"""
    ps = np.int64(P.shape[0] > 1)
    for n in range(q.shape[0]):
        generalized_forces_into(q[n], a[n], P[n * ps], input_map, out[n])


@_batch
def batch_forward_dynamics(q, qd, tau, P, model, out):
    ps = np.int64(P.shape[0] > 1)
    for n in range(q.shape[0]):
        if model == MODEL_CONSISTENT:
            consistent_forward_dynamics_into(q[n], qd[n], tau[n], P[n * ps], out[n])
        else:
            forward_dynamics_into(q[n], qd[n], tau[n], P[n * ps], out[n])


@_batch
def batch_energies(q, qd, P, model, out):
    """out[n] = (kinetic, potential)."""
    ps = np.int64(P.shape[0] > 1)
    for n in range(q.shape[0]):
        p = P[n * ps]
        if model == MODEL_CONSISTENT:
            out[n, 0], out[n, 1] = consistent_energies(q[n], qd[n], p)
        else:
            out[n, 0] = kinetic_energy(q[n], qd[n], p)
            out[n, 1] = potential_energy(q[n], p)


@_batch
def batch_tip_positions(q, P, model, out):
    """The tips of the model's Lagrangian: rotated (consistent), or not (paper)."""
    ps = np.int64(P.shape[0] > 1)
    for n in range(q.shape[0]):
        if model == MODEL_CONSISTENT:
            tip_positions_into(q[n], P[n * ps], out[n])
        else:
            paper_tip_positions_into(q[n], P[n * ps], out[n])


@_batch
def batch_rk4_step(q, qd, u, ext, P, dt, input_map, model, q_out, qd_out):
    """u (N, 5): held commands (actuators padded to 5, or tau with ``HELD_TAU``); ext (N, 2) or (1, 2).
    ``model`` ``MODEL_CONSISTENT`` takes ``input_map`` ``HELD_TAU`` or ``INPUT_MAP_EXACT``."""
    ps = np.int64(P.shape[0] > 1)
    es = np.int64(ext.shape[0] > 1)
    for n in range(q.shape[0]):
        if model == MODEL_CONSISTENT:
            consistent_rk4_step_into(q[n], qd[n], u[n], ext[n * es], P[n * ps], dt, input_map, q_out[n], qd_out[n])
        else:
            rk4_step_into(q[n], qd[n], u[n], ext[n * es], P[n * ps], dt, input_map, q_out[n], qd_out[n])
