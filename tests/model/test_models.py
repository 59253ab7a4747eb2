"""Physical properties of both models, ``model="paper"`` and ``model="consistent"`` (the paper's energy
terms with the rotor masses at the tips rotated by theta; docs/model.md): SPD inertia, Ddot - 2C skew,
the Euler-Lagrange solve, energy conserved without input, dH/dt = qdot . tau with input, RK4, batching.
The symbolic comparison of both models is in test_dynamics_sympy.py."""

from __future__ import annotations

import itertools

import numba
import numpy as np
import pytest
from scipy.integrate import simpson, solve_ivp

from softpvtol_gym import SoftPVTOLParams, dynamics, integrators

MODELS = ("paper", "consistent")
SPECIAL_Q = [0.0, 1e-9, 1e-6, 0.1, np.pi, -np.pi, 1.0]
NONDEFAULT = SoftPVTOLParams(m=3.0, m_l=0.7, m_r=1.3, I=0.8, I_l=0.05, I_r=0.15, l_l=0.6, l_r=0.4, g=9.8, epsilon=0.1)


@pytest.fixture(autouse=True)
def _one_numba_thread():
    """One numba thread for the many tiny calls (see test_dynamics_physics.py)."""
    old = numba.get_num_threads()
    numba.set_num_threads(1)
    yield
    numba.set_num_threads(old)


def random_params(rng) -> SoftPVTOLParams:
    return SoftPVTOLParams(m=rng.uniform(1.0, 8.0), m_l=rng.uniform(0.2, 2.0), m_r=rng.uniform(0.2, 2.0),
                           I=rng.uniform(0.2, 2.0), I_l=rng.uniform(0.02, 0.3), I_r=rng.uniform(0.02, 0.3),
                           l_l=rng.uniform(0.2, 1.0), l_r=rng.uniform(0.2, 1.0), g=rng.uniform(5.0, 12.0),
                           epsilon=rng.uniform(0.0, 0.3))


def random_q(rng, shape=()):
    q = np.empty(shape + (5,))
    q[..., :2] = rng.uniform(-3, 3, size=shape + (2,))
    q[..., 2:] = rng.uniform(-np.pi, np.pi, size=shape + (3,))
    return q


# ----------------------------------------------------------------------------- inertia matrix
@pytest.mark.parametrize("model", MODELS)
def test_mass_matrix_spd_on_grid(model):
    """D is SPD on a grid of both curvatures over [-pi, pi] x attitudes, with lambda_min(D) >=
    min(m, I, I_l, I_r) (the kinetic energy is a sum of squares plus those diagonal terms)."""
    rng = np.random.default_rng(0)
    for p in (NONDEFAULT, SoftPVTOLParams()):
        g = np.linspace(-np.pi, np.pi, 25)
        q = random_q(rng, (25, 25))
        q[..., 3], q[..., 4] = np.meshgrid(g, g, indexing="ij")
        D = dynamics.mass_matrix(q, p, model=model)
        np.testing.assert_array_equal(D, np.swapaxes(D, -1, -2))
        eig = np.linalg.eigvalsh(D)
        assert eig.min() >= min(p.m, p.I, p.I_l, p.I_r) * (1 - 1e-12), eig.min()


@pytest.mark.parametrize("seed", range(4))
def test_consistent_mass_matrix_from_the_tips_jacobians(seed):
    """Consistent D = diag(m, m, I, I_l, I_r) + sum_i m_i J_i^T J_i, J_i the Jacobian of its rotated
    tips (central differences of arm_tip_positions); it depends on theta, the paper's does not."""
    rng = np.random.default_rng(seed)
    p = random_params(rng)
    q = random_q(rng)
    if seed < 2:
        q[3], q[4] = 0.0, [np.pi, -np.pi][seed]
    h = 1e-6
    J = np.stack([(dynamics.arm_tip_positions(q + h * e, p, model="consistent")
                   - dynamics.arm_tip_positions(q - h * e, p, model="consistent")) / (2 * h) for e in np.eye(5)],
                 axis=-1)
    ref = np.diag([p.m, p.m, p.I, p.I_l, p.I_r]) + p.m_l * J[0].T @ J[0] + p.m_r * J[1].T @ J[1]
    np.testing.assert_allclose(dynamics.mass_matrix(q, p, model="consistent"), ref, rtol=1e-8, atol=1e-8)
    q2 = q.copy()
    q2[2] += 0.7
    assert np.abs(dynamics.mass_matrix(q2, p, model="consistent") - dynamics.mass_matrix(q, p, model="consistent")
                  ).max() > 1e-3
    np.testing.assert_array_equal(dynamics.mass_matrix(q2, p), dynamics.mass_matrix(q, p))


@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("seed", range(6))
def test_kinetic_energy_and_gravity(model, seed):
    """K = 1/2 qdot^T D qdot; g = dP/dq (central differences)."""
    rng = np.random.default_rng(10 + seed)
    p = random_params(rng)
    q = random_q(rng)
    q[3] = SPECIAL_Q[seed % len(SPECIAL_Q)]
    qd = rng.uniform(-3, 3, size=5)
    D = dynamics.mass_matrix(q, p, model=model)
    np.testing.assert_allclose(dynamics.kinetic_energy(q, qd, p, model=model), 0.5 * qd @ D @ qd, rtol=1e-13)
    h = 1e-6
    P = dynamics.potential_energy
    grad = np.array([(P(q + h * e, p, model=model) - P(q - h * e, p, model=model)) / (2 * h) for e in np.eye(5)])
    np.testing.assert_allclose(dynamics.gravity_vector(q, p, model=model), grad, rtol=1e-7, atol=1e-7)


# ------------------------------------------------------------------------ skew symmetry of N
@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("seed", range(8))
def test_ddot_minus_2c_is_skew(model, seed):
    rng = np.random.default_rng(100 + seed)
    p = random_params(rng)
    q = random_q(rng)
    q[3], q[4] = SPECIAL_Q[seed % len(SPECIAL_Q)], SPECIAL_Q[-1 - seed % len(SPECIAL_Q)]
    qd = rng.uniform(-3, 3, size=5)
    h = 1e-6
    C = dynamics.coriolis_matrix(q, qd, p, model=model)
    Dd = (dynamics.mass_matrix(q + h * qd, p, model=model) - dynamics.mass_matrix(q - h * qd, p, model=model)) / (2 * h)
    N = Dd - 2 * C
    scale = max(1.0, np.abs(Dd).max(), np.abs(C).max())
    assert np.abs(N + N.T).max() <= 1e-7 * scale
    np.testing.assert_array_equal(dynamics.coriolis_matrix(q, np.zeros(5), p, model=model), np.zeros((5, 5)))
    np.testing.assert_allclose(dynamics.coriolis_matrix(q, -1.5 * qd, p, model=model), -1.5 * C, rtol=1e-14,
                               atol=1e-14)


# --------------------------------------------------------------------------- forward dynamics
@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("seed", range(6))
def test_forward_dynamics_solves_the_euler_lagrange_equation(model, seed):
    rng = np.random.default_rng(200 + seed)
    p = random_params(rng)
    q = random_q(rng, (8,))
    q[:, 3] = SPECIAL_Q[seed % len(SPECIAL_Q)]
    qd = rng.uniform(-3, 3, size=(8, 5))
    tau = rng.uniform(-20, 20, size=(8, 5))
    qdd = dynamics.forward_dynamics(q, qd, tau, p, model=model)
    D = dynamics.mass_matrix(q, p, model=model)
    rhs = (tau - np.einsum("nij,nj->ni", dynamics.coriolis_matrix(q, qd, p, model=model), qd)
           - dynamics.gravity_vector(q, p, model=model))
    ref = np.linalg.solve(D, rhs[..., None])[..., 0]
    assert np.all(np.abs(qdd - ref) <= 1e-10 * np.maximum(1.0, np.abs(ref)))


def test_consistent_gravity_has_an_attitude_moment():
    """Straight arms, eps = 0: tau = g(q) holds the robot at rest in both models; the consistent g has
    a theta row, the moment g (m_r l_r - m_l l_l) cos(theta) of the tips' weights about the body (nonzero
    for unequal arms), which the paper's model lacks; its other rows are the paper's at theta = 0."""
    p = NONDEFAULT.replace(epsilon=0.0)
    for theta in (0.0, 0.3):
        q = np.array([1.0, 2.0, theta, 0.0, 0.0])
        tau = dynamics.gravity_vector(q, p, model="consistent")
        np.testing.assert_allclose(dynamics.forward_dynamics(q, np.zeros(5), tau, p, model="consistent"), 0,
                                   atol=1e-13)
        expected = p.g * (p.m_r * p.l_r - p.m_l * p.l_l) * np.cos(theta)
        assert abs(tau[2] - expected) <= 1e-13 and abs(expected) > 0.1
        assert dynamics.gravity_vector(q, p)[2] == 0.0
    q[2] = 0.0
    np.testing.assert_allclose(dynamics.gravity_vector(q, p, model="consistent")[[0, 1, 3, 4]],
                               dynamics.gravity_vector(q, p)[[0, 1, 3, 4]], rtol=1e-15, atol=1e-15)


# ---------------------------------------------------------------------- energy along trajectories
FREE_FALL = (np.array([0.3, -0.2, 0.4, -2.5, 2.6]), np.array([1.5, -0.8, 0.7, 0.5, -0.52]), 6.0)


def _dop853(model, p, q0, qd0, T, tau):
    def f(t, y):
        return np.concatenate([y[5:], dynamics.forward_dynamics(y[:5], y[5:], tau, p, model=model)])

    return solve_ivp(f, (0.0, T), np.concatenate([q0, qd0]), method="DOP853", rtol=1e-12, atol=1e-12,
                     dense_output=True)


@pytest.mark.parametrize("model", MODELS)
def test_energy_conserved_without_input(model):
    p = NONDEFAULT
    q0, qd0, T = FREE_FALL
    sol = _dop853(model, p, q0, qd0, T, np.zeros(5))
    assert sol.success
    Y = sol.sol(np.linspace(0.0, T, 201)).T
    K = dynamics.kinetic_energy(Y[:, :5], Y[:, 5:], p, model=model)
    P = dynamics.potential_energy(Y[:, :5], p, model=model)
    scale = max(1.0, np.abs(K).max(), np.abs(P).max())
    assert np.ptp(K) > 0.1 * scale  # energy really moves between K and P
    assert np.abs(Y[:, 3:5]).max() <= np.pi
    assert np.abs(K + P - dynamics.total_energy(q0, qd0, p, model=model)).max() <= 1e-10 * scale
    # the RK4 rollout at 0.01 s conserves it too (4th order: drift << scale)
    Q, V = integrators.rollout(q0, qd0, np.zeros((600, 5)), p, 0.01, model=model)
    H = dynamics.total_energy(Q, V, p, model=model)
    assert np.abs(H - H[0]).max() <= 1e-8 * scale


@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("seed", range(5))
def test_power_balance_pointwise(model, seed):
    """dH/dt = dH/dq . qdot + dH/dqdot . qddot equals the input power qdot . tau."""
    rng = np.random.default_rng(300 + seed)
    p = random_params(rng)
    q, qd = random_q(rng), rng.uniform(-3, 3, size=5)
    q[3] = SPECIAL_Q[seed % len(SPECIAL_Q)]
    tau = rng.uniform(-20, 20, size=5)
    qdd = dynamics.forward_dynamics(q, qd, tau, p, model=model)
    E, h = dynamics.total_energy, 1e-6
    dq = np.array([(E(q + h * e, qd, p, model=model) - E(q - h * e, qd, p, model=model)) / (2 * h) for e in np.eye(5)])
    dv = np.array([(E(q, qd + h * e, p, model=model) - E(q, qd - h * e, p, model=model)) / (2 * h) for e in np.eye(5)])
    terms = np.abs(dq * qd).sum() + np.abs(dv * qdd).sum()
    assert abs(dq @ qd + dv @ qdd - qd @ tau) <= 1e-7 * max(1.0, terms)


@pytest.mark.parametrize("model", MODELS)
def test_power_balance_with_held_actuators(model):
    """H(T) - H(0) = int qdot . B(q) a dt along a trajectory under held actuators (the env's step), the
    input map ("exact", the virtual work at the rotated tips, the consistent model's own) evaluated
    along the trajectory."""
    p = NONDEFAULT
    q0 = np.array([0.0, 1.0, 0.2, 0.8, -0.5])
    qd0 = np.array([0.3, 0.1, -0.4, 1.0, 0.7])
    act = np.array([25.0, 35.0, -5.0, -5.0])
    dt, n = 1e-3, 500
    Q, V = [q0], [qd0]
    for _ in range(n):
        q, v = integrators.rk4_step_actuated(Q[-1], V[-1], act, p, dt, input_map="exact", model=model)
        Q.append(q)
        V.append(v)
    Q, V = np.array(Q), np.array(V)
    assert np.abs(Q[:, 3:]).max() <= np.pi
    H = dynamics.total_energy(Q, V, p, model=model)
    tau = dynamics.generalized_forces(Q, act, p, input_map="exact", model=model)
    work = simpson(np.einsum("ni,ni->n", V, tau), dx=dt)
    assert abs(work) > 10.0
    assert abs((H[-1] - H[0]) - work) <= 1e-8 * max(1.0, abs(work), np.abs(H).max())


# ------------------------------------------------------------------------------------ RK4 step
@pytest.mark.parametrize("model", MODELS)
def test_rk4_step_is_classical_rk4(model):
    rng = np.random.default_rng(7)
    p = random_params(rng)
    q, qd, dt = random_q(rng), rng.uniform(-3, 3, size=5), 0.02
    tau = rng.uniform(-10, 10, size=5)

    def f(q, v):
        return v, dynamics.forward_dynamics(q, v, tau, p, model=model)

    k1q, k1v = f(q, qd)
    k2q, k2v = f(q + dt / 2 * k1q, qd + dt / 2 * k1v)
    k3q, k3v = f(q + dt / 2 * k2q, qd + dt / 2 * k2v)
    k4q, k4v = f(q + dt * k3q, qd + dt * k3v)
    q1, v1 = integrators.rk4_step(q, qd, tau, p, dt, model=model)
    np.testing.assert_allclose(q1, q + dt / 6 * (k1q + 2 * k2q + 2 * k3q + k4q), rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(v1, qd + dt / 6 * (k1v + 2 * k2v + 2 * k3v + k4v), rtol=1e-13, atol=1e-13)


def test_models_differ_in_flight():
    """The same actuated step from a tilted state: the two models' accelerations differ by the rotor
    masses' attitude coupling (not a no-op argument)."""
    p = SoftPVTOLParams()
    q = np.array([0.0, 2.0, 0.4, 0.3, -0.2])
    qd = np.array([0.1, 0.0, 0.5, 0.2, 0.1])
    a = np.array([34.3, 34.3, 2.45, 2.45])
    paper = integrators.rk4_step_actuated(q, qd, a, p, 0.01, input_map="exact")
    consistent = integrators.rk4_step_actuated(q, qd, a, p, 0.01, model="consistent")
    assert np.abs(paper[1] - consistent[1]).max() > 1e-3


def test_default_is_the_paper_model_bit_for_bit():
    rng = np.random.default_rng(3)
    p = random_params(rng)
    q, qd, tau = random_q(rng, (4,)), rng.uniform(-3, 3, (4, 5)), rng.uniform(-9, 9, (4, 5))
    a = rng.uniform(0, 30, (4, 4))
    pairs = [
        (dynamics.mass_matrix(q, p), dynamics.mass_matrix(q, p, model="paper")),
        (dynamics.forward_dynamics(q, qd, tau, p), dynamics.forward_dynamics(q, qd, tau, p, model="paper")),
        (dynamics.generalized_forces(q, a, p), dynamics.generalized_forces(q, a, p, "paper", model="paper")),
        (integrators.rk4_step_actuated(q, qd, a, p)[0], integrators.rk4_step_actuated(q, qd, a, p, 0.01, "paper")[0]),
    ]
    for x, y in pairs:
        assert np.array_equal(x, y)


# ----------------------------------------------------------------------- batching / broadcasting
def _calls(p):
    m = "consistent"
    return {
        "mass_matrix": lambda q, qd, tau, a: dynamics.mass_matrix(q, p, model=m),
        "coriolis_matrix": lambda q, qd, tau, a: dynamics.coriolis_matrix(q, qd, p, model=m),
        "gravity_vector": lambda q, qd, tau, a: dynamics.gravity_vector(q, p, model=m),
        "generalized_forces": lambda q, qd, tau, a: dynamics.generalized_forces(q, a, p, model=m),
        "forward_dynamics": lambda q, qd, tau, a: dynamics.forward_dynamics(q, qd, tau, p, model=m),
        "total_energy": lambda q, qd, tau, a: dynamics.total_energy(q, qd, p, model=m),
        "arm_tip_positions": lambda q, qd, tau, a: dynamics.arm_tip_positions(q, p, model=m),
        "rk4_step": lambda q, qd, tau, a: integrators.rk4_step(q, qd, tau, p, 0.01, model=m)[1],
        "rk4_step_actuated": lambda q, qd, tau, a: integrators.rk4_step_actuated(q, qd, a, p, 0.01, model=m)[1],
    }


@pytest.mark.parametrize("fn", sorted(_calls(NONDEFAULT)))
def test_consistent_batched_equals_loop_bit_for_bit(fn):
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    rng = np.random.default_rng(11)
    call = _calls(NONDEFAULT)[fn]
    q = random_q(rng, (3, 4))
    q[0, 0, 3], q[0, 1, 4], q[1, 2, 3] = 0.0, 1e-9, np.pi
    qd, tau, a = rng.uniform(-3, 3, (3, 4, 5)), rng.uniform(-10, 10, (3, 4, 5)), rng.uniform(0, 30, (3, 4, 4))
    out = call(q, qd, tau, a)
    for idx in itertools.product(range(3), range(4)):
        assert np.array_equal(out[idx], call(q[idx], qd[idx], tau[idx], a[idx])), (fn, idx)
