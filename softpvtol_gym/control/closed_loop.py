"""The paper's closed loop as reusable, batched pieces.

Actuated loop (paper Fig. 'controldiagram'): the passivity controller gives tau for the body; the
allocation turns its body rows into thrusts (T_l, T_r) and desired curvatures (q_l^d, q_r^d); the
controller's arm rows, with those curvatures as arm references, give the arm torques (tau_l, tau_r).
The plant is driven through ``generalized_forces`` with the *actual* curvatures, so arm lag is real.

The paper closes an algebraic loop (the arm references enter the body rows through D and C) with
Simulink's algebraic-constraint block; here the body rows use the arm references of the previous
control step and the arm rows the new ones (one-step delay, documented in docs/control.md).

Loops (``LOOPS``):
    ``"paper"``     paper allocation, arm references with zero velocity/acceleration (as printed).
    ``"exact"``     exact allocation, arm references with zero velocity/acceleration: the robust
                    choice under actuator saturation and zero-order hold (the env's base controller).
    ``"improved"``  exact allocation and arm references fed forward with their velocity and
                    acceleration (second-order backward differences of q^d): converges (see README).
    ``"ideal"``     tau applied directly as the generalized force (the setting of Theorem 1).
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np

from ..dynamics import forward_dynamics, generalized_forces, input_map_code
from ..integrators import rk4_step
from ..params import SoftPVTOLParams
from .allocation import ALLOCATION_METHODS, AllocationInfo, allocate
from .passivity import PassivityGains, passivity_control, storage_function
from .references import paper_reference

__all__ = ["LOOPS", "ControlOutput", "PassivityController", "simulate_closed_loop"]

LOOPS: dict[str, dict] = {
    "paper": dict(allocation="paper", arm_feedforward=False),
    "exact": dict(allocation="exact", arm_feedforward=False),
    "improved": dict(allocation="exact", arm_feedforward=True),
    "ideal": dict(allocation="ideal", arm_feedforward=False),
}


@dataclasses.dataclass
class ControlOutput:
    """One control step. Shapes: batch + (k,).

    tau: generalized force the controller asks for (5). For the ideal loop it is applied as is.
    actuators: (T_l, T_r, tau_l, tau_r) to apply through ``generalized_forces`` (None for ideal).
    arm_reference: (q_l^d, q_r^d) used by the arm rows. allocation: diagnostics (None for ideal).
    """

    tau: np.ndarray
    actuators: np.ndarray | None
    arm_reference: np.ndarray
    allocation: AllocationInfo | None


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
        algebraic_iterations: fixed-point passes over the algebraic loop body rows -> allocation ->
            arm references per call (1: the body rows use the previous step's arm references).
        feedforward_limits: bounds (rad/s, rad/s^2) on the fed-forward arm reference velocity and
            acceleration.
    """

    def __init__(
        self,
        params: SoftPVTOLParams | None = None,
        gains: PassivityGains | None = None,
        allocation: str = "paper",
        input_map: str = "paper",
        arm_feedforward: bool = False,
        dt: float = 0.01,
        algebraic_iterations: int = 1,
        feedforward_limits: tuple[float, float] = (5.0, 50.0),
    ) -> None:
        if allocation != "ideal" and allocation not in ALLOCATION_METHODS:
            raise ValueError(
                f"allocation must be one of {sorted([*ALLOCATION_METHODS, 'ideal'])}, got {allocation!r}"
            )
        input_map_code(input_map)
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
        self.feedforward_limits = (float(feedforward_limits[0]), float(feedforward_limits[1]))
        self.reset()

    @classmethod
    def from_loop(cls, loop: str, **kwargs) -> "PassivityController":
        """A controller configured as one of :data:`LOOPS` (``"paper"``, ``"improved"``, ``"ideal"``)."""
        if loop not in LOOPS:
            raise ValueError(f"loop must be one of {sorted(LOOPS)}, got {loop!r}")
        return cls(**{**LOOPS[loop], **kwargs})

    def reset(self, mask: np.ndarray | None = None) -> None:
        """Forget the warm start and arm-reference history (all, or the batch entries where mask)."""
        if mask is None or self._history is None:
            self._history: list[np.ndarray] | None = None
            self._warm: np.ndarray | None = None
            return
        mask = np.asarray(mask, dtype=bool)
        # entries being reset restart from "no history": re-seeded from the state on the next call
        self._reseed = mask if self._reseed is None else (self._reseed | mask)
        if self._warm is not None:
            self._warm[mask] = np.nan  # solved again from the default start

    _history = None
    _reseed = None

    # ------------------------------------------------------------------ arm reference bookkeeping
    def _arm_reference(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Arm references for the body rows: the last allocated curvatures (or, before the first
        allocation / right after a reset, the measured ones) with their feedforward derivatives."""
        if self._history is None:
            zero = np.zeros_like(q[..., 3:5])
            return q[..., 3:5].copy(), zero, zero
        ref = self._history[-1].copy()
        vel, acc = self._derivatives()
        if self._reseed is not None:
            ref[self._reseed] = q[..., 3:5][self._reseed]
            vel[self._reseed] = 0.0
            acc[self._reseed] = 0.0
        return ref, vel, acc

    def _derivatives(self) -> tuple[np.ndarray, np.ndarray]:
        h = self._history
        zero = np.zeros_like(h[-1])
        if not self.arm_feedforward:
            return zero, zero
        dt = self.dt
        vmax, amax = self.feedforward_limits
        # second-order backward differences, bounded so that the large, fast changes of q^d in the
        # initial transient cannot close a high-gain loop through the arm torques
        vel = np.clip((3.0 * h[-1] - 4.0 * h[-2] + h[-3]) / (2.0 * dt), -vmax, vmax)
        acc = np.clip((2.0 * h[-1] - 5.0 * h[-2] + 4.0 * h[-3] - h[-4]) / (dt * dt), -amax, amax)
        return vel, acc

    def _push(self, arm_ref: np.ndarray) -> None:
        """Record the allocated curvatures; a fresh (or freshly reset) entry gets a flat history so
        the differentiator never sees the jump from the measured to the first allocated curvature."""
        if self._history is None:
            self._history = [arm_ref.copy() for _ in range(4)]
            self._reseed = None
            return
        self._history.append(arm_ref.copy())
        self._history.pop(0)
        if self._reseed is not None:
            for h in self._history[:-1]:
                h[self._reseed] = arm_ref[self._reseed]
            self._reseed = None

    # --------------------------------------------------------------------------------- the step
    def __call__(self, q, qdot, q_ref, qdot_ref, qddot_ref, tau_residual=None, commit: bool = True) -> ControlOutput:
        """One control step from the state and the body reference (arm entries of the refs ignored
        in the actuated loops, used as given in the ideal loop). ``tau_residual`` (..., 5) is added
        to the controller's tau before allocation (body rows) and to the arm torques (arm rows).
        ``commit=False`` evaluates without advancing the controller's memory (RK4 stages)."""
        q = np.asarray(q, dtype=np.float64)
        qdot = np.asarray(qdot, dtype=np.float64)
        p, gains = self.params, self.gains
        if self.allocation == "ideal":
            tau = passivity_control(q, qdot, q_ref, qdot_ref, qddot_ref, p, gains)
            if tau_residual is not None:
                tau = tau + tau_residual
            return ControlOutput(tau=tau, actuators=None, arm_reference=np.asarray(q_ref)[..., 3:5], allocation=None)

        q_ref, qdot_ref, qddot_ref = (np.array(np.broadcast_to(r, q.shape), dtype=np.float64) for r in (q_ref, qdot_ref, qddot_ref))
        arm, arm_d, arm_dd = self._arm_reference(q)
        warm = self._warm  # rows set to NaN by reset(mask) are solved from the cold start
        for _ in range(self.algebraic_iterations):
            q_ref[..., 3:5], qdot_ref[..., 3:5], qddot_ref[..., 3:5] = arm, arm_d, arm_dd
            tau = passivity_control(q, qdot, q_ref, qdot_ref, qddot_ref, p, gains)
            if tau_residual is not None:
                tau = tau + tau_residual
            alloc, info = allocate(
                tau, q, p, self.allocation, input_map=self.input_map, warm_start=warm, return_info=True
            )
            warm = alloc
            arm = alloc[..., 2:4]
        if commit:
            self._warm = alloc.copy()
            self._push(arm)
            arm_d, arm_dd = self._derivatives()
        q_ref[..., 3:5], qdot_ref[..., 3:5], qddot_ref[..., 3:5] = arm, arm_d, arm_dd
        tau_arm = passivity_control(q, qdot, q_ref, qdot_ref, qddot_ref, p, gains)[..., 3:5]
        if tau_residual is not None:
            tau_arm = tau_arm + np.asarray(tau_residual)[..., 3:5]
        actuators = np.concatenate([alloc[..., :2], tau_arm], axis=-1)
        if self.input_map == "exact":  # cancel the thrusts' own work on the curvatures
            thrust_only = actuators.copy()
            thrust_only[..., 2:4] = 0.0
            actuators[..., 2:4] -= generalized_forces(q, thrust_only, p, "exact")[..., 3:5]
        tau_cmd = tau.copy()
        tau_cmd[..., 3:5] = tau_arm
        return ControlOutput(tau=tau_cmd, actuators=actuators, arm_reference=np.array(arm), allocation=info)


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
    algebraic_iterations: int | None = None,
) -> dict[str, np.ndarray]:
    """Simulate one of :data:`LOOPS` with fixed-step RK4 (defaults: the paper's case, Sec. 4).

    ``hold="stage"`` evaluates the controller at every RK4 stage, i.e. integrates the continuous-time
    closed loop as the paper's Simulink model does, and solves the algebraic loop with 3 fixed-point
    passes; the controller's memory (warm start, arm-reference history for the feedforward) advances
    once per step. ``hold="step"`` holds the control over each step (zero-order hold), as the
    Gymnasium env does.

    Returns time series: ``t`` (T+1,), ``q``, ``qdot``, ``q_ref``, ``qdot_ref`` (T+1, 5); per step, at
    its start: ``tau`` (commanded, T x 5), ``tau_applied`` (through the input map, T x 5),
    ``actuators`` (T x 4, NaN for the ideal loop), ``arm_reference`` (T x 2),
    ``allocation_residual`` (T,); and ``storage`` (T+1,) along the trajectory.
    """
    if hold not in HOLDS:
        raise ValueError(f"hold must be one of {HOLDS}, got {hold!r}")
    params = SoftPVTOLParams() if params is None else params
    plant = params if plant_params is None else plant_params
    if algebraic_iterations is None:
        algebraic_iterations = 3 if hold == "stage" else 1
    ctrl = PassivityController.from_loop(
        loop, params=params, gains=gains, input_map=input_map, dt=dt, algebraic_iterations=algebraic_iterations
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
        tau_cmd[k], tau_app[k], arm_ref[k] = out.tau, tau, out.arm_reference
        if hold == "step":
            q, v = rk4_step(q, v, tau, plant, dt)
        else:
            h = 0.5 * dt
            a2 = closed_loop(tk + h, q + h * v, v + h * a1, False)[0]
            a3 = closed_loop(tk + h, q + h * (v + h * a1), v + h * a2, False)[0]
            a4 = closed_loop(tk + dt, q + dt * (v + h * a2), v + dt * a3, False)[0]
            q = q + dt / 6.0 * (6.0 * v + dt * (a1 + a2 + a3))
            v = v + dt / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
        Q[k + 1], V[k + 1] = q, v
    # storage function w.r.t. the body reference and the arm references in use
    full_ref = q_ref_all.copy()
    if loop != "ideal":
        full_ref[:n, 3:5] = arm_ref
        full_ref[n, 3:5] = arm_ref[-1]
    storage = storage_function(Q, V, full_ref, qd_ref_all, params, ctrl.gains)
    return dict(
        t=t, q=Q, qdot=V, q_ref=q_ref_all, qdot_ref=qd_ref_all, tau=tau_cmd, tau_applied=tau_app,
        actuators=act, arm_reference=arm_ref, allocation_residual=resid, storage=storage,
    )
