"""The analytic loops beyond the paper: the solved algebraic loop, the "bounded" loop that
is the env's default, controller_loop=, and the control periods the default gains allow."""

from __future__ import annotations

import numpy as np
import pytest

from softpvtol_gym import PassivityPolicy, SoftPVTOLEnv
from softpvtol_gym.control import (
    LOOPS,
    MAX_HELD_CONTROL_PERIOD,
    PassivityController,
    paper_reference,
    simulate_closed_loop,
)
from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv


@pytest.mark.parametrize("loop", ["paper", "exact", "improved", "bounded"])
@pytest.mark.parametrize("hold", ["stage", "step"])
def test_algebraic_loop_solved_to_1e10_every_step(loop, hold):
    r = simulate_closed_loop(loop, t_final=5.0, hold=hold)
    assert np.all(r["algebraic_residual"] <= 1e-10), r["algebraic_residual"].max()
    assert np.all(r["algebraic_iterations"] >= 1)
    # the solution continues the branch: no jump of the arm references by ~pi (another root) per step
    # (the improved loop's unbounded feedforward swings them in its first second: steps up to 1.9 rad)
    assert np.max(np.abs(np.diff(r["arm_reference"], axis=0))) < 2.5


def test_paper_case_first_step_right_rotor_pushes_the_right_way():
    """At t = 0 of the paper's case the right rotor's vertical thrust component is negative: the
    printed arctan would put q_r^d near +1.55 rad (pushing the body the wrong way); atan2 gives the
    quadrant-correct -1.60 rad, whose horizontal force has the commanded sign."""
    c = PassivityController.from_loop("paper")
    q0 = np.array([5.0, 0.0, 0.2 * np.pi, 0.01 * np.pi, -0.15 * np.pi])
    out = c(q0, np.zeros(5), *paper_reference(0.0))
    Tl, Tr, ql, qr = out.actuators[0], out.actuators[1], out.arm_reference[0], out.arm_reference[1]
    ux = np.cos(q0[2]) * out.tau[0] + np.sin(q0[2]) * out.tau[1]  # body-frame horizontal force asked for
    assert -1.7 < qr < -1.5
    np.testing.assert_allclose(Tl * np.sin(ql), ux / 2, rtol=1e-6)
    np.testing.assert_allclose(-Tr * np.sin(qr), ux / 2, rtol=1e-6)


def test_tolerance_zero_runs_exactly_the_given_passes():
    c = PassivityController.from_loop("improved", algebraic_iterations=3, algebraic_tolerance=0.0)
    q0 = np.array([5.0, 0.0, 0.6, 0.03, -0.4])
    out = c(q0, np.ones(5), *paper_reference(0.0))
    assert int(out.loop_iterations) == 3


@pytest.mark.parametrize("loop", ["paper", "exact", "bounded"])
def test_max_held_control_period(loop):
    """The default gains' arm loop is stable held over 0.012 s and diverges from 0.013 s."""
    ok = simulate_closed_loop(loop, hold="step", dt=MAX_HELD_CONTROL_PERIOD, t_final=20.0)
    assert np.all(np.isfinite(ok["q"])) and np.max(np.abs(ok["q"][:, 3:5])) < np.pi
    with pytest.raises(ValueError, match="diverged"):
        simulate_closed_loop(loop, hold="step", dt=0.013, t_final=20.0)


def test_bounded_loop_in_the_env_tracks_the_paper_trajectory_within_1mm():
    """track_paper nominal, default actuator limits: RMS position error over 30-40 s <= 1e-3 m, no
    crash (the exact loop keeps ~5 cm: its arm references have no feedforward)."""
    rms = {}
    for loop in ("bounded", "exact"):
        env = SoftPVTOLVectorEnv(num_envs=1, task="track_paper", action_mode="actuators")
        pol = PassivityPolicy.from_env(env, loop=loop)
        obs, _ = env.reset(seed=0)
        err = []
        for _ in range(env.config.max_steps):
            obs, _, term, trunc, _ = env.step(pol.predict(obs)[0])
            err.append(np.linalg.norm(env.sim.q[0, :2] - env.sim.qr[0, :2]))
            if term[0] or trunc[0]:
                break
        t = 0.01 * np.arange(1, len(err) + 1)
        rms[loop] = (np.sqrt(np.mean(np.square(err)[t >= 30.0])) if t[-1] >= 40.0 - 1e-9 else np.inf, bool(term[0]))
    assert rms["bounded"][0] <= 1e-3 and not rms["bounded"][1], rms
    assert 1e-2 < rms["exact"][0] < 0.1, rms


def test_bounded_loop_does_not_chatter_at_hover():
    """The fed-forward derivatives enter the arm rows only: in the body rows their differences (1/dt^2)
    would close a loop through the allocation with a gain far above 1 at the Nyquist frequency, and the
    arm torques would flip between +-tau_max at every step of a held command."""
    env = SoftPVTOLVectorEnv(num_envs=1, task="hover", action_mode="actuators")
    pol = PassivityPolicy.from_env(env)
    obs, _ = env.reset(seed=1_000_000)
    arm = []
    for _ in range(1000):
        a, _ = pol.predict(obs)
        arm.append(a[0, 2:4].copy())
        obs, *_ = env.step(a)
    late = np.array(arm[300:])
    assert late.std(axis=0).max() < 0.01, late.std(axis=0)  # normalised arm torques after the transient


def test_controller_loop_kwarg_and_defaults():
    assert SoftPVTOLEnv().config.resolved_controller_loop == "bounded"
    assert SoftPVTOLEnv(allocation="paper").config.resolved_controller_loop == "paper"
    assert SoftPVTOLEnv(action_mode="virtual", allocation="ideal").config.resolved_controller_loop == "ideal"
    env = SoftPVTOLEnv(action_mode="residual", controller_loop="improved")
    assert env.config.resolved_controller_loop == "improved" and env.config.resolved_allocation == "exact"
    assert env.sim.controller.arm_feedforward and env.sim.controller.feedforward_limits == (5.0, 50.0)
    env = SoftPVTOLEnv(action_mode="virtual", controller_loop="paper")
    assert env.config.resolved_allocation == "paper"
    assert PassivityPolicy.from_env(SoftPVTOLEnv()).loop == "bounded"
    assert PassivityPolicy.from_env(SoftPVTOLEnv(controller_loop="exact")).loop == "exact"
    c = PassivityController.from_loop("bounded")
    assert c.curvature_limit == LOOPS["bounded"]["curvature_limit"] == 0.6


@pytest.mark.parametrize("kwargs, match", [
    (dict(controller_loop="convergent-ish"), "controller_loop must be one of"),
    (dict(controller_loop="ideal"), "needs action_mode='virtual'"),
    (dict(controller_loop="paper", allocation="exact"), "uses allocation='paper'"),
    (dict(controller_loop=3), "controller_loop must be one of"),
])
def test_controller_loop_bad_values(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SoftPVTOLEnv(**kwargs)


def test_held_period_beyond_the_limit_is_refused_or_warned():
    with pytest.raises(ValueError, match="frame_skip=2"):
        PassivityPolicy.from_env(SoftPVTOLEnv(frame_skip=2))
    with pytest.warns(UserWarning, match="base controller's arm loop diverges"):
        SoftPVTOLEnv(action_mode="residual", frame_skip=2)
