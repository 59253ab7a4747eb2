"""ExtendedPolicy: the dynamically extended loop acting from observations, with the stable-baselines3
``predict`` interface."""

from __future__ import annotations

import numpy as np

from .. import model as MK
from .._parallel import row_ranges, run_split
from .._validation import short_repr
from ..control import extended_kernels as EK
from ..control.extended import ExtendedController, ExtendedGains
from ..dynamics import input_map_code
from ..envs.config import EnvConfig
from ..envs.observation import OBS_DIM
from ._common import (
    _episode_start_mask,
    _is_one_observation,
    _OneObservationPath,
    policy_observations,
    state_from_observation,
)

__all__ = ["ExtendedPolicy"]

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
        # the compiled pass's inputs (control.extended_kernels)
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
        the model's validity. One compiled pass (:mod:`softpvtol_gym.control.extended_kernels`);
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
        q, qd, q_ref, qdr, qddr = state_from_observation(obs)
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
