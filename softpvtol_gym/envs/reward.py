"""The reward, term by term (docs/env.md, "Reward"): 1 + position + attitude + velocity + effort +
curvature + crash, from the true (noise-free) state."""

from __future__ import annotations

import math

from .. import model as MK

REWARD_TERMS = ("alive", "position", "attitude", "velocity", "effort", "curvature", "crash")
W_POS, POS_SCALE = 0.5, 2.0  # -0.5 min(|e_xz| / 2 m, 1)
W_ATT = 0.1  # -0.1 min(|e_theta| / pi, 1)
W_VEL, VEL_SCALE = 0.1, 5.0  # -0.1 min(|e_v| / 5, 1)
W_EFFORT = 0.1  # -0.1 min(mean(a_n^2), 1)
W_CURV = 0.2  # -0.2 clip((max|q_arm| - pi/2) / (pi/2), 0, 1)^2
CRASH_PENALTY = 10.0


@MK.inline
def reward_terms(e_pos, e_theta, e_vel, effort, max_curvature, crashed):
    """The terms of :data:`REWARD_TERMS` from |position error| [m], wrapped attitude error [rad],
    |velocity error|, effort mean(a_n^2), max(|q_l|, |q_r|) and the termination flag."""
    cp = min(max((max_curvature - 0.5 * math.pi) / (0.5 * math.pi), 0.0), 1.0)
    return (
        1.0,
        -W_POS * min(e_pos / POS_SCALE, 1.0),
        -W_ATT * min(abs(e_theta) / math.pi, 1.0),
        -W_VEL * min(e_vel / VEL_SCALE, 1.0),
        -W_EFFORT * min(effort, 1.0),
        -W_CURV * cp * cp,
        -CRASH_PENALTY if crashed else 0.0,
    )
