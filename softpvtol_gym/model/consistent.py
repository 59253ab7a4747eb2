"""The consistent model: the paper's energy terms with the rotor masses at the tips rotated by theta.

D, C and g depend on theta as well as the curvatures; the forward dynamics solves a 3x3 Schur complement
by a written-out Cholesky factorisation. Runs lane by lane (not SIMD): see :mod:`.lanes`.
"""

from __future__ import annotations

import math

from ..params import P_EPS, P_G, P_I, P_IL, P_IR, P_LL, P_LR, P_M, P_ML, P_MR
from .jit import inline, jit
from .series import arm_basis, one_minus_cos_over_q2, sinc

# The paper's energy terms with the rotor masses at the *rotated* tips p_i = p_v + R(theta) r_i(q_i)
# (``docs/model.md``, "The consistent model"). In body-frame vectors (R orthogonal; J = [[0, -1], [1, 0]]
# the 90-degree rotation, dR/dtheta = R J): r_i the tip offset, e_i = dr_i/dq_i, e'_i = de_i/dq_i. The
# Jacobian of p_i has the columns (1, 0), (0, 1), R J r_i (theta) and R e_i (its own curvature), so
#   D = sum_i m_i J_i^T J_i + diag(m, m, I, I_l, I_r),   C = sum_i m_i J_i^T Jdot_i,
# (for point masses the Christoffel C is exactly sum m J^T Jdot), g = dP/dq, P = g (M z + sum m_i z_i).


@inline
def consistent_arm(q_arm, length, eps, side):
    """Body-frame (r, e, e') of one arm, side = -1 left, +1 right: the tip offset r = (side (eps + l S0),
    l q C1), e = dr/dq = (-side l D1, l D2) and e' = de/dq = (-side l D1', l D2'), as a 6-tuple
    (r_x, r_z, e_x, e_z, e'_x, e'_z). Series only: smooth at q = 0."""
    d1, d2, d1p, d2p = arm_basis(q_arm)
    return (side * (eps + length * sinc(q_arm)), length * q_arm * one_minus_cos_over_q2(q_arm),
            -side * length * d1, length * d2, -side * length * d1p, length * d2p)


@inline
def consistent_arms(ql, qr, p):
    """:func:`consistent_arm` of the left and the right arm."""
    return consistent_arm(ql, p[P_LL], p[P_EPS], -1.0), consistent_arm(qr, p[P_LR], p[P_EPS], 1.0)


@inline
def consistent_mass_entries(st, ct, al, ar, p):
    """The upper-triangle entries of the consistent D: (M, D02, D12, D03, D13, D04, D14, D22, D23, D24,
    D33, D44) (D01 = D34 = 0), given st, ct = sin, cos of theta and the arms' :func:`consistent_arm`."""
    ml, mr = p[P_ML], p[P_MR]
    M = p[P_M] + ml + mr
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
        p[P_I] + ml * (al[0] * al[0] + al[1] * al[1]) + mr * (ar[0] * ar[0] + ar[1] * ar[1]),
        ml * (al[0] * al[3] - al[1] * al[2]),
        mr * (ar[0] * ar[3] - ar[1] * ar[2]),
        p[P_IL] + ml * (al[2] * al[2] + al[3] * al[3]),
        p[P_IR] + mr * (ar[2] * ar[2] + ar[3] * ar[3]),
    )


@jit
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


@jit
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
        mi = p[P_ML + i]
        rx, rz, ex, ez, epx, epz = consistent_arm(q[a], p[P_LL + i], p[P_EPS], side)
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


@inline
def consistent_gravity_entries(st, ct, al, ar, p):
    """(g1, g2, g3, g4) of the consistent g = dP/dq (g0 = 0): g_j = g (sum_i m_i dp_i/dq_j)_z."""
    ml, mr, grav = p[P_ML], p[P_MR], p[P_G]
    sx = ml * al[0] + mr * ar[0]
    sz = ml * al[1] + mr * ar[1]
    return (grav * (p[P_M] + ml + mr), grav * (ct * sx - st * sz),
            grav * ml * (st * al[2] + ct * al[3]), grav * mr * (st * ar[2] + ct * ar[3]))


@jit
def consistent_gravity_vector_into(q, p, out):
    al, ar = consistent_arms(q[3], q[4], p)
    g1, g2, g3, g4 = consistent_gravity_entries(math.sin(q[2]), math.cos(q[2]), al, ar, p)
    out[0] = 0.0
    out[1] = g1
    out[2] = g2
    out[3] = g3
    out[4] = g4


@inline
def consistent_bias_arm(w, v, arm, mi):
    """m_i J_i^T Jdot_i qdot of one arm in body-frame terms: returns (the body-frame force f = m_i beta
    on the body (x, z), its theta moment, its curvature row), beta = -w^2 r + 2 w v J e + v^2 e'
    (w = thetadot, v = the arm's curvature rate)."""
    rx, rz, ex, ez, epx, epz = arm
    bx = -w * w * rx - 2.0 * w * v * ez + v * v * epx
    bz = -w * w * rz + 2.0 * w * v * ex + v * v * epz
    return mi * bx, mi * bz, mi * (-rz * bx + rx * bz), mi * (ex * bx + ez * bz)


@jit
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
    flx, flz, flt, fla = consistent_bias_arm(w, qd[3], al, p[P_ML])
    frx, frz, frt, fra = consistent_bias_arm(w, qd[4], ar, p[P_MR])
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


@jit
def consistent_forward_dynamics_into(q, qd, tau, p, out):
    a = consistent_qddot(math.sin(q[2]), math.cos(q[2]), q, qd, tau, p)
    for i in range(5):
        out[i] = a[i]
