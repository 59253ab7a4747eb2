"""Reward terms at crafted states, term by term against the docs/env.md reward table.

Each case starts an episode at a chosen state (``reset(options={"q0", "qdot0", "setpoint"})``) and takes
one step with a chosen action. Expected values are worked out by hand from the table: most states are
equilibria (straight arms, body level, each thrust = the hover thrust T_h = M g / 2, arm torques = the
arm gravity load g m l / 2), so the state after the 0.01 s step is the crafted one to ~1e-10 and the
expected term is a number written here; where the state moves during the step (curvatures away from
an equilibrium) the term is checked exactly (1e-12) against the table's formula at the state the env
reports after the step, and approximately against the crafted number.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from softpvtol_gym import SoftPVTOLEnv

PI = math.pi
#: actuators-mode action of the hover equilibrium: T = T_max (u + 1)/2 = T_h at u = -1/3 (T_max = 3 T_h);
#: arm torque tau_max u = g m l / 2 = tau_max / 4 at u = 1/4
HOVER = np.array([-1 / 3, -1 / 3, 0.25, 0.25], dtype=np.float32)
REST = (0.0, 0.0, 0.0, 0.0, 0.0)


def one_step(q0, qdot0=REST, setpoint=(0.0, 2.0, 0.0), action=HOVER, task="hover", **env_kwargs):
    env = SoftPVTOLEnv(task=task, **env_kwargs)
    options = {"q0": q0, "qdot0": qdot0}
    if task in ("hover", "setpoint"):
        options["setpoint"] = setpoint
    env.reset(seed=0, options=options)
    obs, reward, terminated, truncated, info = env.step(np.asarray(action, dtype=np.float32))
    return env, obs, reward, terminated, truncated, info


def _terms_sum(info) -> float:
    return sum(info["reward_terms"].values())


# --------------------------------------------------------------------------------- each term
@pytest.mark.parametrize(
    "ex,ez,expected",
    [(0.0, 0.0, 0.0), (0.6, 0.8, -0.25), (0.0, -1.5, -0.375), (-1.2, 1.6, -0.5), (3.0, 0.0, -0.5),
     (-10.0, 5.0, -0.5), (0.3, 0.4, -0.125)],
)
@pytest.mark.parametrize("task", ["hover", "setpoint"])
def test_position_term(task, ex, ez, expected):
    """-0.5 min(|(e_x, e_z)| / 2 m, 1): linear up to 2 m, -0.5 beyond (saturation)."""
    sx, sz = 1.0, 3.0
    env, obs, reward, term, trunc, info = one_step((sx + ex, sz + ez, 0, 0, 0), setpoint=(sx, sz, 0.0), task=task)
    t = info["reward_terms"]
    assert not term and not trunc
    assert t["position"] == pytest.approx(expected, abs=1e-9)
    for other in ("attitude", "velocity", "curvature", "crash"):
        assert abs(t[other]) < 1e-9, other
    assert t["alive"] == 1.0
    # effort of the hover command: thrusts at T_h, arm torques at tau_max / 4: -0.1 (2 (1/4)^2) / 4
    assert t["effort"] == pytest.approx(-0.1 * 2 * 0.25**2 / 4, abs=1e-9)
    assert reward == pytest.approx(1.0 + expected - 0.003125, abs=1e-9)


@pytest.mark.parametrize(
    "theta,theta_ref,expected_abs_error",
    [(0.0, 0.5, 0.5), (1.0, -1.0, 2.0), (0.0, -3.0, 3.0), (0.0, 4.0, 2 * PI - 4.0), (0.3, 0.3 + 2 * PI, 0.0),
     (0.0, PI, PI), (-2.5, 2.5, 2 * PI - 5.0)],
)
def test_attitude_term(theta, theta_ref, expected_abs_error):
    """-0.1 min(|e_theta| / pi, 1) with e_theta wrapped to [-pi, pi): at most -0.1 (|e| = pi). The body
    tilt makes the equal thrusts push sideways, but theta itself does not move (tau_theta = 0)."""
    env, obs, reward, term, trunc, info = one_step((0, 2, theta, 0, 0), setpoint=(0, 2, theta_ref), task="setpoint")
    assert not term
    assert env.state[0][2] == pytest.approx(theta, abs=1e-12)
    assert info["reward_terms"]["attitude"] == pytest.approx(-0.1 * expected_abs_error / PI, abs=1e-9)


@pytest.mark.parametrize(
    "v,expected",
    [((3.0, 4.0, 0.0), -0.1), ((1.2, 1.6, 0.0), -0.04), ((0.0, 0.0, 1.5), -0.03), ((6.0, -8.0, 0.0), -0.1),
     ((0.3, 0.0, 0.4), -0.01), ((0.0, -20.0, 0.0), -0.1)],
)
def test_velocity_term(v, expected):
    """-0.1 min(|(xdot, zdot, thetadot) - ref| / 5, 1). At the equilibrium the velocities do not change
    over the step (C qdot has only arm-rate terms): 1e-9. A pitch rate tilts the thrust by thetadot dt,
    changing xdot by ~g thetadot dt^2 / 2 (2e-4 m/s at 0.4 rad/s): tolerance 1e-5 on the term there
    (dropping thetadot from the norm would be off by >= 4e-3 in these cases)."""
    env, obs, reward, term, trunc, info = one_step((0, 2, 0, 0, 0), qdot0=(*v, 0.0, 0.0))
    assert not term
    tol = 1e-9 if v[2] == 0 else 1e-5
    assert info["reward_terms"]["velocity"] == pytest.approx(expected, abs=tol)


def test_velocity_term_is_relative_to_the_reference():
    """track_paper: x_ref = 4 sin(t/2) moves at 2 m/s at t = 0. Starting on the reference at its
    velocity, the velocity error after 0.01 s is |(2 - 2 cos(0.005), 0.3 sin(0.001))| ~ 3e-4 m/s
    (up to the state's own change over the step); at rest it is ~2 m/s (term -0.04)."""
    kw = dict(task="track_paper", action=HOVER)
    _, _, _, _, _, info = one_step((0, 7, 0, 0, 0), qdot0=(2, 0, 0, 0, 0), **kw)
    assert -1e-4 < info["reward_terms"]["velocity"] <= 0.0
    _, _, _, _, _, info = one_step((0, 7, 0, 0, 0), qdot0=REST, **kw)
    assert info["reward_terms"]["velocity"] == pytest.approx(-0.1 * 2.0 / 5, abs=1e-4)


@pytest.mark.parametrize(
    "action,expected",
    [
        ((-1 / 3, -1 / 3, 0.0, 0.0), 0.0),  # hover thrusts, no arm torque
        ((1.0, 1.0, 0.0, 0.0), -0.1 * 2 * (2 / 3) ** 2 / 4),  # (T_max - T_h) / T_max = 2/3
        ((-1.0, -1.0, 1.0, -1.0), -0.1 * (2 * (1 / 3) ** 2 + 2) / 4),  # T = 0: -1/3; |tau| = tau_max: 1
        ((-1 / 3, -1 / 3, 0.5, 0.0), -0.1 * 0.25 / 4),
        ((1.0, -1.0, 0.0, 0.0), -0.1 * ((2 / 3) ** 2 + (1 / 3) ** 2) / 4),
    ],
)
def test_effort_term_actuators(action, expected):
    """-0.1 min(mean(a_n^2), 1), a_n = ((T_l - T_h)/T_max, (T_r - T_h)/T_max, tau_l/tau_max, tau_r/tau_max)."""
    _, _, _, _, _, info = one_step((0, 2, 0, 0, 0), action=action)
    assert info["reward_terms"]["effort"] == pytest.approx(expected, abs=1e-7)  # float32 actions


def test_effort_term_saturates():
    """With actuator_limits=(10 N, 1 N m) the hover thrust is 3.43 T_max: zero thrust gives a_n = -3.43,
    mean(a_n^2) = 5.9 > 1, so the term is -0.1."""
    _, _, _, _, _, info = one_step((0, 2, 0, 0, 0), action=(-1, -1, 0, 0), actuator_limits=(10.0, 1.0))
    assert info["reward_terms"]["effort"] == -0.1
    _, _, _, _, _, info = one_step((0, 2, 0, 0, 0), action=(1, 1, 0, 0), actuator_limits=(10.0, 1.0))
    assert info["reward_terms"]["effort"] == pytest.approx(-0.1 * min(2 * ((10 - 34.3) / 10) ** 2 / 4, 1))
    # within range: T = 10 N, tau = 0.5 N m: ((10 - 34.3)/10)^2 = 5.9 again > 1; T_h itself is out of reach


@pytest.mark.parametrize(
    "u,expected",
    [((0.5, 0, 0, 0, 0), -0.1 * 0.25 / 5), ((1, -1, 1, -1, 1), -0.1), ((0, 0.2, 0, 0, 0), -0.1 * 0.04 / 5),
     ((0, 0, 0, 0, 0), 0.0), ((0.3, 0.4, 0, 0, 0), -0.1 * 0.25 / 5)],
)
def test_effort_term_ideal_mode_normalised_tau(u, expected):
    """allocation="ideal": a_n = (tau - offset) / scale = the action itself, 5 entries."""
    _, _, _, _, _, info = one_step((0, 2, 0, 0, 0), action=u, action_mode="virtual", allocation="ideal")
    assert info["reward_terms"]["effort"] == pytest.approx(expected, abs=1e-7)


def test_effort_term_uses_the_applied_actuators():
    """Virtual mode: action 0 asks for tau = (0, M g, 0, 0, 0), allocated to T_l = T_r = T_h with zero
    arm torques: effort 0. Residual mode, action 0, at the set-point at rest: the passivity controller
    gives T_h each and arm torques = the gravity load tau_max / 4: -0.1 (2 (1/4)^2) / 4. With a lag
    (tau = 0.05 s) the second step's effort is that of the lagged command, not of the new action."""
    _, _, _, _, _, info = one_step((0, 2, 0, 0, 0), action=np.zeros(5), action_mode="virtual")
    assert abs(info["reward_terms"]["effort"]) < 1e-12
    _, _, _, _, _, info = one_step((0, 2, 0, 0, 0), action=np.zeros(5), action_mode="residual")
    assert info["reward_terms"]["effort"] == pytest.approx(-0.003125, abs=1e-9)
    env = SoftPVTOLEnv(tier_options={"actuator_time_constant": 0.05})
    env.reset(seed=0, options={"q0": (0, 2, 0, 0, 0), "qdot0": REST, "setpoint": (0, 2, 0)})
    _, _, _, _, info = env.step(np.array([1, 1, 0, 0], dtype=np.float32))
    assert info["reward_terms"]["effort"] == pytest.approx(-0.1 * 2 * (2 / 3) ** 2 / 4, abs=1e-7)  # lag starts there
    _, _, _, _, info = env.step(HOVER * np.array([1, 1, 0, 0], dtype=np.float32))
    alpha = 1 - math.exp(-0.01 / 0.05)  # applied T - T_h = (T_max - T_h)(1 - alpha)
    assert info["reward_terms"]["effort"] == pytest.approx(-0.1 * 2 * ((2 / 3) * (1 - alpha)) ** 2 / 4, abs=1e-7)


def _curvature_formula(q) -> float:
    cp = min(max((max(abs(q[3]), abs(q[4])) - PI / 2) / (PI / 2), 0.0), 1.0)
    return -0.2 * cp * cp


@pytest.mark.parametrize(
    "ql,qr,expected",
    [(0.5, -1.0, 0.0), (1.5, 0.2, 0.0), (-1.2, 1.4, 0.0), (2.0, 0.1, -0.2 * ((2.0 - PI / 2) / (PI / 2)) ** 2),
     (0.3, -2.5, -0.2 * ((2.5 - PI / 2) / (PI / 2)) ** 2), (3.1, 0.0, -0.2 * ((3.1 - PI / 2) / (PI / 2)) ** 2),
     (-2.2, 2.8, -0.2 * ((2.8 - PI / 2) / (PI / 2)) ** 2)],
)
def test_curvature_term(ql, qr, expected):
    """-0.2 clip((max|q_arm| - pi/2)/(pi/2), 0, 1)^2: zero below pi/2, quadratic above. Bent arms are not
    an equilibrium: the term is checked exactly at the state after the step and to 5e-3 against the
    crafted curvatures (the arms move by ~1e-3 rad in 0.01 s)."""
    env, obs, reward, term, trunc, info = one_step((0, 2, 0, ql, qr))
    assert not term
    c = info["reward_terms"]["curvature"]
    assert c == pytest.approx(_curvature_formula(env.state[0]), abs=1e-12)
    assert c == pytest.approx(expected, abs=5e-3)
    if expected == 0.0:
        assert c == 0.0


def test_curvature_term_is_quadratic_above_half_pi():
    """Doubling the excess over pi/2 quadruples the term."""
    excess = 0.6
    vals = []
    for x in (excess, 2 * excess):
        env, *_, info = one_step((0, 2, 0, PI / 2 + x, 0), qdot0=REST)
        vals.append(info["reward_terms"]["curvature"] / _curvature_formula(env.state[0]) * _curvature_formula(
            (0, 0, 0, PI / 2 + x, 0)))
    assert vals[1] / vals[0] == pytest.approx(4.0, rel=1e-12)


# --------------------------------------------------------------------------------- termination
CRASHES = [
    ("curvature_limit", (0, 2, 0, 3.13, 0), (0, 0, 0, 5, 0)),
    ("curvature_limit", (0, 2, 0, 0, -3.13), (0, 0, 0, 0, -5)),
    ("ground", (0, -0.99, 0, 0, 0), (0, -3, 0, 0, 0)),
    ("out_of_bounds", (19.99, 2, 0, 0, 0), (3, 0, 0, 0, 0)),
    ("out_of_bounds", (-19.99, 2, 0, 0, 0), (-3, 0, 0, 0, 0)),
    ("out_of_bounds", (0, 19.99, 0, 0, 0), (0, 3, 0, 0, 0)),
    ("out_of_bounds", (0, 2, 0, 0, 0), (60, 0, 0, 0, 0)),
    ("out_of_bounds", (0, 2, 0, 0, 0), (0, -55, 0, 0, 0)),
    ("out_of_bounds", (0, 2, 0, 0, 0), (0, 0, 150, 0, 0)),
    ("out_of_bounds", (0, 2, 0, 0, 0), (0, 0, 0, 150, 0)),
    ("out_of_bounds", (0, 2, 0, 0, 0), (0, 0, 0, 0, -150)),
    ("non_finite", (0, 2, 0, 0, 0), (0, 0, 0, 1e200, 0)),
    # two conditions at once: the first in the order of the docs' table is reported
    ("curvature_limit", (0, -0.99, 0, 3.13, 0), (0, -3, 0, 5, 0)),
    ("ground", (0, -0.99, 0, 0, 0), (60, -3, 0, 0, 0)),
]


@pytest.mark.parametrize("reason,q0,qdot0", CRASHES)
def test_crash_term_on_each_termination_reason(reason, q0, qdot0):
    env, obs, reward, term, trunc, info = one_step(q0, qdot0=qdot0)
    t = info["reward_terms"]
    assert term and not trunc and info["termination_reason"] == reason
    assert t["crash"] == -10.0
    assert reward == pytest.approx(_terms_sum(info), abs=1e-12)
    assert -10.0 <= reward <= -9.0  # the other terms add [0, 1]
    q, qd = env.state
    if reason == "non_finite":  # the last finite state is kept
        np.testing.assert_array_equal(q, q0)
        np.testing.assert_array_equal(qd, qdot0)
        assert np.isfinite(obs).all()
    if reason == "curvature_limit":  # max|q_arm| > pi: the curvature term is at its floor
        assert t["curvature"] == -0.2


def test_no_crash_term_at_truncation():
    env = SoftPVTOLEnv(max_episode_seconds=0.03)
    env.reset(seed=0, options={"q0": (0, 2, 0, 0, 0), "qdot0": REST, "setpoint": (0, 2, 0)})
    for k in range(3):
        _, reward, term, trunc, info = env.step(HOVER)
        assert not term and trunc == (k == 2)
        assert info["reward_terms"]["crash"] == 0.0
    assert info["termination_reason"] == "time_limit"
    assert reward == pytest.approx(1 - 0.003125, abs=1e-9)


# ------------------------------------------------------------------------------------- bounds
def test_reward_bounds_at_extremes():
    """All terms at their floor but the curvature (which is -0.2 only at |q| = pi, where the arms leave
    the model's domain after any step): e = 10 m, e_theta = pi, |v| = 10 m/s, effort saturated (limits
    (10 N, 1 N m)), q_l = 3.1: r = 1 - 0.5 - 0.1 - 0.1 - 0.1 - 0.2 ((3.1 - pi/2)/(pi/2))^2 ~ 0.011 >= 0.
    The hover equilibrium without arm torques: r ~ 1 (the arms sag, making a small velocity error)."""
    env, obs, reward, term, trunc, info = one_step(
        (10, 2, 0, 3.1, 0), qdot0=(6, 8, 0, 0, 0), setpoint=(0, 2, PI), action=(-1, -1, 0, 0),
        task="setpoint", actuator_limits=(10.0, 1.0))
    t = info["reward_terms"]
    assert not term
    assert (t["position"], t["attitude"], t["velocity"], t["effort"]) == (-0.5, -0.1, -0.1, -0.1)
    assert reward == pytest.approx(0.2 - 0.2 * ((3.1 - PI / 2) / (PI / 2)) ** 2, abs=5e-3)
    assert 0.0 <= reward < 0.02
    _, _, reward, term, _, info = one_step((0, 2, 0, 0, 0), action=(-1 / 3, -1 / 3, 0, 0))
    assert not term and 0.999 < reward <= 1.0


@pytest.mark.parametrize("mode", [dict(action_mode="actuators"), dict(action_mode="virtual"),
                                  dict(action_mode="virtual", allocation="ideal"), dict(action_mode="residual")])
def test_non_terminal_rewards_in_unit_interval(mode):
    """Random states and actions (hard tier): every non-terminal reward is in [0, 1], every term in its
    range, the crash term 0, and the reward is the sum of the terms."""
    rng = np.random.default_rng(0)
    env = SoftPVTOLEnv(task="setpoint", tier="hard", **mode)
    dim = env.action_space.shape[0]
    ranges = {"alive": (1, 1), "position": (-0.5, 0), "attitude": (-0.1, 0), "velocity": (-0.1, 0),
              "effort": (-0.1, 0), "curvature": (-0.2, 0), "crash": (0, 0)}
    seen = 0
    for _ in range(40):
        q0 = rng.uniform([-15, 0, -3, -3, -3], [15, 15, 3, 3, 3])
        qd0 = rng.uniform(-1, 1, 5) * [8, 8, 6, 6, 6]
        env.reset(seed=int(rng.integers(1 << 30)), options={"q0": q0, "qdot0": qd0,
                                                             "setpoint": rng.uniform([-3, 0, -0.3], [3, 4, 0.3])})
        for _ in range(5):
            _, reward, term, _, info = env.step(rng.uniform(-1, 1, dim).astype(np.float32))
            if term:
                break
            seen += 1
            assert 0.0 <= reward <= 1.0
            for name, (lo, hi) in ranges.items():
                assert lo <= info["reward_terms"][name] <= hi, name
            assert reward == pytest.approx(_terms_sum(info), abs=1e-12)
    assert seen >= 100


def test_terms_use_the_true_state_not_the_measurement():
    """Noisy tier at the set-point: the observation's position error is the noise (~0.02 m), the
    position term that of the true state (~0)."""
    env, obs, reward, term, trunc, info = one_step((0, 2, 0, 0, 0), tier="noisy")
    assert np.abs(obs[:2]).max() > 1e-4
    assert -1e-9 < info["reward_terms"]["position"] <= 0.0
    assert -1e-9 < info["reward_terms"]["velocity"] <= 0.0
