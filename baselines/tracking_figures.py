"""Tracking plots, learning curves (results/tracking/) and the GIF in docs/.

Runs ``softpvtol figures`` with this checkout's paths (``baselines/_clone.py``); every option: ``--help``.
"""

import sys

from _clone import run

if __name__ == "__main__":
    sys.exit(run("figures", "tracking_figures.py"))
