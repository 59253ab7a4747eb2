"""The command of the env step: the actions checked and clipped, then scaled to the actuators of
each action mode (``MODE_*``), through the control allocation in virtual mode."""

from __future__ import annotations

import math

from .. import model as MK
from ..control import kernels as CK
from ..model.jit import jit
from .actions import MODE_ACT, MODE_IDEAL, MODE_RES_ACT
from .packed_state import SC, SI, S
from .rows import nominal_params, row5


@jit
def check_actions(act, adim):
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


@jit
def clip_actions(lo, hi, act, state, istate, adim):
    """Clip the actions of envs lo .. hi - 1 to [-1, 1] into state's action block; flag clipped rows."""
    for i in range(lo, hi):
        clipped = 0
        for k in range(adim):
            x = act[i, k]
            c = -1.0 if x < -1.0 else (1.0 if x > 1.0 else x)
            state[i, S.u + k] = c
            if c != x:
                clipped = 1
        istate[i, SI.clipped] = clipped


@jit
def _virtual_allocation(state, n, consts, alloc, imap, cmd):
    """Virtual mode: thrusts from the body rows of tau (cmd[5:10]) by the allocation, arm rows as
    generalized forces; the command into cmd[0:4], diagnostics into state. Returns the thrust flag."""
    pnom = nominal_params(consts)
    thrust_sat = 0.0
    if alloc == CK.ALLOC_PAPER:
        out, info = CK.allocate_paper(cmd[5], cmd[6], cmd[7], state[n, S.q + 2], pnom, 0.0, 0.0, False)
    else:
        out, info = CK.allocate_exact(cmd[5], cmd[6], cmd[7], state[n, S.q + 2], pnom, imap, 0.0, 0.0, False, math.pi)
    Tl, Tr = out[0], out[1]
    if not (math.isfinite(Tl) and math.isfinite(Tr)):
        Tl, Tr = 0.0, 0.0
        thrust_sat = 1.0
    cmd[0], cmd[1] = Tl, Tr
    state[n, S.allocation_residual] = info[CK.INFO_RESIDUAL] if math.isfinite(info[CK.INFO_RESIDUAL]) else 1.0e300
    state[n, S.arm_reference] = out[2]
    state[n, S.arm_reference + 1] = out[3]
    cmd[2], cmd[3] = cmd[8], cmd[9]
    if imap == MK.INPUT_MAP_EXACT:  # the arm rows get the requested generalized force
        gf = MK.generalized_forces(row5(state, n, S.q), (Tl, Tr, 0.0, 0.0), pnom, imap)
        cmd[2] -= gf[3]
        cmd[3] -= gf[4]
    return thrust_sat


@jit
def command(state, n, consts, mode, alloc, imap, ctl, cmd, virtual):
    """The command of env n before saturation into cmd[0:5] (actuators (4), or tau (5) in ideal mode);
    returns the thrust-saturation flag of the allocation. One branch per action mode (``MODE_*``).

    ``virtual``: None in a kernel compiled for the other modes (numba prunes the allocation's branch on a
    None argument, so that kernel never compiles the allocation), 1 for virtual mode."""
    for i in range(5):
        cmd[i] = 0.0
    tmax, taumax = consts[SC.thrust_max], consts[SC.arm_torque_max]
    if mode == MODE_ACT:
        cmd[0] = tmax * 0.5 * (state[n, S.u] + 1.0)
        cmd[1] = tmax * 0.5 * (state[n, S.u + 1] + 1.0)
        cmd[2] = taumax * state[n, S.u + 2]
        cmd[3] = taumax * state[n, S.u + 3]
        return 0.0
    if mode == MODE_RES_ACT:
        clip_base = consts[SC.residual_base_saturated] > 0.5
        for i in range(4):
            base = ctl[n, CK.OUT_ACT + i]
            if clip_base and math.isfinite(base):  # a non-finite command stays one: the step ends the episode
                lo, hi = (0.0, tmax) if i < 2 else (-taumax, taumax)
                base = min(max(base, lo), hi)
            cmd[i] = base + consts[SC.residual_actuator_scale + i] * state[n, S.u + i]
        return 0.0
    for i in range(5):
        cmd[5 + i] = consts[SC.virtual_offset + i] + consts[SC.virtual_scale + i] * state[n, S.u + i]
    if mode == MODE_IDEAL:
        for i in range(5):
            cmd[i] = cmd[5 + i]
        return 0.0
    if virtual is None:  # not reached: such a kernel steps no virtual-mode env (BatchSim picks it by mode)
        return math.nan
    return _virtual_allocation(state, n, consts, alloc, imap, cmd)
