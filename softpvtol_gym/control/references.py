"""Reference trajectories (q_ref, qdot_ref, qddot_ref), each (..., 5) with the arm entries zero.

Arm curvature references are produced by the allocation in the actuated loop (see closed_loop).
"""

from __future__ import annotations

import numpy as np

from ..references import paper_derivatives

__all__ = ["paper_reference", "hover_reference"]


def paper_reference(t, order: int = 2) -> tuple[np.ndarray, ...]:
    """The paper's eq. (traj_des): x = 4 sin(t/2), z = 3 cos(-t/10) + 4, theta = 0, from its one definition
    (:func:`softpvtol_gym.references.paper_row`, which the env's step kernel evaluates too).

    Derivatives are computed correctly: zdot = -0.3 sin(t/10) (the paper prints -0.3 sin(-t/10), a sign
    error) and zddot = -0.03 cos(t/10). ``t`` [s] scalar or array; outputs (..., 5): (q, qdot, qddot),
    and with ``order=4`` also the third and fourth derivatives (the extended loop needs them).
    """
    if order not in (2, 4):
        raise ValueError(f"order must be 2 (q, qdot, qddot) or 4 (also the third and fourth derivatives), "
                         f"got {order!r}")
    xz = paper_derivatives(t)  # (..., 2, 5): x and z with their first four derivatives
    out = []
    for k in range(order + 1):
        d = np.zeros(xz.shape[:-2] + (5,))
        d[..., 0], d[..., 1] = xz[..., 0, k], xz[..., 1, k]
        out.append(d)
    return tuple(out)


def hover_reference(x=0.0, z=0.0, theta=0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A constant set-point (x [m], z [m], theta [rad]); arrays broadcast. Outputs (..., 5)."""
    x, z, theta = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (x, z, theta)))
    q = np.zeros(x.shape + (5,))
    q[..., 0], q[..., 1], q[..., 2] = x, z, theta
    return q, np.zeros_like(q), np.zeros_like(q)
