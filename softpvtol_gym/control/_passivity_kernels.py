"""Compiled kernels of the passivity law and its storage function (paper eqs. (passControl), (lyap)).

Built on the model kernels (:mod:`softpvtol_gym._kernels`): D, C and g are never written again here.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .. import model as MK

_jit = njit(cache=True, fastmath=False, nogil=True, error_model="numpy")


@MK.inline
def model_entries(q, qd, p):
    """The nonzero entries of D(q), C(q, qdot), g(q) (model kernels: mass_entries, coriolis_entries,
    gravity_entries)."""
    bl, br = MK.arm_basis(q[3]), MK.arm_basis(q[4])
    return (MK.mass_entries_basis(bl, br, p), MK.coriolis_entries_basis(bl, br, qd[3], qd[4], p),
            MK.gravity_entries_basis(bl, br, p))


@MK.inline
def _row(acc, d0, d1, d2, d3, d4, c0, c1, c2, c3, c4, a, v):
    """acc + sum_j (D_ij a_j + C_ij v_j), term by term in j order (the dense loop's rounding; zero
    entries are multiplied, so inf/NaN propagate as in the dense product)."""
    acc += d0 * a[0] + c0 * v[0]
    acc += d1 * a[1] + c1 * v[1]
    acc += d2 * a[2] + c2 * v[2]
    acc += d3 * a[3] + c3 * v[3]
    acc += d4 * a[4] + c4 * v[4]
    return acc


@MK.inline
def passivity_rows(ents, q, qd, qr, qdr, qddr, lam, kg):
    """tau = D(q) a + C(q, qd) v + g(q) - K r as a 5-tuple, D, C, g given by their entries
    (:func:`model_entries`); v = qdot_ref - Lambda q~, a = qddot_ref - Lambda (qdot - qdot_ref)."""
    (M, inertia, d03, d13, d04, d14, d33, d44), (c03, c13, c04, c14, c33, c44), (g1, g3, g4) = ents
    v = (qdr[0] - lam[0] * (q[0] - qr[0]), qdr[1] - lam[1] * (q[1] - qr[1]), qdr[2] - lam[2] * (q[2] - qr[2]),
         qdr[3] - lam[3] * (q[3] - qr[3]), qdr[4] - lam[4] * (q[4] - qr[4]))
    a = (qddr[0] - lam[0] * (qd[0] - qdr[0]), qddr[1] - lam[1] * (qd[1] - qdr[1]),
         qddr[2] - lam[2] * (qd[2] - qdr[2]), qddr[3] - lam[3] * (qd[3] - qdr[3]),
         qddr[4] - lam[4] * (qd[4] - qdr[4]))
    z = 0.0
    return (
        _row(z - kg[0] * (qd[0] - v[0]), M, z, z, d03, d04, z, z, z, c03, c04, a, v),
        _row(g1 - kg[1] * (qd[1] - v[1]), z, M, z, d13, d14, z, z, z, c13, c14, a, v),
        _row(z - kg[2] * (qd[2] - v[2]), z, z, inertia, z, z, z, z, z, z, z, a, v),
        _row(g3 - kg[3] * (qd[3] - v[3]), d03, d13, z, d33, z, z, z, z, c33, z, a, v),
        _row(g4 - kg[4] * (qd[4] - v[4]), d04, d14, z, z, d44, z, z, z, z, c44, a, v),
    )


@_jit
def passivity_into(q, qd, qr, qdr, qddr, p, lam, kg, out):
    """tau = D(q) a + C(q, qd) v + g(q) - K r  (Slotine–Li / Spong form, paper eq. (passControl))."""
    t = passivity_rows(model_entries(q, qd, p), q, qd, qr, qdr, qddr, lam, kg)
    out[0], out[1], out[2], out[3], out[4] = t


@MK.inline
def storage(q, qd, qr, qdr, p, lam, kg):
    """V = 1/2 r^T D r + q~^T Lambda K q~ (paper eq. (lyap)), r = q~dot + Lambda q~; arrays or tuples,
    no allocation. D enters through its nonzero entries (MK.mass_entries)."""
    M, inertia, d03, d13, d04, d14, d33, d44 = MK.mass_entries(q[3], q[4], p)
    e0, e1, e2, e3, e4 = q[0] - qr[0], q[1] - qr[1], q[2] - qr[2], q[3] - qr[3], q[4] - qr[4]
    r0 = qd[0] - qdr[0] + lam[0] * e0
    r1 = qd[1] - qdr[1] + lam[1] * e1
    r2 = qd[2] - qdr[2] + lam[2] * e2
    r3 = qd[3] - qdr[3] + lam[3] * e3
    r4 = qd[4] - qdr[4] + lam[4] * e4
    rDr = (M * (r0 * r0 + r1 * r1) + inertia * r2 * r2 + d33 * r3 * r3 + d44 * r4 * r4
           + 2.0 * (r3 * (d03 * r0 + d13 * r1) + r4 * (d04 * r0 + d14 * r1)))
    return (lam[0] * kg[0] * e0 * e0 + lam[1] * kg[1] * e1 * e1 + lam[2] * kg[2] * e2 * e2
            + lam[3] * kg[3] * e3 * e3 + lam[4] * kg[4] * e4 * e4 + 0.5 * rDr)


@_jit
def storage_into(q, qd, qr, qdr, p, lam, kg):
    """:func:`storage` (compiled entry point for arrays)."""
    return storage(q, qd, qr, qdr, p, lam, kg)


# ------------------------------------------------------------------------------------- batched
# One thread each, GIL released: the public API splits large batches over threads.
_batch = njit(cache=True, nogil=True)


@_batch
def batch_passivity(q, qd, qr, qdr, qddr, P, lam, kg, out):
    ps = np.int64(P.shape[0] > 1)
    for n in range(q.shape[0]):
        passivity_into(q[n], qd[n], qr[n], qdr[n], qddr[n], P[n * ps], lam, kg, out[n])


@_batch
def batch_storage(q, qd, qr, qdr, P, lam, kg, out):
    ps = np.int64(P.shape[0] > 1)
    for n in range(q.shape[0]):
        out[n] = storage_into(q[n], qd[n], qr[n], qdr[n], P[n * ps], lam, kg)
