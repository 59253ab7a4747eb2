"""Training recipes: a named training setup, ``softpvtol_gym/baselines/data/hyperparams/recipes.yml``.

A recipe is an entry of an algorithm's hyperparameter file (``<algo>.yml``, rl-baselines3-zoo's format, keyed by
the action mode's env id) together with everything else a run needs to reproduce it: the residual mode's base
loop, the env options that define the policy's interface (``env_options``), the training-only env options
(``train_env_options``: reward terms, wider starts), a curriculum over the starting error and ``--hp`` style
overrides of the YAML entry. ``train.py --recipe NAME`` and the leaderboard's ``recipe:`` cells use it; every
value is validated by :class:`~softpvtol_gym.baselines.config.run_config.RunConfig` when a run is built.
"""

from __future__ import annotations

from pathlib import Path

from softpvtol_gym.baselines.config.hyperparams import (
    ALGOS,
    ENV_OPTION_KEYS,
    HYPERPARAMS_DIR,
    TRAINING_ENV_OPTION_KEYS,
    apply_overrides,
    load_hyperparams,
    read_yaml,
)
from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.util.paths import check_slug
from softpvtol_gym.control import LOOPS
from softpvtol_gym.envs.actions import ACTION_MODES

RECIPES_FILE = HYPERPARAMS_DIR / "recipes.yml"
#: a recipe's keys; ``description``, ``algo`` and ``action_mode`` are required
RECIPE_KEYS = ("description", "algo", "action_mode", "controller_loop", "env_options", "train_env_options",
               "start_error_curriculum", "hp", "eval_freq")
REQUIRED_RECIPE_KEYS = ("description", "algo", "action_mode")


def load_recipes(path: Path = RECIPES_FILE) -> dict[str, dict]:
    """Every recipe of ``path``, each validated (ConfigError naming the recipe and key otherwise)."""
    table = read_yaml(path, "recipes file")
    if not isinstance(table, dict) or not table:
        raise ConfigError(f"recipes file {path} must map recipe names to entries, got {table!r}")
    return {name: validate_recipe(name, entry, f"recipe {name!r} of {path}") for name, entry in table.items()}


def load_recipe(name: str, path: Path = RECIPES_FILE) -> dict:
    """The recipe ``name`` (ConfigError listing the known ones if there is none)."""
    recipes = load_recipes(path)
    if name not in recipes:
        raise ConfigError(f"no recipe {name!r} in {path}; recipes: {sorted(recipes)}")
    return recipes[name]


def validate_recipe(name, entry, where: str) -> dict:
    """``entry`` with its defaults filled in (controller_loop None, empty options, no curriculum, no hp)."""
    if not isinstance(name, str):
        raise ConfigError(f"{where}: a recipe name must be a string, got {name!r}")
    check_slug(name, f"{where} (its name)")
    if not isinstance(entry, dict):
        raise ConfigError(f"{where} must be a mapping with the keys {list(RECIPE_KEYS)}, got {entry!r}")
    unknown = [k for k in entry if k not in RECIPE_KEYS]
    if unknown:
        raise ConfigError(f"{where} has unknown keys {unknown}; valid ones are {list(RECIPE_KEYS)}")
    lost = [k for k in REQUIRED_RECIPE_KEYS if k not in entry]
    if lost:
        raise ConfigError(f"{where} lacks the keys {lost}")
    out = {"controller_loop": None, "env_options": {}, "train_env_options": {}, "start_error_curriculum": None,
           "hp": [], "eval_freq": None, **entry}
    if not isinstance(out["description"], str) or not out["description"].strip():
        raise ConfigError(f"{where}: description must be a non-empty string, got {out['description']!r}")
    if out["algo"] not in ALGOS:
        raise ConfigError(f"{where}: algo must be one of {list(ALGOS)}, got {out['algo']!r}")
    if out["action_mode"] not in ACTION_MODES:
        raise ConfigError(f"{where}: action_mode must be one of {list(ACTION_MODES)}, got {out['action_mode']!r}")
    if out["controller_loop"] is not None and out["controller_loop"] not in LOOPS:
        raise ConfigError(f"{where}: controller_loop must be one of {list(LOOPS)} or null, got "
                          f"{out['controller_loop']!r}")
    for key, valid in (("env_options", ENV_OPTION_KEYS), ("train_env_options", TRAINING_ENV_OPTION_KEYS)):
        opts = out[key]
        if not isinstance(opts, dict) or any(k not in valid for k in opts):
            raise ConfigError(f"{where}: {key} must be a mapping with keys among {list(valid)}, got {opts!r}")
    hp = out["hp"]
    if not isinstance(hp, list) or not all(isinstance(h, str) for h in hp):
        raise ConfigError(f"{where}: hp must be a list of 'key=value' strings, got {hp!r}")
    freq = out["eval_freq"]
    if freq is not None and (isinstance(freq, bool) or not isinstance(freq, int) or freq < 1):
        raise ConfigError(f"{where}: eval_freq must be a positive integer (train.py's periodic evaluation every "
                          f"that many steps) or null, got {freq!r}")
    return out


def recipe_hyperparams(recipe: dict, directory: Path | None = None) -> dict:
    """The recipe's hyperparameters: its algorithm's entry for its action mode, with its ``hp`` overrides."""
    return apply_overrides(load_hyperparams(recipe["algo"], recipe["action_mode"], directory), recipe["hp"])


def recipe_config_fields(recipe: dict) -> dict:
    """The RunConfig fields a recipe sets (besides hyperparameters, task, tier, seed and budget)."""
    return {"algo": recipe["algo"], "action_mode": recipe["action_mode"], "controller_loop": recipe["controller_loop"],
            "env_options": dict(recipe["env_options"]), "train_env_options": dict(recipe["train_env_options"]),
            "start_error_curriculum": recipe["start_error_curriculum"]}
