"""The env's zero-order hold holds the actuators: B(q) is re-evaluated at every RK4 stage.

The reference here is a plain RK4 written with the public model functions (forward_dynamics and
generalized_forces evaluated at each stage's configuration), not with the env's kernels.
"""

import contextlib

import numpy as np
import pytest

from softpvtol_gym import SoftPVTOLEnv, SoftPVTOLParams, integrators
from softpvtol_gym.dynamics import forward_dynamics, generalized_forces

TOL = dict(rtol=1e-12, atol=1e-12)


def rk4_held(q, v, force_at, params, dt):
    """Classical RK4 of D qdd + C qd + g = force_at(q_stage) (the command held over the step)."""
    h = 0.5 * dt
    k1 = forward_dynamics(q, v, force_at(q), params)
    q2, v2 = q + h * v, v + h * k1
    k2 = forward_dynamics(q2, v2, force_at(q2), params)
    q3, v3 = q + h * v2, v + h * k2
    k3 = forward_dynamics(q3, v3, force_at(q3), params)
    q4, v4 = q + dt * v3, v + dt * k3
    k4 = forward_dynamics(q4, v4, force_at(q4), params)
    return q + dt / 6 * (v + 2 * v2 + 2 * v3 + v4), v + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def held_force(applied, wind, params, input_map, ideal):
    """The generalized force at a configuration under the held command: tau + wind (ideal mode) or
    B(q) a + wind."""
    if ideal:
        return lambda qs: applied + wind
    return lambda qs: generalized_forces(qs, applied[:4], params, input_map) + wind


CASES = [
    dict(action_mode="actuators"),
    dict(action_mode="actuators", input_map="exact"),
    dict(action_mode="actuators", tier="wind"),
    dict(action_mode="actuators", tier="mismatch"),
    dict(action_mode="virtual"),
    dict(action_mode="virtual", allocation="paper", input_map="exact"),
    dict(action_mode="residual", tier="noisy"),
    dict(action_mode="virtual", allocation="ideal", tier="wind"),
]


def make_env(frame_skip: int, **kw) -> SoftPVTOLEnv:
    """The env of a case; the residual mode with frame_skip=2 (0.02 s held) warns (on purpose: its base controller's arm
    loop diverges when held that long, test_control_loops.py) and the warning is checked here."""
    expect = kw.get("action_mode") == "residual" and frame_skip > 1
    with pytest.warns(UserWarning, match="arm loop diverges") if expect else contextlib.nullcontext():
        return SoftPVTOLEnv(task="track_random", frame_skip=frame_skip, **kw)


@pytest.mark.parametrize("frame_skip", [1, 2])
@pytest.mark.parametrize("kw", CASES, ids=lambda kw: "-".join(f"{v}" for v in kw.values()))
def test_env_step_is_rk4_with_the_command_held(kw, frame_skip):
    env = make_env(frame_skip, **kw)
    env.reset(seed=7)
    sim = env.sim
    imap = env.config.input_map
    ideal = env.config.allocation == "ideal"
    rng = np.random.default_rng(0)
    for _ in range(40):
        q, v = env.state
        if np.max(np.abs(q[3:])) > 2.5:  # random actions bend the light arms far: stop before the limit
            break
        p = env.plant_params
        wind = np.r_[sim.wind[0], 0.0, 0.0, 0.0]  # held over the step (the OU update comes after it)
        env.step(rng.uniform(-0.3, 0.3, env.action_space.shape))
        force = held_force(sim.applied[0].copy(), wind, p, imap, ideal)
        for _ in range(frame_skip):
            q, v = rk4_held(q, v, force, p, 0.01)
        np.testing.assert_allclose(env.state[0], q, **TOL)
        np.testing.assert_allclose(env.state[1], v, **TOL)


def test_rk4_step_actuated_differs_from_holding_tau():
    """Holding tau = B(q0) a instead of a differs at first order in dt (the bug this fixes)."""
    p = SoftPVTOLParams()
    q = np.array([0.0, 2.0, 0.4, 0.8, -0.6])
    v = np.array([0.5, -0.2, 3.0, 4.0, -5.0])
    a = np.array([40.0, 30.0, 2.0, -1.0])
    q1, v1 = integrators.rk4_step_actuated(q, v, a, p, 0.01)
    q_ref, v_ref = rk4_held(q, v, lambda qs: generalized_forces(qs, a, p), p, 0.01)
    np.testing.assert_allclose(q1, q_ref, **TOL)
    np.testing.assert_allclose(v1, v_ref, **TOL)
    q0, v0 = integrators.rk4_step(q, v, generalized_forces(q, a, p), p, 0.01)
    assert np.max(np.abs(v0 - v1)) > 1e-4  # 7e-4 m/s here: O(dt) of the tau rates


@pytest.mark.parametrize("bad", [dict(dt=0.0), dict(input_map="nope")])
def test_rk4_step_actuated_rejects_bad_input(bad):
    kw = dict(dt=0.01, input_map="paper") | bad
    with pytest.raises(ValueError):
        integrators.rk4_step_actuated(np.zeros(5), np.zeros(5), np.zeros(4), SoftPVTOLParams(), **kw)
