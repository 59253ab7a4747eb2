"""The branch-free power series of softpvtol_gym._series_coefficients against 110-digit sympy/mpmath references.

The references are the closed forms (sin q / q, ...) evaluated with mpmath at 110 significant
digits, which survives the cancellation near q = 0 (at q = 1e-9 the worst basis function loses
~36 digits), and at exactly q = 0 the symbolic limit.
"""

from __future__ import annotations

import functools

import mpmath
import numpy as np
import pytest
import sympy as sp

from softpvtol_gym._series_coefficients import COEFFICIENTS, horner

_DPS = 110
ATOL = 1e-14

SPECIAL_Q = [0.0, 1e-9, 1e-6, 0.1 - 1e-9, 0.1, 0.1 + 1e-9, np.pi, -np.pi, 1.0]
GRID = np.linspace(-np.pi, np.pi, 257)  # includes 0.0 and +-pi exactly

_q = sp.Symbol("q", real=True)
_D1 = (sp.sin(_q) - _q * sp.cos(_q)) / _q**2  # paper's script-D_1 (d/dq of the left tip's x, / l)
_D2 = (sp.cos(_q) + _q * sp.sin(_q) - 1) / _q**2  # paper's script-D_2
BASIS = {
    "S0": sp.sin(_q) / _q,
    "C1": (1 - sp.cos(_q)) / _q**2,
    "A": (sp.sin(_q) - _q * sp.cos(_q)) / _q**3,
    "D1p": sp.diff(_D1, _q),
    "D2": _D2,
    "D2pq": sp.diff(_D2, _q) / _q,
}
LIMITS_AT_ZERO = {"S0": 1, "C1": sp.Rational(1, 2), "A": sp.Rational(1, 3), "D1p": sp.Rational(1, 3),
                  "D2": sp.Rational(1, 2), "D2pq": sp.Rational(-1, 4)}  # fmt: skip


@functools.cache
def _evaluator(name):
    return sp.lambdify(_q, BASIS[name], modules="mpmath"), sp.limit(BASIS[name], _q, 0)


def reference(name, qs):
    fn, at_zero = _evaluator(name)
    out = []
    with mpmath.workdps(_DPS):
        for v in np.atleast_1d(qs):
            v = float(v)
            out.append(float(at_zero) if v == 0.0 else float(fn(mpmath.mpf(v))))
    return np.array(out)


def test_basis_names():
    assert set(COEFFICIENTS) == set(BASIS)


@pytest.mark.parametrize("name", sorted(BASIS))
def test_limits_at_zero(name):
    """The symbolic limits used as references are the documented ones (and the series' c_0)."""
    _, at_zero = _evaluator(name)
    assert sp.simplify(at_zero - LIMITS_AT_ZERO[name]) == 0
    assert COEFFICIENTS[name][0] == float(LIMITS_AT_ZERO[name])


@pytest.mark.parametrize("name", sorted(BASIS))
@pytest.mark.parametrize("q", SPECIAL_Q)
def test_series_at_special_points(name, q):
    got = horner(COEFFICIENTS[name], np.array([q]))
    ref = reference(name, [q])
    assert abs(got[0] - ref[0]) <= ATOL, f"{name}({q!r}): series {got[0]!r}, reference {ref[0]!r}"


@pytest.mark.parametrize("name", sorted(BASIS))
def test_series_on_grid(name):
    got = horner(COEFFICIENTS[name], GRID)
    ref = reference(name, GRID)
    err = np.abs(got - ref)
    i = int(np.argmax(err))
    assert err[i] <= ATOL, f"{name}({GRID[i]!r}): series {got[i]!r}, reference {ref[i]!r}"


@pytest.mark.parametrize("name", sorted(BASIS))
def test_series_even_and_smooth_at_zero(name):
    """Even functions: f(-q) == f(q) bit for bit; and no jump around the paper's delta = 0.1."""
    qs = np.array([1e-300, 1e-12, 1e-9, 0.05, 0.1 - 1e-12, 0.1, 0.1 + 1e-12, 1.7, np.pi])
    c = COEFFICIENTS[name]
    np.testing.assert_array_equal(horner(c, qs), horner(c, -qs))
    assert horner(c, np.array(0.0)) == c[0]
    jump = horner(c, np.array(0.1 + 1e-12)) - horner(c, np.array(0.1 - 1e-12))
    assert abs(jump) < 1e-11


@pytest.mark.parametrize("name", sorted(BASIS))
def test_coefficients_are_the_taylor_coefficients(name):
    """COEFFICIENTS[name][k] is the (correctly rounded) coefficient of q^(2k) of the closed form."""
    coeffs = COEFFICIENTS[name]
    n = len(coeffs)
    assert n >= 15
    ser = sp.series(BASIS[name], _q, 0, 2 * n).removeO()
    for k in range(2 * n):
        exact = ser.coeff(_q, k)
        if k % 2:
            assert exact == 0
        else:
            assert coeffs[k // 2] == float(exact), (name, k // 2, coeffs[k // 2], exact)


def test_horner_shapes():
    c = COEFFICIENTS["S0"]
    q = np.linspace(-1, 1, 12).reshape(3, 4)
    out = horner(c, q)
    assert out.shape == (3, 4)
    np.testing.assert_array_equal(out.ravel(), horner(c, q.ravel()))
    assert np.ndim(horner(c, 0.5)) == 0
    assert abs(float(horner(c, 0.5)) - np.sin(0.5) / 0.5) < 1e-15


@pytest.mark.parametrize("name", sorted(BASIS))
def test_series_accurate_up_to_one_and_a_half_pi(name):
    """The module docstring promises ulp-level accuracy on |q| <= 1.5 pi (first omitted term < 1e-19)."""
    qs = np.linspace(-1.5 * np.pi, 1.5 * np.pi, 97)
    err = np.abs(horner(COEFFICIENTS[name], qs) - reference(name, qs))
    assert err.max() <= 1e-14
