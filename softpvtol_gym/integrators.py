"""Fixed-step integration of the Soft-PVTOL dynamics (the paper uses a fixed 0.01 s step)."""

from __future__ import annotations

import math

import numpy as np

from . import model as K
from ._batching import broadcast_batch, check_curvature, param_matrix
from ._parallel import run_rows
from .dynamics import input_map_code, model_code, resolve_input_map
from .params import SoftPVTOLParams

__all__ = ["rk4_step", "rk4_step_actuated", "rk4_step_of_rates", "rollout"]


def _check_dt(dt: float) -> float:
    if not (isinstance(dt, (int, float, np.floating)) and math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a finite number > 0 [s], got {dt!r}")
    return float(dt)


def rk4_step(q, qdot, tau, params: SoftPVTOLParams, dt: float = 0.01,
             model: str = "paper") -> tuple[np.ndarray, np.ndarray]:
    """Classical RK4 step of (q, qdot) over ``dt`` seconds with the generalized force tau held, of the
    ``model`` ("paper" or "consistent", see :mod:`softpvtol_gym.dynamics`).

    Shapes: q, qdot, tau (..., 5), broadcast together. Returns (q_next, qdot_next), each (..., 5).
    """
    dt = _check_dt(dt)
    mcode = model_code(model)
    lead, (qf, vf, tf) = broadcast_batch(q=(q, 5), qdot=(qdot, 5), tau=(tau, 5))
    return _step(lead, qf, vf, tf, np.zeros((1, 2)), params, dt, K.HELD_TAU, mcode)


def rk4_step_actuated(q, qdot, actuators, params: SoftPVTOLParams, dt: float = 0.01, input_map: str | None = None,
                      external_force=None, model: str = "paper") -> tuple[np.ndarray, np.ndarray]:
    """Classical RK4 step of (q, qdot) over ``dt`` seconds with the actuators held (zero-order hold).

    The actuators a = (T_l, T_r, tau_l, tau_r) are held, not the generalized force: at every RK4 stage
    tau = B(q_stage) a (:func:`~softpvtol_gym.dynamics.generalized_forces` with ``input_map``), plus the
    held ``external_force`` (f_x, f_z) [N] on the body (default none). This is the env's physics step.
    ``model``: "paper" or "consistent"; ``input_map`` None is the model's own map ("paper", resp.
    "exact"; the consistent model accepts only "exact": see
    :func:`~softpvtol_gym.dynamics.resolve_input_map`).

    Shapes: q, qdot (..., 5), actuators (..., 4), external_force (..., 2), broadcast together.
    Returns (q_next, qdot_next), each (..., 5).
    """
    dt = _check_dt(dt)
    code = input_map_code(resolve_input_map(input_map, model))
    mcode = model_code(model)
    ext = np.zeros(2) if external_force is None else external_force
    lead, (qf, vf, af, ef) = broadcast_batch(q=(q, 5), qdot=(qdot, 5), actuators=(actuators, 4),
                                             external_force=(ext, 2))
    u = np.zeros((af.shape[0], 5))
    u[:, :4] = af
    return _step(lead, qf, vf, u, ef, params, dt, code, mcode)


def rk4_step_of_rates(rates, t: float, q, qdot, dt: float, first, x=None):
    """One classical RK4 step of (q, qdot) and, where given, a controller's own state x, whose rates at a
    stage come from ``rates(t, q, qdot, x) -> (qddot, xdot)`` (xdot None without x): a closed loop
    integrated with its controller at every stage. ``first`` = (qddot, xdot) at the step's start, which the
    caller evaluates itself (that evaluation is the one that advances the controller's memory).

    Shapes: q, qdot, qddot (..., 5); x, xdot any shape of their own. Returns (q_next, qdot_next, x_next), x_next
    None without x.
    """
    a1, x1 = first
    h = 0.5 * dt

    def moved(c, xdot):
        return None if x is None else x + c * xdot

    a2, x2 = rates(t + h, q + h * qdot, qdot + h * a1, moved(h, x1))
    a3, x3 = rates(t + h, q + h * (qdot + h * a1), qdot + h * a2, moved(h, x2))
    a4, x4 = rates(t + dt, q + dt * (qdot + h * a2), qdot + dt * a3, moved(dt, x3))
    q_next = q + dt / 6.0 * (6.0 * qdot + dt * (a1 + a2 + a3))
    qdot_next = qdot + dt / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
    return q_next, qdot_next, None if x is None else x + dt / 6.0 * (x1 + 2.0 * x2 + 2.0 * x3 + x4)


def _step(lead, qf, vf, u, ef, params, dt, code, mcode):
    check_curvature(qf)
    q_out = np.empty_like(qf)
    v_out = np.empty_like(vf)
    run_rows(K.batch_rk4_step, qf.shape[0], qf, vf, u, ef, param_matrix(params), dt, code, mcode, q_out, v_out)
    return q_out.reshape(lead + (5,)), v_out.reshape(lead + (5,))


def rollout(q0, qdot0, tau, params: SoftPVTOLParams, dt: float = 0.01,
            model: str = "paper") -> tuple[np.ndarray, np.ndarray]:
    """Integrate the ``model`` from (q0, qdot0) under a sequence of held generalized forces.

    tau: (T, ..., 5), one force per step. Returns the trajectories q, qdot of shape (T + 1, ..., 5),
    starting with the initial state.
    """
    tau = np.asarray(tau, dtype=np.float64)
    q = np.asarray(q0, dtype=np.float64)
    v = np.asarray(qdot0, dtype=np.float64)
    qs, vs = [q], [v]
    for k in range(tau.shape[0]):
        q, v = rk4_step(q, v, tau[k], params, dt, model)
        qs.append(q)
        vs.append(v)
    return np.stack(qs), np.stack(vs)
