"""Compiled kernels of the passivity controller and the control allocations.

Built on the model kernels (:mod:`softpvtol_gym._kernels`): D, C and g are never written again here.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .. import _kernels as MK

_jit = njit(cache=True, fastmath=False, nogil=True, error_model="numpy")

ALLOC_PAPER = 0
ALLOC_EXACT = 1

# info columns returned by the allocation kernels
INFO_RESIDUAL = 0
INFO_ITERATIONS = 1
INFO_FEASIBLE = 2
N_INFO = 3


@MK._inline
def model_entries(q, qd, p):
    """The nonzero entries of D(q), C(q, qdot), g(q) (model kernels: mass_entries, coriolis_entries,
    gravity_entries)."""
    return (MK.mass_entries(q[3], q[4], p), MK.coriolis_entries(q[3], q[4], qd[3], qd[4], p),
            MK.gravity_entries(q[3], q[4], p))


@MK._inline
def _row(acc, d0, d1, d2, d3, d4, c0, c1, c2, c3, c4, a, v):
    """acc + sum_j (D_ij a_j + C_ij v_j), term by term in j order (the dense loop's rounding; zero
    entries are multiplied, so inf/NaN propagate as in the dense product)."""
    acc += d0 * a[0] + c0 * v[0]
    acc += d1 * a[1] + c1 * v[1]
    acc += d2 * a[2] + c2 * v[2]
    acc += d3 * a[3] + c3 * v[3]
    acc += d4 * a[4] + c4 * v[4]
    return acc


@MK._inline
def passivity_rows(ents, q, qd, qr, qdr, qddr, lam, kg):
    """tau = D(q) a + C(q, qd) v + g(q) - K r as a 5-tuple, D, C, g given by their entries
    (:func:`model_entries`); v = qdot_ref - Lambda q~, a = qddot_ref - Lambda (qdot - qdot_ref)."""
    (M, inertia, d03, d13, d04, d14, d33, d44), (c03, c13, c04, c14, c33, c44), (g1, g3, g4) = ents
    v = (qdr[0] - lam[0] * (q[0] - qr[0]), qdr[1] - lam[1] * (q[1] - qr[1]), qdr[2] - lam[2] * (q[2] - qr[2]),
         qdr[3] - lam[3] * (q[3] - qr[3]), qdr[4] - lam[4] * (q[4] - qr[4]))
    a = (qddr[0] - lam[0] * (qd[0] - qdr[0]), qddr[1] - lam[1] * (qd[1] - qdr[1]),
         qddr[2] - lam[2] * (qd[2] - qdr[2]), qddr[3] - lam[3] * (qd[3] - qdr[3]),
         qddr[4] - lam[4] * (qd[4] - qdr[4]))
    z = 0.0
    return (
        _row(z - kg[0] * (qd[0] - v[0]), M, z, z, d03, d04, z, z, z, c03, c04, a, v),
        _row(g1 - kg[1] * (qd[1] - v[1]), z, M, z, d13, d14, z, z, z, c13, c14, a, v),
        _row(z - kg[2] * (qd[2] - v[2]), z, z, inertia, z, z, z, z, z, z, z, a, v),
        _row(g3 - kg[3] * (qd[3] - v[3]), d03, d13, z, d33, z, z, z, z, c33, z, a, v),
        _row(g4 - kg[4] * (qd[4] - v[4]), d04, d14, z, z, d44, z, z, z, z, c44, a, v),
    )


@_jit
def passivity_into(q, qd, qr, qdr, qddr, p, lam, kg, out):
    """tau = D(q) a + C(q, qd) v + g(q) - K r  (Slotine–Li / Spong form, paper eq. (passControl))."""
    t = passivity_rows(model_entries(q, qd, p), q, qd, qr, qdr, qddr, lam, kg)
    out[0], out[1], out[2], out[3], out[4] = t


@MK._inline
def storage(q, qd, qr, qdr, p, lam, kg):
    """V = 1/2 r^T D r + q~^T Lambda K q~ (paper eq. (lyap)); arrays or tuples, no allocation.

    The quadratic form is summed entry by entry in row-major order, zero entries of D included, so
    the rounding (and NaN propagation) is that of the dense double loop.
    """
    M, inertia, d03, d13, d04, d14, d33, d44 = MK.mass_entries(q[3], q[4], p)
    e0 = q[0] - qr[0]
    e1 = q[1] - qr[1]
    e2 = q[2] - qr[2]
    e3 = q[3] - qr[3]
    e4 = q[4] - qr[4]
    r0 = qd[0] - qdr[0] + lam[0] * e0
    r1 = qd[1] - qdr[1] + lam[1] * e1
    r2 = qd[2] - qdr[2] + lam[2] * e2
    r3 = qd[3] - qdr[3] + lam[3] * e3
    r4 = qd[4] - qdr[4] + lam[4] * e4
    V = 0.0
    V += lam[0] * kg[0] * e0 * e0
    V += lam[1] * kg[1] * e1 * e1
    V += lam[2] * kg[2] * e2 * e2
    V += lam[3] * kg[3] * e3 * e3
    V += lam[4] * kg[4] * e4 * e4
    h = 0.5 * r0
    V += h * M * r0
    V += h * 0.0 * r1
    V += h * 0.0 * r2
    V += h * d03 * r3
    V += h * d04 * r4
    h = 0.5 * r1
    V += h * 0.0 * r0
    V += h * M * r1
    V += h * 0.0 * r2
    V += h * d13 * r3
    V += h * d14 * r4
    h = 0.5 * r2
    V += h * 0.0 * r0
    V += h * 0.0 * r1
    V += h * inertia * r2
    V += h * 0.0 * r3
    V += h * 0.0 * r4
    h = 0.5 * r3
    V += h * d03 * r0
    V += h * d13 * r1
    V += h * 0.0 * r2
    V += h * d33 * r3
    V += h * 0.0 * r4
    h = 0.5 * r4
    V += h * d04 * r0
    V += h * d14 * r1
    V += h * 0.0 * r2
    V += h * 0.0 * r3
    V += h * d44 * r4
    return V


@_jit
def storage_into(q, qd, qr, qdr, p, lam, kg):
    """:func:`storage` (compiled entry point for arrays)."""
    return storage(q, qd, qr, qdr, p, lam, kg)


# ------------------------------------------------------------------------------ exact allocation
@MK._inline
def _lever_poly(v, h, q, T, length, eps, input_map):
    """(G, dG/dv) of :func:`_lever` given q = atan2(h, v) and T = hypot(h, v): the polynomial part
    (vectorizes over a lane block)."""
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
def _lever(v, h, length, eps, input_map):
    """Torque lever term G(v) of one rotor whose thrust has body components (h, v), dG/dv, and the
    rotor's curvature q = atan2(h, v) and thrust T = hypot(h, v) >= 0: (G, dG, q, T).

    paper map:  G = l v sin(q)/q;  exact map: G = eps v + l T sin(q)/q.
    """
    q = math.atan2(h, v)
    T = math.hypot(h, v)
    G, dG = _lever_poly(v, h, q, T, length, eps, input_map)
    return G, dG, q, T


@_jit
def _widen_lo(lo, uz, h, tt, ll, lr, eps, input_map):
    """Lower end of the bracket: doubled until F(lo) > 0 (at most 60 times)."""
    for _ in range(60):
        Glo, _d, _q, _t = _lever(lo, h, ll, eps, input_map)
        Grl, _d, _q, _t = _lever(uz - lo, -h, lr, eps, input_map)
        if Grl - Glo - tt > 0.0:
            break
        lo *= 2.0
    return lo


@_jit
def _widen_hi(hi, uz, h, tt, ll, lr, eps, input_map):
    """Upper end of the bracket: doubled until F(hi) < 0 (at most 60 times)."""
    for _ in range(60):
        Ghi, _d, _q, _t = _lever(hi, h, ll, eps, input_map)
        Grh, _d, _q, _t = _lever(uz - hi, -h, lr, eps, input_map)
        if Grh - Ghi - tt < 0.0:
            break
        hi *= 2.0
    return hi


@_jit
def _bracket_point(x, lo, hi, lo_raw, hi_raw, uz, h, tt, ll, lr, eps, input_map):
    """Make x a point strictly inside the bracket: widen a not-yet-widened end that x lies beyond;
    if x is still outside (or NaN), widen both raw ends and take the midpoint.
    Returns (x, lo, hi, lo_raw, hi_raw)."""
    if lo_raw and not (lo < x):
        lo = _widen_lo(lo, uz, h, tt, ll, lr, eps, input_map)
        lo_raw = False
    if hi_raw and not (x < hi):
        hi = _widen_hi(hi, uz, h, tt, ll, lr, eps, input_map)
        hi_raw = False
    if not (lo < x < hi):
        if lo_raw:
            lo = _widen_lo(lo, uz, h, tt, ll, lr, eps, input_map)
            lo_raw = False
        if hi_raw:
            hi = _widen_hi(hi, uz, h, tt, ll, lr, eps, input_map)
            hi_raw = False
        x = 0.5 * (lo + hi)
    return x, lo, hi, lo_raw, hi_raw


@MK._inline
def _exact_setup(t0, t1, t2, theta, p, input_map, w0, w2, use_warm):
    """Start of :func:`allocate_exact`: the body force in body axes, the bracket and the first point.
    Returns ((x, lo, hi, lo_raw, hi_raw), (uz, h, tt, scale, st, ct))."""
    ll, lr, eps = p[6], p[7], p[9]
    ct, st = math.cos(theta), math.sin(theta)
    ux = ct * t0 + st * t1
    uz = -st * t0 + ct * t1
    tt = t2
    h = 0.5 * ux
    scale = 1.0 + abs(uz) + abs(ux) + abs(tt)
    # F(vl) = G_r(uz - vl; -h) - G_l(vl; h) - tau_theta is non-increasing in vl: bracket and solve
    lo = -scale * (1.0 + 1.0 / min(ll, lr))
    hi = -lo
    lo_raw = True  # lo/hi not yet widened
    hi_raw = True
    x = 0.5 * uz
    if use_warm and math.isfinite(w0 + w2):  # a NaN row means: cold start
        x = w0 * math.cos(w2)
    x, lo, hi, lo_raw, hi_raw = _bracket_point(x, lo, hi, lo_raw, hi_raw, uz, h, tt, ll, lr, eps, input_map)
    return (x, lo, hi, lo_raw, hi_raw), (uz, h, tt, scale, st, ct)


@MK._inline
def _exact_newton(x, lo, hi, lo_raw, hi_raw, Gl, dGl, Gr, dGr, uz, h, tt, scale, p, input_map):
    """One safeguarded Newton iteration of :func:`allocate_exact` from the levers at x.
    Returns (status, x, lo, hi, lo_raw, hi_raw); status 0: go on from the new x, 1: converged at x
    (the levers' q and T are the result's), 2: converged at the new x (not evaluated)."""
    F = Gr - Gl - tt
    if abs(F) <= 1e-13 * scale:
        return 1, x, lo, hi, lo_raw, hi_raw
    if F > 0.0:
        lo = x
        lo_raw = False
    else:
        hi = x
        hi_raw = False
    dF = -dGr - dGl
    # a Newton step, or (dF >= 0: no usable step) NaN, which lies inside no bracket: bisection
    xn = x - F / dF if dF < 0.0 else math.nan
    xn, lo, hi, lo_raw, hi_raw = _bracket_point(xn, lo, hi, lo_raw, hi_raw, uz, h, tt, p[6], p[7], p[9], input_map)
    if abs(xn - x) <= 1e-16 * (1.0 + abs(x)):
        return 2, xn, lo, hi, lo_raw, hi_raw
    return 0, xn, lo, hi, lo_raw, hi_raw


@MK._inline
def _exact_result(x, evaluated, ql, Tl, qr, Tr, uz, h, st, ct, t0, t1, t2, p, input_map, qmax, it):
    """End of :func:`allocate_exact` at the solution x (the split v_l = x): curvatures, thrusts, the
    curvature clip and the residual. (ql, Tl, qr, Tr): those of the levers at x if ``evaluated``."""
    if not evaluated:
        vl = x
        vr = uz - x
        ql = math.atan2(h, vl)
        qr = math.atan2(-h, vr)
        Tl = math.hypot(h, vl)
        Tr = math.hypot(-h, vr)
    feasible = 1.0
    if abs(ql) > qmax or abs(qr) > qmax:
        feasible = 0.0
        ql = min(max(ql, -qmax), qmax)
        qr = min(max(qr, -qmax), qmax)
    # residual: realised body force (through the chosen input map) minus the requested one
    tr = MK.thrust_body_forces(st, ct, ql, qr, Tl, Tr, p, input_map)
    residual = max(abs(tr[0] - t0), abs(tr[1] - t1), abs(tr[2] - t2))
    return (Tl, Tr, ql, qr), (residual, float(it), feasible)


@_jit
def allocate_exact(t0, t1, t2, theta, p, input_map, w0, w2, use_warm, qmax):
    """(T_l, T_r, q_l^d, q_r^d) realising the body force (tau_x, tau_z, tau_theta) exactly.

    The horizontal body force is split equally (the paper's minimum-norm choice); the vertical split
    v_l + v_r = v_z is the root of the scalar torque equation, found by safeguarded Newton on a
    bracket, so it converges for any finite input. Curvatures come from atan2, so thrusts are never
    negative and downward vertical components are allowed. If a curvature beyond +/- qmax would be
    needed, it is clipped and the result is flagged infeasible (the residual tells by how much).
    Returns ((T_l, T_r, q_l^d, q_r^d), (residual, iterations, feasible)); (t0, t1, t2) the body rows
    of tau, (w0, w2) = (T_l, q_l^d) of the warm start.

    The bracket [lo, hi] starts at -/+ scale (1 + 1/min(l_l, l_r)) and each end is doubled until
    F changes sign there. The doubling is done lazily, the first time the end's value matters: it only
    moves an end outwards, so a test ``lo < x`` (``x < hi``) that holds before holds after, and an end
    replaced by a Newton iterate is never needed. The iterates are those of the eager bracket, bit
    for bit; a well warm-started solve skips the four bracket evaluations.

    :func:`allocate_exact_lanes` runs the same steps (``_exact_setup``, ``_lever``, ``_exact_newton``,
    ``_exact_result``) for a block of problems at once.
    """
    ll, lr, eps = p[6], p[7], p[9]
    (x, lo, hi, lo_raw, hi_raw), (uz, h, tt, scale, st, ct) = _exact_setup(t0, t1, t2, theta, p, input_map, w0,
                                                                           w2, use_warm)
    ql = qr = Tl = Tr = 0.0
    status = 0
    it = 0
    for it in range(1, 101):
        Gl, dGl, ql, Tl = _lever(x, h, ll, eps, input_map)
        Gr, dGr, qr, Tr = _lever(uz - x, -h, lr, eps, input_map)
        status, x, lo, hi, lo_raw, hi_raw = _exact_newton(x, lo, hi, lo_raw, hi_raw, Gl, dGl, Gr, dGr, uz, h, tt,
                                                          scale, p, input_map)
        if status != 0:
            break
    return _exact_result(x, status == 1, ql, Tl, qr, Tr, uz, h, st, ct, t0, t1, t2, p, input_map, qmax, it)


#: rows of the work array of :func:`allocate_exact_lanes` (one column per lane)
(AW_X, AW_LO, AW_HI, AW_LO_RAW, AW_HI_RAW, AW_UZ, AW_H, AW_TT, AW_SCALE, AW_ST, AW_CT, AW_QL, AW_TL, AW_QR, AW_TR,
 AW_GL, AW_DGL, AW_GR, AW_DGR, AW_LIVE, AW_IT) = range(21)
N_AW = 21


@_jit
def allocate_exact_lanes(m, X, r_tau, r_theta, r_warm, r_active, r_out, r_info, A, use_warm, p, input_map, qmax):
    """:func:`allocate_exact` for the m problems of a lane block at once, every lane's arithmetic
    that of allocate_exact, bit for bit.

    X is a flat lane block (row r, lane j at ``X[r * CTRL_LANES + j]``) holding the inputs and
    receiving the results in its rows: r_tau (3): body rows of the force; r_theta: theta; r_warm (4):
    (T_l, T_r, q_l^d, q_r^d) of the warm start (may be r_out itself); r_active: lanes to solve
    (nonzero; the others are left alone); r_out (4), r_info (N_INFO): the results. A (N_AW lane rows):
    work. The Newton iterations of the lanes are interleaved: one lane's iteration is a chain of
    dependent libm calls and polynomials, so lanes side by side keep the CPU busy, and the
    polynomials of all lanes run as one SIMD loop.
    """
    L = CTRL_LANES
    ll, lr, eps = p[6], p[7], p[9]
    tau0, tau1, tau2, th_, act_ = r_tau * L, (r_tau + 1) * L, (r_tau + 2) * L, r_theta * L, r_active * L
    x_, lo_, hi_, lor_, hir_, uz_, h_, tt_ = AW_X * L, AW_LO * L, AW_HI * L, AW_LO_RAW * L, AW_HI_RAW * L, AW_UZ * L, \
        AW_H * L, AW_TT * L
    sc_, st_, ct_, ql_, tl_, qr_, tr_ = AW_SCALE * L, AW_ST * L, AW_CT * L, AW_QL * L, AW_TL * L, AW_QR * L, AW_TR * L
    gl_, dgl_, gr_, dgr_, live_, it_ = AW_GL * L, AW_DGL * L, AW_GR * L, AW_DGR * L, AW_LIVE * L, AW_IT * L
    live = 0
    for j in range(m):
        if X[act_ + j] != 0.0:
            (x, lo, hi, lo_raw, hi_raw), (uz, h, tt, scale, st, ct) = _exact_setup(
                X[tau0 + j], X[tau1 + j], X[tau2 + j], X[th_ + j], p, input_map, X[r_warm * L + j],
                X[(r_warm + 2) * L + j], use_warm)
            A[x_ + j], A[lo_ + j], A[hi_ + j] = x, lo, hi
            A[lor_ + j], A[hir_ + j] = 1.0 if lo_raw else 0.0, 1.0 if hi_raw else 0.0
            A[uz_ + j], A[h_ + j], A[tt_ + j], A[sc_ + j], A[st_ + j], A[ct_ + j] = uz, h, tt, scale, st, ct
            A[live_ + j] = 1.0
            live += 1
        else:
            A[x_ + j], A[uz_ + j], A[h_ + j] = 0.0, 0.0, 0.0
            A[live_ + j] = 0.0
    for it in range(1, 101):
        if live == 0:
            break
        for j in range(m):  # libm (atan2, hypot): independent lanes, overlapped by the CPU
            if A[live_ + j] == 1.0:
                x, h = A[x_ + j], A[h_ + j]
                vr = A[uz_ + j] - x
                A[ql_ + j] = math.atan2(h, x)
                A[tl_ + j] = math.hypot(h, x)
                A[qr_ + j] = math.atan2(-h, vr)
                A[tr_ + j] = math.hypot(-h, vr)
        for j in range(L):  # polynomials of every lane (finished and unused ones too: SIMD)
            x, h = A[x_ + j], A[h_ + j]
            A[gl_ + j], A[dgl_ + j] = _lever_poly(x, h, A[ql_ + j], A[tl_ + j], ll, eps, input_map)
            A[gr_ + j], A[dgr_ + j] = _lever_poly(A[uz_ + j] - x, -h, A[qr_ + j], A[tr_ + j], lr, eps, input_map)
        for j in range(m):
            if A[live_ + j] != 1.0:
                continue
            status, x, lo, hi, lo_raw, hi_raw = _exact_newton(
                A[x_ + j], A[lo_ + j], A[hi_ + j], A[lor_ + j] != 0.0, A[hir_ + j] != 0.0, A[gl_ + j], A[dgl_ + j],
                A[gr_ + j], A[dgr_ + j], A[uz_ + j], A[h_ + j], A[tt_ + j], A[sc_ + j], p, input_map)
            A[x_ + j], A[lo_ + j], A[hi_ + j] = x, lo, hi
            A[lor_ + j], A[hir_ + j] = 1.0 if lo_raw else 0.0, 1.0 if hi_raw else 0.0
            if status != 0:
                A[live_ + j] = 1.0 + status  # done: 2 (converged at x) or 3 (at the new x)
                A[it_ + j] = it
                live -= 1
    # (a lane not converged in 100 iterations ends at its last iterate, not evaluated)
    for j in range(m):
        if X[act_ + j] != 0.0:
            o, inf = _exact_result(A[x_ + j], A[live_ + j] == 2.0, A[ql_ + j], A[tl_ + j], A[qr_ + j], A[tr_ + j],
                                   A[uz_ + j], A[h_ + j], A[st_ + j], A[ct_ + j], X[tau0 + j], X[tau1 + j],
                                   X[tau2 + j], p, input_map, qmax,
                                   100 if A[live_ + j] == 1.0 else int(A[it_ + j]))
            X[r_out * L + j], X[(r_out + 1) * L + j], X[(r_out + 2) * L + j], X[(r_out + 3) * L + j] = o
            X[r_info * L + j], X[(r_info + 1) * L + j], X[(r_info + 2) * L + j] = inf


@_jit
def allocate_exact_into(tau, theta, p, input_map, warm, use_warm, qmax, out, info):
    """:func:`allocate_exact` on arrays: tau (>= 3), warm (4), out (4), info (``N_INFO``)."""
    o, inf = allocate_exact(tau[0], tau[1], tau[2], theta, p, input_map, warm[0], warm[2], use_warm, qmax)
    out[0], out[1], out[2], out[3] = o
    info[0], info[1], info[2] = inf


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
def allocate_paper(t0, t1, t2, theta, p, w2, w3, use_warm):
    """The paper's allocation (Sec. 3.1): cos(q/2) for sin(q)/q, arctan/sqrt closed form, and the
    fixed point in (q_l^d, q_r^d) solved by Newton from the paper's initial guess (20, 10, 0.4, -0.2)
    or from the warm start (w2, w3) = (q_l^d, q_r^d). Returns ((T_l, T_r, q_l^d, q_r^d), (residual,
    iterations, feasible)), residual = max |f(x)| of the paper's own eq. (solve_num)."""
    ll, lr = p[6], p[7]
    ct, st = math.cos(theta), math.sin(theta)
    ux = ct * t0 + st * t1
    uz = -st * t0 + ct * t1
    tt = t2
    if use_warm and math.isfinite(w2 + w3):  # a NaN row means: cold start
        ql, qr = w2, w3
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
    # residual of the paper's four equations at x = (T_l, T_r, q_l, q_r)
    residual = max(abs(ql - pl), abs(qr - pr))
    return (Tl, Tr, ql, qr), (residual, float(it), 1.0 if math.isfinite(ql + qr + Tl + Tr) else 0.0)


@_jit
def allocate_paper_into(tau, theta, p, warm, use_warm, out, info):
    """:func:`allocate_paper` on arrays: tau (>= 3), warm (4), out (4), info (``N_INFO``)."""
    o, inf = allocate_paper(tau[0], tau[1], tau[2], theta, p, warm[2], warm[3], use_warm)
    out[0], out[1], out[2], out[3] = o
    info[0], info[1], info[2] = inf


# ------------------------------------------------------------------------- fused controller step
# One control step of :class:`~softpvtol_gym.control.PassivityController` (actuated loops) for a block
# of up to CTRL_LANES batch rows, composed of the kernels above: body rows of the passivity law ->
# allocation (repeated ``algebraic_iterations`` times) -> arm references -> arm rows -> actuators.
# The controller's memory per row lives in a float vector (``ST_*``); the constants in ``cc``
# (``CC_*``). Every row is computed alone (the rows of a block only share the loops), so the result
# of a row does not depend on the block it is in.

#: controller memory per row: warm start (T_l, T_r, q_l^d, q_r^d), the last four allocated arm
#: curvatures (oldest first, (q_l^d, q_r^d) each) and a flag "no history" (fresh, 1.0)
ST_WARM, ST_HIST, ST_FRESH, ST_LEN = 0, 4, 12, 13
#: constants: allocation code, input-map code, algebraic iterations, arm feedforward flag, dt, the
#: feedforward limits (rad/s, rad/s^2), curvature limit, then params (10), Lambda (5), K (5)
CC_METHOD, CC_IMAP, CC_ITERS, CC_FF, CC_DT, CC_VMAX, CC_AMAX, CC_QMAX = range(8)
CC_P, CC_LAM, CC_KG, CC_LEN = 8, 18, 23, 28
#: row error codes: the allocation got a non-finite body force; an arm curvature is beyond 2 pi
#: (``input_map="exact"``: the thrust-work compensation goes through the checked model API)
ERR_NONE, ERR_TAU, ERR_CURVATURE = 0, 1, 2
MAX_CURVATURE = 2.0 * math.pi



@_jit
def _clip(x, lo, hi):
    """np.clip for one value (NaN stays NaN)."""
    if x < lo:
        return lo
    if x > hi:
        return hi
    return x


@_jit
def _arm_derivatives(h0, h1, h2, h3, dt, vmax, amax):
    """Bounded second-order backward differences of an allocated curvature history (h3 newest)."""
    vel = _clip((3.0 * h3 - 4.0 * h2 + h1) / (2.0 * dt), -vmax, vmax)
    acc = _clip((2.0 * h3 - 5.0 * h2 + 4.0 * h1 - h0) / (dt * dt), -amax, amax)
    return vel, acc


#: lanes of a controller block: B[row * CTRL_LANES + lane] holds CB_LEN values per batch row
#: (structure of arrays, flat with constant row offsets: LLVM then vectorises the branch-free lane loops)
CTRL_LANES = 16


@MK._inline
def lane_index(row, lane):
    """Index of (row, lane) in a flat lane block."""
    return row * CTRL_LANES + lane

#: inputs: q, qdot, body reference (arm entries ignored), its velocity and acceleration, tau residual
CB_Q, CB_QD, CB_QR, CB_QDR, CB_QDDR, CB_RES = 0, 5, 10, 15, 20, 25
#: the row's memory before (``ST_*``) and after the step
CB_ST = 30
CB_STN = CB_ST + ST_LEN
#: outputs: error code (ERR_*), tau (5), actuators (4), arm references (2), allocation info (N_INFO)
CB_ERR = CB_STN + ST_LEN
CB_TAU = CB_ERR + 1
CB_ACT = CB_TAU + 5
CB_ARM = CB_ACT + 4
CB_INFO = CB_ARM + 2
#: work: D, C, g entries (17), arm references with their derivatives (6), allocation (4), active flag
CB_ENTS = CB_INFO + N_INFO
CB_REF = CB_ENTS + 17
CB_ALLOC = CB_REF + 6
CB_ACTIVE = CB_ALLOC + 4
CB_LEN = CB_ACTIVE + 1


@_jit
def controller_work():
    """(B, A): the work arrays of :func:`controller_lanes` (one pair per thread)."""
    return np.zeros(CB_LEN * CTRL_LANES), np.zeros(N_AW * CTRL_LANES)


@MK._inline
def lane3(B, c, j):
    """Rows c .. c + 2 of lane j as a tuple (lane4 ... lane8 likewise)."""
    return B[lane_index(c, j)], B[lane_index(c + 1, j)], B[lane_index(c + 2, j)]


@MK._inline
def lane4(B, c, j):
    return lane3(B, c, j) + (B[lane_index(c + 3, j)],)


@MK._inline
def lane5(B, c, j):
    return lane4(B, c, j) + (B[lane_index(c + 4, j)],)


@MK._inline
def lane6(B, c, j):
    return lane3(B, c, j) + lane3(B, c + 3, j)


@MK._inline
def lane8(B, c, j):
    return lane4(B, c, j) + lane4(B, c + 4, j)


@MK._inline
def put_lane3(B, c, j, t):
    """Rows c .. c + 2 of lane j from a tuple (put_lane4, put_lane5 likewise)."""
    B[lane_index(c, j)], B[lane_index(c + 1, j)], B[lane_index(c + 2, j)] = t[0], t[1], t[2]


@MK._inline
def put_lane4(B, c, j, t):
    put_lane3(B, c, j, t)
    B[lane_index(c + 3, j)] = t[3]


@MK._inline
def put_lane5(B, c, j, t):
    put_lane4(B, c, j, t)
    B[lane_index(c + 4, j)] = t[4]


@MK._inline
def put_lane_inputs(B, j, q, qd, qr, qdr, qddr, res, S, n):
    """Inputs of lane j (5-tuples) and its memory S[n] into the block."""
    put_lane5(B, CB_Q, j, q)
    put_lane5(B, CB_QD, j, qd)
    put_lane5(B, CB_QR, j, qr)
    put_lane5(B, CB_QDR, j, qdr)
    put_lane5(B, CB_QDDR, j, qddr)
    put_lane5(B, CB_RES, j, res)
    # written out: a loop here would keep the arrays' reference counting in the row loop
    put_lane5(B, CB_ST, j, (S[n, 0], S[n, 1], S[n, 2], S[n, 3], S[n, 4]))
    put_lane4(B, CB_ST + 5, j, (S[n, 5], S[n, 6], S[n, 7], S[n, 8]))
    put_lane4(B, CB_ST + 9, j, (S[n, 9], S[n, 10], S[n, 11], S[n, 12]))


@MK._inline
def put_lane_memory(B, j, S_new, n):
    """The memory of lane j after the step into S_new[n]."""
    S_new[n, 0], S_new[n, 1], S_new[n, 2], S_new[n, 3], S_new[n, 4] = lane5(B, CB_STN, j)
    S_new[n, 5], S_new[n, 6], S_new[n, 7], S_new[n, 8] = lane4(B, CB_STN + 5, j)
    S_new[n, 9], S_new[n, 10], S_new[n, 11], S_new[n, 12] = lane4(B, CB_STN + 9, j)


@MK._inline
def _lane_inputs(B, j):
    """(D, C, g entries, q, qdot, body reference rows (3 each of qr, qdr, qddr), arm references with
    their derivatives (6), residual) of lane j. (Helpers that take the block array stay branch-free:
    a branch would keep numba's reference counting of the array in the row loops.)"""
    ents = (lane8(B, CB_ENTS, j), lane6(B, CB_ENTS + 8, j), lane3(B, CB_ENTS + 14, j))
    body_ref = lane3(B, CB_QR, j) + lane3(B, CB_QDR, j) + lane3(B, CB_QDDR, j)
    return ents, lane5(B, CB_Q, j), lane5(B, CB_QD, j), body_ref, lane6(B, CB_REF, j), lane5(B, CB_RES, j)


@MK._inline
def _lane_tau(ents, q, qd, br, refs, res, lam, kg, has_res):
    """tau of the passivity law (plus the residual) for the inputs of :func:`_lane_inputs`."""
    arm_l, arm_r, vl, vr, al, ar = refs
    tau = passivity_rows(ents, q, qd, (br[0], br[1], br[2], arm_l, arm_r), (br[3], br[4], br[5], vl, vr),
                         (br[6], br[7], br[8], al, ar), lam, kg)
    if has_res:
        tau = (tau[0] + res[0], tau[1] + res[1], tau[2] + res[2], tau[3] + res[3], tau[4] + res[4])
    return tau


@_jit
def controller_lanes(m, B, A, has_res, commit, cfg, p, lam, kg):
    """One step of the actuated passivity controller for the rows of a block: lanes 0 .. m - 1 of
    B (``CB_*`` rows, inputs filled, see :func:`put_lane_inputs`); A: the allocation's work.

    cfg: (method, input map, algebraic iterations, arm feedforward, dt, vmax, amax, curvature limit)
    (see ``CC_*``); p, lam, kg: params and gains (tuples); the tau residual is added when ``has_res``;
    the memory after the step (into CB_STN) is the one before unless ``commit``. Outputs per lane:
    the error code (CB_ERR: ERR_NONE, or the row's outputs are zeros and its memory unchanged), tau (5:
    the commanded generalized force, arm rows: the arm torques asked for), actuators (T_l, T_r,
    tau_l, tau_r), arm references (2) and allocation info (N_INFO).
    """
    method, imap, iters, ff, dt, vmax, amax, qmax = cfg
    for j in range(CTRL_LANES):  # D, C, g of every lane (unused ones too): polynomials only, SIMD
        d, cor, g = model_entries(lane5(B, CB_Q, j), lane5(B, CB_QD, j), p)
        put_lane4(B, CB_ENTS, j, d[:4])
        put_lane4(B, CB_ENTS + 4, j, d[4:])
        put_lane3(B, CB_ENTS + 8, j, cor[:3])
        put_lane3(B, CB_ENTS + 11, j, cor[3:])
        put_lane3(B, CB_ENTS + 14, j, g)
    for j in range(m):
        # arm references of the body rows: the last allocated curvatures with their feedforward
        # derivatives, or (no history yet / just reset) the measured curvatures at rest
        vl = vr = al = ar = 0.0
        if B[lane_index(CB_ST + ST_FRESH, j)] > 0.5:
            arm_l, arm_r = B[lane_index(CB_Q + 3, j)], B[lane_index(CB_Q + 4, j)]
        else:
            h = CB_ST + ST_HIST
            arm_l, arm_r = B[lane_index(h + 6, j)], B[lane_index(h + 7, j)]
            if ff:
                hist = lane8(B, h, j)
                vl, al = _arm_derivatives(hist[0], hist[2], hist[4], hist[6], dt, vmax, amax)
                vr, ar = _arm_derivatives(hist[1], hist[3], hist[5], hist[7], dt, vmax, amax)
        put_lane3(B, CB_REF, j, (arm_l, arm_r, vl))
        put_lane3(B, CB_REF + 3, j, (vr, al, ar))
        for k in range(4):  # warm start (NaN: cold)
            B[lane_index(CB_ALLOC + k, j)] = B[lane_index(CB_ST + ST_WARM + k, j)]
        put_lane3(B, CB_INFO, j, (0.0, 0.0, 0.0))
        B[lane_index(CB_ERR, j)] = ERR_NONE
    for _ in range(iters):
        for j in range(m):
            active = B[lane_index(CB_ERR, j)] == ERR_NONE
            if active:
                ents, q, qd, br, refs, res = _lane_inputs(B, j)
                tau = _lane_tau(ents, q, qd, br, refs, res, lam, kg, has_res)
                put_lane3(B, CB_TAU, j, tau)
                if not (math.isfinite(tau[0]) and math.isfinite(tau[1]) and math.isfinite(tau[2])):
                    B[lane_index(CB_ERR, j)] = ERR_TAU
                    active = False
            B[lane_index(CB_ACTIVE, j)] = 1.0 if active else 0.0
        if method == ALLOC_PAPER:
            for j in range(m):
                if B[lane_index(CB_ACTIVE, j)] != 0.0:
                    t0, t1, t2 = lane3(B, CB_TAU, j)
                    warm = lane4(B, CB_ALLOC, j)
                    alloc, info = allocate_paper(t0, t1, t2, B[lane_index(CB_Q + 2, j)], p, warm[2], warm[3], True)
                    put_lane4(B, CB_ALLOC, j, alloc)
                    put_lane3(B, CB_INFO, j, info)
        else:
            allocate_exact_lanes(m, B, CB_TAU, CB_Q + 2, CB_ALLOC, CB_ACTIVE, CB_ALLOC, CB_INFO, A, True, p, imap,
                                 qmax)
        for j in range(m):
            if B[lane_index(CB_ACTIVE, j)] != 0.0:
                B[lane_index(CB_REF, j)] = B[lane_index(CB_ALLOC + 2, j)]
                B[lane_index(CB_REF + 1, j)] = B[lane_index(CB_ALLOC + 3, j)]
    for j in range(m):
        ents, q, qd, br, refs, res = _lane_inputs(B, j)
        err = B[lane_index(CB_ERR, j)]
        if err == ERR_NONE and imap == MK.INPUT_MAP_EXACT and not (abs(q[3]) <= MAX_CURVATURE
                                                                   and abs(q[4]) <= MAX_CURVATURE):
            err = ERR_CURVATURE
        for k in range(ST_LEN):
            B[lane_index(CB_STN + k, j)] = B[lane_index(CB_ST + k, j)]
        if err != ERR_NONE:  # zero outputs, memory unchanged
            B[lane_index(CB_ERR, j)] = err
            for k in range(CB_INFO + N_INFO - CB_TAU):
                B[lane_index(CB_TAU + k, j)] = 0.0
            continue
        arm_l, arm_r, vl, vr, al, ar = refs
        Tl, Tr = B[lane_index(CB_ALLOC, j)], B[lane_index(CB_ALLOC + 1, j)]
        if commit:
            # push the allocated curvatures; a fresh row gets a flat history (no jump for the differences)
            h = CB_ST + ST_HIST
            if B[lane_index(CB_ST + ST_FRESH, j)] > 0.5:
                hist = (arm_l, arm_r, arm_l, arm_r, arm_l, arm_r, arm_l, arm_r)
            else:
                hist = lane6(B, h + 2, j) + (arm_l, arm_r)
            for k in range(4):
                B[lane_index(CB_STN + ST_WARM + k, j)] = B[lane_index(CB_ALLOC + k, j)]
            put_lane4(B, CB_STN + ST_HIST, j, hist[:4])
            put_lane4(B, CB_STN + ST_HIST + 4, j, hist[4:])
            B[lane_index(CB_STN + ST_FRESH, j)] = 0.0
            vl = vr = al = ar = 0.0
            if ff:
                vl, al = _arm_derivatives(hist[0], hist[2], hist[4], hist[6], dt, vmax, amax)
                vr, ar = _arm_derivatives(hist[1], hist[3], hist[5], hist[7], dt, vmax, amax)
        # arm rows with the new arm references
        t_arm = _lane_tau(ents, q, qd, br, (arm_l, arm_r, vl, vr, al, ar), res, lam, kg, has_res)
        tau_l, tau_r = t_arm[3], t_arm[4]
        a2, a3 = tau_l, tau_r
        if imap == MK.INPUT_MAP_EXACT:  # cancel the thrusts' own work on the curvatures
            gf = MK.generalized_forces(q, (Tl, Tr, 0.0, 0.0), p, MK.INPUT_MAP_EXACT)
            a2 -= gf[3]
            a3 -= gf[4]
        B[lane_index(CB_TAU + 3, j)], B[lane_index(CB_TAU + 4, j)] = tau_l, tau_r
        put_lane4(B, CB_ACT, j, (Tl, Tr, a2, a3))
        B[lane_index(CB_ARM, j)], B[lane_index(CB_ARM + 1, j)] = arm_l, arm_r


@_jit
def config_tuples(cc):
    """(cfg, p, lam, kg) tuples of :func:`controller_lanes` from the constant vector ``cc``."""
    cfg = (int(cc[CC_METHOD]), int(cc[CC_IMAP]), int(cc[CC_ITERS]), cc[CC_FF] > 0.0, cc[CC_DT], cc[CC_VMAX],
           cc[CC_AMAX], cc[CC_QMAX])
    o = CC_P
    p = (cc[o], cc[o + 1], cc[o + 2], cc[o + 3], cc[o + 4], cc[o + 5], cc[o + 6], cc[o + 7], cc[o + 8], cc[o + 9])
    lam = (cc[CC_LAM], cc[CC_LAM + 1], cc[CC_LAM + 2], cc[CC_LAM + 3], cc[CC_LAM + 4])
    kg = (cc[CC_KG], cc[CC_KG + 1], cc[CC_KG + 2], cc[CC_KG + 3], cc[CC_KG + 4])
    return cfg, p, lam, kg


@MK._inline
def row5(A, n, c):
    """(A[n, c], ..., A[n, c + 4])."""
    return (A[n, c], A[n, c + 1], A[n, c + 2], A[n, c + 3], A[n, c + 4])


@MK._inline
def row5_1d(a):
    """(a[0], ..., a[4])."""
    return (a[0], a[1], a[2], a[3], a[4])


#: columns of the output of :func:`batch_controller`: tau (5), actuators (4), arm references (2),
#: allocation info (residual, iterations, feasible), in the order of the block's output rows
OUT_TAU, OUT_ACT, OUT_ARM, OUT_INFO, OUT_LEN = 0, 5, 9, 11, 14


@njit(cache=True, nogil=True)
def batch_controller(q, qd, qr, qdr, qddr, res, has_res, commit, cc, S, S_new, out, err):
    """:func:`controller_lanes` over a batch (res: one row, broadcast, or one per row): outputs into
    out (N, ``OUT_LEN``), error codes into err (N), the memory after the step into S_new (commit it
    with :func:`commit_rows` once every row is done)."""
    rs = np.int64(res.shape[0] > 1)
    cfg, p, lam, kg = config_tuples(cc)
    B, A = controller_work()
    N = q.shape[0]
    for n0 in range(0, N, CTRL_LANES):
        m = min(CTRL_LANES, N - n0)
        for j in range(m):
            n = n0 + j
            put_lane_inputs(B, j, row5(q, n, 0), row5(qd, n, 0), row5(qr, n, 0), row5(qdr, n, 0), row5(qddr, n, 0),
                            row5(res, n * rs, 0), S, n)
        controller_lanes(m, B, A, has_res, commit, cfg, p, lam, kg)
        for j in range(m):
            n = n0 + j
            err[n] = int(B[lane_index(CB_ERR, j)])
            for k in range(OUT_LEN):
                out[n, k] = B[lane_index(CB_TAU + k, j)]
            put_lane_memory(B, j, S_new, n)


@njit(cache=True, nogil=True)
def batch_controller_commit(q, qd, qr, qdr, qddr, res, has_res, commit, cc, S, out):
    """:func:`batch_controller` and the commit in one call (batches run in one thread); returns the
    first failed row's error code, or ERR_NONE: every row succeeded (and the memory advanced if
    ``commit``). A failed call changes no memory."""
    S_new = S.copy()
    err = np.zeros(q.shape[0], dtype=np.int64)
    batch_controller(q, qd, qr, qdr, qddr, res, has_res, commit, cc, S, S_new, out, err)
    for n in range(err.shape[0]):
        if err[n] != ERR_NONE:
            return err[n]
    if commit:
        _commit_rows(S, S_new, err)
    return ERR_NONE


@njit(cache=True, nogil=True)
def single_controller_commit(q, qd, qr, qdr, qddr, res, has_res, commit, cc, S, out):
    """:func:`batch_controller_commit` for one state: 1-D inputs (5), out (``OUT_LEN``), S (1, ST_LEN)."""
    cfg, p, lam, kg = config_tuples(cc)
    B, A = controller_work()
    put_lane_inputs(B, 0, row5_1d(q), row5_1d(qd), row5_1d(qr), row5_1d(qdr), row5_1d(qddr), row5_1d(res), S, 0)
    controller_lanes(1, B, A, has_res, commit, cfg, p, lam, kg)
    e = int(B[lane_index(CB_ERR, 0)])
    if e != ERR_NONE:
        return e
    for k in range(OUT_LEN):
        out[k] = B[lane_index(CB_TAU + k, 0)]
    if commit:
        put_lane_memory(B, 0, S, 0)
    return ERR_NONE


@_jit
def _commit_rows(S, S_new, err):
    """Copy the new memory of all rows, only if no row failed (a failed call changes nothing)."""
    for n in range(err.shape[0]):
        if err[n] != ERR_NONE:
            return False
    for n in range(S.shape[0]):
        for k in range(ST_LEN):
            S[n, k] = S_new[n, k]
    return True


@njit(cache=True, nogil=True)
def commit_rows(S, S_new, err):
    """:func:`_commit_rows` (compiled entry point): whether the memory advanced."""
    return _commit_rows(S, S_new, err)


# ------------------------------------------------------------------------------------- batched
# One thread each, GIL released: the public API splits large batches over threads.
_batch = njit(cache=True, nogil=True)


@_batch
def batch_passivity(q, qd, qr, qdr, qddr, P, lam, kg, out):
    ps = np.int64(P.shape[0] > 1)
    for n in range(q.shape[0]):
        passivity_into(q[n], qd[n], qr[n], qdr[n], qddr[n], P[n * ps], lam, kg, out[n])


@_batch
def batch_storage(q, qd, qr, qdr, P, lam, kg, out):
    ps = np.int64(P.shape[0] > 1)
    for n in range(q.shape[0]):
        out[n] = storage_into(q[n], qd[n], qr[n], qdr[n], P[n * ps], lam, kg)


@_batch
def batch_allocate(tau, theta, P, method, input_map, warm, use_warm, qmax, out, info):
    ps = np.int64(P.shape[0] > 1)
    ws = np.int64(warm.shape[0] > 1)
    for n in range(tau.shape[0]):
        if method == ALLOC_PAPER:
            allocate_paper_into(tau[n], theta[n], P[n * ps], warm[n * ws], use_warm, out[n], info[n])
        else:
            allocate_exact_into(
                tau[n], theta[n], P[n * ps], input_map, warm[n * ws], use_warm, qmax, out[n], info[n]
            )
