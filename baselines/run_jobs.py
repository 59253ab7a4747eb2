"""Run the leaderboard's job list (``baselines/leaderboard.yml``) in parallel local processes.

    python baselines/run_jobs.py [--workers 2] [--spec baselines/leaderboard.yml] [--only ppo_residual] [--list]

Jobs already done (their ``eval.json`` exists under ``baselines/results/leaderboard_runs/``) are
skipped, so an interrupted run is continued by running the command again. ``--reevaluate``
re-runs every evaluation with the committed models (after a change of env or controller code).
Each worker process runs with one numba and one torch thread. Afterwards
``python baselines/leaderboard.py`` builds LEADERBOARD.md from the results.

The spec is validated first (unknown keys, bad values and job names that would leave ``--root`` are
errors); the root is locked while the jobs run (a second run_jobs.py on it gets exit 2 naming the
holder). Exit codes: 0 done, 2 bad input, a busy root or failed jobs (one line each).
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from baselines.cli import Parser, int_arg, run_main
from baselines.jobs import RUNS_DIR, SPEC_FILE, load_jobs, pending, run_jobs

MAX_WORKERS = 256


def _main(argv=None) -> int:
    ap = Parser(prog="run_jobs.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--workers", type=int_arg(), default=os.cpu_count() or 1, help=f"1 to {MAX_WORKERS}")
    ap.add_argument("--spec", type=Path, default=SPEC_FILE)
    ap.add_argument("--root", type=Path, default=RUNS_DIR)
    ap.add_argument("--only", default=None, help="run only jobs whose name contains this string")
    ap.add_argument("--list", action="store_true", help="print the pending jobs and exit")
    ap.add_argument("--reevaluate", action="store_true",
                    help="re-run the evaluation of finished jobs with their committed models (no training)")
    args = ap.parse_args(argv)
    if not 1 <= args.workers <= MAX_WORKERS:
        ap.error(f"--workers must be in [1, {MAX_WORKERS}], got {args.workers}")
    if not args.spec.is_file():
        ap.error(f"no leaderboard spec at {args.spec}" + (" (it is a directory)" if args.spec.is_dir() else ""))
    if args.root.exists() and not args.root.is_dir():
        ap.error(f"--root {args.root} is a file; expected a directory")
    every = load_jobs(args.spec)
    if args.only is not None:
        every = [j for j in every if args.only in j.name]
        if not every:
            ap.error(f"--only {args.only!r} matches no job of {args.spec}")
    jobs = every if args.reevaluate else pending(every, args.root)
    jobs.sort(key=lambda j: j.learned)  # analytic jobs first (fast), then the spec's order
    if args.list or not jobs:
        for j in jobs:
            print(j.name)
        print(f"{len(jobs)} pending jobs")
        return 0
    from baselines.locks import DirectoryLock

    with DirectoryLock(args.root, "job root"):
        # numba's threading layer per worker would oversubscribe the cores: one thread per worker process
        os.environ.setdefault("NUMBA_NUM_THREADS", "1")
        with ProcessPoolExecutor(max_workers=args.workers, mp_context=mp.get_context("spawn")) as ex:
            run_jobs(jobs, ex, args.root, reevaluate=args.reevaluate)
    return 0


def main(argv=None) -> int:
    from baselines._extras import require

    require("run_jobs.py")
    return run_main(_main, argv, prog="run_jobs.py")


if __name__ == "__main__":
    sys.exit(main())
