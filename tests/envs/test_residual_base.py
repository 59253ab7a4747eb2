"""The residual mode's base in the actuator space: the correction added to the loop's command as computed
(``residual_base="unsaturated"``) or clipped to the actuator box first (``"saturated"``)."""

import numpy as np
import pytest

from softpvtol_gym import PassivityPolicy, SoftPVTOLVectorEnv

N, SCALE = 8, 2.0


def _residual_env(base: str) -> SoftPVTOLVectorEnv:
    """The noisy tier without its actuator lag: the plant's inputs are the step's saturated command."""
    return SoftPVTOLVectorEnv(num_envs=N, action_mode="residual", residual_space="actuators", residual_scale=SCALE,
                              controller_loop="integral", task="track_random", tier="noisy",
                              tier_options={"actuator_time_constant": 0.0}, residual_base=base)


def _loop_beside(env: SoftPVTOLVectorEnv) -> PassivityPolicy:
    """The env's base loop as a policy on the actuators mode, fed the observations the env's loop acts on."""
    probe = SoftPVTOLVectorEnv(num_envs=1, action_mode="actuators", task="track_random", controller_loop="integral")
    return PassivityPolicy.from_env(probe)


@pytest.mark.parametrize("base", ["unsaturated", "saturated"])
def test_the_plant_gets_the_correction_added_to_the_base_as_named(base):
    """Under sensor noise the loop's arm command leaves the box; the plant's inputs are
    clip(base + scale a) with base the loop's command, clipped to the box first where saturated."""
    env, rng = _residual_env(base), np.random.default_rng(0)
    loop = _loop_beside(env)
    obs, _ = env.reset(seed=5)
    start = np.ones(N, bool)
    outside = 0
    for _ in range(60):
        loop.predict(obs, episode_start=start, deterministic=True)
        command = loop.unclipped_actions()
        outside += int((np.abs(command) > 1.0).sum())
        action = rng.uniform(-1, 1, (N, 4)).astype(np.float32)
        expected = np.clip((np.clip(command, -1, 1) if base == "saturated" else command) + SCALE * action, -1, 1)
        obs, _, term, trunc, _ = env.step(action)
        assert not (term | trunc).any()
        # the loop beside reads the float32 observations, the env's loop the float64 measured state
        np.testing.assert_allclose(env.applied_actions(), expected, rtol=0, atol=1e-4)
        start[:] = False
    assert outside > 0, "the check needs base commands outside the actuator box"


def test_action_zero_flies_the_same_episodes_on_either_base():
    """Action 0: clip(clip(base)) = clip(base), the base loop's applied command in both."""
    states = []
    for base in ("unsaturated", "saturated"):
        env = _residual_env(base)
        env.reset(seed=11)
        for _ in range(100):
            env.step(np.zeros((N, 4), np.float32))
        states.append(np.concatenate(env.state, axis=1))
    np.testing.assert_array_equal(states[0], states[1])


def test_the_bases_differ_when_the_command_leaves_the_box():
    """A correction back toward the box from a command outside it: absorbed on the unsaturated base, applied on
    the saturated one."""
    applied = {}
    for base in ("unsaturated", "saturated"):
        env = _residual_env(base)
        env.reset(seed=5)
        env.step(np.zeros((N, 4), np.float32))
        env.step(np.full((N, 4), -0.5, np.float32))
        applied[base] = env.applied_actions()
    assert not np.array_equal(applied["unsaturated"], applied["saturated"])
