"""Search PPO/SAC hyperparameters with Ray Tune (the 'distributed' extra).

Runs ``softpvtol tune`` with this checkout's paths (``baselines/_clone.py``); every option: ``--help``.
"""

import sys

from _clone import run

if __name__ == "__main__":
    sys.exit(run("tune", "tune.py"))
