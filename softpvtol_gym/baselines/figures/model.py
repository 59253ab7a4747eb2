"""The paper model's closed loop under RK4 at several steps, against a reference (``softpvtol model-figures``)."""

from __future__ import annotations

import numpy as np

from softpvtol_gym import SoftPVTOLParams
from softpvtol_gym.control.closed_loop import PassivityController
from softpvtol_gym.control.references import paper_reference
from softpvtol_gym.dynamics import forward_dynamics, generalized_forces

Q0 = np.array([5.0, 0.0, 0.2 * np.pi, 0.01 * np.pi, -0.15 * np.pi])
STEPS = (0.01, 0.001, 0.0005)


def paper_loop_rk4(t_final: float, dt: float, passes: int) -> tuple[np.ndarray, np.ndarray]:
    """q (n + 1, 5) of the paper's actuated loop, RK4 at dt, the controller at every stage, and the arm
    references (q_l^d, q_r^d) (n, 2) at the start of each step."""
    p = SoftPVTOLParams()
    ctrl = PassivityController.from_loop("paper", params=p, input_map="paper", dt=0.01, algebraic_iterations=passes)
    q, v = Q0.copy(), np.zeros(5)
    ctrl(q, v, *paper_reference(0.0), commit=True)  # the allocation at t = 0: every call starts from it

    def acc(t, q, v):
        out = ctrl(q, v, *paper_reference(t), commit=False)
        return forward_dynamics(q, v, generalized_forces(q, out.actuators, p, "paper"), p), out.arm_reference

    n, h = int(round(t_final / dt)), 0.5 * dt
    Q, arm = np.empty((n + 1, 5)), np.empty((n, 2))
    Q[0] = q
    for k in range(n):
        t = k * dt
        a1, arm[k] = acc(t, q, v)
        a2 = acc(t + h, q + h * v, v + h * a1)[0]
        a3 = acc(t + h, q + h * (v + h * a1), v + h * a2)[0]
        a4 = acc(t + dt, q + dt * (v + h * a2), v + dt * a3)[0]
        q = q + dt / 6.0 * (6.0 * v + dt * (a1 + a2 + a3))
        v = v + dt / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
        Q[k + 1] = q
    return Q, arm


def compare(t_final: float, passes: int = 50, steps=STEPS) -> dict:
    """Largest |x|, |z| differences of RK4 at each of ``steps`` but the last from RK4 at the last."""
    runs, arms = {}, {}
    for dt in steps:
        runs[dt], arms[dt] = paper_loop_rk4(t_final, dt, passes)
    ref_dt = steps[-1]
    jumps = np.abs(np.diff(arms[steps[0]], axis=0)).max(axis=0)
    out = {f"largest_arm_reference_change_per_{steps[0]:g}_s_step_rad": [float(jumps[0]), float(jumps[1])]}
    for dt in steps[:-1]:
        stride = int(round(dt / ref_dt))
        d = np.abs(runs[dt][:, :2] - runs[ref_dt][::stride, :2])
        out[f"rk4_{dt:g}_vs_rk4_{ref_dt:g}"] = {
            "max_abs_x_m": float(d[:, 0].max()), "t_of_max_x_s": round(float(d[:, 0].argmax() * dt), 6),
            "max_abs_z_m": float(d[:, 1].max()), "t_of_max_z_s": round(float(d[:, 1].argmax() * dt), 6),
        }
    return out
