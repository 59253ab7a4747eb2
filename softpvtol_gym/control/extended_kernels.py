"""Compiled kernels of the dynamically extended loop: the law of
:meth:`ExtendedController.evaluate <softpvtol_gym.control.extended.ExtendedController.evaluate>` for one row, as
scalar code, and :class:`~softpvtol_gym.policies.ExtendedPolicy`'s whole ``predict`` (its held step: the law,
the RK4 half step to the midpoint, the law there), whose half steps run in lane blocks (SIMD for 64 rows).

The numpy controller (:mod:`.extended`) is the readable reference: the tests compare these kernels with it
(the same operations, in an order that differs only where numpy's einsum sums; values agree to round-off).
D, C, g, B(q) and the RK4 step are the model kernels' (:mod:`softpvtol_gym.model`), never written again here.

Vectors of the plane are 2-tuples; the reference jet ``ref`` is an array (5, 3): q_ref's body entries
(x, z, theta) and their first four time derivatives (sigma's reference is 0).
"""

from __future__ import annotations

import math

import numpy as np

from .. import model as MK
from .._series_coefficients import COEFFICIENTS
from ..params import P_EPS, P_G, P_I, P_LL, P_M, P_ML, P_MR

_S0 = COEFFICIENTS["S0"]
_A = COEFFICIENTS["A"]
_D1P = COEFFICIENTS["D1p"]

#: kernel_constants layout (:func:`extended_constants`)
K_MIN_THRUST, K_MIN_ARM, K_INITIAL_THRUST, K_DT, K_TMAX, K_TAUMAX = range(6)
K_GAINS = 6  # position k0..k3, attitude k0, k1, sigma k0, k1
K_LEN = K_GAINS + 8
#: the policy kernel's error codes
ERR_NONE, ERR_NONFINITE = 0, 1


def extended_constants(controller, tmax: float = 1.0, taumax: float = 1.0) -> np.ndarray:
    """The controller's settings as the kernels' float vector (K_LEN): min thrust, min torque arm, initial
    thrust (NaN: from the reference), dt, the action scales, the gains."""
    g = controller.gains
    init = math.nan if controller.initial_thrust is None else controller.initial_thrust
    return np.array([controller.min_thrust, controller.min_torque_arm, init, controller.dt, tmax, taumax,
                     *g.position, *g.attitude, *g.sigma], dtype=np.float64)


@MK.jit
def sinc_derivatives(x):
    """(sinc, sinc', sinc'') of x (:func:`softpvtol_gym.control.extended.sinc_derivatives`)."""
    if abs(x) < 1.0:
        s = x * x
        return MK.horner(_S0, s), -x * MK.horner(_A, s), -MK.horner(_D1P, s)
    sn, cs = math.sin(x), math.cos(x)
    return sn / x, (x * cs - sn) / (x * x), ((2.0 - x * x) * sn - 2.0 * x * cs) / (x * x * x)


@MK.jit
def torque_arm(q, s, c, length, eps, input_map):
    """(h, h', h'') of a rotor's moment arm (:func:`softpvtol_gym.control.extended.torque_arm`); s, c = sin q,
    cos q (libm: the law needs them too)."""
    if input_map == MK.INPUT_MAP_PAPER:
        f0, f1, f2 = sinc_derivatives(2.0 * q)
        return length * f0, 2.0 * length * f1, 4.0 * length * f2
    f0, f1, f2 = sinc_derivatives(q)
    return eps * c + length * f0, -eps * s + length * f1, -eps * c + length * f2


@MK.accessor
def _quotient1(N, Nl, Nr, Nll, Nlr, Nrr, H, Hl, Hr, Hll, Hrr):
    """One component of ``extended._quotient``: X = N / H and its partials in (q_l, q_r)."""
    X = N / H
    Xl = (Nl - X * Hl) / H
    Xr = (Nr - X * Hr) / H
    Xll = (Nll - 2.0 * Xl * Hl - X * Hll) / H
    Xrr = (Nrr - 2.0 * Xr * Hr - X * Hrr) / H
    Xlr = (Nlr - Xl * Hr - Xr * Hl) / H
    return X, Xl, Xr, Xll, Xlr, Xrr


@MK.accessor
def _rot(c, s, v0, v1):
    return c * v0 - s * v1, s * v0 + c * v1


@MK.accessor
def _thrust_map_rates(Aq, Bq, T, Td, v, vd, vdd, vl, vr, w0):
    """One component of V = T A + v B, V', V'' at w_l - w_r = 0 and dV''/d(w_l - w_r), from A's and B's
    component and partials (:func:`_quotient1`)."""
    A, Al, Ar, All, Alr, Arr = Aq
    B, Bl, Br, Bll, Blr, Brr = Bq
    Aq1, Bq1 = Al * vl + Ar * vr, Bl * vl + Br * vr
    Aqq = All * vl * vl + 2.0 * Alr * vl * vr + Arr * vr * vr
    Bqq = Bll * vl * vl + 2.0 * Blr * vl * vr + Brr * vr * vr
    V = T * A + v * B
    Vd = Td * A + T * Aq1 + vd * B + v * Bq1
    Vdd0 = 2.0 * Td * Aq1 + T * (Aqq + (Al + Ar) * w0) + vdd * B + 2.0 * vd * Bq1 + v * (Bqq + (Bl + Br) * w0)
    return V, Vd, Vdd0, 0.5 * (T * (Al - Ar) + v * (Bl - Br))


@MK.jit
def extended_law(q, qd, T_raw, Td, ref, p, input_map, k):
    """The law at one state: q, qd (5-tuples), the extension (T_raw, Tdot), ``ref`` (5, 3), p the
    parameters, ``k`` the constants (:func:`extended_constants`). Returns (actuators 4-tuple, Tddot = u_1,
    degenerate)."""
    gp0, gp1, gp2, gp3 = k[K_GAINS], k[K_GAINS + 1], k[K_GAINS + 2], k[K_GAINS + 3]
    ga0, ga1, gs0, gs1 = k[K_GAINS + 4], k[K_GAINS + 5], k[K_GAINS + 6], k[K_GAINS + 7]
    inertia, ll, eps, grav = p[P_I], p[P_LL], p[P_EPS], p[P_G]
    th, ql, qr = q[2], q[3], q[4]
    thd, vl, vr = qd[2], qd[3], qd[4]
    # attitude loop
    e0, e1 = th - ref[0, 2], thd - ref[1, 2]
    v = ref[2, 2] - ga1 * e1 - ga0 * e0
    vd = ref[3, 2] - ga1 * (v - ref[2, 2]) - ga0 * e1
    vdd = ref[4, 2] - ga1 * (vd - ref[3, 2]) - ga0 * (v - ref[2, 2])
    vs = -gs1 * (vl + vr) - gs0 * (ql + qr)
    # thrust map
    sl, cl, sr, cr = math.sin(ql), math.cos(ql), math.sin(qr), math.cos(qr)
    hl, hl1, hl2 = torque_arm(ql, sl, cl, ll, eps, input_map)
    hr, hr1, hr2 = torque_arm(qr, sr, cr, ll, eps, input_map)
    H = hl + hr
    small_h = abs(H) < k[K_MIN_ARM]
    if small_h:
        H = (-1.0 if H < 0 else 1.0) * k[K_MIN_ARM]
    ul0, ul1, ur0, ur1 = sl, cl, -sr, cr  # u_l, u_r
    dl0, dl1, dr0, dr1 = cl, -sl, -cr, -sr  # their derivatives
    A0 = _quotient1(hr * ul0 + hl * ur0, hr * dl0 + hl1 * ur0, hr1 * ul0 + hl * dr0, hr * -ul0 + hl2 * ur0,
                    hr1 * dl0 + hl1 * dr0, hr2 * ul0 + hl * -ur0, H, hl1, hr1, hl2, hr2)
    A1 = _quotient1(hr * ul1 + hl * ur1, hr * dl1 + hl1 * ur1, hr1 * ul1 + hl * dr1, hr * -ul1 + hl2 * ur1,
                    hr1 * dl1 + hl1 * dr1, hr2 * ul1 + hl * -ur1, H, hl1, hr1, hl2, hr2)
    B0 = _quotient1(inertia * (ur0 - ul0), -inertia * dl0, inertia * dr0, -inertia * -ul0, 0.0, inertia * -ur0,
                    H, hl1, hr1, hl2, hr2)
    B1 = _quotient1(inertia * (ur1 - ul1), -inertia * dl1, inertia * dr1, -inertia * -ul1, 0.0, inertia * -ur1,
                    H, hl1, hr1, hl2, hr2)
    small_t = T_raw < k[K_MIN_THRUST]
    T = k[K_MIN_THRUST] if small_t else T_raw
    w0 = 0.5 * vs
    V0, Vd0, Vdd00, G0 = _thrust_map_rates(A0, B0, T, Td, v, vd, vdd, vl, vr, w0)
    V1, Vd1, Vdd01, G1 = _thrust_map_rates(A1, B1, T, Td, v, vd, vdd, vl, vr, w0)
    c, s = math.cos(th), math.sin(th)
    M = p[P_M] + p[P_ML] + p[P_MR]
    RV0, RV1 = _rot(c, s, V0, V1)
    RJV0, RJV1 = _rot(c, s, -V1, V0)
    RVd0, RVd1 = _rot(c, s, Vd0, Vd1)
    RJVd0, RJVd1 = _rot(c, s, -Vd1, Vd0)
    RVdd0, RVdd1 = _rot(c, s, Vdd00, Vdd01)
    Phi0, Phi1 = RV0, RV1 - M * grav
    Phid0, Phid1 = thd * RJV0 + RVd0, thd * RJV1 + RVd1
    Phidd00 = -thd * thd * RV0 + v * RJV0 + 2.0 * thd * RJVd0 + RVdd0
    Phidd01 = -thd * thd * RV1 + v * RJV1 + 2.0 * thd * RJVd1 + RVdd1
    # outputs: the centre of mass and its derivatives (D, C and g from one evaluation of each arm's series)
    bl, br = MK.arm_basis(ql), MK.arm_basis(qr)
    _, _, d03, d13, d04, d14, d33, d44 = MK.mass_entries_basis(bl, br, p)
    lx, lz = MK.arm_offset(ql, p[P_LL], p[P_EPS], -1.0)
    rx, rz = MK.arm_offset(qr, p[P_LL + 1], p[P_EPS], 1.0)
    ml, mr = p[P_ML], p[P_MR]
    y0 = q[0] + (ml * lx + mr * rx) / M
    y1 = q[1] + (ml * lz + mr * rz) / M
    yd0 = qd[0] + (d03 * vl + d04 * vr) / M
    yd1 = qd[1] + (d13 * vl + d14 * vr) / M
    ydd0, ydd1 = Phi0 / M, Phi1 / M
    yddd0, yddd1 = Phid0 / M, Phid1 / M
    y40 = (ref[4, 0] - gp3 * (yddd0 - ref[3, 0]) - gp2 * (ydd0 - ref[2, 0]) - gp1 * (yd0 - ref[1, 0])
           - gp0 * (y0 - ref[0, 0]))
    y41 = (ref[4, 1] - gp3 * (yddd1 - ref[3, 1]) - gp2 * (ydd1 - ref[2, 1]) - gp1 * (yd1 - ref[1, 1])
           - gp0 * (y1 - ref[0, 1]))
    rhs0, rhs1 = M * y40 - Phidd00, M * y41 - Phidd01
    rhs0, rhs1 = c * rhs0 + s * rhs1, -s * rhs0 + c * rhs1
    a0, a1 = A0[0], A1[0]
    det = a0 * G1 - a1 * G0
    u1 = (rhs0 * G1 - rhs1 * G0) / det
    wdel = (a0 * rhs1 - a1 * rhs0) / det
    wl, wr = w0 + 0.5 * wdel, w0 - 0.5 * wdel
    Tl = (T_raw * hr - inertia * v) / H
    Tr = (T_raw * hl + inertia * v) / H
    # arm torques by computed torque
    F = MK.generalized_forces_sc(s, c, ql, qr, (Tl, Tr, 0.0, 0.0), p, input_map)
    c03, c13, c04, c14, c33, c44 = MK.coriolis_entries_basis(bl, br, vl, vr, p)
    g1, g3, g4 = MK.gravity_entries_basis(bl, br, p)
    Cq0, Cq1, Cq3, Cq4 = c03 * vl + c04 * vr, c13 * vl + c14 * vr, c33 * vl, c44 * vr
    pdd0 = (F[0] - (d03 * wl + d04 * wr) - Cq0) / M
    pdd1 = (F[1] - (d13 * wl + d14 * wr) - Cq1 - g1) / M
    tau_l = d03 * pdd0 + d13 * pdd1 + d33 * wl + Cq3 + g3 - F[3]
    tau_r = d04 * pdd0 + d14 * pdd1 + d44 * wr + Cq4 + g4 - F[4]
    return (Tl, Tr, tau_l, tau_r), u1, small_t or small_h


@MK.jit
def _row_start(r, obs, theta, hist, hist_len, xi, weights, p, k, ref, mid):
    """The start of row r of :func:`extended_policy_rows`: its reference-acceleration memory advanced, its
    reference jets at the step's start and midpoint into ``ref`` and ``mid`` (5, 3), and (q, qdot, T, Tdot): the
    state and the extension (a fresh one: the thrust the reference needs, at rest)."""
    n_hist = hist.shape[1]
    m = 0.5 * k[K_DT]
    o = obs[r]
    q = (o[0], o[1], theta[r], o[5], o[6])
    qd = (o[7], o[8], o[9], o[10], o[11])
    for j in range(n_hist - 1, 0, -1):
        for c in range(3):
            hist[r, j, c] = hist[r, j - 1, c]
    for c in range(3):
        hist[r, 0, c] = o[15 + c]
    hist_len[r] = min(hist_len[r] + 1, n_hist)
    for c in range(3):
        ref[0, c] = 0.0
        ref[1, c] = o[12 + c]
        ref[2, c] = o[15 + c]
        ref[3, c] = 0.0
        ref[4, c] = 0.0
        mid[3, c] = 0.0
        mid[4, c] = 0.0
    ref[0, 2] = theta[r] - o[2]
    if hist_len[r] == n_hist:
        for c in range(3):
            j3 = j4 = m3 = m4 = 0.0
            for i in range(n_hist):
                a = hist[r, i, c]
                j3 += weights[0, i] * a
                j4 += weights[1, i] * a
                m3 += weights[2, i] * a
                m4 += weights[3, i] * a
            ref[3, c], ref[4, c], mid[3, c], mid[4, c] = j3, j4, m3, m4
    for c in range(3):
        mid[0, c] = (ref[0, c] + m * ref[1, c] + m * m / 2 * ref[2, c] + m ** 3 / 6 * ref[3, c]
                     + m ** 4 / 24 * ref[4, c])
        mid[1, c] = ref[1, c] + m * ref[2, c] + m * m / 2 * ref[3, c] + m ** 3 / 6 * ref[4, c]
        mid[2, c] = ref[2, c] + m * ref[3, c] + m * m / 2 * ref[4, c]
    T0, Td0 = xi[r, 0], xi[r, 1]
    if math.isnan(T0):  # a fresh extension: the thrust the reference needs, at rest
        T0 = k[K_INITIAL_THRUST]
        if math.isnan(T0):
            T0 = (p[P_M] + p[P_ML] + p[P_MR]) * math.hypot(o[15], o[16] + p[P_G])
        T0 = max(T0, k[K_MIN_THRUST])
        Td0 = 0.0
    return q, qd, T0, Td0


@MK.accessor
def _lane_put_step(W, j, q, qd, act, p):
    """Lane j of an RK4 lane block (``MK.RK4_LANES``): the state, the actuators held (the fifth entry 0), no
    external force, the parameters."""
    L = MK.LANES
    for i in range(5):
        W[(MK.LANE_Q + i) * L + j] = q[i]
        W[(MK.LANE_QD + i) * L + j] = qd[i]
    for i in range(4):
        W[(MK.LANE_U + i) * L + j] = act[i]
    W[(MK.LANE_U + 4) * L + j] = 0.0
    W[MK.LANE_EXT * L + j] = 0.0
    W[(MK.LANE_EXT + 1) * L + j] = 0.0
    for i in range(p.shape[0]):
        W[(MK.LANE_P + i) * L + j] = p[i]


@MK.jit
def extended_policy_rows(lo, hi, obs, theta, hist, hist_len, xi, weights, p, input_map, k, midpoint,
                         out, err, simd=None):
    """``ExtendedPolicy.predict`` for rows lo..hi-1: observations (n, 18) and numpy's theta (n,); memory
    ``hist`` (n, H, 3), ``hist_len`` (n,), the extension ``xi`` (n, 2) (NaN: fresh) updated in place;
    ``weights`` (4, H) of the cubic fit; actions into ``out`` (n, 4) float32; per row ``err`` (ERR_*).
    Returns the number of rows with an error (their extension is left as it was).

    Each row is :meth:`ExtendedController.held_step <softpvtol_gym.control.extended.ExtendedController.held_step>`:
    the law at the step's start; with ``midpoint``, the RK4 half step of the model under that command, and the
    law at the predicted midpoint (the start's command if the midpoint leaves the model's range); the extension
    advanced by Tddot. The half steps of up to ``MK.LANES`` rows run as one lane block: ``MK.rk4_lanes``, SIMD
    for a full block, when ``simd`` is not None (numba prunes the other branch: a small batch does not compile
    the SIMD step), else ``MK.rk4_lanes_partial`` lane by lane; every lane's operations are the scalar step's."""
    L = MK.LANES
    lanes = min(L, hi - lo)  # (a single row's call allocates for one)
    refs = np.empty((lanes, 5, 3))  # (every entry written by _row_start)
    mids = np.empty((lanes, 5, 3))
    start = np.empty((lanes, 7))  # per lane: T, Tdot, the start's actuators (4) and Tddot
    W = np.empty(MK.LANE_ROWS_RK4 * L if midpoint else 0)
    h = k[K_DT]
    m = 0.5 * h
    bad = 0
    for b0 in range(lo, hi, L):
        nb = min(L, hi - b0)
        for j in range(nb):
            q, qd, T0, Td0 = _row_start(b0 + j, obs, theta, hist, hist_len, xi, weights, p, k, refs[j], mids[j])
            act, u0, _ = extended_law(q, qd, T0, Td0, refs[j], p, input_map, k)
            start[j, 0], start[j, 1], start[j, 6] = T0, Td0, u0
            for i in range(4):
                start[j, 2 + i] = act[i]
            if midpoint:
                _lane_put_step(W, j, q, qd, act, p)
        if midpoint:
            if simd is not None:
                MK.rk4_lanes(W, m, nb, input_map)
            else:
                MK.rk4_lanes_partial(W, m, nb, input_map)
        for j in range(nb):
            r = b0 + j
            T0, Td0, u0 = start[j, 0], start[j, 1], start[j, 6]
            act = (start[j, 2], start[j, 3], start[j, 4], start[j, 5])
            if midpoint:
                qm, vm, _, _, _ = MK.lane_load(W, j)
                ok = abs(qm[3]) <= math.pi and abs(qm[4]) <= math.pi
                for i in range(5):
                    ok = ok and math.isfinite(qm[i]) and math.isfinite(vm[i])
                if ok:  # (else the start's command: a midpoint predicted outside the model's range)
                    act, u0, _ = extended_law(qm, vm, T0 + m * Td0 + 0.5 * m * m * u0, Td0 + m * u0, mids[j], p,
                                              input_map, k)
            T1, Td1 = T0 + h * Td0 + 0.5 * h * h * u0, Td0 + h * u0
            a0 = 2.0 * act[0] / k[K_TMAX] - 1.0
            a1 = 2.0 * act[1] / k[K_TMAX] - 1.0
            a2 = act[2] / k[K_TAUMAX]
            a3 = act[3] / k[K_TAUMAX]
            if not (math.isfinite(a0) and math.isfinite(a1) and math.isfinite(a2) and math.isfinite(a3)):
                err[r] = ERR_NONFINITE
                bad += 1
                continue
            err[r] = ERR_NONE
            xi[r, 0], xi[r, 1] = T1, Td1
            out[r, 0] = min(max(a0, -1.0), 1.0)
            out[r, 1] = min(max(a1, -1.0), 1.0)
            out[r, 2] = min(max(a2, -1.0), 1.0)
            out[r, 3] = min(max(a3, -1.0), 1.0)
    return bad
