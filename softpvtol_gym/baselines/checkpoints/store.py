"""Checkpoints that cannot run code: weights in safetensors, everything else in JSON / npz.

A checkpoint is a folder. A finished run directory is one (its final model), and so is every
``<run>/checkpoints/step_<NNNNNNNNNN>/`` taken during training. Files:

* ``model.safetensors``   every tensor of the SB3 model: the policy's ``state_dict`` (``policy/...``), the
  optimizers' state (``<optimizer>/state/<i>/<key>``), SB3's extra torch variables (``variables/...``,
  SAC's entropy coefficient) and the model's last observation arrays (``attributes/...``);
* ``model.json``          the rest of the model's training state: algorithm, counters (``num_timesteps``,
  ``_n_updates``, ...), the optimizers' parameter groups, the episode-info buffer, the RNG states of the
  action and observation spaces;
* ``vecnormalize.json``   the VecNormalize settings and running statistics (absent without normalisation);
* ``config.yaml``         the run's :class:`~baselines.config.RunConfig` (the network is rebuilt from it);
* ``resume_state.json`` + ``resume_state.npz``  (training checkpoints) what an exact resume needs
  besides: every array of the vector env (each sub-env mid-episode, the residual controller's memory),
  the sub-envs' generator states, VecNormalize's running returns, the numpy / torch / python RNG states;
* ``replay_buffer.npz`` + ``replay_buffer.json``  (off-policy algorithms) the filled part of the replay
  buffer and its position;
* ``checkpoint.json``     the manifest, written last: format version, algorithm, step count and the
  SHA-256 and size of every file above. A folder without a manifest that verifies is not a checkpoint.

Loading never unpickles: safetensors and JSON hold data only, ``np.load`` runs with
``allow_pickle=False``, and the model is rebuilt from ``config.yaml`` before its weights are filled in.
Files with other names (a ``model.zip`` or ``*.pkl`` planted next to them) are ignored; pickle-based
files are read only through :mod:`baselines.export` with an explicit ``trust_pickle``.

Training checkpoints are written into a temporary folder that is fsync'ed and renamed into place;
``checkpoints/latest`` (the step folder's name) is then replaced atomically, and the newest ``keep`` are
kept. A process killed at any moment leaves the previous or the new checkpoint, never a half-written
one; a checkpoint that does not verify (a bad disk, an edit) is skipped in favour of the previous one.
Checkpoints are taken at rollout boundaries (after a PPO update, before the next rollout), so resuming
continues with exactly the steps that were not yet trained on; for PPO on this env the resumed run is
bit for bit the uninterrupted one (tested).
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import random
import re
import shutil
import sys
from collections import deque
from pathlib import Path

import numpy as np

from .atomic import atomic_dir, atomic_write_bytes, atomic_write_text, clean_stale_temps, fsync_dir
from .config import CONFIG_FILE_NAME, RunConfig, normalize_kwargs
from .errors import CheckpointError, ConfigError
from .models import frame_stack_wrapper

FORMAT = "softpvtol-gym checkpoint"
FORMAT_VERSION = 1
LATEST = "latest"
MANIFEST_FILE = "checkpoint.json"
MODEL_FILE = "model.safetensors"
MODEL_STATE_FILE = "model.json"
VECNORM_FILE = "vecnormalize.json"
CONFIG_FILE = CONFIG_FILE_NAME
STATE_FILE = "resume_state.json"
STATE_ARRAYS_FILE = "resume_state.npz"
REPLAY_FILE = "replay_buffer.npz"
#: the files of the model itself (what evaluation reads), in the order they are written
MODEL_FILES = (MODEL_FILE, MODEL_STATE_FILE, VECNORM_FILE, CONFIG_FILE)
#: names of pickle-based files of earlier versions (and of SB3): never loaded without trust_pickle
LEGACY_FILES = ("model.zip", "vecnormalize.pkl", "resume_state.pkl", "replay_buffer.pkl")
STEP_RE = re.compile(r"^step_\d{10}$")
#: model attributes saved in model.json (counters) and model.safetensors (arrays)
COUNTERS = ("num_timesteps", "_total_timesteps", "_num_timesteps_at_start", "_n_updates", "_episode_num",
            "_current_progress_remaining")
ARRAY_ATTRIBUTES = ("_last_obs", "_last_original_obs", "_last_episode_starts")
_BIT_GENERATORS = ("PCG64", "PCG64DXSM", "MT19937", "Philox", "SFC64")


def step_dir_name(step: int) -> str:
    return f"step_{step:010d}"


# ---------------------------------------------------------------------------------------- manifest
def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def write_manifest(folder: Path, names: list[str], algo: str, num_timesteps: int, kind: str) -> None:
    """Write ``checkpoint.json`` over the files ``names`` of ``folder`` (last: it makes the folder a
    checkpoint)."""
    files = {}
    for name in names:
        data = (Path(folder) / name).read_bytes()
        files[name] = {"sha256": _sha256(data), "bytes": len(data)}
    manifest = {"format": FORMAT, "version": FORMAT_VERSION, "kind": kind, "algo": algo,
                "num_timesteps": int(num_timesteps), "files": files}
    atomic_write_text(Path(folder) / MANIFEST_FILE, json.dumps(manifest, indent=1))


def read_manifest(folder: Path) -> dict:
    """The verified manifest of a checkpoint folder; CheckpointError if it is missing, malformed, or a file it
    lists is missing or differs (size or SHA-256) from what was written."""
    folder = Path(folder)
    path = folder / MANIFEST_FILE
    if not path.is_file():
        raise CheckpointError(f"{folder} is not a checkpoint: no {MANIFEST_FILE}")
    try:
        manifest = json.loads(path.read_bytes())
    except (OSError, ValueError) as exc:
        raise CheckpointError(f"{path} is not readable JSON ({exc})") from None
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise CheckpointError(f"{path} is not a {FORMAT} manifest")
    if manifest.get("version") != FORMAT_VERSION:
        raise CheckpointError(f"{path} has format version {manifest.get('version')!r}; this softpvtol-gym reads "
                              f"version {FORMAT_VERSION}")
    files = manifest.get("files")
    if (not isinstance(files, dict) or not isinstance(manifest.get("num_timesteps"), int)
            or manifest.get("algo") not in ("ppo", "sac")):
        raise CheckpointError(f"{path} is malformed (expected files, algo and num_timesteps)")
    for name, entry in files.items():
        if not isinstance(name, str) or "/" in name or name.startswith(".") or not isinstance(entry, dict):
            raise CheckpointError(f"{path} lists an invalid file entry {name!r}")
        if not (folder / name).is_file():
            raise CheckpointError(f"checkpoint {folder} is incomplete: {name} is missing")
    return manifest


def read_verified(folder: Path, manifest: dict, name: str) -> bytes:
    """The bytes of ``name`` in a checkpoint folder, checked against its manifest entry."""
    entry = manifest["files"].get(name)
    if entry is None:
        raise CheckpointError(f"checkpoint {folder} has no {name} (its manifest does not list it)")
    path = Path(folder) / name
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise CheckpointError(f"cannot read {path}: {exc}") from None
    if len(data) != entry.get("bytes") or _sha256(data) != entry.get("sha256"):
        raise CheckpointError(f"{path} is corrupt or was changed after it was written: its size or SHA-256 does "
                              f"not match {MANIFEST_FILE}")
    return data


def _json(folder: Path, manifest: dict, name: str):
    data = read_verified(folder, manifest, name)
    try:
        return json.loads(data)
    except ValueError as exc:
        raise CheckpointError(f"{Path(folder) / name} is not valid JSON ({exc})") from None


def _npz(folder: Path, manifest: dict, name: str) -> dict[str, np.ndarray]:
    data = read_verified(folder, manifest, name)
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError) as exc:
        raise CheckpointError(f"{Path(folder) / name} is not a readable npz archive ({exc})") from None


def _npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


# ------------------------------------------------------------------------------- JSON helpers
def _to_json(value):
    """Tuples survive a JSON round trip (optimizer parameter groups hold ``betas`` tuples)."""
    if isinstance(value, tuple):
        return {"__tuple__": [_to_json(v) for v in value]}
    if isinstance(value, list):
        return [_to_json(v) for v in value]
    if isinstance(value, dict):
        return {k: _to_json(v) for k, v in value.items()}
    if isinstance(value, np.generic):
        return value.item()
    return value


def _from_json(value):
    if isinstance(value, dict):
        if set(value) == {"__tuple__"}:
            return tuple(_from_json(v) for v in value["__tuple__"])
        return {k: _from_json(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_from_json(v) for v in value]
    return value


def generator_state(gen) -> dict | None:
    return None if gen is None else _to_json(gen.bit_generator.state)


def generator_from_state(state: dict, what: str):
    if not isinstance(state, dict) or state.get("bit_generator") not in _BIT_GENERATORS:
        raise CheckpointError(f"{what}: unknown random generator state {str(state)[:80]!r}")
    gen = np.random.Generator(getattr(np.random, state["bit_generator"])())
    try:
        gen.bit_generator.state = _from_json(state)
    except (TypeError, ValueError, KeyError) as exc:
        raise CheckpointError(f"{what}: invalid random generator state ({exc})") from None
    return gen


# ------------------------------------------------------------------------------------- the model
def _torch_objects(model):
    """(name, object) of every state_dict SB3 saves for ``model``, and (name, tensor) of its variables."""
    def get(name: str):
        obj = model
        for part in name.split("."):
            obj = getattr(obj, part)
        return obj

    state_dicts, variables = model._get_torch_save_params()
    return [(n, get(n)) for n in state_dicts], [(n, get(n)) for n in variables or []]


def model_payload(model) -> tuple[dict, dict]:
    """(tensors, JSON metadata) of everything of an SB3 model that a resume needs."""
    import torch

    tensors: dict[str, torch.Tensor] = {}
    optimizers = {}
    state_dicts, variables = _torch_objects(model)
    for name, obj in state_dicts:
        if isinstance(obj, torch.nn.Module):
            for k, v in obj.state_dict().items():
                tensors[f"{name}/{k}"] = v
        elif isinstance(obj, torch.optim.Optimizer):
            sd = obj.state_dict()
            scalars: dict[str, dict] = {}
            for pid, entries in sd["state"].items():
                for k, v in entries.items():
                    if torch.is_tensor(v):
                        tensors[f"{name}/state/{pid}/{k}"] = v
                    else:
                        scalars.setdefault(str(pid), {})[k] = _to_json(v)
            optimizers[name] = {"param_groups": _to_json(sd["param_groups"]), "scalar_state": scalars,
                                "params_with_state": sorted(int(p) for p in sd["state"])}
        else:  # pragma: no cover (SB3 saves modules and optimizers only)
            raise TypeError(f"cannot save {name}: {type(obj).__name__}")
    for name, tensor in variables:
        tensors[f"variables/{name}"] = tensor.detach()
    for attr in ARRAY_ATTRIBUTES:
        value = getattr(model, attr, None)
        if value is not None:
            tensors[f"attributes/{attr}"] = torch.from_numpy(np.ascontiguousarray(value))
    tensors = {k: v.detach().cpu().clone().contiguous() for k, v in tensors.items()}
    meta = {
        "format": FORMAT, "version": FORMAT_VERSION, "algo": type(model).__name__.lower(),
        "counters": {c: getattr(model, c) for c in COUNTERS},
        "optimizers": optimizers,
        "ep_info_buffer": _to_json(list(model.ep_info_buffer or [])),
        "ep_success_buffer": _to_json(list(model.ep_success_buffer or [])),
        "action_space_rng": generator_state(getattr(model.action_space, "_np_random", None)),
        "observation_space_rng": generator_state(getattr(model.observation_space, "_np_random", None)),
    }
    return tensors, meta


def save_model(model, folder: Path) -> list[str]:
    """Write ``model.safetensors`` and ``model.json`` of ``model`` into ``folder``; returns their names."""
    from safetensors.torch import save as st_save

    tensors, meta = model_payload(model)
    atomic_write_bytes(Path(folder) / MODEL_FILE, st_save(tensors, metadata={"format": FORMAT,
                                                                            "version": str(FORMAT_VERSION)}))
    atomic_write_text(Path(folder) / MODEL_STATE_FILE, json.dumps(meta, indent=1))
    return [MODEL_FILE, MODEL_STATE_FILE]


def _load_tensors(folder: Path, manifest: dict) -> dict:
    from safetensors import SafetensorError
    from safetensors.torch import load as st_load

    data = read_verified(folder, manifest, MODEL_FILE)
    try:
        return st_load(data)
    except (SafetensorError, ValueError, RuntimeError) as exc:
        raise CheckpointError(f"{Path(folder) / MODEL_FILE} is not a readable safetensors file ({exc})") from None


def load_model_state(model, tensors: dict, meta: dict, source: str) -> None:
    """Fill a freshly built SB3 ``model`` with saved tensors and metadata (strict: every tensor must fit)."""
    import torch

    if not isinstance(meta, dict) or meta.get("format") != FORMAT or meta.get("version") != FORMAT_VERSION:
        raise CheckpointError(f"{source}: {MODEL_STATE_FILE} is not a version-{FORMAT_VERSION} model description")
    algo = type(model).__name__.lower()
    if meta.get("algo") != algo:
        raise CheckpointError(f"{source}: the weights are of a {str(meta.get('algo')).upper()} model, config.yaml "
                              f"says {algo.upper()}")
    used = set()
    state_dicts, variables = _torch_objects(model)
    try:
        for name, obj in state_dicts:
            prefix = f"{name}/"
            if isinstance(obj, torch.nn.Module):
                sd = {k[len(prefix):]: v for k, v in tensors.items() if k.startswith(prefix)}
                used.update(prefix + k for k in sd)
                obj.load_state_dict(sd, strict=True)
            else:
                info = meta["optimizers"][name]
                state: dict[int, dict] = {}
                for pid in info["params_with_state"]:
                    entry = dict(_from_json(info["scalar_state"].get(str(pid), {})))
                    p = f"{prefix}state/{pid}/"
                    for k, v in tensors.items():
                        if k.startswith(p):
                            entry[k[len(p):]] = v
                            used.add(k)
                    state[int(pid)] = entry
                obj.load_state_dict({"state": state, "param_groups": _from_json(info["param_groups"])})
        for name, var in variables:
            key = f"variables/{name}"
            if key not in tensors:
                raise KeyError(key)
            with torch.no_grad():
                var.copy_(tensors[key])
            used.add(key)
    except (KeyError, RuntimeError, ValueError, TypeError, IndexError) as exc:
        raise CheckpointError(f"{source}: the saved weights do not fit the network that config.yaml describes "
                              f"({type(exc).__name__}: {str(exc)[:300]})") from None
    for attr in ARRAY_ATTRIBUTES:
        key = f"attributes/{attr}"
        if key in tensors:
            setattr(model, attr, tensors[key].numpy().copy())
            used.add(key)
    extra = sorted(set(tensors) - used)
    if extra:
        raise CheckpointError(f"{source}: {MODEL_FILE} holds tensors the model does not have: {extra[:5]}")
    counters = meta.get("counters", {})
    for c in COUNTERS:
        if c in counters:
            setattr(model, c, counters[c])
    model.ep_info_buffer = deque(_from_json(meta.get("ep_info_buffer", [])), maxlen=model._stats_window_size)
    model.ep_success_buffer = deque(_from_json(meta.get("ep_success_buffer", [])), maxlen=model._stats_window_size)
    for space, key in ((model.action_space, "action_space_rng"), (model.observation_space, "observation_space_rng")):
        if meta.get(key) is not None:
            space._np_random = generator_from_state(meta[key], f"{source}: {key}")


# ------------------------------------------------------------------------------------ VecNormalize
def vecnorm_dict(vecnorm) -> dict:
    def rms(r):
        return {"mean": np.asarray(r.mean, dtype=np.float64).tolist(), "var": np.asarray(r.var, np.float64).tolist(),
                "count": float(r.count), "shape": list(np.shape(r.mean))}

    return {"format": FORMAT, "version": FORMAT_VERSION,
            "norm_obs": bool(vecnorm.norm_obs), "norm_reward": bool(vecnorm.norm_reward),
            "clip_obs": float(vecnorm.clip_obs), "clip_reward": float(vecnorm.clip_reward),
            "gamma": float(vecnorm.gamma), "epsilon": float(vecnorm.epsilon),
            "obs_rms": rms(vecnorm.obs_rms), "ret_rms": rms(vecnorm.ret_rms)}


def save_vecnorm(vecnorm, folder: Path) -> list[str]:
    atomic_write_text(Path(folder) / VECNORM_FILE, json.dumps(vecnorm_dict(vecnorm), indent=1, allow_nan=False))
    return [VECNORM_FILE]


def vecnorm_from_dict(data, venv, training: bool, source: str):
    """A VecNormalize over ``venv`` with the saved settings and statistics (validated)."""
    from stable_baselines3.common.vec_env import VecNormalize

    try:
        if data.get("format") != FORMAT or data.get("version") != FORMAT_VERSION:
            raise ValueError("not a version-1 VecNormalize description")
        vn = VecNormalize(venv, training=training, norm_obs=bool(data["norm_obs"]),
                          norm_reward=bool(data["norm_reward"]), clip_obs=float(data["clip_obs"]),
                          clip_reward=float(data["clip_reward"]), gamma=float(data["gamma"]),
                          epsilon=float(data["epsilon"]))
        for name in ("obs_rms", "ret_rms"):
            r, saved = getattr(vn, name), data[name]
            mean = np.asarray(saved["mean"], dtype=np.float64)
            var = np.asarray(saved["var"], dtype=np.float64)
            if mean.shape != np.shape(r.mean) or var.shape != np.shape(r.var):
                raise ValueError(f"{name} has shape {mean.shape}, the env needs {np.shape(r.mean)}")
            if not (np.isfinite(mean).all() and np.isfinite(var).all() and (var >= 0).all()):
                raise ValueError(f"{name} holds non-finite or negative values")
            count = float(saved["count"])
            if not (np.isfinite(count) and count > 0):
                raise ValueError(f"{name}.count must be > 0, got {count}")
            r.mean, r.var, r.count = (mean if mean.ndim else float(mean)), (var if var.ndim else float(var)), count
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise CheckpointError(f"{source}: {VECNORM_FILE} is invalid ({type(exc).__name__}: {exc})") from None
    return vn


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
    atomic_write_bytes(Path(folder) / STATE_ARRAYS_FILE, _npz_bytes(arrays))
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
    atomic_write_bytes(Path(folder) / REPLAY_FILE, _npz_bytes(arrays))
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


# ---------------------------------------------------------------------------------- checkpoints
def innermost(venv):
    """The SoftPVTOLSB3VecEnv below any SB3 VecEnv wrappers."""
    from softpvtol_gym.envs.sb3 import SoftPVTOLSB3VecEnv

    while not isinstance(venv, SoftPVTOLSB3VecEnv):
        venv = venv.venv  # SB3 VecEnvWrapper
    return venv


def write_model_files(folder: Path, model, vecnorm, config: RunConfig, kind: str) -> None:
    """The model files and, last, the manifest (a run's final model, or the model part of a checkpoint)."""
    folder = Path(folder)
    names = save_model(model, folder)
    if vecnorm is not None:
        names += save_vecnorm(vecnorm, folder)
    if not (folder / CONFIG_FILE).is_file() or RunConfig.load(folder / CONFIG_FILE) != config:
        config.save(folder / CONFIG_FILE)
    names.append(CONFIG_FILE)
    write_manifest(folder, names, config.algo, model.num_timesteps, kind)


def save_checkpoint(run_dir: Path, model, vecnorm, config: RunConfig, keep: int = 2) -> Path:
    """Write a checkpoint of ``model`` (on ``vecnorm`` over the SB3 adapter) atomically; keep the newest
    ``keep`` checkpoints. Returns the checkpoint directory."""
    root = Path(run_dir) / "checkpoints"
    root.mkdir(parents=True, exist_ok=True)
    name = step_dir_name(int(model.num_timesteps))
    final = root / name
    if not _verifies(final):  # the same step again (a resumed run's first boundary): keep the existing one
        with atomic_dir(final) as tmp:
            names = save_model(model, tmp)
            if vecnorm is not None:
                names += save_vecnorm(vecnorm, tmp)
            config.save(tmp / CONFIG_FILE)
            names += [CONFIG_FILE, *save_resume_state(model, vecnorm, tmp)]
            replay = {}
            if getattr(model, "replay_buffer", None) is not None:  # off-policy algorithms (SAC)
                files, replay = save_replay_buffer(model.replay_buffer, tmp)
                names += files
            if replay:
                atomic_write_text(tmp / "replay_buffer.json", json.dumps(replay))
                names.append("replay_buffer.json")
            write_manifest(tmp, names, config.algo, model.num_timesteps, "checkpoint")
    atomic_write_text(root / LATEST, name)
    for old in sorted(p for p in root.glob("step_*") if p.is_dir() and STEP_RE.match(p.name))[:-keep]:
        remove_dir(old)
    fsync_dir(root)
    return final


def remove_dir(path: Path) -> None:
    """Remove a directory so that a process killed meanwhile leaves no half-deleted folder under its name:
    it is renamed to a temporary name first (removed by the next start if the removal is interrupted)."""
    from .atomic import temp_name

    tmp = temp_name(path)
    try:
        os.replace(path, tmp)
    except FileNotFoundError:
        return
    shutil.rmtree(tmp, ignore_errors=True)


def _verifies(folder: Path) -> bool:
    try:
        manifest = read_manifest(folder)
        for name in manifest["files"]:
            read_verified(folder, manifest, name)
        return True
    except CheckpointError:
        return False


def checkpoint_candidates(run_dir: Path) -> list[Path]:
    """A run's training checkpoint folders, newest first: the one ``checkpoints/latest`` names (if it
    is a valid step name), then every other ``step_*`` folder by step. Nothing is verified yet."""
    root = Path(run_dir) / "checkpoints"
    out = []
    pointer = root / LATEST
    if pointer.is_file():
        try:
            name = pointer.read_text(encoding="ascii").strip()
        except (OSError, UnicodeDecodeError):
            name = ""
        if STEP_RE.match(name) and (root / name).is_dir():
            out.append(root / name)
    for p in sorted((p for p in root.glob("step_*") if STEP_RE.match(p.name) and p.is_dir()), reverse=True):
        if p not in out:
            out.append(p)
    return out


def latest_checkpoint(run_dir: Path) -> Path | None:
    """The newest training checkpoint of a run that verifies against its manifest, or None."""
    for cand in checkpoint_candidates(run_dir):
        if _verifies(cand):
            return cand
    return None


def clean_run_dir(run_dir: Path) -> None:
    """Remove what killed writers left in a run directory this process holds the lock of."""
    run_dir = Path(run_dir)
    clean_stale_temps(run_dir, everything=True)
    clean_stale_temps(run_dir / "checkpoints", everything=True)


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
    from .models import build_model, make_env, stack_frames

    folder = Path(folder)
    manifest = read_manifest(folder)
    config_bytes = read_verified(folder, manifest, CONFIG_FILE)
    import yaml

    try:
        raw = yaml.safe_load(config_bytes)
    except yaml.YAMLError as exc:
        raise CheckpointError(f"{folder / CONFIG_FILE} is not valid YAML ({exc})") from None
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
    tensors = _load_tensors(folder, manifest)
    meta = _json(folder, manifest, MODEL_STATE_FILE)
    if env is None:
        env = make_env(config, n_envs)
    vecnorm = None
    if norm:
        norm_env = env if training else make_env(config, 1)
        vecnorm = vecnorm_from_dict(_json(folder, manifest, VECNORM_FILE), norm_env, training, str(folder))
        if not training:
            vecnorm.norm_reward = False
    # the model's observation space is that of the frame stack (hyperparameter frame_stack, saved in config.yaml;
    # a config without it: 1, no stack), over VecNormalize in training as in baselines.training.prepare
    model_env = stack_frames(config, vecnorm if (training and vecnorm is not None) else env)
    model = build_model(config, model_env, tensorboard_log=tensorboard_log, verbose=verbose, device=device)
    load_model_state(model, tensors, meta, str(folder))
    if manifest["num_timesteps"] != model.num_timesteps:
        raise CheckpointError(f"{folder}: {MANIFEST_FILE} says {manifest['num_timesteps']} steps, "
                              f"{MODEL_STATE_FILE} says {model.num_timesteps}")
    return model, vecnorm, config, manifest


def load_for_resume(folder: Path, config: RunConfig, run_dir: Path, verbose: int = 0, device: str = "cpu"):
    """``(model, vecnorm, restore_rng)`` of a training checkpoint: the env rebuilt and put back in its saved
    state, the model and VecNormalize filled in. ``restore_rng()`` sets the global RNGs (call it last)."""
    folder = Path(folder)
    manifest = read_manifest(folder)
    state = _json(folder, manifest, STATE_FILE)
    arrays = _npz(folder, manifest, STATE_ARRAYS_FILE)
    from .models import make_env

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
    if vecnorm is not None:
        try:
            returns = arrays["vecnormalize_returns"]
            if returns.shape != vecnorm.returns.shape:
                raise ValueError(f"vecnormalize_returns has shape {returns.shape}")
            vecnorm.returns = returns.astype(np.float64, copy=True)
            for attr in ("old_obs", "old_reward"):
                if f"vecnormalize_{attr}" in arrays:
                    setattr(vecnorm, attr, arrays[f"vecnormalize_{attr}"].copy())
        except (KeyError, ValueError) as exc:
            raise CheckpointError(f"{folder}: {STATE_ARRAYS_FILE}: {exc}") from None
    if getattr(model, "replay_buffer", None) is not None:
        if REPLAY_FILE not in manifest["files"]:
            raise CheckpointError(f"{folder}: an off-policy checkpoint without {REPLAY_FILE}")
        restore_replay_buffer(model.replay_buffer, _json(folder, manifest, "replay_buffer.json"),
                              _npz(folder, manifest, REPLAY_FILE), str(folder))
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
        stack.stacked_obs.stacked_obs = saved_stack.copy()
    restore = global_rng_state(state, arrays, str(folder))
    return model, vecnorm, restore


def legacy_files(folder: Path) -> list[str]:
    """Pickle-based files of earlier versions present in ``folder``."""
    return [n for n in LEGACY_FILES if (Path(folder) / n).is_file()]


def find_checkpoint(path: Path) -> Path:
    """The checkpoint folder that ``path`` names: a run directory (its final model, else its newest
    training checkpoint that verifies), a checkpoint folder, or a file inside one. CheckpointError, naming
    what was found, otherwise."""
    path = Path(path)
    if not path.exists():
        raise CheckpointError(f"checkpoint {path} does not exist (expected a run directory, a checkpoint directory "
                              f"or its {MODEL_FILE})")
    if path.is_file():
        if path.name in (MODEL_FILE, MANIFEST_FILE, MODEL_STATE_FILE):
            return path.parent
        if path.name in LEGACY_FILES or path.suffix in (".zip", ".pkl", ".pickle", ".pt", ".pth"):
            raise CheckpointError(f"{path} is a pickle-based file ({path.suffix}), which can run code when loaded; "
                                  f"this project loads checkpoints in its safe format only (docs/baselines.md, "
                                  f"'Loading checkpoints'). If you created it or trust its source, pass --trust-pickle "
                                  f"or convert it once with python baselines/export.py from-sb3 --trust-pickle")
        raise CheckpointError(f"{path} is not a checkpoint (a {path.stat().st_size}-byte file); expected a run "
                              f"directory, a checkpoint directory or its {MODEL_FILE}")
    if (path / MANIFEST_FILE).is_file():
        return path
    ck = latest_checkpoint(path)
    if ck is not None:
        return ck
    legacy = legacy_files(path)
    if legacy:
        raise CheckpointError(f"{path} holds only pickle-based files {legacy} (an earlier format, or SB3's), which "
                              f"can run code when loaded; pass --trust-pickle if you created them or trust their "
                              f"source, or convert them once with python baselines/export.py from-sb3 --trust-pickle "
                              f"{path}")
    if (path / MODEL_FILE).is_file():
        raise CheckpointError(f"{path} has {MODEL_FILE} but no {MANIFEST_FILE}: an interrupted save; resume the run "
                              f"to finish it")
    raise CheckpointError(f"{path} holds no checkpoint (no {MANIFEST_FILE}, no complete checkpoints/step_*)")


def warn(message: str) -> None:
    sys.stderr.write(f"warning: {message}\n")
