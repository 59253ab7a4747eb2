"""The integral loop (``LOOPS["integral"]``): integral action in the sliding variable, anti-windup,
reset with the episode, and bad input."""

from __future__ import annotations

import dataclasses
import json
import math
import pickle

import numpy as np
import pytest

from softpvtol_gym import PassivityPolicy, SoftPVTOLParams
from softpvtol_gym.control import LOOPS, PassivityController, hover_reference, simulate_closed_loop
from softpvtol_gym.control import kernels as CK
from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv


def test_the_integral_loop_is_the_bounded_loop_with_integral_action():
    integral, bounded = LOOPS["integral"], LOOPS["bounded"]
    for key in ("allocation", "arm_feedforward", "feedforward_limits", "curvature_limit"):
        assert integral[key] == bounded[key]
    c = PassivityController.from_loop("integral")
    assert all(g > 0 for g in c.integral_gains[:2])
    assert PassivityController.from_loop("bounded").integral_gains == (0.0, 0.0, 0.0)


def _hover_offset(loop: str, t_final: float) -> np.ndarray:
    """Body position error (x, z) at the end of a hover under a 20 % heavier plant than the controller
    believes (a constant disturbance the passivity law cannot cancel)."""
    nominal = SoftPVTOLParams()
    heavy = dataclasses.replace(nominal, m=1.2 * nominal.m)
    out = simulate_closed_loop(loop, q0=(0.3, -0.2, 0.0, 0.0, 0.0), reference=hover_reference, t_final=t_final,
                               dt=0.01, plant_params=heavy, hold="step")
    return out["q"][-1, :2] - out["q_ref"][-1, :2]


def test_integral_action_removes_the_offset_of_a_constant_disturbance():
    # the bounded loop settles with an offset (its stiffness K Lambda resists the missing weight); the
    # integral loop's error decays exponentially to zero: 40 s later it is 1e4 times smaller again
    offset = np.abs(_hover_offset("bounded", 40.0)).max()
    assert offset > 0.1
    e40, e80 = (np.abs(_hover_offset("integral", t)).max() for t in (40.0, 80.0))
    assert e40 < 1e-3 * offset
    assert e80 < 1e-4 * e40 + 1e-12


def test_the_integral_is_bounded_and_held_while_the_error_is_large():
    c = PassivityController.from_loop("integral", integral_limits=(0.3, 0.3, 0.3))
    q = np.array([6.0, -8.0, 0.0, 0.0, 0.0])
    z = np.zeros(5)
    for _ in range(200):  # 2 s 6 m and 8 m away: the integrated error is clipped, then the integral
        c(q, z, z, z, z)
    integral = c._state[0, CK.ST_INT:CK.ST_INT + 3]
    assert integral[0] == pytest.approx(0.3) and integral[1] == pytest.approx(-0.3) and integral[2] == 0.0
    c2 = PassivityController.from_loop("integral")
    for _ in range(10):  # 0.1 s at 6 m: the error integrated is clipped to err_max = 0.5 m per second
        c2(q, z, z, z, z)
    lim = LOOPS["integral"]["integral_error_limits"]
    assert c2._state[0, CK.ST_INT] == pytest.approx(10 * 0.01 * lim[0])


def test_commit_false_leaves_the_integral_alone():
    c = PassivityController.from_loop("integral")
    q, z = np.array([0.2, 0.1, 0.0, 0.0, 0.0]), np.zeros(5)
    c(q, z, z, z, z)
    before = c._state.copy()
    c(q, z, z, z, z, commit=False)
    np.testing.assert_array_equal(c._state, before)


def test_the_policy_resets_the_integral_at_episode_start():
    env = SoftPVTOLVectorEnv(num_envs=2, task="hover", tier="wind")
    obs, _ = env.reset(seed=3)
    policy = PassivityPolicy.from_env(env, loop="integral")
    first, _ = policy.predict(obs, episode_start=np.array([True, True]))
    for _ in range(50):
        obs, *_ = env.step(policy.predict(obs, episode_start=np.array([False, False]))[0])
    assert np.abs(policy.controller._state[:, CK.ST_INT:CK.ST_INT + 2]).max() > 0.0
    fresh = PassivityPolicy.from_env(env, loop="integral")
    again, _ = policy.predict(obs, episode_start=np.array([True, True]))
    np.testing.assert_array_equal(again, fresh.predict(obs, episode_start=np.array([True, True]))[0])
    env.close()


def test_residual_mode_over_the_integral_loop_matches_the_policy_in_actuators_mode():
    # the residual mode's base controller with a zero residual is the integral policy in actuators mode (up
    # to the float32 rounding of the observations the policy acts on), not the bounded one
    def run(action_mode, loop):
        kw = {"controller_loop": loop} if action_mode == "residual" else {}
        env = SoftPVTOLVectorEnv(num_envs=3, action_mode=action_mode, task="hover", tier="mismatch", **kw)
        obs, _ = env.reset(seed=11)
        policy = None if action_mode == "residual" else PassivityPolicy.from_env(env, loop=loop)
        start = np.ones(3, bool)
        for _ in range(100):
            if policy is None:
                action = np.zeros((3, env.single_action_space.shape[0]))
            else:
                action = policy.predict(obs, episode_start=start)[0]
            obs, *_ = env.step(action)
            start[:] = False
        q = env.sim.q[:, :3].copy()
        env.close()
        return q

    residual = run("residual", "integral")
    gap = np.abs(residual - run("actuators", "integral")).max()
    assert gap < 1e-3
    assert np.abs(residual - run("actuators", "bounded")).max() > 100 * gap


@pytest.mark.parametrize("options, match", [
    ({"integral_gains": (0.1, 0.1)}, "integral_gains must be 3 numbers"),
    ({"integral_gains": (0.1, -0.1, 0.0)}, "integral_gains must be 3 numbers"),
    ({"integral_gains": (0.1, math.nan, 0.0)}, "integral_gains must be 3 numbers"),
    ({"integral_gains": "0.1"}, "integral_gains must be 3 numbers"),
    ({"integral_limits": (1.0, 0.0, 1.0)}, "integral_limits must be 3 numbers"),
    ({"integral_error_limits": (1.0, 1.0, -1.0)}, "integral_error_limits must be 3 numbers"),
    ({"integral_gain": (0.1, 0.1, 0.0)}, r"unknown controller option\(s\) \['integral_gain'\]"),
])
def test_bad_integral_options_are_refused(options, match):
    with pytest.raises(ValueError, match=match):
        PassivityController.from_loop("integral", **options)


def test_policy_controller_options_are_checked():
    env = SoftPVTOLVectorEnv(num_envs=1)
    with pytest.raises(ValueError, match="cannot set"):
        PassivityPolicy.from_env(env, loop="integral", controller_options={"dt": 0.02})
    with pytest.raises(ValueError, match="unknown controller option"):
        PassivityPolicy.from_env(env, loop="integral", controller_options={"ki": 1.0})
    policy = PassivityPolicy.from_env(env, loop="bounded", controller_options={"integral_gains": (0.2, 0.2, 0.0)})
    assert policy.controller.integral_gains == (0.2, 0.2, 0.0)
    env.close()


def test_the_ideal_loop_refuses_integral_action():
    with pytest.raises(ValueError, match="need an actuated loop"):
        PassivityController.from_loop("ideal", integral_gains=(0.1, 0.1, 0.0))


def test_a_controller_pickled_under_another_memory_layout_is_refused():
    c = PassivityController.from_loop("integral")
    state = c.__getstate__()
    state["layouts"] = (("controller_memory", 1, None), state["layouts"][1])
    fresh = PassivityController.__new__(PassivityController)
    with pytest.raises(ValueError, match="recreate the env"):
        fresh.__setstate__(state)
    again = pickle.loads(pickle.dumps(c))
    assert again.integral_gains == c.integral_gains


def test_the_sweep_table_in_the_docs_is_generated_from_the_committed_results():
    from benchmarks import integral_sweep

    data = json.loads(integral_sweep.OUT.read_text())
    assert set(data["variants"]) == set(integral_sweep.VARIANTS)
    assert integral_sweep.committed_table_is_current()
    # what docs/control.md says of it: the integral loop removes the steady offsets of wind and mismatch (at
    # most a quarter of the bounded loop's last-half RMS on hover) and crashes in 1 of the 90 episodes, the bounded
    # loop in 6
    chosen, bounded = data["variants"]["**integral** (the loop's settings)"], data["variants"]["bounded (no integral)"]
    for tier in ("wind", "mismatch"):
        assert chosen[f"hover/{tier}"]["steady"] <= 0.25 * bounded[f"hover/{tier}"]["steady"]
    def crashes(variant):
        return round(sum(cell["crash_rate"] for cell in variant.values()) * data["episodes"])

    assert (crashes(chosen), crashes(bounded)) == (1, 6)
