"""How far the committed checkpoints' replays drift from the leaderboard's episodes on this machine.

    python benchmarks/replay_drift.py [--inference torch] [--out drift.json]

The leaderboard's learned cells are replayed on their whole batch of episodes, on the base loop each model was
trained on. With the lean inference the leaderboard is scored with (float64, one row at a time) every value is
equal to the last bit on any machine; with ``--inference torch`` (SB3's float32 forward) the closed loops drift,
by how much depends on the CPU (torch's MKL/oneDNN kernels sum a matrix product in an order that differs by CPU
model and batch size). Per replay it prints the episodes whose crash or length changed, the
largest relative change of an episode's return, RMS position and attitude error and control effort, and the
relative change of the cell's mean RMS position error.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
KEYS = ("return", "rms_position_error", "rms_attitude_error", "control_effort")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--inference", choices=("lean", "torch"), default="lean",
                    help="the policies' inference path (default: lean, the leaderboard's)")
    ap.add_argument("--out", type=Path, help="also write the rows as JSON")
    args = ap.parse_args(argv)
    from softpvtol_gym.baselines.evaluation import run_episodes
    from softpvtol_gym.baselines.training.policy import LearnedPolicy
    from softpvtol_gym.baselines.util.atomic import atomic_write_text

    data = json.loads((ROOT / "results" / "leaderboard.json").read_text())
    learned = sorted({(c["checkpoint"], c["train_tier"], c["task"]) for c in data["cells"] if c["checkpoint"]})
    rows = []
    for checkpoint, tier, task in learned:
        policy, config = LearnedPolicy.load(ROOT / checkpoint, inference=args.inference)
        cell = next(c for c in data["cells"]
                    if c["checkpoint"] == checkpoint and c["tier"] == tier and c["task"] == task)
        want = cell["episodes"]
        got = run_episodes(policy, config.action_mode, task, tier, len(want), cell["eval_seed"],
                           env_kwargs=config.eval_env_kwargs())
        row = {"checkpoint": checkpoint, "tier": tier, "task": task,
               "crash_or_length_changed": sum(g["crashed"] != w["crashed"] or g["length"] != w["length"]
                                              for g, w in zip(got, want)),
               "max_relative_change": max(abs(g[k] - w[k]) / max(abs(w[k]), 1e-12)
                                          for g, w in zip(got, want) for k in KEYS),
               "mean_rms_relative_change": abs(np.mean([g["rms_position_error"] for g in got])
                                               / np.mean([w["rms_position_error"] for w in want]) - 1.0)}
        rows.append(row)
        print(f"{checkpoint.split('leaderboard_runs/')[-1]:70s} {tier:9s} {task:12s} crash/length changed "
              f"{row['crash_or_length_changed']:2d}  max rel {row['max_relative_change']:.1e}  mean RMS rel "
              f"{row['mean_rms_relative_change']:.1e}", flush=True)
    exact = sum(r["max_relative_change"] == 0.0 for r in rows)
    print(f"{exact} of {len(rows)} replays equal to the last bit")
    for tier in sorted({r["tier"] for r in rows}):
        sel = [r for r in rows if r["tier"] == tier]
        print(f"{tier}: {len(sel)} replays, at most {max(r['crash_or_length_changed'] for r in sel)} episodes "
              f"crashed or ended differently, mean RMS moved by at most "
              f"{100 * max(r['mean_rms_relative_change'] for r in sel):.2g} %")
    if args.out:
        atomic_write_text(args.out, json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
