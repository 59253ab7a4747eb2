"""Integration error of the paper's loop at RK4 steps; results/model_figures.json.

Runs ``softpvtol model-figures`` with this checkout's paths (``baselines/_clone.py``); every option: ``--help``.
"""

import sys

from _clone import run

if __name__ == "__main__":
    sys.exit(run("model-figures", "model_figures.py"))
