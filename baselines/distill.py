"""Distil a controller into a student network (behaviour cloning and DAgger).

Runs ``softpvtol distill`` with this checkout's paths (``baselines/_clone.py``); every option: ``--help``.
"""

import sys

from _clone import run

if __name__ == "__main__":
    sys.exit(run("distill", "distill.py"))
