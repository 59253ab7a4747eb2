"""The info dict of a step, built in one place for the single env (Python scalars) and the vector
env (arrays with gymnasium's ``_name`` masks)."""

from __future__ import annotations

from typing import Any

import numpy as np

from .layout import SI, S
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
#: the vector env's info copies less: the reward terms and the diagnostics (one slice), and the time
_BATCH_LO = min(S.terms, *(c for _, c in FLOAT_ENTRIES + FLAG_ENTRIES))
_BATCH_HI = max(S.terms + len(REWARD_TERMS), *(c + 1 for _, c in FLOAT_ENTRIES + FLAG_ENTRIES))


def single_info(sim, reason: str | None) -> dict[str, Any]:
    """The info of entry 0 as Python scalars; ``reason``: the termination/truncation reason or None."""
    return _single_info(sim.F[0, _INFO_LO:_INFO_HI].tolist(), sim.I[0].tolist(), sim, reason)


def _single_info(f: list, i: list, sim, reason: str | None) -> dict[str, Any]:
    """:func:`single_info` from entry 0's info columns ``f`` (a list) and its int state ``i`` (a list)."""
    info: dict[str, Any] = {"reward_terms": dict(zip(REWARD_TERMS, f[_TERMS_LO:_TERMS_HI]))}
    for k, c in _FLOAT_AT:
        info[k] = f[c]
    for k, c in _FLAG_AT:
        info[k] = f[c] > 0.5
    info["action_clipped"] = i[SI.clipped] != 0
    info["termination_reason"] = reason
    info["time"] = f[_TIME_AT]
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
    f = sim.F[0, _INFO_LO:_INFO_HI].tolist()
    i = sim.I[0].tolist()
    code = i[SI.reason]
    terminated = code != R_NONE
    truncated = not terminated and i[SI.steps] >= max_steps
    reason = REASONS[code] if terminated else ("time_limit" if truncated else None)
    return f[_REWARD_AT], terminated, truncated, _single_info(f, i, sim, reason)


def batch_info(sim, reasons: np.ndarray | None) -> dict[str, Any]:
    """The infos of every entry as arrays (one private copy of the state; each array a column of it);
    ``reasons``: an object array of reasons (None where not done), or None when no entry is done."""
    F = sim.F[:, _BATCH_LO:_BATCH_HI].copy()  # the columns the info reads (not the whole state: a copy per step)
    n = F.shape[0]
    info: dict[str, Any] = {"reward_terms": {k: F[:, S.terms - _BATCH_LO + i] for i, k in enumerate(REWARD_TERMS)}}
    for k, c in FLOAT_ENTRIES:
        info[k] = F[:, c - _BATCH_LO]
    for k, c in FLAG_ENTRIES:
        info[k] = F[:, c - _BATCH_LO] > 0.5
    info["action_clipped"] = sim.I[:, SI.clipped] != 0
    # (np.empty of dtype object is None-filled)
    info["termination_reason"] = np.empty(n, dtype=object) if reasons is None else reasons
    info["time"] = sim.F[:, S.t].copy()
    info.update(dict.fromkeys(_MASK_KEYS, np.ones(n, dtype=bool)))
    aids = sim.aids
    if aids is not None:  # the opt-in training aids: their reward terms, the residual gate
        for i, name in enumerate(aids.term_names):
            info["reward_terms"][name] = aids.terms[:, i].copy()
        if aids.sigma is not None:
            info["residual_gate"] = aids.gate.copy()
            info["_residual_gate"] = np.ones(n, dtype=bool)
    return info
