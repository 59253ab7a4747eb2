"""Render an episode of a policy to an animated GIF.

Runs ``softpvtol render-gif`` with this checkout's paths (``baselines/_clone.py``); every option: ``--help``.
"""

import sys

from _clone import run

if __name__ == "__main__":
    sys.exit(run("render-gif", "render_gif.py"))
