"""Reproduce the simulation section of the Soft-PVTOL paper (Sec. 4) and write figures + metrics.

    python baselines/reproduce_paper.py [--out baselines/results/paper_reproduction] [--t-final 40]

The paper's case: default parameters and gains, q(0) = (5, 0, 0.2 pi, 0.01 pi, -0.15 pi), qdot(0) = 0,
reference x = 4 sin(t/2), z = 3 cos(-t/10) + 4, theta = 0, fixed step 0.01 s, 40 s. Loops: "ideal"
(tau applied directly), "paper" (the paper's allocation and arm references as printed) and "improved"
(exact allocation + fed-forward arm references). The controller is evaluated at every RK4 stage
(continuous-time closed loop, as in the paper's Simulink model); the zero-order-hold variant that the
Gymnasium env uses is reported too (``hold="step"``).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from baselines.atomic import atomic_path, atomic_write_text
from softpvtol_gym import SoftPVTOLParams
from softpvtol_gym.control import PassivityGains, simulate_closed_loop

LOOP_NAMES = ("ideal", "paper", "improved")
WINDOWS = ((0.0, 5.0), (5.0, 20.0), (20.0, 40.0))
DEFAULT_OUT = Path(__file__).resolve().parent / "results" / "paper_reproduction"


def window_metrics(result: dict, t_final: float) -> dict:
    """RMS and max |error| of x, z, theta over the paper windows (clipped to t_final)."""
    t, err = result["t"], result["q"] - result["q_ref"]
    out = {}
    for lo, hi in WINDOWS:
        if lo >= t_final:
            continue
        m = (t >= lo) & (t <= min(hi, t_final))
        key = f"{lo:g}-{min(hi, t_final):g}s"
        out[key] = {
            name: {"rms": float(np.sqrt(np.mean(err[m, i] ** 2))), "max_abs": float(np.max(np.abs(err[m, i])))}
            for i, name in enumerate(("x", "z", "theta"))
        }
    return out


def loop_metrics(result: dict, t_final: float) -> dict:
    t = result["t"][:-1]
    act = result["actuators"]
    steady = t >= max(0.0, t_final - 10.0)
    metrics = {"tracking_error": window_metrics(result, t_final)}
    metrics["final_abs_error"] = {
        n: float(abs(result["q"][-1, i] - result["q_ref"][-1, i])) for i, n in enumerate(("x", "z", "theta"))
    }
    dV = np.diff(result["storage"])
    metrics["storage_function"] = {
        "initial": float(result["storage"][0]),
        "final": float(result["storage"][-1]),
        "steps_increasing_gt_1e-9": int(np.sum(dV > 1e-9)),
    }
    metrics["curvature_range_rad"] = {
        "q_l": [float(result["q"][:, 3].min()), float(result["q"][:, 3].max())],
        "q_r": [float(result["q"][:, 4].min()), float(result["q"][:, 4].max())],
    }
    if np.all(np.isnan(act)):
        metrics["generalized_force_steady_mean"] = [float(v) for v in result["tau"][steady].mean(axis=0)]
        return metrics
    metrics["steady_arm_torques_Nm"] = {
        "tau_l_mean": float(act[steady, 2].mean()),
        "tau_r_mean": float(act[steady, 3].mean()),
        "window": f"{max(0.0, t_final - 10.0):g}-{t_final:g}s",
    }
    metrics["thrust_range_N"] = {
        "T_l": [float(act[:, 0].min()), float(act[:, 0].max())],
        "T_r": [float(act[:, 1].min()), float(act[:, 1].max())],
    }
    metrics["desired_curvature_range_rad"] = {
        "q_l_d": [float(result["arm_reference"][:, 0].min()), float(result["arm_reference"][:, 0].max())],
        "q_r_d": [float(result["arm_reference"][:, 1].min()), float(result["arm_reference"][:, 1].max())],
    }
    arm_err = result["q"][:-1, 3:5] - result["arm_reference"]
    metrics["arm_tracking_rms_rad_last_20s"] = float(np.sqrt(np.mean(arm_err[t >= t_final / 2] ** 2)))
    metrics["allocation_residual_max"] = float(np.max(result["allocation_residual"]))
    return metrics


def plot_all(results: dict[str, dict], out: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colors = {"ideal": "tab:green", "paper": "tab:red", "improved": "tab:blue"}
    files = []

    def save(fig, name):
        fig.tight_layout()
        with atomic_path(out / name) as tmp:
            fig.savefig(tmp, format="png", dpi=110)
        plt.close(fig)
        files.append(name)

    any_r = next(iter(results.values()))
    t = any_r["t"]
    # positions and velocities vs reference (paper Fig. 'pos_att')
    fig, axes = plt.subplots(3, 2, figsize=(11, 7.5), sharex=True)
    for i, (name, unit) in enumerate((("x", "m"), ("z", "m"), ("theta", "rad"))):
        axes[i, 0].plot(t, any_r["q_ref"][:, i], "k--", lw=1.2, label="reference")
        axes[i, 1].plot(t, any_r["qdot_ref"][:, i], "k--", lw=1.2, label="reference")
        for loop, r in results.items():
            axes[i, 0].plot(t, r["q"][:, i], color=colors[loop], lw=1, label=loop)
            axes[i, 1].plot(t, r["qdot"][:, i], color=colors[loop], lw=1, label=loop)
        axes[i, 0].set_ylabel(f"{name} [{unit}]")
        axes[i, 1].set_ylabel(f"d{name}/dt [{unit}/s]")
    axes[0, 0].legend(fontsize=8)
    axes[-1, 0].set_xlabel("t [s]")
    axes[-1, 1].set_xlabel("t [s]")
    fig.suptitle("Pose and velocities vs reference (paper Fig. pos_att)")
    save(fig, "positions.png")
    # tracking errors, log scale (paper Fig. 'errors')
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    for i, (name, unit) in enumerate((("x", "m"), ("z", "m"), ("theta", "rad"))):
        for loop, r in results.items():
            axes[i].semilogy(t, np.abs(r["q"][:, i] - r["q_ref"][:, i]) + 1e-16, color=colors[loop], lw=1, label=loop)
        axes[i].set_title(f"|{name} - {name}_ref| [{unit}]")
        axes[i].set_xlabel("t [s]")
        axes[i].set_ylim(1e-9, 20)
    axes[0].legend(fontsize=8)
    save(fig, "errors.png")
    # thrusts and arm torques (paper Fig. 'thrusts_qlqr' left, 'control_inputs' arm rows)
    fig, axes = plt.subplots(2, 2, figsize=(11, 6), sharex=True)
    for loop, r in results.items():
        if np.all(np.isnan(r["actuators"])):
            continue
        for j, (ax, lab) in enumerate(zip(axes.ravel(), ("T_l [N]", "T_r [N]", "tau_l [N m]", "tau_r [N m]"))):
            ax.plot(t[:-1], r["actuators"][:, j], color=colors[loop], lw=1, label=loop)
            ax.set_ylabel(lab)
    for ax in axes[1]:
        ax.set_xlabel("t [s]")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle("Thrusts and arm torques (actuated loops)")
    save(fig, "actuators.png")
    # curvatures and their references (paper Fig. 'thrusts_qlqr' right)
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.6))
    for loop, r in results.items():
        if np.all(np.isnan(r["actuators"])):
            continue
        for j, name in enumerate(("q_l", "q_r")):
            axes[j].plot(t, r["q"][:, 3 + j], color=colors[loop], lw=1, label=f"{loop}: {name}")
            axes[j].plot(t[:-1], r["arm_reference"][:, j], color=colors[loop], lw=1, ls="--", label=f"{loop}: {name}^d")
    for j, name in enumerate(("q_l", "q_r")):
        axes[j].set_ylabel(f"{name} [rad]")
        axes[j].set_xlabel("t [s]")
        axes[j].legend(fontsize=7)
    save(fig, "curvatures.png")
    # generalized forces (paper Fig. 'control_inputs')
    fig, axes = plt.subplots(1, 5, figsize=(16, 3.2))
    for loop, r in results.items():
        for j, lab in enumerate(("tau_x [N]", "tau_z [N]", "tau_theta [N m]", "tau_l [N m]", "tau_r [N m]")):
            axes[j].plot(t[:-1], r["tau_applied"][:, j], color=colors[loop], lw=1, label=loop)
            axes[j].set_title(lab, fontsize=9)
            axes[j].set_xlabel("t [s]")
    axes[0].legend(fontsize=7)
    save(fig, "generalized_forces.png")
    # x-z path (paper Fig. 'traj')
    fig, ax = plt.subplots(figsize=(5.5, 4.5))
    ax.plot(any_r["q_ref"][:, 0], any_r["q_ref"][:, 1], "k--", lw=1, label="reference")
    for loop, r in results.items():
        ax.plot(r["q"][:, 0], r["q"][:, 1], color=colors[loop], lw=1, label=loop)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("z [m]")
    ax.legend(fontsize=8)
    save(fig, "trajectory_xz.png")
    return files


def run(out: Path, t_final: float = 40.0, plots: bool = True) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    params, gains = SoftPVTOLParams(), PassivityGains()
    results, metrics = {}, {}
    for hold in ("stage", "step"):
        for loop in LOOP_NAMES:
            t0 = time.perf_counter()
            r = simulate_closed_loop(loop, params=params, gains=gains, t_final=t_final, hold=hold)
            key = loop if hold == "stage" else f"{loop}_zero_order_hold"
            metrics[key] = loop_metrics(r, t_final)
            metrics[key]["wall_time_s"] = round(time.perf_counter() - t0, 2)
            if hold == "stage":
                results[loop] = r
    report = {
        "command": "python baselines/reproduce_paper.py" + (f" --t-final {t_final:g}" if t_final != 40 else ""),
        "case": {
            "params": {k: getattr(params, k) for k in params.__dataclass_fields__},
            "gains": {"lam": gains.lam, "k": gains.k},
            "q0": [5.0, 0.0, 0.2 * np.pi, 0.01 * np.pi, -0.15 * np.pi],
            "dt": 0.01,
            "t_final": t_final,
            "integrator": "RK4, controller evaluated at every stage (loops without suffix) "
            "or held over the step (_zero_order_hold)",
        },
        "loops": metrics,
    }
    atomic_write_text(out / "metrics.json", json.dumps(report, indent=2))
    if plots:
        report["figures"] = plot_all(results, out)
    return report


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output folder (PNG figures + metrics.json)")
    parser.add_argument("--t-final", type=float, default=40.0, help="simulated time [s] (paper: 40)")
    parser.add_argument("--no-plots", action="store_true", help="write metrics.json only")
    args = parser.parse_args(argv)
    if not (np.isfinite(args.t_final) and args.t_final > 0):
        parser.error(f"--t-final must be > 0, got {args.t_final}")
    report = run(args.out, args.t_final, plots=not args.no_plots)
    for loop, m in report["loops"].items():
        last = list(m["tracking_error"])[-1]
        e = m["tracking_error"][last]
        print(
            f"{loop:26s} RMS over {last}: x {e['x']['rms']:.2e} m, z {e['z']['rms']:.2e} m, "
            f"theta {e['theta']['rms']:.2e} rad; final |x err| {m['final_abs_error']['x']:.1e} m"
        )
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    os.environ.setdefault("MPLBACKEND", "Agg")
    raise SystemExit(main())
