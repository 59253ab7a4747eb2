"""Gymnasium environments: SoftPVTOL-v0 (single), its native vector env and the SB3 adapter."""

from ..tasks import TASKS
from .actions import ACTION_MODES
from .config import EnvConfig
from .observation import OBS_NAMES
from .registration import ENV_ID, MODE_ENV_IDS, register_envs
from .reward import REWARD_TERMS
from .soft_pvtol import SoftPVTOLEnv
from .tiers import TIERS, TierSpec, register_tier
from .vector import SoftPVTOLVectorEnv

__all__ = [
    "SoftPVTOLEnv", "SoftPVTOLVectorEnv", "EnvConfig", "ACTION_MODES", "TASKS", "TIERS", "OBS_NAMES",
    "REWARD_TERMS", "TierSpec", "register_tier", "register_envs", "ENV_ID", "MODE_ENV_IDS",
]

