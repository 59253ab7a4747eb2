"""Gymnasium environments: SoftPVTOL-v0 (single), its native vector env and the SB3 adapter."""

from ..tasks import TASKS
from .actions import ACTION_MODES
from .config import EnvConfig
from .observation import OBS_NAMES
from .reward import REWARD_TERMS
from .soft_pvtol import SoftPVTOLEnv
from .tiers import TIERS, TierSpec, register_tier
from .vector import SoftPVTOLVectorEnv

__all__ = [
    "SoftPVTOLEnv", "SoftPVTOLVectorEnv", "EnvConfig", "ACTION_MODES", "TASKS", "TIERS", "OBS_NAMES",
    "REWARD_TERMS", "TierSpec", "register_tier", "register_envs",
]


def register_envs() -> None:
    """Register SoftPVTOL-v0 (idempotent). The env truncates itself: no max_episode_steps here."""
    from gymnasium.envs.registration import register, registry

    if "SoftPVTOL-v0" in registry:
        return
    register(
        id="SoftPVTOL-v0",
        entry_point="softpvtol_gym.envs.soft_pvtol:SoftPVTOLEnv",
        vector_entry_point="softpvtol_gym.envs.vector:SoftPVTOLVectorEnv",
    )
