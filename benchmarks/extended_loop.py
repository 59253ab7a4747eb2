"""The extended loop on the paper's case, and one env episode; writes the JSON and the tables.

    python benchmarks/extended_loop.py --out benchmarks/extended_loop.json --docs docs/control.md README.md

Simulation (``simulate_closed_loop("extended", t_final=80, dt=...)``): the paper's q(0) and the 5 perturbed
starts of ``reproduce_paper.steady_initial_states()`` (simulated as one batch), hold "stage" (controller
at every RK4 stage, the extension integrated with the plant) and "step" (actuators held over each step,
the env's zero-order hold), dt = 0.01, 0.005, 0.002 s; per cell the worst of the six starts of the max
|x|, |z| error and the RMS position error over 60-80 s. The bounded loop's figures are read from the
paper reproduction's committed metrics.json (``python baselines/reproduce_paper.py``), same starts and
window. The env part: one ``track_paper`` nominal episode (actuators mode, default limits, seed 0) of
``ExtendedPolicy`` and of ``PassivityPolicy`` (bounded): RMS position error over 30-40 s, the share of
steps with a saturated actuator, the end of the episode. ``--docs`` replaces the generated blocks
(``extended_loop.py``) in the pages given. Tables are generated from the JSON; never edit them by hand.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from softpvtol_gym.baselines.commands.reproduce_paper import (  # noqa: E402
    README_SOURCE,
    STEADY_DTS,
    STEADY_T_FINAL,
    STEADY_WINDOW,
    steady_initial_states,
)
from softpvtol_gym.baselines.util.atomic import atomic_write_text  # noqa: E402
from softpvtol_gym.baselines.util.blocks import write_block  # noqa: E402
from softpvtol_gym.control import simulate_closed_loop  # noqa: E402

SOURCE = "benchmarks/extended_loop.json"
BLOCK = "extended_loop.py"
ENV_BLOCK = "extended_loop.py env"


def simulation_study(report: dict, out_path: Path, holds=("stage", "step"), dts=STEADY_DTS,
                     t_final=STEADY_T_FINAL) -> dict:
    """Run the cells (hold x dt) into ``report["simulation"]``, writing ``out_path`` after each."""
    lo, hi = STEADY_WINDOW
    starts = np.array(steady_initial_states())
    sim = report.setdefault("simulation", {})
    sim.update({"initial_states": starts.tolist(), "t_final": t_final, "window_s": [lo, hi]})
    cells = sim.setdefault("cells", {})
    for hold in holds:
        for dt in dts:
            t0 = time.perf_counter()
            r = simulate_closed_loop("extended", q0=starts, t_final=t_final, dt=dt, hold=hold)
            m = (r["t"] >= lo) & (r["t"] <= hi)
            err = r["q"][m][:, :, :2] - r["q_ref"][m][:, None, :2]  # (time, start, 2)
            sigma = r["q"][m][:, :, 3] + r["q"][m][:, :, 4]
            cells[f"{hold} {dt:g}"] = {
                "hold": hold, "dt": dt,
                "worst_max_abs_xz": float(np.abs(err).max()),
                "worst_rms_position": float(np.sqrt(np.mean(np.sum(err**2, axis=2), axis=0)).max()),
                "max_abs_sigma": float(np.abs(sigma).max()),
                "min_thrust_N": float(r["thrust_state"][..., 0].min()),
                "max_thrust_per_rotor_N": float(r["actuators"][..., 0:2].max()),
                "max_abs_arm_torque_Nm": float(np.abs(r["actuators"][..., 2:4]).max()),
                "degenerate_steps": int(r["degenerate"].sum()),
                "seconds": round(time.perf_counter() - t0, 1),
            }
            print(hold, dt, cells[f"{hold} {dt:g}"], flush=True)
            atomic_write_text(out_path, json.dumps(report, indent=1))
    return report


def env_study(seed: int = 0) -> dict:
    from softpvtol_gym import PassivityPolicy, SoftPVTOLEnv

    res = {}
    for name in ("extended", "bounded"):
        env = SoftPVTOLEnv(action_mode="actuators", task="track_paper", tier="nominal")
        policy = PassivityPolicy.from_env(env, loop=name)
        obs, info = env.reset(seed=seed)
        start, errs, sat, steps, end = True, [], 0, 0, "time limit"
        while True:
            action, _ = policy.predict(obs, episode_start=start)
            start = False
            sat += int(np.any(np.abs(action) >= 1.0 - 1e-6))
            obs, reward, terminated, truncated, info = env.step(action)
            steps += 1
            errs.append((steps * env.config.dt, float(np.hypot(obs[0], obs[1]))))
            if terminated or truncated:
                if terminated:
                    end = str(info.get("termination_reason", "terminated"))
                break
        e = np.array(errs)
        w = (e[:, 0] >= 30.0) & (e[:, 0] <= 40.0)
        res[name] = {"steps": steps, "end": end, "saturated_step_share": sat / steps,
                     "rms_position_30_40s": float(np.sqrt(np.mean(e[w, 1] ** 2))) if w.any() else None,
                     "max_position_error_30_40s": float(e[w, 1].max()) if w.any() else None}
        print(name, res[name], flush=True)
    return res


def table(report: dict, bounded: dict | None) -> str:
    sim = report["simulation"]
    dts = sorted({c["dt"] for c in sim["cells"].values()}, reverse=True)
    lines = ["| loop | hold | " + " | ".join(f"dt = {dt:g} s" for dt in dts) + " |", "|---|---|" + "---|" * len(dts)]
    for hold in ("stage", "step"):
        cells = [sim["cells"][f"{hold} {dt:g}"] for dt in dts]
        lines.append(f"| `extended` | {hold} | " + " | ".join(
            f"{c['worst_max_abs_xz']:.1e} / {c['worst_rms_position']:.1e}" for c in cells) + " |")
    if bounded is not None:
        for hold in ("stage", "step"):
            cells = [bounded[hold][f"{dt:g}"] for dt in dts]
            lines.append(f"| `bounded` | {hold} | " + " | ".join(
                f"{c['worst_max_abs_xz']:.1e} / {c['worst_rms_position']:.1e}" for c in cells) + " |")
    return "\n".join(lines)


def env_table(report: dict) -> str:
    lines = ["| policy (loop) | episode end | steps | steps with a saturated actuator "
             "| RMS position error 30–40 s [m] |",
             "|---|---|---|---|---|"]
    for name, r in report["env"].items():
        rms = "–" if r["rms_position_30_40s"] is None else f"{r['rms_position_30_40s']:.1e}"
        lines.append(f"| `{name}` | {r['end']} | {r['steps']} | {100 * r['saturated_step_share']:.1f} % | {rms} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / SOURCE)
    ap.add_argument("--docs", type=Path, nargs="*", default=[], help="pages whose generated blocks to replace")
    ap.add_argument("--parts", nargs="+", choices=("simulation", "env"), default=["simulation", "env"],
                    help="what to (re)run; the other parts are kept from --out")
    ap.add_argument("--holds", nargs="+", choices=("stage", "step"), default=["stage", "step"],
                    help="the simulation cells to (re)run")
    ap.add_argument("--tables-only", action="store_true", help="only regenerate the tables from --out")
    args = ap.parse_args(argv)
    if args.tables_only:
        report = json.loads(args.out.read_text())
    else:
        report = json.loads(args.out.read_text()) if args.out.exists() else {}
        if "simulation" in args.parts:
            simulation_study(report, args.out, holds=args.holds)
        if "env" in args.parts:
            report["env"] = env_study()
        atomic_write_text(args.out, json.dumps(report, indent=1))
    paper = json.loads((ROOT / README_SOURCE).read_text())
    bounded = paper["steady_state"]["loops"].get("bounded")
    for page in args.docs:
        write_block(BLOCK, SOURCE, table(report, bounded), page)
        if "env" in report:
            write_block(ENV_BLOCK, SOURCE, env_table(report), page)
    print(table(report, bounded))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
