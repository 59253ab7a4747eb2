"""Compatibility module: the names of the former ``envs/core.py``, which is now split by job into
:mod:`.config`, :mod:`.tiers`, :mod:`.actions`, :mod:`.layout`, :mod:`.references`, :mod:`.episodes`,
:mod:`.noise`, :mod:`.observation`, :mod:`.reward`, :mod:`.termination`, :mod:`.step`,
:mod:`.batch_sim` and :mod:`.info` (tasks: :mod:`softpvtol_gym.tasks`). Import from those."""

from ..params import PARAM_FIELDS
from ..tasks import HOVER_SETPOINT, PAPER_Q0, TASKS
from .actions import ACTION_MODES, MODE_ACT, MODE_IDEAL, MODE_RES_ACT, MODE_VIRTUAL
from .batch_sim import BatchSim
from .config import ALLOCATIONS, INPUT_MAPS, PHYSICS_DT, RENDER_MODES, RESIDUAL_SPACES, EnvConfig
from .episodes import N_UNIFORMS, sample_episodes
from .observation import OBS_CLIP, OBS_DIM, OBS_NAMES
from .references import N_REF_PARAMS
from .reward import CRASH_PENALTY, REWARD_TERMS
from .termination import BOX_X, BOX_Z, GROUND_Z, MAX_ANG_SPEED, MAX_LIN_SPEED, R_NONE, REASONS
from .tiers import DEFAULT_TIER_OPTIONS, OBS_NOISE_Q, OBS_NOISE_QD, TIERS

__all__ = [
    "PARAM_FIELDS", "HOVER_SETPOINT", "PAPER_Q0", "TASKS", "ACTION_MODES", "MODE_ACT", "MODE_IDEAL", "MODE_RES_ACT",
    "MODE_VIRTUAL", "BatchSim", "ALLOCATIONS", "INPUT_MAPS", "PHYSICS_DT", "RENDER_MODES", "RESIDUAL_SPACES",
    "EnvConfig", "N_UNIFORMS", "sample_episodes", "OBS_CLIP", "OBS_DIM", "OBS_NAMES", "N_REF_PARAMS",
    "CRASH_PENALTY", "REWARD_TERMS", "BOX_X", "BOX_Z", "GROUND_Z", "MAX_ANG_SPEED", "MAX_LIN_SPEED", "REASONS",
    "R_NONE", "DEFAULT_TIER_OPTIONS", "OBS_NOISE_Q", "OBS_NOISE_QD", "TIERS",
]
