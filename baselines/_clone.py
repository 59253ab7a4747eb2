"""The source checkout's paths, for its scripts (``python train.py``, ``python baselines/<script>.py``).

Each script runs one ``softpvtol`` subcommand with this checkout's layout: results under
``results/``, the generated tables in ``README.md`` and ``docs/``. This is the only place that
knows where the checkout is; the library (``softpvtol_gym.baselines``) never looks for it.
"""

from __future__ import annotations

import sys
from pathlib import Path

from softpvtol_gym.baselines.cli import leave_now_after_a_ray_interrupt, run_command
from softpvtol_gym.baselines.util.paths import Layout

REPO_ROOT = Path(__file__).resolve().parents[1]
LAYOUT = Layout(results=REPO_ROOT / "results", root=REPO_ROOT, readme=REPO_ROOT / "README.md",
                docs=REPO_ROOT / "docs")


def run(command: str, script: str) -> int:
    """``softpvtol COMMAND`` with this process's arguments and the checkout's layout; errors name ``script``."""
    try:
        return run_command(command, sys.argv[1:], layout=LAYOUT, prog=script)
    except SystemExit as exc:
        leave_now_after_a_ray_interrupt(exc.code)
        raise
