"""Integration error of the paper's actuated loop at the paper's step (docs/model.md, difference #12).

    python baselines/model_figures.py [--t-final 10] [--json baselines/results/model_figures.json]

The paper integrates its closed loop with Simulink's ode5 at a fixed 0.01 s and this package's
reproduction with classical RK4 at 0.01 s; docs/model.md used to say the two "agree to plotting
accuracy". This script measures how far a 0.01 s RK4 solution of the paper's continuous-time actuated
loop is from the converged solution: the same loop (``PassivityController`` "paper" loop, its algebraic
loop solved to 1e-10 rad in at most ``--passes`` passes from the allocation at t = 0, evaluated as a pure
function of (t, q, qdot) at every RK4 stage) integrated by RK4 at 0.01 s, 0.001 s and 0.0005 s from the
paper's initial state. The 0.001 / 0.0005 s pair bounds the reference's own error. Output: the largest
|x| and |z| differences and when they occur, and the largest change of the arm references (q_l^d, q_r^d)
between two 0.01 s steps (with the printed arctan allocation they jumped by up to 2.7 rad and an
adaptive DOP853 run, rtol = atol = 1e-7, did not finish 4 s of simulated time in 10 minutes; hence
fixed steps).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from baselines.atomic import atomic_write_text
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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--t-final", type=float, default=10.0)
    ap.add_argument("--passes", type=int, default=50, help="fixed-point passes of the algebraic loop")
    ap.add_argument("--json", type=Path, default=Path(__file__).resolve().parent / "results" / "model_figures.json")
    args = ap.parse_args(argv)
    if not (args.t_final > 0 and args.passes >= 1):
        ap.error("--t-final must be > 0 and --passes >= 1")
    t0 = time.perf_counter()
    result = compare(args.t_final, args.passes)
    for name, r in result.items():
        if not isinstance(r, dict):
            print(f"{name}: {r}")
            continue
        print(f"{name}: max |dx| {r['max_abs_x_m']:.4g} m at t = {r['t_of_max_x_s']:.2f} s, "
              f"max |dz| {r['max_abs_z_m']:.4g} m at t = {r['t_of_max_z_s']:.2f} s")
    report = {"command": "python baselines/model_figures.py", "t_final_s": args.t_final, "passes": args.passes,
              "comparisons": {k: v for k, v in result.items() if isinstance(v, dict)},
              "arm_reference_jumps": {k: v for k, v in result.items() if not isinstance(v, dict)},
              "wall_time_s": round(time.perf_counter() - t0, 1)}
    atomic_write_text(args.json, json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
