"""The env's opt-in training aids, as batched kernels of the packed state that BatchSim runs
around the step kernel for the single and the vector env alike (row by row: N = 1 and N > 1 give the
same bits):

* the residual gate (``residual_gate``): before the step, the clipped residual action of each row times
  g = 1 - exp(-rho^2 / sigma^2), rho the measured tracking error the policy observed;
* after the step, the error integrals (``observe_error_integral``: observation entries 18-20) and the
  extra reward terms "precision" (``precision_reward_weight``) and "action_rate" (``action_rate_penalty``),
  added to the reward of the step kernel.

Their memory (the integrals, the previous action) lives in BatchSim's arrays and is cleared with the episode
(:func:`reset_aids`). With every aid off (the defaults) none of this runs: the observation, the reward and
the dynamics are the step kernel's, bit for bit.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .observation import N_ERROR_INTEGRALS, OBS_DIM, wrap
from .packed_state import S

_jit = njit(cache=True, fastmath=False, nogil=True, error_model="numpy")


@_jit
def _clip1(x):
    return -1.0 if x < -1.0 else (1.0 if x > 1.0 else x)


@_jit
def gate_value(state, n, sigma):
    """g = 1 - exp(-rho^2 / sigma^2) of row n (exactly 0 at zero error, ~ rho^2 / sigma^2 near it), rho^2 =
    e_x^2 + e_z^2 + e_theta^2 + edot_x^2 + edot_z^2 + edot_theta^2 of the measured state (qm, qdm) against the
    reference (qr, qdr) of the last observation, e_theta wrapped to [-pi, pi)."""
    ex = state[n, S.qm] - state[n, S.qr]
    ez = state[n, S.qm + 1] - state[n, S.qr + 1]
    eth = wrap(state[n, S.qm + 2] - state[n, S.qr + 2])
    vx = state[n, S.qdm] - state[n, S.qdr]
    vz = state[n, S.qdm + 1] - state[n, S.qdr + 1]
    vth = state[n, S.qdm + 2] - state[n, S.qdr + 2]
    rho2 = (ex * ex + ez * ez + eth * eth + vx * vx + vz * vz + vth * vth) / (sigma * sigma)
    return -math.expm1(-rho2)


@_jit
def gate_actions(act, state, sigma, out, gate, clipped):
    """``out[n] = g_n clip(act[n], -1, 1)`` (g_n: :func:`gate_value`) into out (N, A); g_n into gate (N,),
    whether act[n] was out of range into clipped (N,). A value that is not finite is passed on as it is, so
    that the step refuses it (nothing is written to the state here)."""
    for n in range(act.shape[0]):
        g = gate_value(state, n, sigma)
        gate[n] = g
        flag = 0
        for k in range(act.shape[1]):
            x = act[n, k]
            if math.isfinite(x):
                c = _clip1(x)
                if c != x:
                    flag = 1
                out[n, k] = g * c
            else:
                out[n, k] = x
        clipped[n] = flag


@_jit
def after_step(act, state, obs, integrals, prev, has_prev, terms, dt, limit, elimit, integrate, w_prec, prec_scale,
               w_rate):
    """After a step of every row: the error integrals (``integrate``: += dt x the measured errors of
    observation entries 0-2, each clipped to +/-elimit first, the integral to +/-limit, written to obs[:, 18:21]);
    the precision term w_prec exp(-|(e_x, e_z)| / prec_scale) of the true state (w_prec > 0) and the action-rate term
    -w_rate mean((clip(a_t) - clip(a_(t-1)))^2) (w_rate > 0; 0 at an episode's first step), in that order
    into terms (N, 2) and added to the step's reward. ``act`` (N, A): the actions as the policy gave them
    (finite: the step checked them)."""
    na = act.shape[1]
    for n in range(act.shape[0]):
        if integrate:
            e0 = state[n, S.qm] - state[n, S.qr]
            e1 = state[n, S.qm + 1] - state[n, S.qr + 1]
            e2 = wrap(state[n, S.qm + 2] - state[n, S.qr + 2])
            for i, e in enumerate((e0, e1, e2)):
                e = -elimit if e < -elimit else (elimit if e > elimit else e)
                v = integrals[n, i] + dt * e
                v = -limit if v < -limit else (limit if v > limit else v)
                integrals[n, i] = v
                obs[n, OBS_DIM + i] = v
        k = 0
        if w_prec > 0.0:
            ex = state[n, S.q] - state[n, S.qr]
            ez = state[n, S.q + 1] - state[n, S.qr + 1]
            p = w_prec * math.exp(-math.sqrt(ex * ex + ez * ez) / prec_scale)
            terms[n, k] = p
            state[n, S.reward] += p
            k += 1
        if w_rate > 0.0:
            m = 0.0
            for j in range(na):
                c = _clip1(act[n, j])
                if has_prev[n] != 0:
                    d = c - prev[n, j]
                    m += d * d
                prev[n, j] = c
            has_prev[n] = 1
            r = -w_rate * (m / na)
            terms[n, k] = r
            state[n, S.reward] += r


class TrainingAids:
    """The aids' memory for N rows and their calls (made by BatchSim): ``integrals`` (N, 3) [m s, rad s],
    ``prev_action`` (N, A) (the last clipped action), ``has_prev`` (N,), ``terms`` (N, 2) (the extra reward
    terms of the last step, names ``cfg.extra_reward_terms``), ``gate`` (N,) (the last residual gate)."""

    def __init__(self, cfg, n: int, action_dim: int):
        self.cfg = cfg
        self.integrate = cfg.observe_error_integral
        self.sigma = cfg.residual_gate
        self.w_prec = float(cfg.precision_reward_weight)
        self.w_rate = float(cfg.action_rate_penalty)
        self.term_names = cfg.extra_reward_terms
        self.integrals = np.zeros((n, N_ERROR_INTEGRALS))
        self.prev_action = np.zeros((n, action_dim))
        self.has_prev = np.zeros(n, dtype=np.int64)
        self.terms = np.zeros((n, 2))
        self.gate = np.zeros(n)
        self._gated = np.zeros((n, action_dim))  # (scratch of the gate; zeros: a checkpoint compares them)
        self._new_gate = np.zeros(n)
        self._clipped = np.zeros(n, dtype=np.int64)

    def reset(self, rows: np.ndarray, obs: np.ndarray) -> None:
        """New episodes in ``rows``: the integrals (and their observation entries), the previous action, the
        terms and the gate (no step yet) cleared."""
        self.integrals[rows] = 0.0
        self.prev_action[rows] = 0.0
        self.has_prev[rows] = 0
        self.terms[rows] = 0.0
        self.gate[rows] = 0.0
        if self.integrate:
            obs[rows, OBS_DIM:] = 0.0

    def gated(self, act: np.ndarray, state: np.ndarray) -> np.ndarray:
        """The actions the step kernel gets: ``act`` (N, A) gated (residual_gate) or as they are."""
        if self.sigma is None:
            return act
        gate_actions(act, state, self.sigma, self._gated, self._new_gate, self._clipped)
        return self._gated

    def after_step(self, act: np.ndarray, state: np.ndarray, istate_clipped: np.ndarray, obs: np.ndarray,
                   dt: float) -> None:
        """Once the step has succeeded: the gate's records (the action_clipped flags of the actions as given),
        then :func:`after_step`."""
        if self.sigma is not None:
            self.gate[:] = self._new_gate
            istate_clipped[:] = self._clipped
        if self.integrate or self.term_names:
            elimit = self.cfg.error_integral_error_limit
            after_step(act, state, obs, self.integrals, self.prev_action, self.has_prev, self.terms, dt,
                       float(self.cfg.error_integral_limit), math.inf if elimit is None else float(elimit),
                       self.integrate, self.w_prec, float(self.cfg.precision_reward_scale), self.w_rate)
