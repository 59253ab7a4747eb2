"""The env's opt-in training aids: each does what the docs say, the defaults change
nothing, the single env and the vector env agree bit for bit, bad values are refused."""

import math

import gymnasium as gym
import numpy as np
import pytest

import softpvtol_gym  # noqa: F401
from softpvtol_gym import PassivityPolicy, SoftPVTOLEnv, SoftPVTOLVectorEnv
from softpvtol_gym.control import LOOPS
from softpvtol_gym.envs.config import EnvConfig
from softpvtol_gym.envs.episodes import ATTITUDE_Q, ATTITUDE_QD, START_X, START_Z_MAX, START_Z_MIN, WIDE_Q
from softpvtol_gym.envs.reward import REWARD_TERMS
from softpvtol_gym.tasks import PAPER_Q0

AIDS_ON = dict(observe_error_integral=True, precision_reward_weight=0.5, action_rate_penalty=0.2)


def _wrap(a):
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def _actions(rng, n, dim, scale=1.3):
    return rng.uniform(-scale, scale, size=(n, dim))  # some out of range: clipped


# ---------------------------------------------------------------------------------------------- defaults
def test_defaults_switch_every_aid_off():
    cfg = EnvConfig()
    assert cfg.obs_dim == 18 and cfg.extra_reward_terms == () and not cfg.uses_training_aids
    env = SoftPVTOLEnv(task="track_random")
    obs, info = env.reset(seed=3)
    assert env.sim.aids is None and obs.shape == (18,) and env.observation_space.shape == (18,)
    assert list(info["reward_terms"]) == list(REWARD_TERMS) and "residual_gate" not in info


@pytest.mark.parametrize("action_mode", ["actuators", "residual"])
def test_the_aids_leave_observation_reward_and_dynamics_as_they_were(action_mode):
    """With the error integral and both reward terms on, entries 0-17, the state and the seven default terms are
    those of the plain env bit for bit, and the reward is the plain one plus the two terms, in that order."""
    plain = SoftPVTOLEnv(task="track_random", tier="hard", action_mode=action_mode)
    aided = SoftPVTOLEnv(task="track_random", tier="hard", action_mode=action_mode, **AIDS_ON)
    o1, _ = plain.reset(seed=5)
    o2, _ = aided.reset(seed=5)
    np.testing.assert_array_equal(o2[:18], o1)
    np.testing.assert_array_equal(o2[18:], 0.0)
    rng = np.random.default_rng(0)
    for a in _actions(rng, 60, plain.action_space.shape[0]):
        o1, r1, t1, tr1, i1 = plain.step(a)
        o2, r2, t2, tr2, i2 = aided.step(a)
        np.testing.assert_array_equal(o2[:18], o1)
        for k in REWARD_TERMS:
            assert i2["reward_terms"][k] == i1["reward_terms"][k]
        extra = i2["reward_terms"]
        assert r2 == (r1 + extra["precision"]) + extra["action_rate"]
        assert (t1, tr1) == (t2, tr2)
        np.testing.assert_array_equal(aided.state[0], plain.state[0])
        np.testing.assert_array_equal(aided.state[1], plain.state[1])
        if t1 or tr1:
            break


# ------------------------------------------------------------------------------------- error integral
def test_the_error_integral_is_the_sum_of_dt_times_the_observed_errors():
    env = SoftPVTOLEnv(task="track_random", tier="noisy", observe_error_integral=True, frame_skip=1)
    assert env.observation_space.shape == (21,)
    rng = np.random.default_rng(1)
    for seed in (0, 1):  # a second episode: the integral starts again at 0
        obs, _ = env.reset(seed=seed)
        assert obs.shape == (21,) and (obs[18:] == 0.0).all()
        integral = np.zeros(3)
        from_obs = np.zeros(3)
        for a in _actions(rng, 50, 4, 0.3):
            obs, *_ = env.step(a)
            sim = env.sim
            e = (sim.qm[0, 0] - sim.qr[0, 0], sim.qm[0, 1] - sim.qr[0, 1], _wrap(sim.qm[0, 2] - sim.qr[0, 2]))
            for i in range(3):
                integral[i] = min(max(integral[i] + 0.01 * e[i], -10.0), 10.0)
            from_obs += 0.01 * obs[:3].astype(np.float64)
            np.testing.assert_array_equal(sim.aids.integrals[0], integral)  # the same float64 arithmetic
            np.testing.assert_array_equal(obs[18:], integral.astype(np.float32))
        np.testing.assert_allclose(integral, from_obs, rtol=1e-5, atol=1e-9)  # the float32 errors it observed
        assert np.abs(integral).max() > 1e-3


def test_the_error_integral_is_clipped_to_its_limit():
    env = SoftPVTOLEnv(task="track_paper", observe_error_integral=True, error_integral_limit=0.05)
    env.reset(seed=0)
    for _ in range(30):  # the paper start is 5 m beside and 7 m below the reference: 0.05 after 1 and 2 steps
        obs, *_ = env.step(np.zeros(4))
    assert obs[18] == np.float32(0.05) and obs[19] == np.float32(-0.05)
    assert np.all(np.abs(obs[18:]) <= np.float32(0.05))


def test_each_error_is_clipped_before_it_is_integrated_like_the_integral_loops():
    env = SoftPVTOLEnv(task="track_paper", observe_error_integral=True, error_integral_error_limit=0.5)
    env.reset(seed=0)
    integral = np.zeros(3)
    for _ in range(30):  # the paper start is 5 m beside and 7 m below: the x and z errors stay beyond 0.5 m
        obs, *_ = env.step(np.zeros(4))
        e = obs[:3].astype(np.float64)
        integral = np.clip(integral + 0.01 * np.clip(e, -0.5, 0.5), -10.0, 10.0)
    np.testing.assert_allclose(obs[18:], integral, rtol=1e-6, atol=1e-9)
    assert obs[18] == np.float32(30 * 0.01 * 0.5) and obs[19] == np.float32(-30 * 0.01 * 0.5)
    default = SoftPVTOLEnv(task="track_paper", observe_error_integral=True)  # None: no clip, as before
    default.reset(seed=0)
    obs, *_ = default.step(np.zeros(4))
    assert abs(obs[18]) > 0.01 * 0.5


# ---------------------------------------------------------------------------------------- reward terms
def test_the_precision_term_is_its_formula_and_sees_millimetres():
    w, s = 0.7, 0.01
    env = SoftPVTOLEnv(task="hover", precision_reward_weight=w, precision_reward_scale=s)
    setpoint = np.array([0.0, 2.0, 0.0, 0.0, 0.0])
    for dx in (0.2, 0.01, 1e-3, 1e-4, 0.0):
        env.reset(seed=0, options={"q0": setpoint + [dx, 0.0, 0, 0, 0], "qdot0": np.zeros(5)})
        _, r, *_, info = env.step(np.zeros(4))
        q, _ = env.state
        ex, ez = q[0] - env.sim.qr[0, 0], q[1] - env.sim.qr[0, 1]
        p = info["reward_terms"]["precision"]
        assert p == pytest.approx(w * math.exp(-math.sqrt(ex * ex + ez * ez) / s), rel=1e-14, abs=0)
        assert 0.0 <= p <= w
    # the slope at millimetres: 1 mm vs 0.1 mm is worth ~0.08 w (the default position term: 2e-4)
    assert w * (math.exp(-1e-4 / s) - math.exp(-1e-3 / s)) > 0.08 * w


def test_the_action_rate_term_is_its_formula():
    w = 0.3
    env = SoftPVTOLEnv(task="hover", action_mode="virtual", action_rate_penalty=w)
    rng = np.random.default_rng(2)
    for seed in (0, 1):
        env.reset(seed=seed)
        prev = None
        for a in _actions(rng, 20, 5, 1.5):
            *_, info = env.step(a)
            c = np.clip(a, -1.0, 1.0)
            want = 0.0 if prev is None else -w * float(np.sum((c - prev) ** 2)) / 5
            assert info["reward_terms"]["action_rate"] == pytest.approx(want, rel=1e-14, abs=0)
            assert -4 * w <= info["reward_terms"]["action_rate"] <= 0.0
            prev = c
        assert "precision" not in info["reward_terms"]  # only the terms switched on are listed


# -------------------------------------------------------------------------------------- residual gate
@pytest.mark.parametrize("loop", ["bounded", "integral"])
@pytest.mark.parametrize("space", ["virtual", "actuators"])
def test_the_gated_residual_is_exactly_zero_at_zero_error(loop, space):
    """At the set-point with zero velocity every error is 0: g = 0, and any action steps as action 0."""
    kw = dict(action_mode="residual", task="hover", controller_loop=loop, residual_space=space)
    gated = SoftPVTOLEnv(residual_gate=0.1, **kw)
    base = SoftPVTOLEnv(**kw)
    start = {"q0": [0.0, 2.0, 0.0, 0.0, 0.0], "qdot0": np.zeros(5)}
    o1, _ = gated.reset(seed=0, options=start)
    o2, _ = base.reset(seed=0, options=start)
    np.testing.assert_array_equal(o1[:3], 0.0)
    dim = gated.action_space.shape[0]
    o1, r1, *_, info = gated.step(np.full(dim, 0.9))
    o2, r2, *_ = base.step(np.zeros(dim))
    assert info["residual_gate"] == 0.0 and not info["action_clipped"]
    np.testing.assert_array_equal(o1, o2)
    assert r1 == r2
    np.testing.assert_array_equal(gated.state[0], base.state[0])


def test_the_gate_scales_the_clipped_residual_by_its_formula():
    """Away from the reference a gated env steps exactly as an ungated one given g clip(a)."""
    sigma = 0.5
    kw = dict(action_mode="residual", task="track_random", tier="noisy", controller_loop="integral")
    gated = SoftPVTOLEnv(residual_gate=sigma, **kw)
    plain = SoftPVTOLEnv(**kw)
    o1, _ = gated.reset(seed=4)
    plain.reset(seed=4)
    rng = np.random.default_rng(3)
    gates = []
    for a in _actions(rng, 40, 5, 1.4):
        s = gated.sim
        e = np.array([s.qm[0, 0] - s.qr[0, 0], s.qm[0, 1] - s.qr[0, 1], _wrap(s.qm[0, 2] - s.qr[0, 2]),
                      s.qdm[0, 0] - s.qdr[0, 0], s.qdm[0, 1] - s.qdr[0, 1], s.qdm[0, 2] - s.qdr[0, 2]])
        g = -math.expm1(-float(np.sum(e * e)) / sigma**2)
        o1, r1, *_, info = gated.step(a)
        o2, r2, *_ = plain.step(g * np.clip(a, -1.0, 1.0))
        assert info["residual_gate"] == pytest.approx(g, rel=1e-13)
        assert info["action_clipped"] == bool(np.any(np.abs(a) > 1.0))
        np.testing.assert_array_equal(o1, o2)
        assert r1 == r2
        gates.append(g)
    assert 0.0 < min(gates) < 0.99 and max(gates) <= 1.0


def test_the_gate_still_refuses_non_finite_actions_and_changes_nothing():
    env = SoftPVTOLEnv(action_mode="residual", task="hover", residual_gate=0.2)
    env.reset(seed=0)
    before = env.sim.F.copy()
    for bad in (np.array([np.nan, 0, 0, 0, 0]), np.array([0, np.inf, 0, 0, 0])):
        with pytest.raises(ValueError, match="action must be finite"):
            env.step(bad)
    np.testing.assert_array_equal(env.sim.F, before)


@pytest.mark.parametrize("loop", sorted(k for k in LOOPS if k != "ideal" and "controller" not in LOOPS[k]))
def test_residual_mode_runs_over_every_base_loop(loop):
    """Residual mode over every passivity loop of LOOPS ("ideal" applies tau directly: virtual mode only;
    "extended" is a policy only), with the gate and
    the error integral: action 0 is the base loop, the episode stays up."""
    env = SoftPVTOLEnv(action_mode="residual", task="track_random", controller_loop=loop, residual_gate=0.2,
                       observe_error_integral=True)
    obs, _ = env.reset(seed=2)
    rng = np.random.default_rng(4)
    for a in _actions(rng, 100, 5, 0.3):
        obs, r, term, trunc, info = env.step(a)
        assert not term and np.isfinite(obs).all() and np.isfinite(r)
    assert env.config.resolved_controller_loop == loop
    assert np.abs(obs[:2]).max() < 1.0


def test_residual_mode_refuses_the_ideal_loop():
    with pytest.raises(ValueError, match="controller_loop='ideal'"):
        SoftPVTOLEnv(action_mode="residual", controller_loop="ideal")


# -------------------------------------------------------------------------------------------- starts
def test_start_error_scale_scales_the_deviation_from_the_reference():
    env = SoftPVTOLEnv(task="track_paper", start_error_scale=0.5)
    env.reset(seed=0)
    q, qd = env.state
    ref0 = np.array([0.0, 7.0, 0.0, 0.0, 0.0])  # x = 4 sin(t/2), z = 3 cos(t/10) + 4 at t = 0
    np.testing.assert_allclose(q, ref0 + 0.5 * (np.array(PAPER_Q0) - ref0), rtol=0, atol=1e-15)
    np.testing.assert_allclose(qd, [1.0, 0.0, 0.0, 0.0, 0.0], atol=1e-15)  # 0.5 x 0 + (1 - 0.5) x xdot_ref(0) = 2
    # the reset option overrides the config's scale; 0 starts on the reference
    obs, _ = env.reset(seed=0, options={"start_error_scale": 0.0})
    np.testing.assert_array_equal(obs[:3], 0.0)
    np.testing.assert_allclose(obs[7:9], obs[12:14], atol=1e-6)
    # scale 1 is the task's own start, bit for bit; the reference, plant and noise key do not change with the scale
    plain = SoftPVTOLEnv(task="track_random", tier="mismatch")
    scaled = SoftPVTOLEnv(task="track_random", tier="mismatch", start_error_scale=3.0)
    plain.reset(seed=7)
    scaled.reset(seed=7)
    np.testing.assert_array_equal(scaled.sim.refp, plain.sim.refp)
    np.testing.assert_array_equal(scaled.sim.P, plain.sim.P)
    np.testing.assert_array_equal(scaled.sim.key, plain.sim.key)
    dev_plain = plain.state[0] - plain.sim.qr[0]
    dev_scaled = scaled.state[0] - scaled.sim.qr[0]
    np.testing.assert_allclose(dev_scaled[:3], 3.0 * dev_plain[:3], rtol=1e-12, atol=1e-12)
    scaled.reset(seed=7, options={"start_error_scale": 1.0})
    np.testing.assert_array_equal(scaled.state[0], plain.state[0])


@pytest.mark.parametrize("task", ["track_paper", "track_random", "hover"])
def test_wide_starts_cover_track_papers_start_inside_the_box(task):
    venv = SoftPVTOLVectorEnv(num_envs=400, task=task, start_distribution="wide")
    venv.reset(seed=0)
    s = venv.sim
    dev = s.q - s.qr * np.array([1, 1, 1, 0, 0])
    assert (np.abs(s.q[:, 0]) <= START_X).all() and (s.q[:, 1] >= START_Z_MIN).all()
    assert (s.q[:, 1] <= START_Z_MAX).all()
    assert (np.abs(dev) <= np.array(WIDE_Q) + 1e-12).all()
    # deviations as large as track_paper's (5 m beside, 7 m below, tilted 0.63 rad) occur
    assert np.abs(dev[:, 0]).max() > 5.0 and np.abs(dev[:, 2]).max() > 0.63
    if task == "track_paper":  # z_ref(0) = 7 m: starts down to the ground margin, 7 m below
        assert dev[:, 1].min() < -6.5
    _, _, term, _, _ = venv.step(np.zeros((400, 4)))
    assert not term.any()
    venv.close()


@pytest.mark.parametrize("task", ["hover", "track_random"])
def test_attitude_starts_are_turned_and_spinning_near_the_reference(task):
    venv = SoftPVTOLVectorEnv(num_envs=400, task=task, start_distribution="attitude")
    venv.reset(seed=0)
    s = venv.sim
    dev, dev_rate = s.q - s.qr * np.array([1, 1, 1, 0, 0]), s.qd - s.qdr * np.array([1, 1, 1, 0, 0])
    assert (np.abs(dev) <= np.array(ATTITUDE_Q) + 1e-12).all()
    assert (np.abs(dev_rate) <= np.array(ATTITUDE_QD) + 1e-12).all()
    # the body turned beyond 1 rad, spinning faster than 1.5 rad/s, and the positions within 1 m
    assert np.abs(dev[:, 2]).max() > 1.0 and np.abs(dev_rate[:, 2]).max() > 1.5
    assert np.abs(dev[:, :2]).max() <= 1.0 + 1e-12
    # the same episode seeds as the task's starts: only the start's shape differs
    plain = SoftPVTOLVectorEnv(num_envs=400, task=task)
    plain.reset(seed=0)
    np.testing.assert_array_equal(plain.sim.qr, s.qr)
    assert not np.array_equal(plain.sim.q, s.q)
    _, _, term, _, _ = venv.step(np.zeros((400, 4)))
    assert not term.any()
    venv.close()
    plain.close()


# ------------------------------------------------------------------------------ single = vector, resume
def test_single_and_vector_envs_agree_bit_for_bit_with_every_aid():
    kw = dict(action_mode="residual", task="track_random", tier="hard", controller_loop="integral",
              residual_gate=0.3, start_distribution="wide", start_error_scale=0.5, max_episode_seconds=0.3,
              **AIDS_ON)
    n = 3
    venv = SoftPVTOLVectorEnv(num_envs=n, **kw)
    envs = [SoftPVTOLEnv(**kw) for _ in range(n)]
    vo, _ = venv.reset(seed=10)
    for i, e in enumerate(envs):
        o, _ = e.reset(seed=10 + i)
        np.testing.assert_array_equal(vo[i], o)
    rng = np.random.default_rng(5)
    done = np.zeros(n, bool)
    for a in _actions(rng, 70, 5, 1.2):  # two episodes and more: autoresets clear the aids' memory
        batch = np.tile(a, (n, 1))
        vo, vr, vt, vtr, vi = venv.step(batch)
        for i, e in enumerate(envs):
            if done[i]:  # the vector env's next-step autoreset
                o, _ = e.reset()
                np.testing.assert_array_equal(vo[i], o)
                assert not (vt[i] or vtr[i])
                done[i] = False
                continue
            o, r, t, tr, info = e.step(a)
            np.testing.assert_array_equal(vo[i], o)
            assert vr[i] == r
            for k in ("precision", "action_rate"):
                assert vi["reward_terms"][k][i] == info["reward_terms"][k]
            assert vi["residual_gate"][i] == info["residual_gate"]
            done[i] = t or tr
            assert done[i] == (vt[i] or vtr[i])
    venv.close()


def test_gym_make_and_the_sb3_adapter_see_the_longer_observation():
    env = gym.make("SoftPVTOL-v0", observe_error_integral=True)
    assert env.observation_space.shape == (21,)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (21,)
    venv = gym.make_vec("SoftPVTOL-v0", num_envs=2, vectorization_mode="vector_entry_point",
                        observe_error_integral=True)
    assert venv.single_observation_space.shape == (21,)
    venv.close()


def test_passivity_policy_reads_the_first_18_entries():
    plain = SoftPVTOLEnv(task="track_random")
    aided = SoftPVTOLEnv(task="track_random", observe_error_integral=True)
    p1, p2 = PassivityPolicy.from_env(plain), PassivityPolicy.from_env(aided)
    o1, _ = plain.reset(seed=1)
    o2, _ = aided.reset(seed=1)
    for t in range(50):
        a1, _ = p1.predict(o1, episode_start=t == 0)
        a2, _ = p2.predict(o2, episode_start=t == 0)
        np.testing.assert_array_equal(a1, a2)
        o1, *_ = plain.step(a1)
        o2, *_ = aided.step(a2)
    with pytest.raises(ValueError, match=r"observation must have shape \(21,\) or \(N, 21\)"):
        p2.predict(o1)


def test_checkpoint_resume_restores_the_aids_memory():
    from softpvtol_gym.baselines.checkpoints.resume import env_state, restore_env_state

    kw = dict(num_envs=2, action_mode="residual", task="track_random", residual_gate=0.3, **AIDS_ON)
    a = SoftPVTOLVectorEnv(**kw)
    a.reset(seed=0)
    rng = np.random.default_rng(6)
    a.set_start_error_scale(0.25)
    for act in _actions(rng, 20, 5):
        a.step(np.tile(act, (2, 1)))
    meta, arrays = env_state(a)
    assert "aids" in meta
    b = SoftPVTOLVectorEnv(**kw)
    restore_env_state(b, meta, arrays, "test")
    np.testing.assert_array_equal(b.sim.aids.integrals, a.sim.aids.integrals)
    assert float(b.sim.start_error_scale) == 0.25
    for act in _actions(rng, 5, 5):
        oa, ra, *_ = a.step(np.tile(act, (2, 1)))
        ob, rb, *_ = b.step(np.tile(act, (2, 1)))
        np.testing.assert_array_equal(oa, ob)
        np.testing.assert_array_equal(ra, rb)


# ------------------------------------------------------------------------------------------ bad input
@pytest.mark.parametrize("kwargs, match", [
    ({"observe_error_integral": 1}, "observe_error_integral must be a bool"),
    ({"observe_error_integral": "yes"}, "observe_error_integral must be a bool"),
    ({"error_integral_limit": 0.0}, "error_integral_limit must be finite and > 0"),
    ({"error_integral_limit": math.nan}, "error_integral_limit"),
    ({"error_integral_error_limit": 0.0}, "error_integral_error_limit must be finite and > 0"),
    ({"error_integral_error_limit": math.nan}, "error_integral_error_limit"),
    ({"error_integral_error_limit": -math.inf}, "error_integral_error_limit"),
    ({"precision_reward_weight": -0.1}, r"precision_reward_weight must be in \[0, 100\]"),
    ({"precision_reward_weight": math.nan}, "precision_reward_weight"),
    ({"precision_reward_weight": "1"}, "precision_reward_weight must be a real number"),
    ({"precision_reward_weight": True}, "precision_reward_weight must be a real number"),
    ({"precision_reward_scale": 0.0}, "precision_reward_scale"),
    ({"action_rate_penalty": -1.0}, "action_rate_penalty must be in"),
    ({"action_rate_penalty": math.inf}, "action_rate_penalty"),
    ({"residual_gate": 0.1}, "residual_gate gates the residual action of action_mode='residual'"),
    ({"residual_gate": -0.1, "action_mode": "residual"}, "residual_gate must be finite and > 0"),
    ({"residual_gate": math.nan, "action_mode": "residual"}, "residual_gate"),
    ({"start_error_scale": -0.5}, r"start_error_scale must be in \[0, 10\]"),
    ({"start_error_scale": 11.0}, r"start_error_scale must be in \[0, 10\]"),
    ({"start_distribution": "paper"}, r"start_distribution must be one of \['task', 'wide', 'attitude'\]"),
])
def test_bad_aid_arguments_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SoftPVTOLEnv(**kwargs)
    with pytest.raises(ValueError, match=match):
        SoftPVTOLVectorEnv(num_envs=2, **kwargs)


@pytest.mark.parametrize("value, match", [
    (-1.0, r"start_error_scale' must be in \[0, 10\]"), (math.nan, "start_error_scale"),
    ("2", "start_error_scale' must be a real number"), (np.ones(2), "start_error_scale' must be a real number"),
])
def test_bad_start_error_scale_reset_options_are_refused_before_anything_changes(value, match):
    env = SoftPVTOLEnv(task="hover")
    env.reset(seed=0)
    before = env.sim.F.copy()
    with pytest.raises(ValueError, match=match):
        env.reset(seed=1, options={"start_error_scale": value})
    np.testing.assert_array_equal(env.sim.F, before)
    venv = SoftPVTOLVectorEnv(num_envs=2)
    with pytest.raises(ValueError, match=match):
        venv.reset(seed=1, options={"start_error_scale": value})


def test_set_start_error_scale_is_a_curriculum_knob_for_every_later_reset():
    venv = SoftPVTOLVectorEnv(num_envs=2, task="track_paper", max_episode_seconds=0.02)
    venv.reset(seed=0)
    np.testing.assert_array_equal(venv.sim.q[:, 0], 5.0)
    venv.set_start_error_scale(0.2)
    for _ in range(3):  # the episode ends after 2 steps; the next-step autoreset uses the new scale
        venv.step(np.zeros((2, 4)))
    np.testing.assert_allclose(venv.sim.q[:, :2], [[1.0, 5.6], [1.0, 5.6]], atol=1e-12)
    venv.reset(seed=0, options={"start_error_scale": 1.0})  # the option wins for its reset
    np.testing.assert_array_equal(venv.sim.q[:, 0], 5.0)
    env = SoftPVTOLEnv(task="track_paper")
    env.set_start_error_scale(0.0)
    env.reset(seed=0)
    np.testing.assert_allclose(env.state[0], [0.0, 7.0, 0.0, 0.0, 0.0], atol=1e-15)
    for bad in (-0.1, math.nan, "1", 10.5):
        with pytest.raises(ValueError, match="start_error_scale"):
            env.set_start_error_scale(bad)
    assert float(env.sim.start_error_scale) == 0.0


def test_an_env_with_aids_pickles_with_its_memory():
    import pickle

    env = SoftPVTOLEnv(action_mode="residual", task="track_random", residual_gate=0.3, **AIDS_ON)
    env.reset(seed=0)
    rng = np.random.default_rng(7)
    for a in _actions(rng, 10, 5):
        env.step(a)
    copy = pickle.loads(pickle.dumps(env))
    for a in _actions(rng, 5, 5):
        o1, r1, *_, i1 = env.step(a)
        o2, r2, *_, i2 = copy.step(a)
        np.testing.assert_array_equal(o1, o2)
        assert r1 == r2 and i1["reward_terms"] == i2["reward_terms"]
