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


@MK.accessor
def capped(x):
    """min(x, 1) for x >= 0, and 1 for NaN: a measure that could not be computed counts as the largest
    (bit for bit min(x, 1.0) otherwise)."""
    return x if x < 1.0 else 1.0


@MK.inline
def reward_terms(e_pos, e_theta, e_vel, effort, max_curvature, crashed):
    """The terms of :data:`REWARD_TERMS` from |position error| [m], wrapped attitude error [rad],
    |velocity error|, effort mean(a_n^2), max(|q_l|, |q_r|) and the termination flag. Every term is
    finite whatever its inputs: each normalised measure is capped at 1 and a NaN one counts as 1 (a
    command that was not finite, e.g. the residual mode's base controller outside the model, ends the
    episode as "non_finite"; its effort is then NaN)."""
    cp = capped(max((max_curvature - 0.5 * math.pi) / (0.5 * math.pi), 0.0))
    return (
        1.0,
        -W_POS * capped(e_pos / POS_SCALE),
        -W_ATT * capped(abs(e_theta) / math.pi),
        -W_VEL * capped(e_vel / VEL_SCALE),
        -W_EFFORT * capped(effort),
        -W_CURV * cp * cp,
        -CRASH_PENALTY if crashed else 0.0,
    )
