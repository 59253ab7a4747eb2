"""The SB3 model's tensors and training state (safetensors + JSON), and VecNormalize's statistics, without pickle."""

from __future__ import annotations

import json
import math
from collections import deque
from pathlib import Path

import numpy as np

from softpvtol_gym.baselines.checkpoints.manifest import (
    ARRAY_ATTRIBUTES,
    COUNTERS,
    FORMAT,
    FORMAT_VERSION,
    MODEL_FILE,
    MODEL_STATE_FILE,
    VECNORM_FILE,
    from_json,
    generator_from_state,
    generator_state,
    read_verified,
    to_json,
)
from softpvtol_gym.baselines.errors import CheckpointError
from softpvtol_gym.baselines.util.atomic import (
    atomic_write_bytes,
    atomic_write_text,
)

#: model.json's list of the policy tensors a compacted checkpoint does not keep (a finished PPO run's value
#: function): loading leaves them as the freshly built model initialises them (seeded with the run's seed)
DROPPED_KEY = "tensors_dropped"


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
                        scalars.setdefault(str(pid), {})[k] = to_json(v)
            optimizers[name] = {"param_groups": to_json(sd["param_groups"]), "scalar_state": scalars,
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
        "ep_info_buffer": to_json(list(model.ep_info_buffer or [])),
        "ep_success_buffer": to_json(list(model.ep_success_buffer or [])),
        "action_space_rng": generator_state(getattr(model.action_space, "_np_random", None)),
        "observation_space_rng": generator_state(getattr(model.observation_space, "_np_random", None)),
    }
    return tensors, meta


def sorted_metadata(data: bytes) -> bytes:
    """``data`` (a safetensors file) with the header's ``__metadata__`` keys in sorted order: safetensors writes
    them in the order of a Rust hash map, which varies from process to process, so that two saves of the same
    model would differ. The header keeps its length (the same keys and values) and the tensors their bytes."""
    n = int.from_bytes(data[:8], "little")
    header = json.loads(data[8:8 + n])
    metadata = header.pop("__metadata__", None)
    if metadata is not None:
        header = {"__metadata__": dict(sorted(metadata.items())), **header}
    text = json.dumps(header, separators=(",", ":"), ensure_ascii=False).encode("utf-8")
    if len(text) > n:  # pragma: no cover (a reordering cannot make the header longer)
        raise AssertionError(f"safetensors header grew from {n} to {len(text)} bytes")
    return data[:8] + text + b" " * (n - len(text)) + data[8 + n:]


def save_model(model, folder: Path) -> list[str]:
    """Write ``model.safetensors`` and ``model.json`` of ``model`` into ``folder``; returns their names."""
    from safetensors.torch import save as st_save

    tensors, meta = model_payload(model)
    data = st_save(tensors, metadata={"format": FORMAT, "version": str(FORMAT_VERSION)})
    atomic_write_bytes(Path(folder) / MODEL_FILE, sorted_metadata(data))
    atomic_write_text(Path(folder) / MODEL_STATE_FILE, json.dumps(meta, indent=1))
    return [MODEL_FILE, MODEL_STATE_FILE]


def load_tensors(folder: Path, manifest: dict) -> dict:
    from safetensors import SafetensorError
    from safetensors.torch import load as st_load

    data = read_verified(folder, manifest, MODEL_FILE)
    try:
        return st_load(data)
    except (SafetensorError, ValueError, RuntimeError) as exc:
        raise CheckpointError(f"{Path(folder) / MODEL_FILE} is not a readable safetensors file ({exc})") from None


#: the largest magnitude a network weight (``policy/...`` tensor) may have: trained weights are of order 1; a
#: weight of 1e30 (finite in float32) overflows the first layer's activations to inf
MAX_WEIGHT = 1e6
#: counters of model.json that are step / update / episode counts
_COUNT_COUNTERS = tuple(c for c in COUNTERS if c != "_current_progress_remaining")


def check_tensors(tensors: dict, source: str) -> None:
    """CheckpointError naming the first tensor that holds a non-finite value, or a network weight larger in
    magnitude than :data:`MAX_WEIGHT` (they would load, then make every action NaN inside torch)."""
    import torch

    for name, t in tensors.items():
        if not (t.is_floating_point() or t.is_complex()):
            continue
        if not bool(torch.isfinite(t).all()):
            raise CheckpointError(f"{source}: tensor {name} of {MODEL_FILE} holds non-finite values (NaN or inf)")
        if name.startswith("policy/") and t.numel() and float(t.abs().max()) > MAX_WEIGHT:
            raise CheckpointError(f"{source}: tensor {name} of {MODEL_FILE} holds a weight of magnitude "
                                  f"{float(t.abs().max()):.3g} > {MAX_WEIGHT:g} (a trained network's weights are of "
                                  f"order 1; this one would overflow)")


def check_model_meta(meta, source: str) -> None:
    """The schema of model.json: CheckpointError (one line, naming the field) for a wrong type or value."""
    where = f"{source}: {MODEL_STATE_FILE}"
    if not isinstance(meta, dict) or meta.get("format") != FORMAT or meta.get("version") != FORMAT_VERSION:
        raise CheckpointError(f"{where} is not a version-{FORMAT_VERSION} model description")
    counters = meta.get("counters", {})
    if not isinstance(counters, dict):
        raise CheckpointError(f"{where}: counters must be a mapping of {list(COUNTERS)}, got {str(counters)[:60]!r}")
    for c in _COUNT_COUNTERS:
        v = counters.get(c, 0)
        if isinstance(v, bool) or not isinstance(v, int) or v < 0:
            raise CheckpointError(f"{where}: counters.{c} must be an integer >= 0, got {str(v)[:60]!r}")
    p = counters.get("_current_progress_remaining", 1.0)
    # 1 - num_timesteps / total: below 0 when the last rollout overshoots the total
    if isinstance(p, bool) or not isinstance(p, (int, float)) or not (math.isfinite(p) and p <= 1.0):
        raise CheckpointError(f"{where}: counters._current_progress_remaining must be a finite number <= 1, got "
                              f"{str(p)[:60]!r}")
    optimizers = meta.get("optimizers", {})
    if not isinstance(optimizers, dict) or not all(
            isinstance(o, dict) and isinstance(o.get("param_groups"), list) and isinstance(o.get("scalar_state"), dict)
            and isinstance(o.get("params_with_state"), list)
            and all(isinstance(i, int) and not isinstance(i, bool) for i in o["params_with_state"])
            for o in optimizers.values()):
        raise CheckpointError(f"{where}: optimizers must map each optimizer to param_groups (a list), scalar_state "
                              f"(a mapping) and params_with_state (a list of integers)")
    dropped = meta.get(DROPPED_KEY, [])
    if not isinstance(dropped, list) or not all(isinstance(n, str) for n in dropped):
        raise CheckpointError(f"{where}: {DROPPED_KEY} must be a list of tensor names, got {str(dropped)[:60]!r}")
    for key in ("ep_info_buffer", "ep_success_buffer"):
        buf = meta.get(key, [])
        if not isinstance(buf, list) or (key == "ep_info_buffer" and not all(isinstance(e, dict) for e in buf)):
            raise CheckpointError(f"{where}: {key} must be a list{' of mappings' if key == 'ep_info_buffer' else ''}, "
                                  f"got {str(buf)[:60]!r}")


def load_model_state(model, tensors: dict, meta: dict, source: str) -> None:
    """Fill a freshly built SB3 ``model`` with saved tensors and metadata (strict: every tensor must fit,
    every value finite, model.json of the right schema)."""
    import torch

    check_model_meta(meta, source)
    check_tensors(tensors, source)
    algo = type(model).__name__.lower()
    if meta.get("algo") != algo:
        raise CheckpointError(f"{source}: the weights are of a {str(meta.get('algo')).upper()} model, config.yaml "
                              f"says {algo.upper()}")
    used, dropped = set(), set(meta.get(DROPPED_KEY, []))
    state_dicts, variables = _torch_objects(model)
    modules = [f"{name}/{k}" for name, obj in state_dicts if isinstance(obj, torch.nn.Module) for k in obj.state_dict()]
    unknown = sorted(dropped.difference(modules).union(dropped.intersection(tensors)))
    if unknown:
        raise CheckpointError(f"{source}: {MODEL_STATE_FILE}'s {DROPPED_KEY} names tensors the model does not have "
                              f"or the checkpoint keeps: {unknown[:5]}")
    try:
        for name, obj in state_dicts:
            prefix = f"{name}/"
            if isinstance(obj, torch.nn.Module):
                sd = {k[len(prefix):]: v for k, v in tensors.items() if k.startswith(prefix)}
                used.update(prefix + k for k in sd)
                fresh = obj.state_dict()  # a dropped tensor keeps the freshly built model's value
                sd.update({k: fresh[k] for k in fresh if prefix + k in dropped})
                obj.load_state_dict(sd, strict=True)
            else:
                info = meta["optimizers"][name]
                state: dict[int, dict] = {}
                for pid in info["params_with_state"]:
                    entry = dict(from_json(info["scalar_state"].get(str(pid), {})))
                    p = f"{prefix}state/{pid}/"
                    for k, v in tensors.items():
                        if k.startswith(p):
                            entry[k[len(p):]] = v
                            used.add(k)
                    state[int(pid)] = entry
                obj.load_state_dict({"state": state, "param_groups": from_json(info["param_groups"])})
        for name, var in variables:
            key = f"variables/{name}"
            if key not in tensors:
                raise KeyError(key)
            with torch.no_grad():
                var.copy_(tensors[key])
            used.add(key)
    except (KeyError, RuntimeError, ValueError, TypeError, IndexError, AttributeError) as exc:
        raise CheckpointError(f"{source}: the saved weights do not fit the network that config.yaml describes "
                              f"({type(exc).__name__}: {str(exc)[:300]})") from None
    for attr in ARRAY_ATTRIBUTES:
        key = f"attributes/{attr}"
        if key in tensors:
            setattr(model, attr, _training_attribute(model, attr, tensors[key].numpy().copy(), source))
            used.add(key)
    extra = sorted(set(tensors) - used)
    if extra:
        raise CheckpointError(f"{source}: {MODEL_FILE} holds tensors the model does not have: {extra[:5]}")
    counters = meta.get("counters", {})
    for c in COUNTERS:
        if c in counters:
            setattr(model, c, counters[c])
    model.ep_info_buffer = deque(from_json(meta.get("ep_info_buffer", [])), maxlen=model._stats_window_size)
    model.ep_success_buffer = deque(from_json(meta.get("ep_success_buffer", [])), maxlen=model._stats_window_size)
    for space, key in ((model.action_space, "action_space_rng"), (model.observation_space, "observation_space_rng")):
        if meta.get(key) is not None:
            space._np_random = generator_from_state(meta[key], f"{source}: {key}")


def _training_attribute(model, attr: str, value: np.ndarray, source: str) -> np.ndarray:
    """A saved rollout attribute (:data:`ARRAY_ATTRIBUTES`) checked against the model's env: the last
    observations (n_envs, *observation shape) of floats (the original ones, under a frame stack of K, one frame:
    (n_envs, width / K)), the episode starts (n_envs,) of bools; a CheckpointError
    naming the attribute, what it holds and what the run needs otherwise (it would fail inside SB3 later)."""
    starts = attr == "_last_episode_starts"
    want = (model.n_envs,) if starts else (model.n_envs, *model.observation_space.shape)
    kind_ok = value.dtype == np.bool_ if starts else value.dtype.kind == "f"
    if attr == "_last_original_obs" and value.ndim == 2 and value.shape[0] == model.n_envs and value.shape[1] \
            and want[1] % value.shape[1] == 0:
        want = value.shape  # under a frame stack: one frame (the model sees K of them)
    if value.shape != want or not kind_ok:
        raise CheckpointError(f"{source}: {MODEL_FILE}'s attributes/{attr} is {value.dtype}{value.shape}, this run "
                              f"needs {'bool' if starts else 'float'}{want} ({model.n_envs} envs); the checkpoint "
                              f"belongs to another run or was edited")
    return value


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
        if not isinstance(data, dict) or data.get("format") != FORMAT or data.get("version") != FORMAT_VERSION:
            raise ValueError("not a version-1 VecNormalize description")
        for key in ("norm_obs", "norm_reward"):
            if not isinstance(data[key], bool):
                raise ValueError(f"{key} must be true or false, got {str(data[key])[:40]!r}")
        for key, hi in (("clip_obs", None), ("clip_reward", None), ("gamma", 1.0), ("epsilon", None)):
            v = data[key]
            if (isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v <= 0
                    or (hi is not None and v > hi)):
                raise ValueError(f"{key} must be a finite number > 0{f' and <= {hi:g}' if hi else ''}, got "
                                 f"{str(v)[:40]!r}")
        vn = VecNormalize(venv, training=training, norm_obs=bool(data["norm_obs"]),
                          norm_reward=bool(data["norm_reward"]), clip_obs=float(data["clip_obs"]),
                          clip_reward=float(data["clip_reward"]), gamma=float(data["gamma"]),
                          epsilon=float(data["epsilon"]))
        for name in ("obs_rms", "ret_rms"):
            r, saved = getattr(vn, name), data[name]
            mean = np.asarray(saved["mean"], dtype=np.float64)
            var = np.asarray(saved["var"], dtype=np.float64)
            if mean.shape != np.shape(r.mean) or var.shape != np.shape(r.var):
                raise ValueError(f"{name} has shape {mean.shape} (var {var.shape}), the env needs {np.shape(r.mean)}")
            if not (np.isfinite(mean).all() and np.isfinite(var).all()):
                raise ValueError(f"{name} holds non-finite values (mean or var)")
            if not (var >= 0).all():
                raise ValueError(f"{name}.var holds negative values")
            count = saved["count"]
            if isinstance(count, bool) or not isinstance(count, (int, float)):
                raise ValueError(f"{name}.count must be a number, got {str(count)[:40]!r}")
            count = float(count)
            if not (np.isfinite(count) and count > 0):
                raise ValueError(f"{name}.count must be > 0, got {count}")
            r.mean, r.var, r.count = (mean if mean.ndim else float(mean)), (var if var.ndim else float(var)), count
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise CheckpointError(f"{source}: {VECNORM_FILE} is invalid ({type(exc).__name__}: {exc})") from None
    return vn
