"""Parameter and option validation closed (issue 22, item 2 and the MEDIUM findings on the core):
every accepted value gives finite rewards and observations and a step that returns promptly; every
refused value gets a ValueError naming the argument, the value and the reason.

* ``test_bad_value_refused``: the audit's cases (``g=0``, ``m=1e308``, ``residual_scale=1e308``,
  ``frame_skip`` 2**63-1 / 2**62 / 10**6) and each bound of every argument and tier option;
* ``test_fuzz_accepted_values_stay_finite``: hypothesis over the accepted ranges (parameters at the
  ends of their bands, every action mode, tier, task, frame_skip up to its bound, ...), a few steps
  with extreme actions, stepping on after a termination;
* the reward's NaN guard (``reward_terms`` with a NaN effort; the residual base controller failing
  outside the model), ``PassivityPolicy.from_env(env, loop="ideal")`` in actuators mode and
  ``gym.make(..., render_mode=1)``.
"""

from __future__ import annotations

import math
import re
import time
import warnings

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from softpvtol_gym import PassivityPolicy, SoftPVTOLEnv, SoftPVTOLParams, SoftPVTOLVectorEnv
from softpvtol_gym.control import LOOPS
from softpvtol_gym.envs import EnvConfig
from softpvtol_gym.envs.actions import ACTION_MODES
from softpvtol_gym.envs.config import MAX_FRAME_SKIP, MAX_RESIDUAL_SCALE
from softpvtol_gym.envs.reward import REWARD_TERMS, reward_terms
from softpvtol_gym.envs.tiers import BUILTIN_TIERS, FORCE_MAX, MISMATCH_FIELDS, TIER_OPTION_BOUNDS, tier_values
from softpvtol_gym.params import PARAM_FIELDS, PARAM_MAX, PARAM_MIN
from softpvtol_gym.registry import MAX_EPISODE_SECONDS, TaskSpec

NAN, INF = math.nan, math.inf
BUILTIN_TASKS = ("hover", "setpoint", "track_paper", "track_random")


# ------------------------------------------------------------------------------ refused values
def _hover_reference(t):
    z = np.zeros((t.shape[0], 3))
    return z, z, z


#: (id, call, argument named in the message, value as shown, a fragment of the reason)
BAD = [
    # the audit's cases
    ("g_zero_default_limits", lambda: SoftPVTOLEnv(params=SoftPVTOLParams(g=0.0)), "SoftPVTOLParams.g", "0.0",
     "both 0 without gravity"),
    ("m_1e308", lambda: SoftPVTOLParams(m=1e308), "SoftPVTOLParams.m", "1e+308", "float64"),
    ("residual_scale_1e308", lambda: SoftPVTOLEnv(action_mode="residual", residual_scale=1e308), "residual_scale",
     "1e+308", "saturate"),
    ("frame_skip_int64_max", lambda: SoftPVTOLEnv(frame_skip=2**63 - 1), "frame_skip", str(2**63 - 1), "10 s"),
    ("frame_skip_2_62", lambda: SoftPVTOLEnv(frame_skip=2**62), "frame_skip", str(2**62), "10 s"),
    ("frame_skip_1e6", lambda: SoftPVTOLEnv(frame_skip=10**6), "frame_skip", "1000000", "10 s"),
    ("frame_skip_numpy", lambda: SoftPVTOLEnv(frame_skip=np.int64(MAX_FRAME_SKIP + 1)), "frame_skip", "1001", "10 s"),
    # parameter bands
    *[(f"{f}_above", lambda f=f: SoftPVTOLParams(**{f: 2 * PARAM_MAX}), f"SoftPVTOLParams.{f}", "2000000.0", "float64")
      for f in PARAM_FIELDS],
    *[(f"{f}_below", lambda f=f: SoftPVTOLParams(**{f: PARAM_MIN / 2}), f"SoftPVTOLParams.{f}", "5e-07", "float64")
      for f in PARAM_FIELDS if f not in ("g", "epsilon")],
    ("g_subnormal_env", lambda: SoftPVTOLEnv(params=SoftPVTOLParams(g=5e-324), actuator_limits=(10.0, 1.0)),
     "SoftPVTOLParams.g", "5e-324", "free flight"),
    ("g_tiny_env", lambda: SoftPVTOLEnv(params=SoftPVTOLParams(g=1e-9)), "SoftPVTOLParams.g", "1e-09", "underflow"),
    ("from_array_huge", lambda: SoftPVTOLParams.from_array(np.full(len(PARAM_FIELDS), 1e300)), "SoftPVTOLParams.m",
     "1e+300", "float64"),
    ("mismatch_pushes_m_out", lambda: SoftPVTOLEnv(tier="mismatch", params=SoftPVTOLParams(m=PARAM_MAX)),
     "SoftPVTOLParams.m", "1000000.0", "mismatch_scale"),
    ("mismatch_option_pushes_I_l_out",
     lambda: SoftPVTOLEnv(tier_options={"mismatch_scale": 0.9}, params=SoftPVTOLParams(I_l=5e-6)),
     "SoftPVTOLParams.I_l", "5e-06", "mismatch_scale"),
    # env arguments
    ("residual_scale_above", lambda: SoftPVTOLEnv(residual_scale=MAX_RESIDUAL_SCALE * 1.01), "residual_scale", "101.0",
     "saturate"),
    ("max_episode_seconds_1e308", lambda: SoftPVTOLEnv(max_episode_seconds=1e308), "max_episode_seconds", "1e+308",
     "resolution"),
    ("max_episode_seconds_above", lambda: SoftPVTOLEnv(max_episode_seconds=2 * MAX_EPISODE_SECONDS),
     "max_episode_seconds", "2000000000.0", "resolution"),
    ("task_episode_seconds_above", lambda: TaskSpec("long", _hover_reference, episode_seconds=1e12),
     "TaskSpec.episode_seconds", "1000000000000.0", "resolution"),
    ("thrust_max_above", lambda: SoftPVTOLEnv(actuator_limits=(1e21, 10.0)), "actuator_limits[0] (thrust_max)",
     "1e+21", "float64"),
    ("arm_torque_max_1e308", lambda: SoftPVTOLEnv(actuator_limits=(100.0, 1e308)),
     "actuator_limits[1] (arm_torque_max)", "1e+308", "float64"),
    ("thrust_max_nan", lambda: SoftPVTOLEnv(actuator_limits=(NAN, 10.0)), "actuator_limits[0] (thrust_max)", "nan",
     "float64"),
    # tier options
    ("wind_std_above", lambda: SoftPVTOLEnv(tier_options={"wind_std": 2 * FORCE_MAX}), "tier_options['wind_std']",
     "2e+20", "a force"),
    ("wind_correlation_time_above",
     lambda: SoftPVTOLEnv(tier_options={"wind_correlation_time": 2 * MAX_EPISODE_SECONDS}),
     "tier_options['wind_correlation_time']", "2000000000.0", "constant"),
    ("obs_noise_scale_above", lambda: SoftPVTOLEnv(tier_options={"obs_noise_scale": 1e9}),
     "tier_options['obs_noise_scale']", "1000000000.0", "clipped noise"),
    ("actuator_time_constant_above", lambda: SoftPVTOLEnv(tier_options={"actuator_time_constant": 1e300}),
     "tier_options['actuator_time_constant']", "1e+300", "never moves"),
    ("mismatch_scale_one", lambda: SoftPVTOLEnv(tier_options={"mismatch_scale": 1.0}),
     "tier_options['mismatch_scale']", "1.0", "must stay > 0"),
    ("wind_std_negative", lambda: SoftPVTOLEnv(tier_options={"wind_std": -1.0}), "tier_options['wind_std']", "-1.0",
     "a force"),
    # the policy's loop
    ("policy_ideal_actuators", lambda: PassivityPolicy.from_env(SoftPVTOLEnv(), loop="ideal"), "loop='ideal'",
     "action_mode='actuators'", "valid loops for action_mode='actuators'"),
    ("policy_ideal_residual", lambda: PassivityPolicy(EnvConfig(action_mode="residual"), loop="ideal"),
     "loop='ideal'", "action_mode='residual'", "only action_mode='virtual' takes"),
    # render_mode through gym.make: refused before gymnasium calls str methods on it
    ("make_render_mode_int", lambda: gym.make("SoftPVTOL-v0", render_mode=1), "render_mode", "got 1", "one of"),
    ("make_render_mode_float", lambda: gym.make("SoftPVTOLVirtual-v0", render_mode=1.5), "render_mode", "got 1.5",
     "one of"),
    ("make_render_mode_list", lambda: gym.make("SoftPVTOL-v0", render_mode=["human"]), "render_mode", "['human']",
     "one of"),
    ("make_vec_render_mode_int",
     lambda: gym.make_vec("SoftPVTOL-v0", num_envs=2, render_mode=1, vectorization_mode="sync"), "render_mode",
     "got 1", "one of"),
]


@pytest.mark.parametrize(("call", "argument", "value", "reason"), [pytest.param(*c[1:], id=c[0]) for c in BAD])
def test_bad_value_refused(call, argument, value, reason):
    t0 = time.perf_counter()
    with pytest.raises(ValueError) as info:
        call()
    msg = str(info.value)
    assert argument in msg and value in msg and reason in msg, msg
    assert "\n" not in msg, msg  # one line
    assert time.perf_counter() - t0 < 30.0  # refused up front (a huge frame_skip must not run first)


def test_loop_error_lists_the_valid_loops():
    with pytest.raises(ValueError) as info:
        PassivityPolicy.from_env(SoftPVTOLEnv(), loop="ideal")
    listed = re.search(r"valid loops for action_mode='actuators': \[(.*)\]", str(info.value)).group(1)
    assert sorted(x.strip(" '") for x in listed.split(",")) == sorted(k for k in LOOPS if k != "ideal")
    for loop in sorted(k for k in LOOPS if k != "ideal"):  # each of them is accepted
        PassivityPolicy.from_env(SoftPVTOLEnv(), loop=loop)
    PassivityPolicy.from_env(SoftPVTOLEnv(action_mode="virtual"), loop="ideal")  # tau: what the virtual mode takes


def test_render_mode_membership_keeps_gymnasium_behaviour():
    """The render-mode list refuses only non-str modes: gym.make still turns "rgb_array_list" into the
    RenderCollection wrapper and warns about an unknown str before the env refuses it."""
    modes = SoftPVTOLEnv.metadata["render_modes"]
    assert "rgb_array" in modes and "human" in modes and "ansi" not in modes and None not in modes
    env = gym.make("SoftPVTOL-v0", render_mode="rgb_array_list")
    assert env.render_mode == "rgb_array_list"
    env.close()


def test_g_zero_free_flight_with_limits_is_finite():
    """g = 0 stays allowed with explicit actuator limits (free flight): the dynamics divide by no g."""
    for mode in ACTION_MODES:
        env = SoftPVTOLEnv(action_mode=mode, params=SoftPVTOLParams(g=0.0), actuator_limits=(50.0, 5.0))
        env.reset(seed=0)
        for a in (np.ones(env.action_space.shape), -np.ones(env.action_space.shape), np.zeros(env.action_space.shape)):
            obs, r, *_ = env.step(a.astype(np.float32))
            assert np.isfinite(r) and np.isfinite(obs).all()


def test_num_envs_beyond_memory_names_the_argument():
    with pytest.raises(MemoryError, match=r"num_envs=1000000000000 does not fit in memory"):
        SoftPVTOLVectorEnv(num_envs=10**12)


# ------------------------------------------------------------------------------- reward guard
def test_reward_terms_finite_for_any_input():
    for bad in (NAN, INF, 1e308):
        for i in range(4):
            args = [0.1, 0.1, 0.1, 0.1]
            args[i] = bad
            terms = reward_terms(*args, 0.0, False)
            assert len(terms) == len(REWARD_TERMS) and all(math.isfinite(t) for t in terms), (i, bad, terms)
    # unchanged for ordinary values: min(x, 1) exactly
    assert reward_terms(1.0, 0.5, 2.5, 0.25, 0.0, False) == (1.0, -0.25, -0.1 * (0.5 / math.pi), -0.05, -0.025, -0.0,
                                                             0.0)
    assert reward_terms(4.0, 4.0, 10.0, 3.0, 0.0, True)[1:5] == (-0.5, -0.1, -0.1, -0.1)


def test_reward_finite_when_the_base_controller_fails_outside_the_model():
    """Residual mode: a diverged env stepped once more feeds the base controller an arm curvature beyond
    its model; it returns NaN actuators, the physics ends the step as "non_finite", and the reward (whose
    effort term is NaN then) stays finite."""
    env = SoftPVTOLEnv(action_mode="residual", input_map="exact")  # its controller checks |q_arm| <= 2 pi
    env.reset(seed=0, options={"q0": [0.0, 2.0, 0.0, 3.0, 0.0], "qdot0": [0.0, 0.0, 0.0, 90.0, 0.0]})
    reasons = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # stepping after the end: gymnasium-style warning
        for _ in range(8):
            obs, r, term, trunc, info = env.step(np.zeros(5, dtype=np.float32))
            reasons.append(info.get("termination_reason"))
            assert np.isfinite(r) and np.isfinite(obs).all(), (reasons, r)
            assert all(math.isfinite(v) for v in info["reward_terms"].values()), info["reward_terms"]
            if reasons[-1] == "non_finite":  # the base controller failed: NaN actuators, the largest effort
                assert np.isnan(env.sim.applied[0, :4]).all()
                assert info["reward_terms"]["effort"] == -0.1 and info["reward_terms"]["crash"] == -10.0
    assert "non_finite" in reasons, reasons  # the guarded path was taken


# ------------------------------------------------------------------------------------- fuzz
def _log_uniform(lo: float, hi: float):
    """Floats from lo to hi, uniform in log10, and the two ends themselves."""
    return st.one_of(st.sampled_from([lo, hi]),
                     st.floats(math.log10(lo), math.log10(hi)).map(lambda e: min(max(10.0 ** e, lo), hi)))


@st.composite
def env_arguments(draw):
    """Arguments the env accepts: parameters across their bands, every action mode, tier, task and
    option within its bounds (the mismatch tiers' parameters drawn where the scaled plant stays in its
    band, which the env requires)."""
    mode = draw(st.sampled_from(ACTION_MODES))
    tier = draw(st.sampled_from(BUILTIN_TIERS))
    opts = None
    if draw(st.booleans()):
        opts = {}
        for k, (_, hi, _) in TIER_OPTION_BOUNDS.items():
            if not draw(st.booleans()):
                continue
            if k == "mismatch_scale":
                opts[k] = draw(st.sampled_from([0.0, 0.5, 0.999]))
            elif k == "wind_correlation_time":  # > 0
                opts[k] = draw(_log_uniform(1e-6, hi))
            else:
                opts[k] = draw(st.one_of(st.just(0.0), _log_uniform(1e-6, hi)))
    s = tier_values(tier, opts)["mismatch_scale"]
    p = {f: draw(_log_uniform(PARAM_MIN / (1.0 - s), PARAM_MAX / (1.0 + s))) for f in MISMATCH_FIELDS}
    p["g"] = draw(st.one_of(st.just(0.0), _log_uniform(PARAM_MIN, PARAM_MAX), st.just(9.8)))
    p["epsilon"] = draw(st.one_of(st.just(0.0), _log_uniform(PARAM_MIN, PARAM_MAX)))
    frame_skip = draw(st.one_of(st.integers(1, 3), st.just(MAX_FRAME_SKIP), st.integers(1, MAX_FRAME_SKIP)))
    kw = dict(action_mode=mode, params=SoftPVTOLParams(**p), task=draw(st.sampled_from(BUILTIN_TASKS)), tier=tier,
              input_map=draw(st.sampled_from(["paper", "exact"])), frame_skip=frame_skip, tier_options=opts)
    if p["g"] == 0.0 or draw(st.booleans()):
        kw["actuator_limits"] = (draw(_log_uniform(1e-6, FORCE_MAX)), draw(_log_uniform(1e-6, FORCE_MAX)))
    if mode == "residual":
        kw["residual_scale"] = draw(_log_uniform(1e-6, MAX_RESIDUAL_SCALE))
        kw["residual_space"] = draw(st.sampled_from(["virtual", "actuators"]))
        kw["controller_loop"] = draw(st.sampled_from([None] + sorted(k for k in LOOPS if k != "ideal"
                                                                       and "controller" not in LOOPS[k])))
    if mode == "virtual":
        kw["allocation"] = draw(st.sampled_from([None, "exact", "paper", "ideal"]))
    if draw(st.booleans()):
        dt = 0.01 * frame_skip
        kw["max_episode_seconds"] = draw(st.sampled_from([dt, max(dt, 0.05), max(dt, 1e4), MAX_EPISODE_SECONDS]))
    return kw


#: the lowest reward: every penalty at its cap and the crash penalty (1 - 0.5 - 0.1 - 0.1 - 0.1 - 0.2 - 10)
MIN_REWARD = -10.0
#: the longest an env step may take after the first (which may compile kernels): a step is at most
#: MAX_FRAME_SKIP RK4 steps (~15 ms on the 2-core development machine); generous for a loaded machine
STEP_SECONDS = 2.0


@settings(max_examples=150, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(kw=env_arguments(), seed=st.integers(0, 2**32 - 1),
       actions=st.lists(st.sampled_from([-1.0, 0.0, 1.0, 0.3]), min_size=4, max_size=4))
def test_fuzz_accepted_values_stay_finite(kw, seed, actions):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the residual mode warns about a frame_skip its base controller cannot hold
        env = SoftPVTOLEnv(**kw)
    obs, _ = env.reset(seed=seed)
    assert np.isfinite(obs).all()
    rng = np.random.default_rng(seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # stepping on after the end of an episode warns
        for i, a in enumerate(actions):
            action = np.full(env.action_space.shape, a, dtype=np.float32)
            if i == 3:
                action = rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
            t0 = time.perf_counter()
            obs, r, term, trunc, info = env.step(action)
            dt = time.perf_counter() - t0
            assert isinstance(r, float) and math.isfinite(r), (kw, i, r, info)
            assert np.isfinite(obs).all(), (kw, i, obs)
            assert all(math.isfinite(v) for v in info["reward_terms"].values()), (kw, i, info["reward_terms"])
            assert MIN_REWARD - 1e-12 <= r <= 1.0, (kw, i, r)
            if i > 0:  # the first step of a new kernel variant compiles it
                assert dt < STEP_SECONDS, (kw, i, dt)


def test_fuzz_covers_the_extremes():
    """The fuzz's strategy draws only accepted arguments and reaches both ends of the bands, every action
    mode and tier (a check of the test itself)."""
    seen = {"modes": set(), "tiers": set(), "lo": False, "hi": False, "fs_max": False, "g0": False}

    @settings(max_examples=300, derandomize=True, deadline=None)
    @given(env_arguments())
    def collect(kw):
        EnvConfig(**kw)  # accepted
        seen["modes"].add(kw["action_mode"])
        seen["tiers"].add(kw["tier"])
        vals = [getattr(kw["params"], f) for f in MISMATCH_FIELDS]
        seen["lo"] |= PARAM_MIN in vals
        seen["hi"] |= PARAM_MAX in vals
        seen["fs_max"] |= kw["frame_skip"] == MAX_FRAME_SKIP
        seen["g0"] |= kw["params"].g == 0.0

    collect()
    assert (seen.pop("modes") == set(ACTION_MODES) and seen.pop("tiers") == set(BUILTIN_TIERS)
            and all(seen.values())), seen


def test_vector_env_accepted_extremes_stay_finite():
    """The vector env shares the config and kernels: extremes of every band, several envs, autoreset."""
    p = SoftPVTOLParams(m=PARAM_MAX, m_l=PARAM_MIN, m_r=PARAM_MAX, I=PARAM_MIN, I_l=PARAM_MAX, I_r=PARAM_MIN,
                        l_l=PARAM_MAX, l_r=PARAM_MIN, g=PARAM_MAX, epsilon=PARAM_MAX)
    for kw in (dict(action_mode="residual", residual_scale=MAX_RESIDUAL_SCALE, params=p),
               dict(action_mode="virtual", allocation="ideal", params=p, frame_skip=MAX_FRAME_SKIP),
               dict(tier="hard", tier_options={"wind_std": FORCE_MAX, "obs_noise_scale": 1e8}),
               dict(actuator_limits=(FORCE_MAX, FORCE_MAX), tier="model_gap")):
        venv = SoftPVTOLVectorEnv(num_envs=3, **kw)
        obs, _ = venv.reset(seed=1)
        for _ in range(3):
            obs, r, term, trunc, info = venv.step(venv.action_space.sample())
            assert np.isfinite(r).all() and np.isfinite(obs).all(), (kw, r)
