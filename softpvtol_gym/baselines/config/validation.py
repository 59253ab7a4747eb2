"""Validation of hyperparameters against the algorithm's constructor and stable-baselines3's constraints."""

from __future__ import annotations

import inspect
import math
from typing import Any

from softpvtol_gym.baselines.config.hyperparams import (
    ALGOS,
    MAX_BUFFER_SIZE,
    MAX_FRAME_STACK,
    MAX_N_ENVS,
    MAX_ROLLOUT,
    MAX_TIMESTEPS,
    NON_ALGO_KEYS,
    RESERVED_ALGO_ARGS,
    VECNORM_KEYS,
    linear_schedule_start,
    parse_dict_call,
)
from softpvtol_gym.baselines.errors import ConfigError


# ------------------------------------------------------------------------------- validation
def is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _int(lo=None, hi=None):
    def check(v):
        if not is_int(v) or (lo is not None and v < lo) or (hi is not None and v > hi):
            bounds = " and ".join(b for b in ((f">= {lo:,}" if lo is not None else ""),
                                              (f"<= {hi:,}" if hi is not None else "")) if b)
            return f"an integer {bounds}".rstrip()
    return check


def _num(lo=None, hi=None, lo_open=False, hi_open=False):
    def check(v):
        ok = _is_num(v)
        if ok and lo is not None:
            ok = v > lo if lo_open else v >= lo
        if ok and hi is not None:
            ok = v < hi if hi_open else v <= hi
        if not ok:
            parts = []
            if lo is not None:
                parts.append(f"{'>' if lo_open else '>='} {lo:g}")
            if hi is not None:
                parts.append(f"{'<' if hi_open else '<='} {hi:g}")
            return "a finite number" + (" " + " and ".join(parts) if parts else "")
    return check


def _optional(check):
    def wrapped(v):
        if v is None:
            return None
        msg = check(v)
        return None if msg is None else f"null or {msg}"
    return wrapped


def _bool(v):
    if not isinstance(v, bool):
        return "true or false"


def _none(v):
    if v not in (None, {}):
        return "null (classes and objects cannot be given in a config)"


def _number_or_linear_schedule(v):
    if linear_schedule_start(v) is None and (not _is_num(v) or v <= 0):
        return "a finite number > 0 or a linear schedule 'lin_<initial value > 0>'"


#: the largest network train.py builds: layers of at most MAX_LAYER_UNITS units, at most MAX_LAYERS of them (the
#: project's networks have 2 layers of 64 - 256 units; a size like 4,000,000,000 cannot be allocated, 0 or a
#: negative size is no layer)
MAX_LAYER_UNITS = 4096
MAX_LAYERS = 8
_NET_ARCH_KEYS = ("pi", "vf", "qf")


def _layer_sizes(v) -> bool:
    return (isinstance(v, list) and len(v) <= MAX_LAYERS
            and all(is_int(u) and 1 <= u <= MAX_LAYER_UNITS for u in v))


def _net_arch(v):
    if _layer_sizes(v):
        return None
    if isinstance(v, dict) and v and set(v) <= set(_NET_ARCH_KEYS) and all(_layer_sizes(x) for x in v.values()):
        return None
    return (f"a list of at most {MAX_LAYERS} layer sizes, each an integer in [1, {MAX_LAYER_UNITS}] (units per "
            f"hidden layer), or dict(pi=[...], vf=[...]) / dict(pi=[...], qf=[...]) of such lists")


def _policy_kwargs(v):
    if isinstance(v, str):
        try:
            v = parse_dict_call(v)
        except ConfigError as exc:
            return f"a dict(...) expression ({exc})"
    if not isinstance(v, dict):
        return "a dict or a 'dict(...)' string"
    if "net_arch" in v:
        msg = _net_arch(v["net_arch"])
        if msg is not None:
            return f"a dict whose net_arch is {msg}"
    if "log_std_init" in v and not _is_num(v["log_std_init"]):
        return f"a dict whose log_std_init is a finite number, got {v['log_std_init']!r}"


def _sac_ent_coef(v):
    if isinstance(v, str):
        if v == "auto":
            return None
        if v.startswith("auto_"):
            try:
                x = float(v[5:])
            except ValueError:
                x = float("nan")
            if math.isfinite(x) and x > 0:
                return None
        return "'auto', 'auto_<initial value > 0>' or a number > 0"
    if not _is_num(v) or v <= 0:
        return "'auto', 'auto_<initial value > 0>' or a number > 0"


def _sac_target_entropy(v):
    if v != "auto" and not _is_num(v):
        return "'auto' or a finite number"


def _train_freq(v):
    if is_int(v) and v >= 1:
        return None
    if (isinstance(v, (list, tuple)) and len(v) == 2 and is_int(v[0]) and v[0] >= 1
            and v[1] in ("step", "episode")):
        return None
    return "an integer >= 1 or [n >= 1, 'step' | 'episode']"


def _gradient_steps(v):
    if not is_int(v) or (v < 1 and v != -1):
        return "an integer >= 1, or -1 (as many as env steps)"


#: the policy classes a run's ``policy`` hyperparameter names (the zero-at-zero residual: PPO only)
POLICY_CLASSES = ("MlpPolicy", "ZeroAtZeroPolicy")


def _policy(v):
    if v not in POLICY_CLASSES:
        return ("'MlpPolicy' (the observation is a flat vector) or 'ZeroAtZeroPolicy' (PPO: an action exactly 0 at "
                "zero tracking error)")


def _normalize(v):
    if v is None or isinstance(v, bool):
        return None
    what = f"true, false, or a mapping (or 'dict(...)' string) of VecNormalize arguments {list(VECNORM_KEYS)}"
    if isinstance(v, str):
        try:
            v = parse_dict_call(v, "normalize")
        except ConfigError as exc:
            return f"{what} ({exc})"
    if not isinstance(v, dict):
        return what
    unknown = sorted(set(v) - set(VECNORM_KEYS))
    if unknown:
        return f"{what} (unknown: {unknown})"
    for key, check in (("norm_obs", _bool), ("norm_reward", _bool), ("clip_obs", _num(0, lo_open=True)),
                       ("clip_reward", _num(0, lo_open=True)), ("gamma", _num(0, 1, lo_open=True)),
                       ("epsilon", _num(0, lo_open=True))):
        if key in v and check(v[key]) is not None:
            return f"a mapping whose {key} is {check(v[key])} (got {v[key]!r})"


_COMMON_RULES = {
    "policy": _policy,
    "n_envs": _int(1, MAX_N_ENVS),
    "n_timesteps": _int(1, MAX_TIMESTEPS),
    "normalize": _normalize,
    "frame_stack": _int(1, MAX_FRAME_STACK),
    "learning_rate": _number_or_linear_schedule,
    "gamma": _num(0, 1, lo_open=True),
    "use_sde": _bool,
    "sde_sample_freq": _int(-1),
    "stats_window_size": _int(1),
    "policy_kwargs": _policy_kwargs,
}
_RULES = {
    "ppo": {
        "n_steps": _int(1),
        "batch_size": _int(2),        # SB3: "batch_size must be greater than 1"
        "n_epochs": _int(1),
        "gae_lambda": _num(0, 1),
        "clip_range": _number_or_linear_schedule,
        "clip_range_vf": _optional(_num(0, lo_open=True)),
        "normalize_advantage": _bool,
        "ent_coef": _num(0),
        "vf_coef": _num(0),
        "max_grad_norm": _num(0, lo_open=True),
        "target_kl": _optional(_num(0, lo_open=True)),
        "rollout_buffer_class": _none,
        "rollout_buffer_kwargs": _none,
    },
    "sac": {
        "buffer_size": _int(1, MAX_BUFFER_SIZE),
        "learning_starts": _int(0),
        "batch_size": _int(1),
        "tau": _num(0, 1, lo_open=True),
        "train_freq": _train_freq,
        "gradient_steps": _gradient_steps,
        "action_noise": _none,
        "replay_buffer_class": _none,
        "replay_buffer_kwargs": _none,
        "optimize_memory_usage": _bool,
        "n_steps": _int(1),
        "ent_coef": _sac_ent_coef,
        "target_update_interval": _int(1),
        "target_entropy": _sac_target_entropy,
        "use_sde_at_warmup": _bool,
    },
}


def valid_hyperparameter_keys(algo: str) -> list[str]:
    """Every key a hyperparameter entry of ``algo`` may have: :data:`NON_ALGO_KEYS` and the keyword
    arguments of the SB3 algorithm's constructor (minus those a run sets itself)."""
    return sorted({*NON_ALGO_KEYS, *_COMMON_RULES, *_RULES[algo]} - set(RESERVED_ALGO_ARGS) | {"policy"})


def validate_hyperparams(algo: str, hp: Any, n_envs: int | None = None) -> None:
    """ConfigError for the first hyperparameter that stable-baselines3 would reject (or that the run would
    get wrong): unknown keys, wrong types, out-of-range or non-finite values, ``algo``-specific limits."""
    if algo not in ALGOS:
        raise ConfigError(f"algo must be one of {list(ALGOS)}, got {algo!r}")
    if not isinstance(hp, dict):
        raise ConfigError(f"hyperparameters must be a mapping, got {hp!r}")
    rules = {**_COMMON_RULES, **_RULES[algo]}
    for key in hp:
        if not isinstance(key, str) or key not in rules:
            raise ConfigError(f"unknown hyperparameter {key!r} for {algo.upper()}; valid ones are "
                              f"{valid_hyperparameter_keys(algo)}")
    for key, value in hp.items():
        msg = rules[key](value)
        if msg is not None:
            raise ConfigError(f"hyperparameter {key} must be {msg}, got {value!r}")
    norm = hp.get("normalize")
    if norm not in (None, False, True) and "gamma" in hp:
        norm_gamma = (parse_dict_call(norm, "normalize") if isinstance(norm, str) else norm).get("gamma", hp["gamma"])
        if norm_gamma != hp["gamma"]:
            raise ConfigError(f"normalize's gamma ({norm_gamma!r}) differs from the entry's gamma ({hp['gamma']!r}); "
                              f"VecNormalize uses the entry's gamma (as rl-baselines3-zoo does): leave it out")
    if algo == "ppo":
        envs = n_envs if n_envs is not None else hp.get("n_envs", 16)
        steps = hp.get("n_steps", 2048)
        if steps * envs < 2:
            raise ConfigError(f"n_steps * n_envs must be > 1 for PPO (its advantage normalisation), got "
                              f"{steps} * {envs}")
        if steps * envs > MAX_ROLLOUT:
            raise ConfigError(f"n_steps * n_envs must be <= {MAX_ROLLOUT:,} (the rollout buffer is allocated up "
                              f"front), got {steps} * {envs} = {steps * envs:,}")


def _check_sb3_signature(algo: str) -> None:
    """The validation table covers the constructor of the installed SB3 (a test checks this)."""

    from stable_baselines3 import PPO, SAC

    cls = {"ppo": PPO, "sac": SAC}[algo]
    params = set(inspect.signature(cls.__init__).parameters) - set(RESERVED_ALGO_ARGS)
    table = (set(_COMMON_RULES) | set(_RULES[algo])) - set(NON_ALGO_KEYS)
    if params != table:
        raise AssertionError(f"{algo}: SB3 arguments {sorted(params - table)} are not validated; "
                             f"{sorted(table - params)} are not SB3 arguments")
