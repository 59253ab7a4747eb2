"""The extended loop's analysis, derived here with sympy from the Lagrangian, and the
controller (control/extended.py) checked against it.

Derived from scratch (the paper's Lagrangian: rotor masses at the unrotated tips p + r_i; the
consistent model: at p + R(theta) r_i), equal arms (m_l = m_r = m_a, l_l = l_r = l):

1. mirror symmetry q_r = -q_l: D_ba (1, -1)^T = 0 in the three body rows of the paper's model, and the
   arms' part of the body rows of C qdot vanishes for qdot_r = -qdot_l; in the consistent model the
   position rows vanish too but the attitude row does not (-m_a l (eps + l) at q = 0: -0.25 with the
   paper's values);
2. the body point p has no vector relative degree near sigma = q_l + q_r = 0: p'' contains the arms'
   differential acceleration with the coefficient -D_ba (1, -1)^T / (2 M), zero on sigma = 0 only;
3. the centre of mass y = p + psi(q_a): M psi_q = D_ba, psi = 0 on sigma = 0, and M y'' = B_b(q) a - g_b
   (no arm acceleration);
4. with the thrust split fixed by the attitude loop and T, Tdot as states, y'''' is affine in
   (Tddot, w_l - w_r) with the decoupling matrix R(theta) [A, G], det = -T / 2 on sigma = 0 (theta on
   its reference): invertible for T > 0, at every bend q.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
import sympy as sp

from softpvtol_gym import SoftPVTOLParams, dynamics
from softpvtol_gym.control.extended import ExtendedController, sinc_derivatives, torque_arm

# one worker derives the symbolic model once (cached) and runs every case against it
pytestmark = pytest.mark.xdist_group("extended-derivation")

x, z, th, ql, qr = sp.symbols("x z theta q_l q_r", real=True)
xd, zd, thd, qld, qrd = sp.symbols("xd zd thd qld qrd", real=True)
m, ma, I, Ia, l, g, eps = sp.symbols("m m_a I I_a l g epsilon", positive=True)
Q = [x, z, th, ql, qr]
QD = [xd, zd, thd, qld, qrd]
q_, T, v = sp.symbols("q T v", real=True)


def _tips(model):
    r_l = sp.Matrix([-eps - l * sp.sin(ql) / ql, l * (1 - sp.cos(ql)) / ql])
    r_r = sp.Matrix([eps + l * sp.sin(qr) / qr, l * (1 - sp.cos(qr)) / qr])
    R = sp.Matrix([[sp.cos(th), -sp.sin(th)], [sp.sin(th), sp.cos(th)]])
    if model == "consistent":
        r_l, r_r = R * r_l, R * r_r
    return r_l, r_r


@functools.cache
def lagrangian(model: str = "paper"):
    """(D, C qdot, g, psi) of the model with equal arms, psi the centre of mass offset from p."""
    r_l, r_r = _tips(model)
    p = sp.Matrix([x, z])

    def vel(pt):
        return pt.jacobian(Q) * sp.Matrix(QD)

    K = sp.Rational(1, 2) * (m * vel(p).dot(vel(p)) + ma * vel(p + r_l).dot(vel(p + r_l))
                             + ma * vel(p + r_r).dot(vel(p + r_r)) + I * thd**2 + Ia * (qld**2 + qrd**2))
    P = g * (m * z + ma * (z + r_l[1]) + ma * (z + r_r[1]))
    D = sp.hessian(K, QD)
    Cqd = sp.Matrix([sum(sp.Rational(1, 2) * (sp.diff(D[k, j], Q[i]) + sp.diff(D[k, i], Q[j]) - sp.diff(D[i, j], Q[k]))
                         * QD[i] * QD[j] for i in range(5) for j in range(5)) for k in range(5)])
    gv = sp.Matrix([sp.diff(P, s) for s in Q])
    psi = ma * (r_l + r_r) / (m + 2 * ma)
    return D, Cqd, gv, psi


MIRROR = {qr: -ql}


def test_mirror_arms_do_not_push_the_body_in_the_papers_model():
    D, Cqd, _, _ = lagrangian("paper")
    for row in range(3):  # x, z, theta
        assert sp.simplify((D[row, 3] - D[row, 4]).subs(MIRROR)) == 0
        # the arms' part of the body rows of C qdot (the body velocities do not enter them in this model)
        assert sp.simplify(Cqd[row].subs(MIRROR).subs({qrd: -qld})) == 0
    # ... but the common mode does push it: D_ba (1, 1)^T is not zero (z row at q = 0.3)
    assert abs(float((D[1, 3] + D[1, 4]).subs(MIRROR).subs({ql: 0.3, ma: 1, l: 0.5}))) > 1e-2
    # the package's mass and Coriolis matrices agree (round-off)
    p = SoftPVTOLParams()
    rng = np.random.default_rng(0)
    for _ in range(20):
        a, w = rng.uniform(-1.5, 1.5), rng.uniform(-3, 3)
        q = np.array([0.3, -0.2, rng.uniform(-3, 3), a, -a])
        qd = np.array([0.4, 0.1, 0.7, w, -w])
        Dn = dynamics.mass_matrix(q, p)
        assert np.abs(Dn[:3, 3:5] @ [1.0, -1.0]).max() < 1e-15
        assert np.abs(Dn[:3, 3:5] @ [1.0, 1.0]).max() > 1e-3 or abs(a) < 1e-2
        assert np.abs(dynamics.coriolis_matrix(q, qd, p)[:3] @ qd).max() < 1e-14


def test_in_the_consistent_model_the_attitude_row_does_not_vanish():
    D, _, _, _ = lagrangian("consistent")
    for row in (0, 1):
        assert sp.simplify((D[row, 3] - D[row, 4]).subs(MIRROR)) == 0
    att = D[2, 3] - D[2, 4]
    at0 = sp.simplify(sp.limit(att.subs(MIRROR), ql, 0))
    assert sp.simplify(at0 + ma * l * (eps + l)) == 0, at0
    vals = {ma: 1, l: sp.Rational(1, 2), eps: 0}
    assert at0.subs(vals) == sp.Rational(-1, 4)
    # the package's consistent mass matrix: -0.25 at q = 0, and nonzero along the mirror set
    p = SoftPVTOLParams()
    for a in (0.0, 0.3, -1.0):
        Dn = dynamics.mass_matrix(np.array([0, 0, 0.4, a, -a]), p, model="consistent")
        ref = float(att.subs(MIRROR).subs(vals).subs({ql: a, th: 0.4})) if a else -0.25
        assert abs(Dn[2, 3] - Dn[2, 4] - ref) < 1e-14
        assert abs(Dn[0, 3] - Dn[0, 4]) < 1e-15 and abs(Dn[1, 3] - Dn[1, 4]) < 1e-15


def test_the_body_point_has_no_relative_degree_near_sigma_zero():
    """p'' = (B_b a - D_ba w - C_b qdot - g_b) / M: the arms' differential acceleration w_delta enters it
    with the coefficient -D_ba (1, -1)^T / (2 M), which is zero on sigma = 0 and not off it: the body
    point has relative degree 2 in w_delta where sigma != 0 and more where sigma = 0 (no vector relative
    degree in any neighbourhood of the operating set)."""
    D, _, _, _ = lagrangian("paper")
    coeff = [-(D[row, 3] - D[row, 4]) / (2 * (m + 2 * ma)) for row in (0, 1)]
    vals = {m: 5, ma: 1, l: sp.Rational(1, 2), eps: 0}
    on = [float(c.subs(vals).subs({ql: 0.2, qr: -0.2})) for c in coeff]
    off = [float(c.subs(vals).subs({ql: 0.2, qr: -0.1})) for c in coeff]  # sigma = 0.1
    assert max(map(abs, on)) < 1e-15
    assert max(map(abs, off)) > 1e-3, off


def test_centre_of_mass_carries_no_arm_acceleration():
    D, Cqd, gv, psi = lagrangian("paper")
    M = m + 2 * ma
    J = psi.jacobian([ql, qr])
    for i in range(2):
        for j in range(2):
            assert sp.simplify(M * J[i, j] - D[i, 3 + j]) == 0
    assert sp.simplify(psi.subs(MIRROR)) == sp.zeros(2, 1)
    # M y'' = M p'' + M psi_q q'' + M (d psi_q / dt) qdot_a = body rows of (D q'' + C qdot) (D_bb = M I)
    qdd = sp.symbols("a0:5", real=True)
    body = D[0:2, :] * sp.Matrix(qdd) + Cqd[0:2, :]
    ydd = sp.Matrix([qdd[0], qdd[1]]) + J * sp.Matrix([qdd[3], qdd[4]]) + sp.Matrix(
        [sum(sp.diff(J[i, j], Q[3 + k]) * QD[3 + k] * QD[3 + j] for j in range(2) for k in range(2)) for i in range(2)])
    assert sp.simplify(body - M * ydd) == sp.zeros(2, 1)
    assert sp.simplify(gv[0:2, :] - sp.Matrix([0, M * g])) == sp.zeros(2, 1)


def _thrust_map(input_map: str):
    """A(q_a), B(q_a) of V = T_l u_l + T_r u_r = T A + v B with T_l + T_r = T, h_r T_r - h_l T_l = I v."""
    if input_map == "paper":
        def h(s):
            return l * sp.cos(s) * sp.sin(s) / s
    else:
        def h(s):
            return eps * sp.cos(s) + l * sp.sin(s) / s
    hl, hr = h(ql), h(qr)
    Tl = (T * hr - I * v) / (hl + hr)
    Tr = (T * hl + I * v) / (hl + hr)
    ul = sp.Matrix([sp.sin(ql), sp.cos(ql)])
    ur = sp.Matrix([-sp.sin(qr), sp.cos(qr)])
    return Tl, Tr, Tl * ul + Tr * ur, hl, hr


def test_thrust_split_gives_the_attitude_torque_and_the_decoupling_is_invertible():
    Tl, Tr, V, hl, hr = _thrust_map("paper")
    assert sp.simplify(Tl + Tr - T) == 0
    assert sp.simplify(hr * Tr - hl * Tl - I * v) == 0
    # the paper's printed torque row: l T_r cos q_r sin q_r / q_r - l T_l cos q_l sin q_l / q_l
    assert sp.simplify(l * Tr * sp.cos(qr) * sp.sin(qr) / qr - l * Tl * sp.cos(ql) * sp.sin(ql) / ql - I * v) == 0
    # the columns of y'''' in (Tddot, w_delta): A = dV/dT and G = (dV/dq_l - dV/dq_r)/2 (V'' = ... + G w_delta)
    A = V.diff(T)
    G = (V.diff(ql) - V.diff(qr)) / 2
    det = (A[0] * G[1] - A[1] * G[0])
    on = sp.simplify(det.subs({qr: -q_, ql: q_, v: 0}))
    assert sp.simplify(on + T / 2) == 0, on
    # off the mirror set (sigma = 0.1) and off the attitude reference it stays away from 0 (T = 70 N)
    vals = {l: 0.5, I: 1, T: 70}
    for a, b, vv in ((0.2, -0.1, 0.0), (0.3, -0.35, 1.0), (-0.5, 0.45, -2.0)):
        d = float(det.subs(vals).subs({ql: a, qr: b, v: vv}))
        assert abs(d + 35.0) < 5.0, d


@pytest.mark.parametrize("input_map", ["paper", "exact"])
def test_controller_derivatives_match_sympy(input_map):
    """The controller's closed-form derivatives (control/extended.py) against sympy: y'' = Phi / M,
    y''' and the affine y'''' along a random state, through its actuators applied to the package's
    model: theta'' = v, sigma'' = the sigma loop, and the arms accelerate as asked."""
    p = SoftPVTOLParams(epsilon=0.1 if input_map == "exact" else 0.0)
    ctrl = ExtendedController(p, input_map=input_map)
    rng = np.random.default_rng(1)
    _, _, V, _, _ = _thrust_map(input_map)
    vals = {l: p.l_l, I: p.I, eps: p.epsilon}
    R = sp.Matrix([[sp.cos(th), -sp.sin(th)], [sp.sin(th), sp.cos(th)]])
    M = p.total_mass
    Phi = R * V.subs(vals) - sp.Matrix([0, M * p.g])
    Phi_f = sp.lambdify((th, ql, qr, T, v), Phi, "numpy")
    for _ in range(5):
        q = np.array([rng.normal(), rng.normal(), rng.uniform(-1, 1), rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6)])
        qd = rng.normal(size=5)
        xi = np.array([[rng.uniform(40, 90), rng.normal() * 5]])
        ref = rng.normal(size=(5, 1, 5)) * 0.3
        out = ctrl.evaluate(q[None], qd[None], xi, ref)
        qdd = dynamics.forward_dynamics(q, qd, dynamics.generalized_forces(q, out.actuators[0], p, input_map), p)
        ga, gs = ctrl.gains.attitude, ctrl.gains.sigma
        v_att = ref[2, 0, 2] - ga[1] * (qd[2] - ref[1, 0, 2]) - ga[0] * (q[2] - ref[0, 0, 2])
        assert abs(qdd[2] - v_att) < 1e-12
        assert abs(qdd[3] - out.arm_acceleration[0, 0]) < 1e-10 and abs(qdd[4] - out.arm_acceleration[0, 1]) < 1e-10
        assert abs(qdd[3] + qdd[4] + gs[1] * (qd[3] + qd[4]) + gs[0] * (q[3] + q[4])) < 1e-10
        # M y'' = Phi: the centre of mass's acceleration from the package's model
        D = dynamics.mass_matrix(q, p)
        Cq = dynamics.coriolis_matrix(q, qd, p) @ qd
        ydd = (D[0:2] @ qdd + Cq[0:2]) / M
        phi = np.array(Phi_f(q[2], q[3], q[4], xi[0, 0], v_att), dtype=float).ravel()
        assert np.allclose(ydd * M, phi, rtol=0, atol=1e-10 * M * p.g)


def test_sinc_and_torque_arm_derivatives():
    s = sp.symbols("s")
    f = sp.sin(s) / s
    xs = np.array([0.0, 1e-8, 0.3, 0.999, 1.0, 1.001, 2.5, -3.0, 6.0])
    got = sinc_derivatives(xs)
    for k, gk in enumerate(got):
        fk = sp.diff(f, s, k)
        ref = [float(sp.limit(fk, s, 0)) if a == 0 else float(fk.subs(s, sp.Float(a, 40))) for a in xs]
        assert np.allclose(gk, ref, rtol=0, atol=1e-14), (k, gk, ref)
    # h, h', h'' of both maps by sympy
    for imap in ("paper", "exact"):
        h = l * sp.cos(s) * sp.sin(s) / s if imap == "paper" else eps * sp.cos(s) + l * sp.sin(s) / s
        h = h.subs({l: 0.5, eps: 0.1})
        qs = np.array([0.2, -0.7, 1.3])
        got = torque_arm(qs, 0.5, 0.1, imap)
        for k in range(3):
            ref = [float(sp.diff(h, s, k).subs(s, a)) for a in qs]
            assert np.allclose(got[k], ref, rtol=0, atol=1e-14)


def test_third_and_fourth_derivatives_match_sympy():
    """y''' = Phi' / M and y'''' = Phi'' / M by sympy's chain rule (theta'' = v, q_a'' = w, T'' = u_1, v' and
    v'' from the attitude loop) at the controller's (u_1, w): y'''' is the value the linear law assigns."""
    wl, wr, Td, u1, vd, vdd = sp.symbols("w_l w_r Td u_1 vd vdd", real=True)
    chain = {th: thd, thd: v, ql: qld, qld: wl, qr: qrd, qrd: wr, T: Td, Td: u1, v: vd, vd: vdd}

    def ddt(e):
        return sum((sp.diff(e, s) * ds for s, ds in chain.items()), sp.zeros(*e.shape))

    p = SoftPVTOLParams()
    ctrl = ExtendedController(p)
    _, _, V, _, _ = _thrust_map("paper")
    R = sp.Matrix([[sp.cos(th), -sp.sin(th)], [sp.sin(th), sp.cos(th)]])
    Phi = (R * V).subs({l: p.l_l, I: p.I})  # the gravity term is constant
    d1, d2 = ddt(Phi), ddt(ddt(Phi))
    args = (th, ql, qr, thd, qld, qrd, T, Td, v, vd, vdd, wl, wr, u1)
    f1, f2 = sp.lambdify(args, d1, "numpy"), sp.lambdify(args, d2, "numpy")
    rng = np.random.default_rng(2)
    ga, M = ctrl.gains.attitude, p.total_mass
    for _ in range(5):
        q = np.array([rng.normal(), rng.normal(), rng.uniform(-1, 1), rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6)])
        qd = rng.normal(size=5)
        xi = np.array([[rng.uniform(40, 90), rng.normal() * 5]])
        ref = rng.normal(size=(5, 1, 5)) * 0.3
        out = ctrl.evaluate(q[None], qd[None], xi, ref)
        e1 = qd[2] - ref[1, 0, 2]
        va = ref[2, 0, 2] - ga[1] * e1 - ga[0] * (q[2] - ref[0, 0, 2])
        vda = ref[3, 0, 2] - ga[1] * (va - ref[2, 0, 2]) - ga[0] * e1
        vdda = ref[4, 0, 2] - ga[1] * (vda - ref[3, 0, 2]) - ga[0] * (va - ref[2, 0, 2])
        vals = (q[2], q[3], q[4], qd[2], qd[3], qd[4], xi[0, 0], xi[0, 1], va, vda, vdda,
                out.arm_acceleration[0, 0], out.arm_acceleration[0, 1], out.thrust_accel[0])
        y3 = np.array(f1(*vals), dtype=float).ravel() / M
        y4 = np.array(f2(*vals), dtype=float).ravel() / M
        yder = out.output_derivatives[0]
        assert np.allclose(y3, yder[3], rtol=0, atol=1e-11), (y3, yder[3])
        assert np.allclose(y4, yder[4], rtol=0, atol=1e-10), (y4, yder[4])
        # and y'''' is the linear law's value
        k = ctrl.gains.position
        r = ref[:, 0, 0:2]
        law = r[4] - sum(k[j] * (yder[j] - r[j]) for j in range(4))
        assert np.allclose(yder[4], law, rtol=0, atol=1e-12)
