"""Analytic policies with the stable-baselines3 ``predict`` interface."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from . import model as MK
from ._batching import MAX_CURVATURE
from ._parallel import row_ranges, run_split
from .control import PassivityController
from .control import _extended_kernels as EK
from .control import _kernels as CK
from .control.closed_loop import LOOPS, MAX_HELD_CONTROL_PERIOD
from .control.extended import ExtendedController, ExtendedGains
from .control.passivity import PassivityGains
from .dynamics import input_map_code
from .envs._validation import real_array, short_repr
from .envs.config import EnvConfig
from .envs.observation import OBS_DIM, OBS_NAMES

__all__ = ["PassivityPolicy", "ExtendedPolicy"]

_jit = njit(cache=True, fastmath=False, nogil=True, error_model="numpy")

_F64 = np.dtype(np.float64)
#: kernel codes of the action the policy returns
ACTION_ACTUATORS, ACTION_VIRTUAL = 0, 1


@_jit
def _clip1(x):
    if x < -1.0:
        return -1.0
    if x > 1.0:
        return 1.0
    return x


@_jit
def policy_rows(lo, hi, obs, theta, kind, scale, offset, tmax, taumax, cc, S, S_new, X, ctl, out, err):
    """Rows lo .. hi - 1 of :meth:`PassivityPolicy.predict` for the actuated loops: the controller's
    inputs from the observation (the state of :meth:`PassivityPolicy.state_from_observation`, theta
    given) into X, the controller block driver (outputs into ctl, new memory into S_new), and the
    scaled, clipped action into out."""
    for n in range(lo, hi):
        th = theta[n]
        q = (obs[n, 0], obs[n, 1], th, obs[n, 5], obs[n, 6])
        qr = (0.0, 0.0, th - obs[n, 2], 0.0, 0.0)
        qdr = (obs[n, 12], obs[n, 13], obs[n, 14], 0.0, 0.0)
        qddr = (obs[n, 15], obs[n, 16], obs[n, 17], 0.0, 0.0)
        for i in range(5):
            X[n, CK.IN_Q + i] = q[i]
            X[n, CK.IN_QD + i] = obs[n, 7 + i]
            X[n, CK.IN_QR + i] = qr[i]
            X[n, CK.IN_QDR + i] = qdr[i]
            X[n, CK.IN_QDDR + i] = qddr[i]
            X[n, CK.IN_RES + i] = 0.0
    CK.controller_rows(lo, hi, X, False, True, cc, S, S_new, ctl, err)
    for n in range(lo, hi):
        if kind == ACTION_VIRTUAL:
            for i in range(5):
                out[n, i] = _clip1((ctl[n, CK.OUT_TAU + i] - offset[i]) / scale[i])
        else:
            out[n, 0] = _clip1(2.0 * ctl[n, CK.OUT_ACT] / tmax - 1.0)
            out[n, 1] = _clip1(2.0 * ctl[n, CK.OUT_ACT + 1] / tmax - 1.0)
            out[n, 2] = _clip1(ctl[n, CK.OUT_ACT + 2] / taumax)
            out[n, 3] = _clip1(ctl[n, CK.OUT_ACT + 3] / taumax)


@njit(cache=True, nogil=True)
def policy_step(lo, hi, obs, theta, kind, scale, offset, tmax, taumax, cc, S, S_new, X, ctl, out, err):
    """:func:`policy_rows`; returns the number of rows lo .. hi - 1 with an error code."""
    policy_rows(lo, hi, obs, theta, kind, scale, offset, tmax, taumax, cc, S, S_new, X, ctl, out, err)
    bad = 0
    for n in range(lo, hi):
        if err[n] != 0:
            bad += 1
    return bad


@njit(cache=True, nogil=True)
def _observations_ok(obs, qmax):
    """True if every entry of obs (N, 18) is finite and |q_l|, |q_r| (columns 5, 6) <= qmax (one
    compiled pass: cheaper than the ufunc calls for the single observations of an evaluation loop)."""
    for n in range(obs.shape[0]):
        for k in range(obs.shape[1]):
            if not math.isfinite(obs[n, k]):
                return False
        if not (abs(obs[n, 5]) <= qmax and abs(obs[n, 6]) <= qmax):
            return False
    return True


def _check_observation(obs: np.ndarray) -> None:
    """Observations (N, 18) the controller can act on: finite, arm curvatures inside the model's
    validity (the controller's series are accurate up to 2 pi; the env ends an episode beyond pi)."""
    if _observations_ok(obs, MAX_CURVATURE):
        return
    if not np.isfinite(obs).all():
        rows, cols = np.nonzero(~np.isfinite(obs))
        raise ValueError(f"observation must be finite, got {obs[rows[0], cols[0]]} at "
                         f"{'index ' + str(cols[0]) if obs.shape[0] == 1 else f'[{rows[0]}, {cols[0]}]'} "
                         f"({OBS_NAMES[cols[0]]})")
    arms = obs[:, 5:7]
    bad = ~(np.abs(arms) <= MAX_CURVATURE)
    if bad.any():
        rows, cols = np.nonzero(bad)
        r, c = rows[0], cols[0] + 5
        raise ValueError(
            f"observation {'index ' + str(c) if obs.shape[0] == 1 else f'[{r}, {c}]'} ({OBS_NAMES[c]}) = "
            f"{float(obs[r, c])!r} is outside the model's validity: the controller needs arm curvatures "
            f"|q_l|, |q_r| <= 2 pi (the model holds for |q| <= pi; the env ends an episode beyond pi as "
            f"'curvature_limit', and clips observations at +-1e6 only after a divergence); act on observations "
            f"of running episodes"
        )


def policy_observations(observation, dim: int) -> tuple[np.ndarray, bool]:
    """(obs (N, 18) float64, single) of the analytic policies' ``predict``: ``observation`` (dim,) or (N,
    dim) of the policy's env (dim 18, or 21 with its ``observe_error_integral``: the controllers read
    entries 0-17), checked (real numbers, the shape, finite, arm curvatures inside the model's validity);
    a ValueError naming what was received otherwise."""
    obs = observation
    if type(obs) is np.ndarray and obs.dtype.kind == "f":  # the common case (float32 from the env)
        if not (obs.dtype is _F64 and obs.flags.c_contiguous and obs.flags.writeable):
            obs = obs.astype(_F64)  # (a C-contiguous copy)
    else:
        obs = real_array("observation", observation, f"an array of shape ({dim},) or (N, {dim})")
    single = obs.ndim == 1
    if obs.ndim not in (1, 2) or obs.shape[-1] != dim or obs.shape[0] == 0:
        raise ValueError(f"observation must have shape ({dim},) or (N, {dim}) with N >= 1 (the observation of "
                         f"the policy's env), got shape {obs.shape}")
    obs = obs.reshape(-1, dim)
    if dim != OBS_DIM:  # the controllers read entries 0-17; the error integrals are the env's, not their memory
        obs = np.ascontiguousarray(obs[:, :OBS_DIM])
    _check_observation(obs)
    return obs, single


def _episode_start_mask(episode_start, n: int) -> np.ndarray:
    """``episode_start`` as a bool mask of n entries: a bool (or 0/1) scalar, or N of them."""
    a = np.asarray(episode_start)
    if a.dtype.kind not in "biuf" or a.size not in (1, n) or (a.dtype.kind != "b" and not np.isin(a, (0, 1)).all()):
        raise ValueError(f"episode_start must be None, a bool or a bool array of {n} entries (one per "
                         f"observation), got {short_repr(episode_start)}"
                         + (f" with {a.size} entries" if a.dtype.kind in "biuf" and a.size not in (1, n) else ""))
    mask = a.astype(bool).reshape(-1)
    return np.repeat(mask, n) if mask.size == 1 and n > 1 else mask


def env_config(env) -> EnvConfig:
    """The :class:`EnvConfig` of a SoftPVTOLEnv / SoftPVTOLVectorEnv (wrapped or not) or the SB3 adapter
    (what the policies' ``from_env`` build from); ValueError for anything else."""
    cfg = getattr(env, "config", None)
    if cfg is None and hasattr(env, "unwrapped"):
        cfg = getattr(env.unwrapped, "config", None)
    if cfg is None and hasattr(env, "venv"):
        cfg = getattr(env.venv, "config", None)
    if cfg is None and hasattr(env, "get_wrapper_attr"):
        cfg = env.get_wrapper_attr("config")
    if not isinstance(cfg, EnvConfig):
        raise ValueError(f"env must be a SoftPVTOLEnv / SoftPVTOLVectorEnv (wrapped or not) or the SB3 adapter: "
                         f"cannot find a SoftPVTOL EnvConfig on {short_repr(env)}")
    return cfg


def actuator_action(actuators: np.ndarray, thrust_max: float, arm_torque_max: float) -> np.ndarray:
    """The env's normalised action (unclipped) of actuators (..., 4) = (T_l, T_r, tau_l, tau_r):
    thrusts [0, T_max] -> [-1, 1] (2 T / T_max - 1), arm torques [-tau_max, tau_max] -> [-1, 1]
    (the compiled path of :class:`PassivityPolicy` writes the same formula in its kernel)."""
    a = np.asarray(actuators, dtype=np.float64)
    u = np.empty(a.shape)
    u[..., 0:2] = 2.0 * a[..., 0:2] / thrust_max - 1.0
    u[..., 2:4] = a[..., 2:4] / arm_torque_max
    return u


class _OneObservationPath:
    """What PassivityPolicy and ExtendedPolicy share for their one-observation path: the buffers
    (:class:`_OneObservation`), built at first use and left out of a copy (they hold views of themselves, which a
    copy would turn into independent arrays)."""

    _one = None

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_one": None}

    def _load_one(self, observation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_OneObservation.load` of the policy's buffers."""
        if self._one is None:
            self._one = _OneObservation()
        return self._one.load(observation)


class PassivityPolicy(_OneObservationPath):
    """The paper's passivity controller acting from SoftPVTOL observations only.

    ``predict(observation, state=None, episode_start=None, deterministic=True) -> (action, state)``
    like a stable-baselines3 policy, for single (18,) or batched (N, 18) observations, returning the
    action in the env's normalised action space:

    * ``"actuators"``: the allocated actuators (T_l, T_r, tau_l, tau_r) scaled to [-1, 1] and clipped;
    * ``"virtual"``: the controller's generalized force tau scaled (ideal loop for allocation "ideal");
    * ``"residual"``: zeros (the env's base controller is this controller).

    From the observation it rebuilds q = (e_x, e_z, theta, q_l, q_r) with theta = atan2(sin, cos),
    the reference (0, 0, theta - e_theta), qdot, and the reference velocity/acceleration; the
    controller needs nothing else (D, C, g depend on the curvatures only, the allocation on theta).
    The controller keeps memory (allocation warm start, arm-reference history) per batch entry; it is
    reset where ``episode_start`` is True (and entirely when the batch size changes).

    Args:
        config: the env's :class:`EnvConfig` (use :meth:`from_env`).
        loop: PassivityController loop (:data:`~softpvtol_gym.control.LOOPS`: "bounded", "integral",
            "improved", "exact", "paper", "ideal"); default: the env's ``controller_loop``, or from its allocation
            ("exact" -> "bounded", "paper" -> "paper", "ideal" -> "ideal"), the loop of the residual
            mode's base controller.
        gains: :class:`PassivityGains`.
        controller_options: further :class:`~softpvtol_gym.control.PassivityController` arguments that
            override the loop's settings, e.g. ``{"integral_gains": (0.1, 0.1, 0.0)}`` (an unknown
            option is a ValueError listing the valid ones).
    """

    def __init__(self, config: EnvConfig, loop: str | None = None, gains: PassivityGains | None = None,
                 controller_options: dict | None = None):
        if not isinstance(config, EnvConfig):
            raise ValueError(f"config must be an EnvConfig, got {short_repr(config)} of type {type(config).__name__} "
                             "(build the policy with PassivityPolicy.from_env(env))")
        if gains is not None and not isinstance(gains, PassivityGains):
            raise ValueError(f"gains must be a PassivityGains or None, got {short_repr(gains)} of type "
                             f"{type(gains).__name__}")
        if loop is not None and (not isinstance(loop, str) or loop not in LOOPS):
            raise ValueError(f"loop must be one of {sorted(LOOPS)} or None (from the env's allocation), got "
                             f"{short_repr(loop)}")
        self.config = config
        self.loop = config.resolved_controller_loop if loop is None else loop
        if "controller" in LOOPS[self.loop]:
            raise ValueError(f"loop={self.loop!r} is not a passivity loop: build its policy with "
                             f"PassivityPolicy.from_env(env, loop={self.loop!r}) or ExtendedPolicy(config)")
        default_gains = gains is None or gains == PassivityGains()
        if self.loop != "ideal" and default_gains and config.dt > MAX_HELD_CONTROL_PERIOD:
            raise ValueError(
                f"the analytic controller with the default gains diverges when its command is held longer than "
                f"{MAX_HELD_CONTROL_PERIOD} s (the arm loop's K/D ~ 130 1/s), got a control period of "
                f"{config.dt:g} s (frame_skip={config.frame_skip}); use frame_skip=1, or pass gains with smaller "
                "arm gains k[3:5] (the limit scales roughly with 1/k)")
        if config.action_mode == "virtual" and config.resolved_allocation == "ideal" and self.loop != "ideal":
            raise ValueError("with allocation='ideal' the policy must use loop='ideal'")
        if self.loop == "ideal" and config.action_mode != "virtual":
            valid = sorted(k for k in LOOPS if k != "ideal")
            raise ValueError(
                f"loop='ideal' is not valid for action_mode={config.action_mode!r}: the ideal loop outputs the "
                f"generalized force tau with no allocation to thrusts and arm torques, which only "
                f"action_mode='virtual' takes; valid loops for action_mode={config.action_mode!r}: {valid}")
        options = dict(controller_options or {})
        fixed = sorted({"params", "gains", "input_map", "dt"} & set(options))
        if fixed:
            raise ValueError(f"controller_options cannot set {fixed}: they come from the env's config (params, "
                             "input_map, dt) and the gains argument")
        self.controller = PassivityController.from_loop(
            self.loop, params=config.params, gains=gains, input_map=config.input_map, dt=config.dt, **options
        )
        self._n: int | None = None
        self._work = None  # the controller driver's inputs, outputs and error codes for a batch of n
        self._scale = config.virtual_scale
        self._offset = config.virtual_offset
        self._tmax = config.thrust_max
        self._taumax = config.arm_torque_max
        self._kind = ACTION_VIRTUAL if config.action_mode == "virtual" else ACTION_ACTUATORS
        self._action_dim = config.action_dim
        # predict's path for one observation (_predict_one): the actuated loops' compiled pass
        self._compiled = (config.action_mode != "residual" and self.controller.allocation != "ideal"
                          and config.obs_dim == OBS_DIM)

    @classmethod
    def from_env(cls, env, loop: str | None = None, gains: PassivityGains | None = None,
                 controller_options: dict | None = None) -> PassivityPolicy:
        """Policy for a SoftPVTOLEnv / SoftPVTOLVectorEnv (wrapped or not) or the SB3 adapter."""
        cfg = env_config(env)
        if (loop if loop is not None else cfg.resolved_controller_loop) == "extended":
            if controller_options:
                raise ValueError("controller_options are PassivityController options; the extended loop takes "
                                 "ExtendedPolicy(config, gains=ExtendedGains(...))")
            return ExtendedPolicy(cfg, gains=gains)  # the sibling controller (control/extended.py)
        return cls(cfg, loop=loop, gains=gains, controller_options=controller_options)

    def reset(self) -> None:
        self.controller.reset()
        self._n = None

    @staticmethod
    def state_from_observation(obs: np.ndarray) -> tuple[np.ndarray, ...]:
        """(q, qdot, q_ref, qdot_ref, qddot_ref), each (N, 5), from observations (N, 18)."""
        obs = np.asarray(obs, dtype=np.float64)
        n = obs.shape[0]
        theta = np.arctan2(obs[:, 3], obs[:, 4])
        q = np.zeros((n, 5))
        q[:, 0], q[:, 1], q[:, 2], q[:, 3], q[:, 4] = obs[:, 0], obs[:, 1], theta, obs[:, 5], obs[:, 6]
        q_ref = np.zeros((n, 5))
        q_ref[:, 2] = theta - obs[:, 2]
        qd = obs[:, 7:12].copy()
        qdr = np.zeros((n, 5))
        qdr[:, :3] = obs[:, 12:15]
        qddr = np.zeros((n, 5))
        qddr[:, :3] = obs[:, 15:18]
        return q, qd, q_ref, qdr, qddr

    def _predict_compiled(self, obs: np.ndarray, n: int) -> np.ndarray:
        """The actuated loops: one compiled pass from observations to actions (same values as the
        controller called on :meth:`state_from_observation`, then scaled and clipped)."""
        obs = np.ascontiguousarray(obs)
        theta = np.arctan2(obs[:, 3], obs[:, 4])  # numpy's arctan2, as state_from_observation
        ctrl = self.controller
        S, S_new = ctrl.memory_pair(n)
        if self._work is None or self._work[0].shape[0] != n:  # (per batch size: inputs, outputs, errors, ranges)
            self._work = (np.empty((n, CK.IN_LEN)), np.empty((n, CK.OUT_LEN)), np.zeros(n, dtype=np.int64),
                          row_ranges(n))
        X, ctl, err, ranges = self._work
        out = np.empty((n, self._action_dim), dtype=np.float32)
        args = (obs, theta, self._kind, self._scale, self._offset, self._tmax, self._taumax, ctrl.kernel_constants,
                S, S_new, X, ctl, out, err)
        if len(ranges) == 1:
            bad = policy_step(0, n, *args)
        else:
            bad = 0
            run_split(lambda lo, hi: policy_step(lo, hi, *args), ranges)
        if bad or (len(ranges) > 1 and err.any()):  # nothing changed: the new memory is not swapped in
            ctrl.raise_for(err, self.state_from_observation(obs)[0])
        ctrl.swap_memory()
        return out

    def _predict_one(self, observation) -> np.ndarray:
        """:meth:`predict` of one float observation (18,) for the actuated loops, the batch size staying 1, no
        episode start: the same kernel on the same values with less around it (an evaluation loop's case)."""
        buf, theta = self._load_one(observation)
        ctrl = self.controller
        S, S_new = ctrl._state, ctrl._spare
        if S is None or S_new is None or S.shape[0] != 1:  # (the controller was reset: memory_pair's checks)
            S, S_new = ctrl.memory_pair(1)
        X, ctl, err, _ = self._work
        out = np.empty((1, self._action_dim), dtype=np.float32)
        if policy_step(0, 1, buf, theta, self._kind, self._scale, self._offset, self._tmax, self._taumax,
                       ctrl.kernel_constants, S, S_new, X, ctl, out, err):
            ctrl.raise_for(err, self.state_from_observation(buf)[0])
        ctrl.swap_memory()
        return out[0]

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        """(action, state) for observations (18,) or (N, 18) of the env (21 entries with the env's
        ``observe_error_integral``: the policy reads entries 0-17); ``episode_start``: None, a bool
        or a bool array of N entries (the entries whose controller memory is reset). Observations must be
        finite and inside the model's validity (arm curvatures |q_l|, |q_r| <= 2 pi); ValueError otherwise."""
        if episode_start is None and self._n == 1 and self._compiled and _is_one_observation(observation):
            return self._predict_one(observation), state
        obs, single = policy_observations(observation, self.config.obs_dim)
        n = obs.shape[0]
        mask = None if episode_start is None else _episode_start_mask(episode_start, n)
        if self._n != n:
            self.controller.reset()
            self._n = n
        elif mask is not None:
            if mask.all():
                self.controller.reset(np.ones(n, dtype=bool))
            elif mask.any():
                self.controller.reset(mask)
        cfg = self.config
        if cfg.action_mode == "residual":
            action = np.zeros((n, cfg.action_dim), dtype=np.float32)
        elif self.controller.allocation != "ideal":
            action = self._predict_compiled(obs, n)
        else:
            out = self.controller(*self.state_from_observation(obs))
            if cfg.action_mode == "virtual":
                u = (out.tau - self._offset) / self._scale
            else:
                u = actuator_action(out.actuators, self._tmax, self._taumax)
            action = np.clip(u, -1.0, 1.0).astype(np.float32)
        return (action[0] if single else action), state


#: the shape of one observation that PassivityPolicy.predict takes its short path for
_ONE_OBS = (OBS_DIM,)


def _is_one_observation(observation) -> bool:
    """Whether the policies' one-observation path takes ``observation``: a float array of shape (18,)."""
    return type(observation) is np.ndarray and observation.shape == _ONE_OBS and observation.dtype.kind == "f"


class _OneObservation:
    """The policies' buffers for one observation (the path of an evaluation loop): the observation (1, 18)
    float64, its sin and cos columns (views) and theta (1,). Not copied with a policy (it holds views of
    itself): the policies leave it out of their pickled state and build it again at first use."""

    __slots__ = ("obs", "sin", "cos", "theta")

    def __init__(self):
        self.obs = np.empty((1, OBS_DIM))
        self.sin, self.cos, self.theta = self.obs[:, 3], self.obs[:, 4], np.empty(1)

    def load(self, observation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(obs (1, 18), theta (1,)) of a float observation (18,): copied, checked as policy_observations
        checks it, theta by numpy's arctan2 as state_from_observation (the same values as the general path)."""
        obs = self.obs
        obs[0] = observation
        if not _observations_ok(obs, MAX_CURVATURE):
            _check_observation(obs)
        np.arctan2(self.sin, self.cos, out=self.theta)
        return obs, self.theta


#: observations of the reference acceleration the extended policy fits a cubic to (its jerk and snap)
REF_HISTORY = 8


def _cubic_fit_weights(n: int, dt: float) -> np.ndarray:
    """Weights (4, n) that give, from samples a(-i dt) (i = 0 .. n-1), the first and second derivative of
    their least-squares cubic at t = 0 (rows 0, 1) and t = dt / 2 (rows 2, 3)."""
    tau = -np.arange(n) * dt
    V = np.vander(tau, 4, increasing=True)  # columns 1, t, t^2, t^3
    P = np.linalg.pinv(V)  # coefficients = P @ samples
    rows = []
    for t in (0.0, 0.5 * dt):
        rows.append(np.array([0.0, 1.0, 2.0 * t, 3.0 * t * t]) @ P)
        rows.append(np.array([0.0, 0.0, 2.0, 6.0 * t]) @ P)
    return np.array(rows)


class ExtendedPolicy(_OneObservationPath):
    """The dynamically extended loop (:class:`~softpvtol_gym.control.extended.ExtendedController`) acting
    from SoftPVTOL observations, with :class:`PassivityPolicy`'s ``predict`` interface
    (``PassivityPolicy.from_env(env, loop="extended")`` builds it).

    Actuators mode only: the action is the controller's (T_l, T_r, tau_l, tau_r) scaled to [-1, 1] and
    clipped (the env saturates at its limits; the controller's extension (T, Tdot) keeps its own value,
    there is no anti-windup). The state is rebuilt from the observation as in
    :meth:`PassivityPolicy.state_from_observation`; the observation carries the reference's velocity and
    acceleration only, so its third and fourth derivatives, at the step's start and midpoint (the held
    command is the law's at the predicted midpoint, ``ExtendedController.held_step``), are those of a
    least-squares cubic through the last ``REF_HISTORY`` = 8 observed reference accelerations (zero until
    8 observations of the episode exist), unlike ``simulate_closed_loop("extended")``, which takes them
    exactly. Memory (the extension and that history) per batch entry, reset where
    ``episode_start`` is True and entirely when the batch size changes.

    Args:
        config: the env's :class:`EnvConfig` (use :meth:`PassivityPolicy.from_env`).
        gains: :class:`~softpvtol_gym.control.extended.ExtendedGains`.
    """

    loop = "extended"

    def __init__(self, config: EnvConfig, gains: ExtendedGains | None = None):
        if not isinstance(config, EnvConfig):
            raise ValueError(f"config must be an EnvConfig, got {short_repr(config)} of type {type(config).__name__} "
                             "(build the policy with PassivityPolicy.from_env(env, loop='extended'))")
        if gains is not None and not isinstance(gains, ExtendedGains):
            raise ValueError(f"gains must be an ExtendedGains or None for the extended loop, got {short_repr(gains)} "
                             f"of type {type(gains).__name__}")
        if config.action_mode != "actuators":
            raise ValueError(f"the extended loop's policy acts in action_mode='actuators' only (its output is the "
                             f"actuators), got action_mode={config.action_mode!r}")
        self.config = config
        self.controller = ExtendedController(config.params, gains, input_map=config.input_map, dt=config.dt)
        self._n: int | None = None
        self._acc_hist: np.ndarray | None = None  # (n, REF_HISTORY, 3): the last observed reference accelerations
        self._hist_len: np.ndarray | None = None
        self._weights = _cubic_fit_weights(REF_HISTORY, config.dt)
        self._tmax = config.thrust_max
        self._taumax = config.arm_torque_max
        # the compiled pass's inputs (control._extended_kernels)
        self._p = config.params.array
        self._map_code = input_map_code(config.input_map)
        self._constants = EK.extended_constants(self.controller, self._tmax, self._taumax)
        self._work = None

    def reset(self) -> None:
        self.controller.reset()
        self._n = None

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        """(action, state) for observations (18,) or (N, 18) (21 with ``observe_error_integral``: entries
        0-17 are read); ``episode_start``: None, a bool or N bools
        (the entries whose memory is reset). ValueError for observations that are not finite or outside
        the model's validity. One compiled pass (:mod:`softpvtol_gym.control._extended_kernels`);
        :meth:`predict_reference` is the same policy in numpy, the readable reference it is tested against."""
        if (episode_start is None and self._n == 1 and self.config.obs_dim == OBS_DIM
                and _is_one_observation(observation)):
            # one float observation, the batch size staying 1, no episode start (an evaluation loop's case)
            obs, theta = self._load_one(observation)
            single, n = True, 1
        else:
            obs, single, n = self._prepare(observation, episode_start)
            obs = np.ascontiguousarray(obs)
            theta = np.arctan2(obs[:, 3], obs[:, 4])  # numpy's arctan2, as state_from_observation
        ctrl = self.controller
        if ctrl._xi is None:
            ctrl._xi = np.full((n, 2), np.nan)
        if self._work is None or self._work[0].shape[0] != n:  # (per batch size: errors, thread ranges)
            self._work = (np.zeros(n, dtype=np.int64), row_ranges(n))
        err, ranges = self._work
        out = np.empty((n, 4), dtype=np.float32)
        args = (obs, theta, self._acc_hist, self._hist_len, ctrl._xi, self._weights, self._p, self._map_code,
                self._constants, ctrl.held_command == "midpoint", out, err)
        if n >= MK.LANES:  # the midpoint predictions of full lane blocks as SIMD code (compiled for such batches)
            args += (1,)
        if len(ranges) == 1:
            bad = EK.extended_policy_rows(0, n, *args)
        else:
            bad = 0
            run_split(lambda lo, hi: EK.extended_policy_rows(lo, hi, *args), ranges)
        if bad or (len(ranges) > 1 and err.any()):  # pragma: no cover (the law safeguards its divisions)
            raise ValueError(f"the extended loop produced non-finite actuators in rows {np.flatnonzero(err).tolist()}; "
                             "their extension is kept, reset the policy")
        return (out[0] if single else out), state

    def _prepare(self, observation, episode_start):
        """The checked observations (N, 18), whether one was given, N; the memory sized for N and reset
        where ``episode_start``."""
        obs, single = policy_observations(observation, self.config.obs_dim)
        n = obs.shape[0]
        mask = None if episode_start is None else _episode_start_mask(episode_start, n)
        if self._n != n:
            self.controller.reset()
            self._n = n
            self._acc_hist = np.zeros((n, REF_HISTORY, 3))
            self._hist_len = np.zeros(n, dtype=np.int64)
        elif mask is not None and mask.any():
            self.controller.reset(mask)
            self._hist_len[mask] = 0
        return obs, single, n

    def predict_reference(self, observation, state=None, episode_start=None, deterministic: bool = True):
        """:meth:`predict` in numpy through :class:`ExtendedController` (the readable reference; the same
        memory): the same actions to round-off."""
        obs, single, n = self._prepare(observation, episode_start)
        q, qd, q_ref, qdr, qddr = PassivityPolicy.state_from_observation(obs)
        hist, k = self._acc_hist, self._hist_len
        hist[:, 1:] = hist[:, :-1].copy()
        hist[:, 0] = qddr[:, :3]  # hist[:, i]: the reference acceleration i steps ago
        np.minimum(k + 1, REF_HISTORY, out=k)
        jet = np.zeros((5, n, 5))
        jet[0], jet[1], jet[2] = q_ref, qdr, qddr
        mid = jet.copy()
        full = k == REF_HISTORY
        if full.any():  # the fitted cubic's derivatives at the step's start and midpoint
            w = self._weights
            for row, (c3, c4) in ((jet, (w[0], w[1])), (mid, (w[2], w[3]))):
                row[3][full, :3] = np.einsum("i,nic->nc", c3, hist[full])
                row[4][full, :3] = np.einsum("i,nic->nc", c4, hist[full])
        m = 0.5 * self.controller.dt
        mid[0] = jet[0] + m * jet[1] + m * m / 2 * jet[2] + m**3 / 6 * jet[3] + m**4 / 24 * jet[4]
        mid[1] = jet[1] + m * jet[2] + m * m / 2 * jet[3] + m**3 / 6 * jet[4]
        mid[2] = jet[2] + m * jet[3] + m * m / 2 * jet[4]
        out = self.controller(q, qd, q_ref, qdr, qddr, jet[3], jet[4], ref_mid=mid)
        a = out.actuators
        u = np.empty((n, 4))
        u[:, 0:2] = 2.0 * a[:, 0:2] / self._tmax - 1.0
        u[:, 2:4] = a[:, 2:4] / self._taumax
        if not np.isfinite(u).all():  # pragma: no cover (the law safeguards its divisions)
            raise ValueError("the extended loop produced non-finite actuators; its memory is kept, reset it")
        action = np.clip(u, -1.0, 1.0).astype(np.float32)
        return (action[0] if single else action), state
