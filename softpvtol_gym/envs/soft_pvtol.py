"""SoftPVTOL-v0: the single Gymnasium environment."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.error import ResetNeeded

from .._validation import choice, seed_value
from ..params import SoftPVTOLParams
from .batch_sim import BatchSim
from .config import RENDER_MODES, EnvConfig
from .episodes import N_UNIFORMS, check_reset_options
from .info import single_info, single_outcome
from .observation import OBS_CLIP


def make_spaces(cfg: EnvConfig) -> tuple[spaces.Box, spaces.Box]:
    """(observation_space, action_space) of one env."""
    obs = spaces.Box(-OBS_CLIP, OBS_CLIP, shape=(cfg.obs_dim,), dtype=np.float32)
    act = spaces.Box(-1.0, 1.0, shape=(cfg.action_dim,), dtype=np.float32)
    return obs, act


class RenderModes(list):
    """``metadata["render_modes"]``: a list whose membership test refuses a ``render_mode`` that is not
    a str (nor None) with the env's own error. ``gym.make`` tests ``render_mode in render_modes`` and
    then calls ``render_mode.endswith`` before the env's ``__init__`` runs, so without this
    ``gym.make("SoftPVTOL-v0", render_mode=1)`` fails inside gymnasium with an AttributeError."""

    def __contains__(self, mode) -> bool:
        if mode is not None and not isinstance(mode, str):
            choice("render_mode", mode, RENDER_MODES)  # raises: the message lists the valid modes
        return super().__contains__(mode)


class SoftPVTOLEnv(gym.Env):
    r"""
    ## Description

    The Soft-PVTOL: a planar vertical take-off and landing robot whose two rotors sit at the tips of
    soft, actively bent arms (constant-curvature model). Generalized coordinates
    q = (x, z, theta, q_l, q_r): body position [m], pitch [rad], arm curvatures (bending angles)
    [rad]. Physics: the package's compiled Euler-Lagrange model, integrated with classical RK4 at the
    paper's 0.01 s step; one env step = ``frame_skip`` (default 1) RK4 steps with the actuators held
    (zero-order hold: B(q) re-evaluated at every RK4 stage; the wind force held too), so the control
    period is 0.01 s x ``frame_skip``; the arm loop of the passivity controller is stable under the
    zero-order hold only up to 0.012 s (:data:`softpvtol_gym.control.MAX_HELD_CONTROL_PERIOD`).
    The model and the controller are those of the Soft-PVTOL paper (docs/model.md, docs/control.md).

    ## Action Space

    ``Box(-1, 1, (dim,), float32)``; the meaning depends on ``action_mode``:

    | mode | dim | entries | physical value |
    |---|---|---|---|
    | ``"actuators"`` (default) | 4 | T_l, T_r [N], tau_l, tau_r [N m] | T = T_max (u + 1) / 2 in [0, T_max]; tau_arm = tau_max u |
    | ``"virtual"`` | 5 | tau_x, tau_z [N], tau_theta, tau_ql, tau_qr [N m] | tau = offset + scale * u, offset = (0, M g, 0, 0, 0), scale = (2 M g, 2 M g, 20 N m, tau_max, tau_max) |
    | ``"residual"`` | 5 (or 4) | correction to the passivity controller | ``residual_scale`` (0.2) x the virtual scales added to its tau (or, ``residual_space="actuators"``, 0.2 x (T_max/2, T_max/2, tau_max, tau_max) added to its actuators) |

    T_max [N] and tau_max [N m] are ``actuator_limits``: by default 3 x the hover thrust per rotor
    (102.9 N with the default params) and 4 x the arm gravity load g m_i l_i / 2 (9.8 N m); M g = total
    weight (68.6 N). In ``"virtual"`` mode the body rows of tau go through the control allocation
    (``allocation``: "exact" default, or "paper") to thrusts; the arm rows are the generalized arm
    forces (with ``input_map="exact"`` the thrusts' own work on the curvatures is compensated); thrusts
    are saturated to [0, T_max] and arm torques to ±tau_max (``info["thrust_saturated"]``,
    ``info["arm_torque_saturated"]``). ``allocation="ideal"`` applies tau directly as the generalized
    force (the paper's idealised loop, no saturation). In ``"residual"`` mode the base controller is
    :class:`~softpvtol_gym.control.PassivityController` with the nominal ``params`` and the loop
    ``controller_loop``: by default "bounded" (exact allocation, arm references fed forward with bounded
    rates, desired curvatures within 0.6 rad) for allocation "exact", "paper" for "paper"; it is fed the
    measured state, and action 0 reproduces it exactly. An actuator-space residual is added to the base
    controller's command as computed (``residual_base="unsaturated"``) or clipped to the actuator box
    (``"saturated"``: a command far outside the box cannot absorb the correction). ``residual_gate=sigma``
    multiplies the clipped residual by g = 1 - exp(-rho^2 / sigma^2), rho^2 = e_x^2 + e_z^2 + e_theta^2 + edot_x^2 + edot_z^2 +
    edot_theta^2 of the measured body errors (position, attitude and their rates; SI units) of the last
    observation: the residual is exactly 0 at zero tracking error, with zero slope there
    (``info["residual_gate"]``: the g applied). Finite out-of-range actions are clipped
    (``info["action_clipped"]``); NaN/inf, wrong shapes and values that are not real numbers (str, bool,
    complex, None) raise ValueError (nothing is cast).

    ## Observation Space

    ``Box(-1e6, 1e6, (18,), float32)`` (entries are clipped to ±1e6 so they stay finite):

    | idx | observation | unit |
    |---|---|---|
    | 0 | x - x_ref | m |
    | 1 | z - z_ref | m |
    | 2 | theta - theta_ref, wrapped to [-pi, pi) | rad |
    | 3 | sin theta | - |
    | 4 | cos theta | - |
    | 5 | q_l (left arm curvature) | rad |
    | 6 | q_r (right arm curvature) | rad |
    | 7 | xdot | m/s |
    | 8 | zdot | m/s |
    | 9 | thetadot | rad/s |
    | 10 | q_l dot | rad/s |
    | 11 | q_r dot | rad/s |
    | 12 | xdot_ref | m/s |
    | 13 | zdot_ref | m/s |
    | 14 | thetadot_ref | rad/s |
    | 15 | xddot_ref | m/s^2 |
    | 16 | zddot_ref | m/s^2 |
    | 17 | thetaddot_ref | rad/s^2 |

    Entries 0-11 are computed from the measured state (noisy in the "noisy"/"hard" tiers), 12-17
    from the reference. This is everything the passivity controller needs
    (:class:`~softpvtol_gym.PassivityPolicy` acts from it alone).

    With ``observe_error_integral=True`` the observation is ``Box(-1e6, 1e6, (21,), float32)``: entries
    18, 19, 20 are the integrals over the episode of entries 0, 1, 2 (the measured errors; m s, m s, rad s):
    I_k = clip(I_(k-1) + dt clip(e_k, -E, E), -L, L) after every step k, I_0 = 0 at the reset, L =
    ``error_integral_limit`` (10), E = ``error_integral_error_limit`` (None: no clip).
    :class:`~softpvtol_gym.PassivityPolicy` takes the 21 entries and reads 0-17.

    ## Rewards

    r = 1 + position + attitude + velocity + effort + curvature + crash, with (each in ``info["reward_terms"]``)
    position = -0.5 min(|(e_x, e_z)| / 2 m, 1); attitude = -0.1 min(|e_theta| / pi, 1);
    velocity = -0.1 min(|(xdot, zdot, thetadot) - ref| / 5, 1);
    effort = -0.1 min(mean(a_n^2), 1), a_n = ((T_l - T_h)/T_max, (T_r - T_h)/T_max, tau_l/tau_max, tau_r/tau_max)
    of the applied actuators (T_h the hover thrust; ideal mode: the normalised tau);
    curvature = -0.2 clip((max|q_arm| - pi/2) / (pi/2), 0, 1)^2; crash = -10 at termination.
    Non-terminal rewards lie in [0, 1]; the terms use the true (noise-free) state.

    Opt-in terms (off by default; when on, added to r and listed after "crash" in ``info["reward_terms"]``):
    precision = w_p exp(-|(e_x, e_z)| / s_p) (``precision_reward_weight`` w_p, ``precision_reward_scale``
    s_p = 0.01 m; true state; in [0, w_p], slope w_p / s_p at zero error, so 0.1 mm against 0.2 m is worth
    ~w_p); action_rate = -w_r mean((a_t - a_(t-1))^2) (``action_rate_penalty`` w_r; a the clipped action as
    the policy gave it; 0 at an episode's first step; in [-4 w_r, 0]).

    ## Starting State

    * ``"hover"``: setpoint (0, 2 m, 0); x, z uniform within ±1 m of it, theta, q_l, q_r in ±0.3 rad,
      xdot, zdot in ±0.5 m/s, thetadot, arm rates in ±0.2 rad/s. 10 s.
    * ``"setpoint"``: setpoint x in ±3 m, z in [0, 4] m, theta in ±0.3 rad; start x in ±3 m,
      z in [0, 4] m, angles and rates as hover. 10 s.
    * ``"track_paper"``: the paper's reference (x = 4 sin(t/2), z = 3 cos(t/10) + 4, theta = 0) from
      q0 = (5, 0, 0.2 pi, 0.01 pi, -0.15 pi), qdot0 = 0 (deterministic). 40 s.
    * ``"track_random"``: x_ref = sum_k A_k (sin(w_k t + phi_k) - sin phi_k), 3 terms, A_k in [0, 1] m;
      z_ref = 3 m + the same with A_k in [0, 0.5] m; w_k in [0.2, 0.8] rad/s, phi_k in [0, 2 pi);
      theta_ref = 0. Start at the reference plus half the hover perturbation. 20 s.

    ``start_error_scale`` (default 1) scales every start's deviation from the reference at t = 0 (q and
    qdot; arm references 0; positions then clipped into |x| <= 19 m, 0 <= z <= 19 m, arms into ±0.9 pi);
    ``start_distribution="wide"`` draws the deviations uniformly in ±(6 m, 8 m, 0.7 rad, 0.5 rad, 0.5 rad)
    and ±(1 m/s, 1 m/s, 0.5 rad/s x 3) (x the scale; x, z uniform on the part inside that box), around any
    task's reference: starts like track_paper's; ``start_distribution="attitude"`` likewise in ±(1 m, 1 m,
    1.2 rad, 0.6 rad, 0.6 rad) and ±(0.5 m/s, 0.5 m/s, 2 rad/s, 1 rad/s, 1 rad/s): near the reference, turned,
    bent and spinning (recovery). All use the episode's own uniforms (no extra draws).
    ``reset(options={"start_error_scale": s})`` sets the scale for that reset,
    ``env.set_start_error_scale(s)`` for every later one (a curriculum).

    ``reset(options={"q0": ..., "qdot0": ..., "setpoint": (x, z, theta)})`` overrides them; q0 must lie
    inside the position limits below (|q_l|, |q_r| <= pi: the model's validity; the box) and the
    setpoint inside the box, qdot0 be finite, else ValueError (checked before anything changes). ``seed``: an int
    >= 0 (Python or numpy integer) or None.

    ## Episode End

    Termination (``info["termination_reason"]``): ``"curvature_limit"`` |q_l| or |q_r| > pi (model
    validity); ``"ground"`` z < -1 m; ``"out_of_bounds"`` |x| > 20 m, z > 20 m, |xdot| or |zdot| >
    50 m/s, or |thetadot|, |q_arm dot| > 100 rad/s; ``"non_finite"`` the state became NaN/inf (the
    last finite state and observation are returned). Truncation (``"time_limit"``) at the task's
    episode length (or ``max_episode_seconds``); the env truncates itself, so ``gym.make`` and
    ``gym.make_vec`` agree.

    ## Arguments

    ``SoftPVTOLEnv(render_mode=None, *, action_mode="actuators", task="hover", ...)``, or
    ``gym.make("SoftPVTOL-v0", **arguments)``; :class:`SoftPVTOLVectorEnv` takes the same arguments
    (plus ``num_envs`` and ``autoreset_mode``). Generated from :class:`~softpvtol_gym.envs.config.EnvConfig`
    by :func:`~softpvtol_gym.envs.config.argument_table_markdown` (a test keeps them equal):

    | argument | type | default | description |
    |---|---|---|---|
    | `render_mode` | `str \| None` | `None` | None \| "rgb_array" \| "human": `render()` returns an RGB array (H, W, 3), or draws in a window (the vector env: None \| "rgb_array", its first sub-env). |
    | `action_mode` | `str` | `"actuators"` | "actuators" \| "virtual" \| "residual": what the action commands (see Action Space). |
    | `task` | `str` | `"hover"` | a registered task: "hover" \| "setpoint" \| "track_paper" \| "track_random" built in, or one registered with `softpvtol_gym.tasks.register_task` (a `TaskSpec`); sets the reference, the starting state and the episode length. |
    | `tier` | `str` | `"nominal"` | a registered robustness tier (`softpvtol_gym.envs.register_tier`); built in: "nominal" (no disturbance) \| "mismatch" (plant m, m_l, m_r, I, I_l, I_r, l_l, l_r each x U(0.8, 1.2) per episode; the controllers keep the nominal params) \| "wind" (Ornstein-Uhlenbeck force on x and z, std 3 N, correlation time 1 s) \| "noisy" (Gaussian measurement noise, std (0.02 m, 0.02 m, 0.01 rad, 0.02 rad, 0.02 rad) on q and (0.05 m/s, 0.05 m/s, 0.02 rad/s, 0.05 rad/s, 0.05 rad/s) on qdot, and a 0.05 s first-order lag of the applied command) \| "hard" (mismatch, wind and noisy together) \| "model_gap" (the plant is the consistent model; the controllers keep the paper's). |
    | `params` | `SoftPVTOLParams \| None` | `None` | the nominal physical parameters (SI units; masses, inertias, lengths in [1e-6, 1e6], g 0 (with `actuator_limits`) or in [1e-6, 1e6], epsilon in [0, 1e6]): the plant's in the nominal tier and the model of the controllers; None: the paper's values, `SoftPVTOLParams()`. |
    | `input_map` | `str` | `"paper"` | "paper" \| "exact": the input map tau = B(q) a of the paper's model (as printed, or the virtual work of the thrusts at the tips): the plant's under `model="paper"` and the one the controllers assume. |
    | `allocation` | `str \| None` | `None` | virtual and residual modes: how body forces become thrusts, "exact" \| "paper" \| "ideal" (tau applied directly, virtual mode only, no saturation); None: "exact", or the `controller_loop`'s. |
    | `residual_space` | `str` | `"virtual"` | residual mode: "virtual" (the correction is added to the base controller's tau, 5 entries) \| "actuators" (added to its actuators, 4 entries). |
    | `residual_base` | `str` | `"unsaturated"` | residual mode with `residual_space="actuators"`: what the correction is added to, "unsaturated" (the base controller's actuator command as computed, which may lie far outside the actuator box) \| "saturated" (that command clipped to the box first, so that with `residual_scale` >= 2 an action reaches every point of the box); the sum is saturated in both, and action 0 gives the base controller's applied command in both. |
    | `frame_skip` | `int` | `1` | RK4 steps of 0.01 s per env step, in [1, 1000] (the control period is 0.01 s x frame_skip, at most 10 s, the shortest built-in episode; the analytic controllers need <= 0.012 s). |
    | `max_episode_seconds` | `float \| None` | `None` | episode length [s] (truncation), from one control step to 1e9 s (the clock t = steps x dt keeps a resolution below 1e-6 s); None: the task's (hover, setpoint 10 s, track_paper 40 s, track_random 20 s). |
    | `tier_options` | `dict \| None` | `None` | overrides of the tier's numbers: `mismatch_scale` (in [0, 1), default 0.2; the scaled plant parameters must stay within the `SoftPVTOLParams` bounds), `wind_std` [N] (in [0, 1e20], 3), `wind_correlation_time` [s] (in (0, 1e9], 1), `obs_noise_scale` (x the noise stds, in [0, 1e8], 1), `actuator_time_constant` [s] (in [0, 1e9], 0.05); an option given by hand switches its effect on. |
    | `residual_scale` | `float` | `0.2` | residual mode: the correction at action +/-1 as a fraction of the virtual scales (or of (T_max/2, T_max/2, tau_max, tau_max) with `residual_space="actuators"`), in (0, 100] (at 100 an action of 0.02 already exceeds the default actuator range). |
    | `actuator_limits` | `tuple \| None` | `None` | (T_max [N], tau_max [N m]), two numbers in (0, 1e20]: each rotor's thrust range [0, T_max] and each arm's torque range [-tau_max, tau_max], which scale the actions and saturate the applied commands; None: 3 x the hover thrust per rotor and 4 x the larger arm gravity load g m_i l_i / 2 of `params` (102.9 N, 9.8 N m with the defaults; with g = 0, free flight, these are 0: give the limits). |
    | `controller_loop` | `str \| None` | `None` | residual mode's base controller and `PassivityPolicy`'s default: a loop of `softpvtol_gym.control.LOOPS` ("paper" \| "exact" \| "improved" \| "bounded" \| "integral" \| "ideal" \| "extended"; "extended", the dynamically extended loop, is a policy only, not a residual base controller); None: from the allocation, "bounded" for "exact" (the default), "paper" for "paper", "ideal" for "ideal". A loop whose allocation differs from a given `allocation` is refused. |
    | `model` | `str \| None` | `None` | "paper" \| "consistent": the plant's Lagrangian (docs/model.md): the paper's (rotor masses at tips that do not rotate with theta) or the consistent one (tips rotated by theta, virtual-work input map); None: "consistent" in a tier with the consistent plant ("model_gap"), else "paper". The controllers use the paper's model in every case. |
    | `observe_error_integral` | `bool` | `False` | True: the observation gets 3 more entries (18-20), the integrals over the episode of the measured tracking errors e_x, e_z [m s] and e_theta [rad s] (the errors of entries 0-2, summed x dt after every step, reset to 0 with the episode, each clipped to +/-`error_integral_limit`). |
    | `error_integral_limit` | `float` | `10.0` | `observe_error_integral`: the bound of each error integral (anti-windup clamp), in (0, 1e6] [m s or rad s]; 10 is an error of 1 m held for 10 s. |
    | `error_integral_error_limit` | `float \| None` | `None` | `observe_error_integral`: the bound on each step's error before it is integrated, in (0, 1e6] [m or rad]; None: none. With 0.5 and `error_integral_limit=8` the integrals are those of the integral loop (`LOOPS["integral"]`), which clips each error at 0.5 m before integrating it. |
    | `precision_reward_weight` | `float` | `0.0` | w >= 0 (at most 100): adds the reward term precision = w exp(-\|(e_x, e_z)\| / `precision_reward_scale`) (true state; in [0, w]; its slope w / scale stays the largest at millimetre errors); 0: no term. |
    | `precision_reward_scale` | `float` | `0.01` | the precision term's length scale [m], in [1e-6, 100]: the term is w/e (37 %) at this error, 0.9 w at a tenth of it. |
    | `action_rate_penalty` | `float` | `0.0` | w >= 0 (at most 100): adds the reward term action_rate = -w mean((a_t - a_(t-1))^2) of the clipped actions (0 at an episode's first step; in [-4 w, 0]); 0: no term. |
    | `residual_gate` | `float \| None` | `None` | residual mode: sigma > 0 (at most 1e6): the residual action is multiplied by the gate g = 1 - exp(-rho^2 / sigma^2) of the measured tracking error rho^2 = e_x^2 + e_z^2 + e_theta^2 + edot_x^2 + edot_z^2 + edot_theta^2 (SI units: m, rad, m/s, rad/s) at the start of the step, so the correction is exactly 0 at zero error and its slope there is 0 (the base loop alone near the reference); None: no gate. |
    | `start_error_scale` | `float` | `1.0` | scales the starting state's deviation from the reference at t = 0 (q0 - q_ref(0), qdot0 - qdot_ref(0); arm references 0), in [0, 10]; 0: starts on the reference; positions are then clipped into \|x\| <= 19 m, 0 <= z <= 19 m, arms into +/-0.9 pi. A curriculum sets it per reset (reset option `start_error_scale`) or for every later reset, autoresets included (`env.set_start_error_scale(s)`). |
    | `start_distribution` | `str` | `"task"` | "task" (the task's starting states, see Starting State) \| "wide": deviations from the reference at t = 0 uniform in +/-(6 m, 8 m, 0.7 rad, 0.5 rad, 0.5 rad) on q and +/-(1 m/s, 1 m/s, 0.5, 0.5, 0.5 rad/s) on qdot (x `start_error_scale`), positions truncated to \|x\| <= 19 m, 0 <= z <= 19 m: starts like track_paper's (5 m beside, 7 m below, tilted 0.63 rad) around any task's reference \| "attitude": the same in +/-(1 m, 1 m, 1.2 rad, 0.6 rad, 0.6 rad) and +/-(0.5 m/s, 0.5 m/s, 2, 1, 1 rad/s): turned and spinning near the reference (recovery). |

    An unknown argument is a TypeError naming the valid ones.

    All randomness comes from ``self.np_random`` (one block of uniforms per reset; per-step noise
    from a counter-based generator keyed per episode), so trajectories are reproducible from the
    seed and identical to the matching sub-env of :class:`SoftPVTOLVectorEnv`.

    ## Version History

    Version policy: the id's version is the env's behaviour. After a release, any change of what a
    given id, arguments and seed produce (dynamics, observation, reward, termination, starting states,
    defaults) bumps the id (``SoftPVTOL-v0`` -> ``SoftPVTOL-v1``) and is listed here; additions that
    leave every existing configuration bit-identical (a new argument with an unchanged default, a new
    task or tier) keep it.

    * v0: initial version (not released yet).
    """

    # per instance: render_fps = 1 / control period
    metadata = {"render_modes": RenderModes(["human", "rgb_array"]), "render_fps": 100}

    def __init__(
        self,
        render_mode: str | None = None,
        *,
        action_mode: str = "actuators",
        task: str = "hover",
        tier: str = "nominal",
        params: SoftPVTOLParams | None = None,
        input_map: str = "paper",
        allocation: str | None = None,
        residual_space: str = "virtual",
        residual_base: str = "unsaturated",
        frame_skip: int = 1,
        max_episode_seconds: float | None = None,
        tier_options: dict | None = None,
        residual_scale: float = 0.2,
        actuator_limits: tuple | None = None,
        controller_loop: str | None = None,
        model: str | None = None,
        observe_error_integral: bool = False,
        error_integral_limit: float = 10.0,
        error_integral_error_limit: float | None = None,
        precision_reward_weight: float = 0.0,
        precision_reward_scale: float = 0.01,
        action_rate_penalty: float = 0.0,
        residual_gate: float | None = None,
        start_error_scale: float = 1.0,
        start_distribution: str = "task",
        **unknown,
    ) -> None:
        """The arguments are :class:`EnvConfig`'s fields (see Arguments), validated there; ``unknown``
        only collects misspelled names, refused with a TypeError that lists the valid ones."""
        self.config = EnvConfig.from_init_arguments(locals(), ("render_mode",))
        choice("render_mode", render_mode, RENDER_MODES)
        self.render_mode = render_mode
        self.observation_space, self.action_space = make_spaces(self.config)
        self._sim = BatchSim(self.config, 1)
        self.dt = self.config.dt
        self.metadata = dict(self.metadata, render_fps=int(round(1.0 / self.dt)))
        self._renderer = None
        self._needs_reset = True  # step() and render() need a reset() first (as under gym.make)
        self._episode_over = self._warned_over = False

    # ------------------------------------------------------------------------------------ api
    def check_reset_arguments(self, seed=None, options=None) -> tuple[int | None, dict]:
        """(seed, options) of ``reset`` checked, changing nothing: ValueError for a bad seed or option."""
        return seed_value(seed), check_reset_options(self.config, options)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        # checked before anything changes: a bad seed or option leaves the env as it was
        seed, options = self.check_reset_arguments(seed, options)
        super().reset(seed=seed)
        u = self.np_random.random(N_UNIFORMS)[None, :]
        self._sim.reset_entries(np.array([0]), u, options)
        self._needs_reset = False
        self._episode_over = self._warned_over = False
        if self._renderer is not None:
            self._renderer.clear_trail()
        if self.render_mode == "human":
            self.render()
        return self._sim.obs[0].copy(), single_info(self._sim, None)

    def step(self, action):
        if self._needs_reset:
            raise ResetNeeded("Cannot call env.step() before calling env.reset()")
        if self._episode_over and not self._warned_over:  # as CartPole: once per episode, stepping stays allowed
            self._warned_over = True
            gym.logger.warn(
                "You are calling 'step()' even though this environment has already returned terminated = True "
                "or truncated = True. You should always call 'reset()' once you receive 'terminated = True' or "
                "'truncated = True' -- any further steps are undefined behavior."
            )
        sim = self._sim
        sim.step(action, False)
        reward, terminated, truncated, info = single_outcome(sim, sim.max_steps)
        if terminated or truncated:
            self._episode_over = True
        if self.render_mode == "human":
            self.render()
        return sim.bound.obs0.copy(), reward, terminated, truncated, info

    def set_start_error_scale(self, scale: float) -> None:
        """Scale the starting deviations of the next resets (``start_error_scale``, in [0, 10]) that do not
        pass the ``start_error_scale`` reset option, the autoresets included: a curriculum's knob (e.g. from a
        training callback, ``vec_env.env_method("set_start_error_scale", 0.5)``). ValueError outside [0, 10]."""
        self._sim.set_start_error_scale(scale)

    # --------------------------------------------------------------------------------- access
    @property
    def sim(self) -> BatchSim:
        """The batched simulator behind this env (N = 1): named views of its state (``q``, ``qd``,
        ``qr``, ``qdr``, ``qddr``, ``P``, ``wind``, ``lag``, ``applied``, ...). Read them; do not write."""
        return self._sim

    @property
    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """True (q, qdot) of the plant (copies)."""
        return self._sim.q[0].copy(), self._sim.qd[0].copy()

    @property
    def plant_params(self) -> SoftPVTOLParams:
        """Parameters of the plant in this episode (differ from ``params`` in the mismatch tiers)."""
        return SoftPVTOLParams.from_array(self._sim.P[0])

    # ------------------------------------------------------------------------------ rendering
    def render(self):
        if self.render_mode is None:
            gym.logger.warn(
                "You are calling render method without specifying any render mode. You can specify the "
                'render_mode at initialization, e.g. gym.make("SoftPVTOL-v0", render_mode="rgb_array")'
            )
            return None
        if self._needs_reset:
            raise ResetNeeded("Cannot call env.render() before calling env.reset()")
        if self._renderer is None:
            from .rendering import Renderer

            self._renderer = Renderer(self.config, self.render_mode, self.metadata["render_fps"])
        s = self._sim
        return self._renderer.draw(s.q[0], s.qr[0], s.P[0], s.applied[0], s.t[0])

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None



class PassiveEnvChecker(gym.wrappers.PassiveEnvChecker):
    """gymnasium's PassiveEnvChecker, whose first-call checks wait for the first reset that succeeds. gymnasium's
    marks its first reset as checked before running it: after a refused first reset (a bad seed or option) it
    held no reset data, and the next step failed in it with a TypeError. ``gym.make``'s SoftPVTOL ids wrap the env
    in this one (their registration turns gymnasium's off; the wrapper chain reads as before:
    OrderEnforcing, PassiveEnvChecker, the env). A step before a successful reset raises ``ResetNeeded``."""

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if not self.checked_reset:  # refused here, before the first-call flag is set
            self.env.unwrapped.check_reset_arguments(seed, options)
        return super().reset(seed=seed, options=options)

    def step(self, action):
        if not self.checked_reset:  # no successful reset yet: the env raises ResetNeeded
            return self.env.step(action)
        return super().step(action)

    @property
    def spec(self):
        """The env's spec as registered (the checker is part of the entry point, not gym.make's)."""
        return self.env.spec


def checked_env(**kwargs) -> PassiveEnvChecker:
    """The entry point of ``gym.make("SoftPVTOL-v0")``: the env in :class:`PassiveEnvChecker`."""
    return PassiveEnvChecker(SoftPVTOLEnv(**kwargs))


checked_env.metadata = SoftPVTOLEnv.metadata  # gym.make reads the render modes here (rgb_array_list, human)
