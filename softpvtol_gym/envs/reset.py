"""Episode starts in the packed env state: initial state, plant parameters, noise keys, reference and
the first observation and diagnostics of the reset rows."""

from __future__ import annotations

import math

from numba import njit

from .. import model as MK
from ..params import N_PARAMS
from .diagnostics import energy_storage
from .noise import STREAM_WIND, counter_normal
from .observation import observe_range
from .packed_state import SC, SI, S
from .rows import nominal_params, row5, row10, vec5
from .termination import R_NONE


@njit(cache=True, nogil=True)
def reset_rows(state, obs, keys, istate, consts, rows, q0, qd0, P, new_keys, refp, ref, consistent=None):
    """Start new episodes in the given rows (initial state, plant parameters, noise keys, reference
    parameters and the reference at t = 0 as (N, 9), row j of the inputs for rows[j]): clear the
    episode state, draw the initial wind, compute the observation, measured state and diagnostics.
    ``consistent``: None (the default) unless the plant is the consistent model (its energy; the kernel
    compiled for None leaves the consistent model out: :func:`softpvtol_gym.envs.step.kernel_flags`)."""
    std = consts[SC.wind_std]
    for j in range(rows.shape[0]):
        n = rows[j]
        for i in range(S.P):  # every float column up to the plant parameters: cleared
            state[n, i] = 0.0
        for i in range(5):
            state[n, S.q + i] = q0[j, i]
            state[n, S.qd + i] = qd0[j, i]
            state[n, S.applied + i] = math.nan
        for i in range(3):
            state[n, S.qr + i] = ref[j, i]
            state[n, S.qdr + i] = ref[j, 3 + i]
            state[n, S.qddr + i] = ref[j, 6 + i]
        for i in range(refp.shape[1]):
            state[n, S.refp + i] = refp[j, i]
        for i in range(N_PARAMS):
            state[n, S.P + i] = P[j, i]
        state[n, S.t] = 0.0
        keys[n] = new_keys[j]
        istate[n, SI.counter] = 0
        istate[n, SI.steps] = 0
        istate[n, SI.lag_init] = 1
        istate[n, SI.clipped] = 0
        istate[n, SI.reason] = R_NONE
        if std > 0:  # initial wind: a stationary OU sample from the counter noise at counter 0
            state[n, S.wind] = std * counter_normal(keys[n], 0, STREAM_WIND)
            state[n, S.wind + 1] = std * counter_normal(keys[n], 0, STREAM_WIND + 1)
        observe_range(n, n + 1, state, keys, istate, consts, obs)
        state[n, S.total_energy], state[n, S.storage_function] = energy_storage(
            row5(state, n, S.q), row5(state, n, S.qd), (state[n, S.qr], state[n, S.qr + 1], state[n, S.qr + 2]),
            (state[n, S.qdr], state[n, S.qdr + 1], state[n, S.qdr + 2]), row10(state, n, S.P), nominal_params(consts),
            vec5(consts, SC.lam), vec5(consts, SC.kg))
        if consistent is not None:
            kin, pot = MK.consistent_energies(row5(state, n, S.q), row5(state, n, S.qd), row10(state, n, S.P))
            state[n, S.total_energy] = kin + pot
        state[n, S.curvature_violation] = max(abs(state[n, S.q + 3]) - math.pi, abs(state[n, S.q + 4]) - math.pi, 0.0)
