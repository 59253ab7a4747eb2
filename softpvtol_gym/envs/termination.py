"""Termination: the reasons an episode ends before its time limit, and their thresholds."""

from __future__ import annotations

import math

from .. import model as MK

GROUND_Z = -1.0  # m: terminate when z < GROUND_Z
BOX_X = 20.0  # m: terminate when |x| > BOX_X
BOX_Z = 20.0  # m: terminate when z > BOX_Z
MAX_LIN_SPEED = 50.0  # m/s: terminate when |xdot| or |zdot| exceeds it
MAX_ANG_SPEED = 100.0  # rad/s: terminate when |thetadot|, |q_l dot| or |q_r dot| exceeds it

#: the configurations an episode may start from, per coordinate of q: (name, lower, upper, the
#: termination reason beyond), the position limits of :func:`termination_reason` (``reset(options=...)``
#: refuses a q0 outside them; speeds beyond the speed limits are valid model states, they end the
#: episode as "out_of_bounds" at its first step)
Q_LIMITS = (("x", -BOX_X, BOX_X, "out_of_bounds"), ("z", GROUND_Z, BOX_Z, "ground/out_of_bounds"),
            ("theta", -math.inf, math.inf, ""), ("q_l", -math.pi, math.pi, "curvature_limit (model validity)"),
            ("q_r", -math.pi, math.pi, "curvature_limit (model validity)"))

REASONS = ("", "curvature_limit", "ground", "out_of_bounds", "non_finite")
R_NONE, R_CURV, R_GROUND, R_OOB, R_NONFINITE = range(5)


@MK.inline
def termination_reason(q, qd):
    """``R_*`` code of a finite state (q, qdot): the first limit it violates, in the order of REASONS."""
    if abs(q[3]) > math.pi or abs(q[4]) > math.pi:
        return R_CURV
    if q[1] < GROUND_Z:
        return R_GROUND
    if (abs(q[0]) > BOX_X or q[1] > BOX_Z or abs(qd[0]) > MAX_LIN_SPEED or abs(qd[1]) > MAX_LIN_SPEED
            or abs(qd[2]) > MAX_ANG_SPEED or abs(qd[3]) > MAX_ANG_SPEED or abs(qd[4]) > MAX_ANG_SPEED):
        return R_OOB
    return R_NONE
