"""Run the leaderboard's job list (the package's ``leaderboard.yml``, or ``--spec``) in local processes or on Ray.

    softpvtol run-jobs [--workers 2] [--spec my_leaderboard.yml] [--only ppo_residual] [--list]
    softpvtol run-jobs --executor ray [--workers 8]     # a local Ray instance with 8 CPUs
    softpvtol run-jobs --executor ray --address auto    # the Ray cluster of `ray start`

Run directories go under ``--root`` (default ``./results/leaderboard_runs``; in a source checkout
``python baselines/run_jobs.py`` uses ``results/leaderboard_runs``). Jobs already done (their
``eval.json`` under the root holds every task and
tier they are evaluated on) are skipped, so an interrupted run is continued by running the command again;
a task added to a cell's ``also_evaluated_on`` (a tier added to the spec) only runs the missing evaluations.
``--reevaluate`` re-runs every evaluation with the committed models (after a change of env or controller code).
``--rescore`` re-runs only the stale parts of the evaluations of jobs that have a result: tiers or tasks they lack,
results recorded before the windowed metrics (episodes without ``rms_position_error_steady``,
``compute_us_per_step``, ...), missing selection episodes, a per-robot compute pass (``compute_us_single``) missing
or measured otherwise than the package measures it now (the result's ``compute_pass``),
learned results scored with another forward pass than ``--inference`` (default: the spec's, ``lean``), with the
committed models; it never trains (a learned job without its model fails, naming it) and leaves
the jobs that have no result to a run without it.

    softpvtol run-jobs --rescore --workers 2      # learned cells with stale results, re-scored (windowed metrics)
Each worker process (each Ray task: one CPU) runs with one numba and one torch thread. The same jobs
and seeds give the same result files with either executor; on a Ray cluster ``--root`` must be on a
file system that every node mounts at the same path (each task checks it, see docs/baselines.md).
Afterwards ``softpvtol leaderboard`` (``python baselines/leaderboard.py``) builds the leaderboard from the results.

The spec is validated first (unknown keys, bad values and job names that would leave ``--root`` are
errors); the root is locked while the jobs run (a second run_jobs.py on it gets exit 2 naming the
holder). Each job runs in a process of its own (at most ``--workers`` at once): a worker that is killed (``kill
-9``, the OOM killer; on Ray a crashed worker) fails only its job, reported as ``worker crashed``; the other jobs
go on, and at the end the failed jobs and the command that re-runs them are printed (exit 2). Ctrl-C / SIGTERM
stop the running workers (none is left behind), keep the finished jobs and print how many (exit 130 / 143).
Exit codes: 0 done, 2 bad input, a busy root or failed jobs (one line each), 74 an unwritable ``--root`` found
late (disk full), 130 / 143 interrupted.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import shlex
import sys
from pathlib import Path

from softpvtol_gym.baselines.leaderboard.jobs import SPEC_FILE, load_jobs, pending, run_jobs, stale_jobs
from softpvtol_gym.baselines.leaderboard.process_executor import ProcessPerJobExecutor
from softpvtol_gym.baselines.leaderboard.ray_executor import RayExecutor, start_ray
from softpvtol_gym.baselines.leaderboard.spec import INFERENCE
from softpvtol_gym.baselines.util.args import Parser, check_output_dir, command_main, int_arg, interrupted
from softpvtol_gym.baselines.util.extras import DISTRIBUTED, require
from softpvtol_gym.baselines.util.locks import DirectoryLock
from softpvtol_gym.baselines.util.paths import Layout

MAX_WORKERS = 256
EXECUTORS = ("pool", "ray")


def _main(argv, layout: Layout, prog: str) -> int:
    ap = Parser(prog=prog, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--executor", choices=EXECUTORS, default="pool",
                    help="pool: local processes (default); ray: Ray tasks, one CPU each (the 'distributed' extra)")
    ap.add_argument("--address", default=None,
                    help="with --executor ray: an existing Ray cluster, 'auto' (the one `ray start` started on this "
                         "machine) or HOST:PORT; default: a local Ray instance with --workers CPUs")
    ap.add_argument("--workers", type=int_arg(), default=None,
                    help=f"parallel jobs, 1 to {MAX_WORKERS} (default: the number of CPUs; not with --address)")
    ap.add_argument("--spec", type=Path, default=SPEC_FILE,
                    help="the job list (default: the package's leaderboard.yml)")
    ap.add_argument("--root", type=Path, default=layout.runs, help="the jobs' run directories (default: %(default)s)")
    ap.add_argument("--only", default=None, help="run only jobs whose name contains this string")
    ap.add_argument("--list", action="store_true", help="print the pending jobs and exit")
    ap.add_argument("--reevaluate", action="store_true",
                    help="re-run the evaluation of finished jobs with their committed models (no training)")
    ap.add_argument("--rescore", action="store_true",
                    help="re-run only the stale evaluations (missing tiers, results without the windowed metrics) of "
                         "jobs that have a result, with their committed models; never trains")
    ap.add_argument("--inference", choices=INFERENCE, default=None,
                    help="the learned entries' forward pass (default: the spec's evaluation.inference, lean): torch "
                         "re-scores them with SB3's torch forward (with --rescore: only what is not scored so yet); "
                         "build the leaderboard with the same --inference")
    ap.add_argument("--no-progress-bar", action="store_true", help="no progress bar (one line per job stays)")
    args = ap.parse_args(argv)
    given = sys.argv[1:] if argv is None else list(argv)
    rerun = f"{'python baselines/' if prog.endswith('.py') else ''}{prog} {shlex.join(given)}".strip()
    try:
        return _checked(ap, args, layout, prog, rerun)
    except KeyboardInterrupt as exc:
        if not getattr(exc, "kept", None):  # stopped before the first job was submitted (Ray starting, say)
            interrupted(exc, f"no job had started, nothing was written under {args.root}; rerun: {rerun}")
        raise


def _checked(ap: Parser, args, layout: Layout, prog: str, rerun: str) -> int:
    """The options checked, then the pending jobs run."""
    if args.workers is not None and not 1 <= args.workers <= MAX_WORKERS:
        ap.error(f"--workers must be in [1, {MAX_WORKERS}], got {args.workers}")
    if args.address is not None and args.executor != "ray":
        ap.error("--address needs --executor ray")
    if args.address is not None and args.workers is not None:
        ap.error("--workers with --address: the cluster's CPUs (its `ray start --num-cpus`) set the parallelism")
    if args.address is not None and not args.address.strip():
        ap.error("--address must be 'auto' or HOST:PORT, got an empty string")
    if not args.spec.is_file():
        ap.error(f"no leaderboard spec at {args.spec}" + (" (it is a directory)" if args.spec.is_dir() else ""))
    if args.root.exists() and not args.root.is_dir():
        ap.error(f"--root {args.root} is a file; expected a directory")
    every = load_jobs(args.spec, inference=args.inference)
    if args.only is not None:
        if not args.only.strip():
            ap.error(f"--only {args.only!r} would match every job; give a part of the job names to run (--list "
                     f"shows them), or leave --only out to run all")
        every = [j for j in every if args.only in j.name]
        if not every:
            ap.error(f"--only {args.only!r} matches no job of {args.spec}")
    if args.rescore and args.reevaluate:
        ap.error("--rescore runs the stale evaluations only, --reevaluate all of them; pass one")
    if args.rescore:
        jobs, unrun = stale_jobs(every, args.root)
        if unrun:
            print(f"--rescore: {len(unrun)} jobs have no result under {args.root} and are left to a run without "
                  f"--rescore (first: {unrun[0].name})")
    else:
        jobs = every if args.reevaluate else pending(every, args.root)
    jobs.sort(key=lambda j: j.learned)  # analytic jobs first (fast), then the spec's order
    if args.list or not jobs:
        for j in jobs:
            print(j.name)
        print(f"{len(jobs)} pending jobs")
        return 0
    if args.executor == "ray":
        require("run_jobs.py", DISTRIBUTED, prog=prog)
    check_output_dir(args.root, "--root")  # before any job: not under /proc, a file or a read-only mount
    _run(args, jobs, layout, rerun, progress=not args.no_progress_bar)
    return 0


def _run(args, jobs, layout: Layout, rerun: str, progress: bool) -> None:
    """The jobs on the chosen executor, with the root locked."""
    with DirectoryLock(args.root, "job root"):
        if args.executor == "ray":
            with start_ray(address=args.address, num_cpus=args.workers) as resources:
                print(f"Ray: {len(jobs)} jobs on {resources.get('CPU', 0):g} CPUs", flush=True)
                run_jobs(jobs, RayExecutor(num_cpus=1), args.root, reevaluate=args.reevaluate, check_root=True,
                         progress=progress, base=layout.root, rerun=rerun, rescore=args.rescore)
        else:
            # numba's threading layer per worker would oversubscribe the cores: one thread per worker process
            # (unless the user set it), in the workers' environment only
            worker_env = {} if "NUMBA_NUM_THREADS" in os.environ else {"NUMBA_NUM_THREADS": "1"}
            workers = args.workers or os.cpu_count() or 1
            # a process per job: a killed worker fails its own job only; leaving the block (Ctrl-C, SIGTERM)
            # terminates the running ones
            with ProcessPerJobExecutor(max_workers=workers, mp_context=mp.get_context("spawn"),
                                       worker_env=worker_env) as ex:
                run_jobs(jobs, ex, args.root, reevaluate=args.reevaluate, progress=progress,
                         base=layout.root, rerun=rerun, rescore=args.rescore)


main = command_main("run_jobs.py", _main,
                    "``softpvtol run-jobs``: the leaderboard jobs, run directories under ``layout.runs`` (default "
                    "``./results/leaderboard_runs``).")

