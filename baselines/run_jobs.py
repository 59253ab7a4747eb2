"""Run the leaderboard's jobs; results under results/leaderboard_runs/.

Runs ``softpvtol run-jobs`` with this checkout's paths (``baselines/_clone.py``); every option: ``--help``.
"""

import sys

from _clone import run

if __name__ == "__main__":
    sys.exit(run("run-jobs", "run_jobs.py"))
