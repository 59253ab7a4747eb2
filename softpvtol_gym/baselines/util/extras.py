"""Optional dependencies of the scripts: a missing one is named with the extra that installs it.

The package's plain install (``pip install softpvtol-gym``) has the env, the controller and SB3; the
training, evaluation and leaderboard scripts need the ``baselines`` extra, and Ray (``run_jobs.py
--executor ray``, ``tune.py``) the ``distributed`` extra. Standard library only.
"""

from __future__ import annotations

import importlib
import sys

EXTRA = "baselines"
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
    "tracking_figures.py": ("yaml", "filelock", "safetensors", "matplotlib", "PIL"),
    "tune.py": ("yaml", "filelock", "safetensors", "tensorboard", "ray", "optuna"),
}
#: modules of the ``distributed`` extra (Ray and the search library of its Tune searcher)
DISTRIBUTED = ("ray", "optuna")
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


def require(script: str, modules=None) -> None:
    """Exit 2 with one line naming the missing packages and the extra that installs them if ``script``
    cannot run (``modules``: what it needs, default :data:`NEEDS` of the script)."""
    lost = missing(NEEDS.get(script, ()) if modules is None else modules)
    if lost:
        extra = "distributed" if set(lost) & set(DISTRIBUTED) else EXTRA
        sys.stderr.write(f"{script}: error: missing {', '.join(lost)}, which the '{extra}' extra installs: "
                         f"pip install 'softpvtol-gym[{extra}]' (in a source checkout: pip install -e '.[{extra}]')\n")
        raise SystemExit(2)
