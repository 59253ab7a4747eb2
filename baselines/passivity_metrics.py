"""The passivity policy on every task x tier; results/passivity_metrics.json and its docs/control.md table.

Runs ``softpvtol passivity-metrics`` with this checkout's paths (``baselines/_clone.py``); every option: ``--help``.
"""

import sys

from _clone import run

if __name__ == "__main__":
    sys.exit(run("passivity-metrics", "passivity_metrics.py"))
