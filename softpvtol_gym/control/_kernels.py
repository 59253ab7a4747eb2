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


@_jit
def model_terms_into(q, qd, p, D, C, g):
    """D(q), C(q, qdot), g(q) of the model kernels into D (5x5), C (5x5), g (5)."""
    MK.mass_matrix_into(q, p, D)
    MK.coriolis_matrix_into(q, qd, p, C)
    MK.gravity_vector_into(q, p, g)


@_jit
def passivity_apply(D, C, g, q, qd, qr, qdr, qddr, lam, kg, row0, out, v, a):
    """Rows row0..4 of tau = D a + C v + g - K r for given D, C, g (v, a: 5-vector scratch)."""
    for i in range(5):
        v[i] = qdr[i] - lam[i] * (q[i] - qr[i])
        a[i] = qddr[i] - lam[i] * (qd[i] - qdr[i])
    for i in range(row0, 5):
        acc = g[i] - kg[i] * (qd[i] - v[i])
        for j in range(5):
            acc += D[i, j] * a[j] + C[i, j] * v[j]
        out[i] = acc


@_jit
def passivity_into(q, qd, qr, qdr, qddr, p, lam, kg, out, work):
    """tau = D(q) a + C(q, qd) v + g(q) - K r  (Slotine–Li / Spong form, paper eq. (passControl)).

    ``work``: scratch of at least ``PASSIVITY_WORK`` floats (no allocation here).
    """
    D = work[0:25].reshape((5, 5))
    C = work[25:50].reshape((5, 5))
    g = work[50:55]
    model_terms_into(q, qd, p, D, C, g)
    passivity_apply(D, C, g, q, qd, qr, qdr, qddr, lam, kg, 0, out, work[55:60], work[60:65])


PASSIVITY_WORK = 65


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
def _widen_lo(lo, uz, h, tt, ll, lr, eps, input_map):
    """Lower end of the bracket: doubled until F(lo) > 0 (at most 60 times)."""
    for _ in range(60):
        Glo, _d = _lever(lo, h, ll, eps, input_map)
        Grl, _d = _lever(uz - lo, -h, lr, eps, input_map)
        if Grl - Glo - tt > 0.0:
            break
        lo *= 2.0
    return lo


@_jit
def _widen_hi(hi, uz, h, tt, ll, lr, eps, input_map):
    """Upper end of the bracket: doubled until F(hi) < 0 (at most 60 times)."""
    for _ in range(60):
        Ghi, _d = _lever(hi, h, ll, eps, input_map)
        Grh, _d = _lever(uz - hi, -h, lr, eps, input_map)
        if Grh - Ghi - tt < 0.0:
            break
        hi *= 2.0
    return hi


@_jit
def allocate_exact_into(tau, theta, p, input_map, warm, use_warm, qmax, out, info):
    """(T_l, T_r, q_l^d, q_r^d) realising the body force (tau_x, tau_z, tau_theta) exactly.

    The horizontal body force is split equally (the paper's minimum-norm choice); the vertical split
    v_l + v_r = v_z is the root of the scalar torque equation, found by safeguarded Newton on a
    bracket, so it converges for any finite input. Curvatures come from atan2, so thrusts are never
    negative and downward vertical components are allowed. If a curvature beyond +/- qmax would be
    needed, it is clipped and the result is flagged infeasible (the residual tells by how much).

    The bracket [lo, hi] starts at -/+ scale (1 + 1/min(l_l, l_r)) and each end is doubled until
    F changes sign there. The doubling is done lazily, the first time the end's value matters: it only
    moves an end outwards, so a test ``lo < x`` (``x < hi``) that holds before holds after, and an end
    replaced by a Newton iterate is never needed. The iterates are those of the eager bracket, bit
    for bit; a well warm-started solve skips the four bracket evaluations.
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
    lo_raw = True  # lo/hi not yet widened
    hi_raw = True
    x = 0.5 * uz
    if use_warm and math.isfinite(warm[0] + warm[2]):  # a NaN row means: cold start
        x = warm[0] * math.cos(warm[2])
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
            lo_raw = False
        else:
            hi = x
            hi_raw = False
        dF = -dGr - dGl
        if dF < 0.0:
            xn = x - F / dF
        else:
            if lo_raw:
                lo = _widen_lo(lo, uz, h, tt, ll, lr, eps, input_map)
                lo_raw = False
            if hi_raw:
                hi = _widen_hi(hi, uz, h, tt, ll, lr, eps, input_map)
                hi_raw = False
            xn = 0.5 * (lo + hi)
        if lo_raw and not (lo < xn):
            lo = _widen_lo(lo, uz, h, tt, ll, lr, eps, input_map)
            lo_raw = False
        if hi_raw and not (xn < hi):
            hi = _widen_hi(hi, uz, h, tt, ll, lr, eps, input_map)
            hi_raw = False
        if not (lo < xn < hi):
            if lo_raw:
                lo = _widen_lo(lo, uz, h, tt, ll, lr, eps, input_map)
                lo_raw = False
            if hi_raw:
                hi = _widen_hi(hi, uz, h, tt, ll, lr, eps, input_map)
                hi_raw = False
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
    tr = MK.generalized_forces((0.0, 0.0, theta, ql, qr), (Tl, Tr, 0.0, 0.0), p, input_map)
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


# ------------------------------------------------------------------------- fused controller step
# One control step of :class:`~softpvtol_gym.control.PassivityController` (actuated loops) for one
# batch row, composed of the kernels above: body rows of the passivity law -> allocation (repeated
# ``algebraic_iterations`` times) -> arm references -> arm rows -> actuators. The controller's memory
# per row lives in a float vector (``ST_*``); the constants in ``cc`` (``CC_*``).

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

# scratch layout of controller_row
_W_D, _W_C, _W_G, _W_V, _W_A = 0, 25, 50, 55, 60
_W_QR, _W_QDR, _W_QDDR, _W_TAU, _W_ALLOC, _W_WARM, _W_INFO = 65, 70, 75, 80, 85, 89, 93
CONTROLLER_WORK = 96


@_jit
def _clip(x, lo, hi):
    """np.clip for one value (NaN stays NaN)."""
    if x < lo:
        return lo
    if x > hi:
        return hi
    return x


@_jit
def _arm_derivatives(st, dt, vmax, amax, arm):
    """Bounded second-order backward differences of the allocated curvature history of one arm."""
    h0 = st[ST_HIST + arm]
    h1 = st[ST_HIST + 2 + arm]
    h2 = st[ST_HIST + 4 + arm]
    h3 = st[ST_HIST + 6 + arm]
    vel = _clip((3.0 * h3 - 4.0 * h2 + h1) / (2.0 * dt), -vmax, vmax)
    acc = _clip((2.0 * h3 - 5.0 * h2 + 4.0 * h1 - h0) / (dt * dt), -amax, amax)
    return vel, acc


@_jit
def controller_row(q, qd, qr, qdr, qddr, res, has_res, commit, cc, st, st_new, tau_out, act_out, arm_out,
                   info, work):
    """One step of the actuated passivity controller for one row; returns an ``ERR_*`` code.

    q, qd: state (5); qr, qdr, qddr: body reference (arm entries ignored); res: tau residual (5),
    added when ``has_res``; st: the row's memory (read only), st_new: the memory after the step
    (written when ``commit``; may be st itself). Outputs: tau_out (5) the commanded generalized
    force (arm rows: the arm torques asked for), act_out (4) actuators (T_l, T_r, tau_l, tau_r),
    arm_out (2) arm references, info (3) allocation diagnostics.
    """
    p = cc[CC_P:CC_P + 10]
    lam = cc[CC_LAM:CC_LAM + 5]
    kg = cc[CC_KG:CC_KG + 5]
    method = int(cc[CC_METHOD])
    imap = int(cc[CC_IMAP])
    ff = cc[CC_FF] > 0.0
    dt, vmax, amax, qmax = cc[CC_DT], cc[CC_VMAX], cc[CC_AMAX], cc[CC_QMAX]
    D = work[_W_D:_W_D + 25].reshape((5, 5))
    C = work[_W_C:_W_C + 25].reshape((5, 5))
    g = work[_W_G:_W_G + 5]
    v = work[_W_V:_W_V + 5]
    a = work[_W_A:_W_A + 5]
    rq = work[_W_QR:_W_QR + 5]
    rqd = work[_W_QDR:_W_QDR + 5]
    rqdd = work[_W_QDDR:_W_QDDR + 5]
    tau = work[_W_TAU:_W_TAU + 5]
    alloc = work[_W_ALLOC:_W_ALLOC + 4]
    warm = work[_W_WARM:_W_WARM + 4]
    ainfo = work[_W_INFO:_W_INFO + 3]

    # arm references of the body rows: the last allocated curvatures with their feedforward
    # derivatives, or (no history yet / just reset) the measured curvatures at rest
    fresh = st[ST_FRESH] > 0.5
    vl = vr = al = ar = 0.0
    if fresh:
        arm_l, arm_r = q[3], q[4]
    else:
        arm_l, arm_r = st[ST_HIST + 6], st[ST_HIST + 7]
        if ff:
            vl, al = _arm_derivatives(st, dt, vmax, amax, 0)
            vr, ar = _arm_derivatives(st, dt, vmax, amax, 1)
    for i in range(3):
        rq[i] = qr[i]
        rqd[i] = qdr[i]
        rqdd[i] = qddr[i]
    for i in range(4):
        warm[i] = st[ST_WARM + i]  # NaN: cold start
    model_terms_into(q, qd, p, D, C, g)
    iters = int(cc[CC_ITERS])
    for _ in range(iters):
        rq[3], rq[4] = arm_l, arm_r
        rqd[3], rqd[4] = vl, vr
        rqdd[3], rqdd[4] = al, ar
        passivity_apply(D, C, g, q, qd, rq, rqd, rqdd, lam, kg, 0, tau, v, a)
        if has_res:
            for i in range(5):
                tau[i] = tau[i] + res[i]
        if not (math.isfinite(tau[0]) and math.isfinite(tau[1]) and math.isfinite(tau[2])):
            return ERR_TAU
        if method == ALLOC_PAPER:
            allocate_paper_into(tau, q[2], p, warm, True, alloc, ainfo)
        else:
            allocate_exact_into(tau, q[2], p, imap, warm, True, qmax, alloc, ainfo)
        for i in range(4):
            warm[i] = alloc[i]
        arm_l, arm_r = alloc[2], alloc[3]
    if imap == MK.INPUT_MAP_EXACT and not (abs(q[3]) <= MAX_CURVATURE and abs(q[4]) <= MAX_CURVATURE):
        return ERR_CURVATURE
    if commit:
        # push the allocated curvatures; a fresh row gets a flat history (no jump for the differences)
        h = st_new[ST_HIST:ST_HIST + 8]
        if fresh:
            for k in range(4):
                h[2 * k] = arm_l
                h[2 * k + 1] = arm_r
        else:
            old = (st[ST_HIST + 2], st[ST_HIST + 3], st[ST_HIST + 4], st[ST_HIST + 5], st[ST_HIST + 6],
                   st[ST_HIST + 7])
            h[0], h[1], h[2], h[3], h[4], h[5] = old
            h[6] = arm_l
            h[7] = arm_r
        for i in range(4):
            st_new[ST_WARM + i] = alloc[i]
        st_new[ST_FRESH] = 0.0
        if ff:
            vl, al = _arm_derivatives(st_new, dt, vmax, amax, 0)
            vr, ar = _arm_derivatives(st_new, dt, vmax, amax, 1)
        else:
            vl = vr = al = ar = 0.0
    # arm rows with the new arm references
    rq[3], rq[4] = arm_l, arm_r
    rqd[3], rqd[4] = vl, vr
    rqdd[3], rqdd[4] = al, ar
    passivity_apply(D, C, g, q, qd, rq, rqd, rqdd, lam, kg, 3, tau_out, v, a)
    tau_l, tau_r = tau_out[3], tau_out[4]
    if has_res:
        tau_l = tau_l + res[3]
        tau_r = tau_r + res[4]
    act_out[0] = alloc[0]
    act_out[1] = alloc[1]
    act_out[2] = tau_l
    act_out[3] = tau_r
    if imap == MK.INPUT_MAP_EXACT:  # cancel the thrusts' own work on the curvatures
        gf = MK.generalized_forces(q, (alloc[0], alloc[1], 0.0, 0.0), p, MK.INPUT_MAP_EXACT)
        act_out[2] -= gf[3]
        act_out[3] -= gf[4]
    tau_out[0], tau_out[1], tau_out[2] = tau[0], tau[1], tau[2]
    tau_out[3], tau_out[4] = tau_l, tau_r
    arm_out[0], arm_out[1] = arm_l, arm_r
    for i in range(3):
        info[i] = ainfo[i]
    return ERR_NONE


@njit(cache=True, nogil=True)
def batch_controller(q, qd, qr, qdr, qddr, res, has_res, commit, cc, S, S_new, tau, act, arm, info, err):
    """:func:`controller_row` over a batch (res: one row, broadcast, or one per row); the memory after
    the step into S_new (commit it with :func:`commit_rows` once every row is done)."""
    rs = np.int64(res.shape[0] > 1)
    work = np.empty(CONTROLLER_WORK)
    for n in range(q.shape[0]):
        err[n] = controller_row(q[n], qd[n], qr[n], qdr[n], qddr[n], res[n * rs], has_res, commit, cc, S[n],
                                S_new[n], tau[n], act[n], arm[n], info[n], work)


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
    work = np.empty(PASSIVITY_WORK)
    for n in range(q.shape[0]):
        passivity_into(q[n], qd[n], qr[n], qdr[n], qddr[n], P[n * ps], lam, kg, out[n], work)


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
