"""Score the learned controller's ablation and render its table in docs/baselines.md ("Ablation").

Runs ``softpvtol ablation`` with this checkout's paths (``baselines/_clone.py``); every option: ``--help``.
"""

import sys

from _clone import run

if __name__ == "__main__":
    sys.exit(run("ablation", "ablation.py"))
