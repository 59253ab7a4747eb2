"""Loading a checkpoint folder (for evaluation or for an exact resume) without unpickling."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from softpvtol_gym.baselines.checkpoints.manifest import (
    CONFIG_FILE,
    FORMAT,
    FORMAT_VERSION,
    MANIFEST_FILE,
    MODEL_STATE_FILE,
    REPLAY_FILE,
    STATE_ARRAYS_FILE,
    STATE_FILE,
    VECNORM_FILE,
    read_json,
    read_manifest,
    read_npz,
    read_verified,
)
from softpvtol_gym.baselines.checkpoints.model_state import load_model_state, load_tensors, vecnorm_from_dict
from softpvtol_gym.baselines.checkpoints.resume import global_rng_state, restore_env_state, restore_replay_buffer
from softpvtol_gym.baselines.config.hyperparams import normalize_kwargs
from softpvtol_gym.baselines.config.run_config import RunConfig
from softpvtol_gym.baselines.errors import CheckpointError, ConfigError
from softpvtol_gym.baselines.training.models import build_model, make_env, stack_frames
from softpvtol_gym.baselines.training.stacking import frame_stack_wrapper
from softpvtol_gym.baselines.util.safe_load import loads_yaml


# ------------------------------------------------------------------------------------- loading
def load_folder(folder: Path, *, training: bool = False, n_envs: int | None = None,
                tensorboard_log: str | None = None, verbose: int = 0, env=None, device: str = "cpu"):
    """Load the model of a checkpoint folder (a finished run or a training checkpoint) without unpickling.

    Returns ``(model, vecnorm, config, manifest)``: the SB3 model rebuilt from ``config.yaml`` and filled
    with the saved tensors and state; its VecNormalize (over ``env``, or a one-env stand-in for
    evaluation), or None when the run has no normalisation; the policy on ``device`` ("cpu" or "cuda").
    Every file is checked against the manifest;
    a run whose config asks for normalisation without a normalisation file (or the reverse) is an error.
    """

    folder = Path(folder)
    manifest = read_manifest(folder)
    config_bytes = read_verified(folder, manifest, CONFIG_FILE)

    raw = loads_yaml(config_bytes, str(folder / CONFIG_FILE), error=CheckpointError)
    if isinstance(raw, dict) and raw.get("algo") != manifest["algo"]:
        raise CheckpointError(f"{folder}: {MANIFEST_FILE} says {manifest['algo'].upper()}, config.yaml says "
                              f"{str(raw.get('algo')).upper()}")
    try:
        config = RunConfig.from_dict(raw, source=f"run config {folder / CONFIG_FILE}", strict=True)
    except ConfigError as exc:
        raise CheckpointError(str(exc)) from None
    norm = normalize_kwargs(config.hyperparams) is not None
    has_norm_file = VECNORM_FILE in manifest["files"]
    if norm and not has_norm_file:
        raise CheckpointError(f"{folder}: config.yaml asks for observation/reward normalisation but the checkpoint "
                              f"has no {VECNORM_FILE}; without it the policy would see unnormalised observations")
    if has_norm_file and not norm:
        raise CheckpointError(f"{folder}: {VECNORM_FILE} is present but config.yaml has no normalisation")
    tensors = load_tensors(folder, manifest)
    meta = read_json(folder, manifest, MODEL_STATE_FILE)
    if env is None:
        env = make_env(config, n_envs)
    vecnorm = None
    if norm:
        norm_env = env if training else make_env(config, 1)
        vecnorm = vecnorm_from_dict(read_json(folder, manifest, VECNORM_FILE), norm_env, training, str(folder))
        if not training:
            vecnorm.norm_reward = False
    # the model's observation space is that of the frame stack (hyperparameter frame_stack, saved in config.yaml;
    # a config without it: 1, no stack), over VecNormalize in training as in training.loop.prepare
    model_env = stack_frames(config, vecnorm if (training and vecnorm is not None) else env)
    model = build_model(config, model_env, tensorboard_log=tensorboard_log, verbose=verbose, device=device)
    load_model_state(model, tensors, meta, str(folder))
    if manifest["num_timesteps"] != model.num_timesteps:
        raise CheckpointError(f"{folder}: {MANIFEST_FILE} says {manifest['num_timesteps']} steps, "
                              f"{MODEL_STATE_FILE} says {model.num_timesteps}")
    return model, vecnorm, config, manifest


def _vecnorm_state(vecnorm, arrays: dict, num_envs: int, source: str) -> dict:
    """The VecNormalize attributes of a resume state (running returns, last raw observation and reward),
    checked: shape (num_envs, ...) of the run's env, finite."""
    if vecnorm is None:
        return {}
    obs_shape = tuple(vecnorm.observation_space.shape)
    expected = {"returns": ((num_envs,), True), "old_obs": ((num_envs, *obs_shape), False),
                "old_reward": ((num_envs,), False)}
    out = {}
    for attr, (shape, required) in expected.items():
        key = f"vecnormalize_{attr}"
        if key not in arrays:
            if required:
                raise CheckpointError(f"{source} lacks {key} (the run normalises its observations or rewards)")
            continue
        value = arrays[key]
        if attr == "old_reward" and value.shape == (0,):  # SB3's value before the first step
            shape = (0,)
        if value.shape != shape or value.dtype.kind != "f":
            raise CheckpointError(f"{source}: {key} is {value.dtype}{value.shape}, the run needs a float array of "
                                  f"shape {shape}")
        if not np.isfinite(value).all():
            raise CheckpointError(f"{source}: {key} holds non-finite values")
        out[attr] = value.astype(np.float64 if attr == "returns" else value.dtype, copy=True)
    return out


def load_for_resume(folder: Path, config: RunConfig, run_dir: Path, verbose: int = 0, device: str = "cpu"):
    """``(model, vecnorm, restore_rng)`` of a training checkpoint: the env rebuilt and put back in its saved
    state, the model and VecNormalize filled in. ``restore_rng()`` sets the global RNGs (call it last)."""
    folder = Path(folder)
    manifest = read_manifest(folder)
    state = read_json(folder, manifest, STATE_FILE)
    arrays = read_npz(folder, manifest, STATE_ARRAYS_FILE)

    env = make_env(config)
    model, vecnorm, saved, _ = load_folder(folder, training=True, env=env, tensorboard_log=str(Path(run_dir) / "tb"),
                                           verbose=verbose, device=device)
    if not isinstance(state, dict) or state.get("format") != FORMAT or state.get("version") != FORMAT_VERSION:
        raise CheckpointError(f"{folder}: {STATE_FILE} is not a version-{FORMAT_VERSION} resume state")
    if state.get("num_timesteps") != model.num_timesteps:
        raise CheckpointError(f"{folder}: {STATE_FILE} is for step {state.get('num_timesteps')}, the model for "
                              f"{model.num_timesteps}")
    if state.get("num_envs") != env.num_envs:
        raise CheckpointError(f"{folder}: {state.get('num_envs')} sub-envs saved, the run has {env.num_envs}")
    restore_env_state(env.venv, state.get("env", {}),
                      {k[4:]: v for k, v in arrays.items() if k.startswith("env/")}, str(folder))
    vecnorm_state = _vecnorm_state(vecnorm, arrays, env.num_envs, f"{folder / STATE_ARRAYS_FILE}")
    if getattr(model, "replay_buffer", None) is not None:
        if REPLAY_FILE not in manifest["files"]:
            raise CheckpointError(f"{folder}: an off-policy checkpoint without {REPLAY_FILE}")
        restore_replay_buffer(model.replay_buffer, read_json(folder, manifest, "replay_buffer.json"),
                              read_npz(folder, manifest, REPLAY_FILE), str(folder))
    stack = frame_stack_wrapper(model.get_env())
    if (stack is not None) != ("framestack_obs" in arrays):
        raise CheckpointError(f"{folder}: {STATE_ARRAYS_FILE} {'lacks' if stack is not None else 'has'} the frame "
                              f"stack's observations, config.yaml {'has' if stack is not None else 'has no'} "
                              f"frame_stack")
    if stack is not None:
        saved_stack, target = arrays["framestack_obs"], stack.stacked_obs.stacked_obs
        if saved_stack.shape != target.shape or saved_stack.dtype != target.dtype:
            raise CheckpointError(f"{folder}: framestack_obs is {saved_stack.dtype}{saved_stack.shape}, the run's "
                                  f"frame stack is {target.dtype}{target.shape}")
        if not np.isfinite(saved_stack).all():
            raise CheckpointError(f"{folder / STATE_ARRAYS_FILE}: framestack_obs holds non-finite values")
    restore = global_rng_state(state, arrays, str(folder))
    # everything checked: write the wrappers' state
    if stack is not None:
        stack.stacked_obs.stacked_obs = arrays["framestack_obs"].copy()
    for attr, value in vecnorm_state.items():
        setattr(vecnorm, attr, value)
    return model, vecnorm, restore
