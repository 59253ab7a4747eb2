"""The info dict of a step, built in one place for the single env (Python scalars) and the vector
env (arrays with gymnasium's ``_name`` masks)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit

from .packed_state import SI, S
from .reward import REWARD_TERMS
from .termination import R_NONE, REASONS

#: float diagnostics: (info key, column of the packed state)
FLOAT_ENTRIES = (("total_energy", S.total_energy), ("storage_function", S.storage_function),
                 ("curvature_violation", S.curvature_violation), ("allocation_residual", S.allocation_residual))
#: flags stored as 0.0/1.0
FLAG_ENTRIES = (("thrust_saturated", S.thrust_saturated), ("arm_torque_saturated", S.arm_torque_saturated))
#: (with ``residual_gate``, also "residual_gate": the gate g applied to the step's residual, 0 at a reset)
INFO_KEYS = ("reward_terms", *(k for k, _ in FLOAT_ENTRIES), *(k for k, _ in FLAG_ENTRIES), "action_clipped",
             "termination_reason", "time")
_MASK_KEYS = tuple("_" + k for k in INFO_KEYS)
#: the columns of the packed state that the reward and the info read (copied as one slice, lowest to highest)
_INFO_COLUMNS = (S.reward, *range(S.terms, S.terms + len(REWARD_TERMS)), *(c for _, c in FLOAT_ENTRIES + FLAG_ENTRIES),
                 S.t)
_INFO_LO, _INFO_HI = min(_INFO_COLUMNS), max(_INFO_COLUMNS) + 1
# their places in that slice
_TERMS_LO, _TERMS_HI = S.terms - _INFO_LO, S.terms - _INFO_LO + len(REWARD_TERMS)
_FLOAT_AT = tuple((k, c - _INFO_LO) for k, c in FLOAT_ENTRIES)
_FLAG_AT = tuple((k, c - _INFO_LO) for k, c in FLAG_ENTRIES)
_REWARD_AT, _TIME_AT = S.reward - _INFO_LO, S.t - _INFO_LO
def single_info(sim, reason: str | None) -> dict[str, Any]:
    """The info of entry 0 as Python scalars; ``reason``: the termination/truncation reason or None."""
    return _single_info(sim.F[0, _INFO_LO:_INFO_HI].tolist(), sim.I[0].tolist(), sim, reason)


# The single env builds its info on every step, so _single_info writes it as one dict display (a third of the
# time of filling it key by key): the places of its entries in the info columns, by name (the unpacking fails,
# and the check below raises, if the tables above change: update both)
(_ALIVE, _POSITION, _ATTITUDE, _VELOCITY, _EFFORT, _CURVATURE, _CRASH) = range(_TERMS_LO, _TERMS_HI)
(_ENERGY, _STORAGE, _VIOLATION, _ALLOCATION), (_THRUST, _TORQUE) = (c for _, c in _FLOAT_AT), (c for _, c in _FLAG_AT)
_CLIPPED = SI.clipped
if (REWARD_TERMS != ("alive", "position", "attitude", "velocity", "effort", "curvature", "crash")
        or INFO_KEYS[1:7] != ("total_energy", "storage_function", "curvature_violation", "allocation_residual",
                              "thrust_saturated", "arm_torque_saturated")):  # pragma: no cover
    raise RuntimeError(f"envs.info._single_info is written for other entries: update it for {INFO_KEYS}")


def _single_info(f: list, i: list, sim, reason: str | None) -> dict[str, Any]:
    """:func:`single_info` from entry 0's info columns ``f`` (a list) and its int state ``i`` (a list)."""
    info: dict[str, Any] = {
        "reward_terms": {"alive": f[_ALIVE], "position": f[_POSITION], "attitude": f[_ATTITUDE],
                         "velocity": f[_VELOCITY], "effort": f[_EFFORT], "curvature": f[_CURVATURE],
                         "crash": f[_CRASH]},
        "total_energy": f[_ENERGY], "storage_function": f[_STORAGE], "curvature_violation": f[_VIOLATION],
        "allocation_residual": f[_ALLOCATION], "thrust_saturated": f[_THRUST] > 0.5,
        "arm_torque_saturated": f[_TORQUE] > 0.5, "action_clipped": i[_CLIPPED] != 0, "termination_reason": reason,
        "time": f[_TIME_AT]}
    aids = sim.aids
    if aids is not None:  # the opt-in training aids: their reward terms, the residual gate
        for n, name in enumerate(aids.term_names):
            info["reward_terms"][name] = float(aids.terms[0, n])
        if aids.sigma is not None:
            info["residual_gate"] = float(aids.gate[0])
    return info


def single_outcome(sim, max_steps: int) -> tuple[float, bool, bool, dict[str, Any]]:
    """(reward, terminated, truncated, info) of entry 0 after a step: one conversion of its state to
    Python scalars (the single env's step, on every call)."""
    bound = sim.bound
    f = bound.F0[_INFO_LO:_INFO_HI].tolist()
    i = bound.I0.tolist()
    code = i[SI.reason]
    terminated = code != R_NONE
    truncated = not terminated and i[SI.steps] >= max_steps
    reason = REASONS[code] if terminated else ("time_limit" if truncated else None)
    return f[_REWARD_AT], terminated, truncated, _single_info(f, i, sim, reason)


# ----------------------------------------------------------------------------- vector step
#: the float columns a vector step copies out: the reward, its terms and the diagnostics (one slice of the
#: packed state), then the time
_OUT_LO = S.reward
_OUT_HI = max(S.terms + len(REWARD_TERMS), *(c + 1 for _, c in FLOAT_ENTRIES + FLAG_ENTRIES))
_OUT_TIME = _OUT_HI - _OUT_LO
OUT_WIDTH = _OUT_TIME + 1
_FLAG_COLUMNS = tuple(c for _, c in FLAG_ENTRIES)
# the columns of StepOutputs.f of the reward terms (a slice) and of the float entries, and of its flags
_OUT_TERMS = slice(S.terms - _OUT_LO, S.terms - _OUT_LO + len(REWARD_TERMS))
_OUT_FLOATS = tuple((k, c - _OUT_LO) for k, c in FLOAT_ENTRIES)
_OUT_FLAGS = tuple((k, 1 + i) for i, (k, _) in enumerate(FLAG_ENTRIES))
#: the code of a truncated episode in :attr:`StepOutputs.codes` (after the termination codes)
R_TIME_LIMIT = len(REASONS)
#: the termination_reason of each code: None (R_NONE), the reasons, "time_limit"
_REASON_NAMES = np.array([None, *REASONS[1:], "time_limit"], dtype=object)


@njit(cache=True, nogil=True)
def gather_outputs(lo, hi, state, istate, obs, max_steps, out_obs, out_f, rewards, terminated, truncated, codes,
                   flags):
    """Rows lo .. hi - 1 of a vector step's outputs, copied from the packed state: the observation, the info
    columns (``out_f``, :data:`OUT_WIDTH` wide), the reward, terminated, truncated (the time limit of
    ``max_steps`` steps), the end code (``R_*`` or :data:`R_TIME_LIMIT`) and the flags (action clipped,
    then those of FLAG_ENTRIES)."""
    for n in range(lo, hi):
        for k in range(obs.shape[1]):
            out_obs[n, k] = obs[n, k]
        for k in range(_OUT_TIME):
            out_f[n, k] = state[n, _OUT_LO + k]
        out_f[n, _OUT_TIME] = state[n, S.t]
        rewards[n] = state[n, S.reward]
        code = istate[n, SI.reason]
        term = code != R_NONE
        trunc = not term and istate[n, SI.steps] >= max_steps
        terminated[n] = term
        truncated[n] = trunc
        codes[n] = code if term else (R_TIME_LIMIT if trunc else R_NONE)
        flags[n, 0] = istate[n, SI.clipped] != 0
        for i in range(len(_FLAG_COLUMNS)):
            flags[n, 1 + i] = state[n, _FLAG_COLUMNS[i]] > 0.5


class StepOutputs:
    """What a vector step returns, as fresh arrays of N rows (the caller keeps them; the env never writes
    them again): ``obs`` (N, obs_dim) float32, ``rewards`` (N,), ``terminated``/``truncated`` (N,) bool,
    and the info's columns. :meth:`gather` fills rows lo .. hi - 1 from the packed state (each thread its
    range, right after its physics), :meth:`info` builds the info dict."""

    __slots__ = ("obs", "f", "rewards", "terminated", "truncated", "codes", "flags")

    def __init__(self, n: int, obs_dim: int):
        self.obs = np.empty((n, obs_dim), dtype=np.float32)
        self.f = np.empty((n, OUT_WIDTH))
        self.rewards = np.empty(n)
        self.terminated = np.empty(n, dtype=bool)
        self.truncated = np.empty(n, dtype=bool)
        self.codes = np.empty(n, dtype=np.int64)
        self.flags = np.empty((n, 1 + len(FLAG_ENTRIES)), dtype=bool)

    @classmethod
    def of(cls, sim) -> StepOutputs:
        """The outputs of every entry of ``sim`` now (a copy of its state)."""
        out = cls(sim.n, sim.obs.shape[1])
        out.gather(sim, 0, sim.n)
        return out

    def gather(self, sim, lo: int, hi: int) -> None:
        gather_outputs(lo, hi, sim.F, sim.I, sim.obs, sim.max_steps, self.obs, self.f, self.rewards, self.terminated,
                       self.truncated, self.codes, self.flags)

    def gather_into(self, sim):
        """:meth:`gather` as a function of (lo, hi) (BatchSim.step's ``after``)."""
        return lambda lo, hi: self.gather(sim, lo, hi)

    def info(self, sim) -> dict[str, Any]:
        """The infos of every entry as arrays (columns of the gathered copies) with gymnasium's ``_name``
        masks; ``termination_reason`` an object array (None where the episode goes on)."""
        F, flags, n = self.f.T, self.flags.T, self.f.shape[0]  # (their rows: the columns)
        info: dict[str, Any] = {"reward_terms": dict(zip(REWARD_TERMS, F[_OUT_TERMS]))}
        for k, r in _OUT_FLOATS:
            info[k] = F[r]
        for k, r in _OUT_FLAGS:
            info[k] = flags[r]
        info["action_clipped"] = flags[0]
        codes = self.codes
        if n <= 1024:  # (one take over every entry: faster for small batches, the sparse fill for large ones)
            reasons = _REASON_NAMES[codes]
        else:
            reasons = np.empty(n, dtype=object)  # (None-filled)
            done = np.flatnonzero(codes)
            if done.size:
                reasons[done] = _REASON_NAMES[codes[done]]
        info["termination_reason"] = reasons
        info["time"] = F[_OUT_TIME]
        info.update(dict.fromkeys(_MASK_KEYS, np.ones(n, dtype=bool)))
        aids = sim.aids
        if aids is not None:  # the opt-in training aids: their reward terms, the residual gate
            for i, name in enumerate(aids.term_names):
                info["reward_terms"][name] = aids.terms[:, i].copy()
            if aids.sigma is not None:
                info["residual_gate"] = aids.gate.copy()
                info["_residual_gate"] = np.ones(n, dtype=bool)
        return info


def batch_info(sim) -> dict[str, Any]:
    """The infos of every entry as arrays (:meth:`StepOutputs.info` of a copy of the state now)."""
    return StepOutputs.of(sim).info(sim)
