"""Build the leaderboard: results/leaderboard.{json,png}, docs/leaderboard.md, the README summary.

Runs ``softpvtol leaderboard`` with this checkout's paths (``baselines/_clone.py``); every option: ``--help``.
"""

import sys

from _clone import run

if __name__ == "__main__":
    sys.exit(run("leaderboard", "leaderboard.py"))
