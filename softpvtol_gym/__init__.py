"""softpvtol-gym: a Gymnasium environment for the Soft-PVTOL soft aerial robot."""

from __future__ import annotations

from . import dynamics, integrators
from .params import PARAM_FIELDS, SoftPVTOLParams
from .envs import SoftPVTOLEnv, SoftPVTOLVectorEnv, register_envs
from .policies import PassivityPolicy

register_envs()

__version__ = "0.1.0"

__all__ = [
    "SoftPVTOLParams", "PARAM_FIELDS", "dynamics", "integrators", "__version__",
    "SoftPVTOLEnv", "SoftPVTOLVectorEnv", "PassivityPolicy",
]
