"""Evaluate a policy (the passivity controller or a checkpoint) on one task and tier.

Runs ``softpvtol evaluate`` with this checkout's paths (``baselines/_clone.py``); every option: ``--help``.
"""

import sys

from _clone import run

if __name__ == "__main__":
    sys.exit(run("evaluate", "evaluate.py"))
