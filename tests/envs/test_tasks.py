"""The task and tier registries: a task registered from user code runs everywhere a built-in one does."""

import pickle

import gymnasium as gym
import numpy as np
import pytest

import softpvtol_gym  # noqa: F401
from softpvtol_gym import PassivityPolicy, SoftPVTOLEnv, SoftPVTOLVectorEnv
from softpvtol_gym.envs import TierSpec, register_tier
from softpvtol_gym.envs.tiers import registered_tiers
from softpvtol_gym.tasks import BUILTIN_TASKS, TaskSpec, get_task, register_task, registered_tasks


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
    assert BUILTIN_TASKS == ("hover", "setpoint", "track_paper", "track_random")
    assert registered_tasks()[:4] == BUILTIN_TASKS
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


def test_run_time_registrations_are_visible_through_every_lookup():
    """TASKS/TIERS are live lookups (not import-time snapshots): a task and a tier registered after
    every module was imported are in registered_tasks()/registered_tiers(), in every TASKS/TIERS
    attribute, and accepted by the env, the vector env and EnvConfig; a name nobody registered is
    still refused."""
    import softpvtol_gym.envs as envs_pkg
    import softpvtol_gym.envs.tiers as tiers_mod
    import softpvtol_gym.registry as registry
    import softpvtol_gym.tasks as tasks_mod
    from softpvtol_gym.envs import EnvConfig

    before_tasks, before_tiers = tasks_mod.TASKS, tiers_mod.TIERS
    assert "test_live_task" not in before_tasks and "test_live_tier" not in before_tiers
    register_task(TaskSpec("test_live_task", circle, episode_seconds=3.0), overwrite=True)
    register_tier(TierSpec("test_live_tier", ("lag",)), overwrite=True)
    for names in (registered_tasks(), registry.registered_tasks(), tasks_mod.TASKS, envs_pkg.TASKS):
        assert "test_live_task" in names and names[:4] == BUILTIN_TASKS
    for names in (registered_tiers(), registry.registered_tiers(), tiers_mod.TIERS, envs_pkg.TIERS):
        assert "test_live_tier" in names and names[:len(tiers_mod.BUILTIN_TIERS)] == tiers_mod.BUILTIN_TIERS
    assert "test_live_task" in registry.TASK_REGISTRY and "test_live_tier" in registry.TIER_REGISTRY
    assert "TASKS" in dir(tasks_mod) and "TIERS" in dir(envs_pkg)
    with pytest.raises(AttributeError):
        tasks_mod.NO_SUCH_NAME  # noqa: B018
    # the env, the vector env and the config accept them
    cfg = EnvConfig(task="test_live_task", tier="test_live_tier")
    assert cfg.max_steps == 300 and cfg.tier_values["actuator_time_constant"] == 0.05
    env = SoftPVTOLEnv(task="test_live_task", tier="test_live_tier")
    obs, _ = env.reset(seed=0)
    assert np.isfinite(obs).all()
    venv = SoftPVTOLVectorEnv(2, task="test_live_task", tier="test_live_tier")
    obs, _ = venv.reset(seed=0)
    assert obs.shape[0] == 2 and np.isfinite(obs).all()
    venv.close()
    # the built-ins' snapshot names are unchanged; a name nobody registered is still refused
    assert before_tasks == tuple(n for n in tasks_mod.TASKS if n != "test_live_task")
    with pytest.raises(ValueError, match="registered tiers"):
        EnvConfig(tier="test_never_registered")


def test_task_and_tier_registries_share_one_implementation():
    """One generic Registry class behind both (no second copy of the register/get/list code)."""
    from softpvtol_gym import registry

    assert type(registry.TASK_REGISTRY) is type(registry.TIER_REGISTRY) is registry.Registry
    with pytest.raises(TypeError, match="register_tier takes a TierSpec"):
        register_tier(TaskSpec("test_wrong_kind", circle, 5.0))
    with pytest.raises(ValueError, match="already registered"):
        register_tier(TierSpec("nominal"))
