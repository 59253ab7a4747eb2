"""Compiled control allocations: body force (tau_x, tau_z, tau_theta) -> thrusts and desired curvatures
(the exact allocation, scalar and in lane blocks, and the paper's)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .. import model as MK
from .._columns import Columns
from ..params import P_EPS, P_LL, P_LR

_jit = njit(cache=True, fastmath=False, nogil=True, error_model="numpy")

ALLOC_PAPER = 0
ALLOC_EXACT = 1

# info columns returned by the allocation kernels
INFO_RESIDUAL = 0
INFO_ITERATIONS = 1
INFO_FEASIBLE = 2
N_INFO = 3
#: lanes of a controller block (:mod:`._block_kernels`): X[row * CTRL_LANES + lane]
CTRL_LANES = 16


# ------------------------------------------------------------------------------ exact allocation
@MK.inline
def _lever_poly(v, h, q, T, length, eps, input_map):
    """(G, dG/dv) of :func:`_lever` given q = atan2(h, v) and T = sqrt(h^2 + v^2): the polynomial part
    (vectorizes over a lane block)."""
    s0 = MK.sinc(q)
    # d sinc / dq = -q A(q); dq/dv = -h / T^2
    dsinc = -q * MK.horner(MK.A_COEFFS, q * q)
    if input_map == MK.INPUT_MAP_PAPER:
        G = length * v * s0
        dG = length * s0 + (length * v * dsinc * (-h / (T * T)) if T > 0.0 else 0.0)
    else:
        G = eps * v + length * T * s0
        dG = eps + (length * (v * s0 + q * h * MK.horner(MK.A_COEFFS, q * q)) / T if T > 0.0 else length)
    return G, dG


@_jit
def _lever(v, h, length, eps, input_map):
    """Torque lever term G(v) of one rotor whose thrust has body components (h, v), dG/dv, and the
    rotor's curvature q = atan2(h, v) and thrust T = sqrt(h^2 + v^2) >= 0: (G, dG, q, T).

    paper map:  G = l v sin(q)/q;  exact map: G = eps v + l T sin(q)/q.
    """
    q = math.atan2(h, v)
    T = math.sqrt(h * h + v * v)
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


@MK.inline
def _exact_setup(t0, t1, t2, theta, p, input_map, w0, w2, use_warm):
    """Start of :func:`allocate_exact`: the body force in body axes, the bracket and the first point.
    Returns ((x, lo, hi, lo_raw, hi_raw), (uz, h, tt, scale, st, ct))."""
    return _exact_setup_sc(t0, t1, t2, math.sin(theta), math.cos(theta), p, input_map, w0, w2, use_warm)


@MK.inline
def _exact_setup_sc(t0, t1, t2, st, ct, p, input_map, w0, w2, use_warm):
    """:func:`_exact_setup` given st, ct = sin(theta), cos(theta)."""
    ll, lr, eps = p[P_LL], p[P_LR], p[P_EPS]
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


@MK.inline
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
    xn, lo, hi, lo_raw, hi_raw = _bracket_point(xn, lo, hi, lo_raw, hi_raw, uz, h, tt, p[P_LL], p[P_LR], p[P_EPS],
                                                input_map)
    if abs(xn - x) <= 1e-16 * (1.0 + abs(x)):
        return 2, xn, lo, hi, lo_raw, hi_raw
    return 0, xn, lo, hi, lo_raw, hi_raw


@MK.inline
def _exact_result(x, evaluated, ql, Tl, qr, Tr, uz, h, st, ct, t0, t1, t2, p, input_map, qmax, it):
    """End of :func:`allocate_exact` at the solution x (the split v_l = x): curvatures, thrusts, the
    curvature clip and the residual. (ql, Tl, qr, Tr): those of the levers at x if ``evaluated``."""
    o, feasible = _exact_solution(x, evaluated, ql, Tl, qr, Tr, uz, h, qmax)
    return o, (allocation_residual(st, ct, o[2], o[3], o[0], o[1], t0, t1, t2, p, input_map), float(it), feasible)


@MK.inline
def _exact_solution(x, evaluated, ql, Tl, qr, Tr, uz, h, qmax):
    """:func:`_exact_result` without the residual: ((T_l, T_r, q_l^d, q_r^d), feasible)."""
    if not evaluated:
        vl = x
        vr = uz - x
        ql = math.atan2(h, vl)
        qr = math.atan2(-h, vr)
        Tl = math.sqrt(h * h + vl * vl)
        Tr = math.sqrt(h * h + vr * vr)
    feasible = 1.0
    if abs(ql) > qmax or abs(qr) > qmax:
        feasible = 0.0
        ql = min(max(ql, -qmax), qmax)
        qr = min(max(qr, -qmax), qmax)
    return (Tl, Tr, ql, qr), feasible


@MK.inline
def allocation_residual(st, ct, ql, qr, Tl, Tr, t0, t1, t2, p, input_map):
    """The realised body force of an allocation (T_l, T_r, q_l^d, q_r^d) through the chosen input map, minus
    the requested one (t0, t1, t2): the largest absolute difference (st, ct = sin(theta), cos(theta))."""
    tr = MK.thrust_body_forces(st, ct, ql, qr, Tl, Tr, p, input_map)
    return max(abs(tr[0] - t0), abs(tr[1] - t1), abs(tr[2] - t2))


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
    ll, lr, eps = p[P_LL], p[P_LR], p[P_EPS]
    (x, lo, hi, lo_raw, hi_raw), (uz, h, tt, scale, st, ct) = _exact_setup(t0, t1, t2, theta, p, input_map, w0,
                                                                           w2, use_warm)
    ql = qr = Tl = Tr = 0.0
    status = 0
    it = 0
    for it in range(1, 101):  # noqa: B007 (the count of the last iteration is returned)
        Gl, dGl, ql, Tl = _lever(x, h, ll, eps, input_map)
        Gr, dGr, qr, Tr = _lever(uz - x, -h, lr, eps, input_map)
        status, x, lo, hi, lo_raw, hi_raw = _exact_newton(x, lo, hi, lo_raw, hi_raw, Gl, dGl, Gr, dGr, uz, h, tt,
                                                          scale, p, input_map)
        if status != 0:
            break
    return _exact_result(x, status == 1, ql, Tl, qr, Tr, uz, h, st, ct, t0, t1, t2, p, input_map, qmax, it)


#: rows of the work array of :func:`allocate_exact_lanes` (one column per lane)
WORK = Columns("allocation_work", [(f, 1) for f in (
    "x", "lo", "hi", "lo_raw", "hi_raw", "uz", "h", "tt", "scale", "st", "ct", "ql", "tl", "qr", "tr", "gl", "dgl",
    "gr", "dgr", "live", "it")])
(AW_X, AW_LO, AW_HI, AW_LO_RAW, AW_HI_RAW, AW_UZ, AW_H, AW_TT, AW_SCALE, AW_ST, AW_CT, AW_QL, AW_TL, AW_QR, AW_TR,
 AW_GL, AW_DGL, AW_GR, AW_DGR, AW_LIVE, AW_IT) = WORK.at
N_AW = WORK.size


@_jit
def lever_poly_lanes(A, ll, lr, eps, input_map):
    """The lever polynomials of :func:`allocate_exact_lanes` for every lane of its work block A
    (finished and unused lanes too): one SIMD loop."""
    L = CTRL_LANES
    x_, uz_, h_ = AW_X * L, AW_UZ * L, AW_H * L
    ql_, tl_, qr_, tr_ = AW_QL * L, AW_TL * L, AW_QR * L, AW_TR * L
    gl_, dgl_, gr_, dgr_ = AW_GL * L, AW_DGL * L, AW_GR * L, AW_DGR * L
    for j in range(L):
        x, h = A[x_ + j], A[h_ + j]
        A[gl_ + j], A[dgl_ + j] = _lever_poly(x, h, A[ql_ + j], A[tl_ + j], ll, eps, input_map)
        A[gr_ + j], A[dgr_ + j] = _lever_poly(A[uz_ + j] - x, -h, A[qr_ + j], A[tr_ + j], lr, eps, input_map)


@_jit
def allocate_exact_lanes(m, X, r_tau, r_theta, r_warm, r_active, r_out, r_info, A, use_warm, p, input_map, qmax,
                         trig_ready=False, with_residual=True):
    """:func:`allocate_exact` for the m problems of a lane block at once, every lane's arithmetic
    that of allocate_exact, bit for bit.

    X is a flat lane block (row r, lane j at ``X[r * CTRL_LANES + j]``) holding the inputs and
    receiving the results in its rows: r_tau (3): body rows of the force; r_theta: theta; r_warm (4):
    (T_l, T_r, q_l^d, q_r^d) of the warm start (may be r_out itself); r_active: lanes to solve
    (nonzero; the others are left alone); r_out (4), r_info (N_INFO): the results. A (N_AW lane rows):
    work. The Newton iterations of the lanes are interleaved: one lane's iteration is a chain of
    dependent libm calls and polynomials, so lanes side by side keep the CPU busy, and the
    polynomials of all lanes run as one SIMD loop.

    For the passes of the controller's algebraic loop (the same theta, another force each): ``trig_ready``
    says that A's rows ``AW_ST``, ``AW_CT`` already hold sin and cos of every active lane's theta (an earlier
    call on these lanes wrote them); ``with_residual=False`` leaves the residual (info row 0) NaN, to be filled
    by :func:`allocation_residual` for the last pass only. The other results are the same either way.
    """
    L = CTRL_LANES
    ll, lr, eps = p[P_LL], p[P_LR], p[P_EPS]
    tau0, tau1, tau2, th_, act_ = r_tau * L, (r_tau + 1) * L, (r_tau + 2) * L, r_theta * L, r_active * L
    x_, lo_, hi_, lor_, hir_, uz_, h_, tt_ = AW_X * L, AW_LO * L, AW_HI * L, AW_LO_RAW * L, AW_HI_RAW * L, AW_UZ * L, \
        AW_H * L, AW_TT * L
    sc_, st_, ct_, ql_, tl_, qr_, tr_ = AW_SCALE * L, AW_ST * L, AW_CT * L, AW_QL * L, AW_TL * L, AW_QR * L, AW_TR * L
    gl_, dgl_, gr_, dgr_, live_, it_ = AW_GL * L, AW_DGL * L, AW_GR * L, AW_DGR * L, AW_LIVE * L, AW_IT * L
    live = 0
    for j in range(m):
        if X[act_ + j] != 0.0:
            if trig_ready:
                st, ct = A[st_ + j], A[ct_ + j]
            else:
                th = X[th_ + j]
                st, ct = math.sin(th), math.cos(th)
            (x, lo, hi, lo_raw, hi_raw), (uz, h, tt, scale, st, ct) = _exact_setup_sc(
                X[tau0 + j], X[tau1 + j], X[tau2 + j], st, ct, p, input_map, X[r_warm * L + j],
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
        for j in range(m):  # libm (atan2, sqrt): independent lanes, overlapped by the CPU
            if A[live_ + j] == 1.0:
                x, h = A[x_ + j], A[h_ + j]
                vr = A[uz_ + j] - x
                A[ql_ + j] = math.atan2(h, x)
                A[tl_ + j] = math.sqrt(h * h + x * x)
                A[qr_ + j] = math.atan2(-h, vr)
                A[tr_ + j] = math.sqrt(h * h + vr * vr)
        lever_poly_lanes(A, ll, lr, eps, input_map)
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
            o, feasible = _exact_solution(A[x_ + j], A[live_ + j] == 2.0, A[ql_ + j], A[tl_ + j], A[qr_ + j],
                                          A[tr_ + j], A[uz_ + j], A[h_ + j], qmax)
            residual = math.nan
            if with_residual:
                residual = allocation_residual(A[st_ + j], A[ct_ + j], o[2], o[3], o[0], o[1], X[tau0 + j],
                                               X[tau1 + j], X[tau2 + j], p, input_map)
            X[r_out * L + j], X[(r_out + 1) * L + j], X[(r_out + 2) * L + j], X[(r_out + 3) * L + j] = o
            X[r_info * L + j] = residual
            X[(r_info + 1) * L + j] = 100.0 if A[live_ + j] == 1.0 else float(int(A[it_ + j]))
            X[(r_info + 2) * L + j] = feasible


@_jit
def allocate_exact_into(tau, theta, p, input_map, warm, use_warm, qmax, out, info):
    """:func:`allocate_exact` on arrays: tau (>= 3), warm (4), out (4), info (``N_INFO``)."""
    o, inf = allocate_exact(tau[0], tau[1], tau[2], theta, p, input_map, warm[0], warm[2], use_warm, qmax)
    out[0], out[1], out[2], out[3] = o
    info[0], info[1], info[2] = inf


# ------------------------------------------------------------------------------ paper allocation
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
    # the paper prints q = arctan(num / den); with T >= 0 the rotor's force components are
    # T (sin q, cos q) = (num, den) / (2 S), so the quadrant-correct angle is atan2(num, den): the two
    # agree while the rotor's vertical component is positive, and atan2 stays continuous (and right)
    # when it is not (docs/model.md, "The allocation's arctan")
    return Tl, Tr, math.atan2(ux * S, 2.0 * nl), math.atan2(-ux * S, 2.0 * nr)


@_jit
def allocate_paper(t0, t1, t2, theta, p, w2, w3, use_warm):
    """The paper's allocation (Sec. 3.1): cos(q/2) for sin(q)/q, arctan/sqrt closed form, and the
    fixed point in (q_l^d, q_r^d) solved by Newton from the paper's initial guess (20, 10, 0.4, -0.2)
    or from the warm start (w2, w3) = (q_l^d, q_r^d). Returns ((T_l, T_r, q_l^d, q_r^d), (residual,
    iterations, feasible)), residual = max |f(x)| of the paper's own eq. (solve_num)."""
    ll, lr = p[P_LL], p[P_LR]
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
    for it in range(1, 61):  # noqa: B007 (the count of the last iteration is returned)
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


# One thread each, GIL released: the public API splits large batches over threads.
_batch = njit(cache=True, nogil=True)


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
