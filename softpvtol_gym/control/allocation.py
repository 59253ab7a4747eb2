"""Control allocation: from the body rows of tau to thrusts and desired arm curvatures (paper Sec. 3.1)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._batching import as_batch, broadcast_batch, param_matrix
from .._parallel import run_rows
from ..dynamics import input_map_code
from ..params import SoftPVTOLParams
from . import kernels as CK

__all__ = ["ALLOCATION_METHODS", "AllocationInfo", "allocate"]

#: Valid ``method`` names of :func:`allocate`.
ALLOCATION_METHODS: dict[str, int] = {"paper": CK.ALLOC_PAPER, "exact": CK.ALLOC_EXACT}


@dataclass(frozen=True)
class AllocationInfo:
    """Diagnostics of :func:`allocate`, each of the batch shape.

    residual: for ``"exact"`` the max abs error [N or N m] of the body force realised through
    ``generalized_forces`` (input map as requested); for ``"paper"`` the max abs residual of the
    paper's own eq. (solve_num). iterations: Newton iterations used. feasible: False where the
    requested force needed a curvature beyond ``curvature_limit`` (then clipped) or did not converge.
    """

    residual: np.ndarray
    iterations: np.ndarray
    feasible: np.ndarray


def _allocation_info(residual, iterations, feasible) -> AllocationInfo:
    """AllocationInfo(residual, iterations, feasible) without the frozen dataclass's per-field
    ``object.__setattr__`` (a third of a microsecond: the single-state control step is hot)."""
    info = object.__new__(AllocationInfo)
    d = info.__dict__
    d["residual"], d["iterations"], d["feasible"] = residual, iterations, feasible
    return info


def allocate(
    tau,
    q,
    params: SoftPVTOLParams,
    method: str = "paper",
    *,
    input_map: str = "paper",
    warm_start=None,
    curvature_limit: float = math.pi,
    return_info: bool = False,
):
    """Actuator references (T_l, T_r, q_l^d, q_r^d) that realise the body rows of ``tau``.

    Args:
        tau: (..., 5) or (..., 3) generalized force; only (tau_x, tau_z, tau_theta) are used. They are
            rotated to body axes, (v_x, v_z) = R(theta)^T (tau_x, tau_z), as in the paper's eq. (vxvz).
        q: (..., 5) state (only theta is used).
        method: ``"paper"`` — the paper's allocation as printed (sin(q)/q ~ cos(q/2), arctan/sqrt form,
            Newton from the paper's initial guess (20, 10, 0.4, -0.2)). ``"exact"`` — no approximation,
            atan2 (valid when a rotor must push downwards), residual <= 1e-10 through
            :func:`~softpvtol_gym.dynamics.generalized_forces`.
        input_map: for ``"exact"``, the input map whose tau_theta row is inverted.
        warm_start: (..., 4) previous solution to start Newton from (both methods); rows containing
            NaN are solved from the cold start.
        curvature_limit: |q^d| beyond this is clipped and reported infeasible (``"exact"``).
        return_info: also return an :class:`AllocationInfo`.

    Returns: (..., 4) actuators (T_l [N], T_r [N], q_l^d [rad], q_r^d [rad]); never NaN for finite input.
    """
    try:
        code = ALLOCATION_METHODS[method]
    except (KeyError, TypeError):
        raise ValueError(
            f"allocation method must be one of {sorted(ALLOCATION_METHODS)}, got {method!r} "
            "(the 'ideal' loop applies tau directly and needs no allocation)"
        ) from None
    imap = input_map_code(input_map)
    tau = as_batch("tau", tau, np.shape(tau)[-1] if np.ndim(tau) else 5)
    if tau.shape[-1] not in (3, 5):
        raise ValueError(f"tau must have shape (..., 5) or (..., 3), got {tau.shape}")
    body = tau[..., :3]
    if not np.all(np.isfinite(body)):
        raise ValueError("tau contains NaN or inf; allocation needs a finite body force")
    if not (math.isfinite(curvature_limit) and 0 < curvature_limit <= math.pi):
        raise ValueError(f"curvature_limit must be in (0, pi], got {curvature_limit!r}")
    if warm_start is None:
        lead, (bf, qf) = broadcast_batch(tau=(body, 3), q=(q, 5))
        warm = np.zeros((1, 4))
        use_warm = False
    else:
        lead, (bf, qf, warm) = broadcast_batch(tau=(body, 3), q=(q, 5), warm_start=(warm_start, 4))
        use_warm = True
    n = bf.shape[0]
    out = np.empty((n, 4))
    info = np.empty((n, CK.N_INFO))
    theta = np.ascontiguousarray(qf[:, 2])
    run_rows(CK.batch_allocate, n, bf, theta, param_matrix(params), code, imap, warm, use_warm,
             float(curvature_limit), out, info)
    out = out.reshape(lead + (4,))
    if not return_info:
        return out
    return out, AllocationInfo(
        residual=info[:, CK.INFO_RESIDUAL].reshape(lead),
        iterations=info[:, CK.INFO_ITERATIONS].astype(np.int64).reshape(lead),
        feasible=(info[:, CK.INFO_FEASIBLE] > 0.5).reshape(lead),
    )
