"""Fixed-step integration of the Soft-PVTOL dynamics (the paper uses a fixed 0.01 s step)."""

from __future__ import annotations

import math

import numpy as np

from . import _kernels as K
from ._batching import broadcast_batch, check_curvature, param_matrix
from ._parallel import run_rows
from .params import SoftPVTOLParams

__all__ = ["rk4_step", "rollout"]


def _check_dt(dt: float) -> float:
    if not (isinstance(dt, (int, float, np.floating)) and math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a finite number > 0 [s], got {dt!r}")
    return float(dt)


def rk4_step(q, qdot, tau, params: SoftPVTOLParams, dt: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Classical RK4 step of (q, qdot) over ``dt`` seconds with the generalized force tau held.

    Shapes: q, qdot, tau (..., 5), broadcast together. Returns (q_next, qdot_next), each (..., 5).
    """
    dt = _check_dt(dt)
    lead, (qf, vf, tf) = broadcast_batch(q=(q, 5), qdot=(qdot, 5), tau=(tau, 5))
    check_curvature(qf)
    q_out = np.empty_like(qf)
    v_out = np.empty_like(vf)
    run_rows(K.batch_rk4_step, qf.shape[0], qf, vf, tf, param_matrix(params), dt, q_out, v_out)
    return q_out.reshape(lead + (5,)), v_out.reshape(lead + (5,))


def rollout(q0, qdot0, tau, params: SoftPVTOLParams, dt: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Integrate from (q0, qdot0) under a sequence of held generalized forces.

    tau: (T, ..., 5), one force per step. Returns the trajectories q, qdot of shape (T + 1, ..., 5),
    starting with the initial state.
    """
    tau = np.asarray(tau, dtype=np.float64)
    q = np.asarray(q0, dtype=np.float64)
    v = np.asarray(qdot0, dtype=np.float64)
    qs, vs = [q], [v]
    for k in range(tau.shape[0]):
        q, v = rk4_step(q, v, tau[k], params, dt)
        qs.append(q)
        vs.append(v)
    return np.stack(qs), np.stack(vs)
