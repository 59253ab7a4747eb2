"""The task and tier registries: a task registered from user code runs everywhere a built-in one does."""

import pickle

import gymnasium as gym
import numpy as np
import pytest

import softpvtol_gym  # noqa: F401
from softpvtol_gym import PassivityPolicy, SoftPVTOLEnv, SoftPVTOLVectorEnv
from softpvtol_gym.envs import TierSpec, register_tier
from softpvtol_gym.envs.tiers import registered_tiers
from softpvtol_gym.tasks import TASKS, TaskSpec, get_task, register_task, registered_tasks


def circle(t):
    """A 2 m circle around (0, 3) at 0.5 rad/s, theta = 0."""
    w = 0.5
    pos = np.stack([2 * np.sin(w * t), 3 + 2 * np.cos(w * t), 0 * t], axis=1)
    vel = np.stack([2 * w * np.cos(w * t), -2 * w * np.sin(w * t), 0 * t], axis=1)
    acc = np.stack([-2 * w * w * np.sin(w * t), -2 * w * w * np.cos(w * t), 0 * t], axis=1)
    return pos, vel, acc


@pytest.fixture(scope="module")
def circle_task():
    return register_task(TaskSpec("test_circle", circle, episode_seconds=12.0), overwrite=True)


def test_builtin_tasks_are_registered_specs():
    assert TASKS == ("hover", "setpoint", "track_paper", "track_random")
    assert set(TASKS) <= set(registered_tasks())
    spec = get_task("track_paper")
    pos, vel, acc = spec.evaluate(np.array([0.0, 1.0]))
    np.testing.assert_allclose(pos[1], [4 * np.sin(0.5), 3 * np.cos(0.1) + 4, 0], rtol=0, atol=1e-14)
    np.testing.assert_allclose(vel[1], [2 * np.cos(0.5), -0.3 * np.sin(0.1), 0], rtol=0, atol=1e-14)
    np.testing.assert_allclose(acc[1], [-np.sin(0.5), -0.03 * np.cos(0.1), 0], rtol=0, atol=1e-14)


def test_registered_task_runs_in_single_env_and_follows_its_reference(circle_task):
    env = gym.make("SoftPVTOL-v0", task="test_circle", action_mode="actuators", render_mode="rgb_array")
    obs, info = env.reset(seed=3)
    sim = env.unwrapped.sim
    # starts at the reference at t = 0 plus the hover perturbation (|dx|, |dz| <= 1 m)
    assert np.all(np.abs(sim.q[0, :2] - [0.0, 5.0]) <= 1.0)
    policy = PassivityPolicy.from_env(env)
    err = []
    for k in range(env.unwrapped.config.max_steps):
        action, _ = policy.predict(obs, episode_start=np.array([k == 0]))
        obs, r, term, trunc, info = env.step(action)
        t = sim.t[0]
        pos, vel, acc = circle(np.array([t]))
        np.testing.assert_allclose(sim.qr[0, :3], pos[0], rtol=0, atol=1e-15)
        np.testing.assert_allclose(obs[12:15], vel[0], rtol=0, atol=1e-6)
        np.testing.assert_allclose(obs[15:18], acc[0], rtol=0, atol=1e-6)
        err.append(np.hypot(*(sim.q[0, :2] - pos[0, :2])))
        assert not term
    assert trunc and info["termination_reason"] == "time_limit"
    assert np.mean(err[-200:]) < 0.3  # the passivity policy tracks it
    frame = env.render()
    assert frame.shape == (450, 600, 3)


def test_registered_task_vector_env_equals_single_envs(circle_task):
    n = 3
    venv = SoftPVTOLVectorEnv(num_envs=n, task="test_circle", action_mode="residual", tier="wind")
    obs_v, _ = venv.reset(seed=10)
    singles = [SoftPVTOLEnv(task="test_circle", action_mode="residual", tier="wind") for _ in range(n)]
    for i, e in enumerate(singles):
        np.testing.assert_array_equal(e.reset(seed=10 + i)[0], obs_v[i])
    rng = np.random.default_rng(0)
    for _ in range(60):
        a = rng.uniform(-0.2, 0.2, (n, 5)).astype(np.float32)
        obs_v, r_v, *_ = venv.step(a)
        for i, e in enumerate(singles):
            o, r, *_ = e.step(a[i])
            np.testing.assert_array_equal(o, obs_v[i])
            assert r == r_v[i]


def test_registered_task_with_initial_state_and_view():
    def start(u):
        n = u.shape[0]
        q0 = np.zeros((n, 5))
        q0[:, 1] = 1.0 + u[:, 0]
        return q0, np.zeros((n, 5))

    register_task(TaskSpec("test_climb", lambda t: (np.c_[0 * t, 2 + 0 * t, 0 * t], np.zeros((t.size, 3)),
                                                     np.zeros((t.size, 3))), 5.0, initial_state=start,
                           view=(-3.0, 3.0, -1.0)), overwrite=True)
    env = SoftPVTOLEnv(task="test_climb", render_mode="rgb_array")
    env.reset(seed=0)
    assert 1.0 <= env.state[0][1] < 2.0 and env.state[0][0] == 0.0
    assert env.config.max_steps == 500
    assert env.render().shape == (450, 600, 3)


def test_pickled_env_keeps_its_task(circle_task):
    env = SoftPVTOLEnv(task="track_paper")
    env.reset(seed=0)
    env2 = pickle.loads(pickle.dumps(env))
    a = np.zeros(4)
    np.testing.assert_array_equal(env.step(a)[0], env2.step(a)[0])


def test_pickled_state_of_another_layout_is_refused():
    env = SoftPVTOLEnv()
    state = env.sim.__getstate__()
    state["layouts"] = (("env_state", 1, (("q", 5),)), state["layouts"][1])
    with pytest.raises(ValueError, match="layout"):
        type(env.sim).__new__(type(env.sim)).__setstate__(state)


@pytest.mark.parametrize("bad, match", [
    (dict(name=""), "name"),
    (dict(reference=3), "callable"),
    (dict(episode_seconds=0), "episode_seconds"),
    (dict(episode_seconds=float("nan")), "episode_seconds"),
    (dict(initial_state="x"), "initial_state"),
    (dict(view=(1, 0, 0)), "view"),
])
def test_bad_task_specs_are_refused(bad, match):
    kw = dict(name="test_bad", reference=circle, episode_seconds=5.0) | bad
    with pytest.raises(ValueError, match=match):
        TaskSpec(**kw)


@pytest.mark.parametrize("reference, match", [
    (lambda t: (np.zeros((t.size, 2)),) * 3, "shape"),
    (lambda t: np.zeros((t.size, 3)), "tuple"),
    (lambda t: (np.full((t.size, 3), np.nan),) * 3, "non-finite"),
])
def test_bad_references_are_refused_at_registration(reference, match):
    with pytest.raises(ValueError, match=match):
        register_task(TaskSpec("test_bad_ref", reference, 5.0))
    assert "test_bad_ref" not in registered_tasks()


def test_duplicate_and_unknown_tasks():
    with pytest.raises(ValueError, match="already registered"):
        register_task(TaskSpec("hover", circle, 5.0))
    with pytest.raises(TypeError):
        register_task("hover")
    with pytest.raises(ValueError, match="registered tasks"):
        SoftPVTOLEnv(task="no_such_task")


def test_registered_tier_runs():
    register_tier(TierSpec("test_windy_noisy", ("wind", "noise")), overwrite=True)
    assert "test_windy_noisy" in registered_tiers()
    env = SoftPVTOLEnv(tier="test_windy_noisy")
    env.reset(seed=0)
    assert env.config.tier_values["wind_std"] == 3.0 and env.config.tier_values["actuator_time_constant"] == 0.0
    env.step(np.zeros(4))
    assert np.any(env.sim.wind[0] != 0) and np.any(env.sim.qm[0] != env.sim.q[0])
    with pytest.raises(ValueError, match="unknown tier effects"):
        TierSpec("test_bad", ("rain",))
    with pytest.raises(ValueError, match="tier must be one of"):
        SoftPVTOLEnv(tier="no_such_tier")
