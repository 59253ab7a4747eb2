"""Optional dependencies of the scripts: a missing one is named with the extra that installs it.

The package's plain install (``pip install softpvtol-gym``) has the env, the controller and SB3; the
training, evaluation and leaderboard scripts need the ``baselines`` extra. Standard library only.
"""

from __future__ import annotations

import importlib
import sys

EXTRA = "baselines"
INSTALL = "pip install 'softpvtol-gym[baselines]'"
#: what each script imports beyond the plain install (module names)
NEEDS = {
    "train.py": ("yaml", "filelock", "safetensors", "tensorboard", "tqdm", "rich"),
    "evaluate.py": ("yaml", "filelock", "safetensors"),
    "export.py": ("yaml", "filelock", "safetensors"),
    "run_jobs.py": ("yaml", "filelock", "safetensors", "tensorboard"),
    "leaderboard.py": ("yaml", "filelock", "rliable", "matplotlib"),
    "passivity_metrics.py": (),
    "reproduce_paper.py": ("matplotlib",),
    "render_gif.py": ("yaml", "filelock", "safetensors", "PIL"),
}
#: module name -> distribution name, where they differ
_DIST = {"yaml": "pyyaml", "PIL": "pillow"}


def missing(modules) -> list[str]:
    out = []
    for m in modules:
        try:
            importlib.import_module(m)
        except ImportError:
            out.append(_DIST.get(m, m))
    return out


def require(script: str) -> None:
    """Exit 2 with one line naming the missing packages and the extra if ``script`` cannot run."""
    lost = missing(NEEDS.get(script, ()))
    if lost:
        sys.stderr.write(f"{script}: error: missing {', '.join(lost)}, which the '{EXTRA}' extra installs: "
                         f"{INSTALL} (in a source checkout: pip install -e '.[{EXTRA}]')\n")
        raise SystemExit(2)
