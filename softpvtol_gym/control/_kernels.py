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
    """
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
        # a Newton step, or (dF >= 0: no usable step) NaN, which lies inside no bracket: bisection
        xn = x - F / dF if dF < 0.0 else math.nan
        xn, lo, hi, lo_raw, hi_raw = _bracket_point(xn, lo, hi, lo_raw, hi_raw, uz, h, tt, ll, lr, eps, input_map)
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
    # residual: realised body force (through the chosen input map) minus the requested one
    tr = MK.generalized_forces((0.0, 0.0, theta, ql, qr), (Tl, Tr, 0.0, 0.0), p, input_map)
    residual = max(abs(tr[0] - t0), abs(tr[1] - t1), abs(tr[2] - t2))
    return (Tl, Tr, ql, qr), (residual, float(it), feasible)


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


@_jit
def controller_step(q, qd, qr, qdr, qddr, res, has_res, commit, cfg, p, lam, kg, st):
    """One step of the actuated passivity controller for one batch row (all arguments tuples).

    q, qd: state (5); qr, qdr, qddr: body reference (arm entries ignored); res: tau residual (5), added
    when ``has_res``; cfg: (method, input map, algebraic iterations, arm feedforward, dt, vmax, amax,
    curvature limit) (see ``CC_*``); p, lam, kg: params and gains; st: the row's memory (``ST_*``).
    Returns (err, tau (5): the commanded generalized force (arm rows: the arm torques asked for),
    actuators (T_l, T_r, tau_l, tau_r), arm references (2), allocation info (3), the memory after the
    step (st itself unless ``commit``)). err != ERR_NONE: the other values are meaningless.
    """
    method, imap, iters, ff, dt, vmax, amax, qmax = cfg
    ents = model_entries(q, qd, p)
    # arm references of the body rows: the last allocated curvatures with their feedforward
    # derivatives, or (no history yet / just reset) the measured curvatures at rest
    fresh = st[ST_FRESH] > 0.5
    vl = vr = al = ar = 0.0
    if fresh:
        arm_l, arm_r = q[3], q[4]
    else:
        arm_l, arm_r = st[ST_HIST + 6], st[ST_HIST + 7]
        if ff:
            vl, al = _arm_derivatives(st[ST_HIST], st[ST_HIST + 2], st[ST_HIST + 4], st[ST_HIST + 6], dt, vmax, amax)
            vr, ar = _arm_derivatives(st[ST_HIST + 1], st[ST_HIST + 3], st[ST_HIST + 5], st[ST_HIST + 7], dt, vmax,
                                      amax)
    alloc = (st[ST_WARM], st[ST_WARM + 1], st[ST_WARM + 2], st[ST_WARM + 3])  # warm start (NaN: cold)
    info = (0.0, 0.0, 0.0)
    tau = (0.0, 0.0, 0.0, 0.0, 0.0)
    nothing = (ERR_TAU, tau, (0.0, 0.0, 0.0, 0.0), (0.0, 0.0), info, st)
    for _ in range(iters):
        tau = passivity_rows(ents, q, qd, (qr[0], qr[1], qr[2], arm_l, arm_r), (qdr[0], qdr[1], qdr[2], vl, vr),
                             (qddr[0], qddr[1], qddr[2], al, ar), lam, kg)
        if has_res:
            tau = (tau[0] + res[0], tau[1] + res[1], tau[2] + res[2], tau[3] + res[3], tau[4] + res[4])
        if not (math.isfinite(tau[0]) and math.isfinite(tau[1]) and math.isfinite(tau[2])):
            return nothing
        if method == ALLOC_PAPER:
            alloc, info = allocate_paper(tau[0], tau[1], tau[2], q[2], p, alloc[2], alloc[3], True)
        else:
            alloc, info = allocate_exact(tau[0], tau[1], tau[2], q[2], p, imap, alloc[0], alloc[2], True, qmax)
        arm_l, arm_r = alloc[2], alloc[3]
    if imap == MK.INPUT_MAP_EXACT and not (abs(q[3]) <= MAX_CURVATURE and abs(q[4]) <= MAX_CURVATURE):
        return (ERR_CURVATURE,) + nothing[1:]
    st_new = st
    if commit:
        # push the allocated curvatures; a fresh row gets a flat history (no jump for the differences)
        if fresh:
            hist = (arm_l, arm_r, arm_l, arm_r, arm_l, arm_r, arm_l, arm_r)
        else:
            hist = (st[ST_HIST + 2], st[ST_HIST + 3], st[ST_HIST + 4], st[ST_HIST + 5], st[ST_HIST + 6],
                    st[ST_HIST + 7], arm_l, arm_r)
        st_new = alloc + hist + (0.0,)
        if ff:
            vl, al = _arm_derivatives(hist[0], hist[2], hist[4], hist[6], dt, vmax, amax)
            vr, ar = _arm_derivatives(hist[1], hist[3], hist[5], hist[7], dt, vmax, amax)
        else:
            vl = vr = al = ar = 0.0
    # arm rows with the new arm references
    t_arm = passivity_rows(ents, q, qd, (qr[0], qr[1], qr[2], arm_l, arm_r), (qdr[0], qdr[1], qdr[2], vl, vr),
                           (qddr[0], qddr[1], qddr[2], al, ar), lam, kg)
    tau_l, tau_r = t_arm[3], t_arm[4]
    if has_res:
        tau_l = tau_l + res[3]
        tau_r = tau_r + res[4]
    a2, a3 = tau_l, tau_r
    if imap == MK.INPUT_MAP_EXACT:  # cancel the thrusts' own work on the curvatures
        gf = MK.generalized_forces(q, (alloc[0], alloc[1], 0.0, 0.0), p, MK.INPUT_MAP_EXACT)
        a2 -= gf[3]
        a3 -= gf[4]
    return (ERR_NONE, (tau[0], tau[1], tau[2], tau_l, tau_r), (alloc[0], alloc[1], a2, a3), (arm_l, arm_r), info,
            st_new)


@_jit
def config_tuples(cc):
    """(cfg, p, lam, kg) tuples of :func:`controller_step` from the constant vector ``cc``."""
    cfg = (int(cc[CC_METHOD]), int(cc[CC_IMAP]), int(cc[CC_ITERS]), cc[CC_FF] > 0.0, cc[CC_DT], cc[CC_VMAX],
           cc[CC_AMAX], cc[CC_QMAX])
    o = CC_P
    p = (cc[o], cc[o + 1], cc[o + 2], cc[o + 3], cc[o + 4], cc[o + 5], cc[o + 6], cc[o + 7], cc[o + 8], cc[o + 9])
    lam = (cc[CC_LAM], cc[CC_LAM + 1], cc[CC_LAM + 2], cc[CC_LAM + 3], cc[CC_LAM + 4])
    kg = (cc[CC_KG], cc[CC_KG + 1], cc[CC_KG + 2], cc[CC_KG + 3], cc[CC_KG + 4])
    return cfg, p, lam, kg


@_jit
def row5(A, n, c):
    """(A[n, c], ..., A[n, c + 4])."""
    return (A[n, c], A[n, c + 1], A[n, c + 2], A[n, c + 3], A[n, c + 4])


@_jit
def state_row(S, n):
    """Row n of a memory array as a tuple (``ST_LEN``)."""
    return (S[n, 0], S[n, 1], S[n, 2], S[n, 3], S[n, 4], S[n, 5], S[n, 6], S[n, 7], S[n, 8], S[n, 9], S[n, 10],
            S[n, 11], S[n, 12])


@_jit
def put_state_row(S, n, st):
    S[n, 0], S[n, 1], S[n, 2], S[n, 3], S[n, 4], S[n, 5], S[n, 6] = st[0], st[1], st[2], st[3], st[4], st[5], st[6]
    S[n, 7], S[n, 8], S[n, 9], S[n, 10], S[n, 11], S[n, 12] = st[7], st[8], st[9], st[10], st[11], st[12]


@njit(cache=True, nogil=True)
def batch_controller(q, qd, qr, qdr, qddr, res, has_res, commit, cc, S, S_new, tau, act, arm, resid, iters, feas,
                     err):
    """:func:`controller_step` over a batch (res: one row, broadcast, or one per row); the memory after
    the step into S_new (commit it with :func:`commit_rows` once every row is done). Allocation info
    into resid (float), iters (int), feas (bool)."""
    rs = np.int64(res.shape[0] > 1)
    cfg, p, lam, kg = config_tuples(cc)
    for n in range(q.shape[0]):
        e, t, a, r, inf, st = controller_step(row5(q, n, 0), row5(qd, n, 0), row5(qr, n, 0), row5(qdr, n, 0),
                                              row5(qddr, n, 0), row5(res, n * rs, 0), has_res, commit, cfg, p, lam,
                                              kg, state_row(S, n))
        err[n] = e
        tau[n, 0], tau[n, 1], tau[n, 2], tau[n, 3], tau[n, 4] = t
        act[n, 0], act[n, 1], act[n, 2], act[n, 3] = a
        arm[n, 0], arm[n, 1] = r
        resid[n] = inf[INFO_RESIDUAL]
        iters[n] = int(inf[INFO_ITERATIONS])
        feas[n] = inf[INFO_FEASIBLE] > 0.5
        put_state_row(S_new, n, st)


@njit(cache=True, nogil=True)
def batch_controller_commit(q, qd, qr, qdr, qddr, res, has_res, commit, cc, S, tau, act, arm, resid, iters, feas,
                            err):
    """:func:`batch_controller` and the commit in one call (batches run in one thread); returns
    whether every row succeeded (the memory advanced if ``commit``)."""
    S_new = S.copy()
    batch_controller(q, qd, qr, qdr, qddr, res, has_res, commit, cc, S, S_new, tau, act, arm, resid, iters, feas,
                     err)
    if commit:
        return _commit_rows(S, S_new, err)
    for n in range(err.shape[0]):
        if err[n] != ERR_NONE:
            return False
    return True


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
