"""softpvtol-gym: a Gymnasium environment for the Soft-PVTOL soft aerial robot."""

from __future__ import annotations

from ._cache import configure_numba_cache
from ._version import __version__

#: the numba cache of this source version (see softpvtol_gym._cache); set before any kernel is defined
NUMBA_CACHE_DIR = configure_numba_cache()

from . import dynamics, integrators  # noqa: E402
from .envs import SoftPVTOLEnv, SoftPVTOLVectorEnv, register_envs  # noqa: E402
from .params import PARAM_FIELDS, SoftPVTOLParams  # noqa: E402
from .policies import ExtendedPolicy, PassivityPolicy  # noqa: E402

register_envs()

__all__ = [
    "SoftPVTOLParams", "PARAM_FIELDS", "dynamics", "integrators", "__version__",
    "SoftPVTOLEnv", "SoftPVTOLVectorEnv", "PassivityPolicy", "ExtendedPolicy", "MPCPolicy",
]


def __getattr__(name: str):
    """``MPCPolicy`` (:mod:`softpvtol_gym.policies.mpc`), imported on first use (PEP 562): the package
    imports without CasADi, the MPC's optional dependency."""
    if name == "MPCPolicy":
        from .policies.mpc import MPCPolicy

        return MPCPolicy
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
