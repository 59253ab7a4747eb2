"""The compiled env step: command (action scaling, allocation, saturation, lag), physics (RK4 with the
command held), clock, wind, termination, observation and reward of a range of envs.

The physics of up to ``MK.LANES`` envs at a time runs in a lane block (structure of arrays, layout
:data:`~softpvtol_gym.envs.layout.LANES`) that LLVM turns into SIMD code. The residual mode's base
controller is the controller block driver of :mod:`softpvtol_gym.control._kernels`, fed the
measured state. Entry points: :func:`step_serial` (one call, small batches) and, for large batches
split over threads by BatchSim, :func:`step_check_actions`, :func:`step_controller_rows` and
:func:`step_physics_rows`. An error code changes nothing.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .. import _kernels as MK
from ..control import _kernels as CK
from .actions import MODE_ACT, MODE_IDEAL, MODE_RES_ACT
from .layout import LANES, S, SC, SI, SK, SL
from .noise import STREAM_WIND, counter_normal
from .observation import observe_range, wrap
from .references import REF_CONSTANT, REF_CUSTOM, reference_row
from .reward import REWARD_TERMS, reward_terms
from .termination import R_NONE, R_NONFINITE, termination_reason

_jit = njit(cache=True, fastmath=False, nogil=True, error_model="numpy")

#: size of the physics lane block
LANE_BLOCK = LANES.size * MK.LANES
#: step kernel return codes
STEP_OK, STEP_BAD_ACTION, STEP_CONTROLLER_TAU, STEP_CONTROLLER_CURVATURE = range(4)
#: per-row controller outputs in residual mode: actuators (4), allocation residual, arm references (2)
CTL_ACT, CTL_RESIDUAL, CTL_ARM, CTL_LEN = 0, 4, 5, 7


@_jit
def _row5(A, n, c):
    return (A[n, c], A[n, c + 1], A[n, c + 2], A[n, c + 3], A[n, c + 4])


@_jit
def _row10(A, n, c):
    return _row5(A, n, c) + _row5(A, n, c + 5)


@_jit
def _vec5(v, c):
    return (v[c], v[c + 1], v[c + 2], v[c + 3], v[c + 4])


@_jit
def _nominal_params(C):
    return _vec5(C, SC.p_nominal) + _vec5(C, SC.p_nominal + 5)


# ---------------------------------------------------------------------------------- lane blocks
@_jit
def _lane_put(W, row, j, v):
    """Rows row .. row + len(v) - 1 of lane j from the tuple v."""
    for i in range(len(v)):
        W[(row + i) * MK.LANES + j] = v[i]


@_jit
def _lane5(W, row, j):
    L = MK.LANES
    o = row * L + j
    return (W[o], W[o + L], W[o + 2 * L], W[o + 3 * L], W[o + 4 * L])


# ---------------------------------------------------------------------------------- diagnostics
@MK._inline
def _energy_storage(q, qd, qr, qdr, P, Pnom, lam, kg):
    """(total energy of the plant, controller storage w.r.t. the body reference with arm references 0)."""
    energy = MK.kinetic_energy(q, qd, P) + MK.potential_energy(q, P)
    storage = CK.storage(q, qd, (qr[0], qr[1], qr[2], 0.0, 0.0), (qdr[0], qdr[1], qdr[2], 0.0, 0.0), Pnom, lam, kg)
    return energy, storage


@_jit
def energy_storage(q, qd, qr, qdr, P, Pnom, lam, kg):
    """:func:`_energy_storage` as a compiled call (the non-inlined copy, shared by partial lane blocks
    and resets: inlining costs compile time)."""
    return _energy_storage(q, qd, qr, qdr, P, Pnom, lam, kg)


@MK._inline
def _diag_lane_in(W, j):
    q, qd, _u, _ext, p = MK._lane_load(W, j)
    L = MK.LANES
    qr = (W[SL.qr * L + j], W[(SL.qr + 1) * L + j], W[(SL.qr + 2) * L + j])
    qdr = (W[SL.qdr * L + j], W[(SL.qdr + 1) * L + j], W[(SL.qdr + 2) * L + j])
    return q, qd, qr, qdr, p


@_jit
def _diag_lanes(W, m, pnom, lam, kg):
    """Energy and storage of the first m lanes (SIMD for full blocks)."""
    L = MK.LANES
    if m == L:
        for j in range(L):
            q, qd, qr, qdr, p = _diag_lane_in(W, j)
            W[SL.energy * L + j], W[SL.storage * L + j] = _energy_storage(q, qd, qr, qdr, p, pnom, lam, kg)
    else:
        for j in range(m):
            q, qd, qr, qdr, p = _diag_lane_in(W, j)
            W[SL.energy * L + j], W[SL.storage * L + j] = energy_storage(q, qd, qr, qdr, p, pnom, lam, kg)


# ------------------------------------------------------------------------------------ reference
@_jit
def _put_reference(F, n, code, t):
    """The compiled reference ``code`` at time t into row n's qr, qdr, qddr (body entries)."""
    pos, vel, acc = reference_row(code, t, F, n, S.refp)
    for i in range(3):
        F[n, S.qr + i] = pos[i]
        F[n, S.qdr + i] = vel[i]
        F[n, S.qddr + i] = acc[i]


# -------------------------------------------------------------------------------------- command
@_jit
def _virtual_allocation(F, n, C, alloc, imap, ws):
    """Virtual mode: thrusts from the body rows of tau (ws[5:10]) by the allocation, arm rows as
    generalized forces; the command into ws[0:4], diagnostics into F. Returns the thrust flag."""
    pnom = _nominal_params(C)
    thrust_sat = 0.0
    if alloc == CK.ALLOC_PAPER:
        out, info = CK.allocate_paper(ws[5], ws[6], ws[7], F[n, S.q + 2], pnom, 0.0, 0.0, False)
    else:
        out, info = CK.allocate_exact(ws[5], ws[6], ws[7], F[n, S.q + 2], pnom, imap, 0.0, 0.0, False, math.pi)
    Tl, Tr = out[0], out[1]
    if not (math.isfinite(Tl) and math.isfinite(Tr)):
        Tl, Tr = 0.0, 0.0
        thrust_sat = 1.0
    ws[0], ws[1] = Tl, Tr
    F[n, S.allocation_residual] = info[CK.INFO_RESIDUAL] if math.isfinite(info[CK.INFO_RESIDUAL]) else 1.0e300
    F[n, S.arm_reference] = out[2]
    F[n, S.arm_reference + 1] = out[3]
    ws[2], ws[3] = ws[8], ws[9]
    if imap == MK.INPUT_MAP_EXACT:  # the arm rows get the requested generalized force
        gf = MK.generalized_forces(_row5(F, n, S.q), (Tl, Tr, 0.0, 0.0), pnom, imap)
        ws[2] -= gf[3]
        ws[3] -= gf[4]
    return thrust_sat


@_jit
def _command(F, n, C, mode, alloc, imap, ctl, ws):
    """The command of env n before saturation into ws[0:5] (actuators (4), or tau (5) in ideal mode);
    returns the thrust-saturation flag of the allocation. One branch per action mode (``MODE_*``)."""
    for i in range(5):
        ws[i] = 0.0
    tmax, taumax = C[SC.thrust_max], C[SC.arm_torque_max]
    if mode == MODE_ACT:
        ws[0] = tmax * 0.5 * (F[n, S.u] + 1.0)
        ws[1] = tmax * 0.5 * (F[n, S.u + 1] + 1.0)
        ws[2] = taumax * F[n, S.u + 2]
        ws[3] = taumax * F[n, S.u + 3]
        return 0.0
    if mode == MODE_RES_ACT:
        for i in range(4):
            ws[i] = ctl[n, CTL_ACT + i] + C[SC.residual_actuator_scale + i] * F[n, S.u + i]
        return 0.0
    for i in range(5):
        ws[5 + i] = C[SC.virtual_offset + i] + C[SC.virtual_scale + i] * F[n, S.u + i]
    if mode == MODE_IDEAL:
        for i in range(5):
            ws[i] = ws[5 + i]
        return 0.0
    return _virtual_allocation(F, n, C, alloc, imap, ws)


@_jit
def _begin_range(lo, hi, F, I, C, K, ctl, W, ws):
    """Clock, reference and applied command (action scaling, allocation, saturation, actuator lag) of
    envs lo .. hi - 1; their state, command and wind into the lanes of W."""
    mode, alloc, imap, ref = K[SK.mode], K[SK.alloc], K[SK.imap], K[SK.ref]
    tmax, taumax = C[SC.thrust_max], C[SC.arm_torque_max]
    lag_on = C[SC.lag_on] > 0.0
    na = 5 if mode == MODE_IDEAL else 4
    for n in range(lo, hi):
        I[n, SI.steps] += 1
        t = I[n, SI.steps] * C[SC.dt_control]
        F[n, S.t] = t
        if ref == REF_CUSTOM:  # set by BatchSim before the step
            for i in range(3):
                F[n, S.qr + i] = F[n, S.qr_custom + i]
                F[n, S.qdr + i] = F[n, S.qr_custom + 3 + i]
                F[n, S.qddr + i] = F[n, S.qr_custom + 6 + i]
        elif ref != REF_CONSTANT:
            _put_reference(F, n, ref, t)
        F[n, S.allocation_residual] = 0.0
        F[n, S.arm_reference] = 0.0
        F[n, S.arm_reference + 1] = 0.0
        thrust_sat = _command(F, n, C, mode, alloc, imap, ctl, ws)
        torque_sat = 0.0
        if mode != MODE_IDEAL:
            for i in range(2):
                if ws[i] < 0.0:
                    ws[i] = 0.0
                    thrust_sat = 1.0
                elif ws[i] > tmax:
                    ws[i] = tmax
                    thrust_sat = 1.0
            for i in range(2, 4):
                if ws[i] < -taumax:
                    ws[i] = -taumax
                    torque_sat = 1.0
                elif ws[i] > taumax:
                    ws[i] = taumax
                    torque_sat = 1.0
        F[n, S.thrust_saturated] = thrust_sat
        F[n, S.arm_torque_saturated] = torque_sat
        # first-order actuator lag (starts at the first command of the episode)
        if lag_on:
            if I[n, SI.lag_init] != 0:
                for i in range(na):
                    F[n, S.lag + i] = ws[i]
                I[n, SI.lag_init] = 0
            else:
                al = C[SC.lag_a]
                for i in range(na):
                    F[n, S.lag + i] = F[n, S.lag + i] + al * (ws[i] - F[n, S.lag + i])
            for i in range(na):
                ws[i] = F[n, S.lag + i]
        for i in range(5):
            F[n, S.applied + i] = ws[i] if i < na else math.nan
        if mode == MODE_RES_ACT:
            F[n, S.allocation_residual] = ctl[n, CTL_RESIDUAL]
            F[n, S.arm_reference] = ctl[n, CTL_ARM]
            F[n, S.arm_reference + 1] = ctl[n, CTL_ARM + 1]
        j = n - lo
        _lane_put(W, SL.q, j, _row5(F, n, S.q))
        _lane_put(W, SL.qd, j, _row5(F, n, S.qd))
        # the held command: actuators (ws[4] = 0), or tau in ideal mode
        _lane_put(W, SL.u, j, (ws[0], ws[1], ws[2], ws[3], ws[4]))
        _lane_put(W, SL.ext, j, (F[n, S.wind], F[n, S.wind + 1]))  # (0 unless the wind is on)
        _lane_put(W, SL.p, j, _row10(F, n, S.P))


@_jit
def _end_range(lo, hi, F, key, I, C, W):
    """Noise counter, wind and termination of envs lo .. hi - 1; the final state from W back into F
    (the last finite one if it diverged, also into W); the body reference into W for the diagnostics."""
    L = MK.LANES
    wind_on = C[SC.wind_on] > 0.0
    for n in range(lo, hi):
        j = n - lo
        I[n, SI.counter] += 1
        counter = I[n, SI.counter]
        if wind_on:  # Ornstein-Uhlenbeck update, after the step it was held over
            wa, wb = C[SC.wind_a], C[SC.wind_b]
            F[n, S.wind] = wa * F[n, S.wind] + wb * counter_normal(key[n], counter, STREAM_WIND)
            F[n, S.wind + 1] = wa * F[n, S.wind + 1] + wb * counter_normal(key[n], counter, STREAM_WIND + 1)
        q = _lane5(W, SL.q, j)
        qd = _lane5(W, SL.qd, j)
        finite = True
        for i in range(5):
            if not (math.isfinite(q[i]) and math.isfinite(qd[i])):
                finite = False
        if finite:
            for i in range(5):
                F[n, S.q + i] = q[i]
                F[n, S.qd + i] = qd[i]
            I[n, SI.reason] = termination_reason(q, qd)
        else:  # keep the last finite state: observation and info stay finite
            I[n, SI.reason] = R_NONFINITE
            _lane_put(W, SL.q, j, _row5(F, n, S.q))
            _lane_put(W, SL.qd, j, _row5(F, n, S.qd))
        _lane_put(W, SL.qr, j, (F[n, S.qr], F[n, S.qr + 1], F[n, S.qr + 2]))
        _lane_put(W, SL.qdr, j, (F[n, S.qdr], F[n, S.qdr + 1], F[n, S.qdr + 2]))


@_jit
def _reward_range(lo, hi, F, I, C, K, W):
    """Diagnostics (energy and storage from the lanes of W) and reward terms of envs lo .. hi - 1
    (true state, not the noisy measurement)."""
    L = MK.LANES
    ideal = K[SK.mode] == MODE_IDEAL
    tmax, taumax = C[SC.thrust_max], C[SC.arm_torque_max]
    for n in range(lo, hi):
        j = n - lo
        q3, q4 = F[n, S.q + 3], F[n, S.q + 4]
        F[n, S.total_energy] = W[SL.energy * L + j]
        F[n, S.storage_function] = W[SL.storage * L + j]
        F[n, S.curvature_violation] = max(abs(q3) - math.pi, abs(q4) - math.pi, 0.0)
        ex, ez = F[n, S.q] - F[n, S.qr], F[n, S.q + 1] - F[n, S.qr + 1]
        eth = wrap(F[n, S.q + 2] - F[n, S.qr + 2])
        ev = math.sqrt((F[n, S.qd] - F[n, S.qdr]) ** 2 + (F[n, S.qd + 1] - F[n, S.qdr + 1]) ** 2
                       + (F[n, S.qd + 2] - F[n, S.qdr + 2]) ** 2)
        if ideal:
            eff = 0.0
            for i in range(5):
                eff += ((F[n, S.applied + i] - C[SC.virtual_offset + i]) / C[SC.virtual_scale + i]) ** 2
            eff /= 5.0
        else:
            th = C[SC.hover_thrust]
            eff = 0.25 * (((F[n, S.applied] - th) / tmax) ** 2 + ((F[n, S.applied + 1] - th) / tmax) ** 2
                          + (F[n, S.applied + 2] / taumax) ** 2 + (F[n, S.applied + 3] / taumax) ** 2)
        terms = reward_terms(math.sqrt(ex * ex + ez * ez), eth, ev, eff, max(abs(q3), abs(q4)),
                             I[n, SI.reason] != R_NONE)
        r = 0.0
        for i in range(len(REWARD_TERMS)):
            F[n, S.terms + i] = terms[i]
            r += terms[i]
        F[n, S.reward] = r


@_jit
def _step_block(n0, m, F, obs, key, I, C, K, ctl, W, ws):
    """Advance envs n0 .. n0 + m - 1 (m <= LANES) by one control step; their physics runs in the
    lane block W."""
    hi = n0 + m
    _begin_range(n0, hi, F, I, C, K, ctl, W, ws)
    held = MK.HELD_TAU if K[SK.mode] == MODE_IDEAL else K[SK.imap]
    for _ in range(int(C[SC.frame_skip])):  # the command and the wind held over frame_skip RK4 steps
        MK.rk4_lanes(W, C[SC.dt_physics], m, held)
    _end_range(n0, hi, F, key, I, C, W)
    _diag_lanes(W, m, _nominal_params(C), _vec5(C, SC.lam), _vec5(C, SC.kg))
    observe_range(n0, hi, F, key, I, C, obs)
    _reward_range(n0, hi, F, I, C, K, W)


# ---------------------------------------------------------------------------------------- reset
@njit(cache=True, nogil=True)
def reset_rows(F, obs, key, I, C, rows, q0, qd0, P, keys, refp, ref):
    """Start new episodes in the given rows (initial state, plant params, noise keys, reference
    parameters and the reference at t = 0 as (N, 9), row j of the inputs for rows[j]): clear the
    episode state, draw the initial wind, compute the observation, measured state and diagnostics."""
    std = C[SC.wind_std]
    for j in range(rows.shape[0]):
        n = rows[j]
        for i in range(S.P):  # every float column up to the plant parameters: cleared
            F[n, i] = 0.0
        for i in range(5):
            F[n, S.q + i] = q0[j, i]
            F[n, S.qd + i] = qd0[j, i]
            F[n, S.applied + i] = math.nan
        for i in range(3):
            F[n, S.qr + i] = ref[j, i]
            F[n, S.qdr + i] = ref[j, 3 + i]
            F[n, S.qddr + i] = ref[j, 6 + i]
        for i in range(refp.shape[1]):
            F[n, S.refp + i] = refp[j, i]
        for i in range(10):
            F[n, S.P + i] = P[j, i]
        F[n, S.t] = 0.0
        key[n] = keys[j]
        I[n, SI.counter] = 0
        I[n, SI.steps] = 0
        I[n, SI.lag_init] = 1
        I[n, SI.clipped] = 0
        I[n, SI.reason] = R_NONE
        if std > 0:  # initial wind: a stationary OU sample from the counter noise at counter 0
            F[n, S.wind] = std * counter_normal(key[n], 0, STREAM_WIND)
            F[n, S.wind + 1] = std * counter_normal(key[n], 0, STREAM_WIND + 1)
        observe_range(n, n + 1, F, key, I, C, obs)
        F[n, S.total_energy], F[n, S.storage_function] = energy_storage(
            _row5(F, n, S.q), _row5(F, n, S.qd), (F[n, S.qr], F[n, S.qr + 1], F[n, S.qr + 2]),
            (F[n, S.qdr], F[n, S.qdr + 1], F[n, S.qdr + 2]), _row10(F, n, S.P), _nominal_params(C),
            _vec5(C, SC.lam), _vec5(C, SC.kg))
        F[n, S.curvature_violation] = max(abs(F[n, S.q + 3]) - math.pi, abs(F[n, S.q + 4]) - math.pi, 0.0)


# -------------------------------------------------------------------------------------- actions
@_jit
def _check_actions(act, adim):
    """(all actions finite, any action nonzero): read only, so a bad action changes nothing."""
    anyu = False
    for i in range(act.shape[0]):
        for k in range(adim):
            x = act[i, k]
            if not math.isfinite(x):
                return False, False
            if x != 0.0:  # the clipped value is nonzero exactly when x is (x finite)
                anyu = True
    return True, anyu


@_jit
def _clip_actions(lo, hi, act, F, I, adim):
    """Clip the actions of envs lo .. hi - 1 to [-1, 1] into F's action block; flag clipped rows."""
    for i in range(lo, hi):
        clipped = 0
        for k in range(adim):
            x = act[i, k]
            c = -1.0 if x < -1.0 else (1.0 if x > 1.0 else x)
            F[i, S.u + k] = c
            if c != x:
                clipped = 1
        I[i, SI.clipped] = clipped


# ----------------------------------------------------------------------------------- controller
@_jit
def _controller_rows(lo, hi, F, C, has_res, cc, S_mem, S_new, ctl, err):
    """The residual-mode base controller (the controller block driver, fed the measured state) for
    envs lo .. hi - 1: actuators, allocation residual and arm references into ctl, the new memory into
    S_new. A row whose measured state is out of the model (a diverged env stepped once more before its
    autoreset) gets NaN actuators, so that the physics ends it as "non_finite" instead of the step
    raising; its memory stays as it was."""
    cfg, p, lam, kg = CK.config_tuples(cc)
    zero = (0.0, 0.0, 0.0, 0.0, 0.0)
    B, A = CK.controller_work()
    for n0 in range(lo, hi, CK.CTRL_LANES):
        m = min(CK.CTRL_LANES, hi - n0)
        for j in range(m):
            n = n0 + j
            res = zero
            if has_res:
                res = (F[n, S.u] * C[SC.residual_tau_scale], F[n, S.u + 1] * C[SC.residual_tau_scale + 1],
                       F[n, S.u + 2] * C[SC.residual_tau_scale + 2], F[n, S.u + 3] * C[SC.residual_tau_scale + 3],
                       F[n, S.u + 4] * C[SC.residual_tau_scale + 4])
            CK.put_lane_inputs(B, j, _row5(F, n, S.qm), _row5(F, n, S.qdm), _row5(F, n, S.qr), _row5(F, n, S.qdr),
                               _row5(F, n, S.qddr), res, S_mem, n)
        CK.controller_lanes(m, B, A, has_res, True, cfg, p, lam, kg)
        for j in range(m):
            n = n0 + j
            err[n] = CK.ERR_NONE
            if B[CK.lane_index(CK.CB_ERR, j)] != CK.ERR_NONE:
                for k in range(CTL_LEN):
                    ctl[n, k] = math.nan
            else:
                ctl[n, 0], ctl[n, 1], ctl[n, 2], ctl[n, 3] = CK.lane4(B, CK.CB_ACT, j)
                ctl[n, CTL_RESIDUAL] = B[CK.lane_index(CK.CB_INFO + CK.INFO_RESIDUAL, j)]
                ctl[n, CTL_ARM] = B[CK.lane_index(CK.CB_ARM, j)]
                ctl[n, CTL_ARM + 1] = B[CK.lane_index(CK.CB_ARM + 1, j)]
            CK.put_lane_memory(B, j, S_new, n)


@_jit
def _physics_rows(lo, hi, F, obs, key, I, C, K, ctl):
    """Advance envs lo .. hi - 1 by one control step, in blocks of LANES (the controller done)."""
    W = np.empty(LANE_BLOCK)
    ws = np.empty(10)  # the command (5) and, in virtual mode, the requested tau (5)
    for n0 in range(lo, hi, MK.LANES):
        _step_block(n0, min(MK.LANES, hi - n0), F, obs, key, I, C, K, ctl, W, ws)


# --------------------------------------------------------------------------------- entry points
@njit(cache=True, nogil=True)
def step_check_actions(act, K):
    """(all actions finite, a tau residual is added) (see _check_actions)."""
    ok, anyu = _check_actions(act, K[SK.action_dim])
    return ok, anyu and K[SK.res_virtual] != 0


@njit(cache=True, nogil=True)
def step_controller_rows(lo, hi, act, F, I, C, K, has_res, cc, S_mem, S_new, ctl, err):
    """Residual mode, envs lo .. hi - 1: clip the actions, then the base controller."""
    _clip_actions(lo, hi, act, F, I, K[SK.action_dim])
    _controller_rows(lo, hi, F, C, has_res, cc, S_mem, S_new, ctl, err)


@njit(cache=True, nogil=True)
def step_physics_rows(lo, hi, act, F, obs, key, I, C, K, ctl):
    """Envs lo .. hi - 1: clip the actions (unless the controller phase did), then the step."""
    if K[SK.mode] != MODE_RES_ACT:
        _clip_actions(lo, hi, act, F, I, K[SK.action_dim])
    _physics_rows(lo, hi, F, obs, key, I, C, K, ctl)


@njit(cache=True, nogil=True)
def controller_error(err):
    """``STEP_*`` code of the controller phase: the first failed row's, or STEP_OK."""
    for n in range(err.shape[0]):
        if err[n] == CK.ERR_TAU:
            return STEP_CONTROLLER_TAU
        if err[n] == CK.ERR_CURVATURE:
            return STEP_CONTROLLER_CURVATURE
    return STEP_OK


@njit(cache=True, nogil=True)
def step_serial(act, F, obs, key, I, C, K, cc, S_mem, S_new, ctl):
    """One control step of every env (actions act (N, A)) in this thread; returns a ``STEP_*`` code.
    Residual mode: the controller's new memory goes into S_new (the caller swaps it in on STEP_OK)."""
    n = F.shape[0]
    ok, anyu = _check_actions(act, K[SK.action_dim])
    if not ok:
        return STEP_BAD_ACTION
    _clip_actions(0, n, act, F, I, K[SK.action_dim])
    if K[SK.mode] == MODE_RES_ACT:
        err = np.zeros(n, dtype=np.int64)
        _controller_rows(0, n, F, C, anyu and K[SK.res_virtual] != 0, cc, S_mem, S_new, ctl, err)
        code = controller_error(err)
        if code != STEP_OK:
            return code
    _physics_rows(0, n, F, obs, key, I, C, K, ctl)
    return STEP_OK
