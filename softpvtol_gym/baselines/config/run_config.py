"""RunConfig: everything a training run needs, saved as ``<out>/config.yaml`` next to its checkpoints."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import yaml

from softpvtol_gym.baselines.config.hyperparams import (
    ALGOS,
    ENV_OPTION_KEYS,
    LEGACY_CONTROLLER_LOOP,
    LEGACY_ENV_OPTIONS,
    MAX_EPISODES,
    MAX_N_ENVS,
    MAX_TIMESTEPS,
    RESIDUAL_ONLY_ENV_OPTIONS,
    TRAIN_SEED_LIMIT,
    TRAINING_ENV_OPTION_KEYS,
    read_yaml,
)
from softpvtol_gym.baselines.config.validation import is_int, validate_hyperparams
from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.util.atomic import atomic_write_text
from softpvtol_gym.envs.actions import ACTION_MODES
from softpvtol_gym.envs.config import EnvConfig
from softpvtol_gym.envs.registration import ENV_ID
from softpvtol_gym.envs.tiers import registered_tiers
from softpvtol_gym.tasks import registered_tasks


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
    #: env arguments of the training env only (:data:`TRAINING_ENV_OPTION_KEYS`: extra reward terms, wider
    #: starts; train.py ``--train-env key=value``); evaluations use the task's own reward and starts
    train_env_options: dict = dataclasses.field(default_factory=dict)
    #: a curriculum over the starting error: ``[s0, ramp_steps]`` scales the starts' deviation from the
    #: reference (``start_error_scale``) from s0 at step 0 linearly to the run's scale (train_env_options'
    #: ``start_error_scale``, default 1) at ``ramp_steps``, set at every rollout's start; None: no curriculum
    start_error_curriculum: list | None = None
    #: the training recipe the run was made from (train.py ``--recipe``; its settings are in the fields above),
    #: for the record and for ``--resume``; None: no recipe (or a run saved before the field existed)
    recipe: str | None = None
    #: the run whose policy (and observation statistics) this run started from (train.py ``--init-from``), as
    #: given; None: a fresh policy
    init_from: str | None = None
    #: the imitation term toward a teacher while fine-tuning (train.py ``--bc-weight``): ``{"teacher": NAME,
    #: "weight": w0, "decay_steps": N, "epochs": k}`` (:mod:`~softpvtol_gym.baselines.training.imitation`); None: none
    imitation: dict | None = None

    def __post_init__(self) -> None:
        if self.algo not in ALGOS:
            raise ConfigError(f"algo must be one of {list(ALGOS)}, got {self.algo!r}")
        for name, valid in (("action_mode", ACTION_MODES), ("task", registered_tasks()), ("tier", registered_tiers())):
            if getattr(self, name) not in valid:
                raise ConfigError(f"{name} must be one of {list(valid)}, got {getattr(self, name)!r}")
        if self.env_id != ENV_ID:
            raise ConfigError(f"env_id must be {ENV_ID!r}, got {self.env_id!r}")
        for name, hi in (("timesteps", MAX_TIMESTEPS), ("n_envs", MAX_N_ENVS), ("checkpoint_freq", MAX_TIMESTEPS),
                         ("eval_freq", MAX_TIMESTEPS)):
            v = getattr(self, name)
            if not is_int(v) or v < 1 or v > hi:
                raise ConfigError(f"{name} must be an integer in [1, {hi:,}], got {v!r}")
        if not is_int(self.eval_episodes) or not 0 <= self.eval_episodes <= MAX_EPISODES:
            raise ConfigError(f"eval_episodes must be an integer in [0, {MAX_EPISODES:,}], got {self.eval_episodes!r}")
        if not is_int(self.seed) or not 0 <= self.seed < TRAIN_SEED_LIMIT:
            raise ConfigError(f"seed must be an integer in [0, {TRAIN_SEED_LIMIT:,}) (evaluation seeds start at "
                              f"1,000,000), got {self.seed!r}")
        if not isinstance(self.overrides, list) or not all(isinstance(o, str) for o in self.overrides):
            raise ConfigError(f"overrides must be a list of 'key=value' strings, got {self.overrides!r}")
        validate_hyperparams(self.algo, self.hyperparams, self.n_envs)

        try:
            env_config = EnvConfig(action_mode=self.action_mode, controller_loop=self.controller_loop)
        except (ValueError, TypeError) as exc:
            raise ConfigError(f"controller_loop: {exc}") from None
        self.controller_loop = env_config.resolved_controller_loop
        self._check_env_options(EnvConfig, "env_options", ENV_OPTION_KEYS)
        self._check_env_options(EnvConfig, "train_env_options", TRAINING_ENV_OPTION_KEYS)
        try:  # the two together, as the training env gets them
            EnvConfig(action_mode=self.action_mode, controller_loop=self.controller_loop, **self.env_options,
                      **self.train_env_options)
        except (ValueError, TypeError) as exc:
            raise ConfigError(f"env_options with train_env_options: {exc}") from None
        self._check_curriculum()
        if self.recipe is not None and (not isinstance(self.recipe, str) or not self.recipe):
            raise ConfigError(f"recipe must be a recipe's name or None, got {self.recipe!r}")
        if self.init_from is not None and (not isinstance(self.init_from, str) or not self.init_from):
            raise ConfigError(f"init_from must be a run directory's path or None, got {self.init_from!r}")
        self._check_imitation()

    def _check_imitation(self) -> None:
        spec = self.imitation
        if spec is None:
            return
        keys = {"teacher", "weight", "decay_steps", "epochs"}
        ok = (isinstance(spec, dict) and set(spec) == keys and isinstance(spec["teacher"], str) and spec["teacher"]
              and isinstance(spec["weight"], (int, float)) and not isinstance(spec["weight"], bool)
              and 0 < spec["weight"] <= 1e6
              and is_int(spec["decay_steps"]) and 1 <= spec["decay_steps"] <= MAX_TIMESTEPS
              and is_int(spec["epochs"]) and 1 <= spec["epochs"] <= 100)
        if not ok:
            raise ConfigError(f"imitation must be None or {{teacher: a teacher's name, weight: in (0, 1e6], "
                              f"decay_steps: an integer in [1, {MAX_TIMESTEPS:,}], epochs: an integer in [1, 100]}}, "
                              f"got {spec!r}")
        if self.algo != "ppo":
            raise ConfigError(f"the imitation term fine-tunes PPO runs, got algo {self.algo!r}")
        if self.action_mode != "actuators":
            raise ConfigError(f"the imitation term imitates a teacher's actuator commands: it needs action_mode "
                              f"'actuators', got {self.action_mode!r}")

    def _check_env_options(self, env_config_class, field: str, valid: tuple) -> None:
        """``field``: a mapping of ``valid`` keys that the env accepts (each value checked by EnvConfig; a
        ConfigError names the key), each of which has an effect in the run's action mode."""
        opts = getattr(self, field)
        flag = "--env" if field == "env_options" else "--train-env"
        what = "env option" if field == "env_options" else "training env option"
        if not isinstance(opts, dict):
            raise ConfigError(f"{field} must be a mapping of {list(valid)} to values, got {opts!r}")
        for key, value in opts.items():
            if key not in valid:
                other = TRAINING_ENV_OPTION_KEYS if field == "env_options" else ENV_OPTION_KEYS
                hint = (f" ({key} is a{' training-only' if field == 'env_options' else 'n interface'} option: pass "
                        f"it as {'--train-env' if flag == '--env' else '--env'})" if key in other else "")
                raise ConfigError(f"unknown {what} {key!r} ({flag}); a run may set {list(valid)}{hint}")
            if key in RESIDUAL_ONLY_ENV_OPTIONS and self.action_mode != "residual":
                raise ConfigError(f"env option {key} acts on the residual action mode only; this run's action mode "
                                  f"is {self.action_mode!r} (leave {key} out)")
            # residual_base is checked with the space it acts in (only the actuator space has a base to clip)
            context = {"residual_space": opts["residual_space"]} if key == "residual_base" and \
                "residual_space" in opts else {}
            try:
                env_config_class(action_mode=self.action_mode, controller_loop=self.controller_loop, **context,
                                 **{key: value})
            except (ValueError, TypeError) as exc:
                raise ConfigError(f"{what} {key}: {exc}") from None

    def _check_curriculum(self) -> None:
        c = self.start_error_curriculum
        if c is None:
            return
        ok = (isinstance(c, list) and len(c) == 2 and isinstance(c[0], (int, float)) and not isinstance(c[0], bool)
              and 0.0 <= c[0] <= 10.0 and is_int(c[1]) and 1 <= c[1] <= MAX_TIMESTEPS)
        if not ok:
            raise ConfigError(f"start_error_curriculum must be [s0, ramp_steps] with 0 <= s0 <= 10 (the starting "
                              f"error's scale at step 0) and an integer ramp_steps in [1, {MAX_TIMESTEPS:,}], or "
                              f"None; got {c!r}")

    def start_error_scale_at(self, step: int) -> float:
        """The curriculum's starting-error scale at training step ``step`` (the run's scale without one)."""
        target = float(self.train_env_options.get("start_error_scale", 1.0))
        if self.start_error_curriculum is None:
            return target
        s0, ramp = self.start_error_curriculum
        return float(s0) + (target - float(s0)) * min(1.0, max(0, step) / ramp)

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
            # saved before the field existed (2026-12-01): those runs used the env's defaults
            data = {**data, "env_options": dict(LEGACY_ENV_OPTIONS)}
        if strict:  # saved before the fields existed (2026-12-02): no training aids
            data = {"train_env_options": {}, "start_error_curriculum": None, **data}
        if strict:  # saved before the recipe was recorded: none recorded
            data = {"recipe": None, **data}
        if strict:  # saved before fine-tuning existed: a fresh policy, no imitation term
            data = {"init_from": None, "imitation": None, **data}
        if strict:
            lost = [n for n in names if n not in data]
            if lost:
                raise ConfigError(f"{source} lacks the keys {lost} (a saved run config has all of {names})")
        return cls(**data)

    def to_yaml(self) -> str:
        return yaml.safe_dump(self.to_dict(), sort_keys=False)

    def save(self, path: Path) -> None:
        atomic_write_text(path, self.to_yaml())

    @classmethod
    def load(cls, path: Path) -> RunConfig:
        path = Path(path)
        return cls.from_dict(read_yaml(path, "run config"), source=f"run config {path}", strict=True)

    def env_kwargs(self) -> dict:
        """Env arguments of this run's training env."""
        return {"action_mode": self.action_mode, "task": self.task, "tier": self.tier, **self.eval_env_kwargs(),
                **self.train_env_options}

    def eval_env_kwargs(self) -> dict:
        """Env arguments of this run's evaluations besides mode, task and tier (the base loop and the env
        options): a policy is evaluated on the action space it was trained on, on any task and tier."""
        return {"controller_loop": self.controller_loop, **self.env_options}
