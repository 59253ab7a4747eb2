"""The paper's closed loop as reusable, batched pieces.

Actuated loop (paper Fig. 'controldiagram'): the passivity controller gives tau for the body; the
allocation turns its body rows into thrusts (T_l, T_r) and desired curvatures (q_l^d, q_r^d); the
controller's arm rows, with those curvatures as arm references, give the arm torques (tau_l, tau_r).
The plant is driven through ``generalized_forces`` with the *actual* curvatures, so arm lag is real.

The paper closes an algebraic loop (the arm references enter the body rows through D and C) with
Simulink's algebraic-constraint block; here every call solves it by passes body rows -> allocation
-> arm references until the curvatures move by at most ``algebraic_tolerance`` (1e-10 rad), from
the last two steps' solutions extrapolated to this one (2 q^d_k-1 - q^d_k-2), so that the solution
continues the branch it is on.

Loops (``LOOPS``):
    ``"paper"``     paper allocation, arm references with zero velocity/acceleration (as printed).
    ``"exact"``     exact allocation, arm references with zero velocity/acceleration.
    ``"improved"``  exact allocation and arm references fed forward with their velocity and
                    acceleration (second-order backward differences of q^d, bounded by 5 rad/s and
                    50 rad/s^2): a small tracking error, not zero (docs/control.md).
    ``"bounded"``   the improved loop with its demands bounded to what the env's default actuators
                    deliver: fed-forward arm rates within 1 rad/s and 5 rad/s^2, desired curvatures
                    within 0.6 rad (the default of PassivityPolicy and of the residual base controller).
    ``"integral"``  the bounded loop with integral action on the body position, as a control
                    engineer would tune it: the integral z of the position error (x, z) enters the
                    sliding variable, r = q~dot + Lambda clip(q~) + Lambda_I z, with the position
                    gains raised (Lambda 2 1/s, K 14 N s/m; :data:`INTEGRAL_LOOP_GAINS`), Lambda_I =
                    1 1/s^2 (a double pole at -1 1/s), the law's position error clipped to +-0.5 m
                    (a far start is approached at <= 1 m/s), the integrated error to +-0.5 m and
                    the integral to +-8 m s (anti-windup), held while the allocation clips a
                    curvature; reset with the episode (docs/control.md, "Integral action": the sweep).
    ``"ideal"``     tau applied directly as the generalized force (the setting of Theorem 1).
"""

from __future__ import annotations

import dataclasses
import inspect
import math
from collections.abc import Callable

import numpy as np

from .._batching import broadcast_batch, check_curvature
from .._parallel import run_rows
from ..dynamics import forward_dynamics, generalized_forces, input_map_code
from ..integrators import rk4_step, rk4_step_actuated, rk4_step_of_rates
from ..params import SoftPVTOLParams
from . import kernels as CK
from .allocation import ALLOCATION_METHODS, AllocationInfo, _allocation_info
from .passivity import PassivityGains, passivity_control, storage_function
from .references import paper_reference

__all__ = ["LOOPS", "ControlOutput", "PassivityController", "simulate_closed_loop", "MAX_HELD_CONTROL_PERIOD"]

#: The longest zero-order-hold control period [s] under which the actuated loops with the default
#: gains stay stable: the arm loop (K / D ~ 130 1/s) diverges from 0.013 s on (measured on the paper's
#: case: ``simulate_closed_loop(loop, hold="step", dt=...)`` for "paper", "exact", "bounded": stable
#: at 0.012 s, diverged at 0.013 s; tests/control/test_loops.py re-checks it). With other gains the
#: limit scales roughly with 1 / K of the arms.
MAX_HELD_CONTROL_PERIOD = 0.012

_F64 = np.dtype(np.float64)
# the single-state call's names, bound once (it is a hot path: a module attribute costs a lookup per use)
_ND, _ONE_SHAPE, _ONE_STRIDES = np.ndarray, (5,), (8,)
_OUT_LEN, _OUT_INFO, _OUT_LOOP, _ERR_NONE = CK.OUT_LEN, CK.OUT_INFO, CK.OUT_LOOP, CK.ERR_NONE
_single_controller = CK.single_controller

#: Lambda and K of the integral loop: the body position's (x, z) raised from (1, 2.55) to (2, 14), the
#: rest as the default (:class:`PassivityGains`); chosen with its integral gains by the sweep of
#: ``benchmarks/integral_sweep.py`` (docs/control.md, "Integral action")
INTEGRAL_LOOP_GAINS = PassivityGains(lam=(2.0, 2.0, 5.0, 10.0, 10.0), k=(14.0, 14.0, 10.5, 21.0, 21.0))

LOOPS: dict[str, dict] = {
    "paper": dict(allocation="paper", arm_feedforward=False),
    "exact": dict(allocation="exact", arm_feedforward=False),
    "improved": dict(allocation="exact", arm_feedforward=True),
    "bounded": dict(allocation="exact", arm_feedforward=True, feedforward_limits=(1.0, 5.0), curvature_limit=0.6),
    "integral": dict(allocation="exact", arm_feedforward=True, feedforward_limits=(1.0, 5.0), curvature_limit=0.6,
                     gains=INTEGRAL_LOOP_GAINS, integral_gains=(1.0, 1.0, 0.0), integral_limits=(8.0, 8.0, 8.0),
                     integral_error_limits=(0.5, 0.5, 0.5), error_limits=(0.5, 0.5, math.inf)),
    "ideal": dict(allocation="ideal", arm_feedforward=False),
    "extended": dict(allocation="exact", controller="extended"),  # control.extended.ExtendedController
}


@dataclasses.dataclass
class ControlOutput:
    """One control step. Shapes: batch + (k,).

    tau: generalized force the controller asks for (5). For the ideal loop it is applied as is.
    actuators: (T_l, T_r, tau_l, tau_r) to apply through ``generalized_forces`` (None for ideal).
    arm_reference: (q_l^d, q_r^d) used by the arm rows. allocation: diagnostics (None for ideal).
    loop_residual: the algebraic loop's last change of the allocated curvatures [rad] (batch; <= the
    controller's ``algebraic_tolerance`` when solved; None for ideal). loop_iterations: its passes.
    """

    tau: np.ndarray
    actuators: np.ndarray | None
    arm_reference: np.ndarray
    allocation: AllocationInfo | None
    loop_residual: np.ndarray | None = None
    loop_iterations: np.ndarray | None = None


class PassivityController:
    """Stateful, batched passivity controller + allocation (one instance per rollout batch).

    Args:
        params: model parameters the controller believes (nominal; the plant may differ).
        gains: :class:`PassivityGains`.
        allocation: ``"paper"``, ``"exact"`` or ``"ideal"`` (tau applied directly, no allocation).
        input_map: the plant's input map; with ``"exact"`` the thrusts' work on the curvatures is
            compensated in the arm torques so that the arm rows get the torque the controller asked for.
        arm_feedforward: feed the arm references' velocity and acceleration (backward differences of
            the allocated curvatures over the last control steps) instead of zeros.
        dt: control period [s] (used by the feedforward differences).
        algebraic_iterations: the most passes over the algebraic loop body rows -> allocation -> arm
            references per call (each pass starts from the last one's arm references, the first from
            the previous step's, or the measured curvatures after a reset: the solution continues the
            branch of the last step).
        algebraic_tolerance: the loop is solved when a pass moves the allocated curvatures by at most
            this much (rad); 0 runs exactly ``algebraic_iterations`` passes (1: the body rows use the
            previous step's arm references). The last pass's change is reported per call
            (``ControlOutput.loop_residual``).
        curvature_limit: desired curvatures beyond it (rad, in (0, pi]) are clipped by the exact
            allocation and reported infeasible.
        feedforward_limits: bounds (rad/s, rad/s^2) on the fed-forward arm reference velocity and
            acceleration.
        integral_gains: Lambda_I (x, z, theta) [1/s^2] of the integral action (all 0, the default:
            none): the integral z of the body error q~ enters the sliding variable, r = q~dot +
            Lambda q~ + Lambda_I z (the passivity law with the reference rates qdot_ref - Lambda_I z
            and qddot_ref - Lambda_I q~ + Lambda Lambda_I z); linearised, the error obeys
            (s^2 + lambda s + lambda_I) q~ = 0 once r = 0, so a constant disturbance leaves no offset.
            Actuated loops only.
        integral_limits: bounds on |z| (m s, m s, rad s): anti-windup clamping.
        integral_error_limits: bounds on the error integrated per step (m, m, rad), so that a large
            transient (a start metres away) winds the integral up no faster than this. z advances
            once per committed step, and not while the allocation clips a desired curvature
            (conditional integration); it is zero after a reset.
        error_limits: bounds (m, m, rad) on the body error q~ in the law's v = qdot_ref - Lambda
            clip(q~) - Lambda_I z (a saturated proportional term: a start far away is approached at
            a speed of at most lambda * limit, instead of a force demand proportional to the
            distance). Actuated loops only.

    A call of the actuated loops is one compiled kernel per batch (``control.kernels.controller_lanes``
    on blocks of ``CTRL_LANES`` rows, built from the same passivity and allocation kernels as
    :func:`passivity_control` and :func:`allocate`; every row computed alone, so its result does not
    depend on the batch); the env's residual mode and :class:`~softpvtol_gym.PassivityPolicy` run the
    same block function. The memory (allocation warm start, arm-reference history) is one row of
    ``ST_LEN`` floats per batch entry, created at the first call; the batch size is then fixed until
    :meth:`reset` (a call with another batch size raises ValueError).
    """

    def __init__(
        self,
        params: SoftPVTOLParams | None = None,
        gains: PassivityGains | None = None,
        allocation: str = "paper",
        input_map: str = "paper",
        arm_feedforward: bool = False,
        dt: float = 0.01,
        algebraic_iterations: int = 100,
        feedforward_limits: tuple[float, float] = (5.0, 50.0),
        algebraic_tolerance: float = 1e-10,
        curvature_limit: float = math.pi,
        integral_gains: tuple[float, float, float] = (0.0, 0.0, 0.0),
        integral_limits: tuple[float, float, float] = (math.inf, math.inf, math.inf),
        integral_error_limits: tuple[float, float, float] = (math.inf, math.inf, math.inf),
        error_limits: tuple[float, float, float] = (math.inf, math.inf, math.inf),
    ) -> None:
        if allocation != "ideal" and allocation not in ALLOCATION_METHODS:
            raise ValueError(
                f"allocation must be one of {sorted([*ALLOCATION_METHODS, 'ideal'])}, got {allocation!r}"
            )
        imap = input_map_code(input_map)
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a finite number > 0 [s], got {dt!r}")
        self.params = SoftPVTOLParams() if params is None else params
        self.gains = PassivityGains() if gains is None else gains
        self.allocation = allocation
        self.input_map = input_map
        self.arm_feedforward = bool(arm_feedforward)
        self.dt = float(dt)
        if int(algebraic_iterations) < 1:
            raise ValueError(f"algebraic_iterations must be >= 1, got {algebraic_iterations!r}")
        self.algebraic_iterations = int(algebraic_iterations)
        if not (isinstance(algebraic_tolerance, (int, float, np.floating, np.integer))
                and not isinstance(algebraic_tolerance, bool) and algebraic_tolerance >= 0):
            raise ValueError(f"algebraic_tolerance must be a number >= 0 [rad] (0: exactly algebraic_iterations "
                             f"passes), got {algebraic_tolerance!r}")
        self.algebraic_tolerance = float(algebraic_tolerance)
        if not (isinstance(curvature_limit, (int, float, np.floating, np.integer))
                and not isinstance(curvature_limit, bool) and 0.0 < curvature_limit <= math.pi):
            raise ValueError(f"curvature_limit must be a number in (0, pi] [rad], got {curvature_limit!r}")
        self.curvature_limit = float(curvature_limit)
        self.feedforward_limits = (float(feedforward_limits[0]), float(feedforward_limits[1]))
        self.integral_gains = _three("integral_gains", integral_gains, "[1/s^2]", 0.0, math.inf)
        self.integral_limits = _three("integral_limits", integral_limits, "(m s, m s, rad s)", 0.0, math.inf, True)
        self.integral_error_limits = _three("integral_error_limits", integral_error_limits, "(m, m, rad)", 0.0,
                                            math.inf, True)
        self.error_limits = _three("error_limits", error_limits, "(m, m, rad)", 0.0, math.inf, True)
        if allocation == "ideal" and (any(self.integral_gains) or min(self.error_limits) < math.inf):
            raise ValueError("integral_gains and error_limits need an actuated loop (allocation 'exact' or 'paper'); "
                             f"the ideal loop has neither, got integral_gains={integral_gains!r}, "
                             f"error_limits={error_limits!r}")
        cc = np.zeros(CK.CC_LEN)
        cc[CK.CC_METHOD] = ALLOCATION_METHODS.get(allocation, 0)
        cc[CK.CC_IMAP] = imap
        cc[CK.CC_ITERS] = self.algebraic_iterations
        cc[CK.CC_TOL] = self.algebraic_tolerance
        cc[CK.CC_FF] = 1.0 if self.arm_feedforward else 0.0
        cc[CK.CC_DT] = self.dt
        cc[CK.CC_VMAX], cc[CK.CC_AMAX] = self.feedforward_limits
        cc[CK.CC_QMAX] = self.curvature_limit
        cc[CK.CC_P:CK.CC_P + 10] = self.params.array
        cc[CK.CC_LAM:CK.CC_LAM + 5] = self.gains.lam_array
        cc[CK.CC_KG:CK.CC_KG + 5] = self.gains.k_array
        cc[CK.CC_LAMI:CK.CC_LAMI + 3] = self.integral_gains
        cc[CK.CC_IMAX:CK.CC_IMAX + 3] = self.integral_limits
        cc[CK.CC_EMAX:CK.CC_EMAX + 3] = self.integral_error_limits
        cc[CK.CC_PMAX:CK.CC_PMAX + 3] = self.error_limits
        #: kernel constants (``control.kernels.CC_*``)
        self.kernel_constants = cc
        self._no_residual = np.zeros((1, 5))
        self.reset()

    def __getstate__(self) -> dict:
        # the layouts of the memory and the constants travel with them: a controller pickled under another
        # layout is refused on unpickling instead of being read wrongly
        return {**self.__dict__, "layouts": (CK.MEMORY.signature, CK.CONSTANTS.signature)}

    def __setstate__(self, state: dict) -> None:
        state = dict(state)
        memory, constants = state.pop("layouts", (("controller_memory", 1, None), ("controller_constants", 1, None)))
        CK.MEMORY.check(memory)
        CK.CONSTANTS.check(constants)
        self.__dict__.update(state)

    @classmethod
    def from_loop(cls, loop: str, **kwargs) -> PassivityController:
        """A controller configured as one of :data:`LOOPS` (``"paper"``, ``"exact"``, ``"improved"``,
        ``"bounded"``, ``"integral"``, ``"ideal"``); keyword arguments override the loop's settings."""
        if loop not in LOOPS:
            raise ValueError(f"loop must be one of {sorted(LOOPS)}, got {loop!r}")
        if "controller" in LOOPS[loop]:
            raise ValueError(f"loop {loop!r} is not a PassivityController loop: use "
                             "control.extended.ExtendedController (simulate_closed_loop and "
                             "PassivityPolicy.from_env dispatch to it)")
        valid = [k for k in inspect.signature(cls.__init__).parameters if k != "self"]
        unknown = sorted(set(kwargs) - set(valid))
        if unknown:
            raise ValueError(f"unknown controller option(s) {unknown}; valid options: {valid}")
        # None (params, gains: "the default") leaves the loop's own setting
        return cls(**{**LOOPS[loop], **{k: v for k, v in kwargs.items() if v is not None}})

    def reset(self, mask: np.ndarray | None = None) -> None:
        """Forget the warm start and arm-reference history (all, or the batch entries where mask)."""
        if mask is None or self._state is None:
            self._state: np.ndarray | None = None
            self._spare: np.ndarray | None = None
            return
        # entries being reset restart from "no history" (re-seeded from the state on the next call)
        # and solve the allocation from the cold start (NaN warm start)
        rows = np.asarray(mask, dtype=bool).reshape(-1)
        self._state[rows, CK.ST_FRESH] = 1.0
        self._state[rows, CK.ST_WARM:CK.ST_WARM + 4] = np.nan

    def reset_rows(self, rows: np.ndarray) -> None:
        """:meth:`reset` of the batch entries ``rows`` (integer indices into the flattened batch)."""
        if self._state is not None:
            self._state[rows, CK.ST_FRESH] = 1.0
            self._state[rows, CK.ST_WARM:CK.ST_WARM + 4] = np.nan

    _state = None
    _spare = None

    def state_rows(self, n: int) -> np.ndarray:
        """The memory (n, ``ST_LEN``) of a batch of n entries, created fresh at the first call."""
        if self._state is None:
            st = np.zeros((n, CK.ST_LEN))
            st[:, CK.ST_WARM:CK.ST_WARM + 4] = np.nan
            st[:, CK.ST_FRESH] = 1.0
            self._state = st
        elif self._state.shape[0] != n:
            raise ValueError(
                f"the controller's memory is for a batch of {self._state.shape[0]} entries, got {n}; "
                "call reset() before changing the batch size"
            )
        return self._state

    def memory_pair(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """(memory, spare) of a batch of n entries: a kernel reads the memory and writes every row's
        memory after the step into the spare; :meth:`swap_memory` then makes the spare the memory (a
        failed step swaps nothing, so it changes no memory)."""
        S = self.state_rows(n)
        if self._spare is None or self._spare.shape != S.shape:
            self._spare = np.empty_like(S)
        return S, self._spare

    def swap_memory(self) -> None:
        """Make the spare of :meth:`memory_pair` (written by a successful step) the memory."""
        self._state, self._spare = self._spare, self._state

    @staticmethod
    def raise_for(err: np.ndarray, q: np.ndarray) -> None:
        """Raise the error a failed kernel call reports (nothing is changed by such a call)."""
        if (err == CK.ERR_TAU).any():
            raise ValueError("tau contains NaN or inf; allocation needs a finite body force")
        if (err == CK.ERR_CURVATURE).any():
            check_curvature(q)
        raise ValueError(f"controller kernel failed with codes {np.unique(err)}")  # pragma: no cover

    # --------------------------------------------------------------------------------- the step
    def __call__(self, q, qdot, q_ref, qdot_ref, qddot_ref, tau_residual=None, commit: bool = True) -> ControlOutput:
        """One control step from the state and the body reference (arm entries of the refs ignored
        in the actuated loops, used as given in the ideal loop). ``tau_residual`` (..., 5) is added
        to the controller's tau before allocation (body rows) and to the arm torques (arm rows).
        ``commit=False`` evaluates without advancing the controller's memory (RK4 stages)."""
        ins = (q, qdot, q_ref, qdot_ref, qddot_ref) if tau_residual is None else (
            q, qdot, q_ref, qdot_ref, qddot_ref, tau_residual)
        if self.allocation != "ideal":  # fast path: one state, contiguous float64 arrays (5,)
            for x in ins:
                if type(x) is not _ND or x.dtype is not _F64 or x.strides != _ONE_STRIDES or x.shape != _ONE_SHAPE:
                    break
            else:
                return self._call_single(ins, tau_residual is not None, commit is True or bool(commit))
        p, gains = self.params, self.gains
        if self.allocation == "ideal":
            q = np.asarray(q, dtype=np.float64)
            qdot = np.asarray(qdot, dtype=np.float64)
            tau = passivity_control(q, qdot, q_ref, qdot_ref, qddot_ref, p, gains)
            if tau_residual is not None:
                tau = tau + tau_residual
            return ControlOutput(tau=tau, actuators=None, arm_reference=np.asarray(q_ref)[..., 3:5], allocation=None)

        shape = getattr(q, "shape", None)
        ndarray, f64 = np.ndarray, np.float64
        if shape and shape[-1] == 5 and all([type(x) is ndarray and x.dtype == f64 and x.shape == shape for x in ins]):
            # fast path: float64 arrays of one shape
            lead = shape[:-1]
            flat = [x.reshape(-1, 5) for x in ins]
            if not all([x.flags.c_contiguous for x in flat]):
                flat = [np.ascontiguousarray(x) for x in flat]
        else:
            names = ("q", "qdot", "q_ref", "qdot_ref", "qddot_ref", "tau_residual")
            lead, flat = broadcast_batch(**{name: (x, 5) for name, x in zip(names, ins)})
        n = flat[0].shape[0]
        X = np.empty((n, CK.IN_LEN))
        for c, x in zip((CK.IN_Q, CK.IN_QD, CK.IN_QR, CK.IN_QDR, CK.IN_QDDR), flat[:5]):
            X[:, c:c + 5] = x
        has_res, commit = tau_residual is not None, bool(commit)
        X[:, CK.IN_RES:CK.IN_RES + 5] = flat[5] if has_res else 0.0
        out = np.empty((n, CK.OUT_LEN))
        err = np.zeros(n, dtype=np.int64)
        S, S_new = self.memory_pair(n)
        run_rows(CK.batch_controller, n, X, has_res, commit, self.kernel_constants, S, S_new, out, err)
        if err.any():  # nothing changed: the new memory is not swapped in
            self.raise_for(err, flat[0])
        if commit:
            self.swap_memory()
        if lead != (n,):
            out = out.reshape(lead + (CK.OUT_LEN,))
        info = out[..., CK.OUT_INFO:]
        allocation = AllocationInfo(residual=info[..., 0], iterations=info[..., 1].astype(np.int64),
                                    feasible=info[..., 2] > 0.5)
        return ControlOutput(tau=out[..., :5], actuators=out[..., 5:9], arm_reference=out[..., 9:11],
                             allocation=allocation, loop_residual=out[..., CK.OUT_LOOP],
                             loop_iterations=out[..., CK.OUT_LOOP + 1].astype(np.int64))

    def _call_single(self, ins, has_res: bool, commit: bool) -> ControlOutput:
        """__call__ for one state given as contiguous float64 arrays (5,) (the fast path; the control step of
        an evaluation loop, so its outputs are built without the generic constructors)."""
        out = np.empty(_OUT_LEN)
        S = self._state
        if S is None or S.shape[0] != 1:
            S = self.state_rows(1)
        code = _single_controller(ins[0], ins[1], ins[2], ins[3], ins[4], ins[5] if has_res else self._no_residual[0],
                                  has_res, commit, self.kernel_constants, S, out)
        if code != _ERR_NONE:
            self.raise_for(np.array([code]), ins[0].reshape(1, 5))
        allocation = _allocation_info(out[..., _OUT_INFO], np.array(int(out[_OUT_INFO + 1])),
                                      np.array(out[_OUT_INFO + 2] > 0.5))
        # (ControlOutput's fields set directly: its generated __init__ costs half a microsecond, on a hot path)
        result = object.__new__(ControlOutput)
        result.__dict__.update(tau=out[0:5], actuators=out[5:9], arm_reference=out[9:11], allocation=allocation,
                               loop_residual=out[_OUT_LOOP], loop_iterations=np.int64(int(out[_OUT_LOOP + 1])))
        return result


def _three(name: str, value, unit: str, lo: float, hi: float, positive: bool = False) -> tuple[float, float, float]:
    """``value`` as 3 floats in [lo, hi] (> lo if ``positive``), or a ValueError naming what was given."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        arr = None
    ok = arr is not None and arr.shape == (3,) and not np.isnan(arr).any() and bool(np.all(arr <= hi)) and bool(
        np.all(arr > lo) if positive else np.all(arr >= lo))
    if not ok or isinstance(value, (str, bytes)):
        raise ValueError(f"{name} must be 3 numbers (x, z, theta) {unit}, each {'>' if positive else '>='} {lo:g}"
                         f"{'' if hi == math.inf else f' and <= {hi:g}'}, got {value!r}")
    return (float(arr[0]), float(arr[1]), float(arr[2]))


HOLDS = ("stage", "step")


def simulate_closed_loop(
    loop: str = "paper",
    *,
    params: SoftPVTOLParams | None = None,
    gains: PassivityGains | None = None,
    q0=(5.0, 0.0, 0.2 * np.pi, 0.01 * np.pi, -0.15 * np.pi),
    qdot0=(0.0, 0.0, 0.0, 0.0, 0.0),
    reference: Callable = paper_reference,
    t_final: float = 40.0,
    dt: float = 0.01,
    input_map: str = "paper",
    plant_params: SoftPVTOLParams | None = None,
    hold: str = "stage",
    algebraic_iterations: int = 100,
    algebraic_tolerance: float = 1e-10,
) -> dict[str, np.ndarray]:
    """Simulate one of :data:`LOOPS` with fixed-step RK4 (defaults: the paper's case, Sec. 4).

    ``hold="stage"`` evaluates the controller at every RK4 stage, i.e. integrates the continuous-time
    closed loop as the paper's Simulink model does; the controller's memory (warm start, arm-reference
    history for the feedforward) advances once per step. ``hold="step"`` holds the control over each
    step (zero-order hold), as the Gymnasium env does: the actuated loops hold the actuators (B(q)
    re-evaluated at every RK4 stage), the ideal loop holds tau.

    Returns time series: ``t`` (T+1,), ``q``, ``qdot``, ``q_ref``, ``qdot_ref`` (T+1, 5); per step, at
    its start: ``tau`` (commanded, T x 5), ``tau_applied`` (through the input map, T x 5),
    ``actuators`` (T x 4, NaN for the ideal loop), ``arm_reference`` (T x 2),
    ``allocation_residual`` (T,), ``algebraic_residual`` and ``algebraic_iterations`` (T,: the algebraic
    loop's last change and passes, solved to ``algebraic_tolerance`` by default; 0 for the ideal loop);
    and ``storage`` (T+1,) along the trajectory.
    """
    if hold not in HOLDS:
        raise ValueError(f"hold must be one of {HOLDS}, got {hold!r}")
    if loop == "extended":  # a sibling controller (control/extended.py), not a passivity loop
        from .extended import simulate_extended_loop
        if (algebraic_iterations, algebraic_tolerance) != (100, 1e-10):
            raise ValueError("the extended loop has no algebraic loop: leave algebraic_iterations and "
                             "algebraic_tolerance at their defaults")
        return simulate_extended_loop(params=params, gains=gains, q0=q0, qdot0=qdot0, reference=reference,
                                      t_final=t_final, dt=dt, input_map=input_map, plant_params=plant_params,
                                      hold=hold)
    params = SoftPVTOLParams() if params is None else params
    plant = params if plant_params is None else plant_params
    ctrl = PassivityController.from_loop(
        loop, params=params, gains=gains, input_map=input_map, dt=dt, algebraic_iterations=algebraic_iterations,
        algebraic_tolerance=algebraic_tolerance,
    )
    n = int(round(t_final / dt))
    t = np.arange(n + 1) * dt
    q_ref_all, qd_ref_all = (np.array(np.broadcast_to(r, (n + 1, 5))) for r in reference(t)[:2])
    q = np.array(q0, dtype=np.float64)
    v = np.array(qdot0, dtype=np.float64)
    Q, V = np.empty((n + 1, 5)), np.empty((n + 1, 5))
    tau_cmd, tau_app = np.empty((n, 5)), np.empty((n, 5))
    act = np.full((n, 4), np.nan)
    arm_ref = np.empty((n, 2))
    resid = np.zeros(n)
    loop_resid, loop_iters = np.zeros(n), np.zeros(n, dtype=np.int64)
    Q[0], V[0] = q, v

    def closed_loop(tk, qk, vk, commit):
        out = ctrl(qk, vk, *reference(tk), commit=commit)
        tau = out.tau if out.actuators is None else generalized_forces(qk, out.actuators, plant, input_map)
        return forward_dynamics(qk, vk, tau, plant), out, tau

    for k in range(n):
        tk = t[k]
        a1, out, tau = closed_loop(tk, q, v, True)
        if out.actuators is not None:
            act[k] = out.actuators
            resid[k] = out.allocation.residual
            loop_resid[k], loop_iters[k] = out.loop_residual, out.loop_iterations
        tau_cmd[k], tau_app[k], arm_ref[k] = out.tau, tau, out.arm_reference
        if hold == "step":  # zero-order hold of the command: the actuators (B(q) at every stage), or tau
            if out.actuators is None:
                q, v = rk4_step(q, v, tau, plant, dt)
            else:
                q, v = rk4_step_actuated(q, v, out.actuators, plant, dt, input_map)
        else:
            q, v, _ = rk4_step_of_rates(lambda ts, qs, vs, _: (closed_loop(ts, qs, vs, False)[0], None), tk, q, v, dt,
                                        (a1, None))
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v))):
            raise ValueError(f"the closed loop diverged: the state is not finite after t = {t[k + 1]:.4g} s "
                             f"(loop {loop!r}, hold {hold!r}, dt = {dt:g} s); a shorter dt or other gains may keep "
                             "it stable")
        Q[k + 1], V[k + 1] = q, v
    # storage function w.r.t. the body reference and the arm references in use
    full_ref = q_ref_all.copy()
    if loop != "ideal":
        full_ref[:n, 3:5] = arm_ref
        full_ref[n, 3:5] = arm_ref[-1]
    storage = storage_function(Q, V, full_ref, qd_ref_all, params, ctrl.gains)
    return dict(
        t=t, q=Q, qdot=V, q_ref=q_ref_all, qdot_ref=qd_ref_all, tau=tau_cmd, tau_applied=tau_app,
        actuators=act, arm_reference=arm_ref, allocation_residual=resid, algebraic_residual=loop_resid,
        algebraic_iterations=loop_iters, storage=storage,
    )
