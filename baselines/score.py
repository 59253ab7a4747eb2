"""Score a policy of your own (MODULE:FACTORY) on the leaderboard's episodes and rank it among the entries.

Runs ``softpvtol score`` with this checkout's paths (``baselines/_clone.py``); every option: ``--help``.
"""

import sys

from _clone import run

if __name__ == "__main__":
    sys.exit(run("score", "score.py"))
