"""Euler–Lagrange dynamics of the Soft-PVTOL: D(q) qdd + C(q, qd) qd + g(q) = tau.

Pure functions of arrays and a :class:`~softpvtol_gym.SoftPVTOLParams`, float64, batched over any
leading axes (inputs broadcast against each other). q = (x_v, z_v, theta, q_l, q_r) with x, z in m
and angles/curvatures in rad; actuators a = (T_l, T_r, tau_l, tau_r) in (N, N, N m, N m).

All of them call the compiled kernels in :mod:`softpvtol_gym._kernels`, the only place the
physics is written. See ``docs/model.md`` for the equations and every difference from the paper.
"""

from __future__ import annotations

import numpy as np

from . import _kernels as K
from ._batching import broadcast_batch, check_curvature, param_matrix
from ._parallel import run_rows
from .params import SoftPVTOLParams

__all__ = [
    "INPUT_MAPS",
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


def input_map_code(input_map: str) -> int:
    """Kernel code of an input map name, with a clear error for unknown names."""
    try:
        return INPUT_MAPS[input_map]
    except (KeyError, TypeError):
        raise ValueError(f"input_map must be one of {sorted(INPUT_MAPS)}, got {input_map!r}") from None


def mass_matrix(q, params: SoftPVTOLParams) -> np.ndarray:
    """Inertia matrix D(q): (..., 5) -> (..., 5, 5), symmetric positive definite."""
    lead, (qf,) = broadcast_batch(q=(q, 5))
    check_curvature(qf)
    out = np.empty((qf.shape[0], 5, 5))
    run_rows(K.batch_mass_matrix, qf.shape[0], qf, param_matrix(params), out)
    return out.reshape(lead + (5, 5))


def coriolis_matrix(q, qdot, params: SoftPVTOLParams) -> np.ndarray:
    """Coriolis/centrifugal matrix C(q, qdot) (Christoffel symbols of the first kind): (..., 5, 5)."""
    lead, (qf, vf) = broadcast_batch(q=(q, 5), qdot=(qdot, 5))
    check_curvature(qf)
    out = np.empty((qf.shape[0], 5, 5))
    run_rows(K.batch_coriolis_matrix, qf.shape[0], qf, vf, param_matrix(params), out)
    return out.reshape(lead + (5, 5))


def gravity_vector(q, params: SoftPVTOLParams) -> np.ndarray:
    """Gravity vector g(q) = dP/dq: (..., 5)."""
    lead, (qf,) = broadcast_batch(q=(q, 5))
    check_curvature(qf)
    out = np.empty((qf.shape[0], 5))
    run_rows(K.batch_gravity_vector, qf.shape[0], qf, param_matrix(params), out)
    return out.reshape(lead + (5,))


def generalized_forces(q, actuators, params: SoftPVTOLParams, input_map: str = "paper") -> np.ndarray:
    """Generalized force tau = B(q) a of the actuators a = (T_l, T_r, tau_l, tau_r): (..., 5).

    ``input_map="paper"``: the paper's map as printed. ``"exact"``: derived from the virtual work of
    the two thrusts applied at the arm tips (adds the moment of the horizontal thrust components and
    of epsilon about the body, and the work T_i l_i (1 - cos q_i)/q_i^2 done on each curvature).
    """
    code = input_map_code(input_map)
    lead, (qf, af) = broadcast_batch(q=(q, 5), actuators=(actuators, 4))
    check_curvature(qf)
    out = np.empty((qf.shape[0], 5))
    run_rows(K.batch_generalized_forces, qf.shape[0], qf, af, param_matrix(params), code, out)
    return out.reshape(lead + (5,))


def forward_dynamics(q, qdot, tau, params: SoftPVTOLParams) -> np.ndarray:
    """Accelerations qddot = D(q)^-1 (tau - C(q, qdot) qdot - g(q)): (..., 5)."""
    lead, (qf, vf, tf) = broadcast_batch(q=(q, 5), qdot=(qdot, 5), tau=(tau, 5))
    check_curvature(qf)
    out = np.empty((qf.shape[0], 5))
    run_rows(K.batch_forward_dynamics, qf.shape[0], qf, vf, tf, param_matrix(params), out)
    return out.reshape(lead + (5,))


def _energies(q, qdot, params) -> tuple[tuple[int, ...], np.ndarray]:
    lead, (qf, vf) = broadcast_batch(q=(q, 5), qdot=(qdot, 5))
    check_curvature(qf)
    out = np.empty((qf.shape[0], 2))
    run_rows(K.batch_energies, qf.shape[0], qf, vf, param_matrix(params), out)
    return lead, out


def kinetic_energy(q, qdot, params: SoftPVTOLParams) -> np.ndarray:
    """Kinetic energy 1/2 qdot^T D(q) qdot [J]: (...)."""
    lead, out = _energies(q, qdot, params)
    return out[:, 0].reshape(lead)


def potential_energy(q, params: SoftPVTOLParams) -> np.ndarray:
    """Potential energy P(q) = g (M z_v + m_l z_l + m_r z_r) [J]: (...)."""
    q = np.asarray(q, dtype=np.float64)
    lead, out = _energies(q, np.zeros(5), params)
    return out[:, 1].reshape(lead)


def total_energy(q, qdot, params: SoftPVTOLParams) -> np.ndarray:
    """Total energy H = T + P [J]: (...)."""
    lead, out = _energies(q, qdot, params)
    return (out[:, 0] + out[:, 1]).reshape(lead)


def arm_tip_positions(q, params: SoftPVTOLParams) -> np.ndarray:
    """World-frame (x, z) of the left and right arm tips (rotor positions) [m]: (..., 2, 2).

    ``[..., 0, :]`` is the left tip, ``[..., 1, :]`` the right; each is p_v + R(theta) r_i(q_i) with the
    body-frame arc end r_l = (-eps - l_l sin q_l / q_l, l_l (1 - cos q_l)/q_l) and its mirror image.
    (The paper's eq. (coords) omits R(theta); see docs/model.md.)
    """
    lead, (qf,) = broadcast_batch(q=(q, 5))
    check_curvature(qf)
    out = np.empty((qf.shape[0], 2, 2))
    run_rows(K.batch_tip_positions, qf.shape[0], qf, param_matrix(params), out)
    return out.reshape(lead + (2, 2))
