"""Euler–Lagrange dynamics of the Soft-PVTOL: D(q) qdd + C(q, qd) qd + g(q) = tau.

Pure functions of arrays and a :class:`~softpvtol_gym.SoftPVTOLParams`, float64, batched over any
leading axes (inputs broadcast against each other). q = (x_v, z_v, theta, q_l, q_r) with x, z in m
and angles/curvatures in rad; actuators a = (T_l, T_r, tau_l, tau_r) in (N, N, N m, N m).

Every function takes ``model``: "paper" (default; the paper's Lagrangian as printed) or "consistent"
(the same energy terms with the rotor masses on the tips rotated by theta). All of them call the
compiled kernels in :mod:`softpvtol_gym.model`, the only place the physics is written. See
``docs/model.md`` for the equations and every difference from the paper.
"""

from __future__ import annotations

import numpy as np

from . import model as K
from ._batching import broadcast_batch, check_curvature, param_matrix
from ._parallel import run_rows
from .params import SoftPVTOLParams

__all__ = [
    "INPUT_MAPS",
    "MODELS",
    "mass_matrix",
    "coriolis_matrix",
    "gravity_vector",
    "generalized_forces",
    "forward_dynamics",
    "kinetic_energy",
    "potential_energy",
    "total_energy",
    "arm_tip_positions",
]

#: Valid values of ``input_map``.
INPUT_MAPS: dict[str, int] = {"paper": K.INPUT_MAP_PAPER, "exact": K.INPUT_MAP_EXACT}
#: Valid values of ``model``: "paper" (the paper's Lagrangian as printed: tips not rotated by theta) and
#: "consistent" (the same energy terms with the tips rotated by theta; see docs/model.md).
MODELS: dict[str, int] = {"paper": K.MODEL_PAPER, "consistent": K.MODEL_CONSISTENT}
#: each model's own input map (``input_map=None``)
NATURAL_INPUT_MAP = {"paper": "paper", "consistent": "exact"}


def model_code(model: str) -> int:
    """Kernel code of a model name, with a clear error for unknown names."""
    try:
        return MODELS[model]
    except (KeyError, TypeError):
        raise ValueError(f"model must be one of {sorted(MODELS)}, got {model!r}") from None


def input_map_code(input_map: str) -> int:
    """Kernel code of an input map name, with a clear error for unknown names."""
    try:
        return INPUT_MAPS[input_map]
    except (KeyError, TypeError):
        raise ValueError(f"input_map must be one of {sorted(INPUT_MAPS)}, got {input_map!r}") from None


def resolve_input_map(input_map: str | None, model: str) -> str:
    """The input map used by ``model`` for the argument ``input_map`` (None: the model's own).

    The paper's model takes "paper" (its printed map) or "exact" (the virtual work of the thrusts at
    the rotated tips, kept for the paper model as before); the consistent model takes only its own
    map, the virtual work at its (rotated) tips, which is "exact": the printed map is not derived
    from it, and pairing the two would mix two models.
    """
    model_code(model)
    if input_map is None:
        return NATURAL_INPUT_MAP[model]
    input_map_code(input_map)
    if model == "consistent" and input_map != "exact":
        raise ValueError(
            f"input_map={input_map!r} is not an input map of model='consistent': its input map is the "
            "virtual work of the thrusts at the rotated tips, input_map='exact' (or None, the model's own); "
            "the paper's printed map belongs to model='paper'"
        )
    return input_map


def mass_matrix(q, params: SoftPVTOLParams, model: str = "paper") -> np.ndarray:
    """Inertia matrix D(q): (..., 5) -> (..., 5, 5), symmetric positive definite.

    ``model="paper"``: depends on the curvatures only; ``"consistent"``: also on theta."""
    code = model_code(model)
    lead, (qf,) = broadcast_batch(q=(q, 5))
    check_curvature(qf)
    out = np.empty((qf.shape[0], 5, 5))
    run_rows(K.batch_mass_matrix, qf.shape[0], qf, param_matrix(params), code, out)
    return out.reshape(lead + (5, 5))


def coriolis_matrix(q, qdot, params: SoftPVTOLParams, model: str = "paper") -> np.ndarray:
    """Coriolis/centrifugal matrix C(q, qdot) (Christoffel symbols of the first kind): (..., 5, 5)."""
    code = model_code(model)
    lead, (qf, vf) = broadcast_batch(q=(q, 5), qdot=(qdot, 5))
    check_curvature(qf)
    out = np.empty((qf.shape[0], 5, 5))
    run_rows(K.batch_coriolis_matrix, qf.shape[0], qf, vf, param_matrix(params), code, out)
    return out.reshape(lead + (5, 5))


def gravity_vector(q, params: SoftPVTOLParams, model: str = "paper") -> np.ndarray:
    """Gravity vector g(q) = dP/dq: (..., 5)."""
    code = model_code(model)
    lead, (qf,) = broadcast_batch(q=(q, 5))
    check_curvature(qf)
    out = np.empty((qf.shape[0], 5))
    run_rows(K.batch_gravity_vector, qf.shape[0], qf, param_matrix(params), code, out)
    return out.reshape(lead + (5,))


def generalized_forces(q, actuators, params: SoftPVTOLParams, input_map: str | None = None,
                       model: str = "paper") -> np.ndarray:
    """Generalized force tau = B(q) a of the actuators a = (T_l, T_r, tau_l, tau_r): (..., 5).

    ``input_map="paper"``: the paper's map as printed. ``"exact"``: derived from the virtual work of
    the two thrusts applied at the rotated arm tips (adds the moment of the horizontal thrust
    components and of epsilon about the body, and the work T_i l_i (1 - cos q_i)/q_i^2 done on each
    curvature). ``None`` (default): the model's own map, "paper" for ``model="paper"`` and "exact" for
    ``model="consistent"`` (whose tips those are; it accepts no other, see :func:`resolve_input_map`).
    """
    code = input_map_code(resolve_input_map(input_map, model))
    lead, (qf, af) = broadcast_batch(q=(q, 5), actuators=(actuators, 4))
    check_curvature(qf)
    out = np.empty((qf.shape[0], 5))
    run_rows(K.batch_generalized_forces, qf.shape[0], qf, af, param_matrix(params), code, out)
    return out.reshape(lead + (5,))


def forward_dynamics(q, qdot, tau, params: SoftPVTOLParams, model: str = "paper") -> np.ndarray:
    """Accelerations qddot = D(q)^-1 (tau - C(q, qdot) qdot - g(q)): (..., 5)."""
    code = model_code(model)
    lead, (qf, vf, tf) = broadcast_batch(q=(q, 5), qdot=(qdot, 5), tau=(tau, 5))
    check_curvature(qf)
    out = np.empty((qf.shape[0], 5))
    run_rows(K.batch_forward_dynamics, qf.shape[0], qf, vf, tf, param_matrix(params), code, out)
    return out.reshape(lead + (5,))


def _energies(q, qdot, params, model) -> tuple[tuple[int, ...], np.ndarray]:
    code = model_code(model)
    lead, (qf, vf) = broadcast_batch(q=(q, 5), qdot=(qdot, 5))
    check_curvature(qf)
    out = np.empty((qf.shape[0], 2))
    run_rows(K.batch_energies, qf.shape[0], qf, vf, param_matrix(params), code, out)
    return lead, out


def kinetic_energy(q, qdot, params: SoftPVTOLParams, model: str = "paper") -> np.ndarray:
    """Kinetic energy 1/2 qdot^T D(q) qdot [J]: (...)."""
    lead, out = _energies(q, qdot, params, model)
    return out[:, 0].reshape(lead)


def potential_energy(q, params: SoftPVTOLParams, model: str = "paper") -> np.ndarray:
    """Potential energy P(q) = g (M z_v + m_l z_l + m_r z_r) [J], z_i the tips' heights: (...)."""
    q = np.asarray(q, dtype=np.float64)
    lead, out = _energies(q, np.zeros(5), params, model)
    return out[:, 1].reshape(lead)


def total_energy(q, qdot, params: SoftPVTOLParams, model: str = "paper") -> np.ndarray:
    """Total energy H = T + P [J]: (...)."""
    lead, out = _energies(q, qdot, params, model)
    return (out[:, 0] + out[:, 1]).reshape(lead)


def arm_tip_positions(q, params: SoftPVTOLParams, model: str = "paper") -> np.ndarray:
    """World-frame (x, z) of the left and right arm tips (the rotor masses of the model) [m]: (..., 2, 2).

    ``[..., 0, :]`` is the left tip, ``[..., 1, :]`` the right, with the body-frame arc end
    r_l = (-eps - l_l sin q_l / q_l, l_l (1 - cos q_l)/q_l) and its mirror image r_r. ``model="paper"``:
    p_v + r_i, the paper's eq. (coords), whose Lagrangian places the rotor masses there (not rotated by
    theta); ``"consistent"``: the physical tips p_v + R(theta) r_i, where the "exact" input map applies
    the thrusts. The two agree at theta = 0 (docs/model.md).
    """
    code = model_code(model)
    lead, (qf,) = broadcast_batch(q=(q, 5))
    check_curvature(qf)
    out = np.empty((qf.shape[0], 2, 2))
    run_rows(K.batch_tip_positions, qf.shape[0], qf, param_matrix(params), code, out)
    return out.reshape(lead + (2, 2))
