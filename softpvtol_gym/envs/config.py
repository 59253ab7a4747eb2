"""EnvConfig: the validated configuration shared by the single env, the vector env and PassivityPolicy.

Every derived number (limits, scales, the kernels' constant vector) is a property or method of the
frozen config, computed from its fields; nothing is stored twice.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

from .. import model as MK
from .._validation import bounded_number, choice, short_repr
from ..control import kernels as CK
from ..control.closed_loop import LOOPS
from ..control.passivity import PassivityGains
from ..params import G_MIN, PARAM_BOUNDS, SoftPVTOLParams
from ..registry import EPISODE_SECONDS_REASON, MAX_EPISODE_SECONDS
from ..tasks import TaskSpec, get_task
from . import tiers as _tiers
from .actions import ACTION_MODE_SPECS, ACTION_MODES
from .episodes import MAX_START_ERROR_SCALE, START_DISTRIBUTIONS, START_SCALE_REASON
from .observation import N_ERROR_INTEGRALS, OBS_DIM
from .packed_state import CODES, CONST, SC, SK

PHYSICS_DT = 0.01  # s, the paper's RK4 step
INPUT_MAPS = ("paper", "exact")
MODELS = (None, "paper", "consistent")
ALLOCATIONS = ("paper", "exact", "ideal")
RESIDUAL_SPACES = ("virtual", "actuators")
#: what an actuator-space residual is added to: the base loop's command as computed, or clipped to the actuator box
RESIDUAL_BASES = ("unsaturated", "saturated")
RENDER_MODES = (None, "rgb_array", "human")

#: the most RK4 steps per env step: a control period of 10 s, the length of the shortest built-in
#: episode (hover, setpoint), and a step of about 15 ms of compute (13 us per RK4 step on the 2-core
#: development machine); the analytic controllers need <= 0.012 s anyway
MAX_FRAME_SKIP = 1000
FRAME_SKIP_REASON = (f"RK4 steps of {PHYSICS_DT} s per env step; {MAX_FRAME_SKIP} is a control period of "
                     f"{MAX_FRAME_SKIP * PHYSICS_DT:g} s, the shortest built-in episode, and keeps a step near 15 ms "
                     "of compute")
#: the largest residual_scale: at 100 x the virtual scales (2 M g on the body forces) an action of 0.02
#: already asks for more than the default actuator range (3 M g / 2 per rotor); beyond, every action saturates
MAX_RESIDUAL_SCALE = 100.0
RESIDUAL_SCALE_REASON = ("the correction at action +-1 as a fraction of the virtual (or actuator) scales; at "
                         f"{MAX_RESIDUAL_SCALE:g} an action of 0.02 already exceeds the default actuator range, so "
                         "larger scales only saturate")
#: the largest explicit actuator limit [N, N m] (the same bound as the wind force)
ACTUATOR_LIMIT_MAX = _tiers.FORCE_MAX
ACTUATOR_LIMIT_REASON = (f"> 0; {ACTUATOR_LIMIT_MAX:g} is 50 x the largest default limit the parameter bounds give "
                         "(2e18 N m), far inside float64")


#: training aids: the largest reward weight of the precision and action-rate terms and the
#: largest error-integral bound (the start-error scale's bound and the start distributions: .episodes)
MAX_AID_WEIGHT = 100.0
ERROR_INTEGRAL_LIMIT_MAX = 1.0e6


def _argument(default, type_: str, description: str, *, factory=None, default_text: str | None = None):
    """A field of :class:`EnvConfig` with its documentation (``metadata``: type, description, default text):
    the one source of the env's Arguments table (:func:`argument_table_markdown`)."""
    if default_text is None:
        default_text = f'"{default}"' if isinstance(default, str) else repr(default)
    meta = {"type": type_, "description": description, "default": default_text}
    if factory is not None:
        return dataclasses.field(default_factory=factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


@dataclasses.dataclass(frozen=True)
class EnvConfig:
    """Validated configuration: the arguments of :class:`~softpvtol_gym.envs.soft_pvtol.SoftPVTOLEnv` and
    :class:`~softpvtol_gym.envs.vector.SoftPVTOLVectorEnv` (their table: :func:`argument_table_markdown`)."""

    action_mode: str = _argument(
        "actuators", "str",
        '"actuators" | "virtual" | "residual": what the action commands (see Action Space).')
    task: str = _argument(
        "hover", "str",
        'a registered task: "hover" | "setpoint" | "track_paper" | "track_random" built in, or one registered '
        "with `softpvtol_gym.tasks.register_task` (a `TaskSpec`); sets the reference, the starting state and "
        "the episode length.")
    tier: str = _argument(
        "nominal", "str",
        'a registered robustness tier (`softpvtol_gym.envs.register_tier`); built in: "nominal" (no disturbance) '
        '| "mismatch" (plant m, m_l, m_r, I, I_l, I_r, l_l, l_r each x U(0.8, 1.2) per episode; the controllers '
        'keep the nominal params) | "wind" (Ornstein-Uhlenbeck force on x and z, std 3 N, correlation time 1 s) '
        '| "noisy" (Gaussian measurement noise, std (0.02 m, 0.02 m, 0.01 rad, 0.02 rad, 0.02 rad) on q and '
        '(0.05 m/s, 0.05 m/s, 0.02 rad/s, 0.05 rad/s, 0.05 rad/s) on qdot, and a 0.05 s first-order lag of the '
        'applied command) | "hard" (mismatch, wind and noisy together) | "model_gap" (the plant is the '
        "consistent model; the controllers keep the paper's).")
    params: SoftPVTOLParams | None = _argument(
        None, "SoftPVTOLParams | None",
        "the nominal physical parameters (SI units; masses, inertias, lengths in [1e-6, 1e6], g 0 (with "
        "`actuator_limits`) or in [1e-6, 1e6], epsilon in [0, 1e6]): the plant's in the nominal tier and the "
        "model of the controllers; None: the paper's values, `SoftPVTOLParams()`.", factory=SoftPVTOLParams,
        default_text="None")
    input_map: str = _argument(
        "paper", "str",
        '"paper" | "exact": the input map tau = B(q) a of the paper\'s model (as printed, or the virtual work '
        "of the thrusts at the tips): the plant's under `model=\"paper\"` and the one the controllers assume.")
    allocation: str | None = _argument(
        None, "str | None",
        'virtual and residual modes: how body forces become thrusts, "exact" | "paper" | "ideal" (tau applied '
        'directly, virtual mode only, no saturation); None: "exact", or the `controller_loop`\'s.')
    residual_space: str = _argument(
        "virtual", "str",
        'residual mode: "virtual" (the correction is added to the base controller\'s tau, 5 entries) | '
        '"actuators" (added to its actuators, 4 entries).')
    residual_base: str = _argument(
        "unsaturated", "str",
        'residual mode with `residual_space="actuators"`: what the correction is added to, "unsaturated" (the base '
        'controller\'s actuator command as computed, which may lie far outside the actuator box) | "saturated" (that '
        "command clipped to the box first, so that with `residual_scale` >= 2 an action reaches every point of the "
        "box); the sum is saturated in both, and action 0 gives the base controller's applied command in both.")
    frame_skip: int = _argument(
        1, "int",
        "RK4 steps of 0.01 s per env step, in [1, 1000] (the control period is 0.01 s x frame_skip, at most 10 s, "
        "the shortest built-in episode; the analytic controllers need <= 0.012 s).")
    max_episode_seconds: float | None = _argument(
        None, "float | None",
        "episode length [s] (truncation), from one control step to 1e9 s (the clock t = steps x dt keeps a "
        "resolution below 1e-6 s); None: the task's (hover, setpoint 10 s, track_paper 40 s, track_random 20 s).")
    tier_options: dict | None = _argument(
        None, "dict | None",
        "overrides of the tier's numbers: `mismatch_scale` (in [0, 1), default 0.2; the scaled plant "
        "parameters must stay within the `SoftPVTOLParams` bounds), `wind_std` [N] (in [0, 1e20], 3), "
        "`wind_correlation_time` [s] (in (0, 1e9], 1), `obs_noise_scale` (x the noise stds, in [0, 1e8], 1), "
        "`actuator_time_constant` [s] (in [0, 1e9], 0.05); an option given by hand switches its effect on.")
    residual_scale: float = _argument(
        0.2, "float",
        "residual mode: the correction at action +/-1 as a fraction of the virtual scales (or of "
        "(T_max/2, T_max/2, tau_max, tau_max) with `residual_space=\"actuators\"`), in (0, 100] (at 100 an "
        "action of 0.02 already exceeds the default actuator range).")
    actuator_limits: tuple | None = _argument(
        None, "tuple | None",
        "(T_max [N], tau_max [N m]), two numbers in (0, 1e20]: each rotor's thrust range [0, T_max] and each "
        "arm's torque range [-tau_max, tau_max], which scale the actions and saturate the applied commands; None: "
        "3 x the hover thrust per rotor and 4 x the larger arm gravity load g m_i l_i / 2 of `params` "
        "(102.9 N, 9.8 N m with the defaults; with g = 0, free flight, these are 0: give the limits).")
    controller_loop: str | None = _argument(
        None, "str | None",
        "residual mode's base controller and `PassivityPolicy`'s default: a loop of "
        '`softpvtol_gym.control.LOOPS` ("paper" | "exact" | "improved" | "bounded" | "integral" | "ideal" | '
        '"extended"; "extended", the dynamically extended loop, is a policy only, not a residual base '
        'controller); None: '
        'from the allocation, "bounded" for "exact" (the default), "paper" for "paper", "ideal" for "ideal". '
        "A loop whose allocation differs from a given `allocation` is refused.")
    model: str | None = _argument(
        None, "str | None",
        '"paper" | "consistent": the plant\'s Lagrangian (docs/model.md): the paper\'s (rotor masses at tips '
        "that do not rotate with theta) or the consistent one (tips rotated by theta, virtual-work input map); "
        'None: "consistent" in a tier with the consistent plant ("model_gap"), else "paper". The controllers '
        "use the paper's model in every case.")
    # ---- training aids: opt-in, the defaults leave observation, reward and dynamics as they were
    observe_error_integral: bool = _argument(
        False, "bool",
        "True: the observation gets 3 more entries (18-20), the integrals over the episode of the measured "
        "tracking errors e_x, e_z [m s] and e_theta [rad s] (the errors of entries 0-2, summed x dt after every "
        "step, reset to 0 with the episode, each clipped to +/-`error_integral_limit`).")
    error_integral_limit: float = _argument(
        10.0, "float",
        "`observe_error_integral`: the bound of each error integral (anti-windup clamp), in (0, 1e6] [m s or "
        "rad s]; 10 is an error of 1 m held for 10 s.")
    error_integral_error_limit: float | None = _argument(
        None, "float | None",
        "`observe_error_integral`: the bound on each step's error before it is integrated, in (0, 1e6] [m or "
        "rad]; None: none. With 0.5 and `error_integral_limit=8` the integrals are those of the integral loop "
        "(`LOOPS[\"integral\"]`), which clips each error at 0.5 m before integrating it.")
    precision_reward_weight: float = _argument(
        0.0, "float",
        "w >= 0 (at most 100): adds the reward term precision = w exp(-|(e_x, e_z)| / `precision_reward_scale`) "
        "(true state; in [0, w]; its slope w / scale stays the largest at millimetre errors); 0: no term.")
    precision_reward_scale: float = _argument(
        0.01, "float",
        "the precision term's length scale [m], in [1e-6, 100]: the term is w/e (37 %) at this error, 0.9 w at "
        "a tenth of it.")
    action_rate_penalty: float = _argument(
        0.0, "float",
        "w >= 0 (at most 100): adds the reward term action_rate = -w mean((a_t - a_(t-1))^2) of the clipped "
        "actions (0 at an episode's first step; in [-4 w, 0]); 0: no term.")
    residual_gate: float | None = _argument(
        None, "float | None",
        'residual mode: sigma > 0 (at most 1e6): the residual action is multiplied by the gate g = 1 - exp(-rho^2 '
        '/ sigma^2) of the measured tracking error rho^2 = e_x^2 + e_z^2 + e_theta^2 + edot_x^2 + edot_z^2 + '
        "edot_theta^2 (SI units: m, rad, m/s, rad/s) at the start of the step, so the correction is exactly 0 at "
        "zero error and its slope there is 0 (the base loop alone near the reference); None: no gate.")
    start_error_scale: float = _argument(
        1.0, "float",
        "scales the starting state's deviation from the reference at t = 0 (q0 - q_ref(0), qdot0 - qdot_ref(0); "
        "arm references 0), in [0, 10]; 0: starts on the reference; positions are then clipped into |x| <= 19 m, "
        "0 <= z <= 19 m, arms into +/-0.9 pi. A curriculum sets it per reset (reset option `start_error_scale`) "
        "or for every later reset, autoresets included (`env.set_start_error_scale(s)`).")
    start_distribution: str = _argument(
        "task", "str",
        '"task" (the task\'s starting states, see Starting State) | "wide": deviations from the reference at '
        "t = 0 uniform in +/-(6 m, 8 m, 0.7 rad, 0.5 rad, 0.5 rad) on q and +/-(1 m/s, 1 m/s, 0.5, 0.5, 0.5 rad/s) "
        "on qdot (x `start_error_scale`), positions truncated to |x| <= 19 m, 0 <= z <= 19 m: starts like "
        "track_paper's (5 m beside, 7 m below, tilted 0.63 rad) around any task's reference | \"attitude\": the "
        "same in +/-(1 m, 1 m, 1.2 rad, 0.6 rad, 0.6 rad) and +/-(0.5 m/s, 0.5 m/s, 2, 1, 1 rad/s): turned and "
        "spinning near the reference (recovery).")

    def __post_init__(self) -> None:
        if self.actuator_limits is not None:
            lim = self.actuator_limits
            if not isinstance(lim, (tuple, list)) or len(lim) != 2:
                raise ValueError(f"actuator_limits must be a tuple (thrust_max [N], arm_torque_max [N m]) of two "
                                 f"numbers > 0, e.g. (102.9, 9.8), or None (the defaults); got {short_repr(lim)}"
                                 + (" (pass tuple(limits))" if isinstance(lim, np.ndarray) and lim.shape == (2,)
                                    else ""))
            bounded_number("actuator_limits[0] (thrust_max)", lim[0], 0.0, ACTUATOR_LIMIT_MAX, ACTUATOR_LIMIT_REASON,
                           low_open=True)
            bounded_number("actuator_limits[1] (arm_torque_max)", lim[1], 0.0, ACTUATOR_LIMIT_MAX,
                           ACTUATOR_LIMIT_REASON, low_open=True)
        choice("action_mode", self.action_mode, ACTION_MODES)
        get_task(self.task)
        _tiers.get_tier(self.tier)
        choice("input_map", self.input_map, INPUT_MAPS)
        choice("model", self.model, MODELS)
        if self.model == "paper" and "consistent_plant" in _tiers.get_tier(self.tier).effects:
            raise ValueError(f"tier={self.tier!r} integrates the consistent model as the plant, but model='paper' was "
                             "given; pass model=None (the tier's) or 'consistent', or another tier")
        if self.params is None:  # the default, as for the env's other arguments
            object.__setattr__(self, "params", SoftPVTOLParams())
        if not isinstance(self.params, SoftPVTOLParams):
            raise ValueError(f"params must be a SoftPVTOLParams (e.g. SoftPVTOLParams(m=4.0)) or None, got "
                             f"{short_repr(self.params)} of type {type(self.params).__name__}"
                             + (" (use SoftPVTOLParams(**d))" if isinstance(self.params, dict) else ""))
        if self.allocation is not None:
            choice("allocation", self.allocation, ALLOCATIONS)
            if self.allocation == "ideal" and self.action_mode != "virtual":
                raise ValueError(
                    f"allocation='ideal' (tau applied directly) is only valid with action_mode='virtual', "
                    f"got action_mode={self.action_mode!r}; use one of ['exact', 'paper']"
                )
        choice("residual_space", self.residual_space, RESIDUAL_SPACES)
        choice("residual_base", self.residual_base, RESIDUAL_BASES)
        if self.residual_base != "unsaturated" and (self.action_mode, self.residual_space) != ("residual", "actuators"):
            raise ValueError(f"residual_base={self.residual_base!r} sets what an actuator-space residual is added to, "
                             f"got action_mode={self.action_mode!r}, residual_space={self.residual_space!r}; pass "
                             "residual_base='unsaturated', or action_mode='residual' with residual_space='actuators'")
        fs = self.frame_skip
        if isinstance(fs, (bool, np.bool_)) or not isinstance(fs, (int, np.integer)) or not 1 <= fs <= MAX_FRAME_SKIP:
            raise ValueError(f"frame_skip must be an int >= 1 and <= {MAX_FRAME_SKIP} ({FRAME_SKIP_REASON}), got "
                             f"{short_repr(self.frame_skip)} of type {type(fs).__name__}")
        if self.max_episode_seconds is not None:
            t = bounded_number("max_episode_seconds", self.max_episode_seconds, 0.0, MAX_EPISODE_SECONDS,
                               f"[s]; {EPISODE_SECONDS_REASON}", low_open=True)
            if t < self.dt:
                raise ValueError(f"max_episode_seconds must be at least one control step (dt = {self.dt:g} s with "
                                 f"frame_skip={fs}), got {self.max_episode_seconds!r}")
        bounded_number("residual_scale", self.residual_scale, 0.0, MAX_RESIDUAL_SCALE, RESIDUAL_SCALE_REASON,
                       low_open=True)
        if self.controller_loop is not None:
            choice("controller_loop", self.controller_loop, tuple(LOOPS))
            if self.controller_loop == "ideal" and self.action_mode != "virtual":
                raise ValueError("controller_loop='ideal' (tau applied directly) needs action_mode='virtual' with "
                                 f"allocation='ideal', got action_mode={self.action_mode!r}, allocation="
                                 f"{self.allocation!r}")
            if "controller" in LOOPS[self.controller_loop] and self.action_mode == "residual":
                raise ValueError(
                    f"controller_loop={self.controller_loop!r} is not available as the residual mode's base "
                    "controller (its extension states and reference derivatives are not part of the env's compiled "
                    "step); use it as a policy (PassivityPolicy.from_env(env, loop=...)) in action_mode='actuators', "
                    "or a passivity loop (\"bounded\", the default) as the base controller")
            loop_alloc = LOOPS[self.controller_loop]["allocation"]
            if self.allocation is not None and loop_alloc != self.allocation:
                raise ValueError(f"controller_loop={self.controller_loop!r} uses allocation={loop_alloc!r}, but "
                                 f"allocation={self.allocation!r} was given; pass one of them, or both consistent")
        _tiers.check_tier_options(self.tier_options)
        self._check_training_aids()
        self._check_physics()

    def _check_training_aids(self) -> None:
        """The opt-in training aids: types and ranges, and the residual gate only in residual mode."""
        flag = self.observe_error_integral
        if not isinstance(flag, (bool, np.bool_)):
            raise ValueError(f"observe_error_integral must be a bool (True: 3 more observation entries), got "
                             f"{short_repr(flag)} of type {type(flag).__name__}")
        object.__setattr__(self, "observe_error_integral", bool(flag))
        bounded_number("error_integral_limit", self.error_integral_limit, 0.0, ERROR_INTEGRAL_LIMIT_MAX,
                       "[m s]; the bound of each error integral, inside the observation clip 1e6", low_open=True)
        if self.error_integral_error_limit is not None:
            bounded_number("error_integral_error_limit", self.error_integral_error_limit, 0.0,
                           ERROR_INTEGRAL_LIMIT_MAX, "[m]; the bound on each step's error before it is integrated, "
                           "or None for none", low_open=True)
        for name in ("precision_reward_weight", "action_rate_penalty"):
            bounded_number(name, getattr(self, name), 0.0, MAX_AID_WEIGHT,
                           f"a reward weight; 0 switches the term off, {MAX_AID_WEIGHT:g} is 100 x the alive bonus")
        bounded_number("precision_reward_scale", self.precision_reward_scale, 1e-6, 100.0,
                       "[m]; the error at which the precision term has fallen to w/e")
        if self.residual_gate is not None:
            bounded_number("residual_gate", self.residual_gate, 0.0, 1e6,
                           "the gate's error scale sigma (SI units); None: no gate", low_open=True)
            if self.action_mode != "residual":
                raise ValueError(f"residual_gate gates the residual action of action_mode='residual', got "
                                 f"action_mode={self.action_mode!r}; pass residual_gate=None or action_mode='residual'")
        bounded_number("start_error_scale", self.start_error_scale, 0.0, MAX_START_ERROR_SCALE, START_SCALE_REASON)
        choice("start_distribution", self.start_distribution, START_DISTRIBUTIONS)

    def _check_physics(self) -> None:
        """What the parameters must satisfy together with the other arguments: the default actuator
        limits need gravity, and the mismatch tiers' plant parameters stay within the parameter bounds."""
        p = self.params
        if 0.0 < p.g < G_MIN:
            raise ValueError(f"SoftPVTOLParams.g = {p.g!r} is below the env's smallest non-zero gravity "
                             f"{G_MIN:g} m/s^2: it moves a body less than 1 mm in 40 s, free flight in effect, while "
                             "the hover thrust g (m + m_l + m_r) / 2 and the arm loads the env scales actions and the "
                             "reward by go toward 0 (and underflow); pass g=0 with actuator_limits for free flight, "
                             f"or g >= {G_MIN:g}")
        if p.g == 0.0 and self.actuator_limits is None:
            raise ValueError("SoftPVTOLParams.g = 0.0 (free flight) needs actuator_limits=(T_max [N], tau_max [N m]): "
                             "the default limits are 3 x the hover thrust g (m + m_l + m_r) / 2 and 4 x the arm "
                             "gravity load g m_i l_i / 2, both 0 without gravity, and the actions and the reward's "
                             "effort term are normalised by them; pass actuator_limits, or g > 0")
        s = self.mismatch_scale
        if s > 0.0:
            for name in _tiers.MISMATCH_FIELDS:
                lo, hi = PARAM_BOUNDS[name]
                v = getattr(p, name)
                if v * (1.0 - s) < lo or v * (1.0 + s) > hi:
                    raise ValueError(
                        f"tier {self.tier!r} with mismatch_scale={s:g} scales the plant's SoftPVTOLParams.{name}={v!r} "
                        f"into [{v * (1.0 - s):g}, {v * (1.0 + s):g}], outside its bounds [{lo:g}, {hi:g}] (the band "
                        "in which the model stays far inside float64); use a smaller mismatch_scale in tier_options "
                        f"or a {name} nearer the band's middle")

    @classmethod
    def from_kwargs(cls, **kwargs) -> EnvConfig:
        """EnvConfig(**kwargs) with a clear error for an argument it does not have."""
        names = [f.name for f in dataclasses.fields(cls)]
        unknown = [k for k in kwargs if k not in names]
        if unknown:
            raise TypeError(f"unknown SoftPVTOL argument(s) {unknown}; valid ones are {names} "
                            "(plus render_mode, and num_envs/autoreset_mode for the vector env)")
        return cls(**kwargs)

    @classmethod
    def from_init_arguments(cls, arguments: dict, env_arguments: tuple[str, ...] = ()) -> EnvConfig:
        """EnvConfig from an env's ``__init__`` arguments (its ``locals()`` before anything else is bound): every
        argument but ``self``, the env's own (``env_arguments``, e.g. ``render_mode``) and ``unknown`` (the
        ``**unknown`` of misspelled names, passed on so that :meth:`from_kwargs` refuses them)."""
        own = {"self", "unknown", *env_arguments}
        return cls.from_kwargs(**{k: v for k, v in arguments.items() if k not in own}, **arguments.get("unknown", {}))

    # ---------------------------------------------------------------------------- derived values
    @property
    def task_spec(self) -> TaskSpec:
        """The registered :class:`~softpvtol_gym.tasks.TaskSpec` of ``task``."""
        return get_task(self.task)

    @property
    def plant_model(self) -> str:
        """The plant's model: ``model``, or by default "consistent" in a tier with the "consistent_plant"
        effect (e.g. "model_gap") and "paper" otherwise. The controllers always use the paper's."""
        if self.model is not None:
            return self.model
        return "consistent" if "consistent_plant" in _tiers.get_tier(self.tier).effects else "paper"

    @property
    def resolved_allocation(self) -> str:
        """The allocation actually used: the argument, that of ``controller_loop``, or "exact"."""
        if self.allocation is not None:
            return self.allocation
        if self.controller_loop is not None:
            return LOOPS[self.controller_loop]["allocation"]
        return "exact"

    @property
    def resolved_controller_loop(self) -> str:
        """PassivityController loop (:data:`~softpvtol_gym.control.LOOPS`) of the residual base controller
        and the default of PassivityPolicy: ``controller_loop``, or from the allocation: "paper" ->
        "paper", "ideal" -> "ideal", otherwise "bounded" (the strongest loop measured in the env)."""
        if self.controller_loop is not None:
            return self.controller_loop
        return {"paper": "paper", "ideal": "ideal"}.get(self.resolved_allocation, "bounded")

    @property
    def dt(self) -> float:
        """Control period [s] = 0.01 s x frame_skip."""
        return PHYSICS_DT * int(self.frame_skip)

    @property
    def episode_seconds(self) -> float:
        if self.max_episode_seconds is None:
            return self.task_spec.episode_seconds
        return float(self.max_episode_seconds)

    @property
    def max_steps(self) -> int:
        # (at most 2**62: an "endless" episode length stays an int64)
        return max(1, min(int(round(self.episode_seconds / self.dt)), 2**62))

    @property
    def obs_dim(self) -> int:
        """Observation entries: 18 (:data:`~softpvtol_gym.envs.observation.OBS_DIM`), + 3 error integrals with
        ``observe_error_integral``."""
        return OBS_DIM + (N_ERROR_INTEGRALS if self.observe_error_integral else 0)

    @property
    def extra_reward_terms(self) -> tuple[str, ...]:
        """The opt-in reward terms switched on, after :data:`~softpvtol_gym.envs.reward.REWARD_TERMS` in
        ``info["reward_terms"]``: "precision" (``precision_reward_weight > 0``), "action_rate"
        (``action_rate_penalty > 0``)."""
        return tuple(name for name, w in (("precision", self.precision_reward_weight),
                                          ("action_rate", self.action_rate_penalty)) if w > 0)

    @property
    def uses_training_aids(self) -> bool:
        """Whether a step needs the training aids' kernels (:mod:`~softpvtol_gym.envs.training_aids`)."""
        return self.observe_error_integral or bool(self.extra_reward_terms) or self.residual_gate is not None

    @functools.cached_property
    def tier_values(self) -> dict:
        """Tier numbers in effect: options of disabled effects are reported as 0 (off)."""
        return _tiers.tier_values(self.tier, self.tier_options)

    @property
    def mismatch_scale(self) -> float:
        """Plant parameter mismatch scale in effect (0: off)."""
        return self.tier_values["mismatch_scale"]

    @property
    def thrust_max(self) -> float:
        """T_max = 3 x the nominal hover thrust per rotor [N] (102.9 N with defaults)."""
        if self.actuator_limits is not None:
            return float(self.actuator_limits[0])
        return 3.0 * self.params.hover_thrust

    @property
    def arm_torque_max(self) -> float:
        """tau_max = 4 x the larger nominal arm gravity load [N m] (9.8 N m with defaults)."""
        if self.actuator_limits is not None:
            return float(self.actuator_limits[1])
        return 4.0 * max(self.params.arm_gravity_torques)

    @property
    def virtual_scale(self) -> np.ndarray:
        """Per-unit scales of the virtual action: (2 M g, 2 M g, 20 N m, tau_max, tau_max)."""
        w = 2.0 * self.params.total_mass * self.params.g if self.params.g > 0 else 2.0 * self.params.total_mass * 9.8
        return np.array([w, w, 20.0, self.arm_torque_max, self.arm_torque_max])

    @property
    def virtual_offset(self) -> np.ndarray:
        """Virtual force at action 0: (0, M g, 0, 0, 0) (the nominal weight)."""
        return np.array([0.0, self.params.total_mass * self.params.g, 0.0, 0.0, 0.0])

    @property
    def residual_tau_scale(self) -> np.ndarray:
        return self.residual_scale * self.virtual_scale

    @property
    def residual_actuator_scale(self) -> np.ndarray:
        t, a = self.thrust_max, self.arm_torque_max
        return self.residual_scale * np.array([0.5 * t, 0.5 * t, a, a])

    @property
    def kernel_mode(self) -> int:
        return ACTION_MODE_SPECS[self.action_mode].kernel_mode(self)

    @property
    def action_dim(self) -> int:
        return ACTION_MODE_SPECS[self.action_mode].action_dim(self)

    # ------------------------------------------------------------------------- kernel constants
    def constants(self) -> np.ndarray:
        """The step kernel's constant vector C (layout ``CONST``)."""
        tv = self.tier_values
        C = np.zeros(CONST.size)
        dt = self.dt
        C[SC.dt_physics] = PHYSICS_DT
        C[SC.frame_skip] = self.frame_skip
        C[SC.thrust_max] = self.thrust_max
        C[SC.arm_torque_max] = self.arm_torque_max
        tc = tv["actuator_time_constant"]
        C[SC.lag_a] = 1.0 - math.exp(-dt / tc) if tc > 0 else 1.0
        a = math.exp(-dt / tv["wind_correlation_time"])
        C[SC.wind_a] = a
        C[SC.wind_b] = tv["wind_std"] * math.sqrt(1.0 - a * a)
        C[SC.wind_std] = tv["wind_std"]
        s = tv["obs_noise_scale"]
        C[SC.noise_q:SC.noise_q + 5] = np.asarray(_tiers.OBS_NOISE_Q) * s
        C[SC.noise_qd:SC.noise_qd + 5] = np.asarray(_tiers.OBS_NOISE_QD) * s
        C[SC.virtual_scale:SC.virtual_scale + 5] = self.virtual_scale
        C[SC.virtual_offset:SC.virtual_offset + 5] = self.virtual_offset
        # actuator-space residuals only: a virtual residual enters through the controller's tau alone
        if self.action_mode == "residual" and self.residual_space == "actuators":
            C[SC.residual_actuator_scale:SC.residual_actuator_scale + 4] = self.residual_actuator_scale
            C[SC.residual_base_saturated] = 1.0 if self.residual_base == "saturated" else 0.0
        C[SC.residual_tau_scale:SC.residual_tau_scale + 5] = self.residual_tau_scale
        C[SC.hover_thrust] = self.params.hover_thrust
        C[SC.lag_on] = 1.0 if tc > 0 else 0.0
        C[SC.wind_on] = 1.0 if tv["wind_std"] > 0 else 0.0
        C[SC.noise_on] = 1.0 if s > 0 else 0.0
        C[SC.p_nominal:SC.p_nominal + 10] = self.params.array
        gains = PassivityGains()
        C[SC.lam:SC.lam + 5] = gains.lam_array
        C[SC.kg:SC.kg + 5] = gains.k_array
        C[SC.dt_control] = dt
        C[SC.consistent_plant] = 1.0 if self.plant_model == "consistent" else 0.0
        return C

    def codes(self) -> np.ndarray:
        """The step kernel's integer codes K (layout ``CODES``)."""
        K = np.zeros(CODES.size, dtype=np.int64)
        K[SK.mode] = self.kernel_mode
        K[SK.alloc] = CK.ALLOC_PAPER if self.resolved_allocation == "paper" else CK.ALLOC_EXACT
        K[SK.imap] = MK.INPUT_MAP_PAPER if self.input_map == "paper" else MK.INPUT_MAP_EXACT
        K[SK.res_virtual] = 1 if self.residual_space == "virtual" else 0
        K[SK.ref] = self.task_spec.compiled_reference
        K[SK.action_dim] = self.action_dim
        return K


# ------------------------------------------------------------------------------ documentation
#: the env's own argument (the rest are :class:`EnvConfig`'s fields): (name, type, default, description)
RENDER_MODE_ARGUMENT = ("render_mode", "str | None", "None",
                        'None | "rgb_array" | "human": `render()` returns an RGB array (H, W, 3), or draws in a '
                        'window (the vector env: None | "rgb_array", its first sub-env).')


def argument_rows() -> list[tuple[str, str, str, str]]:
    """(argument, type, default, description) of every env argument: ``render_mode``, then the fields of
    :class:`EnvConfig` in their order (the documentation is the fields' ``metadata``)."""
    rows = [RENDER_MODE_ARGUMENT]
    for f in dataclasses.fields(EnvConfig):
        rows.append((f.name, f.metadata["type"], f.metadata["default"], f.metadata["description"]))
    return rows


def argument_table_markdown() -> str:
    """The env's Arguments table in Markdown (columns: argument, type, default, description), generated
    from :class:`EnvConfig`'s field metadata: the table of the env docstring and of docs/env.md."""

    def cell(text: str) -> str:
        return text.replace("|", "\\|")

    lines = ["| argument | type | default | description |", "|---|---|---|---|"]
    for name, type_, default, description in argument_rows():
        lines.append(f"| `{name}` | `{cell(type_)}` | `{cell(default)}` | {cell(description)} |")
    return "\n".join(lines)
