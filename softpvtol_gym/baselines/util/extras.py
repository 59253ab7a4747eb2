"""Optional dependencies of the commands: a missing one is named with the extra that installs it.

The package's plain install (``pip install softpvtol-gym``) has the env and the analytic controller; the
training, evaluation and leaderboard commands need the ``baselines`` extra, and Ray (``softpvtol run-jobs
--executor ray``, ``softpvtol tune``) the ``distributed`` extra. :func:`require` runs before a command's
module is imported (by :mod:`softpvtol_gym.baselines.cli` and the checkout's scripts), so a missing
package is reported in one line, never as an ImportError traceback. Standard library only.
"""

from __future__ import annotations

import importlib.util
import sys

EXTRA = "baselines"
#: what a learned policy needs (the RL library and the checkpoint format)
_LEARNED = ("stable_baselines3", "torch", "yaml", "filelock", "safetensors")
#: what each command imports beyond the plain install (module names), by its checkout script's name
NEEDS = {
    "train.py": (*_LEARNED, "tensorboard", "tqdm", "rich"),
    "evaluate.py": _LEARNED,
    "distill.py": (*_LEARNED, "tqdm"),
    "export.py": _LEARNED,
    "run_jobs.py": (*_LEARNED, "tensorboard", "tqdm"),
    "leaderboard.py": ("yaml", "filelock", "rliable", "matplotlib"),
    "score.py": ("yaml", "filelock", "rliable"),
    "ablation.py": ("yaml", "filelock", "rliable", "matplotlib"),
    "passivity_metrics.py": (),
    "reproduce_paper.py": (),  # matplotlib for the figures only (--no-plots, --render-only run without it)
    "model_figures.py": (),
    "results.py": ("safetensors",),
    "render_gif.py": (*_LEARNED, "PIL"),
    "tracking_figures.py": (*_LEARNED, "matplotlib", "PIL"),
    "tune.py": (*_LEARNED, "tensorboard", "ray", "optuna"),
}
#: modules of the ``distributed`` extra (Ray and the search library of its Tune searcher)
DISTRIBUTED = ("ray", "optuna")
#: module name -> distribution name, where they differ
_DIST = {"yaml": "pyyaml", "PIL": "pillow", "stable_baselines3": "stable-baselines3"}


def installed(module: str) -> bool:
    """Whether ``module`` is importable, found without importing it (a command's ``--help`` does not wait for
    torch)."""
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):  # a parent package that cannot be imported, or a module set to None
        return False


def missing(modules) -> list[str]:
    """The distribution names of ``modules`` that are not installed."""
    return [_DIST.get(m, m) for m in modules if not installed(m)]


def require(script: str, modules=None, prog: str | None = None) -> None:
    """Exit 2 with one line naming the missing packages and the extra that installs them if ``script``
    cannot run (``modules``: what it needs, default :data:`NEEDS` of the script; ``prog``: the name in the
    message, default ``script``)."""
    lost = missing(NEEDS.get(script, ()) if modules is None else modules)
    if lost:
        extra = "distributed" if set(lost) & set(DISTRIBUTED) else EXTRA
        sys.stderr.write(f"{prog or script}: error: missing {', '.join(lost)}, which the '{extra}' extra installs: "
                         f"pip install 'softpvtol-gym[{extra}]' (in a source checkout: pip install -e '.[{extra}]')\n")
        raise SystemExit(2)
