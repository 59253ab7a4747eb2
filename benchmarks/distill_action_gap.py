"""Where a distilled student departs from its teacher: the action gap per actuator channel over the last half of
episodes that the student flies and the teacher labels (the DAgger view of the leaderboard's students).

    python benchmarks/distill_action_gap.py                                   # the 256 x 256 cell's seed 0
    python benchmarks/distill_action_gap.py --run RUN                        # another student

With ``--integrals``, instead: per task, the error integrals the student observes (the env's, of the raw
errors) at the end of teacher-flown episodes, and how far they are from the integral loop's own, which
integrates each step's error clipped to ``integral_error_limits`` (0.5 m): the student's inputs on track_paper
lie far outside those it was trained on, and they no longer tell the teacher's state.

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


def observed_integrals(task: str, episodes: int) -> dict:
    """Per task: the observed error integrals (x, z) [m s] at the end of teacher-flown episodes, their difference
    to the integral of the clipped errors, and the largest |error| [m] on the way (mean over the episodes)."""
    from softpvtol_gym.control import LOOPS

    clip = LOOPS["integral"]["integral_error_limits"][0]
    obs, _ = collect(teacher_policy("integral", task), task, "nominal", episodes, SEED)
    errors = obs[:, :2].reshape(-1, episodes, 2)  # step-major; the episodes do not end early (no crash)
    dt = 0.01
    return {"observed": obs[-episodes:, 18:20].mean(0).tolist(),
            "observed_minus_clipped": ((errors - np.clip(errors, -clip, clip)) * dt).sum(0).mean(0).tolist(),
            "max_abs_error": float(np.abs(errors).max(0).max(1).mean())}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--run", type=Path, default=RUN, help="a distilled student's run folder (default: %(default)s)")
    ap.add_argument("--teacher", default="integral")
    ap.add_argument("--task", default="track_random")
    ap.add_argument("--episodes", type=int, default=4)
    ap.add_argument("--integrals", action="store_true", help="the observed error integrals per task instead")
    args = ap.parse_args(argv)
    if args.integrals:
        print("| task | observed integral at the end (x, z) [m s] | observed minus clipped (x, z) [m s] | max abs "
              "error [m] |\n|---|---|---|---|")
        for task in ("track_random", "track_paper"):
            r = observed_integrals(task, args.episodes)
            seen, off = r["observed"], r["observed_minus_clipped"]
            print(f"| {task} | {seen[0]:+.3f}, {seen[1]:+.3f} | {off[0]:+.3f}, {off[1]:+.3f} | "
                  f"{r['max_abs_error']:.2f} |")
        return 0
    report = action_gap(args.run, args.teacher, args.task, args.episodes)
    print("| channel | teacher std | bias | RMS gap | median abs gap | 99th pct abs gap |\n|---|---|---|---|---|---|")
    for name, r in report.items():
        print(f"| {name} | {r['teacher_std']:.4f} | {r['bias']:+.4f} | {r['rms']:.4f} | {r['median_abs']:.4f} | "
              f"{r['p99_abs']:.4f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
