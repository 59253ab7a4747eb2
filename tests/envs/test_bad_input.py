"""Bad input to the env, the vector env and PassivityPolicy, and the closed validation of parameters
and options.

* ``test_bad_input``: one parametrized matrix of (call, exception type, message fragment); every case gets a
  ValueError/TypeError (or gymnasium's ResetNeeded) whose message names the argument. The constructor cases run
  through the env class, ``gym.make`` and the vector env.
* ``test_bad_value_refused``: extreme values (``g=0``, ``m=1e308``, ``residual_scale=1e308``, ``frame_skip``
  2**63-1 / 2**62 / 10**6) and each bound of every argument and tier option get a ValueError naming the argument,
  the value and the reason.
* ``test_fuzz_accepted_values_stay_finite``: hypothesis over the accepted ranges (parameters at the ends of their
  bands, every action mode, tier, task, frame_skip up to its bound, ...), a few steps with extreme actions,
  stepping on after a termination: rewards and observations stay finite and each step returns promptly.
* the reward's NaN guard (``reward_terms`` with a NaN effort; the residual base controller failing outside the
  model), ``PassivityPolicy.from_env(env, loop="ideal")`` in actuators mode and ``gym.make(..., render_mode=1)``.
"""

from __future__ import annotations

import math
import re
import time
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.error import ResetNeeded
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from softpvtol_gym import PassivityPolicy, SoftPVTOLEnv, SoftPVTOLParams, SoftPVTOLVectorEnv
from softpvtol_gym.control import LOOPS
from softpvtol_gym.control.passivity import PassivityGains
from softpvtol_gym.envs import EnvConfig
from softpvtol_gym.envs.actions import ACTION_MODES
from softpvtol_gym.envs.config import MAX_FRAME_SKIP, MAX_RESIDUAL_SCALE
from softpvtol_gym.envs.reward import REWARD_TERMS, reward_terms
from softpvtol_gym.envs.tiers import BUILTIN_TIERS, FORCE_MAX, MISMATCH_FIELDS, TIER_OPTION_BOUNDS, tier_values
from softpvtol_gym.params import PARAM_FIELDS, PARAM_MAX, PARAM_MIN
from softpvtol_gym.registry import MAX_EPISODE_SECONDS, TaskSpec

NAN, INF = math.nan, math.inf


# ------------------------------------------------------------------------------ constructor
#: (id, kwargs, exception, fragment of the message)
CONSTRUCTOR = [
    ("action_mode_unknown", dict(action_mode="torque"), ValueError, "action_mode must be one of"),
    ("action_mode_none", dict(action_mode=None), ValueError, "action_mode must be one of"),
    ("action_mode_int", dict(action_mode=3), ValueError, "action_mode must be one of"),
    ("action_mode_list", dict(action_mode=["actuators"]), ValueError, "action_mode must be one of"),
    ("task_unknown", dict(task="fly"), ValueError, "task must be one of"),
    ("task_none", dict(task=None), ValueError, "task must be one of"),
    ("task_int", dict(task=3), ValueError, "task must be one of"),
    ("task_list", dict(task=["hover"]), ValueError, "task must be one of"),
    ("tier_unknown", dict(tier="extreme"), ValueError, "tier must be one of"),
    ("tier_none", dict(tier=None), ValueError, "tier must be one of"),
    ("tier_set", dict(tier={"nominal"}), ValueError, "tier must be one of"),
    ("params_dict", dict(params={"m": 5.0}), ValueError, "params must be a SoftPVTOLParams"),
    ("params_array", dict(params=SoftPVTOLParams().array), ValueError, "params must be a SoftPVTOLParams"),
    ("params_str", dict(params="default"), ValueError, "params must be a SoftPVTOLParams"),
    ("input_map_unknown", dict(input_map="approx"), ValueError, "input_map must be one of"),
    ("input_map_none", dict(input_map=None), ValueError, "input_map must be one of"),
    ("allocation_unknown", dict(allocation="lsq"), ValueError, "allocation must be one of"),
    ("allocation_int", dict(allocation=1), ValueError, "allocation must be one of"),
    ("allocation_ideal_actuators", dict(allocation="ideal", action_mode="actuators"), ValueError,
     "only valid with action_mode='virtual'"),
    ("allocation_ideal_residual", dict(allocation="ideal", action_mode="residual"), ValueError,
     "only valid with action_mode='virtual'"),
    ("residual_space_unknown", dict(residual_space="body"), ValueError, "residual_space must be one of"),
    ("residual_space_none", dict(residual_space=None), ValueError, "residual_space must be one of"),
    ("residual_base_unknown", dict(action_mode="residual", residual_space="actuators", residual_base="clipped"),
     ValueError, "residual_base must be one of"),
    ("residual_base_saturated_virtual", dict(action_mode="residual", residual_base="saturated"), ValueError,
     "residual_base='saturated' sets what an actuator-space residual is added to"),
    ("residual_base_saturated_actuators_mode", dict(residual_base="saturated"), ValueError,
     "action_mode='residual' with residual_space='actuators'"),
    ("frame_skip_zero", dict(frame_skip=0), ValueError, "frame_skip must be an int >= 1"),
    ("frame_skip_negative", dict(frame_skip=-1), ValueError, "frame_skip must be an int >= 1"),
    ("frame_skip_float", dict(frame_skip=1.5), ValueError, "frame_skip must be an int >= 1"),
    ("frame_skip_bool", dict(frame_skip=True), ValueError, "frame_skip must be an int >= 1"),
    ("frame_skip_str", dict(frame_skip="2"), ValueError, "frame_skip must be an int >= 1"),
    ("frame_skip_none", dict(frame_skip=None), ValueError, "frame_skip must be an int >= 1"),
    ("max_episode_seconds_negative", dict(max_episode_seconds=-1.0), ValueError, "max_episode_seconds"),
    ("max_episode_seconds_zero", dict(max_episode_seconds=0.0), ValueError, "max_episode_seconds"),
    ("max_episode_seconds_nan", dict(max_episode_seconds=NAN), ValueError, "max_episode_seconds"),
    ("max_episode_seconds_inf", dict(max_episode_seconds=INF), ValueError, "max_episode_seconds"),
    ("max_episode_seconds_str", dict(max_episode_seconds="10"), ValueError, "max_episode_seconds"),
    ("max_episode_seconds_bool", dict(max_episode_seconds=True), ValueError, "max_episode_seconds"),
    ("max_episode_seconds_below_dt", dict(max_episode_seconds=0.004), ValueError,
     "max_episode_seconds must be at least one control step"),
    ("tier_options_list", dict(tier_options=[("wind_std", 1.0)]), ValueError, "tier_options must be a dict"),
    ("tier_options_str", dict(tier_options="wind"), ValueError, "tier_options must be a dict"),
    ("tier_options_unknown", dict(tier_options={"gust": 1.0}), ValueError, "unknown tier option 'gust'"),
    ("tier_options_int_key", dict(tier_options={1: 2.0}), ValueError, "unknown tier option 1"),
    ("tier_options_negative", dict(tier_options={"wind_std": -1.0}), ValueError, "tier_options['wind_std']"),
    ("tier_options_str_value", dict(tier_options={"wind_std": "3"}), ValueError, "tier_options['wind_std']"),
    ("tier_options_nan", dict(tier_options={"wind_std": NAN}), ValueError, "tier_options['wind_std']"),
    ("tier_options_inf", dict(tier_options={"obs_noise_scale": INF}), ValueError, "tier_options['obs_noise_scale']"),
    ("tier_options_bool", dict(tier_options={"mismatch_scale": True}), ValueError, "tier_options['mismatch_scale']"),
    ("tier_options_zero_correlation", dict(tier_options={"wind_correlation_time": 0.0}), ValueError,
     "tier_options['wind_correlation_time']"),
    ("tier_options_mismatch_one", dict(tier_options={"mismatch_scale": 1.0}), ValueError,
     "tier_options['mismatch_scale'] must be in [0, 1)"),
    ("tier_options_mismatch_big", dict(tier_options={"mismatch_scale": 3.0}), ValueError,
     "tier_options['mismatch_scale'] must be in [0, 1)"),
    ("residual_scale_zero", dict(residual_scale=0.0), ValueError, "residual_scale"),
    ("residual_scale_negative", dict(residual_scale=-0.2), ValueError, "residual_scale"),
    ("residual_scale_nan", dict(residual_scale=NAN), ValueError, "residual_scale"),
    ("residual_scale_str", dict(residual_scale="0.2"), ValueError, "residual_scale"),
    ("residual_scale_none", dict(residual_scale=None), ValueError, "residual_scale"),
    ("actuator_limits_one", dict(actuator_limits=(100.0,)), ValueError, "actuator_limits must be a tuple"),
    ("actuator_limits_three", dict(actuator_limits=(100.0, 10.0, 1.0)), ValueError, "actuator_limits must be a tuple"),
    ("actuator_limits_str", dict(actuator_limits="100,10"), ValueError, "actuator_limits must be a tuple"),
    ("actuator_limits_scalar", dict(actuator_limits=5.0), ValueError, "actuator_limits must be a tuple"),
    ("actuator_limits_array", dict(actuator_limits=np.array([100.0, 10.0])), ValueError, "pass tuple(limits)"),
    ("actuator_limits_zero_thrust", dict(actuator_limits=(0.0, 10.0)), ValueError, "actuator_limits[0] (thrust_max)"),
    ("actuator_limits_negative_torque", dict(actuator_limits=(100.0, -1.0)), ValueError,
     "actuator_limits[1] (arm_torque_max)"),
    ("actuator_limits_nan", dict(actuator_limits=(NAN, 10.0)), ValueError, "actuator_limits[0] (thrust_max)"),
    ("actuator_limits_inf", dict(actuator_limits=(100.0, INF)), ValueError, "actuator_limits[1] (arm_torque_max)"),
    ("actuator_limits_str_entry", dict(actuator_limits=("100", 10.0)), ValueError, "actuator_limits[0] (thrust_max)"),
    ("render_mode_unknown", dict(render_mode="ascii"), ValueError, "render_mode must be one of"),
    ("render_mode_int", dict(render_mode=1), ValueError, "render_mode must be one of"),
    ("unknown_argument", dict(foo=1), TypeError, "unknown SoftPVTOL argument(s) ['foo']"),
    ("misspelled_argument", dict(actionmode="virtual"), TypeError, "unknown SoftPVTOL argument(s) ['actionmode']"),
]


def _make_env(how, kwargs):
    if how == "class":
        return SoftPVTOLEnv(**kwargs)
    if how == "gym.make":
        return gym.make("SoftPVTOL-v0", **kwargs)
    return SoftPVTOLVectorEnv(num_envs=2, **kwargs)


CASES = []


def case(id_, exc, match):
    """Register ``fn`` as a matrix case: fn() must raise ``exc`` with ``match`` in its message."""
    def register(fn):
        CASES.append(pytest.param(fn, exc, match, id=id_))
        return fn
    return register


for _id, _kw, _exc, _match in CONSTRUCTOR:
    for _how in ("class", "gym.make", "vector"):
        CASES.append(pytest.param(lambda how=_how, kw=_kw: _make_env(how, kw), _exc, _match, id=f"{_how}-{_id}"))

# the vector env's own arguments
for _id, _kw, _match in [
    ("num_envs_zero", dict(num_envs=0), "num_envs must be an int >= 1"),
    ("num_envs_negative", dict(num_envs=-2), "num_envs must be an int >= 1"),
    ("num_envs_bool", dict(num_envs=True), "num_envs must be an int >= 1"),
    ("num_envs_float", dict(num_envs=2.5), "num_envs must be an int >= 1"),
    ("num_envs_str", dict(num_envs="2"), "num_envs must be an int >= 1"),
    ("num_envs_none", dict(num_envs=None), "num_envs must be an int >= 1"),
    ("autoreset_unknown", dict(num_envs=2, autoreset_mode="sometimes"), "autoreset_mode must be one of"),
    ("autoreset_case", dict(num_envs=2, autoreset_mode="nextstep"), "autoreset_mode must be one of"),
    ("autoreset_none", dict(num_envs=2, autoreset_mode=None), "autoreset_mode must be one of"),
    ("autoreset_int", dict(num_envs=2, autoreset_mode=1), "autoreset_mode must be one of"),
    ("autoreset_list", dict(num_envs=2, autoreset_mode=["NextStep"]), "autoreset_mode must be one of"),
    ("render_mode_human", dict(num_envs=2, render_mode="human"), "render_mode must be one of"),
]:
    CASES.append(pytest.param(lambda kw=_kw: SoftPVTOLVectorEnv(**kw), ValueError, _match, id=f"vector-{_id}"))

case("make_vec-num_envs_zero", ValueError, "num_envs")(
    lambda: gym.make_vec("SoftPVTOL-v0", num_envs=0, vectorization_mode="vector_entry_point"))
case("params-negative_mass", ValueError, "SoftPVTOLParams.m must be finite and > 0")(
    lambda: SoftPVTOLEnv(params=SoftPVTOLParams(m=-1.0)))
case("params-nan_length", ValueError, "SoftPVTOLParams.l_l")(lambda: SoftPVTOLEnv(params=SoftPVTOLParams(l_l=NAN)))
case("params-str_mass", ValueError, "SoftPVTOLParams.m must be a real number")(
    lambda: SoftPVTOLEnv(params=SoftPVTOLParams(m="5")))


# ----------------------------------------------------------------------------------- reset
def _env(**kw):
    return SoftPVTOLEnv(**kw)


def _venv(n=3, **kw):
    return SoftPVTOLVectorEnv(num_envs=n, **kw)


RESET_SEEDS = [
    ("negative", -1, "seed must be an int >= 0"),
    ("float", 1.5, "seed must be an int >= 0"),
    ("integral_float", 3.0, "seed must be an int >= 0"),
    ("numpy_float", np.float64(1.0), "seed must be an int >= 0"),
    ("str", "0", "seed must be an int >= 0"),
    ("bool", True, "seed must be an int >= 0"),
    ("numpy_negative", np.int64(-5), "seed must be an int >= 0"),
    ("complex", 1j, "seed must be an int >= 0"),
]
for _id, _seed, _match in RESET_SEEDS:
    CASES.append(pytest.param(lambda s=_seed: _env().reset(seed=s), ValueError, _match, id=f"reset-seed_{_id}"))
    CASES.append(pytest.param(lambda s=_seed: _venv().reset(seed=s), ValueError, _match, id=f"vector-reset-seed_{_id}"))
case("reset-seed_list", ValueError, "seed must be an int >= 0")(lambda: _env().reset(seed=[0]))
case("vector-reset-seed_list_short", ValueError, "seed list must have num_envs=3 entries, got 2")(
    lambda: _venv().reset(seed=[0, 1]))
case("vector-reset-seed_list_long", ValueError, "seed list must have num_envs=3 entries, got 4")(
    lambda: _venv().reset(seed=[0, 1, 2, 3]))
case("vector-reset-seed_list_negative", ValueError, "seed[2] must be an int >= 0")(
    lambda: _venv().reset(seed=[0, 1, -1]))
case("vector-reset-seed_list_str", ValueError, "seed[0] must be an int >= 0")(
    lambda: _venv().reset(seed=["a", "b", "c"]))
case("vector-reset-seed_list_float", ValueError, "seed[1] must be an int >= 0")(
    lambda: _venv().reset(seed=[0, 1.5, 2]))
case("vector-reset-seed_set", ValueError, "seed must be an int >= 0, a list of num_envs=3")(
    lambda: _venv().reset(seed={0, 1, 2}))
case("vector-reset-seed_dict", ValueError, "seed must be an int >= 0, a list of num_envs=3")(
    lambda: _venv().reset(seed={"a": 1}))

#: (id, options, fragment), for the single and the vector env (hover task)
RESET_OPTIONS = [
    ("str", "q0", "reset options must be a dict"),
    ("list", [("q0", [0, 2, 0, 0, 0])], "reset options must be a dict"),
    ("unknown_key", {"x0": 1.0}, "unknown reset option(s) ['x0']"),
    ("q0_short", {"q0": [0, 0, 0]}, "reset option 'q0' must be 5 finite numbers"),
    ("q0_2d", {"q0": [[0, 2, 0, 0, 0]]}, "reset option 'q0' must be 5 finite numbers"),
    ("q0_scalar", {"q0": 0.0}, "reset option 'q0' must be 5 finite numbers"),
    ("q0_nan", {"q0": [NAN, 2, 0, 0, 0]}, "reset option 'q0' must be 5 finite numbers"),
    ("q0_inf", {"q0": [0, INF, 0, 0, 0]}, "reset option 'q0' must be 5 finite numbers"),
    ("q0_str", {"q0": "abcde"}, "reset option 'q0' must be 5 finite numbers"),
    ("q0_str_numbers", {"q0": ["0", "2", "0", "0", "0"]}, "reset option 'q0' must be 5 finite numbers"),
    ("q0_complex", {"q0": [0, 2, 0, 0, 1j]}, "reset option 'q0' must be 5 finite numbers"),
    ("q0_bool", {"q0": [False, True, False, False, False]}, "reset option 'q0' must be 5 finite numbers"),
    ("q0_none_entry", {"q0": [0, 2, None, 0, 0]}, "reset option 'q0' must be 5 finite numbers"),
    ("q0_ragged", {"q0": [[0, 2], [0]]}, "reset option 'q0' must be 5 finite numbers"),
    ("q0_curvature_left", {"q0": [0, 2, 0, 4.0, 0]}, "reset option 'q0'[3] (q_l) = 4.0 is outside |q_l| <= pi"),
    ("q0_curvature_right", {"q0": [0, 2, 0, 0, -3.2]}, "reset option 'q0'[4] (q_r) = -3.2 is outside |q_r| <= pi"),
    ("q0_x_huge", {"q0": [1e300, 2, 0, 0, 0]}, "reset option 'q0'[0] (x) = 1e+300 is outside |x| <= 20"),
    ("q0_x_box", {"q0": [-20.5, 2, 0, 0, 0]}, "reset option 'q0'[0] (x) = -20.5 is outside |x| <= 20"),
    ("q0_below_ground", {"q0": [0, -2.0, 0, 0, 0]}, "reset option 'q0'[1] (z) = -2.0 is outside -1 <= z <= 20"),
    ("q0_too_high", {"q0": [0, 25.0, 0, 0, 0]}, "reset option 'q0'[1] (z) = 25.0 is outside -1 <= z <= 20"),
    ("qdot0_short", {"qdot0": [0, 0, 0, 0]}, "reset option 'qdot0' must be 5 finite numbers"),
    ("qdot0_nan", {"qdot0": [NAN] * 5}, "reset option 'qdot0' must be 5 finite numbers"),
    ("qdot0_inf", {"qdot0": [0, 0, 0, 0, -INF]}, "reset option 'qdot0' must be 5 finite numbers"),
    ("qdot0_str", {"qdot0": ["0"] * 5}, "reset option 'qdot0' must be 5 finite numbers"),
    ("setpoint_short", {"setpoint": [0, 2]}, "reset option 'setpoint' must be 3 finite numbers"),
    ("setpoint_nan", {"setpoint": [NAN, 2, 0]}, "reset option 'setpoint' must be 3 finite numbers"),
    ("setpoint_outside", {"setpoint": [1e9, 2, 0]}, "reset option 'setpoint'[0] (x) = 1000000000.0 is outside"),
    ("setpoint_underground", {"setpoint": [0, -5, 0]}, "reset option 'setpoint'[1] (z) = -5.0 is outside"),
]
for _id, _opt, _match in RESET_OPTIONS:
    CASES.append(pytest.param(lambda o=_opt: _env().reset(seed=0, options=o), ValueError, _match,
                              id=f"reset-options_{_id}"))
    CASES.append(pytest.param(lambda o=_opt: _venv().reset(seed=0, options=o), ValueError, _match,
                              id=f"vector-reset-options_{_id}"))
case("reset-options_setpoint_track_paper", ValueError, "reset option 'setpoint' needs task 'hover' or 'setpoint'")(
    lambda: _env(task="track_paper").reset(options={"setpoint": [0, 2, 0]}))
case("reset-options_reset_mask_single", ValueError, "unknown reset option(s) ['reset_mask']")(
    lambda: _env().reset(options={"reset_mask": np.ones(1, dtype=bool)}))
case("vector-reset-mask_list", TypeError, "options['reset_mask'] must be a numpy bool array")(
    lambda: _venv().reset(options={"reset_mask": [True, False, True]}))
case("vector-reset-mask_shape", ValueError, "options['reset_mask'] must have shape (3,)")(
    lambda: _venv().reset(options={"reset_mask": np.ones(2, dtype=bool)}))
case("vector-reset-mask_dtype", TypeError, "options['reset_mask'] must have dtype bool")(
    lambda: _venv().reset(options={"reset_mask": np.ones(3)}))
case("vector-reset-mask_all_false", ValueError, "options['reset_mask'] must be True for at least one")(
    lambda: _venv().reset(options={"reset_mask": np.zeros(3, dtype=bool)}))


# ------------------------------------------------------------------------------------ step
def _stepped(action, **kw):
    e = SoftPVTOLEnv(**kw)
    e.reset(seed=0)
    return e.step(action)


def _vstepped(actions, n=3, **kw):
    v = SoftPVTOLVectorEnv(num_envs=n, **kw)
    v.reset(seed=0)
    return v.step(actions)


case("step-before_reset", ResetNeeded, "Cannot call env.step() before calling env.reset()")(
    lambda: SoftPVTOLEnv().step(np.zeros(4)))
case("render-before_reset", ResetNeeded, "Cannot call env.render() before calling env.reset()")(
    lambda: SoftPVTOLEnv(render_mode="rgb_array").render())
case("vector-step-before_reset", ResetNeeded, "Cannot call env.step() before calling env.reset()")(
    lambda: SoftPVTOLVectorEnv(num_envs=2).step(np.zeros((2, 4))))
case("vector-step-partly_reset", ResetNeeded, "never reset")(
    lambda: (v := SoftPVTOLVectorEnv(num_envs=2), v.reset(options={"reset_mask": np.array([True, False])}),
             v.step(np.zeros((2, 4)))))

#: (id, action, fragment) for the single env (actuators: shape (4,))
STEP_ACTIONS = [
    ("str", "up", "action must be an array of shape (4,)"),
    ("str_numbers", ["0", "0", "0", "0"], "got str values"),
    ("str_array", np.array(["0.1", "0", "0", "0"]), "got str values"),
    ("bytes", b"\x00\x00\x00\x00", "action must be an array of shape (4,)"),
    ("complex", np.zeros(4, dtype=complex), "got complex values"),
    ("complex_list", [1j, 0, 0, 0], "got complex values"),
    ("bool_array", np.array([True, False, True, False]), "got bool values"),
    ("bool_list", [True, False, True, False], "got bool values"),
    ("none", None, "action must be an array of shape (4,)"),
    ("dict", {"T_l": 0.0}, "action must be an array of shape (4,)"),
    ("object_with_none", [0.0, None, 0.0, 0.0], "got object values"),
    ("ragged", [[0.0, 0.0], [0.0]], "action must be an array of shape (4,)"),
    ("scalar", 0.0, "action must have shape (4,)"),
    ("batched", np.zeros((1, 4)), "action must have shape (4,)"),
    ("column", np.zeros((4, 1)), "action must have shape (4,)"),
    ("too_long", np.zeros(5), "action must have shape (4,)"),
    ("too_short", np.zeros(3), "action must have shape (4,)"),
    ("empty", [], "action must have shape (4,)"),
    ("nan", np.array([NAN, 0, 0, 0]), "action must be finite"),
    ("inf", np.array([0, INF, 0, 0]), "action must be finite"),
    ("neg_inf", [0, 0, -INF, 0], "action must be finite"),
    ("float32_nan", np.array([0, 0, 0, NAN], dtype=np.float32), "action must be finite"),
]
for _id, _a, _match in STEP_ACTIONS:
    CASES.append(pytest.param(lambda a=_a: _stepped(a), ValueError, _match, id=f"step-action_{_id}"))
case("step-virtual_shape", ValueError, "action must have shape (5,) (action_mode='virtual')")(
    lambda: _stepped(np.zeros(4), action_mode="virtual"))
case("step-residual_actuators_shape", ValueError, "action must have shape (4,) (action_mode='residual')")(
    lambda: _stepped(np.zeros(5), action_mode="residual", residual_space="actuators"))
case("step-residual_nan", ValueError, "action must be finite")(
    lambda: _stepped(np.array([0, NAN, 0, 0, 0]), action_mode="residual"))

#: (id, actions, fragment) for a vector env of 3 (actuators: shape (3, 4))
VECTOR_ACTIONS = [
    ("rows", np.zeros((2, 4)), "action must have shape (3, 4)"),
    ("single", np.zeros(4), "action must have shape (3, 4)"),
    ("transposed", np.zeros((4, 3)), "action must have shape (3, 4)"),
    ("str", [["0"] * 4] * 3, "got str values"),
    ("complex", np.zeros((3, 4), dtype=complex), "got complex values"),
    ("bool", np.zeros((3, 4), dtype=bool), "got bool values"),
    ("nan_row", np.array([[0, 0, 0, 0], [0, NAN, 0, 0], [0, 0, 0, 0]]), "action must be finite"),
    ("none", None, "action must be an array of shape (3, 4)"),
]
for _id, _a, _match in VECTOR_ACTIONS:
    CASES.append(pytest.param(lambda a=_a: _vstepped(a), ValueError, _match, id=f"vector-step-action_{_id}"))


# ------------------------------------------------------------------------------ the policy
def _policy(**kw):
    return PassivityPolicy.from_env(SoftPVTOLEnv(**kw))


def _obs(**entries):
    """A valid observation (hovering at the reference) with some entries replaced: name=value by index."""
    o = np.zeros(18)
    o[4] = 1.0  # cos theta
    for k, v in entries.items():
        o[int(k[1:])] = v
    return o


case("policy-config_str", ValueError, "config must be an EnvConfig")(lambda: PassivityPolicy("hover"))
case("policy-config_env", ValueError, "PassivityPolicy.from_env(env)")(lambda: PassivityPolicy(SoftPVTOLEnv()))
case("policy-loop_unknown", ValueError, "loop must be one of")(lambda: PassivityPolicy(EnvConfig(), loop="fancy"))
case("policy-loop_int", ValueError, "loop must be one of")(lambda: PassivityPolicy(EnvConfig(), loop=1))
case("policy-loop_ideal_mismatch", ValueError, "loop='ideal'")(
    lambda: PassivityPolicy(EnvConfig(action_mode="virtual", allocation="ideal"), loop="exact"))
case("policy-gains_str", ValueError, "gains must be a PassivityGains")(
    lambda: PassivityPolicy(EnvConfig(), gains="big"))
case("policy-gains_negative", ValueError, "PassivityGains.k must be 5 finite values > 0")(
    lambda: PassivityPolicy(EnvConfig(), gains=PassivityGains(k=(-1.0, 1, 1, 1, 1))))
case("policy-from_env_object", ValueError, "env must be a SoftPVTOLEnv")(lambda: PassivityPolicy.from_env(object()))
case("policy-from_env_none", ValueError, "env must be a SoftPVTOLEnv")(lambda: PassivityPolicy.from_env(None))

POLICY_OBS = [
    ("short", np.zeros(17), "observation must have shape (18,) or (N, 18)"),
    ("batched_short", np.zeros((2, 17)), "observation must have shape (18,) or (N, 18)"),
    ("3d", np.zeros((2, 3, 18)), "observation must have shape (18,) or (N, 18)"),
    ("scalar", 0.0, "observation must have shape (18,) or (N, 18)"),
    ("empty_batch", np.zeros((0, 18)), "observation must have shape (18,) or (N, 18) with N >= 1"),
    ("none", None, "observation must be an array of shape (18,)"),
    ("str", "obs", "observation must be an array of shape (18,)"),
    ("complex", np.zeros(18, dtype=complex), "observation must be an array of shape (18,)"),
    ("bool", np.zeros(18, dtype=bool), "observation must be an array of shape (18,)"),
    ("nan", _obs(o0=NAN), "observation must be finite, got nan at index 0 (x - x_ref)"),
    ("inf", _obs(o9=INF), "observation must be finite, got inf at index 9 (thetadot)"),
    ("q_l_clip", _obs(o5=1e6), "observation index 5 (q_l) = 1000000.0 is outside the model's validity"),
    ("q_r_clip", _obs(o6=-1e6), "observation index 6 (q_r) = -1000000.0 is outside the model's validity"),
    ("q_l_7", _obs(o5=7.0), "observation index 5 (q_l) = 7.0 is outside the model's validity"),
    ("batched_q_l_clip", np.stack([_obs(), _obs(o5=1e6)]), "observation [1, 5] (q_l) = 1000000.0 is outside"),
]
for _id, _o, _match in POLICY_OBS:
    for _mode in ("actuators", "virtual"):
        CASES.append(pytest.param(lambda o=_o, m=_mode: _policy(action_mode=m).predict(o), ValueError, _match,
                                  id=f"policy-{_mode}-observation_{_id}"))
case("policy-ideal-observation_q_l_clip", ValueError, "observation index 5 (q_l) = 1000000.0 is outside")(
    lambda: _policy(action_mode="virtual", allocation="ideal").predict(_obs(o5=1e6)))
case("policy-residual-observation_nan", ValueError, "observation must be finite")(
    lambda: _policy(action_mode="residual").predict(_obs(o1=NAN)))


def _predict_twice(episode_start, n=3):
    p = _policy()
    obs = np.stack([_obs()] * n)
    p.predict(obs)
    return p.predict(obs, episode_start=episode_start)


case("policy-episode_start_short", ValueError, "episode_start must be None, a bool or a bool array of 3 entries")(
    lambda: _predict_twice(np.array([True, False])))
case("policy-episode_start_long", ValueError, "episode_start must be None, a bool or a bool array of 3 entries")(
    lambda: _predict_twice(np.ones(4, dtype=bool)))
case("policy-episode_start_first_call", ValueError, "episode_start must be None")(
    lambda: _policy().predict(np.stack([_obs()] * 3), episode_start=np.ones(2, dtype=bool)))
case("policy-episode_start_str", ValueError, "episode_start must be None")(lambda: _predict_twice("yes"))
case("policy-episode_start_values", ValueError, "episode_start must be None")(
    lambda: _predict_twice(np.array([0.5, 0.0, 1.0])))
case("policy-episode_start_none_entries", ValueError, "episode_start must be None")(
    lambda: _predict_twice([True, None, False]))


@pytest.mark.parametrize("call, exc, match", CASES)
def test_bad_input(call, exc, match):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # gym.make's checker warnings are not the point here
        with pytest.raises(exc) as e:
            call()
    assert match in str(e.value), f"message {str(e.value)!r} lacks {match!r}"


def test_matrix_size():
    assert len(CASES) >= 150


# ------------------------------------------------------------------------ accepted inputs
@pytest.mark.parametrize("seed", [np.int64(7), np.uint32(7), np.int8(7)])
def test_numpy_integer_seeds_are_accepted_like_ints(seed):
    a = SoftPVTOLEnv()
    b = SoftPVTOLEnv()
    np.testing.assert_array_equal(a.reset(seed=seed)[0], b.reset(seed=7)[0])
    np.testing.assert_array_equal(a.step(np.full(4, 0.1))[0], b.step(np.full(4, 0.1))[0])
    v = SoftPVTOLVectorEnv(num_envs=2)
    w = SoftPVTOLVectorEnv(num_envs=2)
    np.testing.assert_array_equal(v.reset(seed=seed)[0], w.reset(seed=7)[0])
    np.testing.assert_array_equal(v.reset(seed=np.array([seed, 9]))[0], w.reset(seed=[7, 9])[0])


def test_int_actions_and_float32_actions_are_accepted():
    a = SoftPVTOLEnv()
    b = SoftPVTOLEnv()
    a.reset(seed=1)
    b.reset(seed=1)
    np.testing.assert_array_equal(a.step(np.array([1, 0, 0, 0]))[0], b.step(np.array([1.0, 0.0, 0.0, 0.0]))[0])
    np.testing.assert_array_equal(a.step(np.full(4, 0.25, dtype=np.float32))[0], b.step([0.25] * 4)[0])


def test_states_on_the_limits_are_accepted():
    e = SoftPVTOLEnv()
    obs, _ = e.reset(seed=0, options={"q0": [20.0, -1.0, 0.0, math.pi, -math.pi],
                                      "qdot0": [50.0, -50.0, 100.0, -100.0, 100.0]})
    assert np.isfinite(obs).all()
    np.testing.assert_array_equal(e.state[0], [20.0, -1.0, 0.0, math.pi, -math.pi])
    # speeds beyond the limits are valid states: the episode ends at its first step, with the reason
    e.reset(seed=0, options={"q0": [0, 2, 0, 0, 0], "qdot0": [0, 0, 0, 0, 1e200]})
    *_, terminated, _, info = e.step(np.zeros(4))
    assert terminated and info["termination_reason"] == "non_finite"


def test_bad_reset_changes_nothing():
    e = SoftPVTOLEnv()
    e.reset(seed=3)
    before = (e.state, e.np_random.bit_generator.state)
    with pytest.raises(ValueError):
        e.reset(seed=5, options={"q0": [0, 2, 0, 4.0, 0]})
    np.testing.assert_array_equal(e.state[0], before[0][0])
    assert e.np_random.bit_generator.state == before[1]


@pytest.mark.parametrize("env_id", ["SoftPVTOL-v0", "SoftPVTOLResidual-v0"])
@pytest.mark.parametrize("bad", [dict(options={"bogus": 1}), dict(options={"q0": [0, 2, 0, 4.0, 0]}), dict(seed=-1)],
                         ids=["unknown_option", "q0_outside", "negative_seed"])
def test_a_refused_first_reset_under_gym_make_leaves_the_env_usable(env_id, bad):
    """gymnasium's PassiveEnvChecker marks its first reset as checked before it runs: a refused first reset must
    leave it waiting for a successful one (the next step failed with a TypeError in the checker)."""
    env = gym.make(env_id)
    assert isinstance(env, gym.wrappers.OrderEnforcing) and isinstance(env.env, gym.wrappers.PassiveEnvChecker)
    with pytest.raises(ValueError):
        env.reset(**bad)
    with pytest.raises(ResetNeeded):
        env.step(env.action_space.sample())
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    obs, reward, *_ = env.step(env.action_space.sample())
    assert env.observation_space.contains(obs) and np.isfinite(reward)
    with pytest.raises(ValueError):  # refused in an episode: the episode goes on
        env.reset(options={"bogus": 1})
    env.step(env.action_space.sample())


def test_stepping_after_termination_warns_once_per_episode():
    e = SoftPVTOLEnv(max_episode_seconds=0.02)
    for _ in range(2):
        e.reset(seed=0)
        with warnings.catch_warnings(record=True) as rec:
            warnings.simplefilter("always")
            *_, terminated, truncated, _ = e.step(np.zeros(4))
            *_, terminated, truncated, _ = e.step(np.zeros(4))
            assert truncated and not rec
            for _ in range(3):  # stepping stays allowed
                e.step(np.zeros(4))
        msgs = [str(w.message) for w in rec]
        assert len(msgs) == 1 and "already returned terminated = True" in msgs[0]
    # a termination too (out of the ground)
    e = SoftPVTOLEnv()
    e.reset(seed=0, options={"q0": [0, -0.99, 0, 0, 0], "qdot0": [0, -50, 0, 0, 0]})
    terminated = False
    while not terminated:
        *_, terminated, _, info = e.step(-np.ones(4))
    assert info["termination_reason"] == "ground"
    with pytest.warns(UserWarning, match="already returned terminated = True"):
        e.step(np.zeros(4))


def test_vector_disabled_autoreset_warns_and_reset_mask_resets_only_the_masked():
    v = SoftPVTOLVectorEnv(num_envs=3, autoreset_mode="Disabled", max_episode_seconds=0.02)
    obs0, _ = v.reset(seed=0)
    v.step(np.zeros((3, 4)))
    _, _, _, trunc, _ = v.step(np.zeros((3, 4)))
    assert trunc.all()
    with pytest.warns(UserWarning, match=r"sub-envs \[0, 1, 2\] that have already returned"):
        v.step(np.zeros((3, 4)))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # once per episode
        v.step(np.zeros((3, 4)))
    before = v.state[0].copy()
    obs, infos = v.reset(seed=[10, 11, 12], options={"reset_mask": np.array([False, True, False])})
    np.testing.assert_array_equal(v.state[0][[0, 2]], before[[0, 2]])
    np.testing.assert_array_equal(infos["_time"], [False, True, False])
    single = SoftPVTOLEnv(max_episode_seconds=0.02)
    np.testing.assert_array_equal(obs[1], single.reset(seed=11)[0])
    assert v.sim.steps[1] == 0 and v.sim.steps[0] == 4


def test_policy_actions_stay_finite_at_the_observation_bounds():
    """Every observation entry at +-1e6 (the env's clip value) except the curvatures: a finite action."""
    for mode in ("actuators", "virtual"):
        p = _policy(action_mode=mode)
        rng = np.random.default_rng(0)
        for _ in range(20):
            o = rng.choice([-1e6, 0.0, 1e6], size=18)
            o[5:7] = rng.uniform(-2 * math.pi, 2 * math.pi, size=2)
            a = p.predict(o, episode_start=True)[0]
            assert np.isfinite(a).all() and (np.abs(a) <= 1).all()


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
