"""Run the leaderboard's job list (``baselines/leaderboard.yml``) in parallel local processes.

    python baselines/run_jobs.py [--workers 2] [--spec baselines/leaderboard.yml] [--only ppo_residual] [--list]

Jobs already done (their ``eval.json`` exists under ``baselines/results/leaderboard_runs/``) are
skipped, so an interrupted run is continued by running the command again. ``--reevaluate``
re-runs every evaluation with the committed models (after a change of env or controller code).
Each worker process runs with one numba and one torch thread. Afterwards
``python baselines/leaderboard.py`` builds LEADERBOARD.md from the results.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from baselines.jobs import RUNS_DIR, SPEC_FILE, load_jobs, pending, run_jobs


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--spec", type=Path, default=SPEC_FILE)
    ap.add_argument("--root", type=Path, default=RUNS_DIR)
    ap.add_argument("--only", default=None, help="run only jobs whose name contains this string")
    ap.add_argument("--list", action="store_true", help="print the pending jobs and exit")
    ap.add_argument("--reevaluate", action="store_true",
                    help="re-run the evaluation of finished jobs with their committed models (no training)")
    args = ap.parse_args(argv)
    if args.workers < 1:
        ap.error(f"--workers must be >= 1, got {args.workers}")
    if not args.spec.is_file():
        ap.error(f"no leaderboard spec at {args.spec}")
    jobs = load_jobs(args.spec) if args.reevaluate else pending(load_jobs(args.spec), args.root)
    if args.only:
        jobs = [j for j in jobs if args.only in j.name]
    jobs.sort(key=lambda j: j.learned)  # analytic jobs first (fast), then the spec's order
    if args.list or not jobs:
        for j in jobs:
            print(j.name)
        print(f"{len(jobs)} pending jobs")
        return 0
    # numba's threading layer per worker would oversubscribe the cores: one thread per worker process
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")
    with ProcessPoolExecutor(max_workers=args.workers, mp_context=mp.get_context("spawn")) as ex:
        run_jobs(jobs, ex, args.root, reevaluate=args.reevaluate)
    return 0


if __name__ == "__main__":
    sys.exit(main())
