"""The nonlinear MPC's tracking quality and solve times, against the bounded passivity loop.

    python benchmarks/mpc_quality.py                       # track_paper; tiers nominal, wind, noisy
    python benchmarks/mpc_quality.py --tiers nominal --seconds 20 --json mpc_nominal.json
    python benchmarks/mpc_quality.py --option horizon=20 --option step=0.06
    python benchmarks/mpc_quality.py --table benchmarks/mpc_quality.json   # docs/control.md's table

One episode per (tier, policy) of ``SoftPVTOLVectorEnv(num_envs=1, action_mode="actuators", task=...)``
reset with ``--seed``. The errors are those of the true (noise-free) state, as in
:func:`softpvtol_gym.baselines.evaluation.run_episodes`: RMS of |(x, z) - (x_ref, z_ref)| over the
windows 0-10 s, 10-20 s, 20-40 s (those inside the episode) and the whole episode, and the largest error
over the last 5 s. For the MPC it prints ``MPCPolicy.stats`` (solves, fallbacks, solve time per
control step: median, p99, max in ms) and the machine's load average, since the times depend on it.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from softpvtol_gym import PassivityPolicy, SoftPVTOLVectorEnv  # noqa: E402
from softpvtol_gym.baselines.util.atomic import atomic_write_text  # noqa: E402

WINDOWS = ((0.0, 10.0), (10.0, 20.0), (20.0, 40.0))


def run_episode(policy, task: str, tier: str, seed: int, seconds: float | None) -> dict:
    """Windowed position errors of one episode of ``policy`` (true state)."""
    kwargs = {} if seconds is None else {"max_episode_seconds": seconds}
    env = SoftPVTOLVectorEnv(num_envs=1, action_mode="actuators", task=task, tier=tier, **kwargs)
    obs, _ = env.reset(seed=seed)
    sim, dt = env.sim, env.config.dt
    errors, start, reason = [], np.ones(1, bool), ""
    while True:
        action, _ = policy.predict(obs, episode_start=start)
        start[:] = False
        obs, _, term, trunc, info = env.step(action)
        errors.append(float(np.hypot(*(sim.q[0, :2] - sim.qr[0, :2]))))
        if term[0] or trunc[0]:
            reason = str(info["termination_reason"][0]) if term[0] else ""
            break
    env.close()
    e = np.array(errors)
    t = dt * np.arange(1, e.size + 1)
    out = {"crashed": bool(reason), "termination_reason": reason, "seconds": float(t[-1]),
           "rms_whole": float(np.sqrt(np.mean(e**2))), "max_final_5s": float(e[t > t[-1] - 5.0].max())}
    for lo, hi in WINDOWS:
        m = (t > lo) & (t <= hi + 1e-9)
        if m.any() and t[-1] >= hi - 1e-9:
            out[f"rms_{lo:g}_{hi:g}s"] = float(np.sqrt(np.mean(e[m] ** 2)))
    return out


TABLE_START = ("<!-- benchmarks/mpc_quality.py --table: start (generated from benchmarks/mpc_quality.json, "
               "do not edit) -->")
TABLE_END = "<!-- benchmarks/mpc_quality.py --table: end -->"


def table_markdown(results: list[dict]) -> str:
    """The Markdown table of docs/control.md ("Nonlinear MPC") from this script's JSON."""
    lines = ["| tier | policy | 0-10 s | 10-20 s | 20-40 s | max, last 5 s | crashed | solve ms: median / p99 / max "
             "| load |", "|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        cells = [f"{r[k]:.2g}" if k in r else "-" for k in ("rms_0_10s", "rms_10_20s", "rms_20_40s", "max_final_5s")]
        s = r.get("solver")
        solve = (f"{s['solve_ms_median']:.1f} / {s['solve_ms_p99']:.1f} / {s['solve_ms_max']:.0f} "
                 f"({s['fallbacks']} fallbacks)") if s else "-"
        load = "-" if r["policy"] != "mpc" else f"{r['load_average_1min'][0]:.1f}-{r['load_average_1min'][1]:.1f}"
        lines.append(f"| {r['tier']} | {r['policy']} | {' | '.join(cells)} | "
                     f"{r['termination_reason'] if r['crashed'] else 'no'} | {solve} | {load} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--task", default="track_paper")
    ap.add_argument("--tiers", nargs="+", default=["nominal", "wind", "noisy"])
    ap.add_argument("--seed", type=int, default=1_000_000)
    ap.add_argument("--seconds", type=float, default=None, help="episode length [s]; default: the task's")
    ap.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                    help="an MPCOptions field (repeatable), e.g. horizon=20")
    ap.add_argument("--no-passivity", action="store_true", help="skip the bounded passivity loop")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--table", type=Path, default=None, metavar="JSON",
                    help="print the Markdown table of a JSON this script wrote, and run nothing")
    args = ap.parse_args(argv)
    if args.table is not None:
        print(f"{TABLE_START}\n{table_markdown(json.loads(args.table.read_text()))}\n{TABLE_END}")
        return 0

    from softpvtol_gym import MPCPolicy
    from softpvtol_gym.control.mpc import MPCOptions

    options = MPCOptions.parse_items(args.option)
    results = []
    for tier in args.tiers:
        env = SoftPVTOLVectorEnv(num_envs=1, action_mode="actuators", task=args.task, tier=tier)
        policies = {"mpc": MPCPolicy.from_env(env, **options)}
        if not args.no_passivity:
            policies["passivity-bounded"] = PassivityPolicy.from_env(env)
        env.close()
        for name, policy in policies.items():
            load0 = os.getloadavg()[0]
            row = {"task": args.task, "tier": tier, "policy": name, "seed": args.seed,
                   **run_episode(policy, args.task, tier, args.seed, args.seconds)}
            if name == "mpc":
                row["mpc_options"] = options
                row["solver"] = policy.stats
            row["load_average_1min"] = [round(load0, 2), round(os.getloadavg()[0], 2)]
            results.append(row)
            windows = "  ".join(f"{k[4:]} {v:.3e}" for k, v in row.items() if k.startswith("rms_"))
            print(f"{args.task} {tier:8s} {name:18s} {'CRASH ' + row['termination_reason'] if row['crashed'] else 'ok'}"
                  f"  RMS [m] {windows}  max last 5 s {row['max_final_5s']:.3e}", flush=True)
            if name == "mpc":
                s = row["solver"]
                print(f"    solver: {s['solves']} solves, {s['fallbacks']} fallbacks; solve ms median "
                      f"{s['solve_ms_median']:.2f} p99 {s['solve_ms_p99']:.2f} max {s['solve_ms_max']:.2f} "
                      f"(load average {row['load_average_1min'][0]} -> {row['load_average_1min'][1]}, "
                      f"{os.cpu_count()} CPUs)", flush=True)
    if args.json is not None:
        atomic_write_text(args.json, json.dumps(results, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
