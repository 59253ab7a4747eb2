"""Tip positions of the arms: the body-frame offset of a tip and the world positions of both tips, rotated
with the body (the consistent model's and the picture's) or not (the paper's Lagrangian)."""

from __future__ import annotations

import math

from ..params import P_EPS, P_LL
from .jit import jit
from .series import one_minus_cos_over_q2, sinc


@jit
def arm_offset(q_arm, length, eps, side):
    """Body-frame (x, z) of the tip of an arm of curvature q_arm; side = -1 left, +1 right."""
    return side * (eps + length * sinc(q_arm)), length * q_arm * one_minus_cos_over_q2(q_arm)


@jit
def tip_positions_into(q, p, out):
    """World (x, z) of the left (out[0]) and right (out[1]) tips: p_v + R(theta) r_i(q_i)."""
    ct, st = math.cos(q[2]), math.sin(q[2])
    for i in range(2):
        side = -1.0 if i == 0 else 1.0
        rx, rz = arm_offset(q[3 + i], p[P_LL + i], p[P_EPS], side)
        out[i, 0] = q[0] + ct * rx - st * rz
        out[i, 1] = q[1] + st * rx + ct * rz



@jit
def paper_tip_positions_into(q, p, out):
    """World (x, z) of the left (out[0]) and right (out[1]) rotor masses of the paper's Lagrangian:
    p_v + r_i(q_i), not rotated by theta (the paper's eq. (coords))."""
    for i in range(2):
        side = -1.0 if i == 0 else 1.0
        rx, rz = arm_offset(q[3 + i], p[P_LL + i], p[P_EPS], side)
        out[i, 0] = q[0] + rx
        out[i, 1] = q[1] + rz
