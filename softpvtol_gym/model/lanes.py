"""SIMD lane blocks: :data:`LANES` states stored structure-of-arrays, stepped by one compiled loop.

A lane block W holds the rows of :data:`RK4_LANES` (q, qdot, held command u, external force, params,
sin/cos of theta), ``W[row * LANES + lane]``; a full block's loop has a constant trip count over the
inlined RK4 step, which LLVM vectorises. Every lane performs exactly the scalar IEEE operations, so the
SIMD path is bit-identical to the scalar one.
"""

from __future__ import annotations

import math

from .._columns import Columns
from ..params import N_PARAMS
from .jit import accessor, jit
from .rk4 import consistent_rk4_step_tuple, rk4_step_sc, rk4_step_tuple

#: width of a lane block: W holds LANES states structure-of-arrays, W[row * LANES + lane]
LANES = 64
#: lane rows of :func:`rk4_lanes`: q, qdot, held command u, external force (f_x, f_z), params
RK4_LANES = Columns("rk4_lanes", [("q", 5), ("qd", 5), ("u", 5), ("ext", 2), ("p", N_PARAMS), ("sc", 2)])
LANE_Q, LANE_QD, LANE_U, LANE_EXT, LANE_P, LANE_SC = RK4_LANES.at
LANE_ROWS_RK4 = RK4_LANES.size


@accessor
def lane_load(W, j):
    L = LANES
    q = (W[j], W[L + j], W[2 * L + j], W[3 * L + j], W[4 * L + j])
    o = LANE_QD * L + j
    qd = (W[o], W[o + L], W[o + 2 * L], W[o + 3 * L], W[o + 4 * L])
    o = LANE_U * L + j
    u = (W[o], W[o + L], W[o + 2 * L], W[o + 3 * L], W[o + 4 * L])
    o = LANE_EXT * L + j
    ext = (W[o], W[o + L])
    o = LANE_P * L + j
    p = (W[o], W[o + L], W[o + 2 * L], W[o + 3 * L], W[o + 4 * L],
         W[o + 5 * L], W[o + 6 * L], W[o + 7 * L], W[o + 8 * L], W[o + 9 * L])
    return q, qd, u, ext, p


@accessor
def lane_store(W, j, qn, vn):
    L = LANES
    W[j], W[L + j], W[2 * L + j], W[3 * L + j], W[4 * L + j] = qn
    o = LANE_QD * L + j
    W[o], W[o + L], W[o + 2 * L], W[o + 3 * L], W[o + 4 * L] = vn


@jit
def rk4_lanes(W, dt, m, input_map):
    """:func:`rk4_step` in place on the first m lanes of a lane block W (rows ``LANE_*``).

    sin and cos of each lane's theta (libm, as in the scalar step) go into the rows ``LANE_SC`` first;
    the step itself is then polynomial arithmetic only: a full block (m == LANES) runs a loop of
    constant trip count over the inlined step, which LLVM vectorises (the lanes are independent); a
    partial block calls the same step lane by lane.
    """
    L = LANES
    for j in range(m):
        th = W[(LANE_Q + 2) * L + j]
        W[LANE_SC * L + j] = math.sin(th)
        W[(LANE_SC + 1) * L + j] = math.cos(th)
    if m == LANES:
        for j in range(LANES):
            q, qd, u, ext, p = lane_load(W, j)
            qn, vn = rk4_step_sc(q, qd, W[LANE_SC * L + j], W[(LANE_SC + 1) * L + j], u, ext, p, dt, input_map)
            lane_store(W, j, qn, vn)
    else:
        rk4_lanes_partial(W, dt, m, input_map)


@jit
def rk4_lanes_partial(W, dt, m, input_map):
    """The lane-by-lane path of :func:`rk4_lanes` (any m <= LANES): :func:`rk4_step_tuple` per lane.
    A batch of fewer than LANES states needs only this (the env's small-batch step kernels call it
    directly: no SIMD copy of the step to compile)."""
    for j in range(m):
        q, qd, u, ext, p = lane_load(W, j)
        qn, vn = rk4_step_tuple(q, qd, u, ext, p, dt, input_map)
        lane_store(W, j, qn, vn)


@jit
def rk4_lanes_consistent(W, dt, m, held):
    """:func:`rk4_lanes` of the consistent model (first m lanes of W, lane by lane: the env's plant
    under ``model="consistent"``); ``held`` as in :func:`consistent_rk4_step`."""
    for j in range(m):
        q, qd, u, ext, p = lane_load(W, j)
        qn, vn = consistent_rk4_step_tuple(q, qd, u, ext, p, dt, held)
        lane_store(W, j, qn, vn)
