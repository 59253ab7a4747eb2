"""The curvature series of the arms, compiled: Horner's rule and the basis functions built on it.

The coefficients come from :mod:`softpvtol_gym._series_coefficients` (exact rationals); here they are evaluated
branch-free as polynomials in s = q^2, so every model term is smooth at q = 0 and a lane loop stays
SIMD code. Also the attitude rotation of an RK4 stage (:func:`rotate`), which uses the same series.
"""

from __future__ import annotations

import math

from .._series_coefficients import COEFFICIENTS
from .jit import inline, jit

#: the coefficient vectors of the basis functions (``_series_coefficients`` names: S0, C1, A, D1p, D2, D2pq)
S0_COEFFS = COEFFICIENTS["S0"]
C1_COEFFS = COEFFICIENTS["C1"]
A_COEFFS = COEFFICIENTS["A"]
D1P_COEFFS = COEFFICIENTS["D1p"]
D2_COEFFS = COEFFICIENTS["D2"]
D2PQ_COEFFS = COEFFICIENTS["D2pq"]

#: coefficients of every series (``_series_coefficients.N_TERMS``): :func:`horner` is written out for this many
HORNER_TERMS = 18
if any(len(c) != HORNER_TERMS for c in COEFFICIENTS.values()):  # pragma: no cover
    raise RuntimeError(f"model.series.horner is written out for {HORNER_TERMS} coefficients; update it for "
                       f"{ {k: len(c) for k, c in COEFFICIENTS.items()} }")


@jit
def horner(c, s):
    """c[0] + c[1] s + ... + c[17] s^17 by Horner's rule, from the highest coefficient down.

    The one small function here that numba does *not* inline: it is called a few hundred times per
    step kernel, and numba's inliner re-types and copies every inlined copy (most of the cold compile
    time). LLVM inlines the call (so lane loops stay SIMD); written out rather than looped, it is one
    straight block, the same operations in the same order as the loop."""
    acc = c[17]
    acc = acc * s + c[16]
    acc = acc * s + c[15]
    acc = acc * s + c[14]
    acc = acc * s + c[13]
    acc = acc * s + c[12]
    acc = acc * s + c[11]
    acc = acc * s + c[10]
    acc = acc * s + c[9]
    acc = acc * s + c[8]
    acc = acc * s + c[7]
    acc = acc * s + c[6]
    acc = acc * s + c[5]
    acc = acc * s + c[4]
    acc = acc * s + c[3]
    acc = acc * s + c[2]
    acc = acc * s + c[1]
    acc = acc * s + c[0]
    return acc


@inline
def arm_basis(q):
    """(D1, D2, dD1/dq, dD2/dq) of one arm's curvature q: branch-free power series."""
    s = q * q
    return q * horner(A_COEFFS, s), horner(D2_COEFFS, s), horner(D1P_COEFFS, s), q * horner(D2PQ_COEFFS, s)


@inline
def sinc(q):
    return horner(S0_COEFFS, q * q)


@inline
def one_minus_cos_over_q2(q):
    return horner(C1_COEFFS, q * q)


@inline
def sin_cos(q):
    """(sin q, cos q) = (q sinc q, 1 - q^2 (1 - cos q)/q^2) from the same series as the rest of the
    model (a few ulps for |q| <= 1.2 pi, 3e-14 at 2 pi): polynomial arithmetic only, so that a lane
    loop that evaluates the input map stays SIMD code. Used for the arm curvatures."""
    s = q * q
    return q * horner(S0_COEFFS, s), 1.0 - s * horner(C1_COEFFS, s)


TWO_PI = 2.0 * math.pi


@inline
def rotate(s0, c0, d):
    """(sin, cos) of theta + d from (s0, c0) = (sin theta, cos theta), d reduced to [-pi, pi] and
    evaluated by the series (branch-free, SIMD): the attitude at an RK4 stage from the step's start."""
    d = d - TWO_PI * math.floor(d / TWO_PI + 0.5)
    sd, cd = sin_cos(d)
    return s0 * cd + c0 * sd, c0 * cd - s0 * sd
