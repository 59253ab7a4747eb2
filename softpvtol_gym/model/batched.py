"""Batched wrappers of the model kernels: the compiled loops behind :mod:`softpvtol_gym.dynamics` and
:mod:`softpvtol_gym.integrators`. ``model``: ``MODEL_PAPER`` or ``MODEL_CONSISTENT``."""

from __future__ import annotations

import numpy as np

from .consistent import (
    consistent_coriolis_matrix_into,
    consistent_forward_dynamics_into,
    consistent_gravity_vector_into,
    consistent_mass_matrix_into,
)
from .energies import consistent_energies, kinetic_energy, potential_energy
from .input_map import generalized_forces_into
from .jit import batch_jit
from .kinematics import paper_tip_positions_into, tip_positions_into
from .paper import coriolis_matrix_into, forward_dynamics_into, gravity_vector_into, mass_matrix_into
from .rk4 import consistent_rk4_step_into, rk4_step_into

#: ``model`` codes of the wrappers
MODEL_PAPER = 0
MODEL_CONSISTENT = 1

# Each takes contiguous (N, ...) float64 arrays and a parameter matrix P of shape (N, 10) or (1, 10).
# They run in one thread and release the GIL: the public API splits large batches over threads
# (softpvtol_gym._parallel.run_rows); results do not depend on the split.


@batch_jit
def batch_mass_matrix(q, P, model, out):
    ps = np.int64(P.shape[0] > 1)
    for n in range(q.shape[0]):
        if model == MODEL_CONSISTENT:
            consistent_mass_matrix_into(q[n], P[n * ps], out[n])
        else:
            mass_matrix_into(q[n], P[n * ps], out[n])


@batch_jit
def batch_coriolis_matrix(q, qd, P, model, out):
    ps = np.int64(P.shape[0] > 1)
    for n in range(q.shape[0]):
        if model == MODEL_CONSISTENT:
            consistent_coriolis_matrix_into(q[n], qd[n], P[n * ps], out[n])
        else:
            coriolis_matrix_into(q[n], qd[n], P[n * ps], out[n])


@batch_jit
def batch_gravity_vector(q, P, model, out):
    ps = np.int64(P.shape[0] > 1)
    for n in range(q.shape[0]):
        if model == MODEL_CONSISTENT:
            consistent_gravity_vector_into(q[n], P[n * ps], out[n])
        else:
            gravity_vector_into(q[n], P[n * ps], out[n])


@batch_jit
def batch_generalized_forces(q, a, P, input_map, out):
    """(The consistent model's input map is ``INPUT_MAP_EXACT``: no model argument needed.)"""
    ps = np.int64(P.shape[0] > 1)
    for n in range(q.shape[0]):
        generalized_forces_into(q[n], a[n], P[n * ps], input_map, out[n])


@batch_jit
def batch_forward_dynamics(q, qd, tau, P, model, out):
    ps = np.int64(P.shape[0] > 1)
    for n in range(q.shape[0]):
        if model == MODEL_CONSISTENT:
            consistent_forward_dynamics_into(q[n], qd[n], tau[n], P[n * ps], out[n])
        else:
            forward_dynamics_into(q[n], qd[n], tau[n], P[n * ps], out[n])


@batch_jit
def batch_energies(q, qd, P, model, out):
    """out[n] = (kinetic, potential)."""
    ps = np.int64(P.shape[0] > 1)
    for n in range(q.shape[0]):
        p = P[n * ps]
        if model == MODEL_CONSISTENT:
            out[n, 0], out[n, 1] = consistent_energies(q[n], qd[n], p)
        else:
            out[n, 0] = kinetic_energy(q[n], qd[n], p)
            out[n, 1] = potential_energy(q[n], p)


@batch_jit
def batch_tip_positions(q, P, model, out):
    """The tips of the model's Lagrangian: rotated (consistent), or not (paper)."""
    ps = np.int64(P.shape[0] > 1)
    for n in range(q.shape[0]):
        if model == MODEL_CONSISTENT:
            tip_positions_into(q[n], P[n * ps], out[n])
        else:
            paper_tip_positions_into(q[n], P[n * ps], out[n])


@batch_jit
def batch_rk4_step(q, qd, u, ext, P, dt, input_map, model, q_out, qd_out):
    """u (N, 5): held commands (actuators padded to 5, or tau with ``HELD_TAU``); ext (N, 2) or (1, 2).
    ``model`` ``MODEL_CONSISTENT`` takes ``input_map`` ``HELD_TAU`` or ``INPUT_MAP_EXACT``."""
    ps = np.int64(P.shape[0] > 1)
    es = np.int64(ext.shape[0] > 1)
    for n in range(q.shape[0]):
        if model == MODEL_CONSISTENT:
            consistent_rk4_step_into(q[n], qd[n], u[n], ext[n * es], P[n * ps], dt, input_map, q_out[n], qd_out[n])
        else:
            rk4_step_into(q[n], qd[n], u[n], ext[n * es], P[n * ps], dt, input_map, q_out[n], qd_out[n])
