"""Pack results/ into results/archive/, unpack it, or check them (``softpvtol results``); every option: ``--help``.

Runs ``softpvtol results`` with this checkout's paths (``baselines/_clone.py``).
"""

import sys

from _clone import run

if __name__ == "__main__":
    sys.exit(run("results", "results.py"))
