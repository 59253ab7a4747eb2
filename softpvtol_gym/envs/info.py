"""The info dict of a step, built in one place for the single env (Python scalars) and the vector
env (arrays with gymnasium's ``_name`` masks)."""

from __future__ import annotations

from typing import Any

import numpy as np

from .layout import SI, S
from .reward import REWARD_TERMS

#: float diagnostics: (info key, column of the packed state)
FLOAT_ENTRIES = (("total_energy", S.total_energy), ("storage_function", S.storage_function),
                 ("curvature_violation", S.curvature_violation), ("allocation_residual", S.allocation_residual))
#: flags stored as 0.0/1.0
FLAG_ENTRIES = (("thrust_saturated", S.thrust_saturated), ("arm_torque_saturated", S.arm_torque_saturated))
#: (with ``residual_gate``, also "residual_gate": the gate g applied to the step's residual, 0 at a reset)
INFO_KEYS = ("reward_terms", *(k for k, _ in FLOAT_ENTRIES), *(k for k, _ in FLAG_ENTRIES), "action_clipped",
             "termination_reason", "time")
_MASK_KEYS = tuple("_" + k for k in INFO_KEYS)
#: the contiguous columns of the packed state that hold the reward terms and the diagnostics of the info
_INFO_COLUMNS = (*range(S.terms, S.terms + len(REWARD_TERMS)), *(c for _, c in FLOAT_ENTRIES + FLAG_ENTRIES))
_INFO_LO, _INFO_HI = min(_INFO_COLUMNS), max(_INFO_COLUMNS) + 1
# their places in that slice
_TERMS_LO, _TERMS_HI = S.terms - _INFO_LO, S.terms - _INFO_LO + len(REWARD_TERMS)
_FLOAT_AT = tuple((k, c - _INFO_LO) for k, c in FLOAT_ENTRIES)
_FLAG_AT = tuple((k, c - _INFO_LO) for k, c in FLAG_ENTRIES)


def single_info(sim, reason: str | None) -> dict[str, Any]:
    """The info of entry 0 as Python scalars; ``reason``: the termination/truncation reason or None."""
    f = sim.F[0, _INFO_LO:_INFO_HI].tolist()  # (one conversion of the columns read, on every step)
    info: dict[str, Any] = {"reward_terms": dict(zip(REWARD_TERMS, f[_TERMS_LO:_TERMS_HI]))}
    for k, c in _FLOAT_AT:
        info[k] = f[c]
    for k, c in _FLAG_AT:
        info[k] = f[c] > 0.5
    info["action_clipped"] = bool(sim.I[0, SI.clipped])
    info["termination_reason"] = reason
    info["time"] = float(sim.F[0, S.t])
    aids = sim.aids
    if aids is not None:  # the opt-in training aids: their reward terms, the residual gate
        for i, name in enumerate(aids.term_names):
            info["reward_terms"][name] = float(aids.terms[0, i])
        if aids.sigma is not None:
            info["residual_gate"] = float(aids.gate[0])
    return info


def batch_info(sim, reasons: np.ndarray | None) -> dict[str, Any]:
    """The infos of every entry as arrays (one private copy of the state; each array a column of it);
    ``reasons``: an object array of reasons (None where not done), or None when no entry is done."""
    F = sim.F[:, _INFO_LO:_INFO_HI].copy()  # the columns the info reads (not the whole state: a copy per step)
    n = F.shape[0]
    info: dict[str, Any] = {"reward_terms": {k: F[:, _TERMS_LO + i] for i, k in enumerate(REWARD_TERMS)}}
    for k, c in _FLOAT_AT:
        info[k] = F[:, c]
    for k, c in _FLAG_AT:
        info[k] = F[:, c] > 0.5
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
