"""Run configuration: hyperparameters from YAML per env id (one per action mode), CLI overrides, validation,
saving.

``baselines/hyperparams/<algo>.yml`` holds one entry per env id, in rl-baselines3-zoo's format (the same
file works with ``python -m rl_zoo3.train --conf-file``): the action modes are the ids
``SoftPVTOLResidual-v0``, ``SoftPVTOLVirtual-v0`` and ``SoftPVTOLActuators-v0`` (``SoftPVTOL-v0``, whose
default action mode is ``actuators``, is an alias of the last). :func:`load_hyperparams` reads the entry,
:func:`apply_overrides` applies ``key=value`` strings from the command line (values parsed as YAML),
:func:`validate_hyperparams` checks every key against the algorithm's constructor and stable-baselines3's
constraints (before anything is written), and :class:`RunConfig` is what a run saves next to its
checkpoints (``config.yaml``), so that a run can be resumed, evaluated or audited later.
"""

from __future__ import annotations

import ast
import dataclasses
import math
from pathlib import Path
from typing import Any

from softpvtol_gym.envs.core import ACTION_MODES, TASKS, TIERS
from softpvtol_gym.envs.registration import ENV_ID, MODE_ENV_IDS

from .errors import ConfigError

__all__ = ["ConfigError", "RunConfig", "load_hyperparams", "apply_overrides", "algo_kwargs", "validate_hyperparams",
           "read_yaml", "frame_stack", "parse_env_options", "ENV_OPTION_KEYS"]

CONFIG_FILE_NAME = "config.yaml"
#: the residual base loop of runs saved before RunConfig had ``controller_loop`` (the env's default then)
LEGACY_CONTROLLER_LOOP = "exact"
HYPERPARAMS_DIR = Path(__file__).resolve().parent / "hyperparams"
ALGOS = ("ppo", "sac")
#: keys of a hyperparameter entry that are not keyword arguments of the SB3 algorithm
NON_ALGO_KEYS = ("policy", "n_envs", "n_timesteps", "normalize", "frame_stack")
#: the most observations ``frame_stack`` may stack (a bound on the policy's input, 64 floats per observation)
MAX_FRAME_STACK = 64
#: env arguments a run may set besides mode, task, tier and base loop (RunConfig.env_options, train.py --env):
#: the residual mode's residual scale and the space the residual acts in (softpvtol_gym EnvConfig fields)
ENV_OPTION_KEYS = ("residual_scale", "residual_space")
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


def read_yaml(path: Path, what: str) -> Any:
    """``yaml.safe_load`` of a file, with every failure a ConfigError naming the file and the problem."""
    import yaml

    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"{what} {path} is a directory; expected a YAML file")
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"no {what} at {path}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read {what} {path}: {exc}") from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise ConfigError(f"{what} {path} is not valid YAML{where}: {problem}") from None


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
        out[key] = _parse_value(raw)
    return out


def parse_env_options(items: list[str]) -> dict:
    """``["residual_scale=0.4"]`` as ``{"residual_scale": 0.4}`` (values as YAML, numbers as numbers; nothing is
    evaluated); the keys must be in :data:`ENV_OPTION_KEYS` (the values are checked by :class:`RunConfig`)."""
    out = {}
    for item in items:
        key, sep, raw = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ConfigError(f"an env option must look like key=value, got {item!r}")
        if key not in ENV_OPTION_KEYS:
            raise ConfigError(f"unknown env option {key!r}; a run may set {list(ENV_OPTION_KEYS)}")
        out[key] = _parse_value(raw, "env option")
    return out


def _parse_value(raw: str, what: str = "hyperparameter") -> Any:
    """A YAML value, with numbers like ``1e-4`` (a string for YAML 1.1) read as floats."""
    import yaml

    try:
        value = yaml.safe_load(raw)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{what} value {raw!r} is not valid YAML: {getattr(exc, 'problem', exc)}") from None
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return value
    return value


#: keys that may be a linear schedule ``"lin_<initial value>"`` (rl-baselines3-zoo's notation: the value
#: decreases linearly from the initial value at the start of training to 0 at its end)
SCHEDULE_KEYS = ("learning_rate", "clip_range")


def _linear_schedule_start(value) -> float | None:
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
        kwargs["policy_kwargs"] = _parse_dict_call(pk)
    for key in SCHEDULE_KEYS:
        start = _linear_schedule_start(kwargs.get(key))
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
    kwargs = {} if norm is True else dict(_parse_dict_call(norm) if isinstance(norm, str) else norm)
    if "gamma" in hyperparams:
        kwargs["gamma"] = hyperparams["gamma"]
    return kwargs


def frame_stack(hyperparams: dict) -> int:
    """The number of consecutive observations the policy sees (``frame_stack`` of the entry, as in
    rl-baselines3-zoo: the training env is wrapped in SB3's VecFrameStack); 1 (no stacking) without the key."""
    return int(hyperparams.get("frame_stack", 1))


def _parse_dict_call(text: str, what: str = "policy_kwargs") -> dict:
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

    try:
        tree = ast.parse(text, mode="eval")
    except SyntaxError as exc:
        raise ConfigError(f"{what} {text!r} is not a valid expression: {exc.msg}") from None
    value = conv(tree.body)
    if not isinstance(value, dict):
        raise ConfigError(f"{what} must be a dict, got {text!r}")
    return value


# ------------------------------------------------------------------------------- validation
def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _int(lo=None, hi=None):
    def check(v):
        if not _is_int(v) or (lo is not None and v < lo) or (hi is not None and v > hi):
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
    if _linear_schedule_start(v) is None and (not _is_num(v) or v <= 0):
        return "a finite number > 0 or a linear schedule 'lin_<initial value > 0>'"


def _policy_kwargs(v):
    if isinstance(v, str):
        try:
            _parse_dict_call(v)
        except ConfigError as exc:
            return f"a dict(...) expression ({exc})"
        return None
    if not isinstance(v, dict):
        return "a dict or a 'dict(...)' string"


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
    if _is_int(v) and v >= 1:
        return None
    if (isinstance(v, (list, tuple)) and len(v) == 2 and _is_int(v[0]) and v[0] >= 1
            and v[1] in ("step", "episode")):
        return None
    return "an integer >= 1 or [n >= 1, 'step' | 'episode']"


def _gradient_steps(v):
    if not _is_int(v) or (v < 1 and v != -1):
        return "an integer >= 1, or -1 (as many as env steps)"


def _policy(v):
    if v != "MlpPolicy":
        return "'MlpPolicy' (the observation is a flat vector)"


def _normalize(v):
    if v is None or isinstance(v, bool):
        return None
    what = f"true, false, or a mapping (or 'dict(...)' string) of VecNormalize arguments {list(VECNORM_KEYS)}"
    if isinstance(v, str):
        try:
            v = _parse_dict_call(v, "normalize")
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
        norm_gamma = (_parse_dict_call(norm, "normalize") if isinstance(norm, str) else norm).get("gamma", hp["gamma"])
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
    import inspect

    from stable_baselines3 import PPO, SAC

    cls = {"ppo": PPO, "sac": SAC}[algo]
    params = set(inspect.signature(cls.__init__).parameters) - set(RESERVED_ALGO_ARGS)
    table = (set(_COMMON_RULES) | set(_RULES[algo])) - set(NON_ALGO_KEYS)
    if params != table:
        raise AssertionError(f"{algo}: SB3 arguments {sorted(params - table)} are not validated; "
                             f"{sorted(table - params)} are not SB3 arguments")


# ------------------------------------------------------------------------------- RunConfig
@dataclasses.dataclass
class RunConfig:
    """Everything a training run needs; saved as ``<out>/config.yaml``.

    ``hyperparams`` is the YAML entry after CLI overrides; ``overrides`` lists what the CLI changed
    (``--hp`` strings and explicit ``--n-envs``), for the record. Every field is validated on creation
    (and therefore on loading a saved config).
    """

    algo: str = "ppo"
    action_mode: str = "residual"
    task: str = "hover"
    tier: str = "nominal"
    timesteps: int = 1_000_000
    seed: int = 0
    n_envs: int = 16
    hyperparams: dict = dataclasses.field(default_factory=dict)
    overrides: list = dataclasses.field(default_factory=list)
    checkpoint_freq: int = 100_000
    eval_freq: int = 100_000
    eval_episodes: int = 10
    env_id: str = ENV_ID
    #: the analytic loop of the residual base controller (and of the passivity comparison): None ->
    #: the env's default, stored resolved so that a saved run records it (control.LOOPS)
    controller_loop: str | None = None
    #: env arguments of the run's training and evaluation envs besides the above (:data:`ENV_OPTION_KEYS`,
    #: e.g. ``{"residual_scale": 0.4}``; train.py ``--env key=value``); empty: the env's defaults
    env_options: dict = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.algo not in ALGOS:
            raise ConfigError(f"algo must be one of {list(ALGOS)}, got {self.algo!r}")
        for name, valid in (("action_mode", ACTION_MODES), ("task", TASKS), ("tier", TIERS)):
            if getattr(self, name) not in valid:
                raise ConfigError(f"{name} must be one of {list(valid)}, got {getattr(self, name)!r}")
        if self.env_id != ENV_ID:
            raise ConfigError(f"env_id must be {ENV_ID!r}, got {self.env_id!r}")
        for name, hi in (("timesteps", MAX_TIMESTEPS), ("n_envs", MAX_N_ENVS), ("checkpoint_freq", MAX_TIMESTEPS),
                         ("eval_freq", MAX_TIMESTEPS)):
            v = getattr(self, name)
            if not _is_int(v) or v < 1 or v > hi:
                raise ConfigError(f"{name} must be an integer in [1, {hi:,}], got {v!r}")
        if not _is_int(self.eval_episodes) or not 0 <= self.eval_episodes <= MAX_EPISODES:
            raise ConfigError(f"eval_episodes must be an integer in [0, {MAX_EPISODES:,}], got {self.eval_episodes!r}")
        if not _is_int(self.seed) or not 0 <= self.seed < TRAIN_SEED_LIMIT:
            raise ConfigError(f"seed must be an integer in [0, {TRAIN_SEED_LIMIT:,}) (evaluation seeds start at "
                              f"1,000,000), got {self.seed!r}")
        if not isinstance(self.overrides, list) or not all(isinstance(o, str) for o in self.overrides):
            raise ConfigError(f"overrides must be a list of 'key=value' strings, got {self.overrides!r}")
        validate_hyperparams(self.algo, self.hyperparams, self.n_envs)
        from softpvtol_gym.envs.config import EnvConfig

        try:
            env_config = EnvConfig(action_mode=self.action_mode, controller_loop=self.controller_loop)
        except (ValueError, TypeError) as exc:
            raise ConfigError(f"controller_loop: {exc}") from None
        self.controller_loop = env_config.resolved_controller_loop
        self._check_env_options(EnvConfig)

    def _check_env_options(self, env_config_class) -> None:
        """env_options: a mapping of :data:`ENV_OPTION_KEYS` that the env accepts (each value checked by
        EnvConfig; a ConfigError names the key), each of which has an effect in the run's action mode."""
        opts = self.env_options
        if not isinstance(opts, dict):
            raise ConfigError(f"env_options must be a mapping of {list(ENV_OPTION_KEYS)} to values, got {opts!r}")
        for key, value in opts.items():
            if key not in ENV_OPTION_KEYS:
                raise ConfigError(f"unknown env option {key!r}; a run may set {list(ENV_OPTION_KEYS)}")
            if self.action_mode != "residual":  # both options shape the residual action only
                raise ConfigError(f"env option {key} acts on the residual action mode only; this run's action mode "
                                  f"is {self.action_mode!r} (leave {key} out)")
            try:
                env_config_class(action_mode=self.action_mode, controller_loop=self.controller_loop, **{key: value})
            except (ValueError, TypeError) as exc:
                raise ConfigError(f"env option {key}: {exc}") from None

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: Any, source: str = "run config", strict: bool = False) -> RunConfig:
        """A RunConfig from a mapping; ``strict``: every field must be present (saved configs)."""
        names = [f.name for f in dataclasses.fields(cls)]
        if not isinstance(data, dict):
            what = "empty" if data is None else f"a {type(data).__name__}"
            raise ConfigError(f"{source} is {what}; expected a mapping with the keys {names}")
        unknown = set(data) - set(names)
        if unknown:
            raise ConfigError(f"{source}: unknown keys {sorted(map(str, unknown))}; valid ones are {sorted(names)}")
        if strict and "controller_loop" not in data:
            # saved before the field existed (2026-12-01): those runs trained on the "exact" base loop
            data = {**data, "controller_loop": LEGACY_CONTROLLER_LOOP}
        if strict and "env_options" not in data:
            # saved before the field existed (2026-12-01, issue 16): those runs used the env's defaults
            data = {**data, "env_options": dict(LEGACY_ENV_OPTIONS)}
        if strict:
            lost = [n for n in names if n not in data]
            if lost:
                raise ConfigError(f"{source} lacks the keys {lost} (a saved run config has all of {names})")
        return cls(**data)

    def to_yaml(self) -> str:
        import yaml

        return yaml.safe_dump(self.to_dict(), sort_keys=False)

    def save(self, path: Path) -> None:
        from .atomic import atomic_write_text

        atomic_write_text(path, self.to_yaml())

    @classmethod
    def load(cls, path: Path) -> RunConfig:
        path = Path(path)
        return cls.from_dict(read_yaml(path, "run config"), source=f"run config {path}", strict=True)

    def env_kwargs(self) -> dict:
        """Env arguments of this run's training env."""
        return {"action_mode": self.action_mode, "task": self.task, "tier": self.tier, **self.eval_env_kwargs()}

    def eval_env_kwargs(self) -> dict:
        """Env arguments of this run's evaluations besides mode, task and tier (the base loop and the env
        options): a policy is evaluated on the action space it was trained on, on any task and tier."""
        return {"controller_loop": self.controller_loop, **self.env_options}
