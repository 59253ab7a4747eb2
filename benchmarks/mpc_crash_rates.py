"""Crash rates of the nonlinear MPC and the integral passivity loop per task and tier.

    python benchmarks/mpc_crash_rates.py --json benchmarks/mpc_crash_rates.json
    python benchmarks/mpc_crash_rates.py --tasks hover --tiers model_gap --episodes 3 --option model_input_map=exact

``--episodes`` seeded episodes (seeds ``--seed`` + i; default the tuning range, 3,000,000 + i; the committed JSON
was measured at 1,000,000 + i, before the tuning range) per (task, tier, policy), run together by
:func:`softpvtol_gym.baselines.evaluation.run_episodes` in the actuators mode. For the MPC it adds its
solver statistics (QPs solved and failed, solve time per control step) and the machine's load average.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from softpvtol_gym import PassivityPolicy, SoftPVTOLVectorEnv  # noqa: E402
from softpvtol_gym.baselines.evaluation import TUNING_SEED, run_episodes  # noqa: E402
from softpvtol_gym.baselines.util.atomic import atomic_write_text  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tasks", nargs="+", default=["hover", "track_paper", "track_random"])
    ap.add_argument("--tiers", nargs="+", default=["nominal", "mismatch", "wind", "noisy", "hard", "model_gap"])
    ap.add_argument("--policies", nargs="+", default=["mpc", "integral"], choices=["mpc", "integral"])
    ap.add_argument("--episodes", type=int, default=10)
    ap.add_argument("--task-episodes", nargs="*", default=[], metavar="TASK=N",
                    help="episodes for one task instead of --episodes, e.g. track_paper=3")
    ap.add_argument("--seed", type=int, default=TUNING_SEED,
                    help=f"the first episode's seed (default {TUNING_SEED:,}: the tuning range)")
    ap.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                    help="an MPCOptions field (repeatable), e.g. qp_solver=daqp")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)

    from softpvtol_gym import MPCPolicy
    from softpvtol_gym.control.mpc import MPCOptions

    options = MPCOptions.parse_items(args.option)
    episodes_of = {task: args.episodes for task in args.tasks}
    for item in args.task_episodes:
        task, _, count = item.partition("=")
        if not task or not count.isdigit() or int(count) < 1:
            ap.error(f"--task-episodes takes TASK=N with N >= 1, got {item!r}")
        if task in episodes_of:
            episodes_of[task] = int(count)
    rows = []
    for task in args.tasks:
        for tier in args.tiers:
            env = SoftPVTOLVectorEnv(num_envs=1, action_mode="actuators", task=task, tier=tier)
            for name in args.policies:
                if name == "mpc":
                    policy = MPCPolicy.from_env(env, **options)
                else:
                    policy = PassivityPolicy.from_env(env, loop="integral")
                load0, tic = os.getloadavg()[0], time.perf_counter()
                count = episodes_of[task]
                episodes = run_episodes(policy, "actuators", task, tier, count, args.seed)
                crashed = [e for e in episodes if e["crashed"]]
                row = {"task": task, "tier": tier, "policy": name, "episodes": count, "seed": args.seed,
                       "crashes": len(crashed), "crash_rate": len(crashed) / count,
                       "crash_seeds": [args.seed + i for i, e in enumerate(episodes) if e["crashed"]],
                       "crash_steps": [e["length"] for e in crashed], "seconds": round(time.perf_counter() - tic, 1),
                       "load_average_1min": [round(load0, 2), round(os.getloadavg()[0], 2)]}
                if name == "mpc":
                    row["mpc_options"] = options
                    row["solver"] = policy.stats
                rows.append(row)
                extra = ""
                if name == "mpc":
                    s = row["solver"]
                    extra = (f"  QPs failed {s['failures']}/{s['solves']}, relaxed {s['relaxed']}, "
                             f"solve ms median {s['solve_ms_median']:.2f} "
                             f"p99 {s['solve_ms_p99']:.2f}")
                print(f"{task:12s} {tier:9s} {name:8s} crashes {len(crashed)}/{count} "
                      f"{extra}  (load {row['load_average_1min']})", flush=True)
            env.close()
    if args.json is not None:
        atomic_write_text(args.json, json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
