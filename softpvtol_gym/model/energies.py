"""Kinetic and potential energy of the paper's and the consistent model (the tests' physics checks:
energy conservation, passivity)."""

from __future__ import annotations

import math

from ..params import P_G, P_LL, P_LR, P_M, P_ML, P_MR
from .consistent import consistent_arms, consistent_mass_entries
from .jit import inline, jit
from .paper import mass_entries
from .series import one_minus_cos_over_q2


@inline
def kinetic_energy(q, qd, p):
    """T = 1/2 qdot^T D(q) qdot from D's entries (:func:`mass_entries`)."""
    M, inertia, d03, d13, d04, d14, d33, d44 = mass_entries(q[3], q[4], p)
    vx, vz, w, vl, vr = qd[0], qd[1], qd[2], qd[3], qd[4]
    e = M * (vx * vx + vz * vz) + inertia * w * w
    e += 2.0 * vl * (d03 * vx + d13 * vz) + 2.0 * vr * (d04 * vx + d14 * vz)
    e += d33 * vl * vl + d44 * vr * vr
    return 0.5 * e


@inline
def potential_energy(q, p):
    """P = g (M z + m_l z_l^tip + m_r z_r^tip), tip heights l q (1 - cos q)/q^2 above the body."""
    zl = p[P_LL] * q[3] * one_minus_cos_over_q2(q[3])
    zr = p[P_LR] * q[4] * one_minus_cos_over_q2(q[4])
    return p[P_G] * ((p[P_M] + p[P_ML] + p[P_MR]) * q[1] + p[P_ML] * zl + p[P_MR] * zr)



@inline
def consistent_kinetic_energy(q, qd, p):
    """T = 1/2 qdot^T D(q) qdot of the consistent model."""
    al, ar = consistent_arms(q[3], q[4], p)
    M, d02, d12, d03, d13, d04, d14, d22, d23, d24, d33, d44 = consistent_mass_entries(
        math.sin(q[2]), math.cos(q[2]), al, ar, p)
    vx, vz, w, vl, vr = qd[0], qd[1], qd[2], qd[3], qd[4]
    e = M * (vx * vx + vz * vz) + d22 * w * w + d33 * vl * vl + d44 * vr * vr
    e += 2.0 * w * (d02 * vx + d12 * vz + d23 * vl + d24 * vr)
    e += 2.0 * vl * (d03 * vx + d13 * vz) + 2.0 * vr * (d04 * vx + d14 * vz)
    return 0.5 * e


@inline
def consistent_potential_energy(q, p):
    """P = g (M z + m_l z_l + m_r z_r), z_i = (R(theta) r_i)_z the rotated tips' heights above the body."""
    al, ar = consistent_arms(q[3], q[4], p)
    st, ct = math.sin(q[2]), math.cos(q[2])
    sx = p[P_ML] * al[0] + p[P_MR] * ar[0]
    sz = p[P_ML] * al[1] + p[P_MR] * ar[1]
    return p[P_G] * ((p[P_M] + p[P_ML] + p[P_MR]) * q[1] + st * sx + ct * sz)


@jit
def consistent_energies(q, qd, p):
    """(kinetic, potential) of the consistent model (a compiled call)."""
    return consistent_kinetic_energy(q, qd, p), consistent_potential_energy(q, p)
