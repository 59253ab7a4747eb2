"""The source checkout's paths, for its scripts (``python train.py``, ``python baselines/<script>.py``).

Each script runs one ``softpvtol`` subcommand with this checkout's layout: results under
``results/``, the generated tables in ``README.md`` and ``docs/``. This is the only place that
knows where the checkout is; the library (``softpvtol_gym.baselines``) never looks for it.
"""

from __future__ import annotations

import sys
from pathlib import Path

from softpvtol_gym.baselines.cli import leave_now_after_a_ray_interrupt, run_command
from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.util.extras import require
from softpvtol_gym.baselines.util.paths import Layout

REPO_ROOT = Path(__file__).resolve().parents[1]
LAYOUT = Layout(results=REPO_ROOT / "results", root=REPO_ROOT, readme=REPO_ROOT / "README.md",
                docs=REPO_ROOT / "docs")


def unpack_results() -> None:
    """The committed archives of ``results/archive/`` unpacked where their folders are missing or older
    (``softpvtol results unpack``); a folder that no archive wrote is kept, and named on stderr. Without the
    'baselines' extra (filelock) nothing is unpacked: the commands that read the archived results need it."""
    from softpvtol_gym.baselines.util.extras import installed

    if not installed("filelock"):
        return
    from softpvtol_gym.baselines.packed_results import unpack

    try:
        kept = unpack(LAYOUT.results)[1]
    except ConfigError as exc:  # an archive that does not read: one line, as every command's errors
        sys.stderr.write(f"results/archive: error: {exc}\n")
        raise SystemExit(2) from None
    for p in kept:
        sys.stderr.write(f"kept {p.target.relative_to(REPO_ROOT)}: no archive wrote it (python baselines/results.py "
                         f"pack archives it)\n")


def run(command: str, script: str) -> int:
    """``softpvtol COMMAND`` with this process's arguments and the checkout's layout, the committed results
    unpacked first (but for ``results`` itself); errors name ``script``."""
    try:
        if command != "results":
            require(script, prog=script)  # a missing extra is named before anything is imported for the unpack
            unpack_results()
        return run_command(command, sys.argv[1:], layout=LAYOUT, prog=script)
    except SystemExit as exc:
        leave_now_after_a_ray_interrupt(exc.code)
        raise
