"""The MPC's optimal control problem and its real-time-iteration solver.

Problem (one per control step, from the measured state x0):

    min_{u_0..u_{N-1}}  sum_{k=1..N} |x_k - r_k|^2_{W_k} + sum_{k=0..N-1} |v_k|^2_{R} + |v_k - v_{k-1}|^2_{R_d}
    s.t.  x_{k+1} = F_k(x_k, u_k)        (RK4 of the paper's model, u held over interval k)
          u_lo <= u_k <= u_hi            (the env's actuator limits, hard)
          |q_l,k|, |q_r,k| <= q_max      (the curvature limits, soft, k = 1..N)

with v_k = (u_k - u_hover) / u_scale the normalised input, v_{-1} the input applied at the previous step,
W_k diagonal (the terminal node's times ``terminal_weight``). The intervals are ``first_step`` (the env's
control period: the first input is exactly what the env holds) then ``step`` seconds.

The curvature limits are soft: each QP has a slack s >= 0 per arm and node (|dq + q| <= q_max + s),
charged ``VIOLATION_PENALTY`` per rad (an exact L1 penalty: while the limits can be met, the QP's solution
meets them; when they cannot, as when the arm torques are saturated and the arms still bend outwards,
the QP still has a solution, the plan that exceeds them least, instead of failing) plus a small
quadratic term ``SLACK_WEIGHT``. The line search's merit charges a violation at the same price.

Solver: real-time iteration, i.e. Gauss-Newton SQP with ``sqp_iterations`` steps per control step
(default one; each step shortened by a backtracking line search on the nonlinear cost), single
shooting. Each iteration rolls the model out from x0 under the current input guess and gets the
interval Jacobians A_k = dF/dx, B_k = dF/du from one CasADi Function (symbolic RK4, AD), and solves the
Gauss-Newton QP in the steps of the plan: by default with PIQP's interior point method on the QP with its
stage structure (state and input steps as variables, the linearised dynamics as equality constraints, the
input-rate cost coupling consecutive stages; ``_BandedQP``), with HPIPM through CasADi on the same QP in
HPIPM's stage form (the previous input step carried as a state; ``_SparseQP``), else with a dense solver on
the QP condensed to the input steps (states eliminated: the N x 4 inputs as variables, the 2N curvature rows
as constraints; ``_CondensedQP``). All are the same QP. The guess is
the previous solution shifted by one control period (warm start).

Disturbance: ``d`` (5), a generalized force added to the model's B(q) u, held over the horizon (the
policy's estimate of what the model lacks: wind, parameter errors, another input map). With ``d`` the
problem predicts the plant's drift, so a constant disturbance leaves no steady offset (up to the small
input weight on u - u_hover).
"""

from __future__ import annotations

import contextlib
import ctypes
import dataclasses
import math
import os
import sys
import warnings

import numpy as np

from ..._validation import short_repr
from ...params import SoftPVTOLParams
from . import symbolic
from ._casadi import import_casadi, import_piqp
from ._codegen import compile_functions, find_compiler
from .qp import (
    FREE_BOUND,
    NU,
    NX,
    VIOLATION_PENALTY,
    _BandedQP,
    _Buffered,
    _CondensedQP,
    _differences,
    _PiqpQP,
    _SparseQP,
)

#: the disturbance estimate's size (:data:`.symbolic.DISTURBANCE_SIZE`)
ND = symbolic.DISTURBANCE_SIZE
#: a rollout whose arm curvature reaches this [rad] has diverged: its QP's curvature rows (bounds -qmax - q and
#: qmax - q against the open sides' +-FREE_BOUND) would be ill-posed, which CasADi refuses with an exception
DIVERGED_CURVATURE = 0.5 * FREE_BOUND
#: the line search's step lengths (fractions of the Gauss-Newton step)
LINE_SEARCH_STEPS = (1.0, 0.5, 0.25, 0.125)
#: the QP solvers the MPC accepts and their options: PIQP (its own package, the ``mpc`` extra) and CasADi's
#: conic plugins that its wheels bundle; none of them starts from an earlier call's solution (qpOASES
#: hot-starts from its last active set, PIQP keeps its regularisation: the policy gives each batch entry
#: and episode its own instance, see ``TrackingOCP.new_qp``)
QP_SOLVERS: dict[str, dict] = {
    # PIQP's exits: primal and dual residuals at 1e-9 absolute, its duality gap checks at their defaults,
    # chosen on the tuning episodes (seeds 3,000,000 + i; benchmarks/mpc_tuning.py, its JSON): of 1e-7, 2e-8,
    # 1e-8 and 1e-9, none crashes significantly more often than another in 40 episodes (1-2 crashes each) and 1e-9
    # has the lowest last-half error; no Ruiz scaling
    # (preconditioner_iter 0: the QP is in normalised inputs already, and the scaling's update cost 0.15 ms a
    # call, a quarter of the solve, for the same iteration counts) (benchmarks/README.md, "The MPC's QP solvers")
    "piqp": {"eps_abs": 1e-9, "eps_rel": 0.0, "preconditioner_iter": 0},
    # HPIPM's "speed" mode with its stationarity and complementarity exits at 1e-6 instead of 1e-8: a median
    # 4 interior-point iterations per QP instead of 6 ("balance"), the same plan to the tracking's precision
    # (benchmarks/mpc_solvers.py)
    "hpipm": {"hpipm": {"mode": "speed", "iter_max": 50, "warm_start": 0, "res_g_max": 1e-6, "res_m_max": 1e-6},
              "error_on_fail": False},
    "qpoases": {"printLevel": "none", "sparse": False, "error_on_fail": False},
    "daqp": {"error_on_fail": False},
    "qrqp": {"print_iter": False, "print_header": False, "print_info": False, "error_on_fail": False},
    "osqp": {"osqp": {"verbose": False, "eps_abs": 1e-7, "eps_rel": 1e-7, "max_iter": 4000, "polish": True},
             "warm_start_primal": True, "error_on_fail": False},
}
#: the solvers that take the QP with its OCP structure (states and inputs as variables) and the form each
#: takes it in; the others take it condensed (inputs only: :class:`_CondensedQP`)
STAGED_QP_FORMS = {"piqp": _BandedQP, "hpipm": _SparseQP}
#: the solvers that are not CasADi plugins
NON_CASADI_QP_SOLVERS = ("piqp",)
#: the solvers that print to stdout (silenced around each call)
CHATTY_QP_SOLVERS = ("qpoases",)


@dataclasses.dataclass(frozen=True)
class MPCOptions:
    """Options of :class:`~softpvtol_gym.policies.MPCPolicy` (``MPCPolicy.from_env(env, **options)``).

    ========================= ======== ===================================================================
    option                    default  meaning
    ========================= ======== ===================================================================
    ``horizon``               25       N, the number of intervals (1 .. 200)
    ``step``                  0.05     length [s] of intervals 1 .. N-1 (interval 0: ``first_step``)
    ``first_step``            None     length [s] of interval 0; None: the env's control period
    ``substeps``              1        RK4 steps per interval (1 .. 20)
    ``weight_position``       100      on (x, z) - reference [1/m^2]
    ``weight_attitude``       10       on theta - theta_ref [1/rad^2]
    ``weight_velocity``       1        on (xdot, zdot) - reference velocity [s^2/m^2]
    ``weight_attitude_rate``  0.1      on thetadot - its reference [s^2/rad^2]
    ``weight_arms``           1        on the curvatures q_l, q_r (reference 0: straight arms)
    ``weight_arm_rates``      1        on q_l dot, q_r dot (damps the arms; with 0.01 the noisy tier's
                                       track_paper episode crashed)
    ``weight_input``          0.01     on the normalised input (u - u_hover) / u_scale
    ``weight_input_rate``     0.1      on the change of the normalised input from interval to interval
    ``terminal_weight``       5        factor of the state weights at the last node
    ``curvature_limit``       pi       |q_l|, |q_r| bound [rad] (the env ends an episode beyond pi); soft:
                                       each QP may exceed it at a price of ``VIOLATION_PENALTY`` per rad
                                       (an exact L1 penalty), so that a state it cannot hold still has a plan
    ``sqp_iterations``        1        Gauss-Newton SQP iterations per control step (1: real-time iteration)
    ``qp_solver``             piqp     "piqp" (PIQP's interior point method on the QP with its OCP
                                       structure, its multistage KKT solver) | CasADi conic plugins:
                                       "hpipm" (the same QP, a Riccati-based interior point method) |
                                       "qpoases" | "daqp" | "qrqp" | "osqp" (the QP condensed to the
                                       inputs, dense)
    ``disturbance_gain``      0.05     gain per control step of the disturbance estimate (a constant
                                       generalized force added to the model over the horizon, updated
                                       from the measured velocities against the predicted ones; 0: none)
    ``jerk_extrapolation``    True     extrapolate the reference with its jerk, estimated from the
                                       reference accelerations of consecutive observations (else
                                       constant acceleration)
    ``model_input_map``       None     the input map of the MPC's model: None the env's (``input_map``,
                                       "paper" unless given), "paper" or "exact" (the virtual work of the
                                       thrusts at the tips, which also bend the arms: the map of
                                       ``model_gap``'s consistent plant; with it the MPC holds model_gap
                                       but crashed a track_paper nominal episode, whose plant has the
                                       paper's map, so it is not the default)
    ``compile_model``         None     compile the model's Functions with the system's C compiler (cached
                                       on disk; ~10x faster than CasADi's virtual machine): None if a
                                       compiler is found, True always (error without one), False never
    ========================= ======== ===================================================================

    u_hover is the input that holds the robot still with straight arms (each thrust M g / 2), u_scale
    (T_max / 2, T_max / 2, tau_max, tau_max), as the env's action scaling.
    """

    horizon: int = 25
    step: float = 0.05
    first_step: float | None = None
    substeps: int = 1
    weight_position: float = 100.0
    weight_attitude: float = 10.0
    weight_velocity: float = 1.0
    weight_attitude_rate: float = 0.1
    weight_arms: float = 1.0
    weight_arm_rates: float = 1.0
    weight_input: float = 0.01
    weight_input_rate: float = 0.1
    terminal_weight: float = 5.0
    curvature_limit: float = math.pi
    sqp_iterations: int = 1
    qp_solver: str = "piqp"
    disturbance_gain: float = 0.05
    jerk_extrapolation: bool = True
    model_input_map: str | None = None
    compile_model: bool | None = None

    def __post_init__(self) -> None:
        _int("horizon", self.horizon, 1, 200)
        _int("substeps", self.substeps, 1, 20)
        _int("sqp_iterations", self.sqp_iterations, 1, 50)
        _real("step", self.step, 1e-4, 10.0)
        if self.first_step is not None:
            _real("first_step", self.first_step, 1e-4, 10.0)
        for f in dataclasses.fields(self):
            if f.name.startswith("weight_") or f.name == "terminal_weight":
                _real(f.name, getattr(self, f.name), 0.0, 1e12)
        _real("curvature_limit", self.curvature_limit, 1e-3, math.pi)
        _real("disturbance_gain", self.disturbance_gain, 0.0, 1.0)
        if not isinstance(self.qp_solver, str) or self.qp_solver not in QP_SOLVERS:
            raise ValueError(f"MPC option qp_solver must be one of {sorted(QP_SOLVERS)}, got "
                             f"{short_repr(self.qp_solver)}")
        if self.model_input_map not in (None, "paper", "exact"):
            raise ValueError(f"MPC option model_input_map must be None, 'paper' or 'exact', got "
                             f"{short_repr(self.model_input_map)}")
        if self.compile_model is not None and not isinstance(self.compile_model, (bool, np.bool_)):
            raise ValueError(f"MPC option compile_model must be None, True or False, got "
                             f"{short_repr(self.compile_model)}")
        if not isinstance(self.jerk_extrapolation, (bool, np.bool_)):
            raise ValueError(f"MPC option jerk_extrapolation must be a bool, got {short_repr(self.jerk_extrapolation)}")

    @classmethod
    def names(cls) -> list[str]:
        return [f.name for f in dataclasses.fields(cls)]

    @classmethod
    def from_kwargs(cls, **kwargs) -> MPCOptions:
        """MPCOptions(**kwargs) with a ValueError naming the valid options for an unknown one."""
        unknown = [k for k in kwargs if k not in cls.names()]
        if unknown:
            raise ValueError(f"unknown MPC option(s) {unknown}; valid options are {cls.names()}")
        return cls(**kwargs)

    @classmethod
    def parse_items(cls, items) -> dict:
        """Option keywords from "KEY=VALUE" strings (the command line's ``--mpc-option``): VALUE as an int,
        a float, true/false or none where it reads as one, else the string; the values are checked by
        :class:`MPCOptions` itself. ValueError for an item without "=" or an unknown KEY."""
        out = {}
        for item in items:
            key, sep, text = str(item).partition("=")
            key = key.strip().replace("-", "_")
            if not sep or not key:
                raise ValueError(f"an MPC option must read KEY=VALUE, got {item!r}; valid keys are {cls.names()}")
            if key not in cls.names():
                raise ValueError(f"unknown MPC option {key!r}; valid options are {cls.names()}")
            out[key] = _parse_value(text.strip())
        return out


def _parse_value(text: str):
    low = text.lower()
    if low in ("true", "false"):
        return low == "true"
    if low == "none":
        return None
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def _int(name, value, lo, hi) -> None:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or not lo <= value <= hi:
        raise ValueError(f"MPC option {name} must be an int in [{lo}, {hi}], got {short_repr(value)}")


def _real(name, value, lo, hi) -> None:
    ok = (not isinstance(value, (bool, np.bool_)) and isinstance(value, (int, float, np.integer, np.floating))
          and math.isfinite(value) and lo <= value <= hi)
    if not ok:
        raise ValueError(f"MPC option {name} must be a finite number in [{lo:g}, {hi:g}], got {short_repr(value)}")


@contextlib.contextmanager
def _quiet_stdout():
    """The process's stdout (file descriptor 1, where C libraries print) sent to os.devnull."""
    sys.stdout.flush()
    try:
        saved = os.dup(1)
    except OSError:  # no file descriptor 1: nothing to silence
        yield
        return
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
            try:
                yield
            finally:
                _flush_c_stdio()  # what the library printed into C's buffer goes to os.devnull too
    finally:
        os.dup2(saved, 1)
        os.close(saved)


def _flush_c_stdio() -> None:
    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError, TypeError):  # no C library to reach (e.g. Windows): nothing buffered there
        pass


def hover_input(params: SoftPVTOLParams, input_map: str) -> np.ndarray:
    """u_hover (4): the actuators that hold the robot at rest with straight arms (each thrust M g / 2, the
    arm torques that balance gravity and, with the exact map, the thrusts' work on the curvatures),
    from the package's numeric model (:mod:`softpvtol_gym.dynamics`)."""
    from ... import dynamics

    q0 = np.zeros(5)
    thrust = params.hover_thrust
    grav = dynamics.gravity_vector(q0, params)
    from_thrust = dynamics.generalized_forces(q0, np.array([thrust, thrust, 0.0, 0.0]), params, input_map=input_map)
    return np.array([thrust, thrust, grav[3] - from_thrust[3], grav[4] - from_thrust[4]])


class TrackingOCP:
    """The tracking problem of the module docstring for one parameter set, limits and options; the
    CasADi Functions are built once here. :meth:`solve` runs the SQP iterations for one state.

    The QP solver is a CasADi Function that may keep memory between calls (qpOASES hot-starts from
    its last active set): :meth:`new_qp` builds another instance, so that each of several problems
    solved in turn (the policy's batch entries) has its own; :meth:`solve` uses ``qp`` or the
    problem's own instance :attr:`qp`."""

    def __init__(self, params: SoftPVTOLParams, input_map: str, thrust_max: float, arm_torque_max: float,
                 control_period: float, options: MPCOptions):
        ca = import_casadi()
        self.options = o = options
        self.params = params
        n = o.horizon
        first = control_period if o.first_step is None else o.first_step
        self.intervals = np.array([first] + [o.step] * (n - 1))
        #: node times tau_k [s] from now, k = 0 .. N
        self.node_times = np.concatenate([[0.0], np.cumsum(self.intervals)])
        self.u_lo = np.array([0.0, 0.0, -arm_torque_max, -arm_torque_max])
        self.u_hi = np.array([thrust_max, thrust_max, arm_torque_max, arm_torque_max])
        self.u_hover = hover_input(params, input_map)
        self.u_scale = np.array([0.5 * thrust_max, 0.5 * thrust_max, arm_torque_max, arm_torque_max])

        f = symbolic.continuous_dynamics(params.array, input_map, disturbance=True)
        step = symbolic.rk4_step(f, o.substeps)  # (x, u, h, d) -> x_next
        xs, us, hs, ds = ca.SX.sym("x", NX), ca.SX.sym("u", NU), ca.SX.sym("h"), ca.SX.sym("d", ND)
        out = step(xs, us, hs, ds)
        # (x, u, h, d) -> (x_next, dx_next/dx, dx_next/du)
        step_lin = ca.Function("softpvtol_rk4_linearized", [xs, us, hs, ds],
                               ca.cse([out, ca.jacobian(out, xs), ca.jacobian(out, us)]))
        # (x, u, h, d) -> (x_next, dx_next/dd): the disturbance estimator's one-period prediction
        step_dist = ca.Function("softpvtol_rk4_disturbance", [xs, us, hs, ds],
                                ca.cse([out, ca.densify(ca.jacobian(out, ds))]))
        #: how the model's Functions run: "compiled" (machine code, see _codegen) or "virtual machine"
        self.backend = "virtual machine"
        compiler = find_compiler() if o.compile_model is not False else None
        if o.compile_model and compiler is None:
            raise ValueError("MPC option compile_model=True needs a C compiler ($CC, cc or gcc on the PATH), none "
                             "was found; install one, or pass compile_model=None (use one if found) or False")
        if compiler is not None:
            try:
                step, step_lin, step_dist = compile_functions([step, step_lin, step_dist], compiler)
                self.backend = "compiled"
            except RuntimeError as exc:
                if o.compile_model:
                    raise
                warnings.warn(f"{exc}; the MPC runs its model in CasADi's virtual machine (slower)", stacklevel=3)
        self._step_disturbance = _Buffered(step_dist)
        self._step_disturbance.args[2][0] = float(self.intervals[0])
        x0 = ca.MX.sym("x0", NX)
        U = ca.MX.sym("U", NU, n)
        d = ca.MX.sym("d", ND)
        X, A, B = [x0], [], []
        x = x0
        for k in range(n):
            x, a, b = step_lin(x, U[:, k], float(self.intervals[k]), d)
            X.append(x)
            A.append(a)
            B.append(b)
        #: (x0, U, d) -> (X (10, N+1), A (10, 10 N), B (10, 4 N)): rollout and interval Jacobians
        self.linearize = ca.Function("mpc_linearize", [x0, U, d],
                                     [ca.densify(ca.horzcat(*M)) for M in (X, A, B)])
        self._linearize = _Buffered(self.linearize)
        x = x0
        X = [x0]
        for k in range(n):
            x = step(x, U[:, k], float(self.intervals[k]), d)
            X.append(x)
        #: (x0, U, d) -> X (10, N+1): the rollout alone
        self.rollout = ca.Function("mpc_rollout", [x0, U, d], [ca.densify(ca.horzcat(*X))])
        self._rollout = _Buffered(self.rollout)

        # weights per node k = 1 .. N (rows) and state coordinate (columns)
        w = np.array([o.weight_position, o.weight_position, o.weight_attitude, o.weight_arms, o.weight_arms,
                      o.weight_velocity, o.weight_velocity, o.weight_attitude_rate, o.weight_arm_rates,
                      o.weight_arm_rates])
        W = np.tile(w, (n, 1))
        # interval lengths weight the running cost (a finer first interval counts less)
        W *= (self.intervals / o.step)[:, None]
        W[-1] = w * o.terminal_weight
        self.state_weights = W.reshape(-1)
        self._v_lo = np.tile((self.u_lo - self.u_hover) / self.u_scale, n)
        self._v_hi = np.tile((self.u_hi - self.u_hover) / self.u_scale, n)
        #: "sparse" (states and inputs as variables, the OCP structure: piqp in its banded form, hpipm in its
        #: stage form) or "condensed" (inputs only)
        self.formulation = "sparse" if o.qp_solver in STAGED_QP_FORMS else "condensed"
        qp_form = STAGED_QP_FORMS.get(o.qp_solver, _CondensedQP)
        self._qp_data = qp_form(n, self.state_weights, o.weight_input, o.weight_input_rate)
        #: the problem's own QP solver instance (:meth:`new_qp` builds more)
        self.qp = self.new_qp()
        # one solve now: loads the QP solver's library (qpOASES prints its banner then, silenced here) and
        # the compiled condensing, so that the first control step is not the slow one
        with _quiet_stdout():
            self.solve(np.zeros(NX), np.zeros((n, NX)), np.tile(self.u_hover, (n, 1)), self.u_hover)
            self.qp = self.new_qp()  # forget that solve (a fresh instance: no memory of it)

    def new_qp(self) -> _Buffered | _PiqpQP:
        """A fresh instance of the QP solver with no memory of earlier calls, with its argument and result
        arrays: PIQP's solver (:class:`_PiqpQP`) or a CasADi ``conic`` Function (:class:`_Buffered`)."""
        if self.options.qp_solver in NON_CASADI_QP_SOLVERS:
            import_piqp()
            qp = _PiqpQP(self._qp_data.sparsity, QP_SOLVERS[self.options.qp_solver])
            self._qp_data.prepare(qp)
            return qp
        ca = import_casadi()
        with _quiet_stdout():  # qpOASES prints its banner when its plugin loads
            fn = ca.conic("mpc_qp", self.options.qp_solver, self._qp_data.sparsity,
                          {**QP_SOLVERS[self.options.qp_solver], **self._qp_data.solver_options})
        qp = _Buffered(fn, fresh_work=self.options.qp_solver in STAGED_QP_FORMS)
        self._qp_data.prepare(qp)
        return qp

    def predict_step(self, x: np.ndarray, u: np.ndarray, disturbance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(x_next (10), dx_next/dd (10, ND)): the model's state one control period after x under the
        input u and the generalized-force disturbance d (the estimator's prediction)."""
        fn = self._step_disturbance
        fn.args[0][:] = x
        fn.args[1][:] = u
        fn.args[3][:] = disturbance
        fn()
        return fn.res[0].copy(), fn.res[1].reshape(ND, NX).T.copy()

    def _merit(self, X: np.ndarray, V: np.ndarray, x_ref: np.ndarray, v_prev: np.ndarray) -> float:
        """The cost of the plan V with the rollout X (N, 10), plus ``VIOLATION_PENALTY`` x the curvature
        bound violation (the line search's merit function)."""
        o = self.options
        e = (X - x_ref).reshape(-1)
        dv = _differences(V, v_prev)
        cost = e @ (self.state_weights * e) + o.weight_input * (V @ V) + o.weight_input_rate * (dv @ dv)
        excess = np.maximum(np.abs(X[:, 3:5]) - o.curvature_limit, 0.0).sum()
        return 0.5 * cost + VIOLATION_PENALTY * excess

    def solve(self, x0: np.ndarray, x_ref: np.ndarray, U_guess: np.ndarray, u_prev: np.ndarray,
              disturbance: np.ndarray | None = None, qp=None) -> tuple[np.ndarray, bool]:
        """(U (N, 4), success) from the state x0 (10), the reference x_ref (N, 10) at nodes 1 .. N, the
        initial guess U_guess (N, 4), the previously applied input u_prev (4) and the estimated
        disturbance (ND; None: zero), held over the horizon. ``qp``: the QP solver
        instance to use (:meth:`new_qp`; None: :attr:`qp`). On failure (a QP solver failure or a
        non-finite linearisation) U is the guess as given, and :attr:`last_failure` says which ("qp" or
        "rollout"; None after a success). When the model's rollout under the guess is not finite, the
        iteration starts again from the hover input over the horizon (:attr:`restarted`).
        :attr:`last_slack`: the largest curvature slack [rad] of the last QP solved (0: the linearised
        plan meets the curvature limits; nan: no QP solved).

        Each SQP iteration takes the Gauss-Newton step of the QP, shortened by a backtracking line search
        on the nonlinear cost (``_merit``: the rollout of the model, steps 1, 1/2, 1/4, 1/8; none of them
        better than the current plan: the plan is kept)."""
        o = self.options
        n = o.horizon
        qp = self.qp if qp is None else qp
        self.last_slack = math.nan
        self.last_failure = None
        d = np.zeros(ND) if disturbance is None else disturbance
        V = ((U_guess - self.u_hover) / self.u_scale).reshape(-1)
        v_prev = (u_prev - self.u_hover) / self.u_scale
        lo, hi = self._v_lo, self._v_hi
        lin, roll = self._linearize, self._rollout
        lin.args[0][:] = x0
        lin.args[2][:] = d
        roll.args[0][:] = x0
        roll.args[2][:] = d
        quiet = _quiet_stdout if o.qp_solver in CHATTY_QP_SOLVERS else contextlib.nullcontext
        self.restarted = False
        for _ in range(o.sqp_iterations):
            lin.args[1][:] = (self.u_hover + V.reshape(n, NU) * self.u_scale).reshape(-1)
            lin()
            if _diverged(lin.res[0]) and not self.restarted and V.any():
                # the model's rollout under the guess diverged (e.g. full thrust held over the horizon by a
                # model whose thrusts bend the arms beyond the torques' reach): linearise at hover instead
                self.restarted = True
                V = np.zeros_like(V)
                lin.args[1][:] = np.tile(self.u_hover, n)
                lin()
            X = lin.res[0].reshape(n + 1, NX)[1:]  # (N, 10), nodes 1 .. N
            A = lin.res[1].reshape(NX * n, NX).T  # (10, 10 N)
            B = lin.res[2].reshape(NU * n, NX).T  # (10, 4 N)
            if _diverged(X) or not (np.isfinite(A).all() and np.isfinite(B).all()):
                self.last_failure = "rollout"
                return U_guess, False
            self._qp_data.fill(qp, A, B, self.u_scale, X, x_ref, V, v_prev, lo, hi, o.curvature_limit)
            with quiet():  # qpOASES prints some failures even at printLevel "none"
                qp()
            step = self._qp_data.input_step(qp)
            if not qp.success() or not np.isfinite(step).all():
                self.last_failure = "qp"
                return U_guess, False
            self.last_slack = float(self._qp_data.slacks(qp).max())
            merit0 = self._merit(X, V, x_ref, v_prev)
            for alpha in LINE_SEARCH_STEPS:
                V_try = np.clip(V + alpha * step, lo, hi)
                roll.args[1][:] = (self.u_hover + V_try.reshape(n, NU) * self.u_scale).reshape(-1)
                roll()
                X_try = roll.res[0].reshape(n + 1, NX)[1:]
                if np.isfinite(X_try).all() and self._merit(X_try, V_try, x_ref, v_prev) < merit0:
                    V = V_try
                    break
        return self.u_hover + V.reshape(n, NU) * self.u_scale, True

    def shift(self, U: np.ndarray, period: float) -> np.ndarray:
        """The plan U (N, 4) on this grid, started ``period`` seconds later: each interval takes the input
        planned for its start time + period (the last input repeated past the horizon)."""
        starts = self.node_times[:-1] + period + 1e-9  # (a start on a node takes that node's input)
        idx = np.searchsorted(self.node_times, starts, side="right") - 1
        return U[np.minimum(idx, U.shape[0] - 1)]


def _diverged(states: np.ndarray) -> bool:
    """Whether a rollout (states of NX entries, flat or (N, NX)) is not finite or bends an arm past
    :data:`DIVERGED_CURVATURE`."""
    arms = np.reshape(states, (-1, NX))[:, 3:5]
    return not (np.isfinite(states).all() and np.abs(arms).max() < DIVERGED_CURVATURE)
