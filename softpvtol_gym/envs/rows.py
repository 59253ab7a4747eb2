"""Access to the packed env state for the step kernels: tuples of consecutive columns of a row, the
nominal parameter vector of the constants, and rows of a physics lane block (``MK.LANES`` envs
structure-of-arrays)."""

from __future__ import annotations

from .. import model as MK
from ..model.jit import jit
from ..params import N_PARAMS
from .packed_state import SC

if N_PARAMS != 10:  # pragma: no cover
    raise RuntimeError("row10 and nominal_params read a parameter vector of 10 columns; update them")


@jit
def row5(A, n, c):
    """Columns c .. c + 4 of row n of A as a tuple (q, qdot, ...)."""
    return (A[n, c], A[n, c + 1], A[n, c + 2], A[n, c + 3], A[n, c + 4])


@jit
def row10(A, n, c):
    """Columns c .. c + 9 of row n of A as a tuple: a parameter vector (``PARAM_FIELDS`` order)."""
    return row5(A, n, c) + row5(A, n, c + 5)


@jit
def vec5(v, c):
    """Entries c .. c + 4 of the vector v as a tuple."""
    return (v[c], v[c + 1], v[c + 2], v[c + 3], v[c + 4])


@jit
def nominal_params(consts):
    """The nominal parameter vector (the controllers' model) stored in the constants ``consts``."""
    return vec5(consts, SC.p_nominal) + vec5(consts, SC.p_nominal + 5)


# ---------------------------------------------------------------------------------- lane blocks
@jit
def lane_put(lanes, row, j, v):
    """Rows row .. row + len(v) - 1 of lane j from the tuple v."""
    for i in range(len(v)):
        lanes[(row + i) * MK.LANES + j] = v[i]


@jit
def lane5(lanes, row, j):
    """Rows row .. row + 4 of lane j as a tuple."""
    L = MK.LANES
    o = row * L + j
    return (lanes[o], lanes[o + L], lanes[o + 2 * L], lanes[o + 3 * L], lanes[o + 4 * L])
