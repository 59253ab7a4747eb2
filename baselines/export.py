"""Convert checkpoints between the safe format and SB3's pickle-based files.

Runs ``softpvtol export`` with this checkout's paths (``baselines/_clone.py``); every option: ``--help``.
"""

import sys

from _clone import run

if __name__ == "__main__":
    sys.exit(run("export", "export.py"))
