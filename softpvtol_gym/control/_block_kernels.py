"""The controller block driver: one step of the actuated passivity controller (passivity law ->
allocation -> arm references -> arm torques) for blocks of CTRL_LANES rows, shared by
PassivityController, the env's residual mode and PassivityPolicy."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .. import model as MK
from .._columns import Columns
from ._allocation_kernels import (
    ALLOC_PAPER,
    AW_CT,
    AW_ST,
    CTRL_LANES,
    N_AW,
    N_INFO,
    allocate_exact_lanes,
    allocate_paper,
    allocation_residual,
)
from ._passivity_kernels import model_entries, passivity_rows

_jit = njit(cache=True, fastmath=False, nogil=True, error_model="numpy")

# ------------------------------------------------------------------------- fused controller step
# One control step of :class:`~softpvtol_gym.control.PassivityController` (actuated loops) for a block
# of up to CTRL_LANES batch rows, composed of the kernels above: body rows of the passivity law ->
# allocation (repeated ``algebraic_iterations`` times) -> arm references -> arm rows -> actuators.
# The controller's memory per row lives in a float vector (``ST_*``); the constants in ``cc``
# (``CC_*``). Every row is computed alone (the rows of a block only share the loops), so the result
# of a row does not depend on the block it is in.

#: controller memory per row: warm start (T_l, T_r, q_l^d, q_r^d), the last four allocated arm
#: curvatures (oldest first, (q_l^d, q_r^d) each), a flag "no history" (fresh, 1.0) and the integral
#: of the body error (x, z, theta) of the integral loop (zero in the other loops)
MEMORY = Columns("controller_memory", [("warm", 4), ("hist", 8), ("fresh", 1), ("integral", 3)], version=2)
ST_WARM, ST_HIST, ST_FRESH, ST_INT = MEMORY.at
ST_LEN = MEMORY.size
if ST_LEN != 16:  # pragma: no cover (put_lane_inputs / put_lane_memory copy the memory written out)
    raise AssertionError(f"put_lane_inputs and put_lane_memory copy 16 memory columns, the layout has {ST_LEN}")
#: constants: allocation code, input-map code, the algebraic loop's pass limit and tolerance, arm
#: feedforward flag, dt, the feedforward limits (rad/s, rad/s^2), curvature limit, then params (10),
#: Lambda (5), K (5), and the integral loop's body terms (x, z, theta): gains Lambda_I, the integral's
#: bounds, the bound on the error it integrates, the bound on the error of the law (all 0 / inf: off)
CONSTANTS = Columns("controller_constants", [("method", 1), ("imap", 1), ("iters", 1), ("tol", 1), ("ff", 1),
                                            ("dt", 1), ("vmax", 1), ("amax", 1), ("qmax", 1), ("p", 10), ("lam", 5),
                                            ("kg", 5), ("lam_i", 3), ("int_max", 3), ("err_max", 3), ("pos_max", 3)],
                   version=2)
(CC_METHOD, CC_IMAP, CC_ITERS, CC_TOL, CC_FF, CC_DT, CC_VMAX, CC_AMAX, CC_QMAX, CC_P, CC_LAM, CC_KG, CC_LAMI, CC_IMAX,
 CC_EMAX, CC_PMAX) = CONSTANTS.at
CC_LEN = CONSTANTS.size
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




@MK.accessor
def lane_index(row, lane):
    """Index of (row, lane) in a flat lane block."""
    return row * CTRL_LANES + lane

#: rows of a controller block: B[row * CTRL_LANES + lane] (structure of arrays, flat with constant row
#: offsets: LLVM then vectorises the branch-free lane loops). Inputs: q, qdot, body reference (arm
#: entries ignored), its velocity and acceleration, tau residual; the row's memory before and after the
#: step; outputs: error code (ERR_*), tau (5), actuators (4), arm references (2), allocation info (in
#: this order: ``batch_controller`` copies them as one run), the algebraic loop's residual and passes;
#: work: D, C, g entries (17), arm references with their derivatives (6), allocation (4), active flag,
#: the algebraic loop's relaxation factor and previous residual, the body error (integral loop)
BLOCK = Columns("controller_block", [
    ("q", 5), ("qd", 5), ("qr", 5), ("qdr", 5), ("qddr", 5), ("res", 5), ("st", ST_LEN), ("stn", ST_LEN),
    ("err", 1), ("tau", 5), ("act", 4), ("arm", 2), ("info", N_INFO), ("loop", 2),
    ("ents", 17), ("ref", 6), ("alloc", 4), ("active", 1), ("relax", 2), ("qt", 3),
])
(CB_Q, CB_QD, CB_QR, CB_QDR, CB_QDDR, CB_RES, CB_ST, CB_STN, CB_ERR, CB_TAU, CB_ACT, CB_ARM, CB_INFO, CB_LOOP, CB_ENTS,
 CB_REF, CB_ALLOC, CB_ACTIVE, CB_RELAX, CB_QT) = BLOCK.at
CB_LEN = BLOCK.size


@_jit
def controller_work():
    """(B, A): the work arrays of :func:`controller_lanes` (one pair per thread)."""
    return np.zeros(CB_LEN * CTRL_LANES), np.zeros(N_AW * CTRL_LANES)


@MK.accessor
def lane3(B, c, j):
    """Rows c .. c + 2 of lane j as a tuple (lane4 ... lane8 likewise)."""
    return B[lane_index(c, j)], B[lane_index(c + 1, j)], B[lane_index(c + 2, j)]


@MK.accessor
def lane4(B, c, j):
    return lane3(B, c, j) + (B[lane_index(c + 3, j)],)


@MK.accessor
def lane5(B, c, j):
    return lane4(B, c, j) + (B[lane_index(c + 4, j)],)


@MK.accessor
def lane6(B, c, j):
    return lane3(B, c, j) + lane3(B, c + 3, j)


@MK.accessor
def lane8(B, c, j):
    return lane4(B, c, j) + lane4(B, c + 4, j)


@MK.accessor
def put_lane3(B, c, j, t):
    """Rows c .. c + 2 of lane j from a tuple (put_lane4, put_lane5 likewise)."""
    B[lane_index(c, j)], B[lane_index(c + 1, j)], B[lane_index(c + 2, j)] = t[0], t[1], t[2]


@MK.accessor
def put_lane4(B, c, j, t):
    put_lane3(B, c, j, t)
    B[lane_index(c + 3, j)] = t[3]


@MK.accessor
def put_lane5(B, c, j, t):
    put_lane4(B, c, j, t)
    B[lane_index(c + 4, j)] = t[4]


@MK.accessor
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
    put_lane3(B, CB_ST + 13, j, (S[n, 13], S[n, 14], S[n, 15]))


@MK.accessor
def put_lane_memory(B, j, S_new, n):
    """The memory of lane j after the step into S_new[n]."""
    S_new[n, 0], S_new[n, 1], S_new[n, 2], S_new[n, 3], S_new[n, 4] = lane5(B, CB_STN, j)
    S_new[n, 5], S_new[n, 6], S_new[n, 7], S_new[n, 8] = lane4(B, CB_STN + 5, j)
    S_new[n, 9], S_new[n, 10], S_new[n, 11], S_new[n, 12] = lane4(B, CB_STN + 9, j)
    S_new[n, 13], S_new[n, 14], S_new[n, 15] = lane3(B, CB_STN + 13, j)


@MK.accessor
def _lane_inputs(B, j):
    """(D, C, g entries, q, qdot, body reference rows (3 each of qr, qdr, qddr), arm references with
    their derivatives (6), residual) of lane j. (Helpers that take the block array stay branch-free:
    a branch would keep numba's reference counting of the array in the row loops.)"""
    ents = (lane8(B, CB_ENTS, j), lane6(B, CB_ENTS + 8, j), lane3(B, CB_ENTS + 14, j))
    body_ref = lane3(B, CB_QR, j) + lane3(B, CB_QDR, j) + lane3(B, CB_QDDR, j)
    return ents, lane5(B, CB_Q, j), lane5(B, CB_QD, j), body_ref, lane6(B, CB_REF, j), lane5(B, CB_RES, j)


@MK.inline
def _lane_tau(ents, q, qd, br, refs, res, lam, kg, has_res):
    """tau of the passivity law (plus the residual) for the inputs of :func:`_lane_inputs`."""
    arm_l, arm_r, vl, vr, al, ar = refs
    tau = passivity_rows(ents, q, qd, (br[0], br[1], br[2], arm_l, arm_r), (br[3], br[4], br[5], vl, vr),
                         (br[6], br[7], br[8], al, ar), lam, kg)
    if has_res:
        tau = (tau[0] + res[0], tau[1] + res[1], tau[2] + res[2], tau[3] + res[3], tau[4] + res[4])
    return tau


@MK.inline
def _integral_refs(B, j, lam, integ):
    """The integral loop's body reference of lane j, written into the block. With the body error
    q~ = q - q_ref (x, z, theta), its bounded part e = clip(q~, +-pos_max), the integral z (memory,
    zero for a fresh row) of clip(q~, +-err_max) and Lambda_I = ``integ[0:3]``, the passivity law gets
    v = qdot_ref - Lambda e - Lambda_I z and a = qddot_ref - Lambda_I clip(q~, +-err_max) - Lambda q~dot
    (the rate of v; where |q~| > pos_max, e is constant and a drops Lambda q~dot): the sliding
    variable r = qdot - v = q~dot + Lambda e + Lambda_I z, so that once r = 0 the error obeys
    (s^2 + lambda s + lambda_I) q~ = 0, and a far start is approached at a speed of at most
    lambda pos_max. It is passed as the reference q - e with the rates qdot_ref - Lambda_I z and
    a + Lambda (qdot - qdot_ref + Lambda_I z)."""
    for i in range(3):
        li, pmax = integ[i], integ[10 + i]
        if li > 0.0 or pmax < math.inf:
            q = B[lane_index(CB_Q + i, j)]
            qt = q - B[lane_index(CB_QR + i, j)]
            B[lane_index(CB_QT + i, j)] = qt
            e = _clip(qt, -pmax, pmax)
            z = B[lane_index(CB_ST + ST_INT + i, j)]
            qdr = B[lane_index(CB_QDR + i, j)] - li * z
            rate_error = B[lane_index(CB_QD + i, j)] - qdr
            a = B[lane_index(CB_QDDR + i, j)] - li * _clip(qt, -integ[6 + i], integ[6 + i])
            if e == qt:
                a -= lam[i] * (B[lane_index(CB_QD + i, j)] - B[lane_index(CB_QDR + i, j)])
            B[lane_index(CB_QR + i, j)] = q - e
            B[lane_index(CB_QDR + i, j)] = qdr
            B[lane_index(CB_QDDR + i, j)] = a + lam[i] * rate_error


@MK.inline
def _integral_update(B, j, dt, integ):
    """The integral after the step of lane j: z + dt * clip(q~, -err_max, err_max), clipped to
    +-int_max (anti-windup: the integrated error and the integral are bounded); held while the
    allocation reports its demand infeasible (a desired curvature clipped: conditional integration)."""
    feasible = B[lane_index(CB_INFO + 2, j)] > 0.5
    for i in range(3):
        z = B[lane_index(CB_ST + ST_INT + i, j)]
        if feasible and integ[i] > 0.0:
            e = B[lane_index(CB_QT + i, j)]
            z = _clip(z + dt * _clip(e, -integ[6 + i], integ[6 + i]), -integ[3 + i], integ[3 + i])
        B[lane_index(CB_STN + ST_INT + i, j)] = z


@_jit
def controller_model_lanes(B, p):
    """D, C, g entries of every lane of a controller block (unused ones too): polynomials only, SIMD."""
    for j in range(CTRL_LANES):
        d, cor, g = model_entries(lane5(B, CB_Q, j), lane5(B, CB_QD, j), p)
        put_lane4(B, CB_ENTS, j, d[:4])
        put_lane4(B, CB_ENTS + 4, j, d[4:])
        put_lane3(B, CB_ENTS + 8, j, cor[:3])
        put_lane3(B, CB_ENTS + 11, j, cor[3:])
        put_lane3(B, CB_ENTS + 14, j, g)


@_jit
def controller_lanes(m, B, A, has_res, commit, cfg, p, lam, kg, integ):
    """One step of the actuated passivity controller for the rows of a block: lanes 0 .. m - 1 of
    B (``CB_*`` rows, inputs filled, see :func:`put_lane_inputs`); A: the allocation's work.

    cfg: (method, input map, algebraic pass limit and tolerance, arm feedforward, dt, vmax, amax, curvature
    limit)
    (see ``CC_*``); p, lam, kg: params and gains (tuples); integ: the integral action (Lambda_I (3),
    int_max (3), err_max (3), 1.0 if on else 0.0, pos_max (3); see :func:`_integral_refs`); the tau
    residual is added when ``has_res``;
    the memory after the step (into CB_STN) is the one before unless ``commit``. Outputs per lane:
    the error code (CB_ERR: ERR_NONE, or the row's outputs are zeros and its memory unchanged), tau (5:
    the commanded generalized force, arm rows: the arm torques asked for), actuators (T_l, T_r,
    tau_l, tau_r), arm references (2) and allocation info (N_INFO).
    """
    method, imap, iters, tol, ff, dt, vmax, amax, qmax = cfg
    controller_model_lanes(B, p)
    for j in range(m):
        # arm references of the body rows, the algebraic loop's start: the allocated curvatures of the
        # last two steps extrapolated to this one (q^d_k-1 + (q^d_k-1 - q^d_k-2); a fresh history is flat:
        # the last ones), with their feedforward derivatives, or (no history yet / just reset) the measured
        # curvatures at rest
        vl = vr = al = ar = 0.0
        if B[lane_index(CB_ST + ST_FRESH, j)] > 0.5:
            arm_l, arm_r = B[lane_index(CB_Q + 3, j)], B[lane_index(CB_Q + 4, j)]
            put_lane3(B, CB_ST + ST_INT, j, (0.0, 0.0, 0.0))  # a new episode: no integral yet
        else:
            h = CB_ST + ST_HIST
            last_l, last_r = B[lane_index(h + 6, j)], B[lane_index(h + 7, j)]
            arm_l = 2.0 * last_l - B[lane_index(h + 4, j)]
            arm_r = 2.0 * last_r - B[lane_index(h + 5, j)]
            if ff:
                hist = lane8(B, h, j)
                vl, al = _arm_derivatives(hist[0], hist[2], hist[4], hist[6], dt, vmax, amax)
                vr, ar = _arm_derivatives(hist[1], hist[3], hist[5], hist[7], dt, vmax, amax)
        if integ[9] > 0.0:
            _integral_refs(B, j, lam, integ)
        put_lane3(B, CB_REF, j, (arm_l, arm_r, vl))
        put_lane3(B, CB_REF + 3, j, (vr, al, ar))
        for k in range(4):  # warm start (NaN: cold)
            B[lane_index(CB_ALLOC + k, j)] = B[lane_index(CB_ST + ST_WARM + k, j)]
        put_lane3(B, CB_INFO, j, (0.0, 0.0, 0.0))
        B[lane_index(CB_ERR, j)] = ERR_NONE
    # The algebraic loop: the arm references enter the body rows (through D and C), the body rows give
    # the allocation, the allocation the arm references. Passes until the allocated curvatures move by
    # at most ``tol`` (rad) or ``iters`` passes; from the second pass on, a lane whose change grew has its
    # step halved (relaxation), so that the iteration stays on the branch it started from (extrapolated
    # from the last steps' solutions, or the measured curvatures after a reset) instead of cycling between roots.
    for j in range(m):
        B[lane_index(CB_ACTIVE, j)] = 1.0 if B[lane_index(CB_ERR, j)] == ERR_NONE else 0.0
        B[lane_index(CB_RELAX, j)], B[lane_index(CB_RELAX + 1, j)] = 1.0, math.inf
        B[lane_index(CB_LOOP, j)], B[lane_index(CB_LOOP + 1, j)] = 0.0, 0.0
    for it in range(1, iters + 1):
        live = 0
        for j in range(m):
            if B[lane_index(CB_ACTIVE, j)] != 0.0:
                ents, q, qd, br, refs, res = _lane_inputs(B, j)
                # the body rows take the arm references without their fed-forward derivatives: through
                # D_ba and C_ba, differenced derivatives (1/dt^2 on q^d's history) would close a loop
                # q^d -> body rows -> allocation -> q^d with a gain far above 1 at the Nyquist frequency
                # (the arm torques then chatter at +-tau_max under a held command); the arm rows use them
                refs = (refs[0], refs[1], 0.0, 0.0, 0.0, 0.0)
                tau = _lane_tau(ents, q, qd, br, refs, res, lam, kg, has_res)
                put_lane3(B, CB_TAU, j, tau)
                if math.isfinite(tau[0]) and math.isfinite(tau[1]) and math.isfinite(tau[2]):
                    live += 1
                else:
                    B[lane_index(CB_ERR, j)] = ERR_TAU
                    B[lane_index(CB_ACTIVE, j)] = 0.0
        if live == 0:
            break
        if method == ALLOC_PAPER:
            for j in range(m):
                if B[lane_index(CB_ACTIVE, j)] != 0.0:
                    t0, t1, t2 = lane3(B, CB_TAU, j)
                    warm = lane4(B, CB_ALLOC, j)
                    alloc, info = allocate_paper(t0, t1, t2, B[lane_index(CB_Q + 2, j)], p, warm[2], warm[3], True)
                    put_lane4(B, CB_ALLOC, j, alloc)
                    put_lane3(B, CB_INFO, j, info)
        else:
            # (theta is the same in every pass: its sin and cos from the first; the residual of the last pass only)
            allocate_exact_lanes(m, B, CB_TAU, CB_Q + 2, CB_ALLOC, CB_ACTIVE, CB_ALLOC, CB_INFO, A, True, p, imap,
                                 qmax, it > 1, False)
        for j in range(m):
            if B[lane_index(CB_ACTIVE, j)] != 0.0:
                new_l, new_r = B[lane_index(CB_ALLOC + 2, j)], B[lane_index(CB_ALLOC + 3, j)]
                old_l, old_r = B[lane_index(CB_REF, j)], B[lane_index(CB_REF + 1, j)]
                change = max(abs(new_l - old_l), abs(new_r - old_r))
                B[lane_index(CB_LOOP, j)], B[lane_index(CB_LOOP + 1, j)] = change, it
                w = B[lane_index(CB_RELAX, j)]
                if change <= tol or it == iters or not math.isfinite(change):
                    B[lane_index(CB_ACTIVE, j)] = 0.0  # done: the arm rows use the allocated curvatures
                    w = 1.0
                elif change > B[lane_index(CB_RELAX + 1, j)]:
                    w = max(0.5 * w, 1.0 / 1024.0)
                B[lane_index(CB_RELAX, j)], B[lane_index(CB_RELAX + 1, j)] = w, change
                if w == 1.0:
                    B[lane_index(CB_REF, j)], B[lane_index(CB_REF + 1, j)] = new_l, new_r
                else:
                    B[lane_index(CB_REF, j)] = old_l + w * (new_l - old_l)
                    B[lane_index(CB_REF + 1, j)] = old_r + w * (new_r - old_r)
    if method != ALLOC_PAPER:  # the exact allocation's residual, of each row's last pass
        for j in range(m):
            if B[lane_index(CB_ERR, j)] == ERR_NONE:
                Tl, Tr, ql, qr = lane4(B, CB_ALLOC, j)
                t0, t1, t2 = lane3(B, CB_TAU, j)
                B[lane_index(CB_INFO, j)] = allocation_residual(A[AW_ST * CTRL_LANES + j], A[AW_CT * CTRL_LANES + j],
                                                                ql, qr, Tl, Tr, t0, t1, t2, p, imap)
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
            for k in range(CB_LOOP + 2 - CB_TAU):
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
            if integ[9] > 0.0:
                _integral_update(B, j, dt, integ)
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
    """(cfg, p, lam, kg, integ) tuples of :func:`controller_lanes` from the constant vector ``cc``."""
    cfg = (int(cc[CC_METHOD]), int(cc[CC_IMAP]), int(cc[CC_ITERS]), cc[CC_TOL], cc[CC_FF] > 0.0, cc[CC_DT],
           cc[CC_VMAX], cc[CC_AMAX], cc[CC_QMAX])
    o = CC_P
    p = (cc[o], cc[o + 1], cc[o + 2], cc[o + 3], cc[o + 4], cc[o + 5], cc[o + 6], cc[o + 7], cc[o + 8], cc[o + 9])
    lam = (cc[CC_LAM], cc[CC_LAM + 1], cc[CC_LAM + 2], cc[CC_LAM + 3], cc[CC_LAM + 4])
    kg = (cc[CC_KG], cc[CC_KG + 1], cc[CC_KG + 2], cc[CC_KG + 3], cc[CC_KG + 4])
    li = (cc[CC_LAMI], cc[CC_LAMI + 1], cc[CC_LAMI + 2])
    pm = (cc[CC_PMAX], cc[CC_PMAX + 1], cc[CC_PMAX + 2])
    on = li[0] > 0.0 or li[1] > 0.0 or li[2] > 0.0 or pm[0] < math.inf or pm[1] < math.inf or pm[2] < math.inf
    integ = li + (cc[CC_IMAX], cc[CC_IMAX + 1], cc[CC_IMAX + 2], cc[CC_EMAX], cc[CC_EMAX + 1], cc[CC_EMAX + 2],
                  1.0 if on else 0.0) + pm
    return cfg, p, lam, kg, integ


@MK.accessor
def row5(A, n, c):
    """(A[n, c], ..., A[n, c + 4])."""
    return (A[n, c], A[n, c + 1], A[n, c + 2], A[n, c + 3], A[n, c + 4])


#: per-row inputs of the driver (X): q, qdot, body reference (arm entries ignored), its velocity and
#: acceleration, tau residual (5 each)
INPUTS = Columns("controller_inputs", [("q", 5), ("qd", 5), ("qr", 5), ("qdr", 5), ("qddr", 5), ("res", 5)])
IN_Q, IN_QD, IN_QR, IN_QDR, IN_QDDR, IN_RES = INPUTS.at
IN_LEN = INPUTS.size
#: per-row outputs (out): tau (5), actuators (4), arm references (2), allocation info (residual,
#: iterations, feasible), the algebraic loop's residual and passes, in the order of the block's output rows
OUTPUTS = Columns("controller_outputs", [("tau", 5), ("act", 4), ("arm", 2), ("info", N_INFO), ("loop", 2)])
OUT_TAU, OUT_ACT, OUT_ARM, OUT_INFO, OUT_LOOP = OUTPUTS.at
OUT_LEN = OUTPUTS.size


@_jit
def controller_rows(lo, hi, X, has_res, commit, cc, S, S_new, out, err):
    """The controller block driver, the one loop that runs :func:`controller_lanes` over a batch:
    rows lo .. hi - 1 of the inputs X (N, ``IN_LEN``) and the memory S (N, ``ST_LEN``), in blocks of
    CTRL_LANES; outputs into out (N, ``OUT_LEN``), error codes (``ERR_*``) into err (N), and every
    row's memory after the step (unchanged for a failed row, or without ``commit``) into S_new (may
    be S itself: a block's rows are read before they are written). PassivityController, the env's
    residual mode and PassivityPolicy fill X, call this, and read out."""
    cfg, p, lam, kg, integ = config_tuples(cc)
    B, A = controller_work()
    for n0 in range(lo, hi, CTRL_LANES):
        m = min(CTRL_LANES, hi - n0)
        for j in range(m):
            n = n0 + j
            put_lane_inputs(B, j, row5(X, n, IN_Q), row5(X, n, IN_QD), row5(X, n, IN_QR), row5(X, n, IN_QDR),
                            row5(X, n, IN_QDDR), row5(X, n, IN_RES), S, n)
        controller_lanes(m, B, A, has_res, commit, cfg, p, lam, kg, integ)
        for j in range(m):
            n = n0 + j
            err[n] = int(B[lane_index(CB_ERR, j)])
            for k in range(OUT_LEN):
                out[n, k] = B[lane_index(CB_TAU + k, j)]
            put_lane_memory(B, j, S_new, n)


@njit(cache=True, nogil=True)
def batch_controller(X, has_res, commit, cc, S, S_new, out, err):
    """:func:`controller_rows` over all rows of its arguments (a thread's share of a batch)."""
    controller_rows(0, X.shape[0], X, has_res, commit, cc, S, S_new, out, err)


@njit(cache=True, nogil=True)
def single_controller(q, qd, qr, qdr, qddr, res, has_res, commit, cc, S, out):
    """:func:`controller_rows` for one state: 1-D inputs (5), out (``OUT_LEN``), memory S (1, ST_LEN)
    advanced in place if ``commit`` and the row succeeded; returns the row's error code."""
    X = np.empty((1, IN_LEN))
    for i in range(5):
        X[0, IN_Q + i], X[0, IN_QD + i], X[0, IN_QR + i] = q[i], qd[i], qr[i]
        X[0, IN_QDR + i], X[0, IN_QDDR + i], X[0, IN_RES + i] = qdr[i], qddr[i], res[i]
    err = np.zeros(1, dtype=np.int64)
    controller_rows(0, 1, X, has_res, commit, cc, S, S, out.reshape(1, OUT_LEN), err)
    return err[0]
