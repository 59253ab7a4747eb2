"""Policies that act from the env's observations with the stable-baselines3 ``predict`` interface
(``predict(observation, state=None, episode_start=None, deterministic=True) -> (action, state)``), so that
one evaluator serves analytic, model-predictive and learned controllers.

=====================  =========================================================================
:mod:`.passivity`      :class:`PassivityPolicy`, the paper's passivity loops (and the loops beyond it)
:mod:`.extended`       :class:`ExtendedPolicy`, the dynamically extended loop
:mod:`.mpc`            :class:`MPCPolicy`, the nonlinear MPC (needs ``pip install 'softpvtol-gym[mpc]'``)
=====================  =========================================================================
"""

from .extended import ExtendedPolicy
from .passivity import PassivityPolicy

__all__ = ["PassivityPolicy", "ExtendedPolicy", "MPCPolicy"]


def __getattr__(name: str):
    """``MPCPolicy`` (:mod:`.mpc`), imported on first use (PEP 562): the package imports without loading the
    MPC's modules; building an MPCPolicy needs CasADi."""
    if name == "MPCPolicy":
        from .mpc import MPCPolicy

        return MPCPolicy
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
