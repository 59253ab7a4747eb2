"""Compiled kernels of the passivity controller and the control allocations.

Built on the model kernels (:mod:`softpvtol_gym._kernels`): D, C and g are never written again here.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .. import _kernels as MK

_jit = njit(cache=True, fastmath=False, nogil=True, error_model="numpy")

ALLOC_PAPER = 0
ALLOC_EXACT = 1

# info columns returned by the allocation kernels
INFO_RESIDUAL = 0
INFO_ITERATIONS = 1
INFO_FEASIBLE = 2
N_INFO = 3


@_jit
def passivity_into(q, qd, qr, qdr, qddr, p, lam, kg, out):
    """tau = D(q) a + C(q, qd) v + g(q) - K r  (Slotine–Li / Spong form, paper eq. (passControl))."""
    D = np.empty((5, 5))
    C = np.empty((5, 5))
    g = np.empty(5)
    MK.mass_matrix_into(q, p, D)
    MK.coriolis_matrix_into(q, qd, p, C)
    MK.gravity_vector_into(q, p, g)
    v = np.empty(5)
    a = np.empty(5)
    for i in range(5):
        v[i] = qdr[i] - lam[i] * (q[i] - qr[i])
        a[i] = qddr[i] - lam[i] * (qd[i] - qdr[i])
    for i in range(5):
        acc = g[i] - kg[i] * (qd[i] - v[i])
        for j in range(5):
            acc += D[i, j] * a[j] + C[i, j] * v[j]
        out[i] = acc


@_jit
def storage_into(q, qd, qr, qdr, p, lam, kg):
    """V = 1/2 r^T D r + q~^T Lambda K q~ (paper eq. (lyap))."""
    D = np.empty((5, 5))
    MK.mass_matrix_into(q, p, D)
    r = np.empty(5)
    V = 0.0
    for i in range(5):
        e = q[i] - qr[i]
        r[i] = qd[i] - qdr[i] + lam[i] * e
        V += lam[i] * kg[i] * e * e
    for i in range(5):
        for j in range(5):
            V += 0.5 * r[i] * D[i, j] * r[j]
    return V


# ------------------------------------------------------------------------------ exact allocation
@_jit
def _lever(v, h, length, eps, input_map):
    """Torque lever term G(v) of one rotor whose thrust has body components (h, v), and dG/dv.

    The rotor's curvature is q = atan2(h, v) and its thrust T = hypot(h, v) >= 0.
    paper map:  G = l v sin(q)/q;  exact map: G = eps v + l T sin(q)/q.
    """
    q = math.atan2(h, v)
    T = math.hypot(h, v)
    s0 = MK.sinc(q)
    # d sinc / dq = -q A(q); dq/dv = -h / T^2
    dsinc = -q * MK.horner(MK._A, q * q)
    if input_map == MK.INPUT_MAP_PAPER:
        G = length * v * s0
        dG = length * s0 + (length * v * dsinc * (-h / (T * T)) if T > 0.0 else 0.0)
    else:
        G = eps * v + length * T * s0
        dG = eps + (length * (v * s0 + q * h * MK.horner(MK._A, q * q)) / T if T > 0.0 else length)
    return G, dG


@_jit
def allocate_exact_into(tau, theta, p, input_map, warm, use_warm, qmax, out, info):
    """(T_l, T_r, q_l^d, q_r^d) realising the body force (tau_x, tau_z, tau_theta) exactly.

    The horizontal body force is split equally (the paper's minimum-norm choice); the vertical split
    v_l + v_r = v_z is the root of the scalar torque equation, found by safeguarded Newton on a
    bracket, so it converges for any finite input. Curvatures come from atan2, so thrusts are never
    negative and downward vertical components are allowed. If a curvature beyond +/- qmax would be
    needed, it is clipped and the result is flagged infeasible (the residual tells by how much).
    """
    ll, lr, eps = p[6], p[7], p[9]
    ct, st = math.cos(theta), math.sin(theta)
    ux = ct * tau[0] + st * tau[1]
    uz = -st * tau[0] + ct * tau[1]
    tt = tau[2]
    h = 0.5 * ux
    scale = 1.0 + abs(uz) + abs(ux) + abs(tt)

    # F(vl) = G_r(uz - vl; -h) - G_l(vl; h) - tau_theta is non-increasing in vl: bracket and solve
    lo = -scale * (1.0 + 1.0 / min(ll, lr))
    hi = -lo
    for _ in range(60):
        Glo, _d = _lever(lo, h, ll, eps, input_map)
        Grl, _d = _lever(uz - lo, -h, lr, eps, input_map)
        if Grl - Glo - tt > 0.0:
            break
        lo *= 2.0
    for _ in range(60):
        Ghi, _d = _lever(hi, h, ll, eps, input_map)
        Grh, _d = _lever(uz - hi, -h, lr, eps, input_map)
        if Grh - Ghi - tt < 0.0:
            break
        hi *= 2.0
    x = 0.5 * uz
    if use_warm and math.isfinite(warm[0] + warm[2]):  # a NaN row means: cold start
        x = warm[0] * math.cos(warm[2])
    if not (lo < x < hi):
        x = 0.5 * (lo + hi)
    F = 0.0
    it = 0
    for it in range(1, 101):
        Gl, dGl = _lever(x, h, ll, eps, input_map)
        Gr, dGr = _lever(uz - x, -h, lr, eps, input_map)
        F = Gr - Gl - tt
        if abs(F) <= 1e-13 * scale:
            break
        if F > 0.0:
            lo = x
        else:
            hi = x
        dF = -dGr - dGl
        xn = x - F / dF if dF < 0.0 else 0.5 * (lo + hi)
        if not (lo < xn < hi):
            xn = 0.5 * (lo + hi)
        if abs(xn - x) <= 1e-16 * (1.0 + abs(x)):
            x = xn
            break
        x = xn
    vl = x
    vr = uz - x
    ql = math.atan2(h, vl)
    qr = math.atan2(-h, vr)
    Tl = math.hypot(h, vl)
    Tr = math.hypot(h, vr)
    feasible = 1.0
    if abs(ql) > qmax or abs(qr) > qmax:
        feasible = 0.0
        ql = min(max(ql, -qmax), qmax)
        qr = min(max(qr, -qmax), qmax)
    out[0] = Tl
    out[1] = Tr
    out[2] = ql
    out[3] = qr
    # residual: realised body force (through the chosen input map) minus the requested one
    a = np.array([Tl, Tr, 0.0, 0.0])
    qq = np.array([0.0, 0.0, theta, ql, qr])
    tr = np.empty(5)
    MK.generalized_forces_into(qq, a, p, input_map, tr)
    info[INFO_RESIDUAL] = max(abs(tr[0] - tau[0]), abs(tr[1] - tau[1]), abs(tr[2] - tau[2]))
    info[INFO_ITERATIONS] = it
    info[INFO_FEASIBLE] = feasible


# ------------------------------------------------------------------------------ paper allocation
@_jit
def _atan_ratio(num, den):
    """arctan(num/den) as printed (not atan2); 0/0 -> 0 instead of NaN."""
    if den == 0.0:
        if num == 0.0:
            return 0.0
        return math.copysign(0.5 * math.pi, num) * math.copysign(1.0, den)
    return math.atan(num / den)


@_jit
def _paper_map(ql, qr, ux, uz, tt, ll, lr):
    """Right-hand sides of the paper's eq. (solve_num) for given desired curvatures."""
    cl = math.cos(0.5 * ql)
    cr = math.cos(0.5 * qr)
    S = ll * cl + lr * cr
    nl = lr * cr * uz - tt
    nr = ll * cl * uz + tt
    Tl = math.sqrt((0.5 * ux) ** 2 + (nl / S) ** 2)
    Tr = math.sqrt((0.5 * ux) ** 2 + (nr / S) ** 2)
    return Tl, Tr, _atan_ratio(ux * S, 2.0 * nl), _atan_ratio(-ux * S, 2.0 * nr)


@_jit
def allocate_paper_into(tau, theta, p, warm, use_warm, out, info):
    """The paper's allocation (Sec. 3.1): cos(q/2) for sin(q)/q, arctan/sqrt closed form, and the
    fixed point in (q_l^d, q_r^d) solved by Newton from the paper's initial guess (20, 10, 0.4, -0.2)
    or from ``warm``. ``info`` residual = max |f(x)| of the paper's own eq. (solve_num)."""
    ll, lr = p[6], p[7]
    ct, st = math.cos(theta), math.sin(theta)
    ux = ct * tau[0] + st * tau[1]
    uz = -st * tau[0] + ct * tau[1]
    tt = tau[2]
    if use_warm and math.isfinite(warm[2] + warm[3]):  # a NaN row means: cold start
        ql, qr = warm[2], warm[3]
    else:
        ql, qr = 0.4, -0.2
    eps = 1e-7
    it = 0
    for it in range(1, 61):
        _a, _b, pl, pr = _paper_map(ql, qr, ux, uz, tt, ll, lr)
        F0 = ql - pl
        F1 = qr - pr
        if abs(F0) + abs(F1) <= 1e-15:
            break
        # central-difference Jacobian of F(q) = q - phi(q)
        _a, _b, pl1, pr1 = _paper_map(ql + eps, qr, ux, uz, tt, ll, lr)
        _a, _b, pl2, pr2 = _paper_map(ql - eps, qr, ux, uz, tt, ll, lr)
        _a, _b, pl3, pr3 = _paper_map(ql, qr + eps, ux, uz, tt, ll, lr)
        _a, _b, pl4, pr4 = _paper_map(ql, qr - eps, ux, uz, tt, ll, lr)
        J00 = 1.0 - (pl1 - pl2) / (2 * eps)
        J10 = -(pr1 - pr2) / (2 * eps)
        J01 = -(pl3 - pl4) / (2 * eps)
        J11 = 1.0 - (pr3 - pr4) / (2 * eps)
        det = J00 * J11 - J01 * J10
        if det == 0.0 or not math.isfinite(det):
            ql, qr = pl, pr  # fall back to a fixed-point step
            continue
        dql = (J11 * F0 - J01 * F1) / det
        dqr = (J00 * F1 - J10 * F0) / det
        ql -= dql
        qr -= dqr
    Tl, Tr, pl, pr = _paper_map(ql, qr, ux, uz, tt, ll, lr)
    out[0] = Tl
    out[1] = Tr
    out[2] = ql
    out[3] = qr
    # residual of the paper's four equations at x = (T_l, T_r, q_l, q_r)
    info[INFO_RESIDUAL] = max(abs(ql - pl), abs(qr - pr))
    info[INFO_ITERATIONS] = it
    info[INFO_FEASIBLE] = 1.0 if math.isfinite(ql + qr + Tl + Tr) else 0.0


# ------------------------------------------------------------------------------------- batched
@njit(cache=True, parallel=True)
def batch_passivity(q, qd, qr, qdr, qddr, P, lam, kg, out):
    ps = np.int64(P.shape[0] > 1)
    for n in prange(q.shape[0]):
        passivity_into(q[n], qd[n], qr[n], qdr[n], qddr[n], P[n * ps], lam, kg, out[n])


@njit(cache=True, parallel=True)
def batch_storage(q, qd, qr, qdr, P, lam, kg, out):
    ps = np.int64(P.shape[0] > 1)
    for n in prange(q.shape[0]):
        out[n] = storage_into(q[n], qd[n], qr[n], qdr[n], P[n * ps], lam, kg)


@njit(cache=True, parallel=True)
def batch_allocate(tau, theta, P, method, input_map, warm, use_warm, qmax, out, info):
    ps = np.int64(P.shape[0] > 1)
    ws = np.int64(warm.shape[0] > 1)
    for n in prange(tau.shape[0]):
        if method == ALLOC_PAPER:
            allocate_paper_into(tau[n], theta[n], P[n * ps], warm[n * ws], use_warm, out[n], info[n])
        else:
            allocate_exact_into(
                tau[n], theta[n], P[n * ps], input_map, warm[n * ws], use_warm, qmax, out[n], info[n]
            )
