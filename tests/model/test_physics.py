"""Physical properties of the model core: SPD inertia, skew symmetry of Ddot - 2C, energy
conservation / power balance along trajectories, the input maps, batching and shape checks."""

from __future__ import annotations

import itertools

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import simpson, solve_ivp

from softpvtol_gym import SoftPVTOLParams, dynamics, integrators

SPECIAL_Q = [0.0, 1e-9, 1e-6, 0.1 - 1e-9, 0.1, 0.1 + 1e-9, np.pi, -np.pi, 1.0]


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

NONDEFAULT = SoftPVTOLParams(m=3.0, m_l=0.7, m_r=1.3, I=0.8, I_l=0.05, I_r=0.15, l_l=0.6, l_r=0.4, g=9.8, epsilon=0.1)
PARAM_CASES = {
    "default": SoftPVTOLParams(),
    "nondefault": NONDEFAULT,
    "light_arms": SoftPVTOLParams(
        m=1.5, m_l=0.05, m_r=2.5, I=0.3, I_l=0.01, I_r=0.4, l_l=1.2, l_r=0.2, g=3.7, epsilon=0.25
    ),
}


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


def random_q(rng, shape=()):
    q = np.empty(shape + (5,))
    q[..., 0:2] = rng.uniform(-3.0, 3.0, size=shape + (2,))
    q[..., 2:5] = rng.uniform(-np.pi, np.pi, size=shape + (3,))
    return q


def rot(theta):
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


def sinc(q):
    return np.sinc(q / np.pi)  # sin(q)/q, = 1 at q = 0


# ----------------------------------------------------------------------------- inertia matrix
@pytest.mark.parametrize("case", sorted(PARAM_CASES))
def test_mass_matrix_spd_on_grid(case):
    p = PARAM_CASES[case]
    rng = np.random.default_rng(0)
    g = np.linspace(-np.pi, np.pi, 41)
    QL, QR = np.meshgrid(g, g, indexing="ij")
    q = random_q(rng, (41, 41))
    q[..., 3], q[..., 4] = QL, QR
    D = dynamics.mass_matrix(q, p)
    assert D.shape == (41, 41, 5, 5)
    np.testing.assert_array_equal(D, np.swapaxes(D, -1, -2))
    eig = np.linalg.eigvalsh(D)
    assert np.all(eig > 0), f"min eigenvalue {eig.min()}"
    np.linalg.cholesky(D)  # raises LinAlgError if any is not positive definite
    # D does not depend on x, z, theta
    D0 = dynamics.mass_matrix(np.concatenate([np.zeros((41, 41, 3)), q[..., 3:]], axis=-1), p)
    np.testing.assert_array_equal(D, D0)


@pytest.mark.parametrize("seed", range(5))
def test_kinetic_energy_is_quadratic_form_of_mass_matrix(seed):
    rng = np.random.default_rng(seed)
    p = random_params(rng)
    q = random_q(rng, (16,))
    qd = rng.uniform(-3, 3, size=(16, 5))
    D = dynamics.mass_matrix(q, p)
    K = dynamics.kinetic_energy(q, qd, p)
    np.testing.assert_allclose(K, 0.5 * np.einsum("ni,nij,nj->n", qd, D, qd), rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(
        dynamics.total_energy(q, qd, p), K + dynamics.potential_energy(q, p), rtol=1e-14, atol=1e-12
    )


@pytest.mark.parametrize("seed", range(5))
def test_gravity_is_gradient_of_potential(seed):
    rng = np.random.default_rng(seed)
    p = random_params(rng)
    q = random_q(rng)
    h = 1e-6
    grad = np.array(
        [
            (dynamics.potential_energy(q + h * e, p) - dynamics.potential_energy(q - h * e, p)) / (2 * h)
            for e in np.eye(5)
        ]
    )
    np.testing.assert_allclose(dynamics.gravity_vector(q, p), grad, rtol=1e-7, atol=1e-7)


# ------------------------------------------------------------------------ skew symmetry of N
def ddot_fd(q, qd, p, h=1e-6):
    """dD/dt = sum_i dD/dq_i qd_i by a central difference along the velocity."""
    return (dynamics.mass_matrix(q + h * qd, p) - dynamics.mass_matrix(q - h * qd, p)) / (2 * h)


def check_skew(q, qd, p):
    C = dynamics.coriolis_matrix(q, qd, p)
    Dd = ddot_fd(q, qd, p)
    N = Dd - 2 * C
    scale = max(1.0, np.abs(Dd).max(), np.abs(C).max())
    assert np.abs(N + N.T).max() <= 1e-7 * scale, (N + N.T)
    # equivalently (Christoffel C): Ddot = C + C^T
    assert np.abs(Dd - (C + C.T)).max() <= 1e-7 * scale
    # and C is linear in qdot, C(q, 0) = 0
    np.testing.assert_array_equal(dynamics.coriolis_matrix(q, np.zeros(5), p), np.zeros((5, 5)))
    np.testing.assert_allclose(dynamics.coriolis_matrix(q, 2.5 * qd, p), 2.5 * C, rtol=1e-14, atol=1e-14)


@pytest.mark.parametrize("seed", range(10))
def test_ddot_minus_2c_is_skew(seed):
    rng = np.random.default_rng(100 + seed)
    p = random_params(rng)
    q = random_q(rng)
    if seed < len(SPECIAL_Q):
        q[3] = SPECIAL_Q[seed]
        q[4] = SPECIAL_Q[-1 - seed]
    check_skew(q, rng.uniform(-3, 3, size=5), p)


_finite = dict(allow_nan=False, allow_infinity=False)
_curv = st.floats(-np.pi, np.pi, **_finite)
_vel = st.floats(-5.0, 5.0, **_finite)
_params = st.builds(
    SoftPVTOLParams,
    m=st.floats(0.5, 10.0),
    m_l=st.floats(0.01, 3.0),
    m_r=st.floats(0.01, 3.0),
    I=st.floats(0.05, 3.0),
    I_l=st.floats(0.005, 0.5),
    I_r=st.floats(0.005, 0.5),
    l_l=st.floats(0.05, 2.0),
    l_r=st.floats(0.05, 2.0),
    g=st.floats(0.0, 20.0),
    epsilon=st.floats(0.0, 0.5),
)


@settings(max_examples=40, deadline=None)
@given(p=_params, ql=_curv, qr=_curv, theta=_curv)
def test_hypothesis_mass_matrix_spd(p, ql, qr, theta):
    D = dynamics.mass_matrix(np.array([0.3, -1.0, theta, ql, qr]), p)
    np.testing.assert_array_equal(D, D.T)
    assert np.linalg.eigvalsh(D).min() > 0
    # Schur complement bound: the arm block of D minus the body coupling is >= diag(I_l, I_r)
    M = p.m + p.m_l + p.m_r
    S = D[3:, 3:] - D[3:, :2] @ D[:2, 3:] / M
    assert np.linalg.eigvalsh(S - np.diag([p.I_l, p.I_r])).min() > -1e-12 * max(1.0, np.abs(S).max())


@settings(max_examples=40, deadline=None)
@given(p=_params, ql=_curv, qr=_curv, qd=st.lists(_vel, min_size=5, max_size=5))
def test_hypothesis_skew_symmetry(p, ql, qr, qd):
    check_skew(np.array([0.1, 0.2, 0.3, ql, qr]), np.array(qd), p)


# --------------------------------------------------------------------------- forward dynamics
@pytest.mark.parametrize("seed", range(10))
def test_forward_dynamics_solves_the_euler_lagrange_equation(seed):
    rng = np.random.default_rng(200 + seed)
    p = random_params(rng)
    q = random_q(rng, (8,))
    q[:, 3] = SPECIAL_Q[seed % len(SPECIAL_Q)]
    qd = rng.uniform(-3, 3, size=(8, 5))
    tau = rng.uniform(-20, 20, size=(8, 5))
    qdd = dynamics.forward_dynamics(q, qd, tau, p)
    D = dynamics.mass_matrix(q, p)
    C = dynamics.coriolis_matrix(q, qd, p)
    g = dynamics.gravity_vector(q, p)
    rhs = tau - np.einsum("nij,nj->ni", C, qd) - g
    ref = np.linalg.solve(D, rhs[..., None])[..., 0]
    assert np.all(np.abs(qdd - ref) <= 1e-10 * np.maximum(1.0, np.abs(ref)))
    # and the residual of D qdd + C qd + g - tau is at roundoff level
    res = np.einsum("nij,nj->ni", D, qdd) - rhs
    assert np.abs(res).max() <= 1e-11 * max(1.0, np.abs(rhs).max())


def test_hover_equilibrium():
    """Straight arms, tau = g(q): the robot stays at rest (qdd = 0)."""
    p = NONDEFAULT
    q = np.array([1.0, 2.0, 0.0, 0.0, 0.0])
    tau = dynamics.gravity_vector(q, p)
    np.testing.assert_allclose(dynamics.forward_dynamics(q, np.zeros(5), tau, p), 0.0, atol=1e-13)
    np.testing.assert_allclose(
        tau, [0, 9.8 * (3.0 + 0.7 + 1.3), 0, 9.8 * 0.7 * 0.6 / 2, 9.8 * 1.3 * 0.4 / 2], rtol=1e-15
    )


# ------------------------------------------------------------------------------------ RK4 step
def _rhs(q, qd, tau, p):
    return qd, dynamics.forward_dynamics(q, qd, tau, p)


@pytest.mark.parametrize("dt", [0.01, 0.05])
def test_rk4_step_is_classical_rk4(dt):
    """One step equals a NumPy classical RK4 on y = (q, qdot) built on forward_dynamics."""
    rng = np.random.default_rng(7)
    p = random_params(rng)
    q, qd = random_q(rng), rng.uniform(-3, 3, size=5)
    tau = rng.uniform(-10, 10, size=5)
    k1q, k1v = _rhs(q, qd, tau, p)
    k2q, k2v = _rhs(q + dt / 2 * k1q, qd + dt / 2 * k1v, tau, p)
    k3q, k3v = _rhs(q + dt / 2 * k2q, qd + dt / 2 * k2v, tau, p)
    k4q, k4v = _rhs(q + dt * k3q, qd + dt * k3v, tau, p)
    q_ref = q + dt / 6 * (k1q + 2 * k2q + 2 * k3q + k4q)
    v_ref = qd + dt / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
    q1, v1 = integrators.rk4_step(q, qd, tau, p, dt)
    np.testing.assert_allclose(q1, q_ref, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(v1, v_ref, rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("dt", [0.0, -0.01, np.nan, np.inf])
def test_rk4_rejects_bad_dt(dt):
    with pytest.raises(ValueError, match="dt"):
        integrators.rk4_step(np.zeros(5), np.zeros(5), np.zeros(5), SoftPVTOLParams(), dt)


# ---------------------------------------------------------------------- energy along trajectories
# (name, params, q0, qd0, T, (dt_coarse, dt_fine) for the order check)
# The model has no arm stiffness, so with tau = 0 the curvature rates barely change in free fall:
# the states are chosen so that the arms sweep through q = 0 but stay inside |q| <= pi.
TRAJECTORIES = {
    "free_fall_10s": (
        NONDEFAULT,
        np.array([0.3, -0.2, 0.4, -2.5, 2.6]),
        np.array([1.5, -0.8, 0.7, 0.5, -0.52]),
        10.0,
        (0.2, 0.1),
    ),
    "fast_arms_1s": (
        SoftPVTOLParams(m=2.0, m_l=1.1, m_r=0.8, I=0.6, I_l=0.04, I_r=0.07, l_l=0.7, l_r=0.55, g=9.8, epsilon=0.12),
        np.array([0.3, -0.2, 0.4, -1.5, 1.2]),
        np.array([1.5, -0.8, 2.0, 3.0, -2.5]),
        1.0,
        (0.02, 0.01),
    ),
}


def _dop853(p, q0, qd0, T, tau=None):
    tau = np.zeros(5) if tau is None else tau

    def f(t, y):
        return np.concatenate([y[5:], dynamics.forward_dynamics(y[:5], y[5:], tau, p)])

    return solve_ivp(f, (0.0, T), np.concatenate([q0, qd0]), method="DOP853", rtol=1e-12, atol=1e-12, dense_output=True)


def _rk4_energy_drift(p, q0, qd0, T, dt):
    n = int(round(T / dt))
    Q, V = integrators.rollout(q0, qd0, np.zeros((n, 5)), p, dt)
    H = dynamics.total_energy(Q, V, p)
    return Q, V, np.abs(H - H[0]).max()


@pytest.mark.parametrize("name", sorted(TRAJECTORIES))
def test_energy_conserved_without_input(name):
    p, q0, qd0, T, _ = TRAJECTORIES[name]
    sol = _dop853(p, q0, qd0, T)
    assert sol.success
    ts = np.linspace(0.0, T, 201)
    Y = sol.sol(ts).T
    K = dynamics.kinetic_energy(Y[:, :5], Y[:, 5:], p)
    P = dynamics.potential_energy(Y[:, :5], p)
    H0 = dynamics.total_energy(q0, qd0, p)
    scale = max(1.0, np.abs(K).max(), np.abs(P).max())
    # non-trivial: the energy moves between K and P by much more than the tolerances below
    assert np.ptp(K) > 0.1 * scale
    assert np.abs(Y[:, 3:5]).max() <= np.pi
    assert np.abs(K + P - H0).max() <= 1e-10 * scale

    Q, V, drift = _rk4_energy_drift(p, q0, qd0, T, 0.01)
    assert drift <= 1e-9 * scale
    # the RK4 trajectory follows the DOP853 one
    n = int(round(T / 0.01))
    stride = max(1, n // 200)
    Y_rk4 = np.concatenate([Q, V], axis=1)[::stride]
    Y_ref = sol.sol(np.linspace(0.0, T, n // stride + 1)).T
    assert Y_rk4.shape == Y_ref.shape
    assert np.abs(Y_rk4 - Y_ref).max() <= 1e-8 * max(1.0, np.abs(Y_ref).max())


@pytest.mark.parametrize("name", sorted(TRAJECTORIES))
def test_rk4_energy_drift_is_fourth_order(name):
    p, q0, qd0, T, (dt1, dt2) = TRAJECTORIES[name]
    assert dt2 == dt1 / 2
    _, _, e1 = _rk4_energy_drift(p, q0, qd0, T, dt1)
    _, _, e2 = _rk4_energy_drift(p, q0, qd0, T, dt2)
    assert e2 > 0
    assert 13.0 <= e1 / e2 <= 19.0, (e1, e2, e1 / e2)


def _grad_energy(q, qd, p, h=1e-6):
    E = dynamics.total_energy
    dq = np.array([(E(q + h * e, qd, p) - E(q - h * e, qd, p)) / (2 * h) for e in np.eye(5)])
    dv = np.array([(E(q, qd + h * e, p) - E(q, qd - h * e, p)) / (2 * h) for e in np.eye(5)])
    return dq, dv


@pytest.mark.parametrize("seed", range(6))
def test_power_balance_pointwise(seed):
    """dH/dt = dH/dq . qd + dH/dqd . qdd equals the input power qd . tau."""
    rng = np.random.default_rng(300 + seed)
    p = random_params(rng)
    q, qd = random_q(rng), rng.uniform(-3, 3, size=5)
    if seed < 3:
        q[3 + seed % 2] = [0.0, 1e-9, np.pi][seed]
    tau = rng.uniform(-20, 20, size=5)
    qdd = dynamics.forward_dynamics(q, qd, tau, p)
    dq, dv = _grad_energy(q, qd, p)
    dH = dq @ qd + dv @ qdd
    terms = np.abs(dq * qd).sum() + np.abs(dv * qdd).sum()
    assert abs(dH - qd @ tau) <= 1e-7 * max(1.0, terms), (dH, qd @ tau)


def test_power_balance_along_trajectory():
    """H(T) - H(0) = int_0^T qd . tau dt for a constant input (Simpson on a fine RK4 trajectory)."""
    p = NONDEFAULT
    q0 = np.array([0.0, 1.0, 0.2, 0.8, -0.5])
    qd0 = np.array([0.3, 0.1, -0.4, 1.0, 0.7])
    act = np.array([25.0, 35.0, -5.0, -5.0])
    tau = dynamics.generalized_forces(q0, act, p, input_map="exact")
    dt, n = 1e-3, 1000
    Q, V = integrators.rollout(q0, qd0, np.broadcast_to(tau, (n, 5)), p, dt)
    assert np.abs(Q[:, 3:]).max() <= np.pi  # stays in the model's domain
    H = dynamics.total_energy(Q, V, p)
    work = simpson(V @ tau, dx=dt)
    assert abs(work) > 10.0  # the input does real work
    assert abs((H[-1] - H[0]) - work) <= 1e-8 * max(1.0, abs(work), np.abs(H).max())


# ---------------------------------------------------------------------------------- input maps
def paper_map(q, a, p):
    """The paper's printed map (Sec. 2.1, 'control input in vector form')."""
    _, _, th, ql, qr = q
    Tl, Tr, tl, tr = a
    vx = Tl * np.sin(ql) - Tr * np.sin(qr)
    vz = Tl * np.cos(ql) + Tr * np.cos(qr)
    txz = rot(th) @ np.array([vx, vz])
    t_theta = p.l_r * Tr * np.cos(qr) * sinc(qr) - p.l_l * Tl * np.cos(ql) * sinc(ql)
    return np.array([txz[0], txz[1], t_theta, tl, tr])


def exact_map_fd(q, a, p, h=1e-5):
    """Virtual work of the thrusts at the physical tips: Q_j = sum_i F_i . dp_i/dq_j (central FD)."""
    _, _, th, ql, qr = q
    Tl, Tr, tl, tr = a
    F = np.array([rot(th) @ (Tl * np.array([np.sin(ql), np.cos(ql)])),
                  rot(th) @ (Tr * np.array([-np.sin(qr), np.cos(qr)]))])
    Q = np.zeros(5)
    for j, e in enumerate(np.eye(5)):
        dtips = (dynamics.arm_tip_positions(q + h * e, p, model="consistent")
                 - dynamics.arm_tip_positions(q - h * e, p, model="consistent")) / (2 * h)
        Q[j] = np.sum(F * dtips)
    return Q + np.array([0.0, 0.0, 0.0, tl, tr])


def _map_cases():
    cases = []
    for i in range(8):
        cases.append(("random", i, None, None))
    for i, (ql, qr) in enumerate(zip(SPECIAL_Q, SPECIAL_Q[::-1])):
        cases.append(("special", 50 + i, ql, qr))
    return cases


def _map_state(seed, ql, qr):
    rng = np.random.default_rng(400 + seed)
    p = random_params(rng)  # epsilon > 0
    q = random_q(rng)
    q[2] = rng.choice([-1, 1]) * rng.uniform(0.3, 3.0)  # theta != 0
    if ql is not None:
        q[3], q[4] = ql, qr
    a = np.array([rng.uniform(1, 40), rng.uniform(1, 40), rng.uniform(-5, 5), rng.uniform(-5, 5)])
    return p, q, a


@pytest.mark.parametrize(("kind", "seed", "ql", "qr"), _map_cases())
def test_paper_input_map_is_the_printed_formula(kind, seed, ql, qr):
    p, q, a = _map_state(seed, ql, qr)
    got = dynamics.generalized_forces(q, a, p, input_map="paper")
    np.testing.assert_allclose(got, paper_map(q, a, p), rtol=1e-13, atol=1e-12)
    np.testing.assert_array_equal(dynamics.generalized_forces(q, a, p), got)  # "paper" is the default


@pytest.mark.parametrize(("kind", "seed", "ql", "qr"), _map_cases())
def test_exact_input_map_is_virtual_work_at_the_tips(kind, seed, ql, qr):
    p, q, a = _map_state(seed, ql, qr)
    got = dynamics.generalized_forces(q, a, p, input_map="exact")
    ref = exact_map_fd(q, a, p)
    assert np.all(np.abs(got - ref) <= 1e-7 * np.maximum(1.0, np.abs(ref))), (got, ref)


def test_tip_positions_world_frame():
    """Tips are p_v + R(theta) r_i with the body-frame arc ends r_i (checked against numpy) in the
    consistent model, p_v + r_i (not rotated) in the paper's."""
    rng = np.random.default_rng(5)
    p = random_params(rng)
    for _ in range(10):
        q = random_q(rng)
        x, z, th, ql, qr = q
        r_l = np.array([-p.epsilon - p.l_l * sinc(ql), p.l_l * (1 - np.cos(ql)) / ql])
        r_r = np.array([p.epsilon + p.l_r * sinc(qr), p.l_r * (1 - np.cos(qr)) / qr])
        ref = np.array([[x, z] + rot(th) @ r_l, [x, z] + rot(th) @ r_r])
        np.testing.assert_allclose(dynamics.arm_tip_positions(q, p, model="consistent"), ref, rtol=1e-13, atol=1e-13)
        paper = np.array([[x, z] + r_l, [x, z] + r_r])
        np.testing.assert_allclose(dynamics.arm_tip_positions(q, p), paper, rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("seed", range(5))
def test_input_maps_agree_on_translation_rows(seed):
    p, q, a = _map_state(seed, None, None)
    paper = dynamics.generalized_forces(q, a, p, input_map="paper")
    exact = dynamics.generalized_forces(q, a, p, input_map="exact")
    np.testing.assert_allclose(paper[:2], exact[:2], rtol=1e-15, atol=1e-13)


@pytest.mark.parametrize("theta", [0.0, 0.7, -2.0])
def test_input_maps_at_straight_arms_and_zero_epsilon(theta):
    """q_l = q_r = 0, eps = 0: both maps give the rigid PVTOL's (tau_x, tau_z, tau_theta).

    The curvature rows differ, by design of the virtual-work definition: at q_i = 0 the tip moves
    up by l_i/2 per unit curvature, so the thrust T_i does work T_i l_i / 2 on q_i (the "exact" map
    adds it, the paper's map does not).
    """
    p = NONDEFAULT.replace(epsilon=0.0)
    q = np.array([0.4, -1.0, theta, 0.0, 0.0])
    a = np.array([12.0, 17.0, 0.3, -0.8])
    paper = dynamics.generalized_forces(q, a, p, input_map="paper")
    exact = dynamics.generalized_forces(q, a, p, input_map="exact")
    rigid = np.array([-np.sin(theta) * (a[0] + a[1]), np.cos(theta) * (a[0] + a[1]), p.l_r * a[1] - p.l_l * a[0]])
    np.testing.assert_allclose(paper[:3], rigid, rtol=1e-15, atol=1e-13)
    np.testing.assert_allclose(exact[:3], rigid, rtol=1e-15, atol=1e-13)
    np.testing.assert_array_equal(paper[3:], a[2:])
    np.testing.assert_allclose(exact[3:] - paper[3:], [a[0] * p.l_l / 2, a[1] * p.l_r / 2], rtol=1e-15)


@pytest.mark.parametrize("bad", ["Paper", "approx", "", 0])
def test_unknown_input_map_raises(bad):
    with pytest.raises(ValueError) as info:
        dynamics.generalized_forces(np.zeros(5), np.ones(4), SoftPVTOLParams(), input_map=bad)
    msg = str(info.value)
    assert "paper" in msg and "exact" in msg, msg


# ----------------------------------------------------------------------- batching / broadcasting
def _batched_calls(p):
    return {
        "mass_matrix": (lambda q, qd, tau, a: dynamics.mass_matrix(q, p)),
        "coriolis_matrix": (lambda q, qd, tau, a: dynamics.coriolis_matrix(q, qd, p)),
        "gravity_vector": (lambda q, qd, tau, a: dynamics.gravity_vector(q, p)),
        "generalized_forces_paper": (lambda q, qd, tau, a: dynamics.generalized_forces(q, a, p, "paper")),
        "generalized_forces_exact": (lambda q, qd, tau, a: dynamics.generalized_forces(q, a, p, "exact")),
        "forward_dynamics": (lambda q, qd, tau, a: dynamics.forward_dynamics(q, qd, tau, p)),
        "kinetic_energy": (lambda q, qd, tau, a: dynamics.kinetic_energy(q, qd, p)),
        "potential_energy": (lambda q, qd, tau, a: dynamics.potential_energy(q, p)),
        "total_energy": (lambda q, qd, tau, a: dynamics.total_energy(q, qd, p)),
        "arm_tip_positions": (lambda q, qd, tau, a: dynamics.arm_tip_positions(q, p)),
        "rk4_step_q": (lambda q, qd, tau, a: integrators.rk4_step(q, qd, tau, p, 0.01)[0]),
        "rk4_step_qdot": (lambda q, qd, tau, a: integrators.rk4_step(q, qd, tau, p, 0.01)[1]),
    }


_OUT_SHAPE = {
    "mass_matrix": (5, 5),
    "coriolis_matrix": (5, 5),
    "arm_tip_positions": (2, 2),
    "kinetic_energy": (),
    "potential_energy": (),
    "total_energy": (),
}


@pytest.mark.parametrize("fn", sorted(_batched_calls(NONDEFAULT)))
def test_batched_equals_loop_bit_for_bit(fn):
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)  # exercise the multi-threaded batch path
    rng = np.random.default_rng(11)
    call = _batched_calls(NONDEFAULT)[fn]
    q = random_q(rng, (3, 4))
    q[0, 0, 3], q[0, 1, 4], q[1, 2, 3] = 0.0, 1e-9, np.pi
    qd = rng.uniform(-3, 3, size=(3, 4, 5))
    tau = rng.uniform(-10, 10, size=(3, 4, 5))
    a = rng.uniform(0, 30, size=(3, 4, 4))
    out = call(q, qd, tau, a)
    assert out.shape == (3, 4) + _OUT_SHAPE.get(fn, (5,))
    for idx in itertools.product(range(3), range(4)):
        single = call(q[idx], qd[idx], tau[idx], a[idx])
        assert single.shape == _OUT_SHAPE.get(fn, (5,))
        assert np.array_equal(out[idx], single), (fn, idx)


@pytest.mark.parametrize(
    "fn", ["coriolis_matrix", "forward_dynamics", "kinetic_energy", "total_energy", "rk4_step_q", "rk4_step_qdot"]
)
def test_broadcast_batch_of_q_against_single_qdot(fn):
    rng = np.random.default_rng(12)
    call = _batched_calls(NONDEFAULT)[fn]
    q = random_q(rng, (7,))
    qd = rng.uniform(-3, 3, size=5)
    tau = rng.uniform(-10, 10, size=5)
    out = call(q, qd, tau, None)
    assert out.shape == (7,) + _OUT_SHAPE.get(fn, (5,))
    for n in range(7):
        assert np.array_equal(out[n], call(q[n], qd, tau, None))


def test_rollout_shapes_and_consistency():
    rng = np.random.default_rng(13)
    q0, qd0 = random_q(rng, (2,)), rng.uniform(-1, 1, size=(2, 5))
    tau = rng.uniform(-5, 5, size=(4, 2, 5))
    Q, V = integrators.rollout(q0, qd0, tau, NONDEFAULT, 0.02)
    assert Q.shape == V.shape == (5, 2, 5)
    np.testing.assert_array_equal(Q[0], q0)
    q, v = q0, qd0
    for k in range(4):
        q, v = integrators.rk4_step(q, v, tau[k], NONDEFAULT, 0.02)
        assert np.array_equal(Q[k + 1], q) and np.array_equal(V[k + 1], v)


# --------------------------------------------------------------------------------- bad shapes
@pytest.mark.parametrize("shape", [(4,), (3,), (2, 4), (6,)])
def test_mass_matrix_rejects_bad_shape(shape):
    with pytest.raises(ValueError) as info:
        dynamics.mass_matrix(np.zeros(shape), SoftPVTOLParams())
    assert str(shape) in str(info.value), str(info.value)


def test_scalar_q_rejected():
    with pytest.raises(ValueError):
        dynamics.mass_matrix(0.0, SoftPVTOLParams())


def test_other_functions_reject_bad_shapes():
    p = SoftPVTOLParams()
    with pytest.raises(ValueError, match=r"\(4,\)"):
        dynamics.coriolis_matrix(np.zeros(5), np.zeros(4), p)
    with pytest.raises(ValueError, match=r"\(5,\)"):
        dynamics.generalized_forces(np.zeros(5), np.zeros(5), p)
    with pytest.raises(ValueError):
        dynamics.forward_dynamics(np.zeros((3, 5)), np.zeros((2, 5)), np.zeros(5), p)  # no broadcast
