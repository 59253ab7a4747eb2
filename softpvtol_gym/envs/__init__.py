"""Gymnasium environments: SoftPVTOL-v0 (single), its native vector env and the SB3 adapter."""

from .core import ACTION_MODES, OBS_NAMES, REWARD_TERMS, TASKS, TIERS, EnvConfig
from .soft_pvtol import SoftPVTOLEnv
from .vector import SoftPVTOLVectorEnv

__all__ = [
    "SoftPVTOLEnv", "SoftPVTOLVectorEnv", "EnvConfig", "ACTION_MODES", "TASKS", "TIERS", "OBS_NAMES",
    "REWARD_TERMS", "register_envs",
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
