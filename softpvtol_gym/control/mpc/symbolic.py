"""The paper's model written symbolically for CasADi: what the MPC predicts with.

The compiled kernels of :mod:`softpvtol_gym.model` are the single source of truth of the physics, but
numba functions cannot take CasADi symbols. This module writes the same equations once more, term by
term as :mod:`softpvtol_gym.model.paper` and :mod:`softpvtol_gym.model.input_map` write them (the
same curvature series from :mod:`softpvtol_gym._series_coefficients`, Horner's rule, the Schur-complement solve of
the mass matrix), and ``tests/control/test_mpc.py`` checks it against the kernels' public API
(:func:`softpvtol_gym.dynamics.forward_dynamics`, :func:`~softpvtol_gym.dynamics.generalized_forces`,
:func:`softpvtol_gym.integrators.rk4_step_actuated`) to ~1e-12 at random states. Only the paper's model
(the controllers' model in every tier) is written here.

State x = (q, qdot) (10): q = (x, z, theta, q_l, q_r); input u = (T_l, T_r, tau_l, tau_r) (4), held
over a step (zero-order hold, B(q) evaluated at every RK4 stage as in the env's physics step).
"""

from __future__ import annotations

import math

from ...model.series import A_COEFFS, C1_COEFFS, D1P_COEFFS, D2_COEFFS, D2PQ_COEFFS, S0_COEFFS
from ...params import P_EPS, P_G, P_I, P_IL, P_IR, P_LL, P_LR, P_M, P_ML, P_MR
from ._casadi import import_casadi

#: the input maps written here (:data:`softpvtol_gym.dynamics.INPUT_MAPS`)
INPUT_MAPS = ("paper", "exact")
#: |q_l|, |q_r| [rad] beyond which ``continuous_dynamics`` holds the curvature terms constant
CURVATURE_RANGE = 2.0 * math.pi


def horner(c, s):
    """c[0] + c[1] s + ... by Horner's rule from the highest coefficient down (as the kernels)."""
    acc = float(c[-1])
    for ck in c[-2::-1]:
        acc = acc * s + float(ck)
    return acc


def arm_basis(q):
    """(D1, D2, dD1/dq, dD2/dq) of one arm's curvature q (model.series.arm_basis)."""
    s = q * q
    return q * horner(A_COEFFS, s), horner(D2_COEFFS, s), horner(D1P_COEFFS, s), q * horner(D2PQ_COEFFS, s)


def sin_cos_series(q):
    """(sin q, cos q) of an arm curvature from the series (model.series.sin_cos)."""
    s = q * q
    return q * horner(S0_COEFFS, s), 1.0 - s * horner(C1_COEFFS, s)


def qddot(q, qd, tau, p):
    """qddot = D(q)^-1 (tau - C(q, qdot) qdot - g(q)) of the paper's model, a list of 5 expressions
    (model.paper.qddot: the same entries and the same block solve). q, qd, tau: indexable of 5; p: the
    parameter vector (``SoftPVTOLParams.array``)."""
    ml, mr, ll, lr = p[P_ML], p[P_MR], p[P_LL], p[P_LR]
    ql, qr, vl, vr = q[3], q[4], qd[3], qd[4]
    d1l, d2l, d1pl, d2pl = arm_basis(ql)
    d1r, d2r, d1pr, d2pr = arm_basis(qr)
    M = p[P_M] + p[P_ML] + p[P_MR]
    inertia = p[P_I]
    a0, a1 = ml * ll * d1l, ml * ll * d2l
    b0, b1 = -mr * lr * d1r, mr * lr * d2r
    dll = ml * ll * ll * (d1l * d1l + d2l * d2l) + p[P_IL]
    drr = mr * lr * lr * (d1r * d1r + d2r * d2r) + p[P_IR]
    c03, c13 = ml * ll * d1pl * vl, ml * ll * d2pl * vl
    c04, c14 = -mr * lr * d1pr * vr, mr * lr * d2pr * vr
    c33 = ml * ll * ll * (d1l * d1pl + d2l * d2pl) * vl
    c44 = mr * lr * lr * (d1r * d1pr + d2r * d2pr) * vr
    g1 = p[P_G] * (p[P_M] + p[P_ML] + p[P_MR])
    g3 = p[P_G] * p[P_ML] * p[P_LL] * d2l
    g4 = p[P_G] * p[P_MR] * p[P_LR] * d2r
    r0 = tau[0] - (c03 * vl + c04 * vr)
    r1 = tau[1] - (c13 * vl + c14 * vr) - g1
    r3 = tau[3] - c33 * vl - g3
    r4 = tau[4] - c44 * vr - g4
    s11 = dll - (a0 * a0 + a1 * a1) / M
    s22 = drr - (b0 * b0 + b1 * b1) / M
    s12 = -(a0 * b0 + a1 * b1) / M
    h3 = r3 - (a0 * r0 + a1 * r1) / M
    h4 = r4 - (b0 * r0 + b1 * r1) / M
    det = s11 * s22 - s12 * s12
    qdd_l = (s22 * h3 - s12 * h4) / det
    qdd_r = (s11 * h4 - s12 * h3) / det
    return [(r0 - a0 * qdd_l - b0 * qdd_r) / M, (r1 - a1 * qdd_l - b1 * qdd_r) / M, tau[2] / inertia, qdd_l, qdd_r]


#: the size of the disturbance input d of :func:`continuous_dynamics`: a generalized force on each of x, z, theta,
#: q_l, q_r, and the share of each rotor's thrust that bends its arm (left, right)
DISTURBANCE_SIZE = 7


def thrust_bending(q, a, p):
    """The thrusts' work on the curvatures, (l_l T_l C1(q_l^2), l_r T_r C1(q_r^2)): the exact input map's arm
    rows less the paper's."""
    return (a[0] * p[P_LL] * horner(C1_COEFFS, q[3] * q[3]), a[1] * p[P_LR] * horner(C1_COEFFS, q[4] * q[4]))


def generalized_forces(q, a, p, input_map: str):
    """tau = B(q) a for a = (T_l, T_r, tau_l, tau_r), a list of 5 expressions (model.input_map)."""
    ca = import_casadi()
    st, ct = ca.sin(q[2]), ca.cos(q[2])
    ql, qr = q[3], q[4]
    Tl, Tr = a[0], a[1]
    sl, cl = sin_cos_series(ql)
    sr, cr = sin_cos_series(qr)
    vx = Tl * sl - Tr * sr
    vz = Tl * cl + Tr * cr
    t0 = ct * vx - st * vz
    t1 = st * vx + ct * vz
    ll, lr, eps = p[P_LL], p[P_LR], p[P_EPS]
    sinc_l, sinc_r = horner(S0_COEFFS, ql * ql), horner(S0_COEFFS, qr * qr)
    if input_map == "paper":
        return [t0, t1, lr * Tr * cr * sinc_r - ll * Tl * cl * sinc_l, a[2], a[3]]
    if input_map != "exact":
        raise ValueError(f"input_map must be one of {list(INPUT_MAPS)}, got {input_map!r}")
    t2 = Tr * (eps * cr + lr * sinc_r) - Tl * (eps * cl + ll * sinc_l)
    bend_l, bend_r = thrust_bending(q, a, p)
    return [t0, t1, t2, a[2] + bend_l, a[3] + bend_r]


def continuous_dynamics(p, input_map: str, disturbance: bool = False):
    """CasADi Function ``f(x[10], u[4]) -> xdot[10]`` of the paper's model with parameters p; with
    ``disturbance``, ``f(x[10], u[4], d[DISTURBANCE_SIZE])``: the MPC's estimate of the forces its model lacks,
    d[0:5] added to the generalized forces B(q) u, and d[5], d[6] the share of each rotor's thrust that bends its
    own arm (times :func:`thrust_bending`; 0: the paper's map, 1: the exact map's arm rows)."""
    ca = import_casadi()
    x = ca.SX.sym("x", 10)
    u = ca.SX.sym("u", 4)
    q, qd = [x[i] for i in range(5)], [x[5 + i] for i in range(5)]
    # the curvature terms are polynomials accurate to |q| = 2 pi (twice the env's limit) that grow without
    # bound beyond: there they are held at their values at +-2 pi, so that a rollout of the model that
    # leaves that range (an open-loop plan over the horizon) stays finite
    q[3], q[4] = (ca.fmin(ca.fmax(qi, -CURVATURE_RANGE), CURVATURE_RANGE) for qi in (q[3], q[4]))
    tau = generalized_forces(q, [u[i] for i in range(4)], p, input_map)
    inputs, names = [x, u], ["x", "u"]
    if disturbance:
        d = ca.SX.sym("d", DISTURBANCE_SIZE)
        tau = [tau[i] + d[i] for i in range(5)]
        bend_l, bend_r = thrust_bending(q, u, p)
        tau[3] = tau[3] + d[5] * bend_l
        tau[4] = tau[4] + d[6] * bend_r
        inputs.append(d)
        names.append("d")
    acc = qddot(q, qd, tau, p)
    return ca.Function("softpvtol_dynamics", inputs, [ca.vertcat(*qd, *acc)], names, ["xdot"])


def rk4_step(f, substeps: int = 1):
    """CasADi Function ``F(x[10], u[4], h) -> x_next[10]``: ``substeps`` classical RK4 steps of the
    continuous dynamics ``f`` over h seconds in all, u held. For an ``f`` with a disturbance input
    (``continuous_dynamics(..., disturbance=True)``): ``F(x, u, h, d[5])``, d held too."""
    ca = import_casadi()
    x = ca.SX.sym("x", 10)
    u = ca.SX.sym("u", 4)
    h = ca.SX.sym("h")
    extra = [ca.SX.sym("d", f.nnz_in(2))] if f.n_in() == 3 else []
    dt = h / substeps
    xn = x
    for _ in range(substeps):
        k1 = f(xn, u, *extra)
        k2 = f(xn + 0.5 * dt * k1, u, *extra)
        k3 = f(xn + 0.5 * dt * k2, u, *extra)
        k4 = f(xn + dt * k3, u, *extra)
        xn = xn + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    names = ["x", "u", "h"] + (["d"] if extra else [])
    return ca.Function("softpvtol_rk4", [x, u, h, *extra], [xn], names, ["x_next"])
