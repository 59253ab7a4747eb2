"""The compiled env step: command (action scaling, allocation, saturation, lag), physics (RK4 with the
command held), clock, wind, termination, observation and reward of a range of envs.

The physics of up to ``MK.LANES`` envs at a time runs in a lane block (structure of arrays, layout
:data:`~softpvtol_gym.envs.packed_state.LANES`) that LLVM turns into SIMD code. The residual mode's base
controller is the controller block driver of :mod:`softpvtol_gym.control.kernels`, fed the
measured state. Entry points: :func:`serial_step_kernel` (one call, small batches) and, for large batches
split over threads by BatchSim, :func:`step_check_actions`, then :func:`step_residual_rows` (the residual
mode: controller and physics of a range in one pass) or :func:`step_physics_rows`. An error code changes
nothing.

Its parts, by job: the command (:mod:`.command`: actions checked, clipped and scaled, allocation), the
diagnostics (:mod:`.diagnostics`: energy and storage), the episode starts (:mod:`.reset`), and row and
lane access to the packed state (:mod:`.rows`); observation, reward and termination have their modules.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .. import model as MK
from ..control import kernels as CK
from ..references import REF_CONSTANT, REF_CUSTOM, reference_row
from .actions import MODE_IDEAL, MODE_RES_ACT, MODE_VIRTUAL
from .command import check_actions, clip_actions, command
from .diagnostics import consistent_energy_lanes, diag_lanes, diag_lanes_partial
from .noise import STREAM_WIND, counter_normal
from .observation import observe_range, wrap
from .packed_state import LANES, SC, SI, SK, SL, S
from .reward import REWARD_TERMS, reward_terms
from .rows import lane5, lane_put, nominal_params, row5, row10, vec5
from .termination import R_NONE, R_NONFINITE, termination_reason

_jit = njit(cache=True, fastmath=False, nogil=True, error_model="numpy")

#: size of the physics lane block
LANE_BLOCK = LANES.size * MK.LANES
#: step kernel return codes
STEP_OK, STEP_BAD_ACTION = 0, 1


# ------------------------------------------------------------------------------------ reference
@_jit
def _put_reference(state, n, code, t):
    """The compiled reference ``code`` at time t into row n's qr, qdr, qddr (body entries)."""
    pos, vel, acc = reference_row(code, t, state, n, S.refp)
    for i in range(3):
        state[n, S.qr + i] = pos[i]
        state[n, S.qdr + i] = vel[i]
        state[n, S.qddr + i] = acc[i]


@_jit
def _begin_range(lo, hi, state, istate, consts, codes, ctl, lanes, cmd, virtual):
    """Clock, reference and applied command (action scaling, allocation, saturation, actuator lag) of
    envs lo .. hi - 1; their state, command and wind into the lanes of lanes."""
    mode, alloc, imap, ref = codes[SK.mode], codes[SK.alloc], codes[SK.imap], codes[SK.ref]
    tmax, taumax = consts[SC.thrust_max], consts[SC.arm_torque_max]
    lag_on = consts[SC.lag_on] > 0.0
    na = 5 if mode == MODE_IDEAL else 4
    for n in range(lo, hi):
        istate[n, SI.steps] += 1
        t = istate[n, SI.steps] * consts[SC.dt_control]
        state[n, S.t] = t
        if ref == REF_CUSTOM:  # set by BatchSim before the step
            for i in range(3):
                state[n, S.qr + i] = state[n, S.qr_custom + i]
                state[n, S.qdr + i] = state[n, S.qr_custom + 3 + i]
                state[n, S.qddr + i] = state[n, S.qr_custom + 6 + i]
        elif ref != REF_CONSTANT:
            _put_reference(state, n, ref, t)
        state[n, S.allocation_residual] = 0.0
        state[n, S.arm_reference] = 0.0
        state[n, S.arm_reference + 1] = 0.0
        thrust_sat = command(state, n, consts, mode, alloc, imap, ctl, cmd, virtual)
        torque_sat = 0.0
        if mode != MODE_IDEAL:
            for i in range(2):
                if cmd[i] < 0.0:
                    cmd[i] = 0.0
                    thrust_sat = 1.0
                elif cmd[i] > tmax:
                    cmd[i] = tmax
                    thrust_sat = 1.0
            for i in range(2, 4):
                if cmd[i] < -taumax:
                    cmd[i] = -taumax
                    torque_sat = 1.0
                elif cmd[i] > taumax:
                    cmd[i] = taumax
                    torque_sat = 1.0
        state[n, S.thrust_saturated] = thrust_sat
        state[n, S.arm_torque_saturated] = torque_sat
        # first-order actuator lag (starts at the first command of the episode)
        if lag_on:
            if istate[n, SI.lag_init] != 0:
                for i in range(na):
                    state[n, S.lag + i] = cmd[i]
                istate[n, SI.lag_init] = 0
            else:
                al = consts[SC.lag_a]
                for i in range(na):
                    state[n, S.lag + i] = state[n, S.lag + i] + al * (cmd[i] - state[n, S.lag + i])
            for i in range(na):
                cmd[i] = state[n, S.lag + i]
        for i in range(5):
            state[n, S.applied + i] = cmd[i] if i < na else math.nan
        if mode == MODE_RES_ACT:
            state[n, S.allocation_residual] = ctl[n, CK.OUT_INFO + CK.INFO_RESIDUAL]
            state[n, S.arm_reference] = ctl[n, CK.OUT_ARM]
            state[n, S.arm_reference + 1] = ctl[n, CK.OUT_ARM + 1]
        j = n - lo
        lane_put(lanes, SL.q, j, row5(state, n, S.q))
        lane_put(lanes, SL.qd, j, row5(state, n, S.qd))
        # the held command: actuators (cmd[4] = 0), or tau in ideal mode
        lane_put(lanes, SL.u, j, (cmd[0], cmd[1], cmd[2], cmd[3], cmd[4]))
        lane_put(lanes, SL.ext, j, (state[n, S.wind], state[n, S.wind + 1]))  # (0 unless the wind is on)
        lane_put(lanes, SL.p, j, row10(state, n, S.P))


@_jit
def _end_range(lo, hi, state, keys, istate, consts, lanes):
    """Noise counter, wind and termination of envs lo .. hi - 1; the final state from lanes back into state
    (the last finite one if it diverged, also into lanes); the body reference into lanes for the diagnostics."""
    wind_on = consts[SC.wind_on] > 0.0
    for n in range(lo, hi):
        j = n - lo
        istate[n, SI.counter] += 1
        counter = istate[n, SI.counter]
        if wind_on:  # Ornstein-Uhlenbeck update, after the step it was held over
            wa, wb = consts[SC.wind_a], consts[SC.wind_b]
            state[n, S.wind] = wa * state[n, S.wind] + wb * counter_normal(keys[n], counter, STREAM_WIND)
            state[n, S.wind + 1] = wa * state[n, S.wind + 1] + wb * counter_normal(keys[n], counter, STREAM_WIND + 1)
        q = lane5(lanes, SL.q, j)
        qd = lane5(lanes, SL.qd, j)
        finite = True
        for i in range(5):
            if not (math.isfinite(q[i]) and math.isfinite(qd[i])):
                finite = False
        if finite:
            for i in range(5):
                state[n, S.q + i] = q[i]
                state[n, S.qd + i] = qd[i]
            istate[n, SI.reason] = termination_reason(q, qd)
        else:  # keep the last finite state: observation and info stay finite
            istate[n, SI.reason] = R_NONFINITE
            lane_put(lanes, SL.q, j, row5(state, n, S.q))
            lane_put(lanes, SL.qd, j, row5(state, n, S.qd))
        lane_put(lanes, SL.qr, j, (state[n, S.qr], state[n, S.qr + 1], state[n, S.qr + 2]))
        lane_put(lanes, SL.qdr, j, (state[n, S.qdr], state[n, S.qdr + 1], state[n, S.qdr + 2]))


@_jit
def _reward_range(lo, hi, state, istate, consts, codes, lanes):
    """Diagnostics (energy and storage from the lanes of lanes) and reward terms of envs lo .. hi - 1
    (true state, not the noisy measurement)."""
    L = MK.LANES
    ideal = codes[SK.mode] == MODE_IDEAL
    tmax, taumax = consts[SC.thrust_max], consts[SC.arm_torque_max]
    for n in range(lo, hi):
        j = n - lo
        q3, q4 = state[n, S.q + 3], state[n, S.q + 4]
        state[n, S.total_energy] = lanes[SL.energy * L + j]
        state[n, S.storage_function] = lanes[SL.storage * L + j]
        state[n, S.curvature_violation] = max(abs(q3) - math.pi, abs(q4) - math.pi, 0.0)
        ex, ez = state[n, S.q] - state[n, S.qr], state[n, S.q + 1] - state[n, S.qr + 1]
        eth = wrap(state[n, S.q + 2] - state[n, S.qr + 2])
        ev = math.sqrt((state[n, S.qd] - state[n, S.qdr]) ** 2 + (state[n, S.qd + 1] - state[n, S.qdr + 1]) ** 2
                       + (state[n, S.qd + 2] - state[n, S.qdr + 2]) ** 2)
        if ideal:
            eff = 0.0
            for i in range(5):
                eff += ((state[n, S.applied + i] - consts[SC.virtual_offset + i]) / consts[SC.virtual_scale + i]) ** 2
            eff /= 5.0
        else:
            th = consts[SC.hover_thrust]
            eff = 0.25 * (((state[n, S.applied] - th) / tmax) ** 2 + ((state[n, S.applied + 1] - th) / tmax) ** 2
                          + (state[n, S.applied + 2] / taumax) ** 2 + (state[n, S.applied + 3] / taumax) ** 2)
        terms = reward_terms(math.sqrt(ex * ex + ez * ez), eth, ev, eff, max(abs(q3), abs(q4)),
                             istate[n, SI.reason] != R_NONE)
        r = 0.0
        for i in range(len(REWARD_TERMS)):
            state[n, S.terms + i] = terms[i]
            r += terms[i]
        state[n, S.reward] = r


@_jit
def _consistent_physics(lanes, m, consts, codes):
    """The plant step of the first m lanes under the consistent model (``model="consistent"``, the
    "model_gap" tier): frame_skip RK4 steps of :func:`MK.rk4_lanes_consistent`, lane by lane. The held
    actuators act through the consistent model's own input map (virtual work at the rotated tips,
    ``INPUT_MAP_EXACT``), whatever map the controllers assume (``input_map``); ideal mode holds tau."""
    held = MK.HELD_TAU if codes[SK.mode] == MODE_IDEAL else MK.INPUT_MAP_EXACT
    for _ in range(int(consts[SC.frame_skip])):
        MK.rk4_lanes_consistent(lanes, consts[SC.dt_physics], m, held)



@_jit
def _step_block(n0, m, state, obs, keys, istate, consts, codes, ctl, lanes, cmd, virtual, consistent):
    """Advance envs n0 .. n0 + m - 1 (m <= LANES) by one control step; their physics runs in the
    lane block lanes."""
    hi = n0 + m
    _begin_range(n0, hi, state, istate, consts, codes, ctl, lanes, cmd, virtual)
    if consistent is not None:
        _consistent_physics(lanes, m, consts, codes)
    else:
        held = MK.HELD_TAU if codes[SK.mode] == MODE_IDEAL else codes[SK.imap]
        for _ in range(int(consts[SC.frame_skip])):  # the command and the wind held over frame_skip RK4 steps
            MK.rk4_lanes(lanes, consts[SC.dt_physics], m, held)
    _end_range(n0, hi, state, keys, istate, consts, lanes)
    diag_lanes(lanes, m, nominal_params(consts), vec5(consts, SC.lam), vec5(consts, SC.kg))
    if consistent is not None:
        consistent_energy_lanes(lanes, m)
    observe_range(n0, hi, state, keys, istate, consts, obs)
    _reward_range(n0, hi, state, istate, consts, codes, lanes)


@_jit
def _step_block_partial(n0, m, state, obs, keys, istate, consts, codes, ctl, lanes, cmd, virtual, consistent):
    """:func:`_step_block` for m < LANES through the lane-by-lane paths only (what a batch of fewer
    than LANES envs needs: the same functions per lane, without the SIMD copies to compile)."""
    hi = n0 + m
    _begin_range(n0, hi, state, istate, consts, codes, ctl, lanes, cmd, virtual)
    if consistent is not None:
        _consistent_physics(lanes, m, consts, codes)
    else:
        held = MK.HELD_TAU if codes[SK.mode] == MODE_IDEAL else codes[SK.imap]
        for _ in range(int(consts[SC.frame_skip])):
            MK.rk4_lanes_partial(lanes, consts[SC.dt_physics], m, held)
    _end_range(n0, hi, state, keys, istate, consts, lanes)
    diag_lanes_partial(lanes, m, nominal_params(consts), vec5(consts, SC.lam), vec5(consts, SC.kg))
    if consistent is not None:
        consistent_energy_lanes(lanes, m)
    observe_range(n0, hi, state, keys, istate, consts, obs)
    _reward_range(n0, hi, state, istate, consts, codes, lanes)


# ----------------------------------------------------------------------------------- controller
@_jit
def _controller_rows(lo, hi, state, consts, has_res, cc, S_mem, S_new, ctl_in, ctl, ctl_err):
    """The residual mode's base controller for envs lo .. hi - 1: its inputs (measured state,
    reference, tau residual) into ctl_in, then the controller block driver (outputs into ctl (N, OUT_LEN),
    the new memory into S_new). A row whose measured state is out of the model (a diverged env stepped
    once more before its autoreset) gets NaN outputs, so that the physics ends it as "non_finite"
    instead of the step raising; its memory stays as it was."""
    for n in range(lo, hi):
        for i in range(5):
            ctl_in[n, CK.IN_Q + i] = state[n, S.qm + i]
            ctl_in[n, CK.IN_QD + i] = state[n, S.qdm + i]
            ctl_in[n, CK.IN_QR + i] = state[n, S.qr + i]
            ctl_in[n, CK.IN_QDR + i] = state[n, S.qdr + i]
            ctl_in[n, CK.IN_QDDR + i] = state[n, S.qddr + i]
            ctl_in[n, CK.IN_RES + i] = state[n, S.u + i] * consts[SC.residual_tau_scale + i] if has_res else 0.0
    CK.controller_rows(lo, hi, ctl_in, has_res, True, cc, S_mem, S_new, ctl, ctl_err)
    for n in range(lo, hi):
        if ctl_err[n] != CK.ERR_NONE:
            for k in range(CK.OUT_LEN):
                ctl[n, k] = math.nan


@_jit
def _physics_rows(lo, hi, state, obs, keys, istate, consts, codes, ctl, virtual, consistent):
    """Advance envs lo .. hi - 1 by one control step, in blocks of LANES (the controller done)."""
    lanes = np.empty(LANE_BLOCK)
    cmd = np.empty(10)  # the command (5) and, in virtual mode, the requested tau (5)
    for n0 in range(lo, hi, MK.LANES):
        _step_block(n0, min(MK.LANES, hi - n0), state, obs, keys, istate, consts, codes, ctl, lanes, cmd, virtual,
                    consistent)


@_jit
def _physics_rows_small(lo, hi, state, obs, keys, istate, consts, codes, ctl, virtual, consistent):
    """:func:`_physics_rows` for hi - lo < LANES envs (one partial block)."""
    lanes = np.empty(LANE_BLOCK)
    cmd = np.empty(10)
    _step_block_partial(lo, hi - lo, state, obs, keys, istate, consts, codes, ctl, lanes, cmd, virtual, consistent)


# --------------------------------------------------------------------------------- entry points
@njit(cache=True, nogil=True)
def step_check_actions(act, codes):
    """(all actions finite, a tau residual is added) (see check_actions)."""
    ok, anyu = check_actions(act, codes[SK.action_dim])
    return ok, anyu and codes[SK.res_virtual] != 0


@njit(cache=True, nogil=True)
def step_residual_rows(lo, hi, act, state, obs, keys, istate, consts, codes, has_res, cc, S_mem, S_new, ctl_in, ctl,
                       ctl_err, virtual=None, consistent=None):
    """Residual mode, envs lo .. hi - 1, in one pass: clip the actions, the base controller, then the step
    (a thread's rows stay in its cache between the two)."""
    clip_actions(lo, hi, act, state, istate, codes[SK.action_dim])
    _controller_rows(lo, hi, state, consts, has_res, cc, S_mem, S_new, ctl_in, ctl, ctl_err)
    _physics_rows(lo, hi, state, obs, keys, istate, consts, codes, ctl, virtual, consistent)


@njit(cache=True, nogil=True)
def step_physics_rows(lo, hi, act, state, obs, keys, istate, consts, codes, ctl, virtual=None, consistent=None):
    """Action modes without the base controller, envs lo .. hi - 1: clip the actions, then the step."""
    clip_actions(lo, hi, act, state, istate, codes[SK.action_dim])
    _physics_rows(lo, hi, state, obs, keys, istate, consts, codes, ctl, virtual, consistent)


def kernel_flags(consts: np.ndarray, codes: np.ndarray) -> tuple:
    """The step kernels' trailing arguments (virtual, consistent) for an env's constants and codes: 1 where
    the env is in virtual mode (the allocation), resp. steps the consistent plant (model_gap), else None;
    () when both are None (the defaults: two arguments fewer for numba's dispatch to type)."""
    flags = (1 if codes[SK.mode] == MODE_VIRTUAL else None, 1 if consts[SC.consistent_plant] > 0.0 else None)
    return () if flags == (None, None) else flags


# One control step of every env (actions act (N, A)) in this thread; returns a ``STEP_*`` code. Four
# entry points, so that a process compiles only what its env needs (numba compiles a kernel with
# everything it calls, used or not): with or without the residual mode's base controller (its
# constants, memory and work arrays: its new memory goes into S_new; the caller swaps it in on
# STEP_OK), for any N or for N < LANES (lane-by-lane paths only). Same functions per env in each: the
# results do not depend on the choice. (Fewer arguments without the controller: numba's dispatch of a
# call costs about 50 ns per argument, a share of a single env's step.) The last two arguments,
# ``virtual`` and ``consistent`` (:func:`kernel_flags`), are None (the default) unless the env is in virtual
# mode, resp. steps the consistent plant: numba prunes a branch on a None argument before typing it, so a
# kernel compiled for None never compiles the virtual mode's allocation, resp. the consistent model (a cold
# first step compiles what its env uses).
@njit(cache=True, nogil=True)
def _check_and_clip(act, state, istate, codes):
    """The serial entry points' start: (all actions finite, a tau residual is added), the actions clipped
    where they are all finite (see check_actions, clip_actions)."""
    ok, has_res = step_check_actions(act, codes)
    if ok:
        clip_actions(0, state.shape[0], act, state, istate, codes[SK.action_dim])
    return ok, has_res


@njit(cache=True, nogil=True)
def step_serial(act, state, obs, keys, istate, consts, codes, ctl, virtual=None, consistent=None):
    """Action modes without the base controller, any N."""
    if not _check_and_clip(act, state, istate, codes)[0]:
        return STEP_BAD_ACTION
    _physics_rows(0, state.shape[0], state, obs, keys, istate, consts, codes, ctl, virtual, consistent)
    return STEP_OK


@njit(cache=True, nogil=True)
def step_serial_residual(act, state, obs, keys, istate, consts, codes, cc, S_mem, S_new, ctl_in, ctl, ctl_err,
                         virtual=None, consistent=None):
    """Residual mode (the base controller, then the physics), any N."""
    ok, has_res = _check_and_clip(act, state, istate, codes)
    if not ok:
        return STEP_BAD_ACTION
    _controller_rows(0, state.shape[0], state, consts, has_res, cc, S_mem, S_new, ctl_in, ctl, ctl_err)
    _physics_rows(0, state.shape[0], state, obs, keys, istate, consts, codes, ctl, virtual, consistent)
    return STEP_OK


@njit(cache=True, nogil=True)
def step_serial_small(act, state, obs, keys, istate, consts, codes, ctl, virtual=None, consistent=None):
    """:func:`step_serial` for N < LANES."""
    if not _check_and_clip(act, state, istate, codes)[0]:
        return STEP_BAD_ACTION
    _physics_rows_small(0, state.shape[0], state, obs, keys, istate, consts, codes, ctl, virtual, consistent)
    return STEP_OK


@njit(cache=True, nogil=True)
def step_serial_small_residual(act, state, obs, keys, istate, consts, codes, cc, S_mem, S_new, ctl_in, ctl,
                               ctl_err, virtual=None, consistent=None):
    """:func:`step_serial_residual` for N < LANES."""
    ok, has_res = _check_and_clip(act, state, istate, codes)
    if not ok:
        return STEP_BAD_ACTION
    _controller_rows(0, state.shape[0], state, consts, has_res, cc, S_mem, S_new, ctl_in, ctl, ctl_err)
    _physics_rows_small(0, state.shape[0], state, obs, keys, istate, consts, codes, ctl, virtual, consistent)
    return STEP_OK


def serial_step_kernel(n: int, residual: bool):
    """The entry point above for N = n envs, with (residual mode) or without the base controller."""
    if n < MK.LANES:
        return step_serial_small_residual if residual else step_serial_small
    return step_serial_residual if residual else step_serial
