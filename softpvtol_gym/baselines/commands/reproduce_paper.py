"""Reproduce the simulation section of the Soft-PVTOL paper (Sec. 4) and write figures + metrics.

    softpvtol reproduce-paper [--out results/paper_reproduction] [--t-final 40] [--no-steady]
    softpvtol reproduce-paper --render-only --out results/paper_reproduction  # tables only

In a source checkout ``python baselines/reproduce_paper.py`` writes ``results/paper_reproduction``
and refreshes its two tables in ``docs/control.md``.

The paper's case: default parameters and gains, q(0) = (5, 0, 0.2 pi, 0.01 pi, -0.15 pi), qdot(0) = 0,
reference x = 4 sin(t/2), z = 3 cos(-t/10) + 4, theta = 0, fixed step 0.01 s, 40 s. Loops: "ideal"
(tau applied directly), "paper" (the paper's allocation and arm references as printed), "improved"
(exact allocation + fed-forward arm references) and "bounded" (the improved loop with bounded demands,
the env's default). The controller is evaluated at every RK4 stage (continuous-time closed loop, as
in the paper's Simulink model); the zero-order-hold variant that the Gymnasium env uses is reported
too (``hold="step"``).

The steady-state study (``steady_state`` in metrics.json, ``steady_state.png``; skipped with
``--no-steady``) runs the loops that feed the arm references forward, and the ideal loop, for 80 s
from the paper's initial state and 5 perturbed ones, at dt = 0.01, 0.005 and 0.002 s and both holds,
and reports the max |x|, |z| error and the RMS position error over 60-80 s: the error floor that is
left after the transient.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from softpvtol_gym import SoftPVTOLParams
from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.util.args import (
    Parser,
    check_output_dir,
    check_output_file,
    command_main,
    float_arg,
    read_json_report,
    refuse_overwrite,
)
from softpvtol_gym.baselines.util.atomic import atomic_path, atomic_write_text
from softpvtol_gym.baselines.util.blocks import check_page, write_block
from softpvtol_gym.baselines.util.paths import Layout
from softpvtol_gym.control import PassivityGains, simulate_closed_loop

LOOP_NAMES = ("ideal", "paper", "improved", "bounded")
PAPER_Q0 = (5.0, 0.0, 0.2 * np.pi, 0.01 * np.pi, -0.15 * np.pi)
STEADY_LOOPS = ("ideal", "improved", "bounded")
STEADY_DTS = (0.01, 0.005, 0.002)
STEADY_T_FINAL, STEADY_WINDOW = 80.0, (60.0, 80.0)


#: the longest simulation the command accepts [s]: the paper simulates 40 s; the trajectories are kept in memory
MAX_T_FINAL_S = 1000.0

def steady_initial_states(n_perturbed: int = 5, seed: int = 0) -> list[tuple[float, ...]]:
    """The paper's q(0) and ``n_perturbed`` others: x, z +- 0.5 m, theta +- 0.1 rad, curvatures +- 0.05 rad
    (uniform, seeded)."""
    rng = np.random.default_rng(seed)
    spread = np.array([0.5, 0.5, 0.1, 0.05, 0.05])
    return [PAPER_Q0] + [tuple(float(v) for v in np.array(PAPER_Q0) + rng.uniform(-1, 1, 5) * spread)
                         for _ in range(n_perturbed)]


def steady_state_study() -> dict:
    """Error floors over 60-80 s (see the module docstring). Returns {loop: {hold: {dt: {...}}}}."""
    lo, hi = STEADY_WINDOW
    study = {"initial_states": steady_initial_states(), "t_final": STEADY_T_FINAL,
             "window_s": list(STEADY_WINDOW), "loops": {}}
    for loop in STEADY_LOOPS:
        for hold in ("stage", "step"):
            for dt in STEADY_DTS:
                cells = []
                for q0 in study["initial_states"]:
                    r = simulate_closed_loop(loop, q0=q0, t_final=STEADY_T_FINAL, dt=dt, hold=hold)
                    m = (r["t"] >= lo) & (r["t"] <= hi)
                    err = r["q"][m, :2] - r["q_ref"][m, :2]
                    cells.append({"max_abs_x": float(np.abs(err[:, 0]).max()),
                                  "max_abs_z": float(np.abs(err[:, 1]).max()),
                                  "rms_position": float(np.sqrt(np.mean(np.sum(err**2, axis=1))))})
                study["loops"].setdefault(loop, {}).setdefault(hold, {})[f"{dt:g}"] = {
                    "per_initial_state": cells,
                    "worst_max_abs_xz": max(max(c["max_abs_x"], c["max_abs_z"]) for c in cells),
                    "worst_rms_position": max(c["rms_position"] for c in cells),
                }
    return study


def steady_state_table(study: dict) -> str:
    """Markdown table of the steady-state study (README)."""
    lines = ["| loop | hold | " + " | ".join(f"dt = {dt:g} s" for dt in STEADY_DTS) + " |",
             "|---|---|" + "---|" * len(STEADY_DTS)]
    for loop, holds in study["loops"].items():
        for hold, by_dt in holds.items():
            cells = [f"{by_dt[f'{dt:g}']['worst_max_abs_xz']:.1e} / {by_dt[f'{dt:g}']['worst_rms_position']:.1e}"
                     for dt in STEADY_DTS]
            lines.append(f"| `{loop}` | {hold} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def loops_table(report: dict) -> str:
    """Markdown table of the 40 s runs (README): RMS errors per window, final |x err|, steady arm torques."""
    lines = ["| loop | x 0–5 s | x 5–20 s | x 20–40 s | z 20–40 s | θ 20–40 s | \\|x err\\| at 40 s | "
             "steady τ_l / τ_r [N m] | algebraic loop: max residual [rad] / mean passes |",
             "|---|---|---|---|---|---|---|---|---|"]
    for loop, m in report["loops"].items():
        te = m["tracking_error"]
        cells = [f"{te['0-5s']['x']['rms']:.2e}", f"{te['5-20s']['x']['rms']:.2e}", f"{te['20-40s']['x']['rms']:.2e}",
                 f"{te['20-40s']['z']['rms']:.2e}", f"{te['20-40s']['theta']['rms']:.2e}",
                 f"{m['final_abs_error']['x']:.1e}"]
        arm = m.get("steady_arm_torques_Nm")
        cells.append(f"{arm['tau_l_mean']:.3f} / {arm['tau_r_mean']:.3f}" if arm else "–")
        alg = m.get("algebraic_loop")
        cells.append(f"{alg['residual_max_rad']:.1e} / {alg['passes_mean']:.1f}" if alg else "–")
        lines.append(f"| `{loop}` | " + " | ".join(cells) + " |")
    return "\n".join(lines)


README_SOURCE = "results/paper_reproduction/metrics.json"


def plot_steady(study: dict, out: Path) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.2))
    colors = {"ideal": "tab:green", "improved": "tab:blue", "bounded": "tab:purple"}
    for loop, holds in study["loops"].items():
        for hold, by_dt in holds.items():
            ys = [by_dt[f"{dt:g}"]["worst_max_abs_xz"] for dt in STEADY_DTS]
            ax.loglog(STEADY_DTS, ys, marker="o" if hold == "stage" else "s", ls="-" if hold == "stage" else "--",
                      color=colors[loop], label=f"{loop}, hold={hold}")
    ax.set_xlabel("dt [s]")
    ax.set_ylabel("max |x|, |z| error over 60-80 s [m] (worst of 6 ICs)")
    ax.legend(fontsize=7)
    ax.set_title("Error floor after the transient")
    fig.tight_layout()
    with atomic_path(out / "steady_state.png") as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)
    return "steady_state.png"
WINDOWS = ((0.0, 5.0), (5.0, 20.0), (20.0, 40.0))


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
    metrics["algebraic_loop"] = {"residual_max_rad": float(np.max(result["algebraic_residual"])),
                                 "passes_mean": float(np.mean(result["algebraic_iterations"])),
                                 "passes_max": int(np.max(result["algebraic_iterations"]))}
    return metrics


def plot_all(results: dict[str, dict], out: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colors = {"ideal": "tab:green", "paper": "tab:red", "improved": "tab:blue", "bounded": "tab:purple"}
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


def run(out: Path, t_final: float = 40.0, plots: bool = True, steady: bool = True) -> dict:
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
            "q0": list(PAPER_Q0),
            "dt": 0.01,
            "t_final": t_final,
            "integrator": "RK4, controller evaluated at every stage (loops without suffix) "
            "or held over the step (_zero_order_hold)",
        },
        "loops": metrics,
    }
    if steady:
        t0 = time.perf_counter()
        report["steady_state"] = steady_state_study()
        report["steady_state"]["wall_time_s"] = round(time.perf_counter() - t0, 1)
    atomic_write_text(out / "metrics.json", json.dumps(report, indent=2))
    if plots:
        report["figures"] = plot_all(results, out)
        if steady:
            report["figures"].append(plot_steady(report["steady_state"], out))
    return report


#: the page's generated blocks: (name, source)
PAGE_BLOCKS = [("reproduce_paper.py loops", README_SOURCE), ("reproduce_paper.py steady state", README_SOURCE)]


def _write_blocks(report: dict, page: Path) -> bool:
    """Refresh the loops and steady-state tables in ``page``; False if it has neither block."""
    wrote = write_block("reproduce_paper.py loops", README_SOURCE, loops_table(report), page)
    return write_block("reproduce_paper.py steady state", README_SOURCE, steady_state_table(report["steady_state"]),
                       page) or wrote


def _main(argv, layout: Layout, prog: str) -> int:
    os.environ.setdefault("MPLBACKEND", "Agg")
    default_out = layout.results / "paper_reproduction"
    parser = Parser(prog=prog, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=default_out,
                        help="output folder (PNG figures + metrics.json; default: %(default)s)")
    parser.add_argument("--t-final", type=float_arg(0.0, MAX_T_FINAL_S, lo_open=True), default=40.0,
                        help=f"simulated time [s] (paper: 40; at most {MAX_T_FINAL_S:g})")
    parser.add_argument("--no-plots", action="store_true", help="write metrics.json only")
    parser.add_argument("--no-steady", action="store_true", help="skip the 80 s steady-state study (minutes)")
    parser.add_argument("--render-only", action="store_true",
                        help="simulate nothing: print the tables of --out/metrics.json and refresh the generated "
                             "blocks")
    parser.add_argument("--page", type=Path, default=None,
                        help=f"Markdown file whose generated table blocks are refreshed from the default run (default: "
                             f"{layout.doc('control.md')}, where it has them)")
    parser.add_argument("--force", action="store_true",
                        help="let a run with other settings overwrite the default output folder's metrics.json")
    args = parser.parse_args(argv)
    if not args.render_only:
        refuse_overwrite(parser, args, ("t_final", "no_steady"),
                         [(args.out / "metrics.json", default_out / "metrics.json", "--out")])
        check_output_dir(args.out, "--out")  # before simulating anything
    # the page's tables show the default run (40 s with the steady-state study, in the default folder) only
    default_run = (args.render_only or (args.t_final == 40.0 and not args.no_steady)) and (
        args.out.resolve() == default_out.resolve())
    page = args.page or layout.doc("control.md")
    if args.page is not None:
        check_page(args.page, PAGE_BLOCKS)
        if not default_run:
            parser.error(f"--page {args.page}: the page's tables show the default run ({default_out}, 40 s, with "
                         f"the steady-state study) only; leave --page out for this run")
    if page is not None and page.exists():
        check_output_file(page, force=True, option="--page")
    if args.render_only:
        report = read_json_report(args.out / "metrics.json", "paper reproduction metrics")
        if "loops" not in report or "steady_state" not in report:
            raise ConfigError(f"{args.out / 'metrics.json'} lacks 'loops' or 'steady_state' (a run without "
                              f"--no-steady writes both)")
        print(loops_table(report))
        print(steady_state_table(report["steady_state"]))
    else:
        report = run(args.out, args.t_final, plots=not args.no_plots, steady=not args.no_steady)
        for loop, m in report["loops"].items():
            last = list(m["tracking_error"])[-1]
            e = m["tracking_error"][last]
            print(
                f"{loop:26s} RMS over {last}: x {e['x']['rms']:.2e} m, z {e['z']['rms']:.2e} m, "
                f"theta {e['theta']['rms']:.2e} rad; final |x err| {m['final_abs_error']['x']:.1e} m"
            )
        if "steady_state" in report:
            print("steady state, worst over 6 initial states: max |x|,|z| error / RMS position error over 60-80 s [m]")
            print(steady_state_table(report["steady_state"]))
        print(f"wrote {args.out}")
    if page is not None and default_run and page.is_file() and _write_blocks(report, page):
        print(f"updated the tables in {page}")
    return 0


main = command_main("reproduce_paper.py", _main,
                    "``softpvtol reproduce-paper``: figures and metrics under ``layout`` (default: ``./results/``).")
