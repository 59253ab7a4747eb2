"""Gymnasium environments: SoftPVTOL-v0 (single), its native vector env and the SB3 adapter.

``TASKS`` and ``TIERS`` are live lookups (PEP 562): the names registered at the time they are read
(:func:`softpvtol_gym.tasks.registered_tasks`, :func:`softpvtol_gym.envs.tiers.registered_tiers`).
"""

from ..registry import registered_tasks
from .actions import ACTION_MODES
from .config import EnvConfig
from .observation import OBS_NAMES
from .registration import ENV_ID, MODE_ENV_IDS, register_envs
from .reward import REWARD_TERMS
from .soft_pvtol import SoftPVTOLEnv
from .tiers import TierSpec, register_tier, registered_tiers
from .vector import SoftPVTOLVectorEnv

__all__ = [
    "SoftPVTOLEnv", "SoftPVTOLVectorEnv", "EnvConfig", "ACTION_MODES", "TASKS", "TIERS", "OBS_NAMES",
    "REWARD_TERMS", "TierSpec", "register_tier", "register_envs", "ENV_ID", "MODE_ENV_IDS",
]

_LIVE = {"TASKS": registered_tasks, "TIERS": registered_tiers}


def __getattr__(name: str):
    """``TASKS``, ``TIERS``: the names registered now."""
    if name in _LIVE:
        return _LIVE[name]()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LIVE))
