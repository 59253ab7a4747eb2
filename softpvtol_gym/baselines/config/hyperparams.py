"""Run configuration: hyperparameters from YAML per env id (one per action mode), CLI overrides, validation,
saving.

``softpvtol_gym/baselines/data/hyperparams/<algo>.yml`` holds one entry per env id, in rl-baselines3-zoo's
format (the same file works with ``python -m rl_zoo3.train --conf-file``): the action modes are the ids
``SoftPVTOLResidual-v0``, ``SoftPVTOLVirtual-v0`` and ``SoftPVTOLActuators-v0`` (``SoftPVTOL-v0``, whose
default action mode is ``actuators``, is an alias of the last). :func:`load_hyperparams` reads the entry,
:func:`apply_overrides` applies ``key=value`` strings from the command line (values parsed as YAML),
:func:`validate_hyperparams` checks every key against the algorithm's constructor and stable-baselines3's
constraints (before anything is written), and :class:`RunConfig` is what a run saves next to its checkpoints
(``config.yaml``), so that a run can be resumed, evaluated or audited later.
"""

from __future__ import annotations

import ast
import math
from pathlib import Path
from typing import Any

from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.util.paths import data_file
from softpvtol_gym.baselines.util.safe_load import MAX_DEPTH, loads_yaml, nesting_depth
from softpvtol_gym.envs.actions import ACTION_MODES
from softpvtol_gym.envs.registration import MODE_ENV_IDS

CONFIG_FILE_NAME = "config.yaml"
#: the residual base loop of runs saved before RunConfig had ``controller_loop`` (the env's default then)
LEGACY_CONTROLLER_LOOP = "exact"
#: the hyperparameter YAML files shipped with the package (one per algorithm; ``--hyperparams`` passes another folder)
HYPERPARAMS_DIR = data_file("hyperparams")
ALGOS = ("ppo", "sac")
#: keys of a hyperparameter entry that are not keyword arguments of the SB3 algorithm
NON_ALGO_KEYS = ("policy", "n_envs", "n_timesteps", "normalize", "frame_stack")
#: the most observations ``frame_stack`` may stack (a bound on the policy's input, 64 floats per observation)
MAX_FRAME_STACK = 64
#: env arguments a run may set besides mode, task, tier and base loop (RunConfig.env_options, train.py --env):
#: the residual mode's residual scale, the space the residual acts in, what it is added to and its gate, and the
#: error-integral observation (softpvtol_gym EnvConfig fields). They define the policy's interface, so the run's
#: training and evaluation envs both get them
ENV_OPTION_KEYS = ("residual_scale", "residual_space", "residual_base", "residual_gate", "observe_error_integral",
                   "error_integral_limit", "error_integral_error_limit")
#: the env options that shape the residual action (residual mode only); the others apply in every mode
RESIDUAL_ONLY_ENV_OPTIONS = ("residual_scale", "residual_space", "residual_base", "residual_gate")
#: env arguments of the run's training env only (RunConfig.train_env_options, train.py --train-env): the
#: training aids (extra reward terms, wider starts) that change what the agent is trained on but
#: not its interface; evaluations (periodic, leaderboard) use the task's own reward and starts
TRAINING_ENV_OPTION_KEYS = ("precision_reward_weight", "precision_reward_scale", "action_rate_penalty",
                            "start_error_scale", "start_distribution")
#: the env options a run saved before RunConfig had ``env_options`` trained with (none: the env's defaults)
LEGACY_ENV_OPTIONS: dict = {}
#: constructor arguments of the SB3 algorithms that a run sets itself (not hyperparameters)
RESERVED_ALGO_ARGS = ("self", "policy", "env", "seed", "device", "verbose", "tensorboard_log", "_init_setup_model")
#: training seeds are below this (evaluation seeds start at 1,000,000: the two sets never overlap)
TRAIN_SEED_LIMIT = 500_000
MAX_N_ENVS = 1024
#: at most this many evaluation episodes per call (they run as one vector env, in memory together)
MAX_EPISODES = 10_000
MAX_TIMESTEPS = 10**10
MAX_ROLLOUT = 2**24          # PPO: n_steps * n_envs (the rollout buffer is allocated up front)
MAX_BUFFER_SIZE = 10**7      # SAC: the replay buffer is allocated up front
VECNORM_KEYS = ("norm_obs", "norm_reward", "clip_obs", "clip_reward", "gamma", "epsilon")
#: the longest value of a --hp / --env-option override or a policy_kwargs / normalize "dict(...)" string
MAX_VALUE_CHARS = 10_000


#: the largest YAML file read (a run config, hyperparameters, recipes, a search space, a leaderboard spec): the
#: project's are kilobytes; a bigger one is a mistake or a crafted file, refused before it is parsed
MAX_YAML_BYTES = 2**20


def read_yaml(path: Path, what: str) -> Any:
    """``yaml.safe_load`` of a file of at most :data:`MAX_YAML_BYTES`, with every failure a ConfigError naming the
    file and the problem."""

    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"{what} {path} is a directory; expected a YAML file")
    try:
        size = path.stat().st_size
        if size > MAX_YAML_BYTES:
            raise ConfigError(f"{what} {path} is {size:,} bytes, more than the {MAX_YAML_BYTES:,} a YAML file may "
                              f"have")
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"no {what} at {path}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read {what} {path}: {exc}") from None
    # bounded: size, nesting, node count with aliases expanded (util.safe_load)
    return loads_yaml(text, f"{what} {path}", error=ConfigError, max_bytes=MAX_YAML_BYTES)


def hyperparams_key(action_mode: str) -> str:
    """The env id whose entry of a hyperparameter file holds ``action_mode``'s hyperparameters."""
    if action_mode not in ACTION_MODES:
        raise ConfigError(f"action mode must be one of {list(ACTION_MODES)}, got {action_mode!r}")
    return MODE_ENV_IDS[action_mode]


def load_hyperparams(algo: str, action_mode: str, directory: Path | None = None) -> dict:
    """The entry :func:`hyperparams_key` ``(action_mode)`` of ``<directory>/<algo>.yml`` (a copy)."""
    if algo not in ALGOS:
        raise ConfigError(f"algo must be one of {list(ALGOS)}, got {algo!r}")
    key = hyperparams_key(action_mode)
    path = (HYPERPARAMS_DIR if directory is None else Path(directory)) / f"{algo}.yml"
    table = read_yaml(path, "hyperparameter file") or {}
    if not isinstance(table, dict):
        raise ConfigError(f"hyperparameter file {path} must map env ids to entries, got a {type(table).__name__}")
    if key not in table:
        raise ConfigError(f"{path} has no entry {key!r} (the {action_mode} mode); entries: {sorted(map(str, table))}")
    if not isinstance(table[key], dict):
        raise ConfigError(f"entry {key!r} of {path} must be a mapping, got {table[key]!r}")
    return dict(table[key])


def apply_overrides(hyperparams: dict, overrides: list[str]) -> dict:
    """``["n_epochs=5", "learning_rate=1e-4"]`` applied to a copy of ``hyperparams`` (values as YAML)."""
    out = dict(hyperparams)
    for item in overrides:
        if "=" not in item:
            raise ConfigError(f"a hyperparameter override must look like key=value, got {item!r}")
        key, raw = item.split("=", 1)
        key = key.strip()
        if not key:
            raise ConfigError(f"a hyperparameter override must look like key=value, got {item!r}")
        out[key] = _parse_value(raw, f"hyperparameter {key}")
    return out


def parse_env_options(items: list[str], valid: tuple = ENV_OPTION_KEYS, flag: str = "--env") -> dict:
    """``["residual_scale=0.4"]`` as ``{"residual_scale": 0.4}`` (values as YAML, numbers as numbers; nothing is
    evaluated); the keys must be in ``valid`` (default :data:`ENV_OPTION_KEYS`; the values are checked by
    :class:`RunConfig`). ``flag`` names the command-line option in errors."""
    out = {}
    for item in items:
        key, sep, raw = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ConfigError(f"{flag}: an env option must look like key=value, got {item!r}")
        if key not in valid:
            other = {"--env": ("--train-env", TRAINING_ENV_OPTION_KEYS), "--train-env": ("--env", ENV_OPTION_KEYS)}
            hint = ""
            if flag in other and key in other[flag][1]:
                hint = f" ({key} belongs to {other[flag][0]})"
            raise ConfigError(f"unknown env option {key!r}; a run may set {list(valid)} ({flag}){hint}")
        if key in out:
            raise ConfigError(f"{flag} {key} is given twice ({flag} {key}={out[key]!r} and {item!r}); give each key "
                              f"once")
        out[key] = _parse_value(raw, f"env option {key}")
    return out


def _parse_value(raw: str, what: str = "hyperparameter") -> Any:
    """A YAML value, with numbers like ``1e-4`` (a string for YAML 1.1) read as floats."""

    value = loads_yaml(raw, f"{what} value {raw[:80]!r}", error=ConfigError, max_bytes=MAX_VALUE_CHARS)
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return value
    return value


#: keys that may be a linear schedule ``"lin_<initial value>"`` (rl-baselines3-zoo's notation: the value
#: decreases linearly from the initial value at the start of training to 0 at its end)
SCHEDULE_KEYS = ("learning_rate", "clip_range")


def linear_schedule_start(value) -> float | None:
    """The initial value of ``"lin_<x>"`` (x a finite number > 0), else None."""
    if not isinstance(value, str) or not value.startswith("lin_"):
        return None
    try:
        x = float(value[4:])
    except ValueError:
        return None
    return x if math.isfinite(x) and x > 0 else None


def algo_kwargs(hyperparams: dict) -> dict:
    """Keyword arguments for the SB3 algorithm: the entry minus :data:`NON_ALGO_KEYS`, with
    ``policy_kwargs`` given as a string (``"dict(net_arch=[64, 64])"``) parsed safely and
    ``"lin_<x>"`` values of :data:`SCHEDULE_KEYS` as SB3 linear schedules from x to 0."""
    kwargs = {k: v for k, v in hyperparams.items() if k not in NON_ALGO_KEYS}
    pk = kwargs.get("policy_kwargs")
    if isinstance(pk, str):
        kwargs["policy_kwargs"] = parse_dict_call(pk)
    for key in SCHEDULE_KEYS:
        start = linear_schedule_start(kwargs.get(key))
        if start is not None:
            from stable_baselines3.common.utils import LinearSchedule

            kwargs[key] = LinearSchedule(start=start, end=0.0, end_fraction=1.0)
    return kwargs


def normalize_kwargs(hyperparams: dict) -> dict | None:
    """The VecNormalize keyword arguments of an entry, or None (no normalisation), as rl-baselines3-zoo reads
    ``normalize``: ``true`` (VecNormalize's defaults), a mapping or a ``"dict(...)"`` string of arguments, and
    the entry's ``gamma`` (if any) as VecNormalize's ``gamma``."""
    norm = hyperparams.get("normalize")
    if norm is None or norm is False:
        return None
    kwargs = {} if norm is True else dict(parse_dict_call(norm) if isinstance(norm, str) else norm)
    if "gamma" in hyperparams:
        kwargs["gamma"] = hyperparams["gamma"]
    return kwargs


def frame_stack(hyperparams: dict) -> int:
    """The number of consecutive observations the policy sees (``frame_stack`` of the entry, as in
    rl-baselines3-zoo: the training env is wrapped in SB3's VecFrameStack); 1 (no stacking) without the key."""
    return int(hyperparams.get("frame_stack", 1))


def parse_dict_call(text: str, what: str = "policy_kwargs") -> dict:
    """Parse ``"dict(a=1, b=dict(c=[2, 3]))"`` or a ``{...}`` literal without eval."""

    def conv(node: ast.AST) -> Any:
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "dict" and not node.args:
            return {kw.arg: conv(kw.value) for kw in node.keywords}
        if isinstance(node, ast.Dict):
            return {conv(k): conv(v) for k, v in zip(node.keys, node.values)}
        if isinstance(node, (ast.List, ast.Tuple)):
            return [conv(e) for e in node.elts]
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
            return -conv(node.operand)
        if isinstance(node, ast.Constant):
            return node.value
        raise ConfigError(f"{what} may only hold dict(...), lists and constants, got {ast.dump(node)}")

    if not isinstance(text, str) or len(text) > MAX_VALUE_CHARS:
        raise ConfigError(f"{what} must be a string of at most {MAX_VALUE_CHARS:,} characters")
    try:
        tree = ast.parse(text, mode="eval")
        value = conv(tree.body)
    except SyntaxError as exc:
        raise ConfigError(f"{what} {text[:80]!r} is not a valid expression: {exc.msg}") from None
    except (RecursionError, MemoryError):
        raise ConfigError(f"{what} {text[:80]!r}... is nested too deeply") from None
    except TypeError as exc:  # e.g. -"text"
        raise ConfigError(f"{what} {text[:80]!r} is not a valid expression: {exc}") from None
    if nesting_depth(value, MAX_DEPTH) > MAX_DEPTH:
        raise ConfigError(f"{what} {text[:80]!r}... is nested more than {MAX_DEPTH} levels deep")
    if not isinstance(value, dict):
        raise ConfigError(f"{what} must be a dict, got {text!r}")
    return value
