"""What an exact resume needs besides the model: the vector env's arrays, generator and RNG states, the
replay buffer."""

from __future__ import annotations

import json
import random
from pathlib import Path

import numpy as np

from softpvtol_gym.baselines.checkpoints.manifest import (
    FORMAT,
    FORMAT_VERSION,
    REPLAY_FILE,
    STATE_ARRAYS_FILE,
    STATE_FILE,
    generator_from_state,
    generator_state,
    npz_bytes,
)
from softpvtol_gym.baselines.errors import CheckpointError
from softpvtol_gym.baselines.training.models import frame_stack_wrapper
from softpvtol_gym.baselines.util.atomic import (
    atomic_write_bytes,
    atomic_write_text,
)
from softpvtol_gym.envs.sb3 import SoftPVTOLSB3VecEnv


def innermost(venv):
    """The SoftPVTOLSB3VecEnv below any SB3 VecEnv wrappers."""
    while not isinstance(venv, SoftPVTOLSB3VecEnv):
        venv = venv.venv  # SB3 VecEnvWrapper
    return venv


# -------------------------------------------------------------------------------- resume state
def _env_parts(vector_env) -> list[tuple[str, object]]:
    """The objects that hold the native vector env's state: the env, its simulator and (residual mode)
    the simulator's controller."""
    sim = vector_env._sim
    parts = [("venv", vector_env), ("sim", sim)]
    if getattr(sim, "controller", None) is not None:
        parts.append(("controller", sim.controller))
    return parts


def _is_scalar(v) -> bool:
    return v is None or (isinstance(v, (bool, int, float, str)) and not isinstance(v, np.generic))


def _is_generator_list(v) -> bool:
    return isinstance(v, list) and bool(v) and all(isinstance(g, np.random.Generator) for g in v)


def _state_attributes(obj) -> dict[str, str]:
    """The attributes of ``obj`` that are state, by kind: every numpy array (not of object dtype), numpy
    scalar, random generator (or list of them) and plain scalar (None, bool, int, float, str). Everything
    else (configs, spaces, callables) is built from the run's config and is not saved."""
    kinds = {}
    for name, v in vars(obj).items():
        if isinstance(v, np.ndarray):
            if v.dtype.kind != "O":
                kinds[name] = "array"
        elif isinstance(v, np.generic):
            kinds[name] = "numpy_scalar"
        elif isinstance(v, np.random.Generator):
            kinds[name] = "generator"
        elif _is_generator_list(v):
            kinds[name] = "generators"
        elif _is_scalar(v):
            kinds[name] = "scalar"
    return kinds


def env_state(vector_env) -> tuple[dict, dict[str, np.ndarray]]:
    """(JSON, arrays) of every state attribute of the vector env's objects (see :func:`_state_attributes`)."""
    meta, arrays = {}, {}
    for part, obj in _env_parts(vector_env):
        entry = {"arrays": [], "views": [], "numpy_scalars": [], "scalars": {}, "generators": {}}
        for name, kind in _state_attributes(obj).items():
            v = getattr(obj, name)
            if kind in ("array", "numpy_scalar"):
                arrays[f"{part}.{name}"] = np.array(v, copy=True)
                key = "numpy_scalars" if kind == "numpy_scalar" else ("views" if v.base is not None else "arrays")
                entry[key].append(name)
            elif kind == "generator":
                entry["generators"][name] = generator_state(v)
            elif kind == "generators":
                entry["generators"][name] = [generator_state(g) for g in v]
            else:
                entry["scalars"][name] = v
        meta[part] = entry
    return meta, arrays


def restore_env_state(vector_env, meta: dict, arrays: dict, source: str) -> None:
    """Write a saved :func:`env_state` into a freshly built vector env of the same configuration: arrays in
    place (views stay views), the rest set. A state attribute the env has and the checkpoint lacks (or the
    reverse) is an error: the checkpoint was written by another version of the env."""
    try:
        parts = dict(_env_parts(vector_env))
        if set(parts) != set(meta):
            raise ValueError(f"saved parts {sorted(meta)}, the env has {sorted(parts)}")
        for part, obj in parts.items():
            entry = meta[part]
            saved = (set(entry["arrays"]) | set(entry["views"]) | set(entry["numpy_scalars"]) | set(entry["scalars"])
                     | set(entry["generators"]))
            fresh = set(_state_attributes(obj))
            # a None attribute may hold an array later (the controller's memory): compare what can be
            lost = sorted(n for n in fresh - saved if getattr(obj, n) is not None)
            if lost:
                raise ValueError(f"{part} has state {lost} that the checkpoint lacks")
            for name, value in entry["scalars"].items():
                if not _is_scalar(value):
                    raise ValueError(f"{part}.{name} is not a plain value")
                setattr(obj, name, value)
            for name in entry["arrays"] + entry["views"]:  # bases before views
                arr = arrays[f"{part}.{name}"]
                cur = getattr(obj, name)
                if isinstance(cur, np.ndarray) and cur.shape == arr.shape and cur.dtype == arr.dtype:
                    np.copyto(cur, arr)
                elif name in entry["views"]:
                    raise ValueError(f"{part}.{name} is {arr.dtype}{arr.shape}, the env's is "
                                     f"{getattr(cur, 'dtype', None)}{getattr(cur, 'shape', None)}")
                else:
                    setattr(obj, name, arr.copy())
            for name in entry["numpy_scalars"]:
                setattr(obj, name, arrays[f"{part}.{name}"][()])
            for name, value in entry["generators"].items():
                if isinstance(value, list):
                    setattr(obj, name, [generator_from_state(g, source) for g in value])
                else:
                    setattr(obj, name, None if value is None else generator_from_state(value, source))
    except (KeyError, TypeError, ValueError) as exc:
        raise CheckpointError(f"{source}: the saved env state does not fit this run's env "
                              f"({type(exc).__name__}: {exc})") from None


def resume_payload(model, vecnorm) -> tuple[dict, dict]:
    """(JSON state, arrays) of everything besides the model that an exact resume needs."""
    import torch

    venv = innermost(vecnorm if vecnorm is not None else model.get_env()).venv
    env_meta, env_arrays = env_state(venv)
    arrays = {f"env/{k}": v for k, v in env_arrays.items()}
    np_state = np.random.get_state()
    arrays["numpy_rng_key"] = np.asarray(np_state[1])
    arrays["torch_rng"] = torch.get_rng_state().numpy().copy()
    stack = frame_stack_wrapper(model.get_env())
    if stack is not None:  # the last K observations of each sub-env (the model's _last_obs is a copy of them)
        arrays["framestack_obs"] = np.array(stack.stacked_obs.stacked_obs, copy=True)
    if vecnorm is not None:
        arrays["vecnormalize_returns"] = np.asarray(vecnorm.returns, dtype=np.float64)
        for attr in ("old_obs", "old_reward"):
            value = getattr(vecnorm, attr, None)
            if value is not None:
                arrays[f"vecnormalize_{attr}"] = np.asarray(value)
    py = random.getstate()
    state = {
        "format": FORMAT, "version": FORMAT_VERSION, "num_timesteps": int(model.num_timesteps),
        "num_envs": int(venv.num_envs),
        "numpy_rng": {"name": np_state[0], "pos": int(np_state[2]), "has_gauss": int(np_state[3]),
                      "cached_gaussian": float(np_state[4])},
        "python_rng": [py[0], list(py[1]), py[2]],
        "env": env_meta,
    }
    return state, arrays


def save_resume_state(model, vecnorm, folder: Path) -> list[str]:
    state, arrays = resume_payload(model, vecnorm)
    atomic_write_bytes(Path(folder) / STATE_ARRAYS_FILE, npz_bytes(arrays))
    atomic_write_text(Path(folder) / STATE_FILE, json.dumps(state))
    return [STATE_FILE, STATE_ARRAYS_FILE]


def global_rng_state(state: dict, arrays: dict, source: str):
    """A function that restores the numpy / torch / python RNG states (validated now, applied later)."""
    import torch

    try:
        np_rng = state["numpy_rng"]
        key = arrays["numpy_rng_key"]
        if key.dtype != np.uint32 or key.shape != (624,):
            raise ValueError(f"numpy_rng_key is {key.dtype}{key.shape}")
        np_state = (str(np_rng["name"]), key.copy(), int(np_rng["pos"]), int(np_rng["has_gauss"]),
                    float(np_rng["cached_gaussian"]))
        torch_state = torch.from_numpy(arrays["torch_rng"].astype(np.uint8, copy=True))
        py = state["python_rng"]
        py_state = (int(py[0]), tuple(int(x) for x in py[1]), py[2] if py[2] is None else float(py[2]))
        # checked on throw-away generators before anything is changed
        np.random.RandomState().set_state(np_state)
        torch.Generator().set_state(torch_state)
        random.Random().setstate(py_state)
    except (KeyError, TypeError, ValueError, IndexError, RuntimeError) as exc:
        raise CheckpointError(f"{source}: invalid RNG state ({type(exc).__name__}: {exc})") from None

    def restore() -> None:
        np.random.set_state(np_state)
        torch.set_rng_state(torch_state)
        random.setstate(py_state)

    return restore


# ------------------------------------------------------------------------------------ replay buffer
_REPLAY_ARRAYS = ("observations", "next_observations", "actions", "rewards", "dones", "timeouts")


def save_replay_buffer(buffer, folder: Path) -> tuple[list[str], dict]:
    n = buffer.buffer_size if buffer.full else buffer.pos
    arrays = {k: getattr(buffer, k)[:n] for k in _REPLAY_ARRAYS if getattr(buffer, k, None) is not None}
    atomic_write_bytes(Path(folder) / REPLAY_FILE, npz_bytes(arrays))
    return [REPLAY_FILE], {"pos": int(buffer.pos), "full": bool(buffer.full), "filled": int(n),
                           "buffer_size": int(buffer.buffer_size), "n_envs": int(buffer.n_envs)}


def restore_replay_buffer(buffer, info: dict, arrays: dict, source: str) -> None:
    try:
        if info["buffer_size"] != buffer.buffer_size or info["n_envs"] != buffer.n_envs:
            raise ValueError(f"saved buffer of {info['buffer_size']} x {info['n_envs']}, the run's is "
                             f"{buffer.buffer_size} x {buffer.n_envs}")
        n = int(info["filled"])
        for k in _REPLAY_ARRAYS:
            target = getattr(buffer, k, None)
            if target is None:
                continue
            saved = arrays[k]
            if saved.shape != (n, *target.shape[1:]) or saved.dtype != target.dtype:
                raise ValueError(f"{k} is {saved.dtype}{saved.shape}")
            target[:n] = saved
        buffer.pos, buffer.full = int(info["pos"]), bool(info["full"])
    except (KeyError, TypeError, ValueError) as exc:
        raise CheckpointError(f"{source}: {REPLAY_FILE} does not fit the run's replay buffer ({exc})") from None
