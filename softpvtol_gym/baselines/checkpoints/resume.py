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
from softpvtol_gym.baselines.training.stacking import frame_stack_wrapper
from softpvtol_gym.baselines.util.atomic import (
    atomic_write_bytes,
    atomic_write_text,
)
from softpvtol_gym.control import kernels as CK
from softpvtol_gym.envs.packed_state import ISTATE, STATE, S
from softpvtol_gym.envs.termination import REASONS
from softpvtol_gym.params import SoftPVTOLParams


def innermost(venv):
    """The SoftPVTOLSB3VecEnv below any SB3 VecEnv wrappers."""
    from softpvtol_gym.envs.sb3 import SoftPVTOLSB3VecEnv  # stable-baselines3: imported when a run is resumed

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
    if getattr(sim, "aids", None) is not None:  # the opt-in training aids' memory (error integrals, last action)
        parts.append(("aids", sim.aids))
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


# What a resume restores. Everything else a vector env holds (the constants C and codes K, max_steps, dt,
# the controller's settings and kernel constants, num_envs, ...) derives from the run's config: the env
# the resume builds from config.yaml has it already, and the checkpoint's copy is only compared with it
# (a difference is an error, never written: the compiled kernels index C, K and the state arrays by the
# layout's constants, so their memory safety does not rest on the checkpoint being honest).
_DYNAMIC = {
    "venv": ("_autoreset", "_fresh", "_over", "_warned", "_needs_reset", "_np_random_seed", "_rngs", "_np_random"),
    "sim": ("F", "I", "key", "obs", "_ctl_in", "_ctl", "_ctl_err", "start_error_scale"),
    "controller": ("_state", "_spare"),
    "aids": ("integrals", "prev_action", "has_prev", "terms", "gate", "_gated", "_new_gate", "_clipped"),
}
#: dynamic state that checkpoints saved before it existed lack: kept at the fresh env's value (the config's)
_ADDED_LATER = {("sim", "start_error_scale")}
_ENTRY_KEYS = {"arrays": list, "views": list, "numpy_scalars": list, "scalars": dict, "generators": dict}


class _Mismatch(ValueError):
    """A saved field that does not fit the env (the message names the field and what was expected)."""


def _describe(value) -> str:
    if isinstance(value, np.ndarray):
        return f"{value.dtype}{tuple(value.shape)}"
    return f"{value!r}"[:80]


def _differing(saved, fresh) -> str:
    """How a saved value differs from the freshly built one: ``X, this run's config gives Y``, with the first
    differing entry where both are arrays of one dtype and shape (their descriptions would read the same)."""
    if (isinstance(saved, np.ndarray) and isinstance(fresh, np.ndarray) and saved.dtype == fresh.dtype
            and saved.shape == fresh.shape):
        index = next((i for i in np.ndindex(saved.shape) if saved[i].tobytes() != fresh[i].tobytes()), ())
        return (f"{_describe(saved)} with {saved[index]!r} at {index}, this run's config gives {fresh[index]!r} "
                f"there")
    return f"{_describe(saved)}, this run's config gives {_describe(fresh)}"


def _same(saved, fresh) -> bool:
    """Exact equality (type, dtype, shape, bits) of a saved value and the freshly built one."""
    if isinstance(fresh, np.ndarray) or isinstance(saved, np.ndarray):
        return (isinstance(saved, np.ndarray) and isinstance(fresh, np.ndarray) and saved.dtype == fresh.dtype
                and saved.shape == fresh.shape and saved.tobytes() == fresh.tobytes())
    if isinstance(fresh, np.generic):
        fresh = fresh.item()
    if isinstance(saved, np.generic):
        saved = saved.item()
    return type(saved) is type(fresh) and saved == fresh


def _array(name: str, value, fresh: np.ndarray) -> np.ndarray:
    """``value`` if it is an array of ``fresh``'s dtype and shape (the layout of this run's env)."""
    if not isinstance(value, np.ndarray) or value.dtype != fresh.dtype or value.shape != fresh.shape:
        raise _Mismatch(f"{name} is {_describe(value)}, this run's env needs {fresh.dtype}{tuple(fresh.shape)}")
    return value


def _check_sim_state(sim, F: np.ndarray, I: np.ndarray, obs: np.ndarray) -> None:  # noqa: E741
    """Value checks of the simulator's saved state (shapes and dtypes are checked already)."""
    bad = ~np.isfinite(F)
    bad[:, STATE.at.applied:STATE.at.applied + STATE.widths["applied"]] = False  # NaN: no command applied yet
    if bad.any():
        row, col = np.argwhere(bad)[0]
        field = next(f for f, w in STATE.fields if getattr(STATE.at, f) <= col < getattr(STATE.at, f) + w)
        raise _Mismatch(f"sim.F holds a non-finite value (sub-env {row}, field {field}); the env's state is finite")
    if not np.isfinite(obs).all():
        raise _Mismatch("sim.obs holds non-finite values; the env's observations are finite")
    views, iviews = STATE.views(F), ISTATE.views(I)
    if np.abs(views["u"]).max(initial=0.0) > 1.0:
        raise _Mismatch("sim.F: the clipped action u lies outside [-1, 1]")
    if (views["t"] < 0).any():
        raise _Mismatch("sim.F: the episode time t is negative")
    for i, row in enumerate(views["P"]):
        try:
            SoftPVTOLParams.from_array(row)
        except ValueError as exc:
            raise _Mismatch(f"sim.F: the plant parameters P of sub-env {i} are invalid ({exc})") from None
    for field, lo, hi in (("counter", 0, None), ("steps", 0, None), ("reason", 0, len(REASONS) - 1),
                          ("lag_init", 0, 1), ("clipped", 0, 1)):
        v = iviews[field]
        if (v < lo).any() or (hi is not None and (v > hi).any()):
            raise _Mismatch(f"sim.I: {field} must be in [{lo}, {'inf' if hi is None else hi}], got "
                            f"{v.min()} .. {v.max()}")


def _check_controller_memory(ctrl, name: str, value) -> None:
    if name == "_state" and value is not None and not np.isin(value[:, CK.ST_FRESH], (0.0, 1.0)).all():
        raise _Mismatch("controller._state: the 'fresh' flags must be 0 or 1")


def _validated_part(part: str, obj, entry, arrays: dict, num_envs: int) -> dict:
    """{attribute: value} of the dynamic state of one part, every value checked; the config-derived
    attributes compared with the freshly built ones. Changes nothing."""
    if not isinstance(entry, dict):
        raise _Mismatch(f"{part} must be a mapping, got {_describe(entry)}")
    for key, kind in _ENTRY_KEYS.items():
        if not isinstance(entry.get(key), kind):
            raise _Mismatch(f"{part}.{key} must be a {kind.__name__}, got {_describe(entry.get(key))}")
    for key in ("arrays", "views", "numpy_scalars"):
        if not all(isinstance(n, str) for n in entry[key]):
            raise _Mismatch(f"{part}.{key} must list attribute names")
    saved_kind = {}
    for key in _ENTRY_KEYS:
        for n in entry[key]:
            if n in saved_kind:
                raise _Mismatch(f"{part}.{n} is listed twice")
            saved_kind[n] = key
    fresh = _state_attributes(obj)
    dynamic = _DYNAMIC[part]
    for n in saved_kind:
        if n not in fresh and n not in dynamic:
            raise _Mismatch(f"{part}.{n} is not state of this env (the checkpoint names an attribute it does not have)")
    # a None attribute may hold an array later (the controller's memory): compare what can be
    lost = sorted(n for n in fresh if n not in saved_kind and getattr(obj, n) is not None
                  and (part, n) not in _ADDED_LATER)
    if lost:
        raise _Mismatch(f"{part} has state {lost} that the checkpoint lacks")

    def saved_value(n):
        kind = saved_kind[n]
        if kind in ("arrays", "views", "numpy_scalars"):
            key = f"{part}.{n}"
            if key not in arrays:
                raise _Mismatch(f"{key} is listed but not in {STATE_ARRAYS_FILE}")
            return arrays[key][()] if kind == "numpy_scalars" else arrays[key]
        return entry[kind][n]

    out = {}
    for n, kind in saved_kind.items():
        value = saved_value(n)
        current = getattr(obj, n)
        if n not in dynamic:
            if part == "sim" and kind == "views":
                continue  # checked against the saved F and I below
            if not _same(value, current):
                raise _Mismatch(f"{part}.{n} is {_differing(value, current)} "
                                f"(derived from config.yaml, not restored: the checkpoint belongs to another "
                                f"configuration or was edited)")
            continue
        if n in ("_rngs", "_np_random"):
            if n == "_rngs":
                if not isinstance(value, list) or len(value) != num_envs:
                    raise _Mismatch(f"{part}._rngs must be {num_envs} generator states, got {_describe(value)}")
                out[n] = [generator_from_state(g, f"{part}._rngs[{i}]") for i, g in enumerate(value)]
            else:
                out[n] = None if value is None else generator_from_state(value, f"{part}._np_random")
        elif n == "_needs_reset":
            if not isinstance(value, bool):
                raise _Mismatch(f"{part}._needs_reset must be true or false, got {_describe(value)}")
            out[n] = value
        elif n == "_np_random_seed":
            if value is not None and (isinstance(value, bool) or not isinstance(value, int)):
                raise _Mismatch(f"{part}._np_random_seed must be an integer or null, got {_describe(value)}")
            out[n] = value
        elif part == "controller":
            if value is None and n == "_spare":
                out[n] = None
                continue
            ref = obj._state
            if ref is None:  # pragma: no cover (the env's BatchSim creates the memory)
                raise _Mismatch("controller has no memory to restore into")
            out[n] = _array(f"controller.{n}", value, ref).copy()
            _check_controller_memory(obj, n, out[n])
        else:  # the simulator's, the vector env's and the training aids' arrays: this env's layout
            out[n] = _array(f"{part}.{n}", value, current).copy()
            if part == "aids" and not np.isfinite(out[n]).all():
                raise _Mismatch(f"aids.{n} holds non-finite values; the training aids' memory is finite")
            if part == "sim" and n == "start_error_scale" and not 0.0 <= float(out[n]) <= 10.0:
                raise _Mismatch(f"sim.start_error_scale must be in [0, 10], got {float(out[n])!r}")
    if part == "sim":
        _check_sim_state(obj, out["F"], out["I"], out["obs"])
        views = {**STATE.views(out["F"]), **ISTATE.views(out["I"]), "u": out["F"][:, S.u:S.u + obj.action_dim]}
        for n, kind in saved_kind.items():
            if kind == "views":
                if n not in views:
                    raise _Mismatch(f"sim.{n} is not a field of this env's state layout")
                if not _same(saved_value(n), views[n]):
                    raise _Mismatch(f"sim.{n} is {_describe(saved_value(n))} and disagrees with the saved sim.F / "
                                    f"sim.I it is a view of")
    return out


def restore_env_state(vector_env, meta: dict, arrays: dict, source: str) -> None:
    """Write a saved :func:`env_state` into a freshly built vector env of the run's configuration.

    Only the dynamic state (:data:`_DYNAMIC`: the sub-envs' state arrays, the controller's memory, the
    generators, the autoreset flags) is restored, after every field has been checked (all of them before
    anything changes): its dtype and shape against this env's layout (rows = num_envs, columns = the
    layout's width), the state finite, the plant parameters valid, the integer counters non-negative, the
    termination reasons and flags within their codes, the generator states valid, the views equal to the
    arrays they view. The config-derived attributes are rebuilt from the config (the fresh env has them)
    and must equal the checkpoint's copies. CheckpointError (one line, naming the field) otherwise."""
    try:
        parts = dict(_env_parts(vector_env))
        if not isinstance(meta, dict) or set(parts) != set(meta):
            raise _Mismatch(f"saved parts {sorted(meta) if isinstance(meta, dict) else _describe(meta)}, the env "
                            f"has {sorted(parts)}")
        n = vector_env.num_envs
        restored = {part: _validated_part(part, obj, meta[part], arrays, n) for part, obj in parts.items()}
    except (_Mismatch, CheckpointError) as exc:
        raise CheckpointError(f"{source}: the saved env state does not fit this run's env: {exc}") from None
    for part, obj in parts.items():  # everything checked: write
        for name, value in restored[part].items():
            cur = getattr(obj, name)
            if isinstance(value, np.ndarray) and isinstance(cur, np.ndarray) and part == "sim":
                np.copyto(cur, value)  # in place: the views into F and I stay views
            else:
                setattr(obj, name, value)


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
    except (KeyError, TypeError, ValueError, IndexError, RuntimeError, OverflowError) as exc:  # Overflow: pos=2**70
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
    """Fill the run's replay buffer from a checkpoint, every field checked first (sizes, position, dtypes,
    shapes (filled, n_envs, ...) of the run's buffer, finite values)."""
    try:
        if not isinstance(info, dict):
            raise ValueError(f"replay_buffer.json must be a mapping, got {type(info).__name__}")
        for key in ("buffer_size", "n_envs", "filled", "pos"):
            if isinstance(info.get(key), bool) or not isinstance(info.get(key), int):
                raise ValueError(f"{key} must be an integer, got {str(info.get(key))[:40]!r}")
        if not isinstance(info.get("full"), bool):
            raise ValueError(f"full must be true or false, got {str(info.get('full'))[:40]!r}")
        if info["buffer_size"] != buffer.buffer_size or info["n_envs"] != buffer.n_envs:
            raise ValueError(f"saved buffer of {info['buffer_size']} x {info['n_envs']}, the run's is "
                             f"{buffer.buffer_size} x {buffer.n_envs}")
        n, pos, full = info["filled"], info["pos"], info["full"]
        if not (0 <= pos < buffer.buffer_size and n == (buffer.buffer_size if full else pos)):
            raise ValueError(f"position {pos}, {n} filled, full={full} are inconsistent for a buffer of "
                             f"{buffer.buffer_size}")
        checked = {}
        for k in _REPLAY_ARRAYS:
            target = getattr(buffer, k, None)
            if target is None:
                continue
            if k not in arrays:
                raise ValueError(f"{k} is missing")
            saved = arrays[k]
            if saved.shape != (n, *target.shape[1:]) or saved.dtype != target.dtype:
                raise ValueError(f"{k} is {saved.dtype}{saved.shape}, the run's buffer needs "
                                 f"{target.dtype}{(n, *target.shape[1:])}")
            if saved.dtype.kind == "f" and not np.isfinite(saved).all():
                raise ValueError(f"{k} holds non-finite values")
            checked[k] = saved
    except (KeyError, TypeError, ValueError) as exc:
        raise CheckpointError(f"{source}: {REPLAY_FILE} does not fit the run's replay buffer ({exc})") from None
    for k, saved in checked.items():
        getattr(buffer, k)[:n] = saved
    buffer.pos, buffer.full = pos, full
