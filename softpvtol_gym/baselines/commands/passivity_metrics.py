"""Passivity policy on every task x tier of SoftPVTOL-v0 (default env settings, actuators mode).

    python baselines/passivity_metrics.py [--episodes 10] [--seed 100] [--json baselines/results/passivity_metrics.json]

For each cell: mean over episodes of the RMS position error [m] over the episode (until it ends) and
the crash rate (fraction of episodes that terminated before the time limit).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from baselines import readme
from baselines.atomic import atomic_write_text
from baselines.evaluation import evaluate
from softpvtol_gym import PassivityPolicy
from softpvtol_gym.envs.core import TASKS, TIERS
from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv


def run_cell(task: str, tier: str, episodes: int, seed: int) -> dict:
    env = SoftPVTOLVectorEnv(num_envs=1, task=task, tier=tier, action_mode="actuators")
    m = evaluate(PassivityPolicy.from_env(env), "actuators", task, tier, episodes, seed)["summary"]
    return {"rms_position_error_m": m["mean_rms_position_error"], "crash_rate": m["crash_rate"],
            "episodes": m["episodes"]}


README_SOURCE = "baselines/results/passivity_metrics.json"


def metrics_table(report: dict) -> str:
    """The README's task x tier table (mean RMS position error [m] / crash rate) from a report."""
    cells = report["cells"]
    tasks = list(dict.fromkeys(k.split("/")[0] for k in cells))
    tiers = list(dict.fromkeys(k.split("/")[1] for k in cells))
    lines = ["| task | " + " | ".join(tiers) + " |", "|---|" + "---|" * len(tiers)]
    for task in tasks:
        row = [f"{cells[f'{task}/{tier}']['rms_position_error_m']:.2f} / {cells[f'{task}/{tier}']['crash_rate']:.2f}"
               for tier in tiers]
        lines.append(f"| {task} | " + " | ".join(row) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--episodes", type=int, default=10)
    ap.add_argument("--seed", type=int, default=100)
    ap.add_argument("--json", type=Path, default=Path(__file__).resolve().parent / "results" / "passivity_metrics.json")
    args = ap.parse_args(argv)
    if args.episodes < 1:
        ap.error("--episodes must be >= 1")
    cells, t0 = {}, time.perf_counter()
    for task in TASKS:
        for tier in TIERS:
            cells[f"{task}/{tier}"] = m = run_cell(task, tier, args.episodes, args.seed)
            print(f"{task:13s} {tier:9s} rms {m['rms_position_error_m']:.3f} m  crash {m['crash_rate']:.2f}",
                  flush=True)
    command = "python baselines/passivity_metrics.py" + (f" --episodes {args.episodes}" if args.episodes != 10 else "")
    loop = PassivityPolicy.from_env(SoftPVTOLVectorEnv(num_envs=1, action_mode="actuators")).loop
    report = {"command": command, "seed": args.seed, "action_mode": "actuators", "loop": loop, "cells": cells,
              "wall_time_s": round(time.perf_counter() - t0, 1)}
    atomic_write_text(args.json, json.dumps(report, indent=2))
    if args.json.resolve() == Path(__file__).resolve().parent / "results" / "passivity_metrics.json" \
            and args.episodes == 10 and args.seed == 100:
        readme.write_block("passivity_metrics.py", README_SOURCE, metrics_table(report))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
