"""The model core against an independent symbolic derivation (sympy) of both Lagrangians.

The reference is built here from scratch, following Sec. 2 / Appendix A of the paper:

* body-frame tip offsets r_l = (-eps - l_l sin q_l / q_l, l_l (1 - cos q_l)/q_l),
  r_r = (eps + l_r sin q_r / q_r, l_r (1 - cos q_r)/q_r), p_v = (x, z);
* model "paper": tips p_i = p_v + r_i (NOT rotated by theta, as in the paper's Lagrangian);
  model "consistent": tips p_i = p_v + R(theta) r_i;
* K = 1/2 m |p_v'|^2 + 1/2 m_l |p_l'|^2 + 1/2 m_r |p_r'|^2 + 1/2 I th'^2 + 1/2 I_l q_l'^2 + 1/2 I_r q_r'^2,
  P = g (m z + m_l z_l + m_r z_r);
* D = Hessian of K in qdot, C_kj = sum_i 1/2 (dD_kj/dq_i + dD_ki/dq_j - dD_ij/dq_k) qdot_i, g = dP/dq;
* input maps: "paper" as printed; "exact" = J^T F with the thrusts applied at the body-rotated tips
  along their rotated directions (virtual work), the consistent model's own map.

Every reference value is evaluated with mpmath at ``_DPS`` significant digits from the *closed forms*
(which lose up to ~50 digits to cancellation near q = 0, far less than ``_DPS``), and at exactly
q = 0 from the exact symbolic limit (series expansion, ``limit_at_zero``, checked against
``sympy.limit``). The package is then required to agree to 1e-12
relative to max(1, |reference entry|).
"""

from __future__ import annotations

import functools
import zlib

import mpmath
import numba
import numpy as np
import pytest
import sympy as sp

from softpvtol_gym import SoftPVTOLParams, dynamics, integrators
from softpvtol_gym.params import PARAM_MIN

# one worker derives the symbolic model once (cached) and runs every case against it
pytestmark = pytest.mark.xdist_group("sympy")

_DPS = 110  # working precision of the reference: 1/q^5 at q = 1e-9 costs ~45 digits
RTOL = 1e-12  # the worst entry over these tests is 8.2e-15 relative (either model)

SPECIAL_Q = [0.0, 1e-9, 1e-6, 0.1 - 1e-9, 0.1, 0.1 + 1e-9, np.pi, -np.pi, 1.0]

PARAM_NAMES = ("m", "m_l", "m_r", "I", "I_l", "I_r", "l_l", "l_r", "g", "epsilon")


@pytest.fixture(autouse=True)
def _one_numba_thread():
    """Run the kernels' prange loops on one thread: these tests make thousands of tiny calls, and on
    a loaded 2-core machine each multi-threaded parallel region costs ~1 ms of spinning/waiting.
    (Results are per element and do not depend on the thread count; the batching test restores
    all threads for itself.)"""
    old = numba.get_num_threads()
    numba.set_num_threads(1)
    yield
    numba.set_num_threads(old)


# ------------------------------------------------------------------------------ symbolic model
_MAX_POLE = 6  # the closed forms have poles of order <= 5 in each curvature


@functools.cache
def limit_at_zero(expr, var):
    """Exact lim_{var -> 0} of an expression polynomial in (var, 1/var, sin var, cos var).

    sin and cos are replaced by their Taylor polynomials (exact rationals, far beyond the pole
    order), which makes var^_MAX_POLE * expr an exact polynomial in var up to terms of degree
    > _MAX_POLE. Its coefficients below _MAX_POLE (the poles) must vanish identically, and the one of
    var^_MAX_POLE is the limit. (Cross-checked against sympy.limit; ~20x faster.)
    """
    order = 2 * _MAX_POLE + 3
    sin_p = sum((-1) ** k * var ** (2 * k + 1) / sp.factorial(2 * k + 1) for k in range(order // 2 + 1))
    cos_p = sum((-1) ** k * var ** (2 * k) / sp.factorial(2 * k) for k in range(order // 2 + 1))
    poly = sp.Poly(sp.expand(expr.subs({sp.sin(var): sin_p, sp.cos(var): cos_p}) * var**_MAX_POLE), var)
    coeffs = dict(zip((m[0] for m in poly.monoms()), poly.coeffs()))
    for k in range(_MAX_POLE):
        assert sp.expand(coeffs.get(k, 0)) == 0, f"pole of order {_MAX_POLE - k} in {expr}"
    return coeffs.get(_MAX_POLE, sp.Integer(0))


MODELS = ("paper", "consistent")
#: the input maps each model accepts (the consistent model: only its own virtual-work map)
MODEL_INPUT_MAPS = {"paper": ("paper", "exact"), "consistent": ("exact",)}


@functools.cache
def _symbolic_model(model: str = "paper"):
    """Derive everything symbolically once per model; return mpmath-lambdified evaluators per q = 0
    pattern."""
    x, z, th, ql, qr = sp.symbols("x z theta q_l q_r", real=True)
    xd, zd, thd, qld, qrd = sp.symbols("xd zd thd qld qrd", real=True)
    m, ml, mr, I, Il, Ir, ll, lr, g, eps = sp.symbols("m m_l m_r I I_l I_r l_l l_r g epsilon", positive=True)
    Tl, Tr, taul, taur = sp.symbols("T_l T_r tau_l tau_r", real=True)
    q = [x, z, th, ql, qr]
    qd = [xd, zd, thd, qld, qrd]
    params = [m, ml, mr, I, Il, Ir, ll, lr, g, eps]
    act = [Tl, Tr, taul, taur]

    # body-frame offsets of the tips (eq. (coords)); the Lagrangian uses them unrotated
    r_l = sp.Matrix([-eps - ll * sp.sin(ql) / ql, ll * (1 - sp.cos(ql)) / ql])
    r_r = sp.Matrix([eps + lr * sp.sin(qr) / qr, lr * (1 - sp.cos(qr)) / qr])
    p_v = sp.Matrix([x, z])
    R = sp.Matrix([[sp.cos(th), -sp.sin(th)], [sp.sin(th), sp.cos(th)]])
    if model == "paper":
        p_l = p_v + r_l
        p_r = p_v + r_r
    else:
        p_l = p_v + R * r_l
        p_r = p_v + R * r_r

    def vel(p):
        return p.jacobian(q) * sp.Matrix(qd)

    K = sp.Rational(1, 2) * (
        m * vel(p_v).dot(vel(p_v))
        + ml * vel(p_l).dot(vel(p_l))
        + mr * vel(p_r).dot(vel(p_r))
        + I * thd**2
        + Il * qld**2
        + Ir * qrd**2
    )
    P = g * (m * z + ml * p_l[1] + mr * p_r[1])
    D = sp.hessian(K, qd).applyfunc(sp.expand)
    C = sp.zeros(5, 5)
    for k in range(5):
        for j in range(5):
            C[k, j] = sp.expand(
                sum(
                    sp.Rational(1, 2)
                    * (sp.diff(D[k, j], q[i]) + sp.diff(D[k, i], q[j]) - sp.diff(D[i, j], q[k]))
                    * qd[i]
                    for i in range(5)
                )
            )
    G = sp.Matrix([sp.diff(P, qi) for qi in q])

    # physical tips: p_v + R(theta) r_i
    tip_l = p_v + R * r_l
    tip_r = p_v + R * r_r

    # input maps
    vx = Tl * sp.sin(ql) - Tr * sp.sin(qr)
    vz = Tl * sp.cos(ql) + Tr * sp.cos(qr)
    txz = R * sp.Matrix([vx, vz])
    paper = sp.Matrix(
        [
            txz[0],
            txz[1],
            lr * Tr * sp.cos(qr) * sp.sin(qr) / qr - ll * Tl * sp.cos(ql) * sp.sin(ql) / ql,
            taul,
            taur,
        ]
    )
    F_l = R * sp.Matrix([sp.sin(ql), sp.cos(ql)]) * Tl
    F_r = R * sp.Matrix([-sp.sin(qr), sp.cos(qr)]) * Tr
    exact = tip_l.jacobian(q).T * F_l + tip_r.jacobian(q).T * F_r + sp.Matrix([0, 0, 0, taul, taur])

    blocks = {
        "D": list(D),
        "C": list(C),
        "g": list(G),
        "K": [K],
        "P": [P],
        "tips": [p_l[0], p_l[1], p_r[0], p_r[1]],  # the model's own (where its Lagrangian puts the masses)
        "exact": list(exact),
    }
    if model == "paper":
        blocks["paper"] = list(paper)
    names = list(blocks)
    flat = [e for n in names for e in blocks[n]]
    sizes = [len(blocks[n]) for n in names]
    args = q + qd + params + act

    def with_limits(exprs, at_l, at_r):
        out = []
        for e in exprs:
            if at_l and e.has(ql):
                e = limit_at_zero(e, ql)
            if at_r and e.has(qr):
                e = limit_at_zero(e, qr)
            out.append(e)
        return out

    evaluators = {}
    for at_l in (False, True):
        for at_r in (False, True):
            exprs = with_limits(flat, at_l, at_r)
            for e in exprs:  # the limits must be finite (the model has no singularity)
                assert not e.has(sp.oo, -sp.oo, sp.zoo, sp.nan), e
            evaluators[(at_l, at_r)] = sp.lambdify(args, exprs, modules="mpmath")
    return names, sizes, evaluators


def reference(q, qd, p: SoftPVTOLParams, a, model: str = "paper"):
    """High-precision reference values (as float64 arrays) of every block at one state."""
    names, sizes, evaluators = _symbolic_model(model)
    q = [float(v) for v in q]
    fn = evaluators[(q[3] == 0.0, q[4] == 0.0)]
    values = [mpmath.mpf(float(v)) for v in (*q, *qd, *(getattr(p, n) for n in PARAM_NAMES), *a)]
    with mpmath.workdps(_DPS):
        flat = fn(*values)
        flat = np.array([float(mpmath.mpf(v)) for v in flat])
    out, k = {}, 0
    for n, s in zip(names, sizes):
        out[n] = flat[k : k + s]
        k += s
    out["D"] = out["D"].reshape(5, 5)
    out["C"] = out["C"].reshape(5, 5)
    out["K"] = out["K"][0]
    out["P"] = out["P"][0]
    out["tips"] = out["tips"].reshape(2, 2)
    return out


def package(q, qd, p, a, model: str = "paper"):
    out = {
        "D": dynamics.mass_matrix(q, p, model=model),
        "C": dynamics.coriolis_matrix(q, qd, p, model=model),
        "g": dynamics.gravity_vector(q, p, model=model),
        "K": dynamics.kinetic_energy(q, qd, p, model=model),
        "P": dynamics.potential_energy(q, p, model=model),
        "tips": dynamics.arm_tip_positions(q, p, model=model),
    }
    for input_map in MODEL_INPUT_MAPS[model]:
        out[input_map] = dynamics.generalized_forces(q, a, p, input_map=input_map, model=model)
    # the model's own map (input_map=None) is "paper" for the paper's model, "exact" for the consistent one
    own = dynamics.generalized_forces(q, a, p, model=model)
    assert np.array_equal(own, out[dynamics.NATURAL_INPUT_MAP[model]])
    return out


def assert_matches(got, ref, context):
    for name, r in ref.items():
        v = np.asarray(got[name], dtype=np.float64)
        r = np.asarray(r)
        assert v.shape == r.shape, (name, v.shape, r.shape)
        err = np.abs(v - r) / np.maximum(1.0, np.abs(r))
        worst = np.unravel_index(np.argmax(err), err.shape) if err.ndim else ()
        assert np.all(err <= RTOL), (
            f"{name} differs from the symbolic model at {context}: worst entry {worst}: "
            f"package {v[worst]!r} vs sympy {r[worst]!r} (rel err {err[worst]:.3e})"
        )


def random_params(rng) -> SoftPVTOLParams:
    return SoftPVTOLParams(
        m=rng.uniform(1.0, 8.0),
        m_l=rng.uniform(0.2, 2.0),
        m_r=rng.uniform(0.2, 2.0),
        I=rng.uniform(0.2, 2.0),
        I_l=rng.uniform(0.02, 0.3),
        I_r=rng.uniform(0.02, 0.3),
        l_l=rng.uniform(0.2, 1.0),
        l_r=rng.uniform(0.2, 1.0),
        g=rng.uniform(5.0, 12.0),
        epsilon=rng.uniform(0.05, 0.3),
    )


def random_state(rng):
    q = np.array(
        [rng.uniform(-3, 3), rng.uniform(-3, 3),
         rng.uniform(-np.pi, np.pi), rng.uniform(-np.pi, np.pi), rng.uniform(-np.pi, np.pi)]
    )
    qd = rng.uniform(-3.0, 3.0, size=5)
    a = np.array([rng.uniform(0, 40), rng.uniform(0, 40), rng.uniform(-5, 5), rng.uniform(-5, 5)])
    return q, qd, a


# ------------------------------------------------------------------------------------------- tests
@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("seed", range(20))
def test_matches_sympy_at_random_states(seed, model):
    rng = np.random.default_rng(1000 + seed)
    p = random_params(rng)
    q, qd, a = random_state(rng)
    assert_matches(package(q, qd, p, a, model), reference(q, qd, p, a, model),
                   f"model={model}, q={q.tolist()}, qd={qd.tolist()}, {p}")


# each special curvature appears on both arms, paired with a different one on the other arm
_SPECIAL_PAIRS = [(SPECIAL_Q[i], SPECIAL_Q[(i + 4) % len(SPECIAL_Q)]) for i in range(len(SPECIAL_Q))]
_SPECIAL_PAIRS += [(b, a) for a, b in _SPECIAL_PAIRS] + [(0.0, 0.0), (np.pi, -np.pi)]


@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize(("q_l", "q_r"), _SPECIAL_PAIRS)
def test_matches_sympy_at_special_curvatures(q_l, q_r, model):
    rng = np.random.default_rng(zlib.crc32(repr((q_l, q_r)).encode()))
    p = random_params(rng)
    q, qd, a = random_state(rng)
    q[3], q[4] = q_l, q_r
    assert_matches(package(q, qd, p, a, model), reference(q, qd, p, a, model),
                   f"model={model}, q_l={q_l!r}, q_r={q_r!r}, {p}")


@pytest.mark.parametrize("theta", [0.0, np.pi, -np.pi, 0.5 * np.pi, -2.0])
def test_consistent_model_matches_sympy_at_special_attitudes(theta):
    """The consistent model depends on theta: at theta = 0, +-pi, pi/2 and with both arms at 0 / +-pi."""
    rng = np.random.default_rng(zlib.crc32(repr(theta).encode()))
    p = random_params(rng)
    for q_l, q_r in [(0.0, 0.0), (np.pi, -np.pi), (0.0, np.pi), (1e-9, -1.0)]:
        q, qd, a = random_state(rng)
        q[2], q[3], q[4] = theta, q_l, q_r
        assert_matches(package(q, qd, p, a, "consistent"), reference(q, qd, p, a, "consistent"),
                       f"theta={theta!r}, q_l={q_l!r}, q_r={q_r!r}, {p}")


@pytest.mark.parametrize("seed", range(3))
def test_models_agree_where_they_should(seed):
    """At theta = 0 the two models' tips, potential energy and input map coincide; their mass matrices
    differ only by the theta row and column (the rotor masses' coupling with the attitude), which the
    paper's model lacks; with m_l, m_r -> 0 the difference vanishes."""
    rng = np.random.default_rng(50 + seed)
    p = random_params(rng)
    q, qd, a = random_state(rng)
    q[2] = 0.0
    np.testing.assert_allclose(dynamics.arm_tip_positions(q, p, model="consistent"),
                               dynamics.arm_tip_positions(q, p, model="paper"), rtol=0, atol=1e-14)
    np.testing.assert_allclose(dynamics.potential_energy(q, p, model="consistent"),
                               dynamics.potential_energy(q, p, model="paper"), rtol=1e-14, atol=1e-12)
    Dc, Dp = dynamics.mass_matrix(q, p, model="consistent"), dynamics.mass_matrix(q, p, model="paper")
    keep = [0, 1, 3, 4]
    np.testing.assert_allclose(Dc[np.ix_(keep, keep)], Dp[np.ix_(keep, keep)], rtol=1e-14, atol=1e-14)
    assert np.abs(Dc[2] - Dp[2]).max() > 1e-3  # the coupling the paper's model drops
    np.testing.assert_allclose(dynamics.gravity_vector(q, p, model="consistent")[[0, 1, 3, 4]],
                               dynamics.gravity_vector(q, p)[[0, 1, 3, 4]], rtol=1e-14, atol=1e-12)
    np.testing.assert_allclose(dynamics.generalized_forces(q, a, p, model="consistent"),
                               dynamics.generalized_forces(q, a, p, "exact"), rtol=0, atol=0)
    # the difference is linear in the rotor masses: scaled down to the smallest mass SoftPVTOLParams takes
    # (1e-6 kg), it shrinks by the same factor
    scale = PARAM_MIN / min(p.m_l, p.m_r) * (1.0 + 1e-9)  # (not below PARAM_MIN by a rounding)
    light = p.replace(m_l=p.m_l * scale, m_r=p.m_r * scale)
    gap = np.abs(dynamics.mass_matrix(q, p, model="consistent") - dynamics.mass_matrix(q, p, model="paper")).max()
    gap_light = np.abs(dynamics.mass_matrix(q, light, model="consistent")
                       - dynamics.mass_matrix(q, light, model="paper")).max()
    assert gap > 1e-3 and gap_light <= 1.001 * scale * gap + 1e-14, (gap, gap_light, scale)


def test_consistent_body_inertia_with_straight_arms():
    """D_theta_theta = I + sum m_i |r_i|^2 = 1 + 2 x 1 kg x (0.5 m)^2 = 1.5 with the paper's parameters
    (eps = 0) and straight arms, at any attitude; the paper's model has I = 1."""
    p = SoftPVTOLParams()
    for theta in (0.0, 0.8, -2.5):
        q = np.array([0.3, 1.0, theta, 0.0, 0.0])
        assert dynamics.mass_matrix(q, p, model="consistent")[2, 2] == pytest.approx(1.5, rel=1e-15)
        assert dynamics.mass_matrix(q, p)[2, 2] == 1.0


@pytest.mark.parametrize("bad", ["Paper", "exact", "", None, 1])
def test_unknown_model_raises(bad):
    p = SoftPVTOLParams()
    calls = [
        lambda: dynamics.mass_matrix(np.zeros(5), p, model=bad),
        lambda: dynamics.coriolis_matrix(np.zeros(5), np.zeros(5), p, model=bad),
        lambda: dynamics.gravity_vector(np.zeros(5), p, model=bad),
        lambda: dynamics.generalized_forces(np.zeros(5), np.ones(4), p, model=bad),
        lambda: dynamics.forward_dynamics(np.zeros(5), np.zeros(5), np.zeros(5), p, model=bad),
        lambda: dynamics.kinetic_energy(np.zeros(5), np.zeros(5), p, model=bad),
        lambda: dynamics.potential_energy(np.zeros(5), p, model=bad),
        lambda: dynamics.total_energy(np.zeros(5), np.zeros(5), p, model=bad),
        lambda: dynamics.arm_tip_positions(np.zeros(5), p, model=bad),
        lambda: integrators.rk4_step(np.zeros(5), np.zeros(5), np.zeros(5), p, 0.01, model=bad),
        lambda: integrators.rk4_step_actuated(np.zeros(5), np.zeros(5), np.ones(4), p, 0.01, model=bad),
        lambda: integrators.rollout(np.zeros(5), np.zeros(5), np.zeros((2, 5)), p, 0.01, model=bad),
    ]
    for call in calls:
        with pytest.raises(ValueError) as info:
            call()
        msg = str(info.value)
        assert "model must be one of ['consistent', 'paper']" in msg and repr(bad) in msg, msg


def test_consistent_model_refuses_the_papers_printed_input_map():
    p = SoftPVTOLParams()
    for call in (lambda: dynamics.generalized_forces(np.zeros(5), np.ones(4), p, "paper", model="consistent"),
                 lambda: integrators.rk4_step_actuated(np.zeros(5), np.zeros(5), np.ones(4), p, 0.01,
                                                       input_map="paper", model="consistent")):
        with pytest.raises(ValueError, match=r"input_map='paper' is not an input map of model='consistent'.*"
                                             r"input_map='exact'"):
            call()


def test_reference_is_not_the_naive_closed_form_near_zero():
    """Guard of the reference itself: at q = 1e-6 the float64 closed form is wrong by far more than
    the tolerance, while the mpmath reference matches the exact limit behaviour D_44 -> I_l + l^2 m/4."""
    p = SoftPVTOLParams()
    q = np.array([0.0, 0.0, 0.0, 1e-6, 1e-6])
    ref = reference(q, np.ones(5), p, np.ones(4))
    ql = 1e-6
    naive_d44 = p.I_l + p.l_l**2 * p.m_l * (1 / ql**2 + 2 / ql**4 - 2 * np.cos(ql) / ql**4 - 2 * np.sin(ql) / ql**3)
    assert abs(ref["D"][3, 3] - (p.I_l + p.l_l**2 * p.m_l / 4)) < 1e-12
    assert abs(naive_d44 - ref["D"][3, 3]) > 1e-6


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("model", MODELS)
def test_tips_at_theta_zero_are_the_papers_positions(seed, model):
    """At theta = 0 the world-frame tips of either model are the paper's eq. (coords) p_l, p_r."""
    rng = np.random.default_rng(seed)
    p = random_params(rng)
    q, _, _ = random_state(rng)
    q[2] = 0.0
    tips = dynamics.arm_tip_positions(q, p, model=model)
    x, z, _, ql, qr = q
    expected = np.array(
        [
            [x - p.epsilon - p.l_l * np.sin(ql) / ql, z + p.l_l * (1 - np.cos(ql)) / ql],
            [x + p.epsilon + p.l_r * np.sin(qr) / qr, z + p.l_r * (1 - np.cos(qr)) / qr],
        ]
    )
    np.testing.assert_allclose(tips, expected, rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("q_arm", [3 * np.pi, 4 * np.pi, 6 * np.pi])
def test_large_curvature_is_accurate_or_rejected(q_arm):
    """The model has no singularity at any curvature (paper, Sec. 5). A curvature outside the series'
    range must either be evaluated correctly or be rejected with ValueError, never silently wrong."""
    rng = np.random.default_rng(99)
    p = random_params(rng)
    q, qd, a = random_state(rng)
    q[3], q[4] = q_arm, -0.5 * q_arm
    try:
        got = package(q, qd, p, a)
    except ValueError:
        return
    assert_matches(got, reference(q, qd, p, a), f"q_l={q_arm!r}, q_r={-0.5 * q_arm!r}")


def test_series_limit_helper_agrees_with_sympy_limit():
    """The reference's limit_at_zero (used at q = 0) against sympy.limit, and it detects poles."""
    q, l, m = sp.symbols("q l m", positive=True)
    exprs = [
        sp.sin(q) / q,
        # the paper's printed d44 and c44 (Sec. 2.2) with I_l = 0, q_l' = 1
        l**2 * m * (1 / q**2 + 2 / q**4 - 2 * sp.cos(q) / q**4 - 2 * sp.sin(q) / q**3),
        -(l**2) * m / q**3 - 4 * l**2 * m / q**5 + l**2 * m * (q * sp.sin(q) + 4 * sp.cos(q)) / q**5
        - l**2 * m * (q * sp.cos(q) - 3 * sp.sin(q)) / q**4,
        (sp.cos(q) + q * sp.sin(q) - 1) / q**2 * sp.cos(q) ** 2 + m,
    ]
    for e in exprs:
        assert sp.simplify(limit_at_zero(e, q) - sp.limit(e, q, 0)) == 0, e
    with pytest.raises(AssertionError, match="pole"):
        limit_at_zero((1 - sp.cos(q)) / q**3, q)
