"""Run configuration: hyperparameters from YAML per (env id, action mode), CLI overrides, saving.

``baselines/hyperparams/<algo>.yml`` holds one entry per ``"<env id>/<action mode>"`` (rl-baselines3-zoo
style). :func:`load_hyperparams` reads the entry, :func:`apply_overrides` applies ``key=value`` strings
from the command line (values parsed as YAML), and :class:`RunConfig` is what a run saves next to its
checkpoints (``config.yaml``), so that a run can be resumed, evaluated or audited later.
"""

from __future__ import annotations

import ast
import dataclasses
from pathlib import Path
from typing import Any

import yaml

from softpvtol_gym.envs.core import ACTION_MODES, TASKS, TIERS

ENV_ID = "SoftPVTOL-v0"
HYPERPARAMS_DIR = Path(__file__).resolve().parent / "hyperparams"
ALGOS = ("ppo", "sac")
#: keys of a hyperparameter entry that are not keyword arguments of the SB3 algorithm
NON_ALGO_KEYS = ("policy", "n_envs", "n_timesteps", "normalize")


class ConfigError(ValueError):
    """A bad configuration value: the message names what was received and what is expected."""


def load_hyperparams(algo: str, action_mode: str, env_id: str = ENV_ID, directory: Path | None = None) -> dict:
    """The hyperparameter entry ``"<env_id>/<action_mode>"`` of ``<directory>/<algo>.yml`` (a copy)."""
    if algo not in ALGOS:
        raise ConfigError(f"algo must be one of {list(ALGOS)}, got {algo!r}")
    if action_mode not in ACTION_MODES:
        raise ConfigError(f"action mode must be one of {list(ACTION_MODES)}, got {action_mode!r}")
    path = (HYPERPARAMS_DIR if directory is None else Path(directory)) / f"{algo}.yml"
    if not path.is_file():
        raise ConfigError(f"no hyperparameter file {path}")
    table = yaml.safe_load(path.read_text()) or {}
    key = f"{env_id}/{action_mode}"
    if key not in table:
        raise ConfigError(f"{path} has no entry {key!r}; entries: {sorted(table)}")
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


def _parse_value(raw: str) -> Any:
    """A YAML value, with numbers like ``1e-4`` (a string for YAML 1.1) read as floats."""
    value = yaml.safe_load(raw)
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return value
    return value


def algo_kwargs(hyperparams: dict) -> dict:
    """Keyword arguments for the SB3 algorithm: the entry minus :data:`NON_ALGO_KEYS`, with
    ``policy_kwargs`` given as a string (``"dict(net_arch=[64, 64])"``) parsed safely."""
    kwargs = {k: v for k, v in hyperparams.items() if k not in NON_ALGO_KEYS}
    pk = kwargs.get("policy_kwargs")
    if isinstance(pk, str):
        kwargs["policy_kwargs"] = _parse_dict_call(pk)
    return kwargs


def _parse_dict_call(text: str) -> dict:
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
        raise ConfigError(f"policy_kwargs may only hold dict(...), lists and constants, got {ast.dump(node)}")

    try:
        tree = ast.parse(text, mode="eval")
    except SyntaxError as exc:
        raise ConfigError(f"policy_kwargs {text!r} is not a valid expression: {exc.msg}") from None
    value = conv(tree.body)
    if not isinstance(value, dict):
        raise ConfigError(f"policy_kwargs must be a dict, got {text!r}")
    return value


@dataclasses.dataclass
class RunConfig:
    """Everything a training run needs; saved as ``<out>/config.yaml``.

    ``hyperparams`` is the YAML entry after CLI overrides; ``overrides`` lists what the CLI changed
    (``--hp`` strings and explicit ``--n-envs``), for the record.
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

    def __post_init__(self) -> None:
        if self.algo not in ALGOS:
            raise ConfigError(f"algo must be one of {list(ALGOS)}, got {self.algo!r}")
        for name, valid in (("action_mode", ACTION_MODES), ("task", TASKS), ("tier", TIERS)):
            if getattr(self, name) not in valid:
                raise ConfigError(f"{name} must be one of {list(valid)}, got {getattr(self, name)!r}")
        for name in ("timesteps", "n_envs", "checkpoint_freq", "eval_freq"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ConfigError(f"{name} must be an integer >= 1, got {v!r}")
        if isinstance(self.eval_episodes, bool) or not isinstance(self.eval_episodes, int) or self.eval_episodes < 0:
            raise ConfigError(f"eval_episodes must be an integer >= 0, got {self.eval_episodes!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ConfigError(f"seed must be an integer >= 0, got {self.seed!r}")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> RunConfig:
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(data) - names
        if unknown:
            raise ConfigError(f"unknown run config keys {sorted(unknown)}; valid ones are {sorted(names)}")
        return cls(**data)

    def save(self, path: Path) -> None:
        Path(path).write_text(yaml.safe_dump(self.to_dict(), sort_keys=False))

    @classmethod
    def load(cls, path: Path) -> RunConfig:
        path = Path(path)
        if not path.is_file():
            raise ConfigError(f"no run config at {path}")
        return cls.from_dict(yaml.safe_load(path.read_text()))

    def env_kwargs(self) -> dict:
        return {"action_mode": self.action_mode, "task": self.task, "tier": self.tier}
