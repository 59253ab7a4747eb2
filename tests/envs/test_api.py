"""SoftPVTOL-v0 API: registration, checkers, argument validation, spaces, truncation, seeding."""

import contextlib
import os
import warnings

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")

import gymnasium as gym
import numpy as np
import pytest

from softpvtol_gym import SoftPVTOLEnv, SoftPVTOLParams, SoftPVTOLVectorEnv
from softpvtol_gym.envs.reward import REWARD_TERMS
from softpvtol_gym.envs.tiers import BUILTIN_TIERS

MODES = ["actuators", "virtual", "residual"]
TASKS = ["hover", "setpoint", "track_paper", "track_random"]


@pytest.mark.parametrize("task", TASKS)
@pytest.mark.parametrize("mode", MODES)
def test_gymnasium_check_env_no_warnings(mode, task):
    from gymnasium.utils.env_checker import check_env

    env = gym.make("SoftPVTOL-v0", action_mode=mode, task=task)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped, skip_render_check=True)


@pytest.mark.parametrize("task", TASKS)
@pytest.mark.parametrize("mode", MODES)
def test_sb3_check_env_no_warnings(mode, task):
    from stable_baselines3.common.env_checker import check_env

    env = SoftPVTOLEnv(action_mode=mode, task=task)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env, warn=True)


def test_registration_and_make_vec_modes():
    env = gym.make("SoftPVTOL-v0")
    assert isinstance(env.unwrapped, SoftPVTOLEnv)
    venv = gym.make_vec("SoftPVTOL-v0", num_envs=3, vectorization_mode="vector_entry_point")
    assert isinstance(venv.unwrapped, SoftPVTOLVectorEnv)
    sync = gym.make_vec("SoftPVTOL-v0", num_envs=3, vectorization_mode="sync")
    o1, _ = venv.reset(seed=5)
    o2, _ = sync.reset(seed=5)
    np.testing.assert_array_equal(o1, o2)
    assert venv.metadata["autoreset_mode"] == gym.vector.AutoresetMode.NEXT_STEP


@pytest.mark.parametrize("how", ["make", "vector_entry_point", "sync"])
def test_truncation_at_episode_length(how):
    kw = dict(task="hover", max_episode_seconds=0.5, action_mode="residual")
    if how == "make":
        env = gym.make("SoftPVTOL-v0", **kw)
        env.reset(seed=0)
        for k in range(50):
            _, _, term, trunc, info = env.step(np.zeros(5, np.float32))
            assert not term
            assert trunc == (k == 49)
        assert info["termination_reason"] == "time_limit"
    else:
        env = gym.make_vec("SoftPVTOL-v0", num_envs=2, vectorization_mode=how, **kw)
        env.reset(seed=0)
        for k in range(50):
            _, _, term, trunc, _ = env.step(np.zeros((2, 5), np.float32))
            assert not term.any()
            assert trunc.all() == (k == 49)


def test_default_episode_lengths():
    assert {t: SoftPVTOLEnv(task=t).config.max_steps for t in TASKS} == {
        "hover": 1000, "setpoint": 1000, "track_paper": 4000, "track_random": 2000}


def test_action_spaces_and_scales():
    p = SoftPVTOLParams()
    env = SoftPVTOLEnv()
    assert env.action_space.shape == (4,) and env.action_space.dtype == np.float32
    assert env.config.thrust_max == pytest.approx(3 * p.hover_thrust)
    assert env.config.arm_torque_max == pytest.approx(4 * p.arm_gravity_torques[0])
    assert SoftPVTOLEnv(action_mode="virtual").action_space.shape == (5,)
    assert SoftPVTOLEnv(action_mode="residual").action_space.shape == (5,)
    assert SoftPVTOLEnv(action_mode="residual", residual_space="actuators").action_space.shape == (4,)
    assert env.observation_space.shape == (18,) and env.observation_space.dtype == np.float32


def test_actuator_action_maps_to_thrust_and_torque():
    env = SoftPVTOLEnv()
    env.reset(seed=0)
    env.step(np.array([1.0, -1.0, 0.5, -0.5], np.float32))
    a = env._sim.applied[0]
    T, tau = env.config.thrust_max, env.config.arm_torque_max
    np.testing.assert_allclose(a[:4], [T, 0.0, 0.5 * tau, -0.5 * tau])


# ------------------------------------------------------------------------------ bad inputs
@pytest.fixture
def env():
    e = SoftPVTOLEnv()
    e.reset(seed=0)
    return e


def test_nan_action_raises(env):
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([np.nan, 0, 0, 0]))


def test_inf_action_raises(env):
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([0, np.inf, 0, 0]))


def test_wrong_shape_action_raises(env):
    with pytest.raises(ValueError, match=r"shape \(4,\).*got shape \(5,\)"):
        env.step(np.zeros(5))


def test_non_numeric_action_raises(env):
    with pytest.raises(ValueError, match="action"):
        env.step("up")


def test_vector_wrong_shape_action_raises():
    v = SoftPVTOLVectorEnv(num_envs=3)
    v.reset(seed=0)
    with pytest.raises(ValueError, match=r"\(3, 4\)"):
        v.step(np.zeros((2, 4)))


def test_out_of_range_action_is_clipped_and_reported(env):
    _, _, _, _, info = env.step(np.array([2.0, 0, 0, 0]))
    assert info["action_clipped"] is True
    assert env._sim.applied[0, 0] == pytest.approx(env.config.thrust_max)
    _, _, _, _, info = env.step(np.zeros(4))
    assert info["action_clipped"] is False


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(action_mode="torque"), "action_mode must be one of"),
        (dict(task="fly"), "task must be one of"),
        (dict(tier="extreme"), "tier must be one of"),
        (dict(input_map="approx"), "input_map must be one of"),
        (dict(allocation="lsq"), "allocation must be one of"),
        (dict(allocation="ideal", action_mode="actuators"), "only valid with action_mode='virtual'"),
        (dict(allocation="ideal", action_mode="residual"), "only valid with action_mode='virtual'"),
        (dict(params={"m": 5.0}), "params must be a SoftPVTOLParams"),
        (dict(params=SoftPVTOLParams().array), "params must be a SoftPVTOLParams"),
        (dict(residual_space="body"), "residual_space must be one of"),
        (dict(render_mode="ascii"), "render_mode must be one of"),
        (dict(frame_skip=0), "frame_skip"),
        (dict(frame_skip=1.5), "frame_skip"),
        (dict(max_episode_seconds=-1.0), "max_episode_seconds"),
        (dict(tier_options={"gust": 1.0}), "unknown tier option"),
        (dict(tier_options={"wind_std": -1.0}), "wind_std"),
        (dict(actuator_limits=(100.0,)), "actuator_limits"),
        (dict(task=3), "task must be one of"),
    ],
    ids=lambda v: str(v) if isinstance(v, str) else None,
)
def test_bad_arguments_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SoftPVTOLEnv(**kwargs)
    registry_warning = contextlib.nullcontext()
    if "render_mode" in kwargs:  # gym.make itself warns about a mode outside metadata["render_modes"] first
        registry_warning = pytest.warns(UserWarning, match="not in the possible render_modes")
    with pytest.raises(ValueError, match=match), registry_warning:
        gym.make("SoftPVTOL-v0", **kwargs)


def test_error_lists_valid_values():
    with pytest.raises(ValueError) as e:
        SoftPVTOLEnv(tier="extreme")
    for t in BUILTIN_TIERS:
        assert t in str(e.value)


def test_arguments_kept_as_given():
    p = SoftPVTOLParams(m=4.0)
    env = SoftPVTOLEnv(action_mode="virtual", allocation="paper", params=p, input_map="exact")
    assert env.config.params is p
    assert env.config.allocation == "paper" and env.config.input_map == "exact"
    assert SoftPVTOLEnv(action_mode="virtual").config.allocation is None
    assert SoftPVTOLEnv(action_mode="virtual").config.resolved_allocation == "exact"


def test_bad_reset_option():
    e = SoftPVTOLEnv()
    with pytest.raises(ValueError, match="unknown reset option"):
        e.reset(options={"x0": 1.0})
    with pytest.raises(ValueError, match="'q0' must be 5 finite"):
        e.reset(options={"q0": [0, 0, 0]})


def test_reset_options_override_state():
    e = SoftPVTOLEnv(task="setpoint")
    q0 = np.array([1.0, 2.0, 0.1, 0.2, -0.2])
    obs, _ = e.reset(seed=1, options={"q0": q0, "qdot0": np.zeros(5), "setpoint": (0.5, 1.0, 0.0)})
    np.testing.assert_array_equal(e.state[0], q0)
    np.testing.assert_allclose(obs[:2], [0.5, 1.0], rtol=1e-6)


# ------------------------------------------------------------------------------- seeding
def _rollout(env, seed, n=60):
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(123)
    out = [obs]
    for _ in range(n):
        obs, r, term, trunc, _ = env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
        out.append(np.append(obs, [r, term, trunc]))
        if term or trunc:
            env.reset()
    return np.concatenate([np.ravel(o) for o in out])


@pytest.mark.parametrize("tier", ["nominal", "hard"])
def test_same_seed_same_trajectory_different_seed_different(tier):
    a = _rollout(SoftPVTOLEnv(tier=tier), 7)
    b = _rollout(SoftPVTOLEnv(tier=tier), 7)
    c = _rollout(SoftPVTOLEnv(tier=tier), 8)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_info_contents(env):
    _, _, _, _, info = env.step(np.zeros(4))
    for k in ("reward_terms", "total_energy", "storage_function", "curvature_violation", "allocation_residual",
              "thrust_saturated", "arm_torque_saturated", "action_clipped", "termination_reason"):
        assert k in info
    assert set(info["reward_terms"]) == set(REWARD_TERMS)
    assert np.isfinite(info["total_energy"]) and info["storage_function"] >= 0


def test_reward_is_sum_of_terms(env):
    _, r, _, _, info = env.step(np.zeros(4))
    assert r == pytest.approx(sum(info["reward_terms"].values()))
    assert 0.0 <= r <= 1.0
