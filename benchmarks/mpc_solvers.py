"""The MPC's solve time per control step and tracking with each QP solver, on the same episode.

    python benchmarks/mpc_solvers.py --json benchmarks/mpc_solvers.json
    python benchmarks/mpc_solvers.py --solvers piqp hpipm --seconds 10

One ``track_paper`` episode (``--seed``, default 3,000,000: the tuning range; tier nominal, actuators mode) per
solver (the committed JSONs were measured at seed 1,000,000, before the tuning range: on track_paper nominal every
seed gives the same episode), as
``benchmarks/mpc_quality.py`` runs it: the transient is the RMS position error over 0-10 s, the
steady state the largest error over the last 5 s (true state). Solve times are ``MPCPolicy.stats``
(the policy's whole computation per control step, in ms) with the machine's load average.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.mpc_quality import run_episode  # noqa: E402
from softpvtol_gym.baselines.evaluation import TUNING_SEED  # noqa: E402
from softpvtol_gym.baselines.util.atomic import atomic_write_text  # noqa: E402
from softpvtol_gym.envs.config import EnvConfig  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--solvers", nargs="+", default=["piqp", "hpipm", "daqp", "qpoases"])
    ap.add_argument("--task", default="track_paper")
    ap.add_argument("--tier", default="nominal")
    ap.add_argument("--seed", type=int, default=TUNING_SEED,
                    help=f"the first episode's seed (default {TUNING_SEED:,}: the tuning range)")
    ap.add_argument("--seconds", type=float, default=None, help="episode length [s]; default: the task's")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)

    from softpvtol_gym import MPCPolicy

    rows = []
    for solver in args.solvers:
        policy = MPCPolicy(EnvConfig(task=args.task, tier=args.tier, action_mode="actuators"), qp_solver=solver)
        load0 = os.getloadavg()[0]
        row = {"qp_solver": solver, "task": args.task, "tier": args.tier, "seed": args.seed,
               **run_episode(policy, args.task, args.tier, args.seed, args.seconds)}
        row["solver"] = policy.stats
        row["load_average_1min"] = [round(load0, 2), round(os.getloadavg()[0], 2)]
        rows.append(row)
        s = row["solver"]
        print(f"{solver:8s} solve ms median {s['solve_ms_median']:.2f} p99 {s['solve_ms_p99']:.2f} max "
              f"{s['solve_ms_max']:.1f}, {s['failures']} failed QPs; transient (RMS 0-10 s) "
              f"{row.get('rms_0_10s', float('nan')):.3f} m, steady (max last 5 s) {row['max_final_5s']:.2e} m"
              f"{'  CRASH ' + row['termination_reason'] if row['crashed'] else ''} (load "
              f"{row['load_average_1min']}, {os.cpu_count()} CPUs)", flush=True)
    if args.json is not None:
        atomic_write_text(args.json, json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
