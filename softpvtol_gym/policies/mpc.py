"""MPCPolicy: the nonlinear MPC with the stable-baselines3 ``predict`` interface."""

from __future__ import annotations

import time

import numpy as np

from .._validation import short_repr
from ..control.mpc import ND, NU, NX, MPCOptions, TrackingOCP, hover_input, import_casadi
from ..envs.actions import action_actuators, actuator_action
from ..envs.config import EnvConfig
from ._common import (
    _episode_start_mask,
    env_config,
    policy_observations,
    state_from_observation,
)

#: the units in which the disturbance estimate's update is the least change that explains the velocity residual:
#: 1 N or N m for the generalized forces on (x, z, theta, q_l, q_r), 0.3 for each arm's thrust-bending share (a
#: share moves slower than a force, which also follows the measurement noise). Chosen on the tuning episodes
#: (seeds 3,000,000 + i; benchmarks/mpc_tuning.py): of 40 episodes, 1 crashed with these, 7 with the arms' forces
#: at 0.1 and the shares at 1, 3 with 0.1 and 0.3; 3 of 3 track_paper noisy test-range episodes had crashed
#: without the estimate's shares bounded to [0, 1] (benchmarks/mpc_crash_rates.py, before the tuning range)
DISTURBANCE_SCALES = np.array([1.0, 1.0, 1.0, 1.0, 1.0, 0.3, 0.3])

#: a QP's curvature slack [rad] above which :attr:`MPCPolicy.stats` counts the solve as relaxed
RELAXED_SLACK = 1e-4


class MPCPolicy:
    """Nonlinear model-predictive control of the Soft-PVTOL from its observations (actuators mode).

    ``predict(observation, state=None, episode_start=None, deterministic=True) -> (action, state)`` like
    a stable-baselines3 policy (and :class:`~softpvtol_gym.PassivityPolicy`), for single (18,) or
    batched (N, 18) observations; the action is the env's normalised actuator action (T_l, T_r, tau_l,
    tau_r) in [-1, 1]. Needs CasADi: ``pip install 'softpvtol-gym[mpc]'``.

    **Model.** The paper's model with the env's *nominal* parameters and input map (the MPC knows
    neither a tier's parameter mismatch, nor its wind, noise or actuator lag, nor the consistent plant
    of ``model_gap``), written symbolically in :mod:`softpvtol_gym.control.mpc.symbolic` (checked against
    the package's numeric model to ~1e-12), discretised by RK4 with the input held over each interval.
    ``model_input_map="exact"`` gives the model the virtual-work input map instead (the thrusts' work on
    the curvatures, which the paper's map omits: docs/model.md), the map of ``model_gap``'s consistent
    plant: the MPC then knows how that plant's thrusts bend the arms, which a learned policy only sees
    through its observations. It is not the default: with it a track_paper nominal episode (paper's map
    in the plant) crashed, while with the paper's map every model_gap episode measured crashed
    (benchmarks/README.md).

    **Problem** (:mod:`softpvtol_gym.control.mpc.ocp`): N = ``horizon`` intervals, the first one the env's
    control period, the others ``step`` seconds (defaults: 25 intervals, 0.01 s + 24 x 0.05 s = 1.21 s);
    a least-squares tracking cost on (x, z, theta) and their rates, the arm curvatures and their rates
    (towards straight arms), the input relative to hover and its changes; the env's actuator limits as
    hard input bounds; |q_l|, |q_r| <= ``curvature_limit`` (pi, the env's) at every node as soft bounds
    (a slack per arm and node with an exact L1 penalty: met whenever the linearised problem can meet them;
    when it cannot, the QP still has a solution, the plan that exceeds them least, counted as ``relaxed``
    in :attr:`stats`). Solved by real-time iteration: one Gauss-Newton SQP step per control step (by default PIQP on
    the QP with its stage structure; ``qp_solver`` selects HPIPM on the same QP or a dense solver on the
    condensed QP), with a
    backtracking line search on the nonlinear cost, warm-started from the previous plan shifted by one
    control period (from the hover input instead when the model's rollout under that guess diverges).
    When a solve fails (the QP solver, or a rollout that diverges from hover too), the policy applies the
    previous plan's next input (the fallback) and counts it in :attr:`stats`.

    **Disturbance estimate** (offset-free): each entry keeps d, a generalized force on (x, z, theta,
    q_l, q_r) added to the model over the horizon, and the share of each rotor's thrust that bends its arm
    (in [0, 1]: 0 is the paper's input map, 1 the exact map's thrust work on the curvature, which
    ``model_gap``'s consistent plant has): a force that grows with the thrust, so that the plan knows that
    more thrust bends the arm more. After each control step the velocities the model predicted (from the
    last state, the applied input and d) are compared with the measured ones, and d moves by
    ``disturbance_gain`` times the least change (in the units of ``DISTURBANCE_SCALES``) that explains the
    difference (:attr:`disturbance`).

    **Reference over the horizon: extrapolated from the observation** (no preview of the task): the
    observation holds the position error, the reference attitude (theta - e_theta) and the reference's
    velocity and acceleration now; the reference over the horizon is their Taylor extrapolation,
    p_ref(t + s) = p_ref(t) + v s + a s^2 / 2 + j s^3 / 6, with the jerk j estimated by differencing the
    reference accelerations of consecutive observations of the same episode (zero at an episode's first
    step; ``jerk_extrapolation=False``: constant acceleration). A learned policy sees the same
    observations, so the comparison gives the MPC no information the learned policies lack, besides the
    model itself.

    Memory per batch entry: the plan (warm start), the input applied last, the last state and reference
    acceleration, the disturbance estimate and its own QP solver instance (a solver's memory, such as
    qpOASES's hot start, never crosses from one entry to another: an episode's actions are the same
    alone and in a batch); it is reset where ``episode_start`` is True (and entirely when the batch
    size changes).

    Args:
        config: the env's :class:`EnvConfig` (use :meth:`from_env`); ``action_mode`` must be "actuators".
        options: :class:`~softpvtol_gym.control.mpc.MPCOptions` or its fields as keywords (unknown names:
            ValueError listing the valid ones).
    """

    def __init__(self, config: EnvConfig, options: MPCOptions | None = None, **kwargs):
        import_casadi()
        if not isinstance(config, EnvConfig):
            raise ValueError(f"config must be an EnvConfig, got {short_repr(config)} of type {type(config).__name__} "
                             "(build the policy with MPCPolicy.from_env(env, **options))")
        if options is not None and not isinstance(options, MPCOptions):
            raise ValueError(f"options must be an MPCOptions or None, got {short_repr(options)} of type "
                             f"{type(options).__name__}")
        if options is not None and kwargs:
            raise ValueError(f"pass either options=MPCOptions(...) or option keywords, not both (got {sorted(kwargs)})")
        options = options if options is not None else MPCOptions.from_kwargs(**kwargs)
        if config.action_mode != "actuators":
            raise ValueError(f"MPCPolicy acts in action_mode='actuators' (it plans the thrusts and arm torques "
                             f"directly), got an env with action_mode={config.action_mode!r}; build the env with "
                             "action_mode='actuators'")
        check_limits(config)
        self.config = config
        self.options = options
        input_map = options.model_input_map if options.model_input_map is not None else config.input_map
        self.ocp = TrackingOCP(config.params, input_map, config.thrust_max, config.arm_torque_max,
                               config.dt, options)
        self._n: int | None = None
        self._plans = self._applied = self._last_ref_acc = self._last_state = self._disturbance = None
        self._qps: list = []
        #: seconds per solve (one entry per batch entry and control step), since the last :meth:`reset_stats`
        self.solve_times: list[float] = []
        self._solves = 0
        self._failures = 0
        self._relaxed = 0

    @classmethod
    def from_env(cls, env, **options) -> MPCPolicy:
        """Policy for a SoftPVTOLEnv / SoftPVTOLVectorEnv (wrapped or not) or the SB3 adapter, with
        :class:`~softpvtol_gym.control.mpc.MPCOptions` fields as keywords."""
        import_casadi()
        return cls(env_config(env), **options)

    # ------------------------------------------------------------------------------------- memory
    def reset(self) -> None:
        """Forget every batch entry's plan (the statistics stay: :meth:`reset_stats`)."""
        self._n = None

    def reset_stats(self) -> None:
        self.solve_times = []
        self._solves = 0
        self._failures = 0
        self._relaxed = 0

    def _reset_entries(self, mask: np.ndarray) -> None:
        self._plans[mask] = self.ocp.u_hover
        self._applied[mask] = self.ocp.u_hover
        self._last_ref_acc[mask] = np.nan
        self._last_state[mask] = np.nan
        self._disturbance[mask] = 0.0
        for i in np.flatnonzero(mask):
            self._qps[i] = None  # a new QP solver instance at the entry's next solve: no memory of the last episode

    @property
    def disturbance(self) -> np.ndarray | None:
        """The disturbance estimate of each batch entry, (N, 7): the generalized forces on (x, z, theta, q_l,
        q_r) [N, N, N m, N m, N m] and the share of each rotor's thrust that bends its arm (left, right; in [0, 1])
        (None before the first :meth:`predict`)."""
        return None if self._disturbance is None else self._disturbance.copy()

    def _estimate_disturbance(self, i: int, x0: np.ndarray) -> None:
        """Update entry i's disturbance estimate from the velocities measured now against the model's
        prediction from the last state and input (with the current estimate): d += gain * step, the least
        change (in the units of ``DISTURBANCE_SCALES``) with J step = r, for the velocity residual r and
        J = d(velocities one period later)/d(estimate) (5, 7); the thrust-bending shares are then kept in
        [0, 1]. (Letting the forces explain what a share at its bound cannot, as an estimator without shares
        would, crashed more noisy and hard episodes of benchmarks/mpc_crash_rates.py: 5 against 1 on hover and
        track_paper.)"""
        gain = self.options.disturbance_gain
        last = self._last_state[i]
        if gain == 0.0 or not np.isfinite(last).all():
            return
        predicted, jac = self.ocp.predict_step(last, self._applied[i], self._disturbance[i])
        J = jac[5:] * DISTURBANCE_SCALES  # the velocities' sensitivity to the scaled estimate
        try:
            step = DISTURBANCE_SCALES * (J.T @ np.linalg.solve(J @ J.T, x0[5:] - predicted[5:]))
        except np.linalg.LinAlgError:
            return
        if np.isfinite(step).all():
            self._disturbance[i] += gain * step
            # a thrust's share in bending its arm: between none (the paper's map) and all its work (the exact map)
            np.clip(self._disturbance[i, 5:], 0.0, 1.0, out=self._disturbance[i, 5:])

    @property
    def stats(self) -> dict:
        """Solver statistics since the last :meth:`reset_stats`: ``solves`` (QPs attempted, one per batch
        entry and control step), ``failures`` (solves that failed; each one applied the fallback, the
        previous plan's next input), ``fallbacks`` (= failures), ``relaxed`` (solves whose QP could not
        meet the curvature limits over the horizon and exceeded them by a slack of more than
        ``RELAXED_SLACK`` rad: the plan that exceeds them least was applied), and the solve time per control step in
        ms (``solve_ms_median``, ``solve_ms_p99``, ``solve_ms_max``, ``solve_ms_mean``; None before the
        first solve). A solve's time is the policy's whole computation for one entry: reference,
        linearisation, QP, line search."""
        t = np.asarray(self.solve_times) * 1e3
        summary = {"solves": self._solves, "failures": self._failures, "fallbacks": self._failures,
                   "relaxed": self._relaxed}
        for name, fn in (("median", np.median), ("p99", lambda a: np.percentile(a, 99)), ("max", np.max),
                         ("mean", np.mean)):
            summary[f"solve_ms_{name}"] = float(fn(t)) if t.size else None
        return summary

    # ------------------------------------------------------------------------------------ acting
    def _reference(self, obs_row: np.ndarray, theta: float, jerk: np.ndarray) -> np.ndarray:
        """x_ref (N, 10) at nodes 1 .. N, positions relative to the reference position now."""
        s = self.ocp.node_times[1:, None]
        v, a = obs_row[12:15], obs_row[15:18]
        ref = np.zeros((self.options.horizon, NX))
        ref[:, 0:3] = v * s + 0.5 * a * s**2 + jerk * s**3 / 6.0
        ref[:, 2] += theta - obs_row[2]
        ref[:, 5:8] = v + a * s + 0.5 * jerk * s**2
        return ref

    def _act(self, i: int, obs_row: np.ndarray, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """The input (4) for batch entry i; updates its memory."""
        t0 = time.perf_counter()
        acc = obs_row[15:18]
        last = self._last_ref_acc[i]
        jerk = (acc - last) / self.config.dt if self.options.jerk_extrapolation and np.isfinite(last).all() \
            else np.zeros(3)
        x0 = np.concatenate([q, qd])
        x0[0:2] = obs_row[0:2]  # positions relative to the reference position now
        self._estimate_disturbance(i, x0)
        if self._qps[i] is None:
            self._qps[i] = self.ocp.new_qp()
        guess = self._plans[i]
        plan, ok = self.ocp.solve(x0, self._reference(obs_row, q[2], jerk), guess, self._applied[i],
                                  self._disturbance[i], self._qps[i])
        self._solves += 1
        if not ok:
            self._failures += 1
        elif self.ocp.last_slack > RELAXED_SLACK:
            self._relaxed += 1
        u = plan[0].copy()
        self._plans[i] = self.ocp.shift(plan, self.config.dt)
        self._applied[i] = u
        self._last_ref_acc[i] = acc
        self._last_state[i] = x0
        self.solve_times.append(time.perf_counter() - t0)
        return u

    def observe_applied(self, action) -> None:
        """Tell the policy that the env's actions ``action`` (N, 4), not its own of the last :meth:`predict`, were
        applied (another policy flew, as when the MPC labels a student's steps in DAgger): the input applied last,
        from which the disturbance estimate predicts the next state and the input-rate cost counts, becomes
        theirs. Without this call the MPC assumes its own actions were applied."""
        a = np.asarray(action, dtype=np.float64)
        if self._n is None or a.shape != (self._n, NU) or not np.isfinite(a).all():
            raise ValueError(f"observe_applied takes the finite actions ({self._n}, {NU}) of the batch of the last "
                             f"predict, got {short_repr(action)}")
        self._applied[:] = action_actuators(a, self.config.thrust_max, self.config.arm_torque_max)

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        """(action, state) for observations (18,) or (N, 18) of the env (21 with its ``observe_error_integral``:
        entries 0-17 are read); ``episode_start``: None, a bool
        or a bool array of N entries (the entries whose plan is reset). Observations must be finite and
        inside the model's validity (arm curvatures |q_l|, |q_r| <= 2 pi); ValueError otherwise."""
        obs, single = policy_observations(observation, self.config.obs_dim)
        n = obs.shape[0]
        mask = None if episode_start is None else _episode_start_mask(episode_start, n)
        if self._n != n:
            self._plans = np.empty((n, self.options.horizon, NU))
            self._applied = np.empty((n, NU))
            self._last_ref_acc = np.empty((n, 3))
            self._last_state = np.empty((n, NX))
            self._disturbance = np.zeros((n, ND))
            self._qps = [None] * n
            self._reset_entries(np.ones(n, dtype=bool))
            self._n = n
        elif mask is not None and mask.any():
            self._reset_entries(mask)
        q, qd = state_from_observation(obs)[:2]
        u = np.stack([self._act(i, obs[i], q[i], qd[i]) for i in range(n)])
        action = np.clip(actuator_action(u, self.config.thrust_max, self.config.arm_torque_max), -1.0, 1.0)
        action = action.astype(np.float32)
        return (action[0] if single else action), state


def check_limits(config: EnvConfig) -> None:
    """ValueError when the env's actuator limits cannot hold the robot in hover with straight arms (the
    MPC's input reference and the equilibrium its cost regulates to)."""
    p = config.params
    weight = p.total_mass * p.g
    if 2.0 * config.thrust_max <= weight:
        raise ValueError(
            f"infeasible actuator limits for the MPC: the largest total thrust 2 x T_max = "
            f"{2.0 * config.thrust_max:g} N "
            f"does not exceed the weight (m + m_l + m_r) g = {weight:g} N, so the robot cannot hover or climb; "
            f"give actuator_limits with T_max > {0.5 * weight:g} N (the default is 3 x the hover thrust)")
    arms = hover_input(p, config.input_map)[2:]
    if np.abs(arms).max() > config.arm_torque_max:
        raise ValueError(
            f"infeasible actuator limits for the MPC: holding the arms straight in hover needs arm torques "
            f"{arms.round(4).tolist()} N m, beyond tau_max = {config.arm_torque_max:g} N m; give actuator_limits "
            f"with tau_max >= {np.abs(arms).max():g} N m (the default is 4 x the arm gravity load)")
