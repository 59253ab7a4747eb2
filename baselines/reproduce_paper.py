"""Reproduce the paper's simulation section; results/paper_reproduction/ and docs/control.md tables.

Runs ``softpvtol reproduce-paper`` with this checkout's paths (``baselines/_clone.py``); every option: ``--help``.
"""

import sys

from _clone import run

if __name__ == "__main__":
    sys.exit(run("reproduce-paper", "reproduce_paper.py"))
