"""Branch-free, smooth evaluation of the curvature functions of the constant-curvature arms.

Every term of the model divides by powers of the curvature q (sin q / q, (1 - cos q)/q^2, ...).
These are entire functions of q, so instead of switching to a limit below some threshold delta (the
paper's approach, Sec. 4.1, zeroth-order accurate) we evaluate each one as a single truncated Taylor
series in s = q^2 by Horner's rule: a polynomial, hence smooth everywhere, exact at q = 0, with no
branch at all. The coefficients are exact rationals built here with :mod:`fractions`.

With ``N_TERMS`` = 18 terms the first omitted term is below 1e-19 for |q| <= 1.5 pi, so every basis
function is accurate to a few ulps of its scale on the model's domain |q| <= pi (the paper's Assumption
2); the tests compare them with sympy at 1e-14.

Basis functions (per arm, q the curvature), named as in ``docs/model.md``:

=========  ===================================  ===================  ==========
name       function                             q -> 0 limit         parity
=========  ===================================  ===================  ==========
``S0``     sin q / q                            1                    even
``C1``     (1 - cos q) / q^2                    1/2                  even
``A``      D1 / q = (sin q - q cos q) / q^3     1/3                  even
``D1p``    d D1 / dq                            1/3                  even
``D2``     (cos q + q sin q - 1) / q^2          1/2                  even
``D2pq``   (d D2 / dq) / q                      -1/4                 even
=========  ===================================  ===================  ==========

D1 = (sin q - q cos q)/q^2 and D2 are the paper's script-D_1 and script-D_2: the derivatives of the
left tip's body-frame position with respect to q_l, divided by l_l.
"""

from __future__ import annotations

from fractions import Fraction
from math import factorial

import numpy as np

N_TERMS = 18


def _coefficients(term) -> list[Fraction]:
    return [term(k) for k in range(N_TERMS + 2)]


def _sinc(k: int) -> Fraction:  # sin q / q
    return Fraction((-1) ** k, factorial(2 * k + 1))


def _c1(k: int) -> Fraction:  # (1 - cos q) / q^2
    return Fraction((-1) ** k, factorial(2 * k + 2))


def _a(k: int) -> Fraction:  # (sin q - q cos q) / q^3
    return Fraction((-1) ** k * 2 * (k + 1), factorial(2 * k + 3))


def _d2(k: int) -> Fraction:  # (cos q + q sin q - 1)/q^2 = S0 - C1
    return _sinc(k) - _c1(k)


def _odd_derivative(c: list[Fraction]) -> list[Fraction]:
    """Coefficients of d/dq [q P(q^2)] = sum (2k+1) c_k s^k."""
    return [(2 * k + 1) * ck for k, ck in enumerate(c)]


def _even_derivative_over_q(c: list[Fraction]) -> list[Fraction]:
    """Coefficients of (d/dq P(q^2)) / q = sum 2(k+1) c_{k+1} s^k."""
    return [2 * (k + 1) * c[k + 1] for k in range(len(c) - 1)]


EXACT_COEFFICIENTS: dict[str, list[Fraction]] = {
    "S0": _coefficients(_sinc)[:N_TERMS],
    "C1": _coefficients(_c1)[:N_TERMS],
    "A": _coefficients(_a)[:N_TERMS],
    "D1p": _odd_derivative(_coefficients(_a))[:N_TERMS],
    "D2": _coefficients(_d2)[:N_TERMS],
    "D2pq": _even_derivative_over_q(_coefficients(_d2))[:N_TERMS],
}

COEFFICIENTS: dict[str, np.ndarray] = {
    name: np.array([float(c) for c in coeffs], dtype=np.float64) for name, coeffs in EXACT_COEFFICIENTS.items()
}
for _arr in COEFFICIENTS.values():
    _arr.setflags(write=False)


def horner(coefficients: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Evaluate sum_k c_k q^(2k) for any array q (NumPy reference; the kernels inline the same loop)."""
    q = np.asarray(q, dtype=np.float64)
    s = q * q
    acc = np.full_like(s, coefficients[-1])
    for c in coefficients[-2::-1]:
        acc = acc * s + c
    return acc
