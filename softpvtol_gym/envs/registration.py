"""Gymnasium ids: ``SoftPVTOL-v0`` (every argument free, action mode ``actuators`` by default) and one id
per action mode, ``SoftPVTOL<Mode>-v0``, whose action mode is fixed (rl-baselines3-zoo keys its
hyperparameter files by env id: ``softpvtol_gym/baselines/data/hyperparams/ppo.yml``).

``gym.make("SoftPVTOLResidual-v0", task="setpoint")`` is ``gym.make("SoftPVTOL-v0", action_mode="residual",
task="setpoint")``; giving such an id another ``action_mode`` is an error (not an override).
"""

from __future__ import annotations

from .actions import ACTION_MODES

ENV_ID = "SoftPVTOL-v0"
#: the id of each action mode (``SoftPVTOL-v0`` is the actuators mode with every argument free)
MODE_ENV_IDS = {mode: f"SoftPVTOL{mode.capitalize()}-v0" for mode in ACTION_MODES}


def _fixed_mode(mode: str, vector: bool):
    env_id = MODE_ENV_IDS[mode]

    def make(**kwargs):
        if "action_mode" in kwargs and kwargs["action_mode"] != mode:
            other = MODE_ENV_IDS.get(kwargs["action_mode"], ENV_ID)
            raise ValueError(f"{env_id} has action_mode={mode!r}; got action_mode={kwargs['action_mode']!r} (use "
                             f"{other!r}, or {ENV_ID!r} with action_mode=...)")
        kwargs["action_mode"] = mode
        if vector:
            from .vector import SoftPVTOLVectorEnv

            return SoftPVTOLVectorEnv(**kwargs)
        from .soft_pvtol import checked_env

        return checked_env(**kwargs)

    make.__doc__ = f"The {'vector ' if vector else ''}env of {env_id} (action_mode={mode!r})."
    return make


# the entry points of the per-mode ids ("softpvtol_gym.envs.registration:<mode>_env")
actuators_env = _fixed_mode("actuators", vector=False)
actuators_vector_env = _fixed_mode("actuators", vector=True)
virtual_env = _fixed_mode("virtual", vector=False)
virtual_vector_env = _fixed_mode("virtual", vector=True)
residual_env = _fixed_mode("residual", vector=False)
residual_vector_env = _fixed_mode("residual", vector=True)


def register_envs() -> None:
    """Register SoftPVTOL-v0 and the per-mode ids (idempotent). The env truncates itself: no
    max_episode_steps here."""
    from gymnasium.envs.registration import register, registry

    # the entry points wrap the env in softpvtol_gym.envs.soft_pvtol.PassiveEnvChecker (gymnasium's checker, whose
    # first-call checks wait for a successful reset): gym.make's own checker is off, so that it is not applied twice
    if ENV_ID not in registry:
        register(id=ENV_ID, entry_point="softpvtol_gym.envs.soft_pvtol:checked_env",
                 vector_entry_point="softpvtol_gym.envs.vector:SoftPVTOLVectorEnv", disable_env_checker=True)
    for mode, env_id in MODE_ENV_IDS.items():
        if env_id not in registry:
            register(id=env_id, entry_point=f"{__name__}:{mode}_env",
                     vector_entry_point=f"{__name__}:{mode}_vector_env", disable_env_checker=True)
