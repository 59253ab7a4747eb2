"""The paper's model: D(q), C(q, qdot), g(q) and the forward dynamics (paper Sec. 2).

The rotor masses sit on tips that do not rotate with theta (the paper's eq. (coords)), so D, C and g
depend only on the curvatures (q_l, q_r) and their rates; theta decouples. The ``*_entries`` functions
return the nonzero entries as tuples (inlined into the SIMD lane loops); the ``*_into`` functions fill
arrays for the batched public API. The parameter vector p is indexed by the names of
:mod:`softpvtol_gym.params` (``P_M``, ``P_ML``, ...).
"""

from __future__ import annotations

from ..params import P_G, P_I, P_IL, P_IR, P_LL, P_LR, P_M, P_ML, P_MR
from .jit import inline, jit
from .series import arm_basis


@inline
def mass_entries(ql, qr, p):
    """The nonzero entries of D(q): (M, I, D03, D13, D04, D14, D33, D44), D symmetric.

    Only the curvatures enter; D = [[M, 0, 0, D03, D04], [0, M, 0, D13, D14], [0, 0, I, 0, 0], ...].
    """
    return mass_entries_basis(arm_basis(ql), arm_basis(qr), p)


@inline
def mass_entries_basis(bl, br, p):
    """:func:`mass_entries` from the arms' :func:`arm_basis` (bl, br): a caller that needs D, C and g
    evaluates each arm's series once (the same values; one inlined copy instead of three, which keeps
    the cold compile short)."""
    ml, mr, ll, lr = p[P_ML], p[P_MR], p[P_LL], p[P_LR]
    d1l, d2l = bl[0], bl[1]
    d1r, d2r = br[0], br[1]
    M = p[P_M] + p[P_ML] + p[P_MR]
    return (
        M,
        p[P_I],
        ml * ll * d1l,
        ml * ll * d2l,
        -mr * lr * d1r,
        mr * lr * d2r,
        ml * ll * ll * (d1l * d1l + d2l * d2l) + p[P_IL],
        mr * lr * lr * (d1r * d1r + d2r * d2r) + p[P_IR],
    )


@jit
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


@inline
def coriolis_entries(ql, qr, vl, vr, p):
    """The nonzero entries of C(q, qdot): (C03, C13, C04, C14, C33, C44) (Christoffel symbols of the
    first kind, so that Ddot - 2C is skew); only the curvatures and their rates enter."""
    return coriolis_entries_basis(arm_basis(ql), arm_basis(qr), vl, vr, p)


@inline
def coriolis_entries_basis(bl, br, vl, vr, p):
    """:func:`coriolis_entries` from the arms' :func:`arm_basis` (see :func:`mass_entries_basis`)."""
    ml, mr, ll, lr = p[P_ML], p[P_MR], p[P_LL], p[P_LR]
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


@jit
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


@inline
def gravity_entries(ql, qr, p):
    """The nonzero entries of g(q) = dP/dq: (g1, g3, g4) (g0 = g2 = 0)."""
    return gravity_entries_basis(arm_basis(ql), arm_basis(qr), p)


@inline
def gravity_entries_basis(bl, br, p):
    """:func:`gravity_entries` from the arms' :func:`arm_basis` (see :func:`mass_entries_basis`)."""
    d2l, d2r = bl[1], br[1]
    return p[P_G] * (p[P_M] + p[P_ML] + p[P_MR]), p[P_G] * p[P_ML] * p[P_LL] * d2l, p[P_G] * p[P_MR] * p[P_LR] * d2r


@jit
def gravity_vector_into(q, p, out):
    """g(q) = dP/dq."""
    g1, g3, g4 = gravity_entries(q[3], q[4], p)
    out[0] = 0.0
    out[1] = g1
    out[2] = 0.0
    out[3] = g3
    out[4] = g4


@inline
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


@jit
def forward_dynamics_into(q, qd, tau, p, out):
    a = qddot(q[3], q[4], qd[3], qd[4], tau, p)
    for i in range(5):
        out[i] = a[i]
