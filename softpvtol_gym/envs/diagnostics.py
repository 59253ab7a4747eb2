"""Diagnostics of the env step: the plant's total energy and the passivity controller's storage
function of every env (``info["total_energy"]``, ``info["storage_function"]``), in lane blocks."""

from __future__ import annotations

from .. import model as MK
from ..control import kernels as CK
from ..model.jit import accessor, inline, jit
from .packed_state import SL


@inline
def _energy_storage(q, qd, qr, qdr, P, Pnom, lam, kg):
    """(total energy of the plant, controller storage w.r.t. the body reference with arm references 0)."""
    energy = MK.kinetic_energy(q, qd, P) + MK.potential_energy(q, P)
    storage = CK.storage(q, qd, (qr[0], qr[1], qr[2], 0.0, 0.0), (qdr[0], qdr[1], qdr[2], 0.0, 0.0), Pnom, lam, kg)
    return energy, storage


@jit
def energy_storage(q, qd, qr, qdr, P, Pnom, lam, kg):
    """:func:`_energy_storage` as a compiled call (the non-inlined copy, shared by partial lane blocks
    and resets: inlining costs compile time)."""
    return _energy_storage(q, qd, qr, qdr, P, Pnom, lam, kg)


@accessor
def _diag_lane_in(lanes, j):
    q, qd, _u, _ext, p = MK.lane_load(lanes, j)
    L = MK.LANES
    qr = (lanes[SL.qr * L + j], lanes[(SL.qr + 1) * L + j], lanes[(SL.qr + 2) * L + j])
    qdr = (lanes[SL.qdr * L + j], lanes[(SL.qdr + 1) * L + j], lanes[(SL.qdr + 2) * L + j])
    return q, qd, qr, qdr, p


@jit
def diag_lanes(lanes, m, pnom, lam, kg):
    """Energy and storage of the first m lanes (SIMD for full blocks)."""
    L = MK.LANES
    if m == L:
        for j in range(L):
            q, qd, qr, qdr, p = _diag_lane_in(lanes, j)
            lanes[SL.energy * L + j], lanes[SL.storage * L + j] = _energy_storage(q, qd, qr, qdr, p, pnom, lam, kg)
    else:
        diag_lanes_partial(lanes, m, pnom, lam, kg)


@jit
def diag_lanes_partial(lanes, m, pnom, lam, kg):
    """The lane-by-lane path of :func:`diag_lanes` (any m <= LANES)."""
    L = MK.LANES
    for j in range(m):
        q, qd, qr, qdr, p = _diag_lane_in(lanes, j)
        lanes[SL.energy * L + j], lanes[SL.storage * L + j] = energy_storage(q, qd, qr, qdr, p, pnom, lam, kg)


@jit
def consistent_energy_lanes(lanes, m):
    """The plant's total energy of the first m lanes under the consistent model (replaces the paper
    model's in the energy row; the storage row is the controller's and stays)."""
    L = MK.LANES
    for j in range(m):
        q, qd, _u, _ext, p = MK.lane_load(lanes, j)
        kin, pot = MK.consistent_energies(q, qd, p)
        lanes[SL.energy * L + j] = kin + pot
