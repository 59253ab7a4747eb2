"""PassivityPolicy: the paper's passivity controller acting from observations, with the
stable-baselines3 ``predict`` interface."""

from __future__ import annotations

import numpy as np
from numba import njit

from .._parallel import row_ranges, run_split
from .._validation import short_repr
from ..control import PassivityController
from ..control import kernels as CK
from ..control.closed_loop import LOOPS, MAX_HELD_CONTROL_PERIOD
from ..control.passivity import PassivityGains
from ..envs.actions import actuator_action
from ..envs.config import EnvConfig
from ..envs.observation import OBS_DIM
from ._common import (
    _episode_start_mask,
    _is_one_observation,
    _OneObservationPath,
    env_config,
    policy_observations,
    state_from_observation,
)
from .extended import ExtendedPolicy

__all__ = ["PassivityPolicy"]

_jit = njit(cache=True, fastmath=False, nogil=True, error_model="numpy")

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

    state_from_observation = staticmethod(state_from_observation)
    """(q, qdot, q_ref, qdot_ref, qddot_ref), each (N, 5), from observations (N, 18)."""

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

    def unclipped_actions(self) -> np.ndarray:
        """The actuators (N, 4) the last :meth:`predict` commanded (an actuated loop on the actuators mode), as
        normalised actions before the clip to [-1, 1]: the base command to which the residual mode adds its
        correction (the env saturates the sum, not the base)."""
        if self._work is None or self._n is None or self._kind != ACTION_ACTUATORS or \
                self.controller.allocation == "ideal" or self.config.action_mode != "actuators":
            raise ValueError("unclipped_actions() reads the last prediction of an actuated loop on "
                             "action_mode='actuators': call predict first, on such a policy")
        return actuator_action(self._work[1][:self._n, CK.OUT_ACT:CK.OUT_ACT + 4], self._tmax, self._taumax)

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
