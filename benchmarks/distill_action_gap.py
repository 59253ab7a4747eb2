"""Where a distilled student departs from its teacher: the action gap per actuator channel over the last half of
episodes that the student flies and the teacher labels (the DAgger view of the leaderboard's students).

    python benchmarks/distill_action_gap.py                                   # the 256 x 256 cell's seed 0
    python benchmarks/distill_action_gap.py --run RUN                        # another student

Prints, per channel (thrusts left and right, then the two arms' bending inputs, on the actuators' normalised
scale), the teacher's spread over the last half, and the student's bias, RMS, median and 99th percentile of the
absolute gap; episodes from seed 2,600,000 (neither test, selection nor training episodes).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from softpvtol_gym.baselines.training.policy import LearnedPolicy  # noqa: E402
from softpvtol_gym.baselines.training.teachers import collect, teacher_policy  # noqa: E402

RUN = ROOT / "results" / "leaderboard_runs" / "distilled-integral_track_random_nominal" / "seed_0"
CHANNELS = ("thrust left", "thrust right", "arm left", "arm right")
SEED = 2_600_000


def action_gap(run: Path, teacher: str, task: str, episodes: int) -> dict:
    """Per channel: the teacher's standard deviation and the student's gap statistics over the last half."""
    student, _ = LearnedPolicy.load(run)
    obs, labels = collect(teacher_policy(teacher, task), task, "nominal", episodes, SEED, student=student)
    acted = student.predict(obs, deterministic=True)[0]
    steps = np.arange(len(obs)) // episodes  # step-major rows: exact while no episode has ended
    late = steps >= steps.max() // 2
    gap = acted[late] - labels[late]
    return {name: {"teacher_std": float(labels[late, c].std()), "bias": float(gap[:, c].mean()),
                   "rms": float(np.sqrt((gap[:, c] ** 2).mean())), "median_abs": float(np.median(np.abs(gap[:, c]))),
                   "p99_abs": float(np.percentile(np.abs(gap[:, c]), 99))} for c, name in enumerate(CHANNELS)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--run", type=Path, default=RUN, help="a distilled student's run folder (default: %(default)s)")
    ap.add_argument("--teacher", default="integral")
    ap.add_argument("--task", default="track_random")
    ap.add_argument("--episodes", type=int, default=4)
    args = ap.parse_args(argv)
    report = action_gap(args.run, args.teacher, args.task, args.episodes)
    print("| channel | teacher std | bias | RMS gap | median abs gap | 99th pct abs gap |\n|---|---|---|---|---|---|")
    for name, r in report.items():
        print(f"| {name} | {r['teacher_std']:.4f} | {r['bias']:+.4f} | {r['rms']:.4f} | {r['median_abs']:.4f} | "
              f"{r['p99_abs']:.4f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
